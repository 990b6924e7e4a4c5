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

from sharedspace.episodes import (
    BENCHMARK_VARIATIONS,
    METRICS,
    STATUSES,
    outcome_rates,
    run_episodes,
    summarize,
    variation_batches,
)
from sharedspace.train.config import TrainConfig
from sharedspace.train.envs import make_env

__all__ = [
    "METRICS",
    "STATUSES",
    "evaluate_split",
    "outcome_rates",
    "run_episodes",
    "summarize",
]


def evaluate_split(cfg: TrainConfig, actor, split: str = "test") -> dict[str, Any]:
    """Plays ``split`` (``validation``, ``test``, or ``train``: every scene once); returns
    per-episode records and the summary."""
    if split == "validation":
        return _evaluate_validation(cfg, actor)
    n = len(cfg.scene_indices(split))
    env = make_env(cfg, split=split, num_envs=n, seed=cfg.seed, scenario_order="sequential")
    try:
        episodes = run_episodes(env, actor)
    finally:
        env.close()
    return {"episodes": episodes, "summary": summarize(episodes)}


def _evaluate_validation(cfg: TrainConfig, actor) -> dict[str, Any]:
    scenes = cfg.validation_scenes
    episodes: list[dict[str, Any]] = []
    for seeds in variation_batches(scenes, cfg.validation_variations):
        env = make_env(
            cfg,
            split="validation",
            num_envs=len(seeds),
            seed=0,
            scenario_order="sequential",
            variations=BENCHMARK_VARIATIONS,
            variation_seeds=seeds,
        )
        try:
            episodes += run_episodes(env, actor)
        finally:
            env.close()
    return {"episodes": episodes, "summary": summarize(episodes)}
