"""The trainer's evaluation: every scenario of a split played once with the deterministic
policy (the TanhNormal's mode), one sub-env per scenario, summarised as the paper's Table II
columns. :mod:`sharedspace.paper.evaluate` builds the tables,
the human row and the powered test on these; the episode records and summaries are
:mod:`sharedspace.episodes`'s."""

from __future__ import annotations

from typing import Any

from sharedspace.episodes import METRICS, STATUSES, outcome_rates, run_episodes, summarize
from sharedspace.pool import load_pool, split_indices
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
    """Plays every scenario of ``split`` once; returns per-episode records and the summary."""
    pool = load_pool(cfg.scenario_pool or None)
    n = len(split_indices(pool, split))
    env = make_env(cfg, split=split, num_envs=n, seed=cfg.seed, scenario_order="sequential")
    try:
        episodes = run_episodes(env, actor)
    finally:
        env.close()
    return {"episodes": episodes, "summary": summarize(episodes)}
