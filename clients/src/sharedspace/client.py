"""One trainer's connection to the sharedspace servers (protocol/SPEC.md section 5).

:class:`Connection` says where the servers are (an endpoint, a zenoh configuration file, or a
server this process starts on loopback: :meth:`Connection.resolve`); :meth:`Connection.open`
gives a :class:`SimClient` (a :class:`~sharedspace.transport.Transport` with its liveliness
token), which creates envs (K of one :class:`~sharedspace.wire.EnvSpec` in one ``CreateEnv``) on
the least-loaded server and remembers which server owns each env; ``reset``, ``step``,
``batch_step`` and ``close`` take and return numpy arrays (the decoded messages of the spec,
:mod:`sharedspace.wire.replies`); :meth:`SimClient.request` sends any request.
:class:`~sharedspace.vector.VectorClient` steps K envs together over one of these, with
failover. :func:`env_options` sorts an env adapter's keyword arguments into the two.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np

from .closing import Closing
from .transport import (
    CREATE_TIMEOUT,
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    DEFAULT_TIMEOUT,
    QueryFailed,
    ServerLost,
    Transport,
    zenoh_file_settings,
)
from .wire import requests
from .wire.envelope import encode
from .wire.errors import EnvClosed, NoServer, SharedspaceError, WrongShape
from .wire.replies import F4, decode_result, decode_step_result, step_decoder_for
from .wire.requests import Checked, EnvSpec

__all__ = ["Connection", "SimClient", "env_options"]

log = logging.getLogger("sharedspace")

#: Seconds a request's liveliness pre-check may rely on the last read of the server watch.
_ALIVE_MAX_AGE = 0.05


class SimClient:
    """A trainer's connection to the sharedspace servers under ``prefix``.

    Args:
        endpoint, prefix, **transport_options: the :class:`~sharedspace.transport.Transport`
            to open (``mode``, ``listen``, ``multicast``, ``timeout``, ``client_id``,
            ``config``, ``protocol_version``: see there; ignored when ``transport`` is given).
        transport: an existing transport to share.
        server_id: pin every ``create`` to this server (default: least loaded at each create).
        discover_timeout: how long ``create`` waits for a server to answer (default: timeout).
    """

    def __init__(
        self,
        endpoint: str | Sequence[str] | None = DEFAULT_ENDPOINT,
        prefix: str = DEFAULT_PREFIX,
        *,
        transport: Transport | None = None,
        server_id: str | None = None,
        discover_timeout: float | None = None,
        **transport_options: Any,
    ):
        self._own_transport = transport is None
        self.transport = transport or Transport(endpoint, prefix, **transport_options)
        self.server_id = server_id
        self.discover_timeout = (
            self.transport.timeout if discover_timeout is None else float(discover_timeout)
        )
        #: The server this client was opened on by :meth:`Connection.open` when it found one
        #: (``FoundServer``): its lease ends when the client shuts down.
        self.server_lease: Closing | None = None
        #: env id -> server id of every env created (and not closed) by this client.
        self.env_server: dict[str, str] = {}
        #: env id -> ``n_ext`` (number of external agents).
        self.env_n_ext: dict[str, int] = {}
        self._closed_envs: set[str] = set()
        #: env id -> (server id, step key, request head, action shape, reply decoder) of envs
        #: stepped before.
        self._step_keys: dict[str, tuple[str, str, bytes, tuple[int, int], Any]] = {}
        self._step_heads: dict[int, bytes] = {}

    @property
    def client_id(self) -> str:
        return self.transport.client_id

    @property
    def timeout(self) -> float:
        return self.transport.timeout

    # ----------------------------------------------------------------------------------------

    def servers(self, timeout: float | None = None) -> list[dict[str, Any]]:
        """``ServerInfo`` of every live server, least loaded first."""
        return self.transport.servers(timeout if timeout is not None else self.discover_timeout)

    def info(self, server_id: str) -> dict[str, Any]:
        """``ServerInfo`` of one server."""
        return self.request(
            server_id,
            self.transport.key("server", server_id, "info"),
            requests.encode_info_request(self.transport.protocol_version),
        )

    def pick_server(self, exclude: Sequence[str] = (), need: int = 1) -> dict[str, Any]:
        return self.transport.pick_server(exclude, timeout=self.discover_timeout, need=need)

    def pools(self, server_id: str | None = None) -> list[dict[str, Any]]:
        """The scenario pools a server serves (``ServerInfo.pools``: name, split sizes and every
        scenario's name and split in pool order); the least-loaded server's by default."""
        info = self.info(server_id) if server_id else self.pick_server()
        return list(info.get("pools", []))

    def scenarios(
        self, pool: str | None = None, server_id: str | None = None
    ) -> tuple[str, list[tuple[str, str]]]:
        """``(pool name, [(scenario name, split), ...])`` in pool order, as the server serves
        them (``pool`` None: the server's default pool). A scenario's position in the list is
        its ``scenario_index``; its name is what ``Reset``/``CreateEnv`` take."""
        pools = self.pools(server_id)
        chosen = pools[0] if pool is None and pools else None
        for p in pools:
            if p["name"] == pool:
                chosen = p
        if chosen is None:
            names = [p["name"] for p in pools]
            raise SharedspaceError(f"no scenario pool {pool!r} on the server (pools: {names})")
        return str(chosen["name"]), [
            (str(sc["name"]), str(sc["split"])) for sc in chosen.get("scenarios", [])
        ]

    def _server_of(self, env_id: str) -> str:
        sid = self.env_server.get(env_id)
        if sid is None:
            if env_id in self._closed_envs:
                raise EnvClosed("env_closed", f"env {env_id!r} was closed by this client", env_id)
            raise SharedspaceError(f"env {env_id!r} was not created by this client")
        return sid

    def _lost(self, server_id: str, reason: str) -> ServerLost:
        envs = [e for e, s in self.env_server.items() if s == server_id]
        return ServerLost(server_id, reason, envs)

    def _check_alive(self, server_id: str) -> None:
        # Liveliness read at most _ALIVE_MAX_AGE ago is fresh enough here: a request to a
        # server that is gone fails anyway, and the failure path reads it afresh.
        if not self.transport.is_alive(server_id, max_age=_ALIVE_MAX_AGE):
            raise self._lost(server_id, "its liveliness token disappeared")

    def request(
        self,
        server_id: str,
        key: str,
        payload: bytes,
        timeout: float | None = None,
        decode=decode_result,
    ):
        """Sends ``payload`` to ``key`` of server ``server_id`` and returns the reply decoded by
        ``decode``; raises :class:`~sharedspace.transport.ServerLost` when that server is gone
        (its liveliness token disappeared, or the query got no reply)."""
        transport = self.transport
        if transport.closed:
            raise SharedspaceError("the client is closed")
        try:
            pending = transport.get_async(key, payload, timeout)
            # Checked while the server works on the query rather than before sending it: the
            # check costs some microseconds, and a query to a server that is gone is harmless.
            self._check_alive(server_id)
            return decode(transport.wait(pending))
        except QueryFailed as e:
            if not self.transport.is_alive(server_id):
                raise self._lost(server_id, "its liveliness token disappeared") from e
            raise self._lost(server_id, str(e)) from e

    def request_many(self, server_id: str, calls: Sequence[tuple[str, bytes]]) -> list[Any]:
        """Several queries to one server in flight at once; replies in order."""
        self._check_alive(server_id)
        pending = [self.transport.get_async(k, p) for k, p in calls]
        out = []
        first_err: BaseException | None = None
        for p in pending:
            try:
                out.append(decode_result(self.transport.wait(p)))
            except QueryFailed as e:
                reason = (
                    "its liveliness token disappeared"
                    if not self.transport.is_alive(server_id)
                    else str(e)
                )
                first_err = first_err or self._lost(server_id, reason)
            except SharedspaceError as e:
                first_err = first_err or e
        if first_err is not None:
            raise first_err
        return out

    # ----------------------------------------------------------------------------------------
    # Requests

    def create(
        self,
        count: int = 1,
        spec: EnvSpec | None = None,
        *,
        server_id: str | None = None,
        protocol_version: int | None = None,
        **fields: Any,
    ) -> dict[str, Any]:
        """``CreateEnv`` of ``count`` envs of ``spec`` with ``fields`` over it
        (:class:`~sharedspace.wire.EnvSpec`, SPEC 5.2) on ``server_id`` or the least-loaded
        server. Returns ``EnvCreated`` with ``server_id`` added."""
        spec = EnvSpec.of(spec, **fields)
        version = self.transport.protocol_version if protocol_version is None else protocol_version
        sid = server_id or self.server_id
        if sid is None:
            sid = str(self.pick_server(need=int(count))["server_id"])
        payload = requests.encode_create_env(spec, self.client_id, count, int(version))
        try:
            created = self.request(
                sid,
                self.transport.key("server", sid, "env", "create"),
                payload,
                max(self.timeout, CREATE_TIMEOUT),
            )
        except ServerLost as e:
            if sid in self.transport.alive_servers():
                raise
            raise NoServer(
                self.transport.endpoint,
                max(self.timeout, CREATE_TIMEOUT),
                f"server {sid!r} (prefix {self.transport.prefix!r}) did not answer env/create "
                f"on {self.transport.endpoint!r}: {e.reason}",
            ) from e
        created["server_id"] = sid
        n_ext = len(created.get("external_agents") or spec.external_agents)
        for env_id in created["env_ids"]:
            self.env_server[env_id] = sid
            self.env_n_ext[env_id] = n_ext
        return created

    def reset(
        self,
        env_id: str,
        seed: int | None = None,
        scenario: str | None = None,
        variation: int | None = None,
    ) -> dict[str, Any]:
        """``Reset`` (SPEC 5.3) → ``ResetResult``; ``variation``: play the scene variation of
        this seed (an env with variations)."""
        sid = self._server_of(env_id)
        return self.request(
            sid,
            self.transport.key("server", sid, "env", env_id, "reset"),
            requests.encode_reset(seed, scenario, variation),
        )

    def reset_many(
        self,
        env_ids: Sequence[str],
        seeds: Sequence[int | None] | None = None,
        scenarios: Sequence[str | None] | None = None,
        variations: Sequence[int | None] | None = None,
    ) -> list[dict[str, Any]]:
        """``Reset`` of several envs of one server, all queries in flight at once
        (``variations``: per env, the variation seed to play, or None for the env's draw)."""
        if not env_ids:
            return []
        sid = self._server_of(env_ids[0])
        calls = []
        for i, env_id in enumerate(env_ids):
            if self._server_of(env_id) != sid:
                raise ValueError("reset_many: every env must live on the same server")
            seed = None if seeds is None else seeds[i]
            scen = None if scenarios is None else scenarios[i]
            var = None if variations is None else variations[i]
            calls.append(
                (
                    self.transport.key("server", sid, "env", env_id, "reset"),
                    requests.encode_reset(seed, scen, var),
                )
            )
        return self.request_many(sid, calls)

    def step(self, env_id: str, actions: Any) -> dict[str, Any]:
        """``Step`` (SPEC 5.4): ``actions`` ``[n_ext, 2]`` (float32/64) → ``StepResult``."""
        fast = self._step_keys.get(env_id)
        if (
            fast is not None
            and type(actions) is np.ndarray
            and actions.dtype == F4
            and actions.shape == fast[3]
        ):
            # The common case (a float32 array of the right shape, an env stepped before): one
            # lookup, no conversion; a step's client work is a share of its round trip.
            sid, key, head, _, decode = fast
            return self.request(sid, key, head + actions.tobytes(), decode=decode)
        sid = self._server_of(env_id)
        n_ext = self.env_n_ext.get(env_id)
        arr = np.asarray(actions, dtype="<f4")
        if arr.ndim == 1 and n_ext == 1:
            arr = arr.reshape(1, -1)
        if arr.shape != (n_ext, 2):
            raise WrongShape(
                message=f"step: actions of env {env_id} must have shape [{n_ext}, 2] "
                f"(n_ext, [acc, omega]), got {list(arr.shape)}",
                env_id=env_id,
            )
        head = self._step_heads.get(n_ext)
        if head is None:
            head = self._step_heads[n_ext] = requests.step_head(n_ext)
        key = self.transport.key("server", sid, "env", env_id, "step")
        res = self.request(sid, key, head + arr.tobytes(), decode=decode_step_result)
        # Later steps of this env take the fast path above, with a decoder of this layout.
        self._step_keys[env_id] = (sid, key, head, (n_ext, 2), step_decoder_for(res))
        return res

    def batch_step(
        self, env_ids: Sequence[str], actions: Any, timeout: float | None = None
    ) -> dict[str, Any]:
        """``BatchStep`` (SPEC 5.5): ``actions`` ``[K, n_ext, 2]`` → ``BatchStepResult``."""
        env_ids = list(env_ids)
        if not env_ids:
            raise ValueError("batch_step needs at least one env")
        sid = self._server_of(env_ids[0])
        n_ext = self.env_n_ext.get(env_ids[0])
        arr = np.asarray(actions, dtype=np.float32)
        want = (len(env_ids), n_ext, 2)
        if arr.shape != want:
            raise WrongShape(
                message=f"batch_step: actions must have shape [K={want[0]}, n_ext={n_ext}, 2], "
                f"got {list(arr.shape)}",
            )
        for env_id in env_ids:
            if self._server_of(env_id) != sid:
                raise ValueError("batch_step: every env must live on the same server")
        return self.request(
            sid,
            self.transport.key("server", sid, "batch", "step"),
            encode({"env_ids": env_ids, "actions": arr}),
            timeout,
        )

    def close(self, env_id: str) -> dict[str, Any]:
        """``Close`` (SPEC 5.6)."""
        sid = self._server_of(env_id)
        try:
            return self.request(
                sid,
                self.transport.key("server", sid, "env", env_id, "close"),
                requests.encode_close(),
            )
        finally:
            self.forget(env_id)

    def close_many(self, env_ids: Sequence[str]) -> None:
        """Closes envs, all queries in flight at once; errors (already closed, server gone) are
        ignored."""
        by_server: dict[str, list[str]] = {}
        for e in env_ids:
            sid = self.env_server.get(e)
            if sid is not None:
                by_server.setdefault(sid, []).append(e)
        for sid, ids in by_server.items():
            if self.transport.closed or not self.transport.is_alive(sid):
                pass
            else:
                pending = [
                    self.transport.get_async(
                        self.transport.key("server", sid, "env", e, "close"),
                        requests.encode_close(),
                        min(self.timeout, 2.0),
                    )
                    for e in ids
                ]
                for p in pending:
                    try:
                        Transport.wait(p)
                    except SharedspaceError:
                        pass
            for e in ids:
                self.forget(e)

    def forget(self, env_id: str) -> None:
        """Drops an env from the client's books (it is closed or its server is gone)."""
        self.env_server.pop(env_id, None)
        self.env_n_ext.pop(env_id, None)
        self._step_keys.pop(env_id, None)
        self._closed_envs.add(env_id)

    def shutdown(self) -> None:
        """Closes every env of this client and the transport (if this client opened it)."""
        try:
            if not self.transport.closed:
                self.close_many(list(self.env_server))
            if self._own_transport:
                self.transport.close()
        finally:
            lease, self.server_lease = self.server_lease, None
            if lease is not None:
                lease.close()

    def __enter__(self) -> SimClient:
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()


class Connection(Checked):
    """Where the servers are and how to reach them: what :meth:`open` connects with, and what
    an env keeps to connect again when it is copied or unpickled."""

    #: zenoh ``connect`` endpoint(s) of the servers or of a router (``[]``: none, scouting);
    #: ``""``: find one (``$SHAREDSPACE_ENDPOINT``, else a ``sim-server`` this process starts:
    #: :func:`~sharedspace.local_server.find_server`).
    endpoint: str | list[str] | None = ""
    #: Key prefix of the servers (SPEC section 1); with ``endpoint`` "", ``$SHAREDSPACE_PREFIX``
    #: overrides it, and a server this process starts has its own.
    prefix: str = DEFAULT_PREFIX
    #: Query timeout, s (``env/create`` waits at least ``CREATE_TIMEOUT``).
    timeout: float = DEFAULT_TIMEOUT
    #: zenoh mode of the session: ``peer``, or ``client`` of a router.
    zenoh_mode: Literal["peer", "client"] = "peer"
    #: Extra zenoh configuration entries, ``{"path/to/key": value}``.
    config: dict[str, Any] = {}
    #: Re-create the envs on a surviving server when theirs dies (VectorClient's failover).
    failover: bool = False

    def open(self) -> SimClient:
        """A new :class:`SimClient` on this connection; with ``endpoint`` "", on the server
        :func:`~sharedspace.local_server.find_server` finds, which the client holds until it
        shuts down."""
        endpoint, prefix, found = self.endpoint, self.prefix, None
        if endpoint == "":
            from .local_server import find_server

            found = find_server(prefix=prefix)
            endpoint, prefix = found.endpoints, found.prefix
        try:
            client = SimClient(
                endpoint, prefix, timeout=self.timeout, mode=self.zenoh_mode, config=self.config
            )
        except BaseException:
            if found is not None:
                found.close()
            raise
        client.server_lease = found
        return client

    @classmethod
    def of_client(cls, client: SimClient, failover: bool = False) -> Connection:
        """The connection an open client was made with (what a copy of an env reopens)."""
        t = client.transport
        return cls(
            endpoint=list(t.endpoints),
            prefix=t.prefix,
            timeout=t.timeout,
            zenoh_mode=t.mode,
            config=t.config,
            failover=failover,
        )

    @classmethod
    def resolve(
        cls,
        endpoint: str = "",
        prefix: str = DEFAULT_PREFIX,
        zenoh_config: str | Path = "",
        local_pools: Sequence[str | Path] = (),
        local_params: str | Path | None = None,
    ) -> Connection:
        """A trainer's connection: the zenoh configuration file ``zenoh_config`` if given
        (deploy/trainer.json5: its ``mode``, endpoints, TLS, credentials), else ``endpoint``,
        else a ``sim-server`` this process starts on a free loopback port, serving
        ``local_pools`` with ``local_params`` (:func:`sharedspace.local_server.shared_server`;
        it stops when the process exits). ``$SHAREDSPACE_ENDPOINT`` is not read here: a run's
        world is its own, which a named server cannot be checked to serve."""
        if zenoh_config:
            settings = zenoh_file_settings(zenoh_config)
            mode = settings.pop("mode", "client")
            return cls(endpoint=None, prefix=prefix, zenoh_mode=mode, config=settings)
        if endpoint:
            return cls(endpoint=endpoint, prefix=prefix)
        from .local_server import shared_server

        server = shared_server(local_pools, local_params)
        return cls(endpoint=server.endpoint, prefix=server.prefix)


class EnvOptions(NamedTuple):
    """What :func:`env_options` sorted."""

    #: The envs to make.
    spec: EnvSpec
    #: A shared client, or the connection to open.
    client: SimClient | Connection
    #: Re-create the envs on a surviving server when theirs dies.
    failover: bool


def env_options(
    options: Mapping[str, Any],
    spec: EnvSpec | None = None,
    client: SimClient | Connection | None = None,
) -> EnvOptions:
    """Sorts an env adapter's keyword ``options``: :class:`~sharedspace.wire.EnvSpec` fields
    (over ``spec``) and :class:`Connection` fields (over ``client``'s, when it is a
    Connection). Any other name raises ``TypeError`` naming it; connection fields beside a
    shared :class:`SimClient` raise ``ValueError`` (that client says where it is connected;
    ``failover`` alone may be given)."""
    spec_fields = {k: v for k, v in options.items() if k in EnvSpec.fields()}
    conn_fields = {k: v for k, v in options.items() if k in Connection.fields()}
    unknown = sorted(set(options) - set(spec_fields) - set(conn_fields))
    if unknown:
        raise TypeError(
            f"unknown env option(s) {', '.join(map(repr, unknown))}: not a field of EnvSpec "
            f"({', '.join(EnvSpec.fields())}) nor of Connection "
            f"({', '.join(Connection.fields())})"
        )
    spec = EnvSpec.of(spec, **spec_fields)
    if isinstance(client, SimClient):
        where = sorted(set(conn_fields) - {"failover"})
        if where:
            raise ValueError(
                f"{where}: a shared client is already connected (pass one or the other)"
            )
        return EnvOptions(spec, client, bool(conn_fields.get("failover", False)))
    connection = client or Connection()
    if conn_fields:
        connection = connection.replace(**conn_fields)
    return EnvOptions(spec, connection, connection.failover)
