"""`pip install ./clients` into a fresh virtualenv outside the checkout gives a working client:
the envs find the scenario names from the server (ServerInfo.pools), not from files of the
checkout. Needs the package registry for the dependencies (as `make venv` does)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest
from conftest import REPO_ROOT


def test_scenario_discovery_through_the_api(sim_client):
    name, scenarios = sim_client.scenarios()
    assert name == "hbs-paper" and len(scenarios) == 77
    assert sum(split == "test" for _, split in scenarios) == 18
    assert scenarios[0][0].startswith("hbs-car")
    with pytest.raises(Exception, match="no scenario pool"):
        sim_client.scenarios("nosuch")


def test_pip_install_into_a_fresh_venv_outside_the_checkout(sim_server, tmp_path):
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    install = subprocess.run(
        [str(python), "-m", "pip", "install", "-q", str(REPO_ROOT / "clients")],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert install.returncode == 0, install.stderr[-2000:]
    script = textwrap.dedent(
        f"""
        import gymnasium, sharedspace
        assert "{REPO_ROOT}" not in sharedspace.__file__, sharedspace.__file__
        env = gymnasium.make("sharedspace/SharedSpace-v0", endpoint="{sim_server.endpoint}",
                             prefix="{sim_server.prefix}", split="test")
        obs, info = env.reset(seed=0)
        assert info["scenario_index"] >= 0, info
        done, steps = False, 0
        while not done:
            obs, reward, term, trunc, info = env.step(env.action_space.sample())
            done, steps = term or trunc, steps + 1
        print("episode", steps, env.unwrapped._parallel.scenario)
        env.close()
        """
    )
    run = subprocess.run(
        [str(python), "-c", script], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.startswith("episode ") and "hbs-car" in run.stdout
