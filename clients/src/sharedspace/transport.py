"""Zenoh transport of the sharedspace clients (protocol/SPEC.md sections 1, 3, 9).

:class:`Transport` wraps one zenoh session:

- configuration: ``endpoint`` (one or several ``connect`` endpoints, e.g.
  ``"tcp/127.0.0.1:7447"``), ``listen`` endpoints, ``mode`` (``"peer"`` default, or
  ``"client"``); multicast scouting is **off** unless ``multicast=True``;
- every query is a ``get`` under a timeout (:meth:`Transport.query`); a query that gets no
  reply raises :class:`QueryFailed` (no queryable matched: the server is gone, or it timed out);
- the trainer liveliness token ``{p}/trainer/{client_id}`` is declared when the session opens
  (SPEC section 9), so that the server reaps this trainer's envs when the process dies;
- server discovery: liveliness ``{p}/server/*/alive`` plus ``{p}/server/*/info`` queries
  (:meth:`Transport.servers`), the least-loaded choice (:meth:`Transport.pick_server`), and a
  liveliness watch of the servers (:meth:`Transport.is_alive`) used to detect a lost server.

Errors: :class:`~sharedspace.wire.errors.NoServer` (no server answered at the endpoint within the
timeout; the message names both), :class:`~sharedspace.wire.errors.VersionMismatch` (servers found,
none speaking this client's protocol version), :class:`ServerLost` (the server hosting envs
went away).
"""

from __future__ import annotations

import atexit
import json
import logging
import os
import random
import re
import socket
import threading
import time
import weakref
from collections.abc import Iterable, Sequence
from typing import Any

import zenoh

from .closing import Closing
from .wire import requests
from .wire.envelope import PROTOCOL_VERSION
from .wire.errors import NoServer, SharedspaceError, VersionMismatch
from .wire.replies import decode_result

__all__ = [
    "DEFAULT_ENDPOINT",
    "DEFAULT_PREFIX",
    "DEFAULT_TIMEOUT",
    "CREATE_TIMEOUT",
    "QueryFailed",
    "ServerLost",
    "Transport",
    "make_client_id",
    "server_load",
    "undeclare_all",
    "zenoh_file_settings",
]

log = logging.getLogger("sharedspace")

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PREFIX = "sharedspace"
#: Seconds without any zenoh connection to the configured endpoints after which looking for a
#: server gives up with a connection error instead of waiting out the whole timeout.
_CONNECT_GRACE = 1.0
#: Query timeout of every request but ``env/create`` (SPEC section 1 suggests 5 s).
DEFAULT_TIMEOUT = 5.0
#: Timeout of ``env/create`` (SPEC section 1 suggests 10 s).
CREATE_TIMEOUT = 10.0

_SEGMENT_BAD = re.compile(r"[^A-Za-z0-9_.\-]")

#: Open transports, closed when the interpreter shuts down. zenoh-python runs every Python
#: callback (a subscriber's, an observer's) on a non-daemon thread that lives until its session
#: closes, and ``threading._shutdown`` joins those threads *before* ``atexit`` handlers run: a
#: session left open would keep the process alive forever after ``main`` returns.
_OPEN: weakref.WeakSet[Transport] = weakref.WeakSet()

#: Liveliness events buffered between two reads of the server watch (servers come and go
#: rarely; the oldest are dropped only after this many unread changes).
_WATCH_CAPACITY = 4096


def _close_all() -> None:
    for t in list(_OPEN):
        try:
            t.close()
        except Exception:  # noqa: BLE001 - best effort at exit
            pass


# Runs inside threading._shutdown, before it joins the callback threads (concurrent.futures
# relies on the same hook); plain atexit is the fallback where the hook is missing.
_register_before_thread_join = getattr(threading, "_register_atexit", None)
if _register_before_thread_join is not None:
    _register_before_thread_join(_close_all)
atexit.register(_close_all)


class QueryFailed(SharedspaceError):
    """A query got no reply: no queryable matched its key, or none answered in time."""

    def __init__(self, key: str, timeout: float, elapsed: float):
        self.key = key
        self.timeout = timeout
        self.elapsed = elapsed
        self.timed_out = elapsed >= timeout * 0.95
        why = (
            f"no reply within {timeout:g} s"
            if self.timed_out
            else f"no queryable answered (after {elapsed:.3f} s)"
        )
        super().__init__(f"query on {key!r}: {why}")


