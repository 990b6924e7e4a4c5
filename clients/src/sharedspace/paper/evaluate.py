"""Scores a checkpoint on a split: the paper's Table II columns, plus the recorded human driver.

    python -m sharedspace.paper.evaluate --checkpoint runs/x/checkpoints/last.pt --split test
        [--json out.json] [--traces traces.json] [--set key=value ...]
    python -m sharedspace.paper.evaluate --driver pursuit_3 ...   # a scripted reference driver
    python -m sharedspace.paper.evaluate --checkpoint ... --variations 32   # the powered test

Every scenario of the split is played once with the deterministic policy (the TanhNormal's
mode) in a batched env with one sub-env per scenario (``scenario_order="sequential"``). The human
row scores the scenario's recorded ego speeds with the same metric definitions
(``EpisodeMetrics::from_speeds``; every recorded episode counts as a success).

With ``--variations M`` every scenario is played in M seeded scene variations instead (SPEC
5.2.1; the spec is ``--variation-spec``, by default the benchmark's: pedestrians moved by
N(0, 0.25 m), started up to a step earlier or later, desired speeds within +-10 %). Variation
``j`` of every scene is the variation of seed ``j``, for every policy and driver, so results
of two policies are paired episode by episode (:mod:`sharedspace.paper.powered` compares them);
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

from sharedspace.cli import run_command
from sharedspace.episodes import summarize
from sharedspace.outcomes import BENCHMARK_VARIATIONS, outcome_rates
from sharedspace.paper.drivers import DRIVERS, make_driver
from sharedspace.pool import load_pool, recorded_headings
from sharedspace.train.config import add_overrides_argument, command_parser
from sharedspace.train.envs import Driving
from sharedspace.train.evaluation import evaluate_split, play_variations
from sharedspace.train.learners import load_checkpoint_actor
from sharedspace.train.networks import network_label
from sharedspace.world_config import WorldConfig

__all__ = ["COLUMNS", "human_episodes", "format_table", "evaluate_policy", "main"]

#: Table II columns: (key, header).
COLUMNS = (
    ("success", "Success"),
    ("collision", "Collision"),
    ("timeout", "Timeout"),
    ("avg_speed", "Avg speed (m/s)"),
    ("avg_abs_jerk", "Avg |jerk| (m/s^3)"),
    ("max_abs_acc", "Avg max |acc| (m/s^2)"),
)


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


def evaluate_policy(
    world: WorldConfig,
    actor,
    split: str = "test",
    variations: int = 0,
    spec: dict[str, Any] | None = None,
    seed: int = 0,
    driving: Driving = Driving(),  # noqa: B008 - frozen
) -> dict[str, Any]:
    """Plays every scenario of ``split`` of ``world`` once (or in ``variations`` seeded
    variations, :func:`play_variations`), envs seeded ``seed``, ``actor`` driving as
    ``driving`` says; returns per-episode records and the summary."""
    if variations <= 0:
        return evaluate_split(world, actor, split, seed, driving)
    episodes = play_variations(world, actor, variations, split, spec, seed=seed, driving=driving)
    return {"episodes": episodes, "summary": summarize(episodes)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.paper.evaluate", __doc__)
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--checkpoint", help="checkpoint .pt written by the trainer")
    who.add_argument(
        "--driver",
        choices=sorted([*DRIVERS, "human_replay"]),
        help="a scripted reference driver instead of a checkpoint (sharedspace.paper.drivers)",
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
    add_overrides_argument(ap, "world keys (e.g. server_endpoint=...)")
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args(argv)

    if args.checkpoint:
        cfg, actor = load_checkpoint_actor(args.checkpoint, args.set, args.device)
        name = network_label(cfg.net.network, cfg.algorithm)
        world, seed, driving = cfg.world, cfg.seed, cfg.driving
    else:
        world, seed, driving = WorldConfig.from_words(args.set), 0, Driving()
        actor, name = make_driver(args.driver, load_pool(world.scenario_pool or None)), args.driver
    result = evaluate_policy(
        world, actor, args.split, args.variations, args.variation_spec, seed, driving
    )
    human = human_episodes(world.pool_scenes(), world.scene_indices(args.split))
    rows = {name: result["summary"]}
    if args.variations <= 0:  # the record is the recorded scene's, not a variation's
        rows["human"] = summarize(human)
    print(format_table(rows))
    if args.variations > 0:
        eps = result["episodes"]
        cells = []
        for s, rate in outcome_rates(eps).items():
            lo, hi = rate["ci95"]
            share = f"{rate['count']}/{len(eps)} = {rate['rate']:.3f}"
            cells.append(f"{s} {share} [{lo:.3f}, {hi:.3f}]")
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
    sys.exit(run_command(main))
