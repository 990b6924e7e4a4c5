"""Small statistics for the results tables (docs/RESULTS.md): binomial intervals and paired
comparisons over scenarios. numpy only."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "wilson",
    "sign_test",
    "paired_bootstrap",
    "cluster_bootstrap",
    "stratified_bootstrap",
    "paired_clustered",
]


def wilson(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion ``k / n`` (95 % by default)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def sign_test(wins: int, losses: int) -> float:
    """Exact two-sided sign test p-value (ties dropped)."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2 * tail)


def paired_bootstrap(
    diffs: Sequence[float], resamples: int = 10_000, seed: int = 0
) -> tuple[float, float]:
    """95 % percentile interval of the mean of ``diffs`` resampled over scenarios."""
    d = np.asarray(diffs, dtype=float)
    if d.size == 0:
        return (0.0, 0.0)
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, d.size, (resamples, d.size))].mean(1)
    return (float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5)))


def cluster_bootstrap(
    clusters: Sequence[Sequence[float]], resamples: int = 10_000, seed: int = 0
) -> tuple[float, float]:
    """95 % percentile interval of the mean over every value, resampling whole clusters (the
    scenes of a test set) with replacement: values of one scene are not independent, so the
    interval is as wide as the scenes, not the episodes, warrant."""
    sizes = np.array([len(c) for c in clusters], dtype=float)
    if sizes.sum() == 0:
        return (0.0, 0.0)
    sums = np.array([float(np.sum(c)) for c in clusters])
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(clusters), (resamples, len(clusters)))
    n = sizes[pick].sum(1)
    means = np.divide(sums[pick].sum(1), n, out=np.zeros(resamples), where=n > 0)
    return (float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5)))


def stratified_bootstrap(
    clusters: Sequence[Sequence[float]], resamples: int = 10_000, seed: int = 0
) -> tuple[float, float]:
    """95 % percentile interval of the mean over every value, resampling within each cluster
    and keeping the clusters: inference about these scenes only (how sure the mean over their
    variations is), not about scenes not in the test set (:func:`cluster_bootstrap`)."""
    sizes = [len(c) for c in clusters if len(c)]
    if not sizes:
        return (0.0, 0.0)
    rng = np.random.default_rng(seed)
    total = np.zeros(resamples)
    for c in clusters:
        if len(c):
            v = np.asarray(c, dtype=float)
            total += v[rng.integers(0, len(v), (resamples, len(v)))].sum(1)
    means = total / sum(sizes)
    return (float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5)))


def paired_clustered(
    a: dict[tuple[int, int], float],
    b: dict[tuple[int, int], float],
    resamples: int = 10_000,
    seed: int = 0,
) -> dict[str, float]:
    """The paired difference ``a - b`` over the episodes both played, keyed ``(scene,
    variation)``: its mean, and its 95 % interval by :func:`cluster_bootstrap` with the scene
    as cluster; ``pairs`` and ``scenes`` say what it rests on, ``half_width`` how tight it
    is. ``lo_fixed`` / ``hi_fixed`` / ``half_width_fixed``: the interval with the scenes held
    fixed (:func:`stratified_bootstrap`), which more variations narrow without bound."""
    keys = sorted(set(a) & set(b))
    by_scene: dict[int, list[float]] = {}
    for key in keys:
        by_scene.setdefault(key[0], []).append(a[key] - b[key])
    clusters = list(by_scene.values())
    lo, hi = cluster_bootstrap(clusters, resamples, seed)
    lo_f, hi_f = stratified_bootstrap(clusters, resamples, seed)
    diffs = [d for c in clusters for d in c]
    return {
        "diff": float(np.mean(diffs)) if diffs else 0.0,
        "lo": lo,
        "hi": hi,
        "half_width": (hi - lo) / 2,
        "lo_fixed": lo_f,
        "hi_fixed": hi_f,
        "half_width_fixed": (hi_f - lo_f) / 2,
        "pairs": len(diffs),
        "scenes": len(clusters),
    }
