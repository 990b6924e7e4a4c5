"""The paper's Table II from the runs of ``make table2`` (scripts/table2.sh).

    python -m sharedspace.paper.table2 --runs out/table2 [--json docs/table2.json]
        [--doc docs/RESULTS.md] [--set server_endpoint=...]

For every run folder ``{variant}-s{seed}`` with ``checkpoints/last.pt`` it evaluates the
checkpoint on every test scenario (cached in ``eval_test.json`` beside the checkpoints, keyed by
its frame count), then evaluates the scripted drivers and the first-step reachability against
the same server, scores the human driver, and writes:

- per variant: mean and sample standard deviation over seeds of every Table II column;
- pooled over seeds: success / collision / timeout counts with Wilson 95 % intervals;
- paired per-scenario comparisons of the variants (success averaged over seeds per scenario:
  mean difference with a bootstrap 95 % interval over scenarios, and an exact sign test);
- the scripted drivers, the human driver, the paper's rows;
- the scenarios whose goal is kinematically reachable (:func:`drivers.reachability`) and those
  where every extreme action collides on the first step (unavoidable collisions);
- a planner's bound (:func:`sharedspace.paper.planner.open_loop_search`): the test scenarios in
  which a cross-entropy search over open-loop action sequences finds a collision-free arrival;
- generalisation: the final checkpoints' success on the train split beside the test split;
- the learning curves (test-split evaluations logged while training, mean over seeds).

The JSON goes to ``--json``; with ``--doc`` the block between ``<!-- table2:begin -->`` and
``<!-- table2:end -->`` of that markdown file is replaced by the rendered tables.
"""

from __future__ import annotations

import csv
import gzip
import itertools
import json
import platform
import re
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sharedspace.cli import run_command
from sharedspace.episodes import summarize
from sharedspace.outcomes import STATUSES, mean_by_episode, outcome_rates
from sharedspace.paper.drivers import DRIVERS, make_driver, reachability
from sharedspace.paper.evaluate import COLUMNS, evaluate_policy, human_episodes
from sharedspace.paper.planner import open_loop_search, unavoidable_first_step
from sharedspace.pool import load_pool, split_indices
from sharedspace.stats import paired_clustered, sign_test
from sharedspace.train.checkpoint import read_checkpoint
from sharedspace.train.checkpoint import ship as ship_checkpoint
from sharedspace.train.config import add_overrides_argument, command_parser
from sharedspace.train.learners import load_checkpoint_actor
from sharedspace.train.networks import NETWORKS, UnknownNetwork, canonical_network, network_label
from sharedspace.world_config import WorldConfig

__all__ = ["main", "render", "ship"]

#: The paper's Table II (model.md section 9): success, collision, timeout, speed, jerk, max acc.
PAPER_ROWS = {
    "G-SAC-Cog (paper)": (0.94, 0.06, 0.0, 4.470, 0.524, 1.621),
    "G-SAC-NoCog (paper)": (0.83, 0.11, 0.06, None, None, None),
    "S-SAC (paper)": (0.78, 0.22, 0.0, None, None, None),
    "UAW-PCG (paper)": (0.83, 0.17, 0.0, None, None, None),
    "Human (paper)": (1.0, 0.0, 0.0, 2.924, 0.609, 4.240),
}


def _label(network: str) -> str:
    """A learned row's label: the paper's SAC label of the run folder's network."""
    return network_label(network, "sac")


def _network_order(name: str) -> int:
    """Rows in the registry's order (risk graph, uniform graph, MLP, then any other)."""
    try:
        return list(NETWORKS).index(canonical_network(name))
    except UnknownNetwork:
        return len(NETWORKS)


def find_runs(runs: Path) -> dict[str, dict[int, Path]]:
    """``{variant: {seed: run folder}}`` of the folders holding ``checkpoints/last.pt``."""
    out: dict[str, dict[int, Path]] = {}
    for ckpt in sorted(runs.glob("*-s*/checkpoints/last.pt")):
        m = re.fullmatch(r"(.+)-s(\d+)", ckpt.parent.parent.name)
        if m and _network_order(m.group(1)) < len(NETWORKS):
            out.setdefault(m.group(1), {})[int(m.group(2))] = ckpt.parent.parent
    return out


