"""Building a config does nothing else: for every task and algorithm family, from the dataclass
or from the command line's words, no file is written (not the validation carve, not under the
working directory, not under HOME) and no server is asked; the carve is written when a run
first needs it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sharedspace import worlds
from sharedspace.train.config import TrainConfig, load_config
from sharedspace.worlds import TRAINING_TASKS

CASES = [
    ("", "sac"),
    ("", "ppo"),
    *[(task, "ppo") for task, t in TRAINING_TASKS.items() if t.cars == 1],
    *[(task, "sac") for task, t in TRAINING_TASKS.items() if t.cars == 1],
    *[(task, "mappo") for task, t in TRAINING_TASKS.items() if t.cars > 1],
]


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*"))


@pytest.fixture
def empty_places(tmp_path, monkeypatch):
    """The working directory, HOME and the carve's folder, each an empty temporary folder."""
    cwd, home, carve = tmp_path / "cwd", tmp_path / "home", tmp_path / "out"
    for d in (cwd, home, carve):
        d.mkdir()
    monkeypatch.chdir(cwd)
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.setattr(worlds, "_cache_dir", lambda kind: carve / kind)
    return cwd, home, carve


@pytest.mark.parametrize("task, algorithm", CASES)
def test_building_a_config_writes_nothing(task, algorithm, empty_places):
    cwd, home, carve = empty_places
    words = [f"algorithm={algorithm}", "device=cpu"] + ([f"task={task}"] if task else [])
    cfg = load_config(None, words)
    TrainConfig(algorithm=algorithm, task=task, device="cpu")
    cfg.env_spec("train", 0, cfg.variations)
    cfg.env_spec("validation", 0)
    assert cfg.training_pool()  # its path is known
    assert _files(cwd) == _files(home) == _files(carve) == []
    # a run's first need writes it, where the path said
    if cfg.eval_split == "validation" and cfg.scenario_pool is not None:
        path = cfg.carve_validation()
        assert Path(path).is_file() and Path(path).parent == carve / "validation"
        assert cfg.pool_of("validation") == path


def test_the_carve_is_written_once_and_not_again(empty_places):
    _, _, carve = empty_places
    cfg = TrainConfig(algorithm="ppo", task="paper", device="cpu")
    path = Path(cfg.carve_validation())
    stamp = path.stat().st_mtime_ns
    os.utime(path, ns=(stamp - 10**9, stamp - 10**9))
    assert Path(cfg.carve_validation()) == path
    assert path.stat().st_mtime_ns == stamp - 10**9  # read, not rewritten
