"""Playing episodes with no torch: one episode per sub-env of a
:class:`~sharedspace.vector.VectorClient`, each a named scene in a chosen variation, driven by a
NumPy policy ``act(obs) -> actions``.

The benchmark scores every single-car policy through :func:`play_first_episodes`: a scripted
driver or a user's NumPy function needs nothing else, and a checkpoint's network is wrapped into
such a function (:mod:`sharedspace.bench.policies`). The TorchRL env's loop
(:func:`sharedspace.episodes.run_episodes`, the trainers' evaluation) plays the same episodes:
same scene, same variation seed and the same actions give the same outcome, step for step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from sharedspace.client import SimClient
from sharedspace.outcomes import METRICS
from sharedspace.vector import VectorClient
from sharedspace.wire.requests import EnvSpec

__all__ = ["MAX_EVAL_ENVS", "Act", "play_first_episodes", "variation_batches"]

#: Most sub-envs of one evaluation env (the server's default ``max_batch`` is 1024).
MAX_EVAL_ENVS = 512

#: A batch of one car's observations ``{"features" [K, M, F], "adjacency" [K, M, M],
#: "mask" [K, M] (bool)}`` to actions ``[K, 2]`` in [-1, 1] (acceleration, yaw rate).
Act = Callable[[dict[str, np.ndarray]], Any]


def variation_batches(
    scenes: int, variations: int, first: int = 0, max_envs: int = MAX_EVAL_ENVS
) -> list[list[int]]:
    """The variation seed of every sub-env, env by env, to play each of ``scenes`` scenes (in
    sequential order) in the variations ``first .. first + variations - 1``: whole variations
    per env, at most ``max_envs`` sub-envs (at least one variation). Sub-env ``k`` of an env
    plays scene ``k % scenes``."""
    per_env = max(1, max_envs // scenes)
    batches = []
    for start in range(first, first + variations, per_env):
        count = min(per_env, first + variations - start)
        batches.append([start + k // scenes for k in range(scenes * count)])
    return batches


def play_first_episodes(
    client: SimClient,
    spec: EnvSpec,
    act: Act,
    scenes: Sequence[str],
    variations: Sequence[int] | None = None,
    max_steps: int = 10_000,
) -> list[dict[str, Any]]:
    """Plays one episode of scene ``scenes[k]`` (in variation ``variations[k]``, where the
    spec has variations) in sub-env ``k``, all K together, and returns one record per sub-env in
    order: ``scene``, ``variation`` (-1 without), ``status``, the server's episode metrics,
    ``steps`` (actions taken) and ``return`` (the rewards' sum). ``act``'s actions are clipped to
    [-1, 1] as the envs clip them; a sub-env whose episode has ended is reset to its scene and
    stepped on until every episode has ended, its later steps not counted."""
    k = len(scenes)
    chosen = [None] * k if variations is None else [int(v) for v in variations]
    if len(chosen) != k:
        raise ValueError(f"{len(chosen)} variations for {k} scenes")
    vec = VectorClient(k, spec.replace(autoreset=False), client=client)
    if vec.n_ext != 1:
        vec.close()
        raise ValueError("play_first_episodes drives one external agent per sub-env")
    records: list[dict[str, Any] | None] = [None] * k
    steps, returns = np.zeros(k, dtype=np.int64), np.zeros(k)
    try:
        obs = _first(vec.client.reset_many(vec.env_ids, scenarios=scenes, variations=variations))
        for _ in range(max_steps):
            actions = np.asarray(act(obs), dtype=np.float32)
            if actions.shape != (k, 2):
                raise ValueError(f"act gave actions of shape {actions.shape}, wanted ({k}, 2)")
            res = vec.step(np.clip(actions, -1.0, 1.0))
            live = np.array([r is None for r in records])
            steps += live
            returns += np.where(live, np.asarray(res["reward"], dtype=np.float64)[:, 0], 0.0)
            for entry in res["metrics"]:
                i, metrics = int(entry["index"]), entry["metrics"]
                if records[i] is None:
                    records[i] = {
                        "scene": scenes[i],
                        "variation": -1 if chosen[i] is None else chosen[i],
                        "status": metrics.get("outcome", "timeout"),
                        **{m: float(metrics.get(m, 0.0)) for m in METRICS},
                        "steps": int(steps[i]),
                        "return": float(returns[i]),
                    }
            if all(r is not None for r in records):
                break
            # copies: the reply's arrays are read-only, and a policy may write into its input
            obs = {key: np.array(res["obs"][key][:, 0]) for key in ("features", "adjacency")}
            obs["mask"] = np.asarray(res["obs"]["mask"][:, 0], dtype=bool)
            ended = np.flatnonzero((res["terminated"] | res["truncated"])[:, 0])
            if len(ended):
                again = vec.client.reset_many(
                    [vec.env_ids[i] for i in ended],
                    scenarios=[scenes[i] for i in ended],
                    variations=None if variations is None else [chosen[i] for i in ended],
                )
                fresh = _first(again)
                for key in obs:
                    obs[key][ended] = fresh[key]
    finally:
        vec.close()
    return [r for r in records if r is not None]


def _first(results: Sequence[dict[str, Any]]) -> dict[str, np.ndarray]:
    """The first observation of reset episodes, stacked: ``[R, M, ...]`` of their one car."""
    obs = {key: np.stack([r["obs"][key][0] for r in results]) for key in ("features", "adjacency")}
    obs["mask"] = np.stack([np.asarray(r["obs"]["mask"][0], dtype=bool) for r in results])
    return obs
