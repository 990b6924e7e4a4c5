"""Collection overlapped with the update: while the learner updates on batch ``n``, the envs
step batch ``n + 1`` with the policy from before that update (Sample Factory's double-buffered
sampling, PufferLib's asynchronous envs; here one collector thread beside the learner).

The server is its own process, and the collector thread spends most of its time waiting on it
or in torch and zenoh code that releases the GIL, so the server, the policy's forward pass for
collection and the update run at once on the machine's cores, where the synchronous loop
alternates them (docs/BENCHMARKS.md, "The learners' throughput").

The contract (``clients/tests/test_overlap.py``):

- batch ``0`` and batch ``1`` are collected with the initial policy, and batch ``k >= 1`` with
  the weights the learner held after its update on batch ``k - 2``, exactly: the thread waits
  for them rather than run further ahead, so a run is as reproducible as the synchronous one
  and the lag is one update, never more;
- the collector plays its own copy of the actor (the *behaviour* actor), whose weights change
  only between batches, so every frame of a batch carries the log-probability of the policy
  that acted. PPO's ratio divides by that recorded log-probability (TorchRL's
  ``ClipPPOLoss`` reads ``sample_log_prob`` from the batch), so the loss stays the right one
  and the clip bounds the lag's effect;
- an error in the thread (a lost server with no survivor, say) is raised in the learner's
  thread at its next batch, and ``shutdown`` stops the thread and the inner collector.
"""

from __future__ import annotations

import copy
import queue
import threading
from collections.abc import Iterator

import torch
from tensordict import TensorDictBase
from torch import nn

__all__ = ["OverlappedCollector"]

#: Seconds between the thread's looks at its stop flag while it waits.
_POLL_S = 0.1


class OverlappedCollector:
    """Iterates over the batches of ``make_collector(behaviour)`` (a synchronous TorchRL
    collector over a copy of ``actor``), collected one batch ahead in a thread.

    ``update_policy_weights_()``, called by the learner after each update, hands the thread
    the actor's new weights (state dict: parameters and buffers, the feature normalisation's
    running moments included); the thread loads them before the batch after next, as the
    module docstring says.
    """

    def __init__(self, actor: nn.Module, make_collector):
        self.actor = actor
        self.behaviour = copy.deepcopy(actor)
        self.behaviour.requires_grad_(False)
        self.collector = make_collector(self.behaviour)
        self._batches: queue.Queue = queue.Queue(maxsize=1)
        self._weights: dict[int, dict] = {}  # weights handed over, by updates done before them
        self._version = 0  # updates handed over so far
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sharedspace-collector", daemon=True)
        self._started = False
        self._done = False

    # ---- the learner's side
    def __iter__(self) -> Iterator[TensorDictBase]:
        if not self._started:
            self._started = True
            self._thread.start()
        while not self._done:
            kind, item = self._take()
            if kind == "batch":
                yield item
            elif kind == "error":
                self._done = True
                raise item
            else:  # "end": the inner collector has given every frame
                self._done = True

    def update_policy_weights_(self) -> None:
        """Hands the actor's current weights to the collector thread (a copy: the learner may
        go on updating its own)."""
        weights = {k: v.detach().clone() for k, v in self.actor.state_dict().items()}
        with self._cond:
            self._version += 1
            self._weights[self._version] = weights
            self._cond.notify_all()

    def shutdown(self) -> None:
        """Stops the thread (after the batch it is collecting) and the inner collector."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        while self._thread.is_alive():
            try:  # unblock a thread waiting to hand over a batch nobody will take
                self._batches.get_nowait()
            except queue.Empty:
                pass
            self._thread.join(timeout=_POLL_S)
        self.collector.shutdown()

    def _take(self) -> tuple[str, object]:
        while True:
            try:
                return self._batches.get(timeout=_POLL_S)
            except queue.Empty:
                if not self._thread.is_alive() and self._batches.empty():
                    return "error", RuntimeError("the collector thread ended without a word")

    # ---- the collector thread
    def _run(self) -> None:
        try:
            batch_index = 0
            for data in self.collector:
                if not self._put(("batch", data)):
                    return
                # batch k + 1 is played with the weights after the update on batch k - 1
                if not self._load_weights(after_updates=batch_index):
                    return
                batch_index += 1
            self._put(("end", None))
        except BaseException as err:  # noqa: BLE001 - carried to the learner's thread
            self._put(("error", err))

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._batches.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _load_weights(self, after_updates: int) -> bool:
        with self._cond:
            while self._version < after_updates and not self._stop.is_set():
                self._cond.wait(timeout=_POLL_S)
            if self._stop.is_set():
                return False
            # exactly these weights, even if the learner is already further
            weights = self._weights.get(after_updates)
            for version in [v for v in self._weights if v < after_updates]:
                del self._weights[version]
        if weights is not None:
            with torch.no_grad():
                self.behaviour.load_state_dict(weights)
        return True
