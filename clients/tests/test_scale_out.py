"""Scale-out contract: behind one `sim-server router`, two `sim-server serve` processes and two
trainer processes (tests/scale_out_trainer.py, `VectorClient(failover=True)` in zenoh client
mode), all on loopback; the trainers' envs spread over both servers; the server of trainer A is
SIGKILLed mid-run; both trainers finish: A fails over once to the surviving server and its
trajectory there restarts from the seed (equal to its start), B sees no failover and its
trajectory equals an undisturbed run of the same trainer.

No authentication or access control here (the router runs zenoh's defaults plus a loopback
listener, multicast scouting off); the shipped deploy/router.json5 with auth is tested by
sim-server/tests/scale_out.rs.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import free_port, sim_server_binary, unique_prefix, wait_until

from sharedspace.client import SimClient

TRAINER = Path(__file__).with_name("scale_out_trainer.py")
STEPS = 40
PAUSE_AT = 15
WAIT = 30.0  # upper bound of any single wait


class Procs:
    """Child processes, each logging to a file; all killed (SIGKILL) and reaped on teardown."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, cmd: list[str], **env: str) -> subprocess.Popen:
        log = open(self.tmp / f"{name}.log", "wb")  # noqa: SIM115 - the child holds it
        try:
            p = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                env={**os.environ, **env},
            )
        finally:
            log.close()
        self.procs[name] = p
        return p

    def log(self, name: str) -> str:
        return (self.tmp / f"{name}.log").read_text(errors="replace")[-4000:]

    def kill(self, name: str) -> None:
        p = self.procs[name]
        if p.poll() is None:
            p.send_signal(signal.SIGKILL)
        p.wait(timeout=WAIT)

    def kill_all(self) -> None:
        for name in list(self.procs):
            try:
                self.kill(name)
            except Exception:  # noqa: BLE001 - best effort at teardown
                pass


@pytest.fixture
def procs(tmp_path):
    ps = Procs(tmp_path)
    try:
        yield ps
    finally:
        ps.kill_all()


def _wait_listening(ps: Procs, name: str, port: int) -> None:
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        assert ps.procs[name].poll() is None, f"{name} exited:\n{ps.log(name)}"
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    pytest.fail(f"{name} did not listen on 127.0.0.1:{port} within {WAIT} s")


def _wait_file(ps: Procs, path: Path, name: str) -> dict:
    deadline = time.monotonic() + WAIT
    while not path.exists():
        p = ps.procs[name]
        assert p.poll() is None, f"{name} exited ({p.returncode}):\n{ps.log(name)}"
        assert time.monotonic() < deadline, f"no {path.name} from {name} within {WAIT} s"
        time.sleep(0.02)
    return json.loads(path.read_text())


def _trainer(ps: Procs, name: str, endpoint: str, prefix: str, seed: int, pause: bool):
    tmp = ps.tmp
    cmd = [sys.executable, str(TRAINER), "--endpoint", endpoint, "--prefix", prefix]
    cmd += ["--out", str(tmp / f"{name}.json"), "--seed", str(seed), "--steps", str(STEPS)]
    cmd += ["--envs", "2", "--wait", str(WAIT)]
    if pause:
        cmd += ["--pause-at", str(PAUSE_AT), "--paused-file", str(tmp / f"{name}.paused")]
        cmd += ["--go-file", str(tmp / "go")]
    src = str(Path(__file__).resolve().parents[1] / "src")
    pythonpath = os.pathsep.join(filter(None, [src, os.environ.get("PYTHONPATH")]))
    return ps.start(name, cmd, PYTHONPATH=pythonpath)


