"""Each step checkpoint of a run scored deterministically on the scenes it trained on (its
training pool's train split, every scene once, as recorded): does a late swing of the run's
validation curve show on its training scenes too? (docs/RESULTS.md, "Table II from scratch")

    python benchmarks/train_scene_scores.py results/bench/runs/paper-scratch-gcn_risk-s0

Writes RUN/train_scene_scores.json: frames, train-scene success and episodes per checkpoint.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from sharedspace.train.evaluation import evaluate_split
from sharedspace.train.learners import load_checkpoint_actor


def main(run: Path) -> None:
    rows = []
    steps = sorted(
        run.glob("checkpoints/step_*.pt"), key=lambda p: int(p.stem.split("_")[1])
    )
    for ckpt in steps:
        cfg, actor = load_checkpoint_actor(ckpt)
        summary = evaluate_split(cfg, actor, "train")["summary"]
        rows.append(
            {
                "frames": int(ckpt.stem.split("_")[1]),
                "train_success": summary["success"],
                "train_episodes": summary["episodes"],
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    (run / "train_scene_scores.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
