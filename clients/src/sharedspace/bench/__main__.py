"""``python -m sharedspace.bench TASK --policy SPEC [--policy SPEC ...]``: scores a policy (several
pooled into one row) on a frozen task and prints the row; ``--out DIR`` writes
``DIR/TASK/NAME.json`` (every episode) and ``.md``; ``--reference FILE`` adds the paired
difference against a result of the same task version."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from sharedspace.bench.tasks import TASKS, BenchError
from sharedspace.cli import run_command


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sharedspace.bench", description=__doc__)
    ap.add_argument(
        "task",
        help="the task: "
        + "; ".join(f"{t.name} (v{t.version}: {t.description})" for t in TASKS.values()),
    )
    ap.add_argument(
        "--policy",
        action="append",
        required=True,
        help="a scripted driver (car_aware, pursuit_3, ...), a checkpoint (.pt) or "
        "module:function; repeat it to pool several (a learner's seeds) into one row",
    )
    ap.add_argument("--name", default="", help="the row's name (default: the first policy's)")
    ap.add_argument(
        "--reference", default="", help="a result JSON of the same task to compare with"
    )
    ap.add_argument(
        "--endpoint", default="", help="a server serving the task (default: a local one)"
    )
    ap.add_argument("--out", default="", help="write DIR/TASK/NAME.json and .md")
    args = ap.parse_args(argv)
    from sharedspace.bench.leaderboard import legend  # torch: once there is something to play
    from sharedspace.bench.scoring import score

    try:
        result = score(
            args.task,
            args.policy,
            name=args.name,
            endpoint=args.endpoint,
            reference=args.reference or None,
        )
    except BenchError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(result.markdown())
    print(legend(result.task))
    if args.out:
        path = result.save(args.out)
        print(f"wrote {path} and {path.with_suffix('.md').name}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
