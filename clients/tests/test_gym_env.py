"""The Gymnasium env against a live server: registered id, Gymnasium's own env checker, an
episode, pickling and copying (lazy connection), and a vector env in worker processes."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

import sharedspace  # noqa: E402,F401 - registers the id
from sharedspace.gym_env import ENV_ID, SharedSpaceEnv  # noqa: E402


def make(sim_server, **kw):
    return gymnasium.make(ENV_ID, endpoint=sim_server.endpoint, prefix=sim_server.prefix, **kw)


def test_registered_env_passes_gymnasium_check_env(sim_server):
    from gymnasium.utils.env_checker import check_env

    env = make(sim_server)
    try:
        check_env(env.unwrapped, skip_render_check=True)
    finally:
        env.close()


def test_an_episode_and_seeded_resets(sim_server):
    env = make(sim_server, split="test")
    try:
        obs, info = env.reset(seed=3)
        first = obs["features"].copy()
        assert env.observation_space.contains(obs) and info["scenario_index"] >= 0
        done, steps = False, 0
        while not done:
            obs, reward, term, trunc, info = env.step(np.array([0.2, 0.0], np.float32))
            assert np.isfinite(reward)
            done, steps = term or trunc, steps + 1
        assert steps > 0 and info["success"] + info["collision"] + info["timeout"] == 1
        again, _ = env.reset(seed=3)
        np.testing.assert_array_equal(again["features"], first)
    finally:
        env.close()


def test_pickle_and_deepcopy_round_trips_connect_on_their_own(sim_server):
    env = SharedSpaceEnv(endpoint=sim_server.endpoint, prefix=sim_server.prefix, split="test")
    try:
        fresh = pickle.loads(pickle.dumps(env))  # before any connection
        obs, _ = env.reset(seed=1)
        clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env), fresh]
        for clone in clones:
            o, _ = clone.reset(seed=1)  # its own server env, same seed: same start
            np.testing.assert_array_equal(o["features"], obs["features"])
            clone.step(clone.action_space.sample())
            clone.close()
        env.step(env.action_space.sample())  # the original is untouched
    finally:
        env.close()


def test_async_vector_env_in_worker_processes(sim_server):
    endpoint, prefix = sim_server.endpoint, sim_server.prefix  # plain strings travel
    # "module:id" imports sharedspace (and so registers the id) in each fresh worker process
    env_id = f"sharedspace:{ENV_ID}"
    fns = [(lambda: gymnasium.make(env_id, endpoint=endpoint, prefix=prefix)) for _ in range(2)]
    venv = gymnasium.vector.AsyncVectorEnv(fns, context="spawn")
    try:
        obs, _ = venv.reset(seed=0)
        assert obs["features"].shape == (2, 8, 11)
        for _ in range(3):
            obs, rewards, *_ = venv.step(venv.action_space.sample())
        assert rewards.shape == (2,) and np.all(np.isfinite(rewards))
    finally:
        venv.close()
