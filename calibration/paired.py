"""Paired per-scenario comparison of the pedestrian models of Table I (docs/RESULTS.md).

    python -m calibration.paired --table docs/table1.json

For each pair of models (A, B) over the scenarios of the evaluated split: the mean of the
per-scenario differences A − B of ADE and of FDE with a bootstrap 95 % interval (10 000
resamples of the scenarios, seed 0), how many scenarios A is better / worse on, the exact
sign-test p-value, and each model's collisions with a Wilson 95 % interval. Prints markdown.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

from sharedspace.models import LABELS, SOCIAL_FORCE_MODELS
from sharedspace.stats import paired_bootstrap, sign_test, wilson

NAMES = LABELS


def compare(table: dict, a: str, b: str, metric: str) -> dict:
    sa = {s["name"]: s[metric] for s in table["models"][a]["scenarios"]}
    sb = {s["name"]: s[metric] for s in table["models"][b]["scenarios"]}
    names = sorted(set(sa) & set(sb))
    diffs = [sa[n] - sb[n] for n in names]
    better = sum(d < 0 for d in diffs)  # lower error is better
    worse = sum(d > 0 for d in diffs)
    return {
        "scenarios": len(names),
        "mean_diff": sum(diffs) / len(diffs) if diffs else 0.0,
        "bootstrap95": paired_bootstrap(diffs),
        "better": better,
        "worse": worse,
        "sign_test_p": sign_test(better, worse),
    }


def render(table: dict, models: list[str]) -> str:
    lines = [
        f"Paired per scenario, split `{table['split']}` (A − B; negative = A closer to the record):",
        "",
        "| A vs B | ΔADE (m) [bootstrap 95 %] | A better / worse | p | ΔFDE (m) [bootstrap 95 %] "
        "| A better / worse | p |",
        "|---|---|---|---|---|---|---|",
    ]
    for a, b in itertools.combinations(models, 2):
        a, b = b, a  # the later (richer) model first
        cells = []
        for metric in ("ade", "fde"):
            c = compare(table, a, b, metric)
            lo, hi = c["bootstrap95"]
            cells += [
                f"{c['mean_diff']:+.4f} [{lo:+.4f}, {hi:+.4f}]",
                f"{c['better']} / {c['worse']}",
                f"{c['sign_test_p']:.3f}",
            ]
        lines.append(f"| {NAMES.get(a, a)} vs {NAMES.get(b, b)} | " + " | ".join(cells) + " |")
    lines += ["", "| model | collisions | Wilson 95 % |", "|---|---|---|"]
    for m in models:
        sc = table["models"][m]["scenarios"]
        k = sum(bool(s["collided"]) for s in sc)
        lo, hi = wilson(k, len(sc))
        lines.append(f"| {NAMES.get(m, m)} | {k}/{len(sc)} | [{lo:.3f}, {hi:.3f}] |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--table", default="docs/table1.json", help="sim-server eval-peds --out JSON")
    ap.add_argument("--models", default=",".join(SOCIAL_FORCE_MODELS), help="models to compare, in order")
    args = ap.parse_args(argv)
    table = json.loads(Path(args.table).read_text())
    print(render(table, args.models.split(",")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
