"""The Rust simulator on this machine: find ``sim-server``, run one on a free loopback port, or
roll out one scenario with it.

The Python package carries no simulator of its own: everything that steps a world (the envs,
the trainer, the figures) goes through ``sim-server``. **Finding a server** is one rule
(:func:`find_server`), for every env given no endpoint (Gymnasium, PettingZoo, TorchRL: they
all open their connection through ``Connection.open``): the server named by
``$SHAREDSPACE_ENDPOINT`` (with ``$SHAREDSPACE_PREFIX``) if set, else a ``sim-server`` this
process starts on a free loopback port, or the one it already started. An env's lease on that
server ends when the env closes; the server stops when its last lease ends, or at exit. The
trainer and the bench, given no endpoint, start a server of their own instead
(:func:`shared_server`): they need their task's pools and world parameters, which a named
server cannot be checked to serve.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .closing import Closing

__all__ = [
    "ENDPOINT_VAR",
    "PREFIX_VAR",
    "FoundServer",
    "LocalServer",
    "find_server",
    "free_port",
    "rollout",
    "shared_server",
    "sim_server_binary",
    "stop_process",
    "wait_port",
]

REPO_ROOT = Path(__file__).resolve().parents[3]
#: The environment variable naming the server(s) of every env and trainer given no endpoint:
#: zenoh endpoints, comma-separated (``tcp/10.0.0.5:7447``).
ENDPOINT_VAR = "SHAREDSPACE_ENDPOINT"
#: The key prefix of that server (default ``sharedspace``).
PREFIX_VAR = "SHAREDSPACE_PREFIX"


def sim_server_binary() -> Path:
    """``$SHAREDSPACE_SIM_SERVER``, else this checkout's release or debug build, else the
    binary of the ``sharedspace-server`` wheel in this Python environment's scripts folder
    (found whether or not the environment is activated), else ``sim-server`` on ``PATH``."""
    env = os.environ.get("SHAREDSPACE_SIM_SERVER")
    candidates = [Path(env)] if env else []
    candidates += [REPO_ROOT / "target" / b / "sim-server" for b in ("release", "debug")]
    candidates += [Path(sysconfig.get_path("scripts")) / "sim-server"]
    on_path = shutil.which("sim-server")
    candidates += [Path(on_path)] if on_path else []
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    raise FileNotFoundError(
        "sim-server not found: `pip install sharedspace[server]` (or a wheel of `make wheel`), "
        "install it on PATH from a checkout of the repository (`cargo install --path "
        "sim-server`), or set SHAREDSPACE_SIM_SERVER to a built binary (`make build` builds "
        "target/release/sim-server)"
    )


def free_port() -> int:
    """A free TCP port on the loopback interface."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port: int, proc: subprocess.Popen, timeout: float, what: str = "sim-server") -> None:
    """Returns once ``port`` accepts connections; raises if ``proc`` exits or ``timeout`` s pass."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited with {proc.returncode} at start-up")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"{what} did not listen on 127.0.0.1:{port} within {timeout} s")


def die_with_parent() -> None:  # pragma: no cover - runs in the child
    """Linux: the server gets SIGTERM when the process that started it dies, even by SIGKILL."""
    if sys.platform.startswith("linux"):
        import ctypes

        pr_set_pdeathsig = 1
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)


def stop_process(proc: subprocess.Popen, sig: int = signal.SIGTERM, grace_s: float = 10.0) -> None:
    """Sends ``sig`` to ``proc`` if it still runs and waits for it to exit; SIGKILL after
    ``grace_s`` seconds."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=grace_s)


