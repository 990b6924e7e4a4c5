"""A dozen composed scenes beside a dozen recorded train scenes of the same task
(docs/figures/composed-scenes-<task>.png; scenarios/EXTRACTION.md, "Composed scenes").

    .venv/bin/python benchmarks/composed_figure.py --task paper

Each panel shows one scene as stored: the ego's recorded route (black, a square at its start),
every pedestrian's track (a dot at its start, the line to its goal), and other cars (grey).
The composed scenes are those ``benchmarks/composed_realism.py`` writes (seed 0), made from the
task's train scenes less its validation split; the recorded ones are that split's train scenes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def draw(ax, scene: dict) -> None:
    """One scene's tracks, in its own frame (equal axes)."""
    for k, a in enumerate(scene["agents"]):
        xs, ys = zip(*a["positions"], strict=True)
        if k == scene["ego"]:
            ax.plot(xs, ys, color="black", lw=2)
            ax.plot(xs[0], ys[0], "s", color="black", ms=5)
        elif a["kind"] == "vehicle":
            ax.plot(xs, ys, color="0.6", lw=1.5)
        else:
            ax.plot(xs, ys, color="tab:red", lw=0.8, alpha=0.8)
            ax.plot(xs[0], ys[0], "o", color="tab:red", ms=2.5)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title(scene["name"], fontsize=7)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="paper", choices=("paper", "crowd"))
    ap.add_argument(
        "--scenes", type=int, default=300, help="the composed pool file's size"
    )
    args = ap.parse_args()
    from sharedspace.train.config import TrainConfig

    cfg = TrainConfig(algorithm="ppo", task=args.task, device="cpu")
    pool = cfg.world.pool_scenes()
    recorded = [pool[i] for i in cfg.world.scene_indices("train")][:12]
    composed_file = REPO / "out" / "composed" / f"{args.task}-s0-{args.scenes}.json"
    if not composed_file.is_file():
        raise SystemExit(
            f"{composed_file} is missing: run benchmarks/composed_realism.py first"
        )
    composed = json.loads(composed_file.read_text())["scenarios"][:12]
    fig, axes = plt.subplots(4, 6, figsize=(13, 9))
    for ax, scene in zip(axes.flat, recorded + composed, strict=True):
        draw(ax, scene)
    fig.text(0.01, 0.74, "recorded", rotation=90, fontsize=11, va="center")
    fig.text(0.01, 0.27, "composed", rotation=90, fontsize=11, va="center")
    fig.suptitle(
        f"task {args.task}: 12 recorded train scenes (top) and composed scenes 0-11 of seed 0 "
        "(bottom); ego route black, pedestrians red, other cars grey",
        fontsize=10,
    )
    fig.tight_layout(rect=(0.02, 0, 1, 0.96))
    out = REPO / "docs" / "figures" / f"composed-scenes-{args.task}.png"
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
