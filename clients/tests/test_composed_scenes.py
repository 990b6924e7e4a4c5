"""Composed scenes (SPEC 5.2.2) through the clients: a PettingZoo env on them passes the
official API test, and a training config's ``scenes`` composes them from the train scenes less
its validation split while validating on recorded scenes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import sharedspace
from sharedspace.train.config import ConfigError, TrainConfig
from sharedspace.wire.errors import BadRequest


def test_a_pettingzoo_env_on_composed_scenes_passes_the_api_test(sim_client):
    env = sharedspace.parallel_env(
        client=sim_client, max_agents=6, seed=1, composed={"scenes": None, "seed": 3}
    )
    try:
        parallel_api_test(env, num_cycles=200)
        names = set()
        for _ in range(5):
            _, infos = env.reset()
            names.add(env.scenario)
            assert infos["vehicle_0"]["scenario_index"] == -1  # not one of the pool's
        assert len(names) == 5 and all(n.startswith("composed-s3-") for n in names)
        # A composed scene by name is the same scene again.
        first, _ = env.reset(options={"scenario": "composed-s3-42"})
        again, _ = env.reset(options={"scenario": "composed-s3-42"})
        features = first["vehicle_0"]["features"], again["vehicle_0"]["features"]
        np.testing.assert_array_equal(*features)
    finally:
        env.close()


def test_a_composed_request_the_server_cannot_serve_names_what_is_wrong(sim_client):
    for options, needle in [
        ({"composed": {"hold_out": ["hbs-car0"]}}, "hbs-car0"),
        ({"composed": {}, "split": "test"}, "split train"),
        ({"composed": {"source": "hbs-papr"}}, "hbs-papr"),
    ]:
        env = sharedspace.parallel_env(client=sim_client, **options)
        try:
            with pytest.raises(BadRequest, match=needle):
                env.reset()
        finally:
            env.close()


def test_scenes_compose_from_the_train_scenes_less_the_validation_split():
    cfg = TrainConfig(algorithm="ppo", task="paper", scenes=1000, device="cpu")
    composed = cfg.world.env_spec("train", 0).composed
    assert (composed.scenes, composed.source) == (1000, "hbs-paper")
    pool = cfg.world.pool_scenes()
    validation = {pool[i]["name"] for i in cfg.world.scene_indices("validation")}
    assert set(composed.hold_out) == validation and len(validation) == cfg.world.validation_scenes
    # Validation and test envs play recorded scenes only.
    assert cfg.world.env_spec("validation", 0).composed is None
    assert cfg.world.env_spec("test", 0).composed is None
    # -1: a fresh scene every episode; 0: none.
    assert (
        TrainConfig(algorithm="ppo", scenes=-1, device="cpu").world.composed_scenes().scenes is None
    )
    assert TrainConfig(algorithm="ppo", device="cpu").world.env_spec("train", 0).composed is None
    with pytest.raises(ConfigError, match="scenes must be"):
        TrainConfig(algorithm="ppo", scenes=-2, device="cpu")
    assert cfg.world_record()["composed"] == {"scenes": 1000, "seed": 0}


def test_a_tiny_ppo_run_trains_on_composed_scenes(tmp_path):
    pytest.importorskip("torchrl")
    from sharedspace.train.config import load_config
    from sharedspace.train.train import train

    cfg = load_config(
        None,
        [
            "algorithm=ppo",
            "task=paper",
            "scenes=-1",
            "num_envs=4",
            "rollout_steps=8",
            "minibatch_size=16",
            "total_frames=64",
            "hidden_sizes=16,16",
            "gcn_hidden=8",
            "eval_interval=0",
            "checkpoint_interval=0",
            "progress=false",
            f"log_dir={tmp_path}",
        ],
    )
    out = train(cfg)
    assert out["counters"]["frames"] >= 64
    saved = json.loads((tmp_path / "config.json").read_text())
    assert saved["scenes"] == -1