def _finish(ps: Procs, name: str) -> dict:
    p = ps.procs[name]
    try:
        rc = p.wait(timeout=WAIT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{name} did not finish within {WAIT} s:\n{ps.log(name)}")
    out = ps.tmp / f"{name}.json"
    assert out.exists(), f"{name} exited {rc} without a result:\n{ps.log(name)}"
    result = json.loads(out.read_text())
    assert rc == 0 and result["error"] is None, (
        f"{name} exited {rc}: {result['error']}\n{ps.log(name)}"
    )
    return result


def _trajectory(steps: list[dict]) -> list[tuple]:
    keys = ("reward", "terminated", "truncated", "envs", "obs", "resets")
    return [tuple(json.dumps(s[k]) for k in keys) for s in steps]


def test_two_servers_two_trainers_one_server_killed(procs):
    binary = sim_server_binary()
    if binary is None:
        pytest.skip(
            "sim-server binary not found: build it with `cargo build --release -p sim-server` "
            "or set SHAREDSPACE_SIM_SERVER"
        )
    rust_log = {"RUST_LOG": "warn"}
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    procs.start(
        "router",
        [
            str(binary),
            "router",
            "--cfg",
            f'listen/endpoints:["{endpoint}"]',
            "--cfg",
            "scouting/multicast/enabled:false",
        ],
        **rust_log,
    )
    _wait_listening(procs, "router", port)

    prefix = unique_prefix()
    for sid in ("s1", "s2"):
        procs.start(
            sid,
            [
                str(binary),
                "serve",
                "--cfg",
                'zenoh/mode:"client"',
                "--cfg",
                f'zenoh/connect/endpoints:["{endpoint}"]',
                "--cfg",
                "zenoh/scouting/multicast/enabled:false",
                "--cfg",
                f"prefix:{prefix}",
                "--cfg",
                f"server_id:{sid}",
            ],
            **rust_log,
        )
    with SimClient(endpoint, prefix, mode="client", timeout=3.0) as watcher:
        both = wait_until(lambda: len(watcher.servers(timeout=1.0)) == 2, WAIT)
        assert both, f"servers not both up via the router:\n{procs.log('s1')}\n{procs.log('s2')}"

        # A first: it takes the least-loaded server; B, started once A's envs exist, the other.
        _trainer(procs, "A", endpoint, prefix, seed=11, pause=True)
        host_a = _wait_file(procs, procs.tmp / "A.paused", "A")["server_id"]
        _trainer(procs, "B", endpoint, prefix, seed=22, pause=True)
        host_b = _wait_file(procs, procs.tmp / "B.paused", "B")["server_id"]
        assert {host_a, host_b} == {"s1", "s2"}, "the envs did not spread over both servers"

        # Both trainers are mid-run (PAUSE_AT of STEPS steps done): kill A's server, go on.
        procs.kill(host_a)
        assert wait_until(lambda: host_a not in watcher.transport.alive_servers(), WAIT)
        (procs.tmp / "go").write_text("go")
        a = _finish(procs, "A")
        b = _finish(procs, "B")
        assert procs.procs[host_b].poll() is None, f"{host_b} died:\n{procs.log(host_b)}"

        # A: one failover, at the first step after the kill, then every step on the survivor.
        assert a["server_before"] == host_a and a["server_after"] == host_b
        assert a["failovers"] == 1
        assert len(a["steps"]) == STEPS
        flags = [s["failover"] for s in a["steps"]]
        assert flags == [n == PAUSE_AT for n in range(STEPS)]
        assert all(s["server"] == host_a for s in a["steps"][:PAUSE_AT])
        assert all(s["server"] == host_b for s in a["steps"][PAUSE_AT:])
        lost = a["steps"][PAUSE_AT]
        assert lost["truncated"] == [[1], [1]] and lost["reward"] == [[0.0], [0.0]]
        # the re-created envs restart from the seed: same resets, same trajectory as at the start
        assert lost["resets"] == a["reset"]
        after = a["steps"][PAUSE_AT + 1 :][:PAUSE_AT]  # STEPS > 2 * PAUSE_AT: PAUSE_AT steps
        assert len(after) == PAUSE_AT
        assert _trajectory(after) == _trajectory(a["steps"][:PAUSE_AT])

        # B: no failover, all on its server, and no other disturbance: its trajectory equals an
        # undisturbed run of the same trainer (same seed and actions, no kill, no pause).
        assert b["failovers"] == 0 and b["server_before"] == b["server_after"] == host_b
        assert all(not s["failover"] and s["server"] == host_b for s in b["steps"])
        _trainer(procs, "ref", endpoint, prefix, seed=22, pause=False)
        ref = _finish(procs, "ref")
        assert ref["failovers"] == 0 and ref["server_after"] == host_b
        assert b["reset"] == ref["reset"]
        assert _trajectory(b["steps"]) == _trajectory(ref["steps"])
        # and the surviving server still answers
        assert [i["server_id"] for i in watcher.servers(timeout=2.0)] == [host_b]
