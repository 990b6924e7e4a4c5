"""One world step of sharedspace next to pysocialforce's, same N, side by side in one run.

For each N the Rust step (1 AV + N CR-SFM pedestrians at 0.25 /m², cognition, risk and graph
all on; `sim-server bench-step`) and pysocialforce 1.1.2's `Simulator.step` (N pedestrians at the
same density, no obstacles) are timed one after the other, and the ratio of step rates is printed.
pysocialforce's social force is O(N^2) in time and memory, so at large N it runs only a few steps.

Usage: python benchmarks/step_vs_pysocialforce.py --server target/release/sim-server [--n 3 10 ...]
       [--baseline-server OLD_BUILD/sim-server] [--rounds R]

With ``--baseline-server`` every round times the new step, the baseline's step and pysocialforce
one after the other for each N, and the medians over the rounds are printed side by side (the
machines swing 1.5-2x within minutes, so old and new are only compared within one run).
"""

from __future__ import annotations

import argparse
import json
import logging
import platform
import resource
import statistics
import subprocess
import sys
import time

import numpy as np


def time_rust(server: str, n: int, seconds: float) -> float:
    """Seconds per step of the Rust world at N pedestrians."""
    out = subprocess.run(
        [server, "bench-step", "--n", str(n), "--seconds", str(seconds)],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(out)["ns_per_step"] * 1e-9


def time_pysocialforce(n: int, seconds: float, max_steps: int, seed: int = 0) -> float:
    """Seconds per step of pysocialforce at N pedestrians (same density as the Rust scene)."""
    import pysocialforce as psf

    rng = np.random.default_rng(seed)
    side = (n / 0.25) ** 0.5
    pos = rng.uniform(0.0, side, (n, 2))
    heading = rng.uniform(0.0, 2 * np.pi, n)
    speed = rng.uniform(1.0, 1.5, n)
    vel = np.stack([np.cos(heading), np.sin(heading)], axis=1) * speed[:, None]
    goal = rng.uniform(0.0, side, (n, 2))
    sim = psf.Simulator(np.hstack([pos, vel, goal]), obstacles=None)
    sim.step(1)  # numba compilation and first-call overheads
    steps = 0
    start = time.perf_counter()
    while steps < max_steps and (steps == 0 or time.perf_counter() - start < seconds):
        sim.step(1)
        steps += 1
    return (time.perf_counter() - start) / steps


def time_pysocialforce_isolated(
    n: int, seconds: float, max_steps: int, mem_gib: float
) -> float | None:
    """`time_pysocialforce` in a child process under an address-space limit: pysocialforce's
    pairwise arrays need O(N^2) memory (about 20 GiB at N = 10 000) and must not take the machine
    down. Returns None when the child ran out of memory."""
    limit = int(mem_gib * 2**30)

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    child = subprocess.run(
        [
            sys.executable,
            __file__,
            "--pysf-only",
            str(n),
            "--seconds",
            str(seconds),
            "--pysf-max-steps",
            str(max_steps),
        ],
        capture_output=True,
        text=True,
        preexec_fn=cap,
    )
    if child.returncode != 0:
        if "MemoryError" in child.stderr or "Unable to allocate" in child.stderr:
            return None
        raise RuntimeError(f"pysocialforce at N={n} failed:\n{child.stderr[-2000:]}")
    return float(child.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--server", default="target/release/sim-server", help="sim-server binary"
    )
    parser.add_argument("--n", type=int, nargs="+", default=[3, 10, 100, 1000, 10000])
    parser.add_argument(
        "--seconds", type=float, default=3.0, help="timing budget per side and N"
    )
    parser.add_argument(
        "--pysf-max-steps",
        type=int,
        default=200,
        help="cap on pysocialforce steps per N",
    )
    parser.add_argument("--json", help="also write the rows to this file")
    parser.add_argument(
        "--pysf-mem-gib", type=float, default=16.0, help="memory cap for pysocialforce"
    )
    parser.add_argument(
        "--baseline-server", help="an older sim-server build to time alongside"
    )
    parser.add_argument(
        "--rounds", type=int, default=1, help="rounds (medians are printed)"
    )
    parser.add_argument("--pysf-only", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args()
    logging.disable(logging.CRITICAL)  # pysocialforce logs every step at DEBUG
    if args.pysf_only is not None:
        print(time_pysocialforce(args.pysf_only, args.seconds, args.pysf_max_steps))
        return

    rows = []
    print(
        f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}"
    )
    base = args.baseline_server
    print(
        f"{'N':>6} {'rust us/step':>14}"
        + (f" {'baseline us/step':>17} {'new/baseline':>13}" if base else "")
        + f" {'pysf us/step':>14} {'ratio':>9}"
        + (f" {'baseline ratio':>15}" if base else "")
        + f" {'rust us/ped':>12}"
    )
    for n in args.n:
        times: dict[str, list[float]] = {"new": [], "base": [], "pysf": []}
        for _ in range(args.rounds):
            times["new"].append(time_rust(args.server, n, args.seconds))
            if base:
                times["base"].append(time_rust(base, n, args.seconds))
            pysf_steps = args.pysf_max_steps if n < 5000 else 1
            pysf = time_pysocialforce_isolated(
                n, args.seconds, pysf_steps, args.pysf_mem_gib
            )
            if pysf is not None:
                times["pysf"].append(pysf)
        rust = statistics.median(times["new"])
        old = statistics.median(times["base"]) if base else None
        pysf = statistics.median(times["pysf"]) if times["pysf"] else None
        row = {
            "n": n,
            "rounds": args.rounds,
            "rust_us_per_step": rust * 1e6,
            "baseline_us_per_step": None if old is None else old * 1e6,
            "pysf_us_per_step": None if pysf is None else pysf * 1e6,
            "ratio": None if pysf is None else pysf / rust,
            "baseline_ratio": None if pysf is None or old is None else pysf / old,
            "rust_us_per_ped": rust * 1e6 / n,
            "samples_us": {k: [t * 1e6 for t in v] for k, v in times.items()},
        }
        rows.append(row)
        pysf_text = (
            f"{pysf * 1e6:>14.1f}" if pysf is not None else f"{'out of memory':>14}"
        )
        ratio_text = f"{pysf / rust:>8.0f}x" if pysf is not None else f"{'-':>9}"
        base_text = ""
        if old is not None:
            base_text = f" {old * 1e6:>17.2f} {rust / old:>13.2f}"
        base_ratio = ""
        if old is not None:
            base_ratio = f" {pysf / old:>14.0f}x" if pysf is not None else f" {'-':>15}"
        print(
            f"{n:>6} {rust * 1e6:>14.2f}{base_text} {pysf_text} {ratio_text}{base_ratio}"
            f" {rust * 1e6 / n:>12.4f}",
            flush=True,
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
