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


sys.path.insert(0, str(REPO_ROOT / "scripts"))

import wheel_check  # noqa: E402 - scripts/, the check of `make wheel-check`

# The criterion benchmarks are behind sim-server's `bench` feature (sim-server/Cargo.toml).
BENCH = ["--features", "sim-server/bench"]


@pytest.fixture(scope="module")
def wheels(tmp_path_factory) -> dict[str, Path]:
    """What ``make wheel`` builds: ``sharedspace-server``'s wheel (sim-server/pyproject.toml,
    maturin) and sdist, and ``sharedspace``'s wheel with the viewer's page. Built by that target
    in the dev profile and linked against this machine's glibc: it reuses the debug build of
    ``make test`` (the release build's link through zig, to glibc 2.17, compiles every crate
    again: minutes; ``make wheel-check`` checks that wheel). The packaging is the same.
    ``SHAREDSPACE_TEST_WHEELS=DIR`` takes the files of a ``make wheel DIST=DIR`` already run
    instead, to run these tests on the release wheels."""
    given = os.environ.get("SHAREDSPACE_TEST_WHEELS")
    out = Path(given).resolve() if given else tmp_path_factory.mktemp("dist")
    if not given:
        built = subprocess.run(
            [
                "make",
                "--no-print-directory",
                "wheel",
                "WHEEL_PROFILE=",
                "WHEEL_LINK=",
                f"DIST={out}",
            ],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            timeout=1500,
        )
        assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-3000:]
    (server,) = out.glob("sharedspace_server-*.whl")
    (sdist,) = out.glob("sharedspace_server-*.tar.gz")
    (package,) = out.glob("sharedspace-*.whl")
    return {"server": server, "sdist": sdist, "package": package}


def test_the_server_wheel_is_tagged_for_the_glibc_its_binary_needs(wheels):
    """The wheel's platform tag is what pip trusts: it must name a glibc no older than the one
    its binary requires (maturin derives it from the link; `make wheel-check` holds the release
    wheel to manylinux2014, glibc 2.17)."""
    report = wheel_check.inspect(wheels["server"])
    ((name, need),) = report.binaries.items()
    assert name.endswith("/scripts/sim-server") and need is not None
    promised = [v for v in report.tag_glibc.values() if v is not None]
    assert promised and min(promised) >= need[0], (report.tags, need)
    assert not report.problems(max(promised))


def test_the_server_sdist_carries_every_file_its_build_needs(wheels, tmp_path):
    """The sdist is what pip builds where no wheel fits (macOS, aarch64): unpacked outside the
    checkout, its workspace resolves from its own Cargo.lock and every crate, test and bench
    compiles (`cargo check`, offline: the registry crates of make test's build, whose checked
    artefacts in target/ it reuses; what is not in the sdist, like params/, is not there)."""
    import tarfile

    with tarfile.open(wheels["sdist"]) as archive:
        archive.extractall(tmp_path, filter="data")
    (root,) = tmp_path.iterdir()
    assert (root / "pyproject.toml").is_file() and (root / "Cargo.lock").is_file()
    assert not (root / "params").exists()
    # the feature set of make test's clippy, whose checked dependencies this reuses
    checked = subprocess.run(
        [
            "cargo",
            "check",
            "--offline",
            "--locked",
            "--workspace",
            "--all-targets",
            "--quiet",
            *BENCH,
        ],
        cwd=root,
        env={**os.environ, "CARGO_TARGET_DIR": str(REPO_ROOT / "target")},
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert checked.returncode == 0, checked.stderr[-3000:]


def test_the_wheels_install_into_a_fresh_venv_and_train_with_the_bundled_server(wheels, tmp_path):
    """The wheels of `make wheel` into a fresh venv outside the checkout, offline from uv's cache
    (the one `make venv` filled: torch is not downloaded a second time). With only
    `sharedspace[train]`, ``python -m sharedspace.train`` says where to get a server; with the
    `sharedspace-server` wheel too (and a PATH holding no cargo, no target/ and not even the
    venv), the trainer and ``sharedspace.LocalServer`` start the bundled ``sim-server``: 256
    frames of training, a PettingZoo episode, and the viewer serving its page from the wheel."""
    from conftest import TINY_TRAIN

    uv = Path(sys.executable).parent / "uv"
    assert uv.is_file(), f"{uv} missing: `make venv` installs uv"
    server_wheel, package_wheel = wheels["server"], wheels["package"]
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
