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


# ------------------------------------------------------------------------------------------
# The README, as a new user follows it: its blocks marked `<!-- readme-test -->` run in order in
# a fresh venv of the wheels, with nothing listening and no server named.

README = REPO_ROOT / "README.md"
_MARK = "<!-- readme-test"


def readme_blocks(text: str) -> list[tuple[str, str]]:
    """``(language, code)`` of every fenced block whose preceding line is a ``readme-test``
    marker, in order, with the marker's substitutions (``<!-- readme-test: OLD -> NEW, ... -->``,
    small sizes for a test) applied."""
    lines = text.splitlines()
    blocks = []
    for i, line in enumerate(lines):
        if not line.startswith("```") or line == "```" or i == 0:
            continue
        marker = lines[i - 1].strip()
        if not marker.startswith(_MARK):
            continue
        end = lines.index("```", i + 1)
        code = "\n".join(lines[i + 1 : end]) + "\n"
        spec = marker[len(_MARK) :].removesuffix("-->").strip().lstrip(":").strip()
        for pair in filter(None, (p.strip() for p in spec.split(","))):
            old, new = (x.strip() for x in pair.split("->"))
            assert old in code, f"README block {i + 1}: {old!r} is not in it"
            code = code.replace(old, new)
        blocks.append((line[3:].strip(), code))
    return blocks


def test_the_readme_blocks_are_found_with_their_small_sizes():
    blocks = readme_blocks(README.read_text())
    assert [lang for lang, _ in blocks] == ["python", "python", "sh", "sh"]
    assert "total_frames=8192" in blocks[2][1] and "2000000" not in blocks[2][1]
    # what the test below installs is what the README's install line names
    assert 'pip install --find-links dist "sharedspace[train,server]"' in README.read_text()


