"""The powered test (docs/RESULTS.md, "Table II on seeded variations"): policies and scripted
drivers played on the same seeded variations of every test scene, with Wilson intervals and
paired, scene-clustered comparisons.

    python -m sharedspace.paper.powered --policies results/table2/policies \\
        --drivers pursuit_3 pursuit_5 hold stop --variations 32 \\
        --json docs/table2_variations.json --markdown out/powered.md

    python -m sharedspace.paper.powered --from-json docs/table2_variations.json --by-m 8,16,32

Every policy plays variation ``j`` (seed ``j``,
:func:`sharedspace.train.evaluation.play_variations`) of every test scene, so two policies' outcomes
pair up episode by episode. A variant's seeds pool: its outcome in an episode is the mean over its
seeds. A comparison ``A - B`` is the mean paired difference with two 95 % bootstrap intervals
(:func:`sharedspace.stats.paired_clustered`): one that resamples whole scenes (the episodes of one
scene are not independent; this is the interval for scenes like these, and more variations cannot
narrow it below what the scenes disagree by), and one that holds the test scenes fixed (how sure the
mean over these scenes' variations is).
``--by-m`` gives both half-widths for the first M variations of a run, to choose M. With no
``--set server_endpoint=...`` a local server is started with ``--params`` (the Table II world,
``params/table2.json5``, by default).
"""

from __future__ import annotations

import itertools
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sharedspace.cli import run_command
from sharedspace.outcomes import BENCHMARK_VARIATIONS, STATUSES, mean_by_episode, outcome_rates
from sharedspace.paper.drivers import DRIVERS, make_driver
from sharedspace.stats import paired_clustered, wilson
from sharedspace.train.config import add_overrides_argument, command_parser
from sharedspace.train.evaluation import play_variations
from sharedspace.train.learners import load_checkpoint_actor
from sharedspace.train.networks import network_label
from sharedspace.world_config import WorldConfig

__all__ = ["LABELS", "group_table", "comparisons", "label", "render", "main"]


def label(name: str) -> str:
    """A row's label: a driver's from :data:`LABELS`, a learned network's the paper's SAC
    label (:func:`sharedspace.train.networks.network_label`), else the name."""
    return LABELS.get(name) or network_label(name, "sac")


#: Row labels of the drivers (a learned row's is its network's, :func:`label`).
LABELS = {
    "car_aware": "car_aware (script)",
    "bc_script": "BC-script (cloned car_aware)",
    "pursuit_3": "pursuit_3 (script)",
    "pursuit_5": "pursuit_5 (script)",
    "hold": "hold (script)",
    "stop": "stop (script)",
}


def outcome_by_episode(
    episodes: Sequence[dict[str, Any]], status: str
) -> dict[tuple[int, int], float]:
    """``{(scene, variation): 1.0 if the episode ended in status else 0.0}``."""
    return {
        (int(e["scenario_index"]), int(e["variation"])): float(e["status"] == status)
        for e in episodes
    }


def pooled(runs: dict[str, list[dict[str, Any]]], status: str) -> dict[tuple[int, int], float]:
    """A group's outcome per episode: the mean over its runs (seeds) that played it."""
    return mean_by_episode(
        (e for episodes in runs.values() for e in episodes),
        lambda e: (int(e["scenario_index"]), int(e["variation"])),
        lambda e: e["status"] == status,
    )


def group_table(groups: dict[str, dict[str, list[dict[str, Any]]]]) -> dict[str, dict[str, Any]]:
    """Per group: episodes, each status's pooled rate with its Wilson interval, and each run's
    (seed's) success."""
    out = {}
    for name, runs in groups.items():
        eps = [e for episodes in runs.values() for e in episodes]
        n = len(eps)
        row: dict[str, Any] = {"episodes": n, "runs": {}}
        for s, rate in outcome_rates(eps).items():
            row[s] = rate["rate"]
            row[f"{s}_ci"] = tuple(rate["ci95"])
        for run, episodes in runs.items():
            m = len(episodes)
            row["runs"][run] = {
                s: (sum(e["status"] == s for e in episodes) / m if m else 0.0) for s in STATUSES
            }
        out[name] = row
    return out