class LocalServer(Closing):
    """``sim-server serve`` on a free loopback port (multicast scouting off): ``endpoint`` and
    ``prefix`` are what a client connects with. ``cfg`` adds ``--cfg KEY:VALUE`` settings."""

    def __init__(
        self,
        prefix: str = "sharedspace",
        cfg: Sequence[str] = (),
        binary: str | Path | None = None,
        log: str | Path | None = None,
        timeout: float = 30.0,
    ):
        self.binary = Path(binary) if binary else sim_server_binary()
        self.prefix = prefix
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        cmd = [
            str(self.binary),
            "serve",
            "--cfg",
            f'zenoh/listen/endpoints:["{self.endpoint}"]',
            "--cfg",
            "zenoh/scouting/multicast/enabled:false",
            "--cfg",
            f"prefix:{prefix}",
        ]
        for c in cfg:
            cmd += ["--cfg", c]
        self._log = open(log or os.devnull, "ab")  # noqa: SIM115 - closed in close()
        self.proc = subprocess.Popen(
            cmd,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env={**os.environ, "RUST_LOG": os.environ.get("RUST_LOG", "warn")},
            preexec_fn=die_with_parent,
        )
        try:
            wait_port(self.port, self.proc, timeout)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Stops the server (SIGTERM, then SIGKILL after 10 s)."""
        stop_process(self.proc)
        self._log.close()


_shared: dict[tuple[str, ...], LocalServer] = {}
#: Leases held on each shared server; a server whose count falls to 0 stops.
_leases: dict[tuple[str, ...], int] = {}
_shared_lock = threading.Lock()


def _lease_server(pools: Sequence[str | Path], params: str | Path | None) -> tuple:
    """Starts (or reuses) the shared server of ``pools`` and ``params``, counts one more lease
    on it, and returns its key."""
    key = (*(str(p) for p in pools), f"params={params or ''}")
    with _shared_lock:
        server = _shared.get(key)
        if server is None or server.proc.poll() is not None:
            cfg = [f"pools:{json.dumps([str(p) for p in pools])}"] if pools else []
            if params:
                cfg.append(f"params:{json.dumps(str(params))}")
            server = LocalServer(cfg=cfg)
            atexit.register(server.close)
            _shared[key] = server
            _leases[key] = 0
        _leases[key] += 1
        return key


def _release_server(key: tuple) -> None:
    """Ends one lease on the shared server of ``key``; the last one stops it."""
    with _shared_lock:
        _leases[key] -= 1
        if _leases[key] > 0:
            return
        server = _shared.pop(key)
        del _leases[key]
    server.close()


def shared_server(
    pools: Sequence[str | Path] = (), params: str | Path | None = None
) -> LocalServer:
    """This process's local server for ``pools`` (scenario files or ``embedded:NAME``; the
    server's defaults, both embedded pools, when empty) and world ``params`` (a JSON5 parameter
    file, docs/PARAMETERS.md; the server's defaults when None), started on first use and
    stopped at exit (a lease that never ends)."""
    return _shared[_lease_server(pools, params)]


class FoundServer(Closing):
    """Where :func:`find_server` found a server: ``endpoints`` and ``prefix`` to connect with.
    ``close()`` ends this process's lease on a server it started (nothing for a named one)."""

    def __init__(self, endpoints: list[str], prefix: str, lease: tuple | None = None):
        self.endpoints, self.prefix, self._lease = endpoints, prefix, lease

    @property
    def started_here(self) -> bool:
        """Whether this process runs the server."""
        return self._lease is not None

    def close(self) -> None:
        lease, self._lease = self._lease, None
        if lease is not None:
            _release_server(lease)


def find_server(prefix: str = "sharedspace") -> FoundServer:
    """The one rule of every env given no endpoint: the server(s) that ``$SHAREDSPACE_ENDPOINT``
    names (comma-separated endpoints) under the key prefix ``$SHAREDSPACE_PREFIX`` (``prefix``
    when unset); with the variable unset, a lease on this process's own ``sim-server`` (the
    server's default world and both embedded pools: :func:`shared_server`'s), started now if it
    runs not yet. Close the result when done with the server."""
    named = os.environ.get(ENDPOINT_VAR, "").strip()
    if named:
        endpoints = [e.strip() for e in named.split(",") if e.strip()]
        if not endpoints:
            raise ValueError(f"${ENDPOINT_VAR}={named!r} names no endpoint (tcp/HOST:PORT, ...)")
        return FoundServer(endpoints, os.environ.get(PREFIX_VAR, "").strip() or prefix)
    key = _lease_server((), None)
    return FoundServer([_shared[key].endpoint], _shared[key].prefix, key)


def rollout(
    scenario: Mapping[str, Any],
    pedestrian_model: str,
    steps: int | None = None,
    binary: str | Path | None = None,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``sim-server rollout`` of one scenario (every vehicle replaying its record, the
    pedestrians simulated by ``pedestrian_model``, the shipped parameters): the header and the
    first ``steps + 1`` step lines (all when ``None``; docs/ROLLOUT.md)."""
    exe = Path(binary) if binary else sim_server_binary()
    with tempfile.TemporaryDirectory() as tmp:
        pool = Path(tmp) / "pool.json"
        doc = {"version": 1, "name": "rollout", "provenance": "one scenario"}
        doc["scenarios"] = [scenario]
        pool.write_text(json.dumps(doc))
        out = subprocess.run(
            [str(exe), "rollout", "--pool", str(pool), "--model", pedestrian_model],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
    lines = [json.loads(line) for line in out.splitlines() if line.strip()]
    header = lines[0]
    step_lines = [x for x in lines if x.get("type") == "step"]
    return header, step_lines if steps is None else step_lines[: steps + 1]