@pytest.fixture(scope="module")
def user_venv(wheels, tmp_path_factory) -> Path:
    """A fresh venv outside the checkout with ``sharedspace[train,server]`` from the wheels
    (offline, from uv's cache, as the test above installs them)."""
    uv = Path(sys.executable).parent / "uv"
    venv = tmp_path_factory.mktemp("user") / "venv"
    subprocess.run([str(uv), "venv", "-q", "--python", sys.executable, str(venv)], check=True)
    python = venv / "bin" / "python"
    done = subprocess.run(
        [
            str(uv),
            "pip",
            "install",
            "--offline",
            "--python",
            str(python),
            f"sharedspace[train] @ {wheels['package'].as_uri()}",
            str(wheels["server"]),
        ],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return venv


def _user_env(venv: Path, **extra: str) -> dict[str, str]:
    """A user's shell: the venv first on a PATH of no cargo and no checkout, no variable of
    ours (so nothing names a server or a binary)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("SHAREDSPACE_")}
    return {**env, "PATH": f"{venv / 'bin'}:/usr/bin:/bin", "VIRTUAL_ENV": str(venv), **extra}


def test_the_readme_runs_in_a_fresh_venv_of_the_wheels(user_venv, tmp_path):
    work = tmp_path / "user"
    work.mkdir()
    outputs = []
    for n, (lang, code) in enumerate(readme_blocks(README.read_text())):
        if lang == "python":
            script = work / f"block{n}.py"
            script.write_text(code)
            cmd = [str(user_venv / "bin" / "python"), str(script)]
        else:
            cmd = ["bash", "-euo", "pipefail", "-c", code]
        done = subprocess.run(
            cmd, cwd=work, env=_user_env(user_venv), capture_output=True, text=True, timeout=900
        )
        assert done.returncode == 0, f"README block {n} ({lang}):\n{code}\n{done.stderr[-3000:]}"
        assert str(REPO_ROOT) not in done.stdout + done.stderr  # nothing from the checkout
        outputs.append(done.stdout)
    assert outputs[0].startswith("episode over: hbs-car"), outputs[0]
    finished = int(outputs[1].split("episodes finished:")[1])
    assert finished > 4, outputs[1]  # each of the 4 envs ended an episode and went on
    assert (work / "runs" / "ppo-paper" / "checkpoints" / "last.pt").is_file()
    assert (work / "results" / "paper" / "ppo-paper.json").is_file()
    assert "car_aware" in outputs[3] and "paired" in outputs[3].lower(), outputs[3]


def test_an_env_needs_no_server_in_a_fresh_venv(user_venv, tmp_path):
    """With nothing listening: the registered id after `import sharedspace`, and the prefixed id
    with no import, reset and step on a server the process starts (the wheel's binary)."""
    script = textwrap.dedent(
        """
        import gymnasium
        env = gymnasium.make("sharedspace:sharedspace/SharedSpace-v0")
        env.reset(seed=0)
        env.step(env.action_space.sample())
        env.close()
        import sharedspace
        from sharedspace import local_server
        env = gymnasium.make("sharedspace/SharedSpace-v0")
        env.reset(seed=1)
        env.step(env.action_space.sample())
        print("binary", local_server.sim_server_binary())
        env.close()
        print("servers left", len(local_server._shared))
        """
    )
    done = subprocess.run(
        [str(user_venv / "bin" / "python"), "-c", script],
        cwd=tmp_path,
        env=_user_env(user_venv),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"binary {user_venv / 'bin' / 'sim-server'}" in done.stdout, done.stdout
    assert "servers left 0" in done.stdout


def test_envs_use_the_server_the_environment_names_in_a_fresh_venv(user_venv, sim_server, tmp_path):
    """With ``SHAREDSPACE_ENDPOINT`` (and ``SHAREDSPACE_PREFIX``) set, the envs are created on
    that server (its env list shows them) and the process starts no server of its own."""
    script = textwrap.dedent(
        """
        import os, gymnasium, sharedspace
        from sharedspace import local_server
        from sharedspace.client import SimClient
        envs = [gymnasium.make("sharedspace/SharedSpace-v0") for _ in range(3)]
        for env in envs:
            env.reset(seed=0)
        with SimClient(os.environ["SHAREDSPACE_ENDPOINT"], os.environ["SHAREDSPACE_PREFIX"]) as c:
            mine = {env.unwrapped._parallel.client.client_id for env in envs}
            info = c.info(c.pick_server()["server_id"])
            print("ours", sum(e["client_id"] in mine for e in info["envs"]))
        print("own servers", len(local_server._shared))
        for env in envs:
            env.close()
        """
    )
    done = subprocess.run(
        [str(user_venv / "bin" / "python"), "-c", script],
        cwd=tmp_path,
        env=_user_env(
            user_venv,
            SHAREDSPACE_ENDPOINT=sim_server.endpoint,
            SHAREDSPACE_PREFIX=sim_server.prefix,
        ),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "ours 3" in done.stdout and "own servers 0" in done.stdout, done.stdout


def test_the_base_package_scores_a_policy_with_no_torch(wheels, tmp_path):
    """``sharedspace`` without its ``train`` extra (and the server wheel), offline into a fresh
    venv: no torch to import, and ``python -m sharedspace.bench`` still scores the car-aware
    script and a user's NumPy function, its legend printed."""
    uv = Path(sys.executable).parent / "uv"
    venv = tmp_path / "venv"
    subprocess.run([str(uv), "venv", "-q", "--python", sys.executable, str(venv)], check=True)
    python = venv / "bin" / "python"
    done = subprocess.run(
        [str(uv), "pip", "install", "--offline", "--python", str(python)]
        + [wheels["package"].as_uri(), str(wheels["server"])],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    work = tmp_path / "user"
    work.mkdir()
    (work / "mine.py").write_text(
        "import numpy as np\n\n\ndef act(obs):\n    return np.array([0.2, 0.0], dtype=np.float32)\n"
    )
    env = _user_env(venv)

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [str(python), *args], cwd=work, env=env, capture_output=True, text=True, timeout=600
        )

    no_torch = run("-c", "import torch")
    assert no_torch.returncode != 0 and "No module named 'torch'" in no_torch.stderr
    for policy, row in (("car_aware", "| car_aware | 2304 |"), ("mine:act", "| mine:act | 2304 |")):
        scored = run("-m", "sharedspace.bench", "paper", "--policy", policy)
        assert scored.returncode == 0, scored.stderr[-2000:]
        assert row in scored.stdout and "Wilson interval" in scored.stdout, scored.stdout
