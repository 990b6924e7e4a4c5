"""`pip install ./clients` into a fresh virtualenv outside the checkout gives a working client:
the envs find the scenario names from the server (ServerInfo.pools), not from files of the
checkout. Needs the package registry for the dependencies (as `make venv` does)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

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


def test_a_fresh_venv_with_the_train_extra_trains_against_a_server_it_starts(tmp_path):
    """`sharedspace[train]` into a fresh venv outside the checkout, offline from uv's cache (the
    one `make venv` filled: torch is not downloaded a second time), then ``python -m
    sharedspace.train`` with no endpoint: it finds ``sim-server`` on PATH (as ``cargo install
    --path sim-server`` leaves it), starts it and trains a few hundred frames."""
    from conftest import TINY_TRAIN, sim_server_binary

    binary = sim_server_binary()
    assert binary is not None, "no sim-server built (make build)"
    uv = Path(sys.executable).parent / "uv"
    assert uv.is_file(), f"{uv} missing: `make venv` installs uv"
    venv = tmp_path / "venv"
    subprocess.run([str(uv), "venv", "-q", "--python", sys.executable, str(venv)], check=True)
    python = venv / "bin" / "python"
    install = subprocess.run(
        [
            str(uv),
            "pip",
            "install",
            "--offline",
            "--python",
            str(python),
            f"{REPO_ROOT / 'clients'}[train]",
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert install.returncode == 0, install.stderr[-3000:]

    bin_dir = tmp_path / "bin"  # a PATH with sim-server on it, as `cargo install` makes one
    bin_dir.mkdir()
    (bin_dir / "sim-server").symlink_to(Path(binary).resolve())  # may be relative
    env = {k: v for k, v in os.environ.items() if k != "SHAREDSPACE_SIM_SERVER"}

    def run(path: str, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(python), *args],
            cwd=tmp_path,
            env={**env, "PATH": path},
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    missing = run(
        f"{venv / 'bin'}:/usr/bin:/bin",
        "-m",
        "sharedspace.train",
        "--set",
        "total_frames=64",
        timeout=120,
    )
    assert missing.returncode != 0
    assert "cargo install --path sim-server" in missing.stderr, missing.stderr[-2000:]
    assert "SHAREDSPACE_SIM_SERVER" in missing.stderr, missing.stderr[-2000:]

    trained = run(
        f"{bin_dir}:{venv / 'bin'}:/usr/bin:/bin",
        "-m",
        "sharedspace.train",
        "--set",
        *TINY_TRAIN,
        "total_frames=256",
        "eval_interval=0",
        f"log_dir={tmp_path / 'run'}",
    )
    assert trained.returncode == 0, trained.stderr[-3000:]
    out = json.loads(trained.stdout.strip().splitlines()[-1])
    assert out["counters"]["frames"] == 256 and out["counters"]["updates"] > 0, out
    assert str(REPO_ROOT) not in trained.stderr  # nothing came from the checkout
