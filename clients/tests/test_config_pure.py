"""Building a config does nothing else: for every task and algorithm family, from the dataclass
or from the command line's words, no file is written (not under the working directory, not
under HOME, not in the package's cache) and no server is asked. The validation carve is a
selection of the pool's train scenes by name, never a file: the training envs exclude it and
the validation envs play it."""

from __future__ import annotations

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
    cfg.world.env_spec("train", 0, cfg.world.variations)
    cfg.world.env_spec("validation", 0)
    assert _files(cwd) == _files(home) == _files(carve) == []


def test_the_validation_carve_is_a_seeded_selection_of_the_train_scenes_asked_by_name():
    import random

    cfg = TrainConfig(algorithm="ppo", task="paper", device="cpu")
    pool = cfg.world.pool_scenes()
    train = [s["name"] for s in pool if s["split"] == "train"]
    sampled = set(random.Random(0).sample(train, cfg.world.validation_scenes))
    held = cfg.world.validation_names()
    assert set(held) == sampled and list(held) == [n for n in train if n in sampled]
    # train less validation, the validation split and the test scenes partition the pool
    parts = [cfg.world.scene_indices(split) for split in ("train", "validation", "test")]
    assert sorted(i for part in parts for i in part) == list(range(len(pool)))
    assert [pool[i]["name"] for i in parts[1]] == list(held)
    # the training envs exclude it, the others do not; eval_split=test carves nothing
    assert cfg.world.env_spec("train", 0).exclude == held
    assert (
        cfg.world.env_spec("validation", 0).exclude == () == cfg.world.env_spec("test", 0).exclude
    )
    assert cfg.world.env_spec("validation", 0).split == "train"
    plain = TrainConfig(algorithm="ppo", task="paper", eval_split="test", device="cpu")
    assert plain.world.validation_names() == () and plain.world.scene_indices("validation") == []


def test_a_task_s_training_variations_may_be_set_its_world_may_not():
    from sharedspace.train.config import ConfigError

    wide = {"position_sigma": 1.0, "rotation_deg": 30.0}
    cfg = TrainConfig(algorithm="ppo", task="paper", variations=wide, device="cpu")
    assert cfg.world.variations == wide
    assert TrainConfig(algorithm="ppo", task="paper", device="cpu").world.variations != wide
    with pytest.raises(ConfigError, match="max_agents is set by task=paper"):
        TrainConfig(algorithm="ppo", task="paper", max_agents=5, device="cpu")


def test_a_tool_s_world_takes_world_keys_and_names_any_other():
    """The paper's tools build a world alone (``WorldConfig.from_words``): a world key is parsed
    like its field; a key of another part, a misspelt key, a word without ``=`` or a value of
    the wrong type is refused by name, in one line."""
    import subprocess
    import sys

    from sharedspace.world_config import WorldConfig, WorldConfigError

    world = WorldConfig.from_words(["task=crowd", "validation_variations=2", "failover=false"])
    assert (world.max_agents, world.validation_variations, world.failover) == (10, 2, False)
    for words, named in (
        (["lr=1e-3"], "'lr' is no key of the world"),
        (["max_agent=4"], "did you mean 'max_agents'"),
        (["max_agents"], "expected KEY=VALUE"),
        (["max_agents=many"], "--set max_agents=many: expected int"),
        (["task=paper", "max_agents=5"], "max_agents is set by task=paper"),
    ):
        with pytest.raises(WorldConfigError, match=named):
            WorldConfig.from_words(words)
    done = subprocess.run(
        [sys.executable, "-m", "sharedspace.paper.evaluate", "--driver", "hold", "--set", "lr=1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [
        done.stderr.strip().splitlines()[0]
    ]
    assert "error: 'lr' is no key of the world" in done.stderr
