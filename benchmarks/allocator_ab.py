"""jemalloc against glibc malloc: one world step and batch throughput, side by side in one run.

Two builds of the same source: the default release build (jemalloc, the global allocator since
issue 40) and ``cargo build --release -p sim-server --features glibc`` (glibc malloc, kept as a
feature for this comparison). Every round times, for each build one after the other:

1. **world step**: ``sim-server bench-step`` at each ``--n`` (1 AV + N CR-SFM pedestrians at
   0.25 /m², cognition, risk and graph on; the timing of docs/BENCHMARKS.md section 1);
2. **batch throughput**: a fresh ``sim-server serve`` on a free loopback port and a
   ``VectorClient`` of ``--k`` envs stepping ``BatchStep``s of random actions with autoreset
   (the timing of section 3), env-steps per second.

Medians over the rounds are printed side by side with the ratio (the machines swing 1.5-2x
within minutes, so the builds are only compared within one run, interleaved).

``--also LABEL=PATH`` times more builds in the same rounds, each with its ratio to the jemalloc
build: the wheel's binary, linked through zig against glibc 2.17's symbols, against the same
source linked against this machine's glibc (issue 52).

Usage: python benchmarks/allocator_ab.py --jemalloc target/release/sim-server
       --glibc GLIBC_BUILD/sim-server [--also zig=WHEEL_BUILD/sim-server] [--n 100 1000]
       [--k 256] [--rounds 5] [--json F]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from client_roundtrip import bench_batch  # noqa: E402
from step_vs_pysocialforce import time_rust  # noqa: E402

from sharedspace.client import SimClient  # noqa: E402
from sharedspace.local_server import LocalServer  # noqa: E402


def batch_env_steps_per_s(server: str, k: int, seconds: float) -> float:
    """Env-steps per second of a K-env batch against a fresh ``server``."""
    with LocalServer(binary=server) as local:
        client = SimClient(local.endpoint, local.prefix, timeout=10.0)
        client.servers(timeout=10.0)
        rate = bench_batch(client, k, seconds)["env_steps_per_s"]
        client.shutdown()
        return rate


def allocator_of(server: str) -> str:
    """The allocator a build runs on, from the figures a fresh one reports in
    ``ServerInfo.allocator``: only jemalloc's have ``resident``, glibc's ``mallinfo2`` has not."""
    with LocalServer(binary=server) as local:
        client = SimClient(local.endpoint, local.prefix, timeout=10.0)
        figures = client.servers(timeout=10.0)[0].get("allocator", {})
        client.shutdown()
        return (
            "jemalloc" if "resident" in figures else "glibc" if figures else "unknown"
        )


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--jemalloc", required=True, help="the default build's sim-server")
    ap.add_argument(
        "--glibc", required=True, help="the --features glibc build's sim-server"
    )
    ap.add_argument(
        "--also",
        action="append",
        default=[],
        metavar="LABEL=PATH",
        help="another build to time in the same rounds (its allocator is reported, not checked)",
    )
    ap.add_argument("--n", type=int, nargs="+", default=[100, 1000], help="pedestrians")
    ap.add_argument("--k", type=int, default=256, help="envs in the batch")
    ap.add_argument(
        "--seconds", type=float, default=3.0, help="timing budget per measure"
    )
    ap.add_argument(
        "--rounds", type=int, default=5, help="rounds (medians are printed)"
    )
    ap.add_argument("--json", help="also write the samples to this file")
    args = ap.parse_args()
    builds = {"jemalloc": args.jemalloc, "glibc": args.glibc}
    for also in args.also:
        label, sep, path = also.partition("=")
        if not sep or not label or not path or label in builds:
            sys.exit(f"--also {also!r}: expected LABEL=PATH with a new label")
        builds[label] = path
    names = {b: allocator_of(path) for b, path in builds.items()}
    for build in ("jemalloc", "glibc"):
        if names[build] != build:
            sys.exit(f"{builds[build]} reports allocator {names[build]!r}, not {build!r}")

    step = {b: {n: [] for n in args.n} for b in builds}
    batch: dict[str, list[float]] = {b: [] for b in builds}
    for _ in range(args.rounds):
        for build, path in builds.items():
            for n in args.n:
                step[build][n].append(time_rust(path, n, args.seconds) * 1e6)
            batch[build].append(batch_env_steps_per_s(path, args.k, args.seconds))

    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    print(f"{date}, {platform.machine()}, {os.cpu_count()} cores, {args.rounds} rounds")
    others = [b for b in builds if b != "jemalloc"]
    labels = {b: f"{b} ({names[b]})" if b not in ("jemalloc", "glibc") else b for b in builds}
    print(
        "| measure | "
        + " | ".join(labels[b] for b in builds)
        + " | "
        + " | ".join(f"{b} / jemalloc" for b in others)
        + " |"
    )
    print("|---|" + "---:|" * (len(builds) + len(others)))
    # ratios as "how much slower than jemalloc": time over time, rate under rate
    for n in args.n:
        med = {b: statistics.median(step[b][n]) for b in builds}
        cells = [f"{med[b]:,.1f}" for b in builds]
        ratios = [f"{med[b] / med['jemalloc']:.2f}" for b in others]
        print(f"| world step, N = {n} (µs) | " + " | ".join(cells + ratios) + " |")
    med = {b: statistics.median(batch[b]) for b in builds}
    cells = [f"{med[b]:,.0f}" for b in builds]
    ratios = [f"{med['jemalloc'] / med[b]:.2f}" for b in others]
    print(f"| batch K = {args.k} (env-steps/s) | " + " | ".join(cells + ratios) + " |")
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                {
                    "date": date,
                    "args": vars(args),
                    "builds": builds,
                    "allocators": names,
                    "step_us": step,
                    "batch_env_steps_per_s": batch,
                },
                indent=1,
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
