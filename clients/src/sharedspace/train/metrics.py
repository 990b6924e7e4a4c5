"""What a training run records: scalars to ``metrics.csv`` and TensorBoard, ended episodes'
outcomes, and the progress bar's line. Every learner (``train``, ``marl``) logs through these."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import numpy as np
from tensordict import TensorDictBase

from sharedspace.torchrl_env import EPISODE_FLAG_KEYS, EPISODE_FLOAT_KEYS

__all__ = ["EpisodeTracker", "MetricLogger", "episode_metrics"]


class MetricLogger:
    """Scalars to ``metrics.csv`` (long format: frames, wall_s, metric, value) and TensorBoard."""

    def __init__(self, log_dir: Path, tensorboard: bool = True):
        log_dir.mkdir(parents=True, exist_ok=True)
        path = log_dir / "metrics.csv"
        new = not path.exists()
        self._file = path.open("a", newline="")
        self._csv = csv.writer(self._file)
        if new:
            self._csv.writerow(["frames", "wall_s", "metric", "value"])
        self._tb = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                self._tb = SummaryWriter(str(log_dir / "tb"))
            except ImportError:  # pragma: no cover - tensorboard is in requirements-train.txt
                self._tb = None
        self._t0 = time.perf_counter()

    def log(self, metrics: dict[str, float], frames: int) -> None:
        wall = time.perf_counter() - self._t0
        for key, value in metrics.items():
            value = float(value)
            self._csv.writerow([frames, f"{wall:.3f}", key, f"{value:.6g}"])
            if self._tb is not None:
                self._tb.add_scalar(key, value, frames)
        self._file.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


class EpisodeTracker:
    """Running returns per sub-env across collected batches; ended episodes' stats (``lost``:
    ended truncated by a lost server, with none of success, collision, timeout)."""

    def __init__(self, num_envs: int):
        self.returns = np.zeros(num_envs)
        self.lengths = np.zeros(num_envs, dtype=np.int64)
        self.recent: list[dict[str, float]] = []

    def update(self, data: TensorDictBase) -> list[dict[str, float]]:
        """``data`` is a collected batch ``[K, T]``; returns the episodes that ended in it."""
        nxt = data["next"]
        reward = nxt["reward"].reshape(data.shape[0], data.shape[1]).cpu().numpy()
        done = nxt["done"].reshape(data.shape[0], data.shape[1]).cpu().numpy()
        flags = {
            key: nxt[key].reshape(data.shape[0], data.shape[1]).cpu().numpy()
            for key in EPISODE_FLAG_KEYS + EPISODE_FLOAT_KEYS
        }
        ended = []
        for t in range(data.shape[1]):
            self.returns += reward[:, t]
            self.lengths += 1
            for k in np.flatnonzero(done[:, t]):
                ep = {"return": float(self.returns[k]), "length": int(self.lengths[k])}
                for key, values in flags.items():
                    ep[key.removeprefix("episode_")] = float(values[k, t])
                # truncated with no outcome: its server was lost, the env re-created elsewhere
                ep["lost"] = float(not any(ep[s] for s in ("success", "collision", "timeout")))
                ended.append(ep)
                self.returns[k] = 0.0
                self.lengths[k] = 0
        self.recent = (self.recent + ended)[-200:]
        return ended


def episode_metrics(ended: list[dict[str, float]]) -> dict[str, float]:
    """``train/*`` means over the episodes that ended in a batch (none: an empty dict)."""
    if not ended:
        return {}
    out = {
        "train/episode_return": float(np.mean([e["return"] for e in ended])),
        "train/episode_length": float(np.mean([e["length"] for e in ended])),
    }
    keys = ("success", "collision", "timeout", "lost", "avg_speed", "avg_abs_jerk", "max_abs_acc")
    for key in keys:
        out[f"train/{key}"] = float(np.mean([e[key] for e in ended]))
    return out


def progress_postfix(metrics: dict[str, float], recent: list[dict[str, float]]) -> dict[str, str]:
    """The progress bar's line: frames/s, the recent episodes' return and success, and the
    env's share of the wall time so far."""
    return {
        "fps": f"{metrics['train/fps']:.0f}",
        "ret": f"{np.mean([e['return'] for e in recent]):.1f}" if recent else "-",
        "succ": f"{np.mean([e['success'] for e in recent]):.2f}" if recent else "-",
        "env": f"{metrics['train/env_time_share_cum']:.2f}",
    }
