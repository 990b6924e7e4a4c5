"""``python -m sharedspace.adversary COMMAND``: the adversarial stress test of the drivers.

    # train an adversary of a driver (any policy spec; several: a row's seeds, pooled)
    python -m sharedspace.adversary train --name car_aware --driver car_aware --frames 1048576
    # score any driver against CR-SFM and every shipped adversary (results/adversary/policies)
    python -m sharedspace.adversary stress --name my_driver --driver my_pkg.mod:act
    # ... or against adversaries of your choice (label=checkpoint, or label=a scripted one)
    python -m sharedspace.adversary stress --name car_aware --driver car_aware \\
        --adversary own=results/adversary/runs/car_aware/checkpoints/last.pt jaywalker=intercept
    # two drivers side by side against the pedestrians both met: which is harder to break
    python -m sharedspace.adversary compare results/adversary/A.json results/adversary/B.json
    # animations of three failures it found
    python -m sharedspace.adversary gifs --stress results/adversary/car_aware.json --label own
    # the walking range the adversary is held to
    python -m sharedspace.adversary walking-range

Runs go to ``results/adversary/runs/NAME``, scorings to ``results/adversary/NAME.json`` (every
episode) and ``.md`` (docs/RESULTS.md, "Adversarial stress test").
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from sharedspace.adversary.scripted import SCRIPTED_ADVERSARIES
from sharedspace.cli import run_command
from sharedspace.worlds import REPO

RESULTS = Path("results/adversary")
#: The shipped adversaries: ``against-DRIVER.pt``, each trained against that driver.
SHIPPED = REPO / "results" / "adversary" / "policies"


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m sharedspace.adversary",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--task", default="crowd-adversary", help="the adversarial task")
    sub = ap.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train", help="train an adversary against a driver")
    tr.add_argument("--name", required=True, help="the run's folder under results/adversary/runs")
    tr.add_argument("--driver", nargs="+", required=True, help="policy spec(s) of the driver")
    tr.add_argument("--frames", type=int, default=1_048_576, help="frames to train for")
    tr.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides")
    tr.add_argument("--out", default=str(RESULTS / "runs"), help="where runs go")
    st = sub.add_parser("stress", help="score a driver against CR-SFM and adversaries")
    st.add_argument("--name", required=True, help="the driver's row name")
    st.add_argument("--driver", nargs="+", required=True, help="policy spec(s), pooled")
    st.add_argument(
        "--adversary",
        nargs="*",
        default=None,
        metavar="LABEL=ADVERSARY",
        help="adversaries, each a checkpoint or a scripted one's name ("
        + ", ".join(SCRIPTED_ADVERSARIES)
        + "; default: every shipped one, results/adversary/policies/*.pt)",
    )
    st.add_argument("--out", default=str(RESULTS), help="where the scoring goes")
    sub.add_parser("walking-range", help="measure the CR-SFM pedestrians' walking range")
    co = sub.add_parser("compare", help="two drivers' stress scorings, A - B, paired")
    co.add_argument("a", help="driver A's stress scoring (JSON)")
    co.add_argument("b", help="driver B's stress scoring (JSON)")
    co.add_argument("--json", default=None, help="also write the comparison here")
    gi = sub.add_parser("gifs", help="animations of the failures an adversary found")
    gi.add_argument("--stress", required=True, help="a stress scoring's JSON")
    gi.add_argument("--label", required=True, help="the adversary's label in it")
    gi.add_argument("--count", type=int, default=3, help="failures to draw")
    gi.add_argument("--out", default=str(RESULTS / "gifs"), help="where they go")
    return ap


def _walking_range(args: argparse.Namespace, ap: argparse.ArgumentParser) -> None:
    from sharedspace.adversary.task import get_adversary_task
    from sharedspace.adversary.walking import walking_range

    print(json.dumps(walking_range(get_adversary_task(args.task).driving)))


def _compare(args: argparse.Namespace, ap: argparse.ArgumentParser) -> None:
    from sharedspace.adversary.compare import compare_drivers, compare_markdown

    result = compare_drivers(*(json.loads(Path(f).read_text()) for f in (args.a, args.b)))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    print(compare_markdown(result))


def _gifs(args: argparse.Namespace, ap: argparse.ArgumentParser) -> None:
    from sharedspace.adversary.pictures import write_failures

    for path in write_failures(args.stress, args.label, args.out, args.count):
        print("wrote", path)


def _train(args: argparse.Namespace, ap: argparse.ArgumentParser) -> None:
    from sharedspace.adversary.stress import pooled_driver
    from sharedspace.adversary.task import get_adversary_task
    from sharedspace.adversary.train import train

    task = get_adversary_task(args.task)
    driver = pooled_driver(args.driver, task, args.name)
    out = train(driver, Path(args.out) / args.name, args.frames, args.set, task)
    print(json.dumps({"counters": out["counters"], "eval": out["eval"]}, default=str))


def _stress(args: argparse.Namespace, ap: argparse.ArgumentParser) -> None:
    from sharedspace.adversary.stress import stress_row
    from sharedspace.adversary.table import stress_markdown

    adversaries: dict[str, str | None] = {"CR-SFM": None}
    if args.adversary is None:
        adversaries |= {p.stem: str(p) for p in sorted(SHIPPED.glob("*.pt"))}
    for item in args.adversary or []:
        label, _, path = item.partition("=")
        if not path:
            ap.error(f"--adversary {item!r}: give LABEL=CHECKPOINT or LABEL=SCRIPT")
        if path not in SCRIPTED_ADVERSARIES and not Path(path).is_file():
            ap.error(
                f"--adversary {item!r}: {path!r} is neither a checkpoint file nor a scripted"
                f" adversary ({', '.join(SCRIPTED_ADVERSARIES)})"
            )
        adversaries[label] = path
    result = stress_row(args.driver, adversaries, args.task, args.name)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{args.name}.json").write_text(json.dumps(result))
    (out / f"{args.name}.md").write_text(stress_markdown(result))
    print(stress_markdown(result))


#: Each command's handler, ``(args, parser)``.
COMMANDS = {
    "train": _train,
    "stress": _stress,
    "compare": _compare,
    "gifs": _gifs,
    "walking-range": _walking_range,
}


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    COMMANDS[args.command](args, ap)
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
