"""Whole-run PPO throughput, the code before the collection/update overlap against the code
after it, in interleaved rounds on one box; and where the CPU went (the server's and the
learner's shares).

Each run is ``python -m sharedspace.train --set task=crowd algorithm=ppo network=NET
total_frames=FRAMES eval_interval=0 checkpoint_interval=0 progress=false`` as a new user types
it: Table II-G's world, a local release ``sim-server`` that the trainer starts itself. A code
is a ``src`` folder put first on ``PYTHONPATH`` (``--before``: a checkout of the older commit's
``clients/src``, e.g. ``git worktree add /tmp/before <commit>``); ``--after`` defaults to this
checkout's. A run's rate is its frames over its loop's wall time (``train/wall_s`` in
``metrics.csv``), the first iteration left out (allocation, first resets). While a run trains,
the CPU seconds of the trainer and of its server (``/proc/PID/stat``, children included) are
read every second; their shares are CPU seconds per wall second (2.0 = both cores).

Prints a row per run, the medians per code and network, the after / before ratio of the
medians, and one JSON line (docs/BENCHMARKS.md keeps them with the machine and the date).

Usage: python benchmarks/overlap_ab.py --before /tmp/before/clients/src [--rounds 3]
       [--networks mlp gcn_risk] [--frames 196608] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from soak import cpu_s  # benchmarks/, beside this script

ROOT = Path(__file__).resolve().parents[1]
#: Both codes play against the same server: this checkout's release build unless set.
SERVER = os.environ.get(
    "SHAREDSPACE_SIM_SERVER", str(ROOT / "target" / "release" / "sim-server")
)


def cpu_seconds(pid: int) -> float:
    """:func:`soak.cpu_s`, or 0.0 once the process is gone (a run's server ends with it)."""
    try:
        return cpu_s(pid)
    except OSError:
        return 0.0


def code_env(src: str) -> dict[str, str]:
    """The environment of a trainer process that runs the code of ``src`` (first on
    ``PYTHONPATH``) against :data:`SERVER`."""
    return os.environ | {
        "PYTHONPATH": src,
        "PYTHONUNBUFFERED": "1",
        "SHAREDSPACE_SIM_SERVER": SERVER,
    }


def children(pid: int) -> list[int]:
    """The direct children of ``pid``."""
    out = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return out


def one_run(
    src: str, network: str, frames: int, more: list[str], log_dir: Path
) -> dict:
    """One training run of ``src``'s code; its rate and CPU shares."""
    env = code_env(src)
    args = [
        "task=crowd",
        "algorithm=ppo",
        f"network={network}",
        f"total_frames={frames}",
        "eval_interval=0",
        "checkpoint_interval=0",
        "progress=false",
        f"log_dir={log_dir}",
        *more,
    ]
    cmd = [sys.executable, "-m", "sharedspace.train", "--set", *args]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL)
    metrics = log_dir / "metrics.csv"
    samples = []  # (wall, trainer cpu, server cpu, frames so far)
    while proc.poll() is None:
        time.sleep(1.0)
        servers = children(proc.pid)
        done = _frames(metrics)
        samples.append(
            (
                time.perf_counter(),
                cpu_seconds(proc.pid),
                sum(cpu_seconds(p) for p in servers),
                done,
            )
        )
    if proc.returncode:
        raise SystemExit(f"run failed ({proc.returncode}): {' '.join(cmd)}")
    rows = list(csv.DictReader(metrics.open()))
    walls = [
        (int(r["frames"]), float(r["value"]))
        for r in rows
        if r["metric"] == "train/wall_s"
    ]
    (f0, w0), (f1, w1) = walls[0], walls[-1]
    # the CPU shares over the samples taken while batches were coming (after the first)
    busy = [s for s in samples if f0 <= s[3] < f1]
    share = {"trainer_cpu": None, "server_cpu": None}
    if len(busy) >= 2:
        (t_a, tr_a, sv_a, _), (t_b, tr_b, sv_b, _) = busy[0], busy[-1]
        share = {
            "trainer_cpu": (tr_b - tr_a) / (t_b - t_a),
            "server_cpu": (sv_b - sv_a) / (t_b - t_a),
        }
    return {"fps": (f1 - f0) / (w1 - w0), "frames": f1 - f0} | share


def _frames(metrics: Path) -> int:
    """The frames the run has logged so far (0 before its first batch)."""
    try:
        last = metrics.read_text().rstrip().rsplit("\n", 1)[-1]
        return int(last.split(",", 1)[0])
    except (OSError, ValueError):
        return 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", required=True, help="clients/src of the code before")
    ap.add_argument(
        "--after", default=str(ROOT / "clients" / "src"), help="clients/src after"
    )
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--networks", nargs="+", default=["mlp", "gcn_risk"])
    ap.add_argument(
        "--frames", type=int, default=196_608, help="frames per run (24 batches)"
    )
    ap.add_argument(
        "--set", nargs="*", default=[], help="more trainer settings, both codes"
    )
    ap.add_argument(
        "--after-set", nargs="*", default=[], help="settings of the after code only"
    )
    args = ap.parse_args()
    codes = {
        "before": (args.before, args.set),
        "after": (args.after, args.set + args.after_set),
    }
    results: dict[tuple[str, str], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            for network in args.networks:
                order = ("before", "after") if r % 2 == 0 else ("after", "before")
                for code in order:
                    src, more = codes[code]
                    log_dir = Path(tmp) / f"{network}-{code}-{r}"
                    out = one_run(src, network, args.frames, more, log_dir)
                    results.setdefault((network, code), []).append(out)
                    print(
                        f"round {r} {network:9s} {code:6s} {out['fps']:8.0f} frames/s  "
                        f"trainer {out['trainer_cpu'] or 0:.2f} server {out['server_cpu'] or 0:.2f}"
                        " cores",
                        flush=True,
                    )
    summary = {}
    print("\n| network | code | median frames/s | trainer cores | server cores |")
    print("|---|---|---:|---:|---:|")
    for (network, code), runs in results.items():
        med = {
            k: statistics.median(x[k] or 0 for x in runs)
            for k in runs[0]
            if k != "frames"
        }
        summary.setdefault(network, {})[code] = med | {"runs": [x["fps"] for x in runs]}
        print(
            f"| {network} | {code} | {med['fps']:.0f} | {med['trainer_cpu']:.2f} | "
            f"{med['server_cpu']:.2f} |"
        )
    for network, codes_ in summary.items():
        ratio = codes_["after"]["fps"] / codes_["before"]["fps"]
        codes_["ratio"] = ratio
        print(f"{network}: after / before = {ratio:.2f}")
    machine = {"python": platform.python_version(), "cpus": os.cpu_count()}
    print(json.dumps({"machine": machine, "frames": args.frames, "summary": summary}))


if __name__ == "__main__":
    main()
