"""How episodes ended, with no torch: the statuses, the metrics a summary averages, the powered
test's variations, the one outcome summary (:func:`outcome_rates`) and the one per-episode
average over pooled seeds (:func:`mean_by_episode`). The bench, the tables and
the learners' evaluations all count outcomes here (:mod:`sharedspace.episodes` plays them)."""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Sequence
from typing import Any

from sharedspace.stats import wilson

__all__ = ["BENCHMARK_VARIATIONS", "METRICS", "STATUSES", "mean_by_episode", "outcome_rates"]

#: How an episode ends (sim-core ``EpisodeStatus``).
STATUSES = ("success", "collision", "timeout")
#: The per-episode metrics a summary averages (sim-core ``EpisodeMetrics``).
METRICS = ("avg_speed", "avg_abs_jerk", "max_abs_acc")

#: The powered test's scene variations (sim-core ``VariationSpec::benchmark``; docs/RESULTS.md).
BENCHMARK_VARIATIONS = {"position_sigma": 0.25, "start_offset_steps": 1, "desired_speed_scale": 0.1}


def outcome_rates(
    rows: Sequence[dict[str, Any]], flags: Sequence[str] = ()
) -> dict[str, dict[str, Any]]:
    """How episodes ended: for each of :data:`STATUSES` (a row's ``status``) and each boolean
    field of ``flags``, its ``rate``, ``count`` and Wilson 95 % interval ``ci95``. The one
    outcome summary of every learner (single-car rows here, per-car rows in ``marl``)."""
    n = len(rows)
    out: dict[str, dict[str, Any]] = {}
    for key in (*STATUSES, *flags):
        hits = sum(bool(r[key]) if key in flags else r["status"] == key for r in rows)
        lo, hi = wilson(hits, n)
        out[key] = {"rate": hits / max(n, 1), "count": hits, "ci95": [lo, hi]}
    return out


def mean_by_episode(
    rows: Iterable[dict[str, Any]],
    episode: Callable[[dict[str, Any]], Hashable],
    value: Callable[[dict[str, Any]], float],
) -> dict[Hashable, float]:
    """Each episode's ``value`` averaged over the rows that played it (``episode(row)`` names
    it: a scene and variation, or a scene and car): a pooled row's seeds count as one outcome
    per episode, which is what a paired difference pairs. The one per-episode averaging of the
    bench, the tables, the stress test and the multi-car evaluation."""
    plays: dict[Hashable, list[float]] = {}
    for row in rows:
        plays.setdefault(episode(row), []).append(float(value(row)))
    return {key: sum(v) / len(v) for key, v in plays.items()}
