"""Scenes beyond the paper's, through every env type against a live server: the general HBS
pool (every pedestrian and car of a car's window, entering and leaving) and several controlled
vehicles per env."""

from __future__ import annotations

import copy
import pickle

import gymnasium
import numpy as np
import pytest
from pettingzoo.test import parallel_api_test
from torchrl.envs.utils import check_env_specs

import sharedspace  # noqa: F401 - registers the Gymnasium id
from sharedspace.client import SimClient
from sharedspace.pettingzoo_env import SharedSpaceParallelEnv
from sharedspace.torchrl_env import RemoteBatchedEnv
from sharedspace.torchrl_multiagent import RemoteMultiAgentEnv
from sharedspace.vector import VectorClient

GENERAL = "hbs-general"
#: The general pool's crowd: 52 pedestrians (and 6 cars) pass through this car's 84 steps.
CROWD = "hbs-car1346"
M = 64  # observation nodes: the whole crowd in view


def _crowd_stats(node_ids_per_step: list[np.ndarray], masks: list[np.ndarray]) -> tuple:
    """Distinct agents seen, and whether the number present rose and fell over the episode."""
    seen, counts = set(), []
    for ids, mask in zip(node_ids_per_step, masks, strict=True):
        present = np.asarray(ids)[np.asarray(mask, bool)]
        seen.update(int(i) for i in present)
        counts.append(int(np.asarray(mask, bool).sum()))
    rises = any(b > a for a, b in zip(counts, counts[1:], strict=False))
    falls = any(b < a for a, b in zip(counts, counts[1:], strict=False))
    return len(seen), rises, falls


def test_the_server_lists_the_general_pool_next_to_the_paper_pool(sim_client):
    pools = {p["name"]: p for p in sim_client.pools()}
    assert list(pools)[0] == "hbs-paper"  # still the default
    assert GENERAL in pools and len(pools[GENERAL]["scenarios"]) > 300
    name, scenarios = sim_client.scenarios(GENERAL)
    assert name == GENERAL and (CROWD, "train") in [tuple(s) for s in scenarios]


def test_the_crowd_scene_has_fifty_pedestrians_entering_and_leaving():
    """The scene itself, played as recorded (`sim-server rollout`, every vehicle replayed)."""
    import json
    import subprocess

    from conftest import sim_server_binary

    out = subprocess.run(
        [
            str(sim_server_binary()),
            "rollout",
            "--pool",
            f"embedded:{GENERAL}",
            "--scenario",
            CROWD,
            "--model",
            "replay",
            "--av",
            "replay",
        ],
        check=True,
        capture_output=True,
        text=True,
        timeout=120,
    ).stdout.splitlines()
    lines = [json.loads(line) for line in out]
    kinds = {a["id"]: a["kind"] for a in lines[0]["agents"]}
    peds = {i for i, k in kinds.items() if k == "pedestrian"}
    events = [e for line in lines if line["type"] == "step" for e in line["events"]]
    entered = {e["agent"] for e in events if e["event"] == "entered"} & peds
    left = {e["agent"] for e in events if e["event"] == "left"} & peds
    present = [
        sum(kinds[a["id"]] == "pedestrian" for a in line["agents"])
        for line in lines
        if line["type"] == "step"
    ]
    assert len(peds) >= 50 and len(entered) >= 20 and len(left) >= 20, (
        len(peds),
        len(entered),
        len(left),
    )
    assert max(present) >= 15


