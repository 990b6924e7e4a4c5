"""Every Python list of pedestrian models is sim-core's (``sharedspace.models``, from
``models.json``, which ``sim-core/tests/models.rs`` holds equal to ``sim_core::params::MODELS``),
and so is the list a live server reports."""

from __future__ import annotations

import sys
from pathlib import Path

from sharedspace import models
from sharedspace.client import Connection
from sharedspace.pettingzoo_env import SharedSpaceParallelEnv
from sharedspace.train.config import TrainConfig
from sharedspace.wire import EnvSpec

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from calibration import common, crossval, paired, plot_trajectories  # noqa: E402


def test_the_server_reports_the_same_models(sim_server, sim_client):
    info = sim_client.info(sim_server.server_id)
    assert tuple(info["pedestrian_models"]) == models.PEDESTRIAN_MODELS


def test_calibration_lists_derive_from_the_table():
    assert tuple(common.SPACES) == models.SOCIAL_FORCE_MODELS
    assert tuple(crossval.MODELS) == models.EVALUATED_MODELS
    assert tuple(plot_trajectories.MODELS) == models.EVALUATED_MODELS
    assert set(plot_trajectories.COLOURS) == set(models.EVALUATED_MODELS)
    assert paired.NAMES == models.LABELS
    # a model's calibrated parameters follow its weighting: cognitive > risk > plain SFM
    sizes = {m["name"]: len(common.SPACES[m["name"]]) for m in models.MODELS if m["social_force"]}
    assert sizes["sfm"] < sizes["ra_sfm"] < sizes["cr_sfm"]


def test_client_defaults_are_the_tables_default():
    assert models.DEFAULT_MODEL in models.PEDESTRIAN_MODELS
    assert TrainConfig().world.pedestrian_model == models.DEFAULT_MODEL
    assert EnvSpec().pedestrian_model == models.DEFAULT_MODEL
    assert SharedSpaceParallelEnv(client=Connection()).spec.pedestrian_model == models.DEFAULT_MODEL


def test_feature_and_reward_term_names_are_the_servers(sim_client):
    """names.json (kept equal to the protocol crate by protocol/tests/golden.rs) is what a live
    server sends: the observation layout's feature names and the reward terms, in order."""
    import numpy as np

    from sharedspace.names import FEATURE_NAMES, NODE_FEATURES, REWARD_TERMS, Feature

    created = sim_client.create(1)
    env = created["env_ids"][0]
    try:
        assert tuple(created["observation"]["feature_names"]) == FEATURE_NAMES
        sim_client.reset(env)
        step = sim_client.step(env, np.zeros((1, 2), dtype=np.float32))
        assert tuple(step["reward_terms"]) == REWARD_TERMS
        assert step["obs"]["features"].shape[-1] == NODE_FEATURES
        assert FEATURE_NAMES[Feature.GOAL_DIST] == "goal_dist"
    finally:
        sim_client.close(env)
