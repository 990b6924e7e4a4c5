"""What the one training loop (:mod:`sharedspace.train.loop`) asks of an algorithm's module and of
the two objects it makes, stated once: an algorithm module has ``make_world(cfg)`` and
``make_learner(cfg, world, env)``; the world is a :class:`World`, the learner a
:class:`Learner`. PPO, SAC, the multi-car learners and a user's plug-in conform
(``clients/tests/test_learner_protocol.py``).

**One vocabulary for the stats.** A learner's ``step`` adds the gradient steps it took to
``counters["updates"]`` (the loop logs it as ``train/updates``) and returns its other
statistics by plain names (``loss_objective``, ``loss_critic``, ``lr``, ...); the loop logs
them under ``train/``. No learner returns ``updates`` or ``gradient_steps`` itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from tensordict import TensorDictBase
from torch import nn

__all__ = ["Learner", "World", "check_stats"]

#: Names a learner's stats may not take: the loop's own counters.
RESERVED_STATS = ("updates", "gradient_steps", "frames", "episodes", "iterations")


@runtime_checkable
class Learner(Protocol):
    """An algorithm's learning side, as the loop drives it."""

    #: The policy the collector plays; a checkpoint's ``actor`` weights load into it.
    actor: nn.Module
    #: Frames collected per batch, summed over the sub-envs.
    batch_frames: int
    #: Frames of uniform random actions before the actor plays (off-policy warm-up; 0 else).
    random_frames: int

    def start(self, counters: dict[str, Any], logger) -> None:
        """Work before the first batch (SAC: behaviour cloning on prior data), logged."""

    def step(self, data: TensorDictBase, counters: dict[str, Any]) -> dict[str, float]:
        """Learns from one collected batch; adds its gradient steps to ``counters["updates"]``
        and returns its stats by plain names (see the module's docstring)."""

    def state_dict(self) -> dict[str, Any]:
        """What a checkpoint's ``learner`` keeps (networks, targets, normalisations)."""

    def optimizer_state(self) -> dict[str, Any]:
        """What a checkpoint's ``optimizers`` keeps."""

    def load(self, ckpt: dict[str, Any]) -> None:
        """Restores the actor, :meth:`state_dict`, the optimisers and torch's RNG from a
        checkpoint of this algorithm (a resumed run)."""


@runtime_checkable
class World(Protocol):
    """Where a learner's envs come from and how its episodes are counted and scored."""

    def make_env(self, seed: int):
        """The batched training env (TorchRL ``EnvBase``)."""

    def outcomes(self, data: TensorDictBase) -> dict[str, float]:
        """The batch's ended episodes as ``train/*`` metrics, with ``ended`` and ``lost``."""

    def recent(self) -> list[dict[str, float]]:
        """The latest ended episodes (the progress bar's line)."""

    def evaluate(self, actor) -> dict[str, Any]:
        """A scoring of ``actor`` on the config's ``eval_split``: its summary."""

    def network(self) -> str:
        """The network a checkpoint records."""

    def record(self) -> dict[str, Any]:
        """What a checkpoint records of the world."""

    def finish(self, actor, log_dir: Path, summary: dict[str, Any], timing: dict) -> None:
        """Work after the last checkpoint (multi-car runs: ``policy.pt``, ``eval.json``)."""


def check_stats(stats: dict[str, float]) -> dict[str, float]:
    """``stats`` as a learner's ``step`` returned them, refused (ValueError naming the key) if
    one carries a prefix or a counter's name."""
    for key in stats:
        if "/" in key or key in RESERVED_STATS:
            raise ValueError(
                f"a learner's stats are plain names other than {', '.join(RESERVED_STATS)}: "
                f"{key!r} (sharedspace.train.protocol)"
            )
    return stats
