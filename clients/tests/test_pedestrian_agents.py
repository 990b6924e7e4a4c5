"""Pedestrians under external control (issue 60), against a live server: a mixed env, one learned
car and one learned pedestrian among CR-SFM pedestrians and IDM cars, passes PettingZoo's and
TorchRL's own checks, and a pedestrian the scenes lack is refused by name."""

from __future__ import annotations

import pytest

pytest.importorskip("pettingzoo")

import sharedspace  # noqa: E402
from sharedspace.wire.errors import ServerError  # noqa: E402

MIXED = ("vehicle_0", "pedestrian_0")


def options(sim_server):
    return dict(
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        external_agents=MIXED,
        pool="hbs-general",
        vehicle_model="idm",
        max_agents=8,
    )


def test_a_mixed_env_passes_pettingzoo_parallel_api_test(sim_server):
    from pettingzoo.test import parallel_api_test

    env = sharedspace.parallel_env(**options(sim_server))
    try:
        obs, _ = env.reset(seed=0)
        assert env.possible_agents == list(MIXED)
        assert all(obs[a]["features"].shape == (8, 11) for a in MIXED)
        parallel_api_test(env, num_cycles=200)
    finally:
        env.close()


def test_a_mixed_env_passes_torchrl_check_env_specs(sim_server):
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    env = sharedspace.RemoteMultiAgentEnv(num_envs=2, **options(sim_server))
    try:
        check_env_specs(env)
        # grouped by kind: one car, one pedestrian, each with its own tensors
        assert env.groups == {"vehicle": [0], "pedestrian": [1]}
        td = env.rollout(4)
        for group in ("vehicle", "pedestrian"):
            assert td[group, "action"].shape == (2, 4, 1, 2)
            assert td["next", group, "features"].shape == (2, 4, 1, 8, 11)
            assert td["next", group, "reward"].shape == (2, 4, 1, 1)
    finally:
        env.close()


def test_a_pedestrian_the_scenes_lack_is_refused_by_name(sim_server):
    env = sharedspace.parallel_env(
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        external_agents=("vehicle_0", "pedestrian_3"),  # hbs-paper's scenes have 3
    )
    try:
        with pytest.raises(ServerError, match="3 pedestrian|4 pedestrian"):
            env.reset(seed=0)
    finally:
        env.close()


def test_a_gymnasium_env_drives_one_pedestrian_and_passes_check_env(sim_server):
    gymnasium = pytest.importorskip("gymnasium")
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make(
        "sharedspace/SharedSpace-v0",
        agent="pedestrian_0",
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        split="test",
    )
    try:
        check_env(env.unwrapped, skip_render_check=True)
        obs, info = env.reset(seed=0)
        assert obs["features"][0, 7] == 0.0  # node 0, is_vehicle: itself, a pedestrian
        done, steps = False, 0
        while not done:
            obs, reward, term, trunc, info = env.step([1.0, 0.0])  # walk straight on
            done, steps = term or trunc, steps + 1
        assert info["success"] + info["collision"] + info["timeout"] == 1
    finally:
        env.close()
    with pytest.raises(ValueError, match="'walker_0'"):
        gymnasium.make("sharedspace/SharedSpace-v0", agent="walker_0")


def test_agent_names_are_parsed_once():
    from sharedspace.names import agent_group

    assert agent_group("vehicle_0") == "vehicle" and agent_group("pedestrian_12") == "pedestrian"
    for bad in ("pedestrian_01", "pedestrian_", "bus_0", "vehicle_x"):
        with pytest.raises(ValueError, match=repr(bad)):
            agent_group(bad)