class ServerLost(SharedspaceError):
    """The server hosting this client's envs went away (its liveliness token disappeared, or a
    query to it got no reply). The envs, and any episode in flight, are lost with it; see
    :meth:`sharedspace.vector.VectorClient.recreate`."""

    def __init__(self, server_id: str, reason: str, env_ids: Sequence[str] = ()):
        self.server_id = server_id
        self.reason = reason
        self.env_ids = list(env_ids)
        text = f"server {server_id!r} lost: {reason}"
        if self.env_ids:
            text += f" ({len(self.env_ids)} env(s) gone, e.g. {self.env_ids[0]!r})"
        text += "; recreate the envs on another server (VectorClient.recreate / failover=True)"
        super().__init__(text)


def make_client_id() -> str:
    """A trainer id unique to this process: ``{host}-{pid}-{random}`` (one key segment)."""
    host = _SEGMENT_BAD.sub("", socket.gethostname())[:32] or "py"
    return f"{host}-{os.getpid()}-{random.getrandbits(32):08x}"


def server_load(info: dict[str, Any]) -> float:
    """``load / capacity`` of a ``ServerInfo`` (1.0 for a full or capacity-0 server)."""
    cap = int(info.get("capacity") or 0)
    return float(info.get("load") or 0) / cap if cap > 0 else 1.0


def _as_list(x: str | Iterable[str] | None) -> list[str]:
    if x is None:
        return []
    if isinstance(x, str):
        return [x]
    return list(x)


def zenoh_file_settings(path: str | os.PathLike) -> dict[str, Any]:
    """A zenoh JSON5 configuration file (such as deploy/trainer.json5) as the flat
    ``{"path/to/key": value}`` entries :class:`Transport` takes as ``config``."""
    import json5

    flat: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict) and value:
            for key, inner in value.items():
                walk(f"{prefix}/{key}" if prefix else key, inner)
        else:
            flat[prefix] = value

    with open(path) as f:
        walk("", json5.loads(f.read()))
    return flat


def undeclare_all(declarations) -> None:
    """Undeclares zenoh subscribers, tokens and queryables, best effort: one that fails (its
    session already closed) does not keep the others."""
    for d in declarations:
        try:
            d.undeclare()
        except Exception:  # noqa: BLE001 - best effort on shutdown
            pass


