"""A trainer cut off by a network partition (its traffic dropped by a TCP proxy between it and
the server, the sockets left open) is reaped within zenoh's lease plus the server's
`reconnect_grace_s`, and not before the grace; one whose link comes back within the grace
reconnects (zenoh retries its connect endpoint), its liveliness token reappears and it steps
its envs again."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from conftest import free_port, unique_prefix

from sharedspace.client import SimClient

LEASE_MS = 1000


class PartitionProxy:
    """Forwards TCP between `listen_port` and `target_port` on loopback; while `partitioned`
    every byte in either direction is read and dropped (a silent link, not a closed one)."""

    def __init__(self, target_port: int):
        self.port = free_port()
        self.target = target_port
        self.partitioned = threading.Event()
        self._stop = threading.Event()
        self._server = socket.create_server(("127.0.0.1", self.port))
        self._server.settimeout(0.2)
        self._socks: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                upstream = socket.create_connection(("127.0.0.1", self.target), timeout=2)
            except OSError:
                client.close()
                continue
            self._socks += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    def _pipe(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                if not self.partitioned.is_set():
                    dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.close()
            except OSError:
                pass

    def close(self) -> None:
        self._stop.set()
        self._server.close()
        for s in self._socks:
            try:
                s.close()
            except OSError:
                pass


def _load(observer: SimClient) -> int:
    return int(observer.pick_server()["load"])


def _wait_for(pred, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(0.1)
    return False


@pytest.fixture
def partitioned_setup(server_factory):
    def make(reconnect_grace_s: float):
        prefix = unique_prefix()
        server = server_factory(
            prefix,
            "p0",
            "trainer_grace_s:1",
            f"reconnect_grace_s:{reconnect_grace_s}",
            f"zenoh/transport/link/tx/lease:{LEASE_MS}",
        )
        proxy = PartitionProxy(server.port)
        # a short lease, and a short handshake timeout so that reconnecting retries soon
        lease = {"transport/link/tx/lease": LEASE_MS, "transport/unicast/open_timeout": 1000}
        trainer = SimClient(f"tcp/127.0.0.1:{proxy.port}", prefix, config=lease)
        observer = SimClient(server.endpoint, prefix)
        made.append((proxy, trainer, observer))
        return proxy, trainer, observer

    made: list = []
    yield make
    for proxy, trainer, observer in made:
        trainer.shutdown()
        observer.shutdown()
        proxy.close()


def test_a_partitioned_trainer_is_reaped_within_lease_plus_grace(partitioned_setup):
    grace = 2.0
    proxy, trainer, observer = partitioned_setup(grace)
    env = trainer.create(1)["env_ids"][0]
    trainer.reset(env)
    assert _load(observer) == 1
    t0 = time.monotonic()
    proxy.partitioned.set()
    time.sleep(LEASE_MS / 1000 * 0.5)
    assert _load(observer) == 1  # neither the lease nor the grace is over
    assert _wait_for(lambda: _load(observer) == 0, LEASE_MS / 1000 + grace + 3.0)
    elapsed = time.monotonic() - t0
    assert elapsed >= grace, elapsed  # kept for the reconnect grace first


def test_a_trainer_back_within_the_grace_keeps_its_envs(partitioned_setup):
    grace = 10.0
    proxy, trainer, observer = partitioned_setup(grace)
    env = trainer.create(1)["env_ids"][0]
    trainer.reset(env)
    proxy.partitioned.set()
    time.sleep(LEASE_MS / 1000 * 2)  # the lease has run out: the token is gone
    proxy.partitioned.clear()

    def steps() -> bool:
        try:
            out = trainer.step(env, np.zeros((1, 2), np.float32))
        except Exception:  # noqa: BLE001 - reconnecting
            return False
        return bool(np.isfinite(out["reward"]).all())

    assert _wait_for(steps, grace - 3.0), "the trainer did not get its env back"
    time.sleep(grace - (LEASE_MS / 1000 * 2) + 1.0)  # past the grace: still open
    assert _load(observer) == 1