@pytest.mark.parametrize("env_type", ["pettingzoo", "gymnasium", "torchrl", "torchrl_marl"])
def test_a_crowd_scene_runs_through_every_env_type(sim_server, env_type):
    """The crowd scene with the learner's car (a stopped car is soon hit by a recorded one:
    the general pool's other cars replay their record), up to 30 steps."""
    kw = dict(endpoint=sim_server.endpoint, prefix=sim_server.prefix, max_agents=M)
    steps = 0
    if env_type == "pettingzoo":
        env = SharedSpaceParallelEnv(**kw, pool=GENERAL, scenario=CROWD)
        obs, _ = env.reset(seed=1)
        assert env.scenario == CROWD and obs["vehicle_0"]["features"].shape == (M, 11)
        while env.agents and steps < 30:
            obs, *_ = env.step({a: np.zeros(2, np.float32) for a in env.agents})
            steps += 1
        env.close()
    elif env_type == "gymnasium":
        env = gymnasium.make("sharedspace/SharedSpace-v0", **kw, pool=GENERAL, scenario=CROWD)
        obs, info = env.reset(seed=1)
        assert env.unwrapped.scenario == CROWD and obs["mask"].shape == (M,)
        done = False
        while not done and steps < 30:
            obs, _, term, trunc, _ = env.step(np.zeros(2, np.float32))
            done, steps = term or trunc, steps + 1
        env.close()
    elif env_type == "torchrl":
        env = RemoteBatchedEnv(num_envs=2, pool=GENERAL, scenarios=[CROWD], **kw)
        td = env.rollout(10, break_when_any_done=False)
        assert td["features"].shape[-2:] == (M, 11)
        names = env.scenario_names
        assert {names[int(i)] for i in td["scenario_index"].flatten()} == {CROWD}
        steps = td.shape[-1]
        env.close()
    else:
        env = RemoteMultiAgentEnv(num_envs=2, pool=GENERAL, scenario=CROWD, **kw)
        td = env.rollout(10, break_when_any_done=False)
        assert td["vehicle", "features"].shape[-3:] == (2, M, 11)
        assert env.scenarios == [CROWD, CROWD]
        steps = td.shape[-1]
        env.close()
    assert steps >= 1


def test_two_controlled_vehicles_in_the_torchrl_multi_agent_env(sim_server):
    env = RemoteMultiAgentEnv(
        num_envs=3,
        external_agents=("vehicle_0", "vehicle_1"),
        pool=GENERAL,
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        seed=5,
    )
    try:
        check_env_specs(env)
        td = env.rollout(60, break_when_any_done=False)  # long enough for some episodes to end
        assert td["next", "vehicle", "reward"].shape == (3, 60, 2, 1)
        assert td["vehicle", "action"].shape == (3, 60, 2, 2)
        done = td["next", "done"].squeeze(-1)
        agent_done = td["next", "vehicle", "done"].squeeze(-1)
        # The env's episode is over exactly when both vehicles' episodes are.
        assert (done == agent_done.all(-1)).all()
        assert np.isfinite(td["next", "vehicle", "reward"].numpy()).all()
        clone = pickle.loads(pickle.dumps(env))  # its own connection and server envs
        assert clone.vec.env_ids != env.vec.env_ids
        clone.close()
    finally:
        env.close()


def test_two_controlled_vehicles_in_pettingzoo_pass_the_parallel_api_test(sim_server):
    env = SharedSpaceParallelEnv(
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        external_agents=("vehicle_0", "vehicle_1"),
        pool=GENERAL,
        seed=3,
    )
    parallel_api_test(env, num_cycles=40)
    obs, _ = env.reset(seed=3)
    assert set(obs) == {"vehicle_0", "vehicle_1"}
    assert env.state().shape == env.state_space.shape
    copy.deepcopy(env).close()
    env.close()


def test_each_vehicle_leaves_a_pettingzoo_episode_only_with_its_own_outcome(sim_server):
    """Every controlled car stays in ``env.agents`` until the server ends its episode, and leaves
    with exactly one of success, collision or timeout in its info. (The second car used to be
    reported terminated on the first step, with no outcome: its flag was read from a variable
    that the loop over reward terms had overwritten.)"""
    env = SharedSpaceParallelEnv(
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        external_agents=("vehicle_0", "vehicle_1"),
        synthetic=SYNTHETIC,
        max_agents=M,
    )
    env.reset(seed=0)
    left: dict[str, list[str]] = {}
    steps = 0
    while env.agents:
        live = list(env.agents)
        _, _, terms, truncs, infos = env.step({a: np.zeros(2, np.float32) for a in live})
        steps += 1
        if steps == 1:
            assert env.agents == ["vehicle_0", "vehicle_1"], (terms, truncs)
        for a in live:
            if terms[a] or truncs[a]:
                left[a] = [k for k in ("success", "collision", "timeout") if infos[a][k]]
    env.close()
    assert sorted(left) == ["vehicle_0", "vehicle_1"]
    assert all(len(outcome) == 1 for outcome in left.values()), left


