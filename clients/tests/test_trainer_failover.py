"""A training run outlives its server: behind one `sim-server router`, two servers; the one
holding a PPO run's envs is SIGKILLed mid-run. The trainer (its default config: failover on)
re-creates the envs on the survivor, completes its frames, and counts the episodes the kill cut
short as lost (truncated with no outcome). And a shared deployment serves every trainer: two
default `task=paper` trainers with validation carves of their own, scoring on them, behind a
router and two servers that serve only the task's pool, one server killed mid-run."""

from __future__ import annotations

import json
import sys
import time

import pytest
from conftest import free_port, sim_server_binary, unique_prefix, wait_until
from test_scale_out import (
    WAIT,
    _wait_listening,
    procs,  # noqa: F401 - the child processes, killed at teardown
)

from sharedspace.client import SimClient

NUM_ENVS = 4
ITERATION = NUM_ENVS * 8  # frames per PPO iteration (rollout_steps 8)
TOTAL = ITERATION * 20
KILL_AFTER = ITERATION * 6


#: What the servers of a shared deployment serve: the paper task's pool, nothing carved.
ONLY_THE_TASK_POOL = 'pools:["embedded:hbs-paper"]'


def _frames_logged(path) -> int:
    if not path.exists():
        return 0
    lines = [ln.split(",") for ln in path.read_text().splitlines()[1:]]
    return max((int(ln[0]) for ln in lines if len(ln) == 4 and ln[0].isdigit()), default=0)


@pytest.mark.parametrize("overlap", [False, True])
def test_a_ppo_run_survives_the_sigkill_of_its_server(overlap, procs, tmp_path):  # noqa: F811
    """With collection overlapped too (the collector thread's env fails over)."""
    binary = sim_server_binary()
    if binary is None:
        pytest.skip("sim-server binary not found: set SHAREDSPACE_SIM_SERVER or build it")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router_cfg = ["--cfg", f'listen/endpoints:["{endpoint}"]']
    router_cfg += ["--cfg", "scouting/multicast/enabled:false"]
    procs.start("router", [str(binary), "router", *router_cfg], RUST_LOG="warn")
    _wait_listening(procs, "router", port)
    prefix = unique_prefix()
    for sid in ("s1", "s2"):
        serve = ["--cfg", 'zenoh/mode:"client"', "--cfg", f'zenoh/connect/endpoints:["{endpoint}"]']
        serve += ["--cfg", "zenoh/scouting/multicast/enabled:false", "--cfg", f"prefix:{prefix}"]
        serve += ["--cfg", f"server_id:{sid}", "--cfg", ONLY_THE_TASK_POOL]
        procs.start(sid, [str(binary), "serve", *serve], RUST_LOG="warn")
    session = tmp_path / "trainer.json5"
    session.write_text(
        json.dumps(
            {
                "mode": "client",
                "connect": {"endpoints": [endpoint]},
                "scouting": {"multicast": {"enabled": False}},
            }
        )
    )
    log_dir = tmp_path / "run"
    with SimClient(endpoint, prefix, mode="client", timeout=3.0) as watcher:
        assert wait_until(lambda: len(watcher.servers(timeout=1.0)) == 2, WAIT)
        overrides = [
            "algorithm=ppo",
            f"num_envs={NUM_ENVS}",
            "max_agents=5",
            "rollout_steps=8",
            "minibatch_size=16",
            "ppo_epochs=1",
            "hidden_sizes=16,16",
            "gcn_hidden=8",
            f"total_frames={TOTAL}",
            "eval_interval=0",
            "checkpoint_interval=0",
            "progress=false",
            f"overlap={str(overlap).lower()}",
            f"zenoh_config={session}",
            f"server_prefix={prefix}",
            f"log_dir={log_dir}",
        ]
        trainer = procs.start(
            "trainer", [sys.executable, "-m", "sharedspace.train", "--set", *overrides]
        )
        metrics = log_dir / "metrics.csv"
        deadline = time.monotonic() + 4 * WAIT
        while _frames_logged(metrics) < KILL_AFTER:
            assert trainer.poll() is None, procs.log("trainer")
            assert time.monotonic() < deadline, "the run did not start"
            time.sleep(0.05)
        hosts = [i["server_id"] for i in watcher.servers(timeout=2.0) if i.get("envs")]
        assert len(hosts) == 1, hosts
        procs.kill(hosts[0])
        killed_at = _frames_logged(metrics)
        assert killed_at < TOTAL, "the run ended before the kill"
        rc = trainer.wait(timeout=8 * WAIT)
    assert rc == 0, procs.log("trainer")
    out = json.loads(procs.log("trainer").strip().splitlines()[-1])
    assert out["counters"]["frames"] == TOTAL
    assert out["counters"]["lost_episodes"] == NUM_ENVS  # every sub-env's episode, once
    rows = [ln.split(",") for ln in metrics.read_text().splitlines()[1:]]
    lost = [float(r[3]) for r in rows if r[2] == "train/lost" and float(r[3]) > 0]
    assert len(lost) == 1 and int(rows[-1][0]) == TOTAL


