"""How real composed scenes are: composed scenes beside the recorded train scenes they are made
from, in a task's world (docs/RESULTS.md, "Composed scenes").

    .venv/bin/python benchmarks/composed_realism.py --task paper --scenes 300

For the task's recorded train scenes (less its validation split) and ``--scenes`` composed ones
(seed 0, made from those train scenes: ``compose-scenes``), it reports

- the pedestrians within 5 m of the ego's recorded path (at any time), and the recorded car's
  path length (m) and duration (s);
- the success, collision and timeout of the scripted drivers ``hold`` (never moves) and
  ``car_aware`` (pursuit with IDM braking for whoever is in its path), each scene played once
  as stored.

It writes ``results/scenes/realism-<task>.json`` and prints a markdown table. No test scene is
read.
"""

from __future__ import annotations

import argparse
import json
import subprocess
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "results" / "scenes"
DRIVERS = ("hold", "car_aware")
NEAR_PATH_M = 5.0


def compose(task_cfg, scenes: int, path: Path) -> None:
    """``scenes`` composed scenes of seed 0 from the task's train scenes less its validation
    split, written to ``path`` by the scenarios crate's ``compose-scenes``."""
    from sharedspace.worlds import held_out_scenes

    source = task_cfg.scenario_pool or "scenarios/data/hbs-paper.json"
    _, hold_out = held_out_scenes(task_cfg.scenario_pool, task_cfg.validation_scenes)
    exe = REPO / "target" / "release" / "compose-scenes"
    if not exe.is_file():
        subprocess.run(
            ["cargo", "build", "--release", "-p", "scenarios", "--bin", "compose-scenes"],
            cwd=REPO,
            check=True,
        )
    cmd = [str(exe), "--pool", str(REPO / source), "--scenes", str(scenes), "--out", str(path)]
    subprocess.run([*cmd, "--hold-out", ",".join(hold_out)], check=True)


def geometry(scene: dict) -> dict[str, float]:
    """Pedestrians within 5 m of the ego's path; its length (m) and duration (s)."""
    ego = np.asarray(scene["agents"][scene["ego"]]["positions"], dtype=float)
    near = 0
    for a in scene["agents"]:
        if a["kind"] != "pedestrian":
            continue
        p = np.asarray(a["positions"], dtype=float)
        if np.min(np.linalg.norm(p[:, None, :] - ego[None, :, :], axis=2)) <= NEAR_PATH_M:
            near += 1
    return {
        "near_path": near,
        "path_m": float(np.linalg.norm(np.diff(ego, axis=0), axis=1).sum()),
        "duration_s": (len(ego) - 1) * scene["dt"],
    }


def recorded_train(task_cfg, path: Path) -> Path:
    """The task's recorded train scenes less its validation split, as a pool file at ``path``."""
    pool = task_cfg.pool_scenes()
    source = task_cfg.scenario_pool or "scenarios/data/hbs-paper.json"
    doc = json.loads((REPO / source).read_text())
    doc["scenarios"] = [pool[i] for i in task_cfg.scene_indices("train")]
    path.write_text(json.dumps(doc))
    return path


def score(task: str, pool_file: Path) -> dict:
    """The drivers' outcomes and the scenes' geometry on the train split of ``pool_file``."""
    from sharedspace.paper.drivers import make_driver
    from sharedspace.paper.evaluate import evaluate_policy
    from sharedspace.world_config import WorldConfig
    from sharedspace.worlds import training_task

    world = training_task(task)
    cfg = WorldConfig(
        scenario_pool=str(pool_file),
        server_params=world.server_params,
        max_agents=world.max_agents,
        eval_split="test",
    )
    doc = json.loads(pool_file.read_text())
    scenes = [s for s in doc["scenarios"] if s.get("split", "train") == "train"]
    row: dict = {"scenes": len(scenes)}
    geo = [geometry(s) for s in scenes]
    for key in ("near_path", "path_m", "duration_s"):
        row[key] = float(np.mean([g[key] for g in geo]))
    for name in DRIVERS:
        summary = evaluate_policy(cfg, make_driver(name), "train")["summary"]
        row[name] = {k: summary[k] for k in ("success", "collision", "timeout")}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="paper", choices=("paper", "crowd"))
    ap.add_argument("--scenes", type=int, default=300)
    args = ap.parse_args()
    from sharedspace.world_config import WorldConfig

    task_cfg = WorldConfig(task=args.task)
    OUT.mkdir(parents=True, exist_ok=True)
    composed = REPO / "out" / "composed" / f"{args.task}-s0-{args.scenes}.json"
    composed.parent.mkdir(parents=True, exist_ok=True)
    compose(task_cfg, args.scenes, composed)
    recorded = composed.parent / f"{args.task}-recorded-train.json"
    rows = {
        "recorded train": score(args.task, recorded_train(task_cfg, recorded)),
        "composed": score(args.task, composed),
    }
    (OUT / f"realism-{args.task}.json").write_text(json.dumps(rows, indent=1))
    head = "| scenes | n | peds within 5 m of path | path (m) | duration (s) | "
    head += " | ".join(f"{d} success / collision" for d in DRIVERS) + " |"
    print(head)
    print("|" + "---|" * (5 + len(DRIVERS)))
    for name, r in rows.items():
        cells = [
            name,
            str(r["scenes"]),
            f"{r['near_path']:.2f}",
            f"{r['path_m']:.1f}",
            f"{r['duration_s']:.1f}",
        ]
        cells += [f"{r[d]['success']:.3f} / {r[d]['collision']:.3f}" for d in DRIVERS]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
