"""Watching envs: the server's publications (protocol/SPEC.md section 11) as numpy messages.

.. code-block:: python

    with Observer(endpoint="tcp/127.0.0.1:7447", env_id="*") as obs:
        for msg in obs.iter(timeout=5.0):
            print(msg["topic"], msg["env_id"], msg["step"], msg.get("positions"))

Each message is the decoded publication (binary arrays as read-only numpy arrays) with two
keys added: ``topic`` (``states``, ``uncertainty``, ``risk_graph``, ``events`` or ``result``)
and, when the payload lacks it, ``env_id`` (from the key). The server publishes a topic only
while somebody subscribes to it (SPEC section 10), so the first step after subscribing may be
missed; publications are best effort.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import zenoh

from .closing import Closing
from .transport import DEFAULT_ENDPOINT, DEFAULT_PREFIX, Transport, undeclare_all
from .wire.envelope import decode
from .wire.errors import SharedspaceError

__all__ = ["Observer", "TOPICS"]

log = logging.getLogger("sharedspace")

#: Publication topics of an env.
TOPICS = ("states", "uncertainty", "risk_graph", "events", "result")


class Observer(Closing):
    """Subscribes to the publications of ``env_id`` (``"*"``: every env) on ``topics``.

    Args:
        endpoint, prefix: where the servers are (ignored when ``transport`` is given).
        env_id: an env id, or ``"*"`` for every env.
        topics: subset of :data:`TOPICS` (default: states, uncertainty, risk_graph, events).
        callback: called with each decoded message from zenoh's thread; when None the messages
            are queued for :meth:`iter` / :meth:`get` (at most ``maxsize``, oldest dropped).
        transport: share an existing transport (and its session).
    """

    def __init__(
        self,
        endpoint: str | Sequence[str] | None = DEFAULT_ENDPOINT,
        prefix: str = DEFAULT_PREFIX,
        *,
        env_id: str = "*",
        topics: Sequence[str] = ("states", "uncertainty", "risk_graph", "events"),
        callback: Callable[[dict[str, Any]], None] | None = None,
        transport: Transport | None = None,
        maxsize: int = 10_000,
        **transport_kwargs: Any,
    ):
        bad = [t for t in topics if t not in TOPICS]
        if bad:
            raise ValueError(f"unknown topic(s) {bad}; topics are {list(TOPICS)}")
        self._own = transport is None
        self.transport = transport or Transport(endpoint, prefix, **transport_kwargs)
        self.env_id = env_id
        self.topics = tuple(topics)
        self._callback = callback
        self._queue: queue.Queue[dict[str, Any]] = queue.Queue(maxsize=maxsize)
        self.received = 0
        self.dropped = 0
        self._subs = [
            self.transport.declare_subscriber(
                self.transport.key("env", env_id, topic), self._on_sample
            )
            for topic in self.topics
        ]
        self._closed = False

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/")
        topic, env_id = parts[-1], parts[-2]
        try:
            msg = decode(sample.payload.to_bytes())
        except SharedspaceError as e:
            log.warning("sharedspace observer: undecodable publication on %s: %s", key, e)
            return
        if not isinstance(msg, dict):
            return
        msg["topic"] = topic
        msg.setdefault("env_id", env_id)
        self.received += 1
        if self._callback is not None:
            try:
                self._callback(msg)
            except Exception:  # noqa: BLE001 - a user callback must not kill zenoh's thread
                log.exception("sharedspace observer: callback failed")
            return
        while True:
            try:
                self._queue.put_nowait(msg)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()
                    self.dropped += 1
                except queue.Empty:
                    pass

    def get(self, timeout: float | None = None) -> dict[str, Any] | None:
        """The next message, or None after ``timeout`` seconds (``None``: don't wait)."""
        try:
            if timeout is None:
                return self._queue.get_nowait()
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def iter(self, timeout: float = 5.0) -> Iterator[dict[str, Any]]:
        """Yields messages until none arrives for ``timeout`` seconds or the observer closes."""
        while not self._closed:
            msg = self.get(timeout)
            if msg is None:
                return
            yield msg

    def __iter__(self) -> Iterator[dict[str, Any]]:
        return self.iter()

    def wait_for(
        self, pred: Callable[[dict[str, Any]], bool], timeout: float = 5.0
    ) -> dict[str, Any] | None:
        """The first queued message satisfying ``pred`` within ``timeout`` s (others dropped)."""
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            msg = self.get(remaining)
            if msg is not None and pred(msg):
                return msg

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        undeclare_all(self._subs)
        if self._own:
            self.transport.close()
