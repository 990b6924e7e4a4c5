"""Scores a checkpoint on a split: the paper's Table II columns, plus the recorded human driver.

    python -m sharedspace.train.evaluate --checkpoint runs/x/checkpoints/last.pt --split test
        [--json out.json] [--traces traces.json] [--set key=value ...]
    python -m sharedspace.train.evaluate --driver pursuit_3 ...   # a scripted reference driver
    python -m sharedspace.train.evaluate --checkpoint ... --variations 32   # the powered test

Every scenario of the split is played once with the deterministic policy (the TanhNormal's
mode) in a batched env with one sub-env per scenario (``scenario_order="sequential"``). The human
row scores the scenario's recorded ego speeds with the same metric definitions
(``EpisodeMetrics::from_speeds``; every recorded episode counts as a success).

With ``--variations M`` every scenario is played in M seeded scene variations instead (SPEC
5.2.1; the spec is ``--variation-spec``, by default the benchmark's: pedestrians moved by
N(0, 0.25 m), started up to a step earlier or later, desired speeds within +-10 %). Variation
``j`` of every scene is the variation of seed ``j``, for every policy and driver, so results
of two policies are paired episode by episode (:mod:`sharedspace.train.powered` compares them);
any episode replays with ``sim-server rollout --scenario NAME --variation j``. The table then
gives Wilson 95 % intervals.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from sharedspace.names import Feature
from sharedspace.pool import load_pool, recorded_headings, split_indices
from sharedspace.stats import wilson
from sharedspace.train.config import (
    TrainConfig,
    add_overrides_argument,
    apply_overrides,
    command_parser,
)
from sharedspace.train.drivers import DRIVERS, make_driver
from sharedspace.train.sac import make_actor, make_env

__all__ = [
    "COLUMNS",
    "BENCHMARK_VARIATIONS",
    "STATUSES",
    "human_episodes",
    "run_episodes",
    "play_variations",
    "summarize",
    "format_table",
    "load_checkpoint_actor",
    "main",
]

#: Table II columns: (key, header).
COLUMNS = (
    ("success", "Success"),
    ("collision", "Collision"),
    ("timeout", "Timeout"),
    ("avg_speed", "Avg speed (m/s)"),
    ("avg_abs_jerk", "Avg |jerk| (m/s^3)"),
    ("max_abs_acc", "Avg max |acc| (m/s^2)"),
)

#: How an episode ends.
STATUSES = ("success", "collision", "timeout")

#: The powered test's scene variations (sim-core ``VariationSpec::benchmark``; docs/RESULTS.md).
BENCHMARK_VARIATIONS = {"position_sigma": 0.25, "start_offset_steps": 1, "desired_speed_scale": 0.1}

#: Most sub-envs of one evaluation env (the server's default ``max_batch`` is 1024).
MAX_EVAL_ENVS = 512


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


def human_metrics(speeds: Sequence[float], dt: float) -> dict[str, Any]:
    """A recording scored as a successful episode, as sim-core's ``EpisodeMetrics::from_speeds``
    scores one (mean speed after the start, mean |jerk|, max |acc|; ``metrics.rs``, whose
    tests fix these definitions)."""
    steps = max(len(speeds) - 1, 0)
    accs = [(b - a) / dt for a, b in zip(speeds[:-1], speeds[1:], strict=True)]
    jerks = [abs((b - a) / dt) for a, b in zip(accs[:-1], accs[1:], strict=True)]
    return {
        "status": "success",
        "avg_speed": sum(speeds[1:]) / steps if steps else 0.0,
        "avg_abs_jerk": sum(jerks) / len(jerks) if jerks else 0.0,
        "max_abs_acc": max((abs(a) for a in accs), default=0.0),
        "steps": steps,
    }


def human_episodes(pool: Sequence[dict], indices: Sequence[int]) -> list[dict[str, Any]]:
    """The recorded ego of each scenario scored like an episode (status ``success``), with its
    speed and heading traces."""
    out = []
    for idx in indices:
        sc = pool[idx]
        ego = sc["agents"][int(sc["ego"])]
        vel = np.asarray(ego["velocities"], dtype=float).reshape(-1, 2)
        speeds = [math.sqrt(v[0] * v[0] + v[1] * v[1]) for v in vel]
        m = human_metrics(speeds, float(sc["dt"]))
        out.append(
            {
                "scenario_index": int(idx),
                **m,
                "speeds": speeds,
                "headings": recorded_headings(vel).tolist(),
                "positions": np.asarray(ego["positions"], dtype=float).tolist(),
            }
        )
    return out


def summarize(episodes: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Means over episodes (``MetricsSummary::of``): status shares and metric means."""
    n = len(episodes)
    if n == 0:
        return {"episodes": 0, **{c: 0.0 for c, _ in COLUMNS}}
    row: dict[str, float] = {"episodes": n}
    for s in STATUSES:
        row[s] = sum(e["status"] == s for e in episodes) / n
    for key in ("avg_speed", "avg_abs_jerk", "max_abs_acc"):
        row[key] = float(np.mean([e[key] for e in episodes]))
    return row


def format_table(rows: dict[str, dict[str, float]]) -> str:
    """Table II as text: one row per model."""
    head = f"{'Model':<16}" + "".join(f"{h:>22}" for _, h in COLUMNS) + f"{'episodes':>10}"
    lines = [head, "-" * len(head)]
    for name, row in rows.items():
        lines.append(
            f"{name:<16}"
            + "".join(f"{row[c]:>22.3f}" for c, _ in COLUMNS)
            + f"{int(row['episodes']):>10}"
        )
    return "\n".join(lines)


