"""The trainer's evaluation: a split's scenes played with the deterministic policy (the
TanhNormal's mode), summarised as the paper's Table II columns.

- ``validation`` (the default during training): each of the ``validation_scenes`` carved from
  the train scenes (:mod:`sharedspace.worlds`) in its ``validation_variations`` seeded
  variations of the benchmark's spec, as the benchmark plays the test scenes;
- ``test``: every test scene once, as recorded. Only the table commands ask for it.

:mod:`sharedspace.paper.evaluate` builds the tables, the human row and the powered test on
these; the episode records and summaries are :mod:`sharedspace.episodes`'s."""

from __future__ import annotations

from typing import Any

from sharedspace.episodes import BENCHMARK_VARIATIONS, run_episodes, summarize, variation_batches
from sharedspace.train.envs import Driving, make_env
from sharedspace.world_config import WorldConfig

__all__ = ["evaluate_split", "play_variations"]


def evaluate_split(
    world: WorldConfig,
    actor,
    split: str = "test",
    seed: int = 0,
    driving: Driving = Driving(),  # noqa: B008 - frozen
) -> dict[str, Any]:
    """Plays ``split`` of ``world`` (``validation``: each validation scene in the world's
    ``validation_variations``; ``test``, or ``train``: every scene once, envs seeded
    ``seed``) with ``actor`` driving as ``driving`` says; returns per-episode records and the
    summary."""
    if split == "validation":
        episodes = play_variations(
            world, actor, world.validation_variations, "validation", driving=driving
        )
        return {"episodes": episodes, "summary": summarize(episodes)}
    n = len(world.scene_indices(split))
    env = make_env(world, split, n, seed, "sequential", driving=driving)
    try:
        episodes = run_episodes(env, actor)
    finally:
        env.close()
    return {"episodes": episodes, "summary": summarize(episodes)}


def play_variations(
    world: WorldConfig,
    policy,
    variations: int,
    split: str = "test",
    spec: dict[str, Any] | None = None,
    first: int = 0,
    fresh_policy=None,
    seed: int = 0,
    driving: Driving = Driving(),  # noqa: B008 - frozen
) -> list[dict[str, Any]]:
    """Plays every scenario of ``split`` in the variations of seeds ``first .. first +
    variations - 1`` of ``spec`` (default :data:`~sharedspace.outcomes.BENCHMARK_VARIATIONS`):
    one episode per (scenario, variation), each record with its ``variation`` seed. Envs of
    whole variations (:func:`sharedspace.rollout.variation_batches`), seeded ``seed``.
    ``fresh_policy()``, if given, makes the policy anew for each env (a driver that counts its
    steps). The one play loop over variation batches of the trainers' and the tables' TorchRL
    envs."""
    n = len(world.scene_indices(split))
    episodes: list[dict[str, Any]] = []
    for seeds in variation_batches(n, variations, first):
        env = make_env(
            world,
            split,
            len(seeds),
            seed,
            "sequential",
            variations=dict(spec or BENCHMARK_VARIATIONS),
            variation_seeds=seeds,
            driving=driving,
        )
        try:
            episodes += run_episodes(env, fresh_policy() if fresh_policy else policy)
        finally:
            env.close()
    return episodes
