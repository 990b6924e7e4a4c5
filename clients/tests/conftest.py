"""Shared fixtures; prints the reference cross-check's error table at the end of a run."""

from __future__ import annotations

import crosscheck


def pytest_terminal_summary(terminalreporter):
    rows = crosscheck.RESULTS
    if not rows:
        return
    tr = terminalreporter
    tr.section("reference vs Rust cross-check: max abs errors")
    tr.write_line(
        f"{'set':<10} {'model':<7} {'runs':>4} {'steps':>6} {'pos m':>9} {'vel':>9} "
        f"{'psi':>9} {'u':>9} {'A':>9} {'reward':>9}"
    )
    groups: dict[tuple[str, str], list] = {}
    for r in rows:
        groups.setdefault((r["set"], r["model"]), []).append(r)
    for (name, model), rs in sorted(groups.items()):

        def mx(k, rs=rs):
            return max(r[k] for r in rs)

        tr.write_line(
            f"{name:<10} {model:<7} {len(rs):>4} {sum(r['steps'] for r in rs):>6} "
            f"{mx('pos'):9.1e} {mx('vel'):9.1e} {mx('psi'):9.1e} {mx('u'):9.1e} "
            f"{mx('a'):9.1e} {mx('reward'):9.1e}"
        )


# --------------------------------------------------------------------------------------------
# Live sim-server fixtures for the remote-client tests (tests/test_remote_*.py).

import os  # noqa: E402
import signal  # noqa: E402
import time  # noqa: E402
import uuid  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from sharedspace import local_server  # noqa: E402

REPO_ROOT = Path(__file__).resolve().parents[2]


def sim_server_binary() -> Path | None:
    """The binary the package would use (``sharedspace.local_server.sim_server_binary``), or
    ``None`` when there is none (the tests that need it then skip)."""
    try:
        return local_server.sim_server_binary()
    except FileNotFoundError:
        return None


free_port = local_server.free_port


class SimServer(local_server.LocalServer):
    """A ``sim-server serve`` subprocess on a loopback port, multicast scouting off (the
    package's :class:`~sharedspace.local_server.LocalServer`, with a server id)."""

    def __init__(self, binary: Path, prefix: str, server_id: str, *extra_cfg: str):
        self.server_id = server_id
        super().__init__(
            prefix, [f"server_id:{server_id}", *extra_cfg], binary=binary, timeout=20.0
        )

    def kill(self, sig: int = signal.SIGKILL) -> None:
        local_server.stop_process(self.proc, sig)

    def stop(self) -> None:
        self.close()


def start_server(prefix: str, server_id: str, *extra_cfg: str) -> SimServer:
    binary = sim_server_binary()
    if binary is None:
        pytest.skip(
            "sim-server binary not found: build it with `cargo build --release -p sim-server` "
            "or set SHAREDSPACE_SIM_SERVER"
        )
    return SimServer(binary, prefix, server_id, *extra_cfg)


def unique_prefix() -> str:
    return f"sstest{os.getpid()}x{uuid.uuid4().hex[:6]}"


@pytest.fixture(scope="session")
def sim_server():
    """One live server for the session (its own random port and key prefix), serving the
    embedded pools (a trainer's validation split is asked of it by name: CreateEnv.exclude)."""
    server = start_server(unique_prefix(), "srv0")
    yield server
    server.stop()


@pytest.fixture(scope="session")
def sim_client(sim_server):
    """A SimClient connected to :func:`sim_server` (shared by the session's tests)."""
    from sharedspace.client import SimClient

    client = SimClient(sim_server.endpoint, sim_server.prefix, timeout=5.0)
    yield client
    client.shutdown()


@pytest.fixture
def server_factory():
    """Starts extra servers (function scope); all are stopped afterwards."""
    started: list[SimServer] = []

    def make(prefix: str, server_id: str, *extra_cfg: str) -> SimServer:
        s = start_server(prefix, server_id, *extra_cfg)
        started.append(s)
        return s

    yield make
    for s in started:
        s.stop()


#: A tiny but real trainer config (a few seconds against a live server), for smoke tests.
TINY_TRAIN = [
    "num_envs=2",
    "max_agents=5",
    "frames_per_batch=16",
    "init_random_frames=32",
    "utd_ratio=0.25",
    "batch_size=16",
    "buffer_size=500",
    "hidden_sizes=16,16",
    "gcn_hidden=8",
    "progress=false",
]


def wait_until(pred, timeout: float, interval: float = 0.02) -> bool:
    """Polls ``pred`` until it is true or ``timeout`` passes."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(interval)
    return bool(pred())