class Transport(Closing):
    """One zenoh session talking to sharedspace servers under ``prefix``.

    Args:
        endpoint: zenoh ``connect`` endpoint(s) of the server(s) or a router
            (default ``tcp/127.0.0.1:7447``; ``[]`` connects nowhere, for scouting set-ups).
        prefix: key prefix of the servers (SPEC section 1).
        mode: zenoh mode, ``"peer"`` (default) or ``"client"``.
        listen: zenoh ``listen`` endpoints (default none).
        multicast: enable zenoh multicast scouting (default off).
        timeout: query timeout in s (``env/create`` uses ``max(timeout, CREATE_TIMEOUT)``).
        client_id: trainer id (default :func:`make_client_id`).
        config: extra zenoh config entries ``{"path/to/key": json-able value}``.
        protocol_version: the version this client speaks (tests use a wrong one).
    """

    def __init__(
        self,
        endpoint: str | Sequence[str] | None = DEFAULT_ENDPOINT,
        prefix: str = DEFAULT_PREFIX,
        *,
        mode: str = "peer",
        listen: str | Sequence[str] | None = None,
        multicast: bool = False,
        timeout: float = DEFAULT_TIMEOUT,
        client_id: str | None = None,
        config: dict[str, Any] | None = None,
        protocol_version: int = PROTOCOL_VERSION,
    ):
        if mode not in ("peer", "client", "router"):
            raise ValueError(f"mode must be 'peer', 'client' or 'router', got {mode!r}")
        self.endpoints = _as_list(endpoint)
        self.prefix = prefix.strip("/")
        self.mode = mode
        #: The extra zenoh config entries this session was opened with.
        self.config = dict(config or {})
        self.timeout = float(timeout)
        self.protocol_version = int(protocol_version)
        self.client_id = client_id or make_client_id()
        if not self.client_id or _SEGMENT_BAD.search(self.client_id):
            raise ValueError(f"client_id {self.client_id!r} is not a valid key segment")
        zconf = zenoh.Config()
        zconf.insert_json5("mode", json.dumps(mode))
        zconf.insert_json5("connect/endpoints", json.dumps(self.endpoints))
        if mode != "client":
            zconf.insert_json5("listen/endpoints", json.dumps(_as_list(listen)))
        zconf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast)))
        for key, value in (config or {}).items():
            zconf.insert_json5(key, json.dumps(value))
        try:
            self.session = zenoh.open(zconf)
        except zenoh.ZError as e:
            raise NoServer(
                self.endpoint,
                None,
                f"cannot open a zenoh session to {self.endpoint!r} (mode {mode}): {e}",
            ) from e
        self._lock = threading.Lock()
        self._drained_at = float("-inf")
        self._alive: set[str] = set()
        self._lost: set[str] = set()
        self._closed = False
        # Trainer token first (SPEC 9: before any CreateEnv), then the server watch.
        self._token = self.session.liveliness().declare_token(
            f"{self.prefix}/trainer/{self.client_id}"
        )
        # A channel drained on every read rather than a callback: a callback would cost every
        # transport one more Python thread.
        self._watch = self.session.liveliness().declare_subscriber(
            f"{self.prefix}/server/*/alive",
            zenoh.handlers.RingChannel(_WATCH_CAPACITY),
            history=True,
        )
        _OPEN.add(self)

    # ----------------------------------------------------------------------------------------

    @property
    def endpoint(self) -> str:
        """The connect endpoint(s) as one string (for messages)."""
        return ", ".join(self.endpoints) if self.endpoints else "(scouting, no endpoint)"

    def key(self, *parts: str) -> str:
        return "/".join((self.prefix, *parts))

    def _drain_watch(self) -> None:
        """Applies the liveliness changes received since the last read (caller holds the lock)."""
        if self._closed:
            return
        while (sample := self._watch.try_recv()) is not None:
            parts = str(sample.key_expr).split("/")
            if len(parts) < 2:
                continue
            sid = parts[-2]
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(sid)
                self._lost.discard(sid)
            else:
                self._alive.discard(sid)
                self._lost.add(sid)
                log.info("sharedspace: server %s liveliness token gone", sid)

    def is_alive(self, server_id: str, max_age: float = 0.0) -> bool:
        """False once the server's liveliness token was seen disappearing. With ``max_age`` the
        liveliness changes may have been read up to that many seconds ago (a request's
        pre-check: reading them costs a lock and a call into zenoh, some microseconds)."""
        if max_age > 0.0 and time.perf_counter() - self._drained_at < max_age:
            return server_id not in self._lost
        with self._lock:
            self._drain_watch()
            self._drained_at = time.perf_counter()
            return server_id not in self._lost

    def alive_servers(self) -> set[str]:
        with self._lock:
            self._drain_watch()
            return set(self._alive)

    # ----------------------------------------------------------------------------------------
    # Queries

    def get_async(self, key: str, payload: bytes, timeout: float | None = None):
        """Starts a query; returns ``(handler, key, timeout, t0)`` for :meth:`wait`."""
        if self._closed:
            raise SharedspaceError("transport is closed")
        t = self.timeout if timeout is None else float(timeout)
        handler = self.session.get(
            key,
            payload=payload,
            target=zenoh.QueryTarget.BEST_MATCHING,
            consolidation=zenoh.ConsolidationMode.NONE,
            timeout=t,
        )
        return handler, key, t, time.perf_counter()

    @staticmethod
    def wait(pending) -> bytes:
        """The first reply payload of a query started by :meth:`get_async`."""
        handler, key, t, t0 = pending
        try:
            reply = handler.recv()
        except zenoh.ZError:
            raise QueryFailed(key, t, time.perf_counter() - t0) from None
        sample = reply.ok
        if sample is None:
            err = reply.err
            text = err.payload.to_bytes().decode("utf-8", "replace") if err is not None else "?"
            raise SharedspaceError(f"query on {key!r}: zenoh error reply: {text}")
        return sample.payload.to_bytes()

    def query(self, key: str, payload: bytes, timeout: float | None = None) -> bytes:
        """One ``get`` on ``key``; the first reply's payload (raises :class:`QueryFailed`)."""
        return self.wait(self.get_async(key, payload, timeout))

    def request(self, key: str, payload: bytes, timeout: float | None = None) -> Any:
        """A query whose reply envelope is decoded (``ok`` value, or the typed ServerError)."""
        return decode_result(self.query(key, payload, timeout))

    # ----------------------------------------------------------------------------------------
    # Discovery

    def servers(self, timeout: float | None = None, wait: bool = True) -> list[dict[str, Any]]:
        """``ServerInfo`` of every live server (SPEC 5.1), sorted by load then id.

        With ``wait`` the query is repeated until at least one server answers or ``timeout``
        (default: the transport's) passes: a peer session connects in the background.
        """
        total = self.timeout if timeout is None else float(timeout)
        deadline = time.monotonic() + total
        payload = requests.encode_info_request(self.protocol_version)
        while True:
            remaining = max(deadline - time.monotonic(), 0.05)
            handler = self.session.get(
                self.key("server", "*", "info"),
                payload=payload,
                consolidation=zenoh.ConsolidationMode.NONE,
                target=zenoh.QueryTarget.ALL,
                timeout=min(remaining, 2.0),
            )
            infos: dict[str, dict[str, Any]] = {}
            for reply in handler:
                if reply.ok is None:
                    continue
                try:
                    info = decode_result(reply.ok.payload.to_bytes())
                except SharedspaceError as e:
                    log.warning("sharedspace: bad info reply on %s: %s", reply.ok.key_expr, e)
                    continue
                if isinstance(info, dict) and "server_id" in info:
                    infos[str(info["server_id"])] = info
            if infos or not wait or time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        with self._lock:
            self._drain_watch()
            lost = set(self._lost)
        out = [i for sid, i in infos.items() if sid not in lost]
        out.sort(key=lambda i: (server_load(i), str(i["server_id"])))
        return out

    def pick_server(
        self, exclude: Iterable[str] = (), timeout: float | None = None, need: int = 1
    ) -> dict[str, Any]:
        """The least-loaded live server (``load / capacity``) speaking this protocol version
        with room for ``need`` more envs, not in ``exclude``.

        Raises :class:`~sharedspace.wire.errors.NoServer` when none answers within ``timeout`` and
        :class:`~sharedspace.wire.errors.VersionMismatch` when every server speaks another version.
        """
        excluded = set(exclude)
        total = self.timeout if timeout is None else float(timeout)
        start = time.monotonic()
        deadline = start + total
        while True:
            infos = [
                i
                for i in self.servers(
                    timeout=max(min(deadline, start + 1.0) - time.monotonic(), 0.05)
                )
                if str(i["server_id"]) not in excluded
            ]
            if infos or time.monotonic() >= deadline:
                break
            if (
                self.endpoints
                and time.monotonic() - start >= _CONNECT_GRACE
                and not self.connected()
            ):
                raise NoServer(
                    self.endpoint,
                    _CONNECT_GRACE,
                    f"cannot connect to {self.endpoint!r}: no zenoh peer or router answered "
                    f"there within {_CONNECT_GRACE:g} s (is a server or router listening on it?)",
                )
            time.sleep(0.05)
        if not infos:
            extra = f" (excluding {sorted(excluded)})" if excluded else ""
            raise NoServer(
                self.endpoint,
                total,
                f"no sharedspace server (prefix {self.prefix!r}) answered on "
                f"{self.endpoint!r} within {total:g} s{extra}",
            )
        same = [i for i in infos if int(i.get("protocol_version", -1)) == self.protocol_version]
        if not same:
            found = ", ".join(f"{i['server_id']} (v{i.get('protocol_version')})" for i in infos)
            raise VersionMismatch(
                "version_mismatch",
                f"this client speaks protocol version {self.protocol_version}; "
                f"the servers found speak another: {found}",
            )
        roomy = [i for i in same if int(i.get("capacity", 0)) - int(i.get("load", 0)) >= need]
        return (roomy or same)[0]

    def connected(self) -> bool:
        """Whether this session is connected to at least one zenoh peer or router."""
        info = self.session.info
        return bool(list(info.peers_zid()) or list(info.routers_zid()))

    # ----------------------------------------------------------------------------------------

    def declare_subscriber(self, key: str, callback):
        return self.session.declare_subscriber(key, callback)

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        """Undeclares the trainer token (the server then reaps envs still open) and closes."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        undeclare_all((self._watch, self._token))
        try:
            self.session.close()
        except Exception:  # noqa: BLE001
            pass

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
