"""What every training loop does the same way: its run directory, seeding, and the schedule of
evaluations and checkpoints."""

from __future__ import annotations

import json
import random
import sys
from pathlib import Path

import numpy as np
import torch

__all__ = ["next_multiple", "seed_everything", "start_run"]


def seed_everything(seed: int) -> None:
    """Python's, numpy's global and torch's generators."""
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002 - seeds the global stream for third-party code
    torch.manual_seed(seed)


def next_multiple(frames: int, interval: int) -> int:
    """The next multiple of ``interval`` after ``frames`` (never, for interval 0)."""
    return (frames // interval + 1) * interval if interval else sys.maxsize


def start_run(cfg) -> Path:
    """The run directory ``cfg.log_dir``, made, with the config written to ``config.json``;
    torch's CPU threads set to ``cfg.num_threads`` (0: torch's default)."""
    log_dir = Path(cfg.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
    if cfg.num_threads:
        torch.set_num_threads(cfg.num_threads)
    return log_dir