def load_checkpoint_actor(path: str, overrides: Sequence[str] = (), device: str = "cpu"):
    """(config, actor) from a checkpoint written by the trainer."""
    ckpt = torch.load(path, map_location=device, weights_only=False)
    cfg = apply_overrides(TrainConfig(**ckpt["config"]), list(overrides))
    cfg = apply_overrides(cfg, {"device": device})
    probe = make_env(cfg, split=cfg.eval_split, num_envs=1)
    actor = make_actor(cfg, probe.action_spec_unbatched)
    with torch.no_grad():
        actor(probe.reset())  # materialise lazy shapes, if any
    actor.load_state_dict(ckpt["actor"])
    probe.close()
    return cfg, actor


def play_variations(
    cfg: TrainConfig,
    policy,
    variations: int,
    split: str = "test",
    spec: dict[str, Any] | None = None,
    first: int = 0,
    fresh_policy=None,
) -> list[dict[str, Any]]:
    """Plays every scenario of ``split`` in the variations of seeds ``first .. first +
    variations - 1`` of ``spec`` (default :data:`BENCHMARK_VARIATIONS`): one episode per
    (scenario, variation), each record with its ``variation`` seed. Envs of at most
    :data:`MAX_EVAL_ENVS` sub-envs, whole variations each. ``fresh_policy()``, if given, makes
    the policy anew for each env (a driver that counts its steps)."""
    pool = load_pool(cfg.scenario_pool or None)
    n = len(split_indices(pool, split))
    per_env = max(1, MAX_EVAL_ENVS // n)
    episodes: list[dict[str, Any]] = []
    for start in range(first, first + variations, per_env):
        count = min(per_env, first + variations - start)
        # Sub-env k plays the split's scenario k % n (sequential order) in variation k // n.
        seeds = [start + k // n for k in range(n * count)]
        env = make_env(
            cfg,
            split=split,
            num_envs=n * count,
            seed=cfg.seed,
            scenario_order="sequential",
            variations=dict(spec or BENCHMARK_VARIATIONS),
            variation_seeds=seeds,
        )
        try:
            episodes += run_episodes(env, fresh_policy() if fresh_policy else policy)
        finally:
            env.close()
    return episodes


def evaluate_policy(
    cfg: TrainConfig,
    actor,
    split: str = "test",
    variations: int = 0,
    spec: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Plays every scenario of ``split`` once (or in ``variations`` seeded variations,
    :func:`play_variations`); returns per-episode records and the summary."""
    if variations > 0:
        episodes = play_variations(cfg, actor, variations, split, spec)
        return {"episodes": episodes, "summary": summarize(episodes)}
    pool = load_pool(cfg.scenario_pool or None)
    n = len(split_indices(pool, split))
    env = make_env(cfg, split=split, num_envs=n, seed=cfg.seed, scenario_order="sequential")
    try:
        episodes = run_episodes(env, actor)
    finally:
        env.close()
    return {"episodes": episodes, "summary": summarize(episodes)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.train.evaluate", __doc__)
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--checkpoint", help="checkpoint .pt written by the trainer")
    who.add_argument(
        "--driver",
        choices=sorted([*DRIVERS, "human_replay"]),
        help="a scripted reference driver instead of a checkpoint (sharedspace.train.drivers)",
    )
    ap.add_argument("--split", default="test", help="train | test | all")
    ap.add_argument(
        "--variations",
        type=int,
        default=0,
        metavar="M",
        help="play every scenario in M seeded variations (seeds 0..M-1) instead of once",
    )
    ap.add_argument(
        "--variation-spec",
        type=json.loads,
        default=None,
        metavar="JSON",
        help="the variations to draw (SPEC 5.2.1 CreateEnv.variations); "
        f"default {json.dumps(BENCHMARK_VARIATIONS)}",
    )
    ap.add_argument("--json", default="", help="write the table and episodes to this JSON file")
    add_overrides_argument(ap, "config overrides (e.g. env_backend=remote)")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args(argv)

    if args.checkpoint:
        cfg, actor = load_checkpoint_actor(args.checkpoint, args.set, args.device)
        name = cfg.variant
    else:
        cfg = apply_overrides(TrainConfig(), [*args.set, f"device={args.device}"])
        actor, name = make_driver(args.driver, load_pool(cfg.scenario_pool or None)), args.driver
    result = evaluate_policy(cfg, actor, args.split, args.variations, args.variation_spec)
    pool = load_pool(cfg.scenario_pool or None)
    human = human_episodes(pool, split_indices(pool, args.split))
    rows = {name: result["summary"]}
    if args.variations <= 0:  # the record is the recorded scene's, not a variation's
        rows["human"] = summarize(human)
    print(format_table(rows))
    if args.variations > 0:
        eps = result["episodes"]
        cells = []
        for s in STATUSES:
            k = sum(e["status"] == s for e in eps)
            lo, hi = wilson(k, len(eps))
            cells.append(f"{s} {k}/{len(eps)} = {k / len(eps):.3f} [{lo:.3f}, {hi:.3f}]")
        print("Wilson 95 %: " + ", ".join(cells))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {
                    "checkpoint": args.checkpoint,
                    "driver": args.driver,
                    "split": args.split,
                    "variations": args.variations,
                    "variation_spec": args.variation_spec or BENCHMARK_VARIATIONS,
                    "table": rows,
                    "episodes": result["episodes"],
                    "human": human,
                },
                f,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
