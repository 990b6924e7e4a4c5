"""Who hits a car that stops at the start of every scene (issue "Traffic that reacts").

    python benchmarks/stopped_ego.py --pool embedded:hbs-general --split test \
        --params params/table2.json5 --vehicles idm

Rolls out every scene of the split with the ego braking to a stop (``--av=-1,0``) and reports,
per scene, the first collision of the ego: with a car or a pedestrian, and when. Uses the release
``sim-server`` (``cargo build --release -p sim-server``).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SERVER = ROOT / "target" / "release" / "sim-server"


def first_hit(pool: str, index: int, extra: list[str]) -> dict | None:
    """The scene's split and the ego's first collision, or None past the pool's end."""
    cmd = [
        str(SERVER),
        "rollout",
        "--pool",
        pool,
        "--scenario",
        str(index),
        "--av=-1,0",
        *extra,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        if "no scenario" in proc.stderr:
            return None
        raise RuntimeError(f"{' '.join(cmd)}: {proc.stderr.strip()}")
    lines = [json.loads(line) for line in proc.stdout.splitlines()]
    header = lines[0]
    kinds = {a["id"]: a["kind"] for a in header["agents"]}
    ego = header["ego"]
    out = {
        "scenario": header["scenario"],
        "split": header["split"],
        "hit_by": None,
        "t": None,
    }
    for line in lines[1:]:
        for e in line.get("events", []):
            if e.get("event") == "collision" and ego in (e["a"], e["b"]):
                other = e["b"] if e["a"] == ego else e["a"]
                out.update(hit_by=kinds[other], t=line["time"], other=other)
                return out
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--pool", default="embedded:hbs-general")
    ap.add_argument("--split", default="test")
    ap.add_argument("--params", default="params/table2.json5")
    ap.add_argument(
        "--vehicles", default=None, help="replay | idm (default: the pool's)"
    )
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", default=None, help="write the per-scene results here")
    args = ap.parse_args(argv)
    extra = ["--params", args.params] if args.params else []
    if args.vehicles:
        extra += ["--vehicles", args.vehicles]
    results = []
    with ThreadPoolExecutor(args.jobs) as ex:
        start = 0
        while True:
            batch = list(
                ex.map(
                    lambda k: first_hit(args.pool, k, extra), range(start, start + 32)
                )
            )
            results += [r for r in batch if r is not None]
            if any(r is None for r in batch):
                break
            start += 32
    scenes = [r for r in results if r["split"] == args.split]
    by_car = [r for r in scenes if r["hit_by"] == "vehicle"]
    by_ped = [r for r in scenes if r["hit_by"] == "pedestrian"]
    times = [r["t"] for r in by_car + by_ped]
    print(
        f"{args.pool} {args.split} ({len(scenes)} scenes), vehicles {args.vehicles or 'pool default'}, "
        f"params {args.params}: hit by a car in {len(by_car)}, by a pedestrian in {len(by_ped)}"
        + (
            f", median {statistics.median(times):.1f} s after the start"
            if times
            else ""
        )
    )
    for r in by_car + by_ped:
        print(f"  {r['scenario']}: {r['hit_by']} {r['other']} at {r['t']:.1f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(scenes, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
