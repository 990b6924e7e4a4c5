"""Playing and summarising episodes: one record per episode of a batched env, and the one
outcome summary (success, collision, timeout with Wilson intervals, :mod:`sharedspace.outcomes`)
that every learner, table and benchmark reports. It knows envs and policies, not trainers: the
trainer's evaluation (:mod:`sharedspace.train.evaluation`) and the paper's tables play through
:func:`run_episodes`; the benchmark plays the same episodes with no torch
(:func:`sharedspace.rollout.play_first_episodes`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from sharedspace.names import Feature
from sharedspace.outcomes import BENCHMARK_VARIATIONS, METRICS, STATUSES, outcome_rates
from sharedspace.rollout import MAX_EVAL_ENVS, variation_batches

__all__ = [
    "BENCHMARK_VARIATIONS",
    "MAX_EVAL_ENVS",
    "METRICS",
    "STATUSES",
    "outcome_rates",
    "run_episodes",
    "summarize",
    "variation_batches",
]


def run_episodes(env, policy, max_steps: int = 10_000) -> list[dict[str, Any]]:
    """Plays the first episode of every sub-env of ``env`` with ``policy`` (deterministic) and
    returns one record per sub-env: scenario index, status, metrics, return, and the ego's
    speed / normalised action trace (``speeds[0]`` at the start)."""
    k = env.batch_size[0]
    records: list[dict[str, Any] | None] = [None] * k
    traces = [{"speeds": [], "actions": [], "return": 0.0} for _ in range(k)]
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        td = env.reset()
        # The policy may live on a GPU (device=cuda) while the env's tensors are on the CPU.
        param = next(iter(policy.parameters()), None)
        device = param.device if param is not None and param.device != env.device else None
        scen = td["scenario_index"].reshape(-1).tolist()
        seeds = getattr(env, "last_variation_seeds", None)
        variation = [-1 if s is None else int(s) for s in (seeds or [None] * k)]
        for i in range(k):
            traces[i]["speeds"].append(float(td["features"][i, 0, Feature.SPEED]))
        for _ in range(max_steps):
            td = policy(td.to(device)).to(env.device) if device is not None else policy(td)
            td = env.step(td)
            nxt = td["next"]
            done = nxt["done"].reshape(-1)
            terms = getattr(env, "last_reward_terms", None) or {}
            for i in range(k):
                if records[i] is not None:
                    continue
                traces[i]["speeds"].append(float(nxt["features"][i, 0, Feature.SPEED]))
                traces[i]["actions"].append(td["action"][i].tolist())
                traces[i]["return"] += float(nxt["reward"][i])
                for term, values in terms.items():
                    sums = traces[i].setdefault("reward_terms", {})
                    sums[term] = sums.get(term, 0.0) + float(values[i])
                if done[i]:
                    status = next(
                        (s for s in STATUSES if bool(nxt[f"episode_{s}"][i])),
                        "timeout",
                    )
                    records[i] = {
                        "scenario_index": int(scen[i]),
                        "variation": variation[i],
                        "status": status,
                        "avg_speed": float(nxt["episode_avg_speed"][i]),
                        "avg_abs_jerk": float(nxt["episode_avg_abs_jerk"][i]),
                        "max_abs_acc": float(nxt["episode_max_abs_acc"][i]),
                        "steps": len(traces[i]["actions"]),
                        **traces[i],
                    }
            if all(r is not None for r in records):
                break
            td = env.maybe_reset(step_mdp(td))
    return [r for r in records if r is not None]


def summarize(episodes: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Means over episodes (``MetricsSummary::of``): status shares (:func:`outcome_rates`)
    and metric means."""
    n = len(episodes)
    if n == 0:
        return {"episodes": 0, **dict.fromkeys(STATUSES + METRICS, 0.0)}
    row: dict[str, float] = {"episodes": n}
    for s, rate in outcome_rates(episodes).items():
        row[s] = rate["rate"]
    for key in METRICS:
        row[key] = float(np.mean([e[key] for e in episodes]))
    return row
