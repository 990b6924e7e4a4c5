"""The range the CR-SFM pedestrians walk in, which the adversary is held to
(:data:`sharedspace.adversary.task.WALKING_RANGE`): their speeds and accelerations in
``sim-server rollout`` of the driving task's train scenes, in its world."""

from __future__ import annotations

import json
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from sharedspace.bench.tasks import Task
from sharedspace.local_server import sim_server_binary

__all__ = ["walking_samples", "walking_range"]


def walking_samples(task: Task, variation: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Every CR-SFM pedestrian's speed (m/s) and acceleration norm (m/s²,
    ``|v_t - v_{t-1}| / dt``) at every step of ``task``'s train scenes (seeded variation
    ``variation``, the car replaying its record, the task's world)."""
    pool = json.loads(task.pool_path().read_text())
    train = [i for i, s in enumerate(pool["scenarios"]) if s.get("split", "train") == "train"]
    with tempfile.TemporaryDirectory() as tmp:
        params = Path(tmp) / "params.json"
        params.write_text(json.dumps(task.world_params))
        with ThreadPoolExecutor(2) as pool_exec:
            runs = list(pool_exec.map(lambda i: _rollout(task, params, i, variation), train))
    speeds = np.concatenate([r[0] for r in runs])
    accs = np.concatenate([r[1] for r in runs])
    return speeds, accs


def walking_range(task: Task, quantile: float = 0.95) -> dict[str, Any]:
    """The ``quantile`` of the CR-SFM pedestrians' speed and acceleration
    (:func:`walking_samples`)."""
    speeds, accs = walking_samples(task)
    return {
        "speed_max": round(float(np.quantile(speeds, quantile)), 3),
        "acc_max": round(float(np.quantile(accs, quantile)), 3),
        "quantile": quantile,
        "speed_samples": int(speeds.size),
        "acc_samples": int(accs.size),
    }


def _rollout(task: Task, params: Path, index: int, variation: int):
    cmd = [
        str(sim_server_binary()),
        "rollout",
        "--pool",
        str(task.pool_path()),
        "--params",
        str(params),
        "--scenario",
        str(index),
        "--variation",
        str(variation),
    ]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    lines = [json.loads(line) for line in out.splitlines() if line.strip()]
    header = lines[0]
    modelled = {a["id"] for a in header["agents"] if a["control"] == task.pedestrian_model}
    dt = float(header.get("dt", 0.5))
    speeds: list[float] = []
    accs: list[float] = []
    last: dict[int, np.ndarray] = {}
    for step in (x for x in lines if x.get("type") == "step"):
        now = {}
        for a in step["agents"]:
            if a["id"] in modelled:
                v = np.array([a["vx"], a["vy"]])
                now[a["id"]] = v
                speeds.append(float(np.linalg.norm(v)))
                if a["id"] in last:
                    accs.append(float(np.linalg.norm(v - last[a["id"]]) / dt))
        last = now
    return np.asarray(speeds), np.asarray(accs)