def comparisons(
    groups: dict[str, dict[str, list[dict[str, Any]]]], pairs: Sequence[tuple[str, str]]
) -> list[dict[str, Any]]:
    """``A - B`` for each pair: success and collision, paired by episode, clustered by
    scene."""
    out = []
    for a, b in pairs:
        row: dict[str, Any] = {"a": a, "b": b}
        for s in ("success", "collision"):
            row[s] = paired_clustered(pooled(groups[a], s), pooled(groups[b], s))
        out.append(row)
    return out


def default_pairs(names: Sequence[str]) -> list[tuple[str, str]]:
    """Every learned variant against each other, and each against every scripted driver."""
    learned = [n for n in names if n not in DRIVERS]
    scripted = [n for n in names if n in DRIVERS]
    return list(itertools.combinations(learned, 2)) + [(a, b) for a in learned for b in scripted]


def _ci(ci: Sequence[float]) -> str:
    return f"[{ci[0]:.3f}, {ci[1]:.3f}]"


def render(result: dict[str, Any]) -> str:
    """The two markdown tables: rates with Wilson intervals, and the paired comparisons."""
    table, meta = result["table"], result["meta"]
    lines = [
        f"{meta['variations']} variations of each of the {meta['scenes']} test scenes "
        f"({meta['scenes'] * meta['variations']} episodes per run), variations "
        f"`{json.dumps(meta['spec'])}`, seeds 0..{meta['variations'] - 1}.",
        "",
        "| policy | runs | episodes | success [Wilson 95 %] | collision | timeout "
        "| success per run |",
        "|---|---:|---:|---|---|---|---|",
    ]
    for name, row in table.items():
        runs = " / ".join(f"{r['success']:.3f}" for r in row["runs"].values())
        lines.append(
            f"| {label(name)} | {len(row['runs'])} | {row['episodes']} "
            f"| {row['success']:.3f} {_ci(row['success_ci'])} "
            f"| {row['collision']:.3f} {_ci(row['collision_ci'])} "
            f"| {row['timeout']:.3f} {_ci(row['timeout_ci'])} | {runs} |"
        )
    planner = result.get("planner")
    if planner:
        lines.append(
            f"| planner bound (open-loop search, variations 0..{planner['variations'] - 1}) "
            f"| – | {planner['cells']} | {planner['bound']:.3f} {_ci(planner['bound_ci'])} "
            "| – | – | – |"
        )
    lines += [
        "",
        "| A − B | success diff | 95 %, scenes resampled (half-width) "
        "| 95 %, scenes fixed (half-width) | collision diff [95 %, scenes resampled] |",
        "|---|---:|---|---|---|",
    ]
    for c in result["comparisons"]:
        s, col = c["success"], c["collision"]
        lines.append(
            f"| {label(c['a'])} − {label(c['b'])} "
            f"| {s['diff']:+.3f} | [{s['lo']:+.3f}, {s['hi']:+.3f}] ({s['half_width']:.3f}) "
            f"| [{s['lo_fixed']:+.3f}, {s['hi_fixed']:+.3f}] ({s['half_width_fixed']:.3f}) "
            f"| {col['diff']:+.3f} [{col['lo']:+.3f}, {col['hi']:+.3f}] |"
        )
    return "\n".join(lines) + "\n"


