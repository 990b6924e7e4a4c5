"""Scoring drivers on the adversarial task: every test episode (76 scenes x 4 variations of
``crowd``) played by a driver against the crowd's own CR-SFM pedestrian and against each
adversary, and the drop with its paired interval.

A driver given as several policies (a learned row's seeds) plays every episode with each, as
the benchmark pools a row; an adversary is trained against the row as one driver whose seeds
share the sub-envs (:func:`pooled_driver`).
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import nn

from sharedspace.adversary.env import AdversaryEnv
from sharedspace.adversary.scripted import SCRIPTED_ADVERSARIES
from sharedspace.adversary.task import AdversaryTask, get_adversary_task
from sharedspace.adversary.train import serve_task
from sharedspace.bench.policies import Policy, make_policy
from sharedspace.episodes import run_episodes
from sharedspace.outcomes import mean_by_episode, outcome_rates
from sharedspace.stats import paired_clustered

__all__ = [
    "load_adversary",
    "per_episode",
    "play",
    "pooled_driver",
    "stress_row",
    "summarize_stress",
]


def pooled_driver(specs: Sequence[Any], task: AdversaryTask, name: str = "") -> Policy:
    """One driver of several policies (a row's seeds): sub-env ``k`` of a batch is driven by
    policy ``k % n``."""
    made = [make_policy(s, task.driving) for s in specs]
    if len(made) == 1:
        return made[0]

    def act(obs: dict[str, np.ndarray]) -> np.ndarray:
        n = len(made)
        out = np.zeros((len(obs["features"]), 2), dtype=np.float32)
        for j, p in enumerate(made):
            out[j::n] = np.asarray(p.act({k: v[j::n] for k, v in obs.items()}), np.float32)
        return out

    sources = [p.source for p in made]
    return Policy(name or made[0].name, {"kind": "pooled", "policies": sources}, act)


def load_adversary(spec: str | Path, task: AdversaryTask, dt: float = 0.5) -> nn.Module:
    """An adversary: a scripted one by name (:data:`~sharedspace.adversary.scripted.
    SCRIPTED_ADVERSARIES`, held to ``task``'s walking range in a world stepping every ``dt``
    s), or a learned one's actor from its checkpoint (played deterministically)."""
    if str(spec) in SCRIPTED_ADVERSARIES:
        return SCRIPTED_ADVERSARIES[str(spec)](task.walking_range, dt)
    from sharedspace.train.learners import load_checkpoint_actor

    _, actor = load_checkpoint_actor(str(spec))
    return actor


class _Standing(nn.Module):
    """The action of no adversary (the pedestrian is CR-SFM's; the env ignores it)."""

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        return td.set("action", torch.zeros(td.batch_size[0], 2))


def play(
    driver: Policy, adversary: str | Path | None, task: AdversaryTask, client
) -> list[dict[str, Any]]:
    """Every test episode of ``task`` (scene ``k % S`` in variation ``k // S``) driven by
    ``driver`` against ``adversary`` (a checkpoint or a scripted adversary's name; None: the
    CR-SFM pedestrian): one record each (scene, variation, the driver's outcome, ``fault``,
    ``blame``)."""
    pool = json.loads(task.pool_path().read_text())
    scenes = [s["name"] for s in pool["scenarios"] if s["split"] == "test"]
    variations = task.driving.variations
    names = [s for _ in range(variations) for s in scenes]
    seeds = [v for v in range(variations) for _ in scenes]
    env = AdversaryEnv(
        driver,
        task,
        len(names),
        split="test",
        scenarios=names,
        variation_seeds=seeds,
        until="driver",
        adversary=adversary is not None,
        client=client,
    )
    try:
        run_episodes(
            env, _Standing() if adversary is None else load_adversary(adversary, task, env.dt)
        )
        first: dict[tuple[str, int], dict[str, Any]] = {}
        for rec in env.finished:
            first.setdefault((rec["scene"], rec["variation"]), rec)
    finally:
        env.close()
    return [first[(s, v)] for s, v in zip(names, seeds, strict=True)]


def stress_row(
    driver_specs: Sequence[Any],
    adversaries: dict[str, str | Path | None],
    task: str | AdversaryTask = "crowd-adversary",
    name: str = "",
) -> dict[str, Any]:
    """A driver (its policies pooled) against each of ``adversaries`` (label -> checkpoint or
    scripted adversary,
    None for CR-SFM): every episode and the summary of each condition."""
    task = get_adversary_task(task) if isinstance(task, str) else task
    out: dict[str, Any] = {"task": task.tag, "fingerprint": task.fingerprint(), "driver": name}
    out["driver_specs"] = [str(s) for s in driver_specs]
    out["conditions"] = {}
    with tempfile.TemporaryDirectory() as tmp:
        client = serve_task(task, Path(tmp)).open()
        try:
            for label, ckpt in adversaries.items():
                t0 = time.perf_counter()
                episodes = []
                for seed, spec in enumerate(driver_specs):
                    policy = make_policy(spec, task.driving)
                    for rec in play(policy, ckpt, task, client):
                        episodes.append({**rec, "policy": seed})
                out["conditions"][label] = {
                    "adversary": None if ckpt is None else str(ckpt),
                    "episodes": episodes,
                    "wall_s": time.perf_counter() - t0,
                }
        finally:
            client.shutdown()
    return summarize_stress(out)


def summarize_stress(result: dict[str, Any]) -> dict[str, Any]:
    """Adds each condition's rates (Wilson 95 %: success, collision, at fault with the adversary
    and with anyone, the adversary to blame) and, against the first condition (CR-SFM), the
    paired drop in success and rise in at-fault collisions (scenes resampled)."""
    conditions = result["conditions"]
    base_label = next(iter(conditions))
    base = conditions[base_label]["episodes"]
    for label, cond in conditions.items():
        eps = cond["episodes"]
        rows = [
            {
                "status": e["driver"],
                "at_fault": e["fault"],
                "at_fault_any": e.get("fault_any", False),
                "adversary_blamed": e["blame"],
            }
            for e in eps
        ]
        rates = outcome_rates(rows, flags=("at_fault", "at_fault_any", "adversary_blamed"))
        rates.pop("timeout")  # the stress test's conditions report success and collision
        cond["summary"] = {"episodes": len(eps), **rates}
        if label != base_label:
            cond["drop"] = paired_clustered(
                per_episode(base, "success"), per_episode(eps, "success")
            )
            cond["fault_rise"] = paired_clustered(
                per_episode(eps, "fault"), per_episode(base, "fault")
            )
    return result


def per_episode(episodes: list[dict[str, Any]], what: str) -> dict[tuple[str, int], float]:
    """Per (scene, variation), the mean over the pooled policies of success or ``fault``."""
    return mean_by_episode(
        episodes,
        lambda e: (e["scene"], int(e["variation"])),
        lambda e: e["driver"] == "success" if what == "success" else bool(e[what]),
    )
