"""A new user's first hour, against a real server: an env given no endpoint finds one by one
rule (sharedspace.local_server.find_server: ``$SHAREDSPACE_ENDPOINT`` if set, else a sim-server
of its own process, shared by its envs and stopped with the last of them); Gymnasium's checker
passes with no warning; the trainer's ``--help`` lists every key without importing torch and
docs/USAGE.md holds the same list; result files are named safely."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
from conftest import REPO_ROOT, wait_until

gymnasium = pytest.importorskip("gymnasium")

import sharedspace  # noqa: E402
from sharedspace import local_server  # noqa: E402
from sharedspace.client import SimClient  # noqa: E402
from sharedspace.gym_env import ENV_ID  # noqa: E402


@pytest.fixture(autouse=True)
def own_servers_of_this_test(monkeypatch):
    """The process's table of own servers, empty for this test: the servers that earlier tests'
    trainers and benches started (held to the process's exit) are set aside, and come back."""
    monkeypatch.setattr(local_server, "_shared", {})
    monkeypatch.setattr(local_server, "_leases", {})


@pytest.fixture
def no_named_server(monkeypatch):
    monkeypatch.delenv(local_server.ENDPOINT_VAR, raising=False)
    monkeypatch.delenv(local_server.PREFIX_VAR, raising=False)
    yield
    assert not local_server._leases


def _own_servers() -> list[local_server.LocalServer]:
    return list(local_server._shared.values())


def test_envs_with_no_endpoint_share_one_server_of_their_own_and_stop_it_with_the_last(
    no_named_server,
):
    first = gymnasium.make(ENV_ID)
    second = sharedspace.parallel_env(split="test")
    assert not _own_servers(), "a server started before any env was reset"
    first.reset(seed=0)
    obs, *_ = first.step(first.action_space.sample())
    assert first.observation_space.contains(obs)
    (server,) = _own_servers()
    second.reset(seed=1)
    assert _own_servers() == [server] and local_server._leases
    first.close()
    assert server.proc.poll() is None, "the server stopped while an env still used it"
    second.close()
    assert wait_until(lambda: server.proc.poll() is not None, 15.0)
    assert not _own_servers()


def test_the_prefixed_id_needs_no_import_in_a_fresh_process(tmp_path):
    script = (
        "import gymnasium, sys\n"
        "env = gymnasium.make('sharedspace:sharedspace/SharedSpace-v0')\n"
        "obs, info = env.reset(seed=0)\n"
        "obs, r, term, trunc, info = env.step(env.action_space.sample())\n"
        "env.close()\n"
        "print('stepped', float(r))\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith("SHAREDSPACE_")}
    env["SHAREDSPACE_SIM_SERVER"] = str(local_server.sim_server_binary())
    done = subprocess.run(
        [sys.executable, "-c", script],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.startswith("stepped "), done.stdout


def test_the_named_server_is_used_and_none_is_started(sim_server, monkeypatch):
    monkeypatch.setenv(local_server.ENDPOINT_VAR, sim_server.endpoint)
    monkeypatch.setenv(local_server.PREFIX_VAR, sim_server.prefix)
    with SimClient(sim_server.endpoint, sim_server.prefix, timeout=5.0) as watcher:

        def open_envs() -> int:
            info = watcher.info(watcher.pick_server()["server_id"])
            return len(info.get("envs", []))

        before = open_envs()
        envs = [gymnasium.make(ENV_ID) for _ in range(2)]
        try:
            for env in envs:
                env.reset(seed=0)
                env.step(np.zeros(2, np.float32))
            assert open_envs() == before + 2
            assert not _own_servers()
        finally:
            for env in envs:
                env.close()
        assert wait_until(lambda: open_envs() == before, 10.0)


def test_check_env_passes_with_no_warning(sim_server):
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(ENV_ID, endpoint=sim_server.endpoint, prefix=sim_server.prefix)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()
    ours = [w for w in caught if "gymnasium" in w.filename or "sharedspace" in w.filename]
    assert not ours, [str(w.message) for w in ours]
    space = env.observation_space["features"]
    assert np.isfinite(space.low).all() and np.isfinite(space.high).all()


def test_help_answers_without_importing_torch():
    probe = (
        "import runpy, sys\n"
        "sys.argv = ['sharedspace.train', '--help']\n"
        "try:\n"
        "    runpy.run_module('sharedspace.train', run_name='__main__')\n"
        "except SystemExit:\n"
        "    pass\n"
        "print('TORCH' if 'torch' in sys.modules else 'NO TORCH')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, cwd=REPO_ROOT
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "task=" not in done.stderr and "every --set key" in done.stdout
    assert "bc_steps = 0:" in done.stdout  # every key of the default algorithm (sac), its doc
    assert "anneal_start" not in done.stdout  # ppo's: `--set algorithm=ppo --help` lists it
    assert done.stdout.rstrip().endswith("NO TORCH"), done.stdout[-500:]


def test_docs_usage_holds_the_reference_as_generated_now():
    from sharedspace.train.reference import BEGIN, END, markdown

    text = (REPO_ROOT / "docs" / "USAGE.md").read_text()
    generated = text.split(BEGIN, 1)[1].split(END, 1)[0]
    assert generated.strip() == markdown().strip(), (
        "docs/USAGE.md is out of date: python -m sharedspace.train.reference --write docs/USAGE.md"
    )


@pytest.mark.parametrize(
    ("name", "safe"),
    [
        ("mypkg.mymodule:act", "mypkg.mymodule_act"),
        ("sharedspace:sharedspace/SharedSpace-v0", "sharedspace_sharedspace_SharedSpace-v0"),
        ("residual-g_sac_cog", "residual-g_sac_cog"),
        ("..\\x y", "_x_y"),
        ("", "_"),
    ],
)
def test_a_result_file_is_named_safely_on_every_file_system(name, safe):
    from sharedspace.bench.scoring import file_name

    assert file_name(name) == safe


def test_an_endpoint_variable_that_names_no_endpoint_is_refused_by_name(monkeypatch):
    monkeypatch.setenv(local_server.ENDPOINT_VAR, " , ")
    with pytest.raises(ValueError, match="SHAREDSPACE_ENDPOINT"):
        local_server.find_server()


def test_anneal_start_outside_0_1_is_refused_by_name():
    from sharedspace.train.config import ConfigError, TrainConfig

    for bad in (-0.1, 1.0):
        with pytest.raises(ConfigError, match="anneal_start"):
            TrainConfig(algorithm="ppo", anneal_lr=True, anneal_start=bad, device="cpu")
