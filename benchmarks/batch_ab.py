"""Two builds of ``sim-server`` side by side: the batch throughput of a fresh server, in
interleaved rounds of one run (the machines swing 1.5-2x within minutes, so builds are only
compared within one run).

    python benchmarks/batch_ab.py --before OLD/sim-server --after target/release/sim-server
        [--k 256] [--rounds 8] [--seconds 3]

Each round times both builds, in alternating order (before-after, then after-before), as a
``VectorClient`` of ``--k`` envs stepping ``BatchStep``s of random actions with autoreset (the
timing of docs/BENCHMARKS.md section 3); prints every round and the medians' ratio.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from allocator_ab import batch_env_steps_per_s  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--before", required=True, help="the old build's sim-server")
    ap.add_argument("--after", required=True, help="the new build's sim-server")
    ap.add_argument("--k", type=int, default=256, help="envs in the batch")
    ap.add_argument(
        "--rounds", type=int, default=8, help="rounds (medians are compared)"
    )
    ap.add_argument(
        "--seconds", type=float, default=3.0, help="timing budget per measure"
    )
    args = ap.parse_args()
    rates: dict[str, list[float]] = {"before": [], "after": []}
    for r in range(args.rounds):
        order = ("before", "after") if r % 2 == 0 else ("after", "before")
        for build in order:
            path = getattr(args, build)
            rates[build].append(batch_env_steps_per_s(path, args.k, args.seconds))
        print(
            f"round {r}: before {rates['before'][-1]:,.0f}, after {rates['after'][-1]:,.0f}"
            " env-steps/s",
            flush=True,
        )
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    med = {b: statistics.median(v) for b, v in rates.items()}
    print(
        f"{date}, {platform.machine()}, K = {args.k}, {args.rounds} rounds: median before "
        f"{med['before']:,.0f}, after {med['after']:,.0f} env-steps/s; after / before "
        f"{med['after'] / med['before']:.3f}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
