"""The PettingZoo ParallelEnv over a live sim-server."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import sharedspace
from sharedspace.names import Feature
from sharedspace.wire.errors import EnvClosed, WrongShape


@pytest.fixture
def penv(sim_server, sim_client):
    env = sharedspace.parallel_env(client=sim_client, max_agents=6, seed=1)
    yield env
    env.close()


def test_parallel_api(penv):
    assert penv.metadata["name"] == "sharedspace_v1"
    assert penv.possible_agents == ["vehicle_0"]
    parallel_api_test(penv, num_cycles=400)


def test_spaces(penv):
    obs_space = penv.observation_space("vehicle_0")
    assert obs_space is penv.observation_space("vehicle_0")
    assert penv.action_space("vehicle_0") is penv.action_space("vehicle_0")
    assert obs_space["features"].shape == (6, 11) and obs_space["adjacency"].shape == (6, 6)
    obs, infos = penv.reset(seed=3)
    assert obs_space.contains(obs["vehicle_0"]), obs
    assert isinstance(penv.scenario, str) and infos["vehicle_0"]["scenario_index"] >= 0


def _play(env, seed, steps=12):
    obs, infos = env.reset(seed=seed)
    trace = [env.scenario, obs["vehicle_0"]["features"].copy()]
    for t in range(steps):
        if not env.agents:
            break
        a = {"vehicle_0": np.array([np.sin(t), 0.3], np.float32)}
        obs, rew, term, trunc, _ = env.step(a)
        trace += [rew["vehicle_0"], obs["vehicle_0"]["features"].copy()]
    return trace


def test_seed_reproducible(penv):
    a, b = _play(penv, 42), _play(penv, 42)
    assert a[0] == b[0] and len(a) == len(b)
    for x, y in zip(a[1:], b[1:], strict=True):
        np.testing.assert_array_equal(x, y)


def test_seed_reproduces_whole_episodes(penv):
    def episodes(seed):
        trace = []
        penv.reset(seed=seed)
        for _ in range(3):  # three whole episodes: the seeded scenario sequence goes on
            obs, infos = penv.reset() if trace else penv.reset(seed=seed)
            trace += [(penv.scenario,), obs["vehicle_0"]["features"].copy()]
            t = 0
            while penv.agents:
                a = {"vehicle_0": np.array([np.sin(t), np.cos(t) * 0.5], np.float32)}
                obs, rew, term, trunc, infos = penv.step(a)
                trace.append((rew["vehicle_0"], term["vehicle_0"], trunc["vehicle_0"]))
                trace.append(obs["vehicle_0"]["features"].copy())
                t += 1
        return trace

    a, b = episodes(11), episodes(11)
    assert len(a) == len(b) and len(a) > 10
    for x, y in zip(a, b, strict=True):
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y)
        else:
            assert x == y


def test_max_cycles_truncates_and_state_is_in_its_space(sim_client):
    env = sharedspace.parallel_env(client=sim_client, max_agents=6, seed=2, max_cycles=3)
    try:
        obs, _ = env.reset(seed=2)
        state = env.state()
        assert env.state_space.contains(state) and state.shape == (6 * 11 + 36 + 6,)
        np.testing.assert_array_equal(state[: 6 * 11], obs["vehicle_0"]["features"].ravel())
        steps, trunc = 0, {}
        while env.agents:
            _, _, term, trunc, _ = env.step({"vehicle_0": np.zeros(2, np.float32)})
            steps += 1
        assert steps <= 3
        assert steps == 3 and trunc["vehicle_0"] or term["vehicle_0"]
        assert not env.state()[-6:].any()  # the vehicle has left: its part is zeros
        parallel_api_test(env, num_cycles=20)
    finally:
        env.close()


def test_infos_are_numbers_with_the_same_keys_at_reset_and_step(penv):
    from sharedspace.pettingzoo_env import INFO_KEYS

    _, infos = penv.reset(seed=5)
    seen = [infos["vehicle_0"]]
    while penv.agents:
        *_, infos = penv.step({"vehicle_0": np.array([1.0, 0.0], np.float32)})
        seen.append(infos["vehicle_0"])
    for info in seen:
        assert tuple(info) == INFO_KEYS
        assert all(isinstance(v, int | float | bool) for v in info.values()), info
    last = seen[-1]
    assert last["success"] + last["collision"] + last["timeout"] == 1
    assert last["episode_steps"] == len(seen) - 1 and last["avg_speed"] > 0


def test_torchrl_pettingzoo_wrapper_takes_the_env_as_it_is(sim_client):
    pytest.importorskip("torchrl")
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    for use_mask in (False, True):
        penv = sharedspace.parallel_env(client=sim_client, max_agents=6, seed=4)
        env = PettingZooWrapper(penv, use_mask=use_mask)
        try:
            check_env_specs(env)
            td = env.rollout(30, break_when_any_done=False)
            assert td["vehicle", "observation", "features"].shape[-2:] == (6, 11)
            assert td["next", "vehicle", "info", "reward_danger"].shape[0] == 30
        finally:
            env.close()


def test_errors(penv):
    penv.reset(seed=0)
    with pytest.raises(WrongShape, match=r"\[2\]"):
        penv.step({"vehicle_0": np.zeros(3, np.float32)})
    penv.close()
    with pytest.raises(EnvClosed):
        penv.step({"vehicle_0": np.zeros(2, np.float32)})


def test_render_rgb(sim_client):
    env = sharedspace.parallel_env(client=sim_client, render_mode="rgb_array", seed=2)
    try:
        env.reset(seed=2)
        frames, sources = [], []
        for _ in range(8):
            if not env.agents:
                env.reset()
            env.step({"vehicle_0": np.array([0.2, 0.0], np.float32)})
            frames.append(env.render())
            sources.append(env.render_source)
        assert "publications" in sources, sources
        img = frames[-1]
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
        assert img.shape[0] >= 100 and img.std() > 0
        # the controlled vehicle (scene_plot.CONTROLLED) is drawn
        blue = (np.abs(img.astype(int) - (31, 95, 208)).sum(-1) < 12).sum()
        assert blue > 20
        # its goal comes from the StatesMsg, where its own observation (ego frame) puts it too
        frame = env.scene_frame()
        ego = next(a for a in frame.agents if a.controlled)
        obs = env._obs["features"][0][0]
        dx, dy = float(obs[Feature.GOAL_DX]), float(obs[Feature.GOAL_DY])
        c, s = np.cos(ego.heading), np.sin(ego.heading)
        expected = (ego.x + c * dx - s * dy, ego.y + s * dx + c * dy)
        assert len(frame.goals) == 1
        np.testing.assert_allclose(frame.goals[0], expected, atol=1e-3)
    finally:
        env.close()


def test_pickle_and_deepcopy_make_envs_of_their_own(sim_server, sim_client):
    import copy
    import pickle

    env = sharedspace.parallel_env(client=sim_client, max_agents=6, seed=7, split="test")
    try:
        obs, _ = env.reset(seed=7)
        for clone in (pickle.loads(pickle.dumps(env)), copy.deepcopy(env)):
            try:
                assert clone.agents == [] and clone.possible_agents == env.possible_agents
                assert clone.spec == env.spec  # the spec travels whole
                o, _ = clone.reset(seed=7)  # its own server env and connection, same seed
                assert clone.env_id != env.env_id
                np.testing.assert_array_equal(
                    o["vehicle_0"]["features"], obs["vehicle_0"]["features"]
                )
                clone.step({"vehicle_0": np.zeros(2, np.float32)})
            finally:
                clone.close()
        env.step({"vehicle_0": np.zeros(2, np.float32)})  # the original is untouched
    finally:
        env.close()


def test_supersuit_vector_env_trains_stable_baselines3_sac(sim_server):
    supersuit = pytest.importorskip("supersuit")
    sb3 = pytest.importorskip("stable_baselines3")

    penv = sharedspace.parallel_env(
        endpoint=sim_server.endpoint, prefix=sim_server.prefix, max_agents=6, seed=0
    )
    venv = supersuit.pettingzoo_env_to_vec_env_v1(penv)
    venv = supersuit.concat_vec_envs_v1(venv, 2, num_cpus=0, base_class="stable_baselines3")
    try:
        model = sb3.SAC(
            "MultiInputPolicy",
            venv,
            learning_starts=50,
            batch_size=32,
            buffer_size=1_000,
            policy_kwargs={"net_arch": [32, 32]},
            verbose=0,
        )
        model.learn(total_timesteps=300)
        assert model.num_timesteps >= 300
        action, _ = model.predict(venv.reset(), deterministic=True)
        assert action.shape == (2, 2) and np.all(np.abs(action) <= 1.0)
    finally:
        venv.close()
        penv.close()


def test_the_aec_env_passes_pettingzoos_api_and_max_cycles_tests(sim_server, sim_client):
    from pettingzoo.test import api_test, max_cycles_test

    aec = sharedspace.env(client=sim_client, max_agents=6, seed=2)
    try:
        api_test(aec, num_cycles=200)
    finally:
        aec.close()

    class _Module:  # max_cycles_test builds its envs from a module with both constructors
        @staticmethod
        def env(max_cycles):
            return sharedspace.env(client=sim_client, max_agents=6, max_cycles=max_cycles)

        @staticmethod
        def parallel_env(max_cycles):
            return sharedspace.parallel_env(client=sim_client, max_agents=6, max_cycles=max_cycles)

    max_cycles_test(_Module)
