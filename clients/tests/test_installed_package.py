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


def make_wheels(out: Path) -> tuple[Path, Path]:
    """The two wheels of ``make wheel`` (``sharedspace-server``: sim-server/pyproject.toml, maturin;
    ``sharedspace`` with the viewer's page), built by that target in the dev profile: it reuses
    the debug build of ``make test`` (a release build would add minutes); the packaging is the
    same."""
    built = subprocess.run(
        ["make", "--no-print-directory", "wheel", "WHEEL_PROFILE=", f"DIST={out}"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=1500,
    )
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-3000:]
    (server,) = out.glob("sharedspace_server-*.whl")
    (package,) = out.glob("sharedspace-*.whl")
    return server, package


def test_the_wheels_install_into_a_fresh_venv_and_train_with_the_bundled_server(tmp_path):
    """The wheels of `make wheel` into a fresh venv outside the checkout, offline from uv's cache
    (the one `make venv` filled: torch is not downloaded a second time). With only
    `sharedspace[train]`, ``python -m sharedspace.train`` says where to get a server; with the
    `sharedspace-server` wheel too (and a PATH holding no cargo, no target/ and not even the
    venv), the trainer and ``sharedspace.LocalServer`` start the bundled ``sim-server``: 256
    frames of training, a PettingZoo episode, and the viewer serving its page from the wheel."""
    from conftest import TINY_TRAIN

    uv = Path(sys.executable).parent / "uv"
    assert uv.is_file(), f"{uv} missing: `make venv` installs uv"
    server_wheel, package_wheel = make_wheels(tmp_path / "dist")
    venv = tmp_path / "venv"
    subprocess.run([str(uv), "venv", "-q", "--python", sys.executable, str(venv)], check=True)
    python = venv / "bin" / "python"

    def install(*what: str) -> None:
        done = subprocess.run(
            [str(uv), "pip", "install", "--offline", "--python", str(python), *what],
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert done.returncode == 0, done.stderr[-3000:]

    install(f"sharedspace[train] @ {package_wheel.as_uri()}")
    env = {k: v for k, v in os.environ.items() if k != "SHAREDSPACE_SIM_SERVER"}
    bare_path = "/usr/bin:/bin"
    assert not any(
        (Path(d) / "cargo").exists() or (Path(d) / "sim-server").exists()
        for d in bare_path.split(":")
    )

    def run(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(python), *args],
            cwd=tmp_path,
            env={**env, "PATH": bare_path},
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    missing = run("-m", "sharedspace.train", "--set", "total_frames=64", timeout=120)
    assert missing.returncode != 0
    for hint in (
        "sharedspace[server]",
        "cargo install --path sim-server",
        "SHAREDSPACE_SIM_SERVER",
    ):
        assert hint in missing.stderr, missing.stderr[-2000:]

    install(str(server_wheel))
    assert (venv / "bin" / "sim-server").is_file()
    trained = run(
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

    script = textwrap.dedent(
        """
        import urllib.request
        import sharedspace
        from sharedspace.local_server import sim_server_binary
        from sharedspace.viewer import Viewer
        print("binary", sim_server_binary())
        with sharedspace.LocalServer() as server:
            env = sharedspace.parallel_env(endpoint=server.endpoint, prefix=server.prefix)
            obs, infos = env.reset(seed=0)
            steps = 0
            while env.agents:
                actions = {a: env.action_space(a).sample() for a in env.agents}
                obs, rewards, terms, truncs, infos = env.step(actions)
                steps += 1
            env.close()
            print("episode", steps)
            # The watch command's page and router come from the wheels, not from a checkout.
            with Viewer(server.endpoint, prefix=server.prefix) as viewer:
                page = urllib.request.urlopen(viewer.url(), timeout=10).read().decode()
            print("page", sharedspace.viewer.VIEWER_DIST, "viewer.js" in page)
        """
    )
    played = run("-c", script, timeout=300)
    assert played.returncode == 0, played.stderr[-3000:]
    assert f"binary {venv / 'bin' / 'sim-server'}" in played.stdout, played.stdout
    assert "episode " in played.stdout
    site = venv / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    assert f"page {site / 'sharedspace' / 'viewer_page'} True" in played.stdout, played.stdout