def by_m(
    groups: dict[str, dict[str, list[dict[str, Any]]]],
    pairs: Sequence[tuple[str, str]],
    ms: Sequence[int],
) -> str:
    """A markdown table of each pair's success half-widths (scenes resampled / fixed) on the
    first M variations, for each M."""
    lines = [
        "| A − B | " + " | ".join(f"M = {m}" for m in ms) + " |",
        "|---|" + "---:|" * len(ms),
    ]
    for a, b in pairs:
        cells = []
        for m in ms:
            sub = {
                g: {r: [e for e in eps if int(e["variation"]) < m] for r, eps in runs.items()}
                for g, runs in groups.items()
                if g in (a, b)
            }
            c = paired_clustered(pooled(sub[a], "success"), pooled(sub[b], "success"))
            cells.append(f"{c['diff']:+.3f} ± {c['half_width']:.3f} / {c['half_width_fixed']:.3f}")
        lines.append(f"| {label(a)} − {label(b)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def checkpoints_of(paths: Sequence[str]) -> list[tuple[str | None, Path]]:
    """``(group, checkpoint)`` for the ``.pt`` files named, or inside the folders named, sorted;
    an entry ``GROUP=PATH`` puts its checkpoints in that group (default: their variant)."""
    out: list[tuple[str | None, Path]] = []
    for entry in paths:
        group, _, path = entry.rpartition("=") if "=" in entry else (None, "", entry)
        p = Path(path)
        out += [(group or None, c) for c in (sorted(p.glob("*.pt")) if p.is_dir() else [p])]
    return out


def make_parser():
    """The command's arguments."""
    ap = command_parser("python -m sharedspace.paper.powered", __doc__)
    ap.add_argument(
        "--policies",
        nargs="*",
        default=[],
        help="checkpoints or folders of them, each optionally as GROUP=PATH (default group: "
        "the checkpoint's variant; a group's runs pool)",
    )
    ap.add_argument(
        "--drivers", nargs="*", default=[], choices=sorted(DRIVERS), help="scripted drivers"
    )
    ap.add_argument("--variations", type=int, default=32, metavar="M")
    ap.add_argument(
        "--variation-spec",
        type=json.loads,
        default=None,
        metavar="JSON",
        help=f"SPEC 5.2.1 CreateEnv.variations; default {json.dumps(BENCHMARK_VARIATIONS)}",
    )
    ap.add_argument("--split", default="test")
    ap.add_argument(
        "--pool",
        default="",
        help="a scenario file to play (served by the local server; e.g. a validation pool of "
        "sharedspace.paper.pools) instead of the checkpoints' own pool",
    )
    ap.add_argument(
        "--params",
        default="params/table2.json5",
        help="world parameters of the local server (when no server_endpoint is set)",
    )
    ap.add_argument(
        "--planner",
        type=int,
        default=0,
        metavar="MP",
        help="also run the open-loop planner search (planner.open_loop_search) on the first MP "
        "variations of every scene: the share it solves bounds what any driver can reach",
    )
    ap.add_argument("--planner-rounds", type=int, default=6)
    ap.add_argument("--planner-per-round", type=int, default=24)
    ap.add_argument("--json", default="", help="write every episode and the tables here")
    ap.add_argument(
        "--from-json",
        default="",
        help="analyse the episodes of an earlier --json instead of playing (no server)",
    )
    ap.add_argument(
        "--by-m",
        default="",
        metavar="M1,M2,...",
        help="also tabulate each comparison's half-widths on the first M variations",
    )
    ap.add_argument("--markdown", default="", help="write the two tables here")
    add_overrides_argument(ap, "world keys of every evaluation (e.g. server_endpoint=)")
    return ap


def _analyse_saved(path: str, ms: list[int]) -> None:
    """The tables of the episodes of an earlier ``--json``."""
    saved = json.loads(Path(path).read_text())
    groups = saved["episodes"]
    result = {
        **saved,
        "table": group_table(groups),
        "comparisons": comparisons(groups, default_pairs(list(groups))),
    }
    result.pop("episodes")
    print(render(result))
    if ms:
        print(by_m(groups, default_pairs(list(groups)), ms))


def _play_groups(args, overrides: list[str], spec: dict[str, Any]) -> dict[str, Any]:
    """Every policy's and driver's episodes on the variations, by group and run."""
    groups: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for group, path in checkpoints_of(args.policies):
        cfg, actor = load_checkpoint_actor(str(path), overrides)
        t0 = time.perf_counter()
        eps = play_variations(
            cfg.world,
            actor,
            args.variations,
            args.split,
            spec,
            seed=cfg.seed,
            driving=cfg.driving,
        )
        run = f"{path.parent.parent.name}/{path.stem}" if group else path.stem
        groups.setdefault(group or cfg.net.network, {})[run] = eps
        ok = sum(e["status"] == "success" for e in eps) / len(eps)
        print(f"{run}: success {ok:.3f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    world = WorldConfig.from_words(overrides)
    for name in args.drivers:
        eps = play_variations(
            world,
            None,
            args.variations,
            args.split,
            spec,
            fresh_policy=lambda n=name: make_driver(n),
        )
        groups[name] = {name: eps}
        ok = sum(e["status"] == "success" for e in eps) / len(eps)
        print(f"{name}: success {ok:.3f}", flush=True)
    return groups


def _planner_bound(args, overrides: list[str], spec: dict[str, Any]) -> dict[str, Any]:
    """The open-loop search on the first ``args.planner`` variations of every scene."""
    from sharedspace.paper.planner import open_loop_search

    t0 = time.perf_counter()
    found = open_loop_search(
        WorldConfig.from_words(overrides),
        rounds=args.planner_rounds,
        per_round=args.planner_per_round,
        variations=args.planner,
        spec=spec,
    )
    solved = sum(r.get("replayed") == "success" for r in found.values())
    print(f"planner bound: {solved} of {len(found)} solved", flush=True)
    return {
        "variations": args.planner,
        "rounds": args.planner_rounds,
        "per_round": args.planner_per_round,
        "cells": len(found),
        "solved": solved,
        "bound": solved / len(found) if found else 0.0,
        "bound_ci": wilson(solved, len(found)),
        "unsolved": sorted(n for n, r in found.items() if r.get("replayed") != "success"),
        "wall_s": round(time.perf_counter() - t0, 1),
    }


def _slim(groups: dict[str, Any]) -> dict[str, Any]:
    """The episodes as ``--json`` keeps them: what an analysis reads, no traces."""
    keep = ("scenario_index", "variation", "status", "steps")
    return {
        name: {run: [{k: e[k] for k in keep} for e in eps] for run, eps in runs.items()}
        for name, runs in groups.items()
    }


def main(argv: Sequence[str] | None = None) -> int:
    ap = make_parser()
    args = ap.parse_args(argv)
    if args.variations < 1:
        ap.error("--variations must be at least 1")
    spec = dict(args.variation_spec or BENCHMARK_VARIATIONS)
    ms = [int(m) for m in args.by_m.split(",") if m.strip()]
    if args.from_json:
        _analyse_saved(args.from_json, ms)
        return 0

    server = None
    overrides = list(args.set)
    if not any(o.startswith("server_endpoint=") and o.split("=", 1)[1] for o in overrides):
        from sharedspace.local_server import LocalServer

        cfg_lines = [f"params:{json.dumps(args.params)}"]
        if args.pool:
            cfg_lines.append(f"pools:{json.dumps([args.pool])}")
        server = LocalServer(cfg=cfg_lines)
        overrides.append(f"server_endpoint={server.endpoint}")
    if args.pool:
        overrides.append(f"scenario_pool={args.pool}")
    started = time.perf_counter()
    try:
        groups = _play_groups(args, overrides, spec)
        planner = _planner_bound(args, overrides, spec) if args.planner > 0 else None
    finally:
        if server is not None:
            server.close()
    scenes = {e["scenario_index"] for runs in groups.values() for r in runs.values() for e in r}
    result = {
        "meta": {
            "variations": args.variations,
            "spec": spec,
            "split": args.split,
            "scenes": len(scenes),
            "params": args.params if server is not None else None,
            "wall_s": round(time.perf_counter() - started, 1),
        },
        "table": group_table(groups),
        "comparisons": comparisons(groups, default_pairs(list(groups))),
        "planner": planner,
    }
    text = render(result)
    if ms:
        text += "\n" + by_m(groups, default_pairs(list(groups)), ms)
    print(text)
    if args.markdown:
        Path(args.markdown).write_text(text)
    if args.json:
        Path(args.json).write_text(json.dumps({**result, "episodes": _slim(groups)}))
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
