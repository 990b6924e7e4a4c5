"""RemoteBatchedEnv (ENV_CONTRACT.md) over a live sim-server."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from local_env import LocalBatchedEnv  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

from sharedspace.torchrl_env import RemoteBatchedEnv  # noqa: E402


@pytest.fixture
def renv(sim_client):
    env = RemoteBatchedEnv(num_envs=4, max_agents=6, seed=0, client=sim_client)
    yield env
    env.close()


def test_check_env_specs(renv):
    check_env_specs(renv)


def test_same_specs_as_local(renv):
    local = LocalBatchedEnv(num_envs=4, max_agents=6, seed=0)
    assert renv.observation_spec == local.observation_spec
    assert renv.action_spec == local.action_spec
    assert renv.reward_spec == local.reward_spec
    assert renv.done_spec == local.done_spec


def test_partial_reset_uses_autoreset_without_round_trip(renv, monkeypatch):
    td = renv.reset()
    calls = []
    orig = renv.vec.client.reset_many
    monkeypatch.setattr(
        renv.vec.client, "reset_many", lambda *a, **k: calls.append(a) or orig(*a, **k)
    )
    ends = 0
    for t in range(150):
        td["action"] = torch.from_numpy(
            np.random.default_rng(t).uniform(-1, 1, (4, 2)).astype(np.float32)
        )
        out, td = renv.step_and_maybe_reset(td)
        done = out["next", "done"].reshape(-1)
        ends += int(done.sum())
        for k in torch.nonzero(done).reshape(-1).tolist():
            n_flags = sum(
                int(out["next", key][k, 0])
                for key in ("episode_success", "episode_collision", "episode_timeout")
            )
            assert n_flags == 1
            assert not td["done"][k, 0]
    assert ends > 0
    assert calls == [], "partial resets of done sub-envs must not query the server"
    assert renv.env_time_s > 0


def test_stepping_a_done_env_is_an_error(renv):
    td = renv.reset()
    for _ in range(300):
        td["action"] = torch.ones(4, 2)
        td = renv.step(td)["next"]
        if td["done"].any():
            break
    assert td["done"].any()
    td["action"] = torch.zeros(4, 2)
    with pytest.raises(RuntimeError, match="reset"):
        renv.step(td)


def test_sequential_covers_the_test_split(sim_client):
    env = RemoteBatchedEnv(
        num_envs=18, max_agents=4, split="test", scenario_order="sequential", client=sim_client
    )
    try:
        td = env.reset()
        local = LocalBatchedEnv(
            num_envs=18, max_agents=4, split="test", scenario_order="sequential"
        )
        assert (
            td["scenario_index"].reshape(-1).tolist()
            == local.reset()["scenario_index"].reshape(-1).tolist()
        )
    finally:
        env.close()


def test_set_seed_restarts_the_sequence(sim_client):
    env = RemoteBatchedEnv(num_envs=3, max_agents=4, seed=5, client=sim_client)
    try:
        first = env.reset()["scenario_index"].clone()
        env.reset()
        env.set_seed(5)
        again = env.reset()["scenario_index"]
        assert torch.equal(first, again)
    finally:
        env.close()


def test_pickle_and_deepcopy_make_envs_of_their_own(sim_client):
    import copy
    import pickle

    env = RemoteBatchedEnv(
        num_envs=2, max_agents=5, seed=3, client=sim_client, reward_weights={"danger": -0.5}
    )
    try:
        first = env.reset()
        for clone in (pickle.loads(pickle.dumps(env)), copy.deepcopy(env)):
            try:
                assert clone.vec.spec == env.vec.spec  # the spec travels whole
                assert clone.batch_size == env.batch_size
                assert set(clone.vec.env_ids).isdisjoint(env.vec.env_ids)
                td = clone.reset()  # seeded like the original at creation: same first episodes
                assert torch.equal(td["features"], first["features"])
                clone.rand_step(td)
            finally:
                clone.close()
        env.rand_step(first)  # the original is untouched
    finally:
        env.close()


def test_an_env_option_is_checked_before_any_env_is_made(sim_client):
    """A misspelt option, an ill-typed field and a connection beside a shared client are
    refused by name at construction; the server is not asked."""
    open_envs = sim_client.info(sim_client.servers()[0]["server_id"])["load"]
    with pytest.raises(TypeError, match="max_agent"):
        RemoteBatchedEnv(num_envs=2, max_agent=5, client=sim_client)
    with pytest.raises(ValueError, match="EnvSpec.vehicle_model"):
        RemoteBatchedEnv(num_envs=2, vehicle_model="teleport", client=sim_client)
    with pytest.raises(ValueError, match="endpoint"):
        RemoteBatchedEnv(num_envs=2, endpoint="tcp/127.0.0.1:1", client=sim_client)
    assert sim_client.info(sim_client.servers()[0]["server_id"])["load"] == open_envs


def test_a_spec_built_once_is_passed_whole(sim_client):
    from sharedspace.wire import EnvSpec

    spec = EnvSpec(max_agents=5, seed=2, split="test", reward_weights={"danger": -0.5})
    env = RemoteBatchedEnv(spec, 2, client=sim_client, scenario_order="sequential")
    try:
        assert env.vec.spec == spec.replace(autoreset=False)  # autoreset: the adapter's
        assert env.reset()["features"].shape == (2, 5, 11)
    finally:
        env.close()


def test_two_controlled_vehicles_are_refused_by_the_single_vehicle_env(sim_client):
    with pytest.raises(ValueError, match="one external agent"):
        RemoteBatchedEnv(num_envs=1, external_agents=("vehicle_0", "vehicle_1"), client=sim_client)