def test_a_list_of_scenarios_is_played_in_turn(sim_server):
    with SimClient(sim_server.endpoint, sim_server.prefix) as client:
        _, names = client.scenarios(GENERAL)
    train = [n for n, split in names if split == "train"][:3]
    env = SharedSpaceParallelEnv(
        endpoint=sim_server.endpoint, prefix=sim_server.prefix, pool=GENERAL, scenario=train
    )
    played = []
    for _ in range(4):
        env.reset()
        played.append(env.scenario)
    env.close()
    assert played == [*train, train[0]]


SYNTHETIC = {"layout": "crossing", "pedestrians": 60, "vehicles": 2, "seed": 11, "scenes": 2}


@pytest.mark.parametrize("env_type", ["pettingzoo", "torchrl", "torchrl_marl"])
def test_synthetic_crowds_with_two_vehicles_are_asked_for_at_env_creation(sim_server, env_type):
    kw = dict(endpoint=sim_server.endpoint, prefix=sim_server.prefix, max_agents=M)
    if env_type == "pettingzoo":
        env = SharedSpaceParallelEnv(
            **kw, external_agents=("vehicle_0", "vehicle_1"), synthetic=SYNTHETIC
        )
        env.reset(seed=0)
        assert env.scenario.startswith("synthetic-crossing-n60-v2-seed")
        assert len(env._agents_desc) == 62
        obs, rewards, *_ = env.step({a: np.zeros(2, np.float32) for a in env.agents})
        assert set(rewards) == {"vehicle_0", "vehicle_1"}
        # Far more than the default 8 nodes: the crowd within the perception radius.
        assert int(obs["vehicle_0"]["mask"].sum()) >= 30
        env.close()
    elif env_type == "torchrl":
        env = RemoteBatchedEnv(num_envs=2, synthetic=SYNTHETIC, scenario_order="sequential", **kw)
        td = env.rollout(5, break_when_any_done=False)
        names = [env.scenario_names[int(i)] for i in td["scenario_index"][:, 0].flatten()]
        assert names == ["synthetic-crossing-n60-v2-seed11", "synthetic-crossing-n60-v2-seed12"]
        env.close()
    else:
        env = RemoteMultiAgentEnv(num_envs=2, synthetic=SYNTHETIC, **kw)
        check_env_specs(env)
        td = env.rollout(5, break_when_any_done=False)
        # At the start both cars see a crowd (a car whose episode ended sees padding).
        assert td["vehicle", "mask"][:, 0].sum(-1).min() >= 10
        env.close()


def test_the_synth_command_writes_a_pool_a_server_serves(tmp_path, server_factory):
    import json
    import subprocess

    from conftest import free_port, sim_server_binary

    out = tmp_path / "crowds.json"
    subprocess.run(
        [
            str(sim_server_binary()),
            "synth",
            "--layout",
            "random",
            "--pedestrians",
            "55",
            "--vehicles",
            "2",
            "--scenes",
            "13",
            "--name",
            "crowds",
            "--out",
            str(out),
        ],
        check=True,
        timeout=60,
    )
    pool = json.loads(out.read_text())
    assert pool["name"] == "crowds" and len(pool["scenarios"]) == 13
    assert {s["split"] for s in pool["scenarios"]} == {"train", "test"}
    srv = server_factory(f"synth{free_port()}", "s0", f'pools:["{out}"]')
    with SimClient(srv.endpoint, srv.prefix) as client:
        assert [p["name"] for p in client.pools()] == ["crowds"]
        with VectorClient(1, client=client, pool="crowds", split="test", max_agents=M) as vec:
            first = vec.reset()[0]
            assert len(first["agents"]) == 57


def test_wrong_scenario_lists_and_a_pool_beside_synthetic_scenes_are_refused(sim_server):
    kw = dict(endpoint=sim_server.endpoint, prefix=sim_server.prefix)
    with pytest.raises(ValueError, match="not test scenarios"):
        RemoteBatchedEnv(num_envs=1, split="test", scenarios=["hbs-car1346"], pool=GENERAL, **kw)
    with pytest.raises(ValueError, match="empty list"):
        RemoteBatchedEnv(num_envs=1, scenarios=[], **kw)
    with pytest.raises(ValueError, match="exclude each other"):
        RemoteBatchedEnv(num_envs=1, pool=GENERAL, synthetic=SYNTHETIC, **kw)
    with pytest.raises(ValueError, match="empty list"):
        SharedSpaceParallelEnv(scenario=[], **kw)