def evaluate_run(run: Path, overrides: Sequence[str], split: str = "test") -> dict[str, Any]:
    """The evaluation of ``run``'s last checkpoint on ``split`` (cached in
    ``eval_{split}.json`` per frame count)."""
    ckpt = run / "checkpoints" / "last.pt"
    frames = int(read_checkpoint(ckpt)["counters"]["frames"])
    cache = run / f"eval_{split}.json"
    if cache.exists():
        cached = json.loads(cache.read_text())
        fresh = all("reward_terms" in e for e in cached.get("episodes", []))
        if cached.get("frames") == frames and fresh:
            return cached
    cfg, actor = load_checkpoint_actor(str(ckpt), overrides)
    result = evaluate_policy(cfg.world, actor, split, seed=cfg.seed, driving=cfg.driving)
    out = {"frames": frames, **result}
    cache.write_text(json.dumps(out))
    return out


def variant_stats(per_seed: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """Mean and spread over seeds, pooled counts with Wilson intervals."""
    summaries = [r["summary"] for r in per_seed.values()]
    episodes = [e for r in per_seed.values() for e in r["episodes"]]
    stats: dict[str, Any] = {"seeds": sorted(per_seed), "frames": {}}
    stats["frames"] = {str(s): r["frames"] for s, r in per_seed.items()}
    for key, _ in COLUMNS:
        vals = np.array([s[key] for s in summaries], dtype=float)
        stats[key] = {
            "mean": float(vals.mean()),
            "std": float(vals.std(ddof=1)) if len(vals) > 1 else 0.0,
            "per_seed": vals.tolist(),
        }
    n = len(episodes)
    for status, rate in outcome_rates(episodes).items():
        stats[f"pooled_{status}"] = {
            "k": rate["count"],
            "n": n,
            "rate": rate["rate"],
            "wilson95": tuple(rate["ci95"]),
        }
    return stats


def per_scenario_success(per_seed: dict[int, dict[str, Any]]) -> dict[int, float]:
    """Scenario -> success averaged over seeds."""
    return mean_by_episode(
        (e for r in per_seed.values() for e in r["episodes"]),
        lambda e: int(e["scenario_index"]),
        lambda e: e["status"] == "success",
    )


def paired(a: dict[int, float], b: dict[int, float]) -> dict[str, Any]:
    """Per scenario ``a - b`` (success averaged over seeds): the mean and its 95 % interval
    resampling scenarios (:func:`sharedspace.stats.paired_clustered`, each scenario its own
    cluster), and the sign test over the scenarios."""
    common = sorted(set(a) & set(b))
    diffs = [a[i] - b[i] for i in common]
    wins = sum(d > 0 for d in diffs)
    losses = sum(d < 0 for d in diffs)
    interval = paired_clustered({(i, 0): a[i] for i in common}, {(i, 0): b[i] for i in common})
    return {
        "scenarios": len(common),
        "mean_diff": interval["diff"],
        "bootstrap95": (interval["lo"], interval["hi"]),
        "better": wins,
        "worse": losses,
        "tied": len(common) - wins - losses,
        "sign_test_p": sign_test(wins, losses),
    }


def reward_terms(episodes: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Mean over episodes of each reward term's sum along the episode (model.md 7)."""
    sums: dict[str, list[float]] = {}
    for e in episodes:
        for term, value in e.get("reward_terms", {}).items():
            sums.setdefault(term, []).append(value)
    return {term: float(np.mean(v)) for term, v in sums.items()}


def learning_curves(runs: dict[int, Path]) -> dict[str, dict[str, float]]:
    """``{frames: {metric: mean over seeds}}`` of the ``eval/`` metrics logged in training."""
    acc: dict[int, dict[str, list[float]]] = {}
    for run in runs.values():
        path = run / "metrics.csv"
        if not path.exists():
            continue
        with path.open() as f:
            for row in csv.DictReader(f):
                if row["metric"] in ("eval/success", "eval/collision", "eval/avg_speed"):
                    key = row["metric"].removeprefix("eval/")
                    acc.setdefault(int(row["frames"]), {}).setdefault(key, []).append(
                        float(row["value"])
                    )
    return {
        str(fr): {k: float(np.mean(v)) for k, v in m.items()} | {"runs": len(m["success"])}
        for fr, m in sorted(acc.items())
        if "success" in m
    }


def ship(
    runs: dict[str, dict[int, Path]], evaluated: dict, out: Path, budget: int = 0
) -> list[Path]:
    """Writes each run's policy as ``{variant}-s{seed}.pt`` (config, actor weights, counters:
    what ``evaluate --checkpoint`` loads, a few hundred kB) and its test-split record as
    ``{variant}-s{seed}.json`` (summary and per-scenario status) into ``out``, and the run's
    record (``config.json``, ``metrics.csv.gz``, ``eval_test.json``) into
    ``out/../runs/{variant}-s{seed}/`` (results/table2/README.md). Runs that have not reached
    ``budget`` frames are not shipped."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for variant, per_seed in runs.items():
        for seed, run in per_seed.items():
            if evaluated[variant][seed]["frames"] < budget:
                continue
            name = f"{variant}-s{seed}"
            ship_checkpoint(read_checkpoint(run / "checkpoints" / "last.pt"), out / f"{name}.pt")
            rec = evaluated[variant][seed]
            (out / f"{name}.json").write_text(
                json.dumps(
                    {
                        "frames": rec["frames"],
                        "summary": rec["summary"],
                        "status": {str(e["scenario_index"]): e["status"] for e in rec["episodes"]},
                    },
                    indent=1,
                )
            )
            record = out.parent / "runs" / name
            record.mkdir(parents=True, exist_ok=True)
            for file in ("config.json", "eval_test.json"):
                shutil.copyfile(run / file, record / file)
            # mtime=0: shipping the same run twice writes the same bytes.
            with (
                open(run / "metrics.csv", "rb") as src,
                gzip.GzipFile(record / "metrics.csv.gz", "wb", mtime=0) as dst,
            ):
                shutil.copyfileobj(src, dst)
            written.append(out / f"{name}.pt")
    return written


def _fmt(x: float | None, digits: int = 3) -> str:
    return "–" if x is None else f"{x:.{digits}f}"


def _seed_table(table: dict[str, Any]) -> list[str]:
    """Table II: mean ± sd over seeds, the scripted drivers, the human, the paper's rows."""
    lines: list[str] = []
    meta = table["meta"]
    lines.append(
        f"Generated by `make table2` on {meta['date']} ({meta['machine']}); runs in "
        f"`{meta['runs']}`; world parameters `{meta['params']}`; {meta['test_scenarios']} test "
        "scenarios, each played once per checkpoint with the deterministic policy."
    )
    lines.append("")
    head = "| Model | seeds | frames | Success | Collision | Timeout | Avg speed (m/s) | "
    head += "Avg \\|jerk\\| (m/s³) | Avg max \\|acc\\| (m/s²) |"
    lines += [head, "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for v, s in table["variants"].items():
        frames = sorted(set(s["frames"].values()))
        cells = [f"{s[c]['mean']:.3f} ± {s[c]['std']:.3f}" for c, _ in COLUMNS]
        lines.append(
            f"| {_label(v)} | {len(s['seeds'])} | "
            f"{'/'.join(str(f) for f in frames)} | " + " | ".join(cells) + " |"
        )
    for name, row in table["drivers"].items():
        lines.append(
            f"| scripted: {name} | – | – | " + " | ".join(_fmt(row[c]) for c, _ in COLUMNS) + " |"
        )
    h = table["human"]
    lines.append(
        "| Human driver (record) | – | – | " + " | ".join(_fmt(h[c]) for c, _ in COLUMNS) + " |"
    )
    for name, row in PAPER_ROWS.items():
        lines.append(f"| {name} | – | – | " + " | ".join(_fmt(x) for x in row) + " |")
    lines.append("")
    return lines


def _pooled_table(table: dict[str, Any]) -> list[str]:
    """Pooled over seeds, with Wilson intervals."""
    lines: list[str] = []
    lines.append(
        "Mean ± sample standard deviation over seeds. Pooled over seeds, with Wilson 95 %"
        " intervals:"
    )
    lines.append("")
    lines += ["| Model | Success | Collision | Timeout |", "|---|---|---|---|"]
    for v, s in table["variants"].items():
        cells = []
        for st in STATUSES:
            p = s[f"pooled_{st}"]
            lo, hi = p["wilson95"]
            cells.append(f"{p['k']}/{p['n']} = {p['rate']:.3f} [{lo:.3f}, {hi:.3f}]")
        lines.append(f"| {_label(v)} | " + " | ".join(cells) + " |")
    lines.append("")
    return lines


def _paired_table(table: dict[str, Any]) -> list[str]:
    """Paired per scenario, A − B."""
    lines: list[str] = []
    if table["paired"]:
        lines.append("Paired per scenario (success averaged over seeds, A − B):")
        lines.append("")
        lines += [
            "| A vs B | mean diff [bootstrap 95 %] | A better / worse / tied | sign test p |",
            "|---|---|---|---|",
        ]
        for key, p in table["paired"].items():
            a, b = key.split(" vs ")
            lo, hi = p["bootstrap95"]
            lines.append(
                f"| {_label(a)} vs {_label(b)} | "
                f"{p['mean_diff']:+.3f} [{lo:+.3f}, {hi:+.3f}] | "
                f"{p['better']} / {p['worse']} / {p['tied']} | {p['sign_test_p']:.3f} |"
            )
        lines.append("")
    return lines


def _reward_terms_table(table: dict[str, Any]) -> list[str]:
    """Each reward term's sum along the test episodes."""
    lines: list[str] = []
    if table["reward_terms"]:
        names = sorted({t for row in table["reward_terms"].values() for t in row})
        lines.append("Reward terms along the test episodes (mean per episode of each term's sum):")
        lines.append("")
        lines += ["| Model | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
        for who, row in table["reward_terms"].items():
            lines.append(
                f"| {who} | " + " | ".join(f"{row.get(t, 0.0):+.2f}" for t in names) + " |"
            )
        lines.append("")
    return lines


def _failing_table(table: dict[str, Any]) -> tuple[list[str], dict[str, Any]]:
    """The test scenarios a learned policy or the replayed human failed, and the table."""
    lines: list[str] = []
    learned = {_label(v) for v in table["variants"]} | {"human_replay"}
    failing = {
        name: row
        for name, row in sorted(table["outcomes"].items())
        if any(ch != "s" for who, chs in row.items() if who in learned for ch in chs)
    }
    if failing:
        whos = list(next(iter(failing.values())))
        lines.append(
            "Test scenarios where a learned policy or the replayed human driver failed (s "
            "success, c collision, t timeout; a learned variant has one letter per seed):"
        )
        lines.append("")
        lines += ["| scenario | " + " | ".join(whos) + " |", "|---|" + "---|" * len(whos)]
        for name, row in failing.items():
            lines.append(f"| {name} | " + " | ".join(row.get(w, "") for w in whos) + " |")
        lines.append("")
    return lines, failing


def _reachability_note(table: dict[str, Any]) -> list[str]:
    """What any policy can reach: reachability and unavoidable scenes."""
    lines: list[str] = []
    reach = table["reachability"]
    n_reach = sum(r["reachable"] for r in reach)
    lines.append(
        f"Reachability: the goal is kinematically reachable within the horizon in {n_reach} of "
        f"{len(reach)} test scenarios (pursuit law without pedestrians, model.md limits). "
        f"Unavoidable: in {len(table['unavoidable_first_step'])} test scenario(s) "
        f"({', '.join(table['unavoidable_names']) or 'none'}) every action of "
        "{-1, 0, 1}² collides on the first step, so success is at most "
        f"{table['success_ceiling']:.3f} and collision at least "
        f"{1 - table['success_ceiling']:.3f} for any policy."
    )
    return lines


def _planner_note(table: dict[str, Any], failing: dict[str, Any]) -> list[str]:
    """The planner's bound, and the failed scenes it solved."""
    lines: list[str] = []
    planner = table.get("planner") or {}
    if planner:
        solved = [name for name, r in planner.items() if r.get("replayed") == "success"]
        unsolved = sorted(set(planner) - set(solved))
        per = next(iter(planner.values()))["candidates"]
        lines.append("")
        lines.append(
            f"Planner: a cross-entropy search over open-loop action sequences ({per} per "
            "scenario, `open_loop_search`) finds a collision-free arrival, confirmed by "
            "replaying it in a fresh env, in "
            f"{len(solved)} of {len(planner)} test scenarios, so success "
            f"{len(solved) / len(planner):.3f} is reachable on this extraction in this world"
            + (f"; none found in {', '.join(unsolved)}." if unsolved else ".")
        )
        hard = {n: r for n, r in planner.items() if n in failing}
        if hard:
            lines.append("")
            lines += [
                "| scenario | sequences | success | collision | timeout | fewest steps |",
                "|---|---:|---:|---:|---:|---:|",
            ]
            for name, r in hard.items():
                lines.append(
                    f"| {name} | {r['candidates']} | {r['success']} | {r['collision']} | "
                    f"{r['timeout']} | {r['best_steps'] if r['best_steps'] else '–'} |"
                )
    return lines


def _generalisation_table(table: dict[str, Any]) -> list[str]:
    """The final checkpoints on the train and the test split."""
    lines: list[str] = []
    general = table.get("generalisation") or {}
    if general:
        lines.append("")
        lines.append(
            "Generalisation: the same final checkpoints on the train split (the scenarios they "
            "were trained on) and on the test split (mean ± sd over seeds):"
        )
        lines.append("")
        lines += [
            "| Model | train success | train collision | test success | test collision |",
            "|---|---:|---:|---:|---:|",
        ]
        for v, g in general.items():
            cells = [
                f"{g[split][c]['mean']:.3f} ± {g[split][c]['std']:.3f}"
                for split in ("train", "test")
                for c in ("success", "collision")
            ]
            lines.append(f"| {_label(v)} | " + " | ".join(cells) + " |")
    return lines


def _curves_table(table: dict[str, Any]) -> list[str]:
    """Test success logged during training, mean over seeds."""
    lines: list[str] = []
    curves = table["learning_curves"]
    if curves:
        lines.append("")
        lines.append(
            "Learning curves (test-split success logged during training, mean over seeds):"
        )
        lines.append("")
        frames = sorted({int(f) for c in curves.values() for f in c}, key=int)
        lines.append("| Model | " + " | ".join(f"{f // 1000}k" for f in frames) + " |")
        lines.append("|---|" + "---:|" * len(frames))
        for v, c in curves.items():
            cells = [f"{c[str(f)]['success']:.2f}" if str(f) in c else "–" for f in frames]
            lines.append(f"| {_label(v)} | " + " | ".join(cells) + " |")
    return lines


def render(table: dict[str, Any]) -> str:
    """The markdown block of docs/RESULTS.md."""
    failing_lines, failing = _failing_table(table)
    sections = [
        _seed_table(table),
        _pooled_table(table),
        _paired_table(table),
        _reward_terms_table(table),
        failing_lines,
        _reachability_note(table),
        _planner_note(table, failing),
        _generalisation_table(table),
        _curves_table(table),
    ]
    return "\n".join(line for lines in sections for line in lines)


def replace_block(doc: Path, body: str) -> None:
    text = doc.read_text()
    begin, end = "<!-- table2:begin -->", "<!-- table2:end -->"
    if begin not in text or end not in text:
        raise SystemExit(f"{doc} has no {begin} ... {end} block")
    i, j = text.index(begin) + len(begin), text.index(end)
    doc.write_text(text[:i] + "\n" + body + "\n" + text[j:])


def make_parser():
    """The command's arguments."""
    ap = command_parser("python -m sharedspace.paper.table2", __doc__)
    ap.add_argument("--runs", required=True, help="folder of {variant}-s{seed} run folders")
    ap.add_argument("--json", default="", help="write the table here")
    ap.add_argument("--doc", default="", help="markdown file with a table2 block to rewrite")
    ap.add_argument("--params", default="", help="world-parameter file the server ran with")
    ap.add_argument("--frames", type=int, default=0, help="the budget per run (reported)")
    ap.add_argument(
        "--ship", default="", help="write each run's policy (actor + config) into this folder"
    )
    ap.add_argument(
        "--search-rounds",
        type=int,
        default=8,
        help="rounds of the open-loop planner search per test scenario (0 = none)",
    )
    ap.add_argument(
        "--search-per-round",
        type=int,
        default=48,
        help="action sequences per scenario and round of the planner search",
    )
    add_overrides_argument(ap, "world keys (server_endpoint=... max_agents=...)")
    return ap


def _scripted(world: WorldConfig, pool: list[dict[str, Any]], outcomes: dict) -> tuple[dict, dict]:
    """Every scripted driver on the test split: its summary and reward terms; each episode's
    status goes into ``outcomes`` (scenario name -> who -> statuses)."""
    drivers, terms = {}, {}
    for name in [*DRIVERS, "human_replay"]:
        result = evaluate_policy(world, make_driver(name, pool), "test")
        drivers[name] = result["summary"]
        terms[f"scripted: {name}"] = reward_terms(result["episodes"])
        for e in result["episodes"]:
            outcomes.setdefault(pool[e["scenario_index"]]["name"], {})[name] = e["status"][0]
    return drivers, terms


def _learned_outcomes(evaluated: dict, pool: list[dict[str, Any]], outcomes: dict, terms: dict):
    """Each learned variant's statuses per scenario (a letter per seed) into ``outcomes``, its
    reward terms into ``terms``."""
    for v, per in evaluated.items():
        key = _label(v)
        for seed in sorted(per):
            for e in per[seed]["episodes"]:
                row = outcomes.setdefault(pool[e["scenario_index"]]["name"], {})
                row[key] = row.get(key, "") + e["status"][0]
        terms[key] = reward_terms([e for r in per.values() for e in r["episodes"]])


def _per_run(evaluated: dict) -> dict:
    """Each run's frames, summary and episodes (the columns an analysis reads)."""
    keep = ("scenario_index", "status", "avg_speed", "steps")
    return {
        v: {
            str(s): {
                "frames": r["frames"],
                "summary": r["summary"],
                "episodes": [{k: e[k] for k in keep} for e in r["episodes"]],
            }
            for s, r in per.items()
        }
        for v, per in evaluated.items()
    }


def tabulate(args, runs: dict) -> tuple[dict[str, Any], dict]:
    """The whole table of the runs (every variant, driver, bound and analysis), and each run's
    evaluation."""
    t0 = time.time()
    world = WorldConfig.from_words(args.set)
    pool = load_pool(world.scenario_pool or None)
    test = split_indices(pool, "test")
    evaluated = {
        v: {s: evaluate_run(p, args.set) for s, p in sorted(r.items())} for v, r in runs.items()
    }
    variants = {v: variant_stats(evaluated[v]) for v in sorted(evaluated, key=_network_order)}
    success = {v: per_scenario_success(evaluated[v]) for v in variants}
    outcomes: dict[str, dict[str, str]] = {}
    drivers, terms = _scripted(world, pool, outcomes)
    _learned_outcomes(evaluated, pool, outcomes, terms)
    unavoidable = unavoidable_first_step(world)
    planner = (
        open_loop_search(world, rounds=args.search_rounds, per_round=args.search_per_round)
        if args.search_rounds > 0
        else {}
    )
    on_train = {
        v: {s: evaluate_run(p, args.set, "train") for s, p in sorted(r.items())}
        for v, r in runs.items()
    }
    table = {
        "meta": {
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": f"{platform.machine()}, {platform.processor() or 'cpu'}",
            "runs": args.runs,
            "params": args.params,
            "budget_frames": args.frames,
            "test_scenarios": len(test),
            "tabulation_s": None,
        },
        "variants": variants,
        "per_run": _per_run(evaluated),
        "paired": {
            f"{a} vs {b}": paired(success[a], success[b])
            for a, b in itertools.combinations(list(variants), 2)
        },
        "drivers": drivers,
        "reward_terms": terms,
        "outcomes": outcomes,
        "human": summarize(human_episodes(pool, test)),
        "paper": {
            k: dict(zip([c for c, _ in COLUMNS], row, strict=True)) for k, row in PAPER_ROWS.items()
        },
        "reachability": reachability([pool[i] for i in test]),
        "unavoidable_first_step": unavoidable,
        "unavoidable_names": [pool[i]["name"] for i in unavoidable],
        "success_ceiling": 1 - len(unavoidable) / len(test),
        "planner": planner,
        "generalisation": {
            v: {
                split: {c: stats[c] for c in ("success", "collision")}
                for split, stats in (("train", variant_stats(on_train[v])), ("test", variants[v]))
            }
            for v in variants
        },
        "learning_curves": {v: learning_curves(runs[v]) for v in variants},
    }
    table["meta"]["tabulation_s"] = round(time.time() - t0, 1)
    return table, evaluated


def main(argv: Sequence[str] | None = None) -> int:
    args = make_parser().parse_args(argv)
    runs = find_runs(Path(args.runs))
    if not runs:
        raise SystemExit(f"no runs with checkpoints/last.pt under {args.runs}")
    table, evaluated = tabulate(args, runs)
    text = render(table)
    print(text)
    if args.json:
        Path(args.json).write_text(json.dumps(table, indent=1))
    if args.doc:
        replace_block(Path(args.doc), text)
    if args.ship:
        for path in ship(runs, evaluated, Path(args.ship), args.frames):
            print(f"shipped {path}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