def _deployment(procs, tmp_path):  # noqa: F811
    """A router and two servers of the paper task's pool only; the trainers' session file."""
    binary = sim_server_binary()
    if binary is None:
        pytest.skip("sim-server binary not found: set SHAREDSPACE_SIM_SERVER or build it")
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router_cfg = ["--cfg", f'listen/endpoints:["{endpoint}"]']
    router_cfg += ["--cfg", "scouting/multicast/enabled:false"]
    procs.start("router", [str(binary), "router", *router_cfg], RUST_LOG="warn")
    _wait_listening(procs, "router", port)
    prefix = unique_prefix()
    for sid in ("s1", "s2"):
        serve = ["--cfg", 'zenoh/mode:"client"', "--cfg", f'zenoh/connect/endpoints:["{endpoint}"]']
        serve += ["--cfg", "zenoh/scouting/multicast/enabled:false", "--cfg", f"prefix:{prefix}"]
        serve += ["--cfg", f"server_id:{sid}", "--cfg", ONLY_THE_TASK_POOL]
        procs.start(sid, [str(binary), "serve", *serve], RUST_LOG="warn")
    session = tmp_path / "trainer.json5"
    session.write_text(
        json.dumps(
            {
                "mode": "client",
                "connect": {"endpoints": [endpoint]},
                "scouting": {"multicast": {"enabled": False}},
            }
        )
    )
    return endpoint, prefix, session


def test_two_default_trainers_with_carves_of_their_own_share_a_deployment(procs, tmp_path):  # noqa: F811
    endpoint, prefix, session = _deployment(procs, tmp_path)
    total = ITERATION * 24
    with SimClient(endpoint, prefix, mode="client", timeout=3.0) as watcher:
        assert wait_until(lambda: len(watcher.servers(timeout=1.0)) == 2, WAIT)
        trainers = {}
        for name, carve in (("a", 12), ("b", 6)):
            overrides = [
                "algorithm=ppo",
                "task=paper",
                f"validation_scenes={carve}",
                "validation_variations=1",
                f"num_envs={NUM_ENVS}",
                "rollout_steps=8",
                "minibatch_size=16",
                "ppo_epochs=1",
                "hidden_sizes=16,16",
                "gcn_hidden=8",
                f"total_frames={total}",
                f"eval_interval={ITERATION * 8}",
                "checkpoint_interval=0",
                "progress=false",
                f"zenoh_config={session}",
                f"server_prefix={prefix}",
                f"log_dir={tmp_path / name}",
            ]
            trainers[name] = procs.start(
                f"trainer-{name}", [sys.executable, "-m", "sharedspace.train", "--set", *overrides]
            )
        deadline = time.monotonic() + 6 * WAIT
        while min(_frames_logged(tmp_path / n / "metrics.csv") for n in trainers) < KILL_AFTER:
            for n, t in trainers.items():
                assert t.poll() is None, procs.log(f"trainer-{n}")
            assert time.monotonic() < deadline, "the runs did not start"
            time.sleep(0.05)
        procs.kill("s1")
        codes = {n: t.wait(timeout=10 * WAIT) for n, t in trainers.items()}
    for name, carve in (("a", 12), ("b", 6)):
        assert codes[name] == 0, procs.log(f"trainer-{name}")
        out = json.loads(procs.log(f"trainer-{name}").strip().splitlines()[-1])
        assert out["counters"]["frames"] == total
        assert out["eval_split"] == "validation"
        assert out["eval"]["episodes"] == carve  # its own carve, one variation each
        rows = (tmp_path / name / "metrics.csv").read_text().splitlines()
        assert sum(",eval/success," in r for r in rows) >= 2  # scored during the run and at its end
