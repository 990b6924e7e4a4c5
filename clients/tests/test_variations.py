"""Seeded scene variations (SPEC 5.2.1) through live servers and every client: the same
(scene, variation seed) plays bit-identically on two server processes, every refused value is
named, and the PettingZoo, Gymnasium and TorchRL envs and TrainConfig take them."""

from __future__ import annotations

import json
import math
import re
import subprocess

import gymnasium as gym
import msgspec
import numpy as np
import pytest
from conftest import sim_server_binary, unique_prefix

import sharedspace
from sharedspace.client import SimClient
from sharedspace.outcomes import BENCHMARK_VARIATIONS
from sharedspace.stats import cluster_bootstrap, paired_clustered
from sharedspace.torchrl_env import RemoteBatchedEnv
from sharedspace.train.config import TrainConfig, apply_overrides
from sharedspace.wire import envelope, requests
from sharedspace.wire.errors import BadRequest

STRONG = {
    "position_sigma": 0.5,
    "start_offset_steps": 2,
    "desired_speed_scale": 0.2,
    "param_noise": {"a_ped": 0.2, "tau": 0.1},
    "mirror": True,
    "rotation_deg": 180.0,
}


def _episode(client: SimClient, variation: int, scenario: str = "hbs-car1203") -> list[bytes]:
    """Every observation of one episode of ``scenario`` in ``variation``, as bytes, with a
    fixed action sequence."""
    env = client.create(
        1, split="test", seed=5, max_agents=6, variations=STRONG, scenario=scenario
    )["env_ids"][0]
    try:
        r = client.reset(env, variation=variation)
        out = [json.dumps(r["variation"], sort_keys=True).encode()]
        out.append(np.asarray(r["obs"]["features"]).tobytes())
        for t in range(60):
            a = np.array([[math.sin(0.3 * t), 0.5 * math.cos(0.2 * t)]], dtype=np.float32)
            s = client.step(env, a)
            out.append(np.asarray(s["obs"]["features"]).tobytes())
            out.append(np.asarray(s["obs"]["adjacency"]).tobytes())
            if bool(np.asarray(s["terminated"]).any() or np.asarray(s["truncated"]).any()):
                break
        return out
    finally:
        client.close(env)


def test_the_same_variation_seed_plays_bit_identically_on_two_server_processes(server_factory):
    prefix = unique_prefix()
    a = server_factory(prefix + "a", "va")
    b = server_factory(prefix + "b", "vb")
    with (
        SimClient(a.endpoint, a.prefix, timeout=10) as ca,
        SimClient(b.endpoint, b.prefix, timeout=10) as cb,
    ):
        test_scene = ca.scenarios(None, "va")[1]
        name = next(n for n, split in test_scene if split == "test")
        first, second = _episode(ca, 17, name), _episode(cb, 17, name)
        assert len(first) > 10
        assert first == second
        other = _episode(ca, 18, name)
        assert other[0] != first[0] and other[1:] != first[1:]


def test_the_reset_reports_what_rollout_replays(sim_client, tmp_path):
    """The values a server env reports are the ones ``sim-server rollout --variation`` draws
    (same spec, same world parameters): any episode can be replayed from its seed."""
    env = sim_client.create(1, split="test", variations=BENCHMARK_VARIATIONS)["env_ids"][0]
    try:
        r = sim_client.reset(env, variation=4)
    finally:
        sim_client.close(env)
    v = r["variation"]
    assert v["seed"] == 4 and not v["mirrored"] and v["rotation_deg"] == 0.0
    assert {p["start_shift"] for p in v["pedestrians"]} <= {-1, 0, 1}
    assert all(0.9 <= p["speed_scale"] <= 1.1 for p in v["pedestrians"])
    out = subprocess.run(
        [
            str(sim_server_binary()),
            "rollout",
            "--scenario",
            r["scenario"],
            "--av",
            "0,0",
            "--variation",
            "4",
            "--variations",
            json.dumps(BENCHMARK_VARIATIONS),
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    header = json.loads(out.stdout.splitlines()[0])
    assert header["variation"] == v


def test_an_env_draws_a_new_variation_each_episode_and_replays_with_its_seed(sim_client):
    created = sim_client.create(2, split="train", seed=3, variations=BENCHMARK_VARIATIONS)
    ids = created["env_ids"]
    try:
        seeds = [sim_client.reset(ids[0])["variation"]["seed"] for _ in range(3)]
        assert len(set(seeds)) == 3
        again = sim_client.reset(ids[0], seed=3)["variation"]["seed"]
        assert again == seeds[0], "Reset.seed restarts the env's stream of variation seeds"
        other = sim_client.reset(ids[1])["variation"]["seed"]
        assert other not in seeds, "env k + 1 has a stream of its own"
        pinned = sim_client.reset(ids[1], variation=seeds[1])
        assert pinned["variation"]["seed"] == seeds[1]
    finally:
        sim_client.close_many(ids)


@pytest.mark.parametrize(
    "variations,field",
    [
        ({"position_sigma": -0.1}, "variations.position_sigma"),
        ({"position_sigma": float("nan")}, "variations.position_sigma"),
        ({"position_sigma": 11.0}, "variations.position_sigma"),
        ({"start_offset_steps": 21}, "variations.start_offset_steps"),
        ({"desired_speed_scale": 1.0}, "variations.desired_speed_scale"),
        ({"param_noise": {"a_pedd": 0.1}}, "variations.param_noise.a_pedd"),
        ({"param_noise": {"tau": -0.5}}, "variations.param_noise.tau"),
        ({"rotation_deg": 190.0}, "variations.rotation_deg"),
        ({"rotation_deg": float("inf")}, "variations.rotation_deg"),
    ],
)
def test_every_refused_value_is_named_and_the_server_serves_on(sim_client, variations, field):
    with pytest.raises(BadRequest) as e:
        sim_client.create(1, variations=variations)
    assert field in str(e.value)
    env = sim_client.create(1)["env_ids"][0]
    sim_client.reset(env)
    sim_client.close(env)


@pytest.mark.parametrize(
    "variations,field",
    [({"rotate": 10.0}, "rotate"), ({"start_offset_steps": -1}, "variations.start_offset_steps")],
)
def test_a_misspelt_or_ill_typed_variation_is_refused_before_it_is_sent(
    sim_client, variations, field
):
    with pytest.raises(ValueError, match=re.escape(field)):
        sim_client.create(1, variations=variations)


def test_a_variation_seed_without_variations_is_refused(sim_client):
    env = sim_client.create(1)["env_ids"][0]
    try:
        with pytest.raises(BadRequest, match="no variations"):
            sim_client.reset(env, variation=1)
    finally:
        sim_client.close(env)


def test_a_pool_entry_carries_default_variations(server_factory):
    spec = json.dumps([{"path": "embedded:hbs-paper", "variations": {"position_sigma": 0.3}}])
    s = server_factory(unique_prefix(), "pv", f"pools:{spec}")
    with SimClient(s.endpoint, s.prefix, timeout=10) as c:
        env = c.create(1)["env_ids"][0]
        v = c.reset(env)["variation"]
        assert v is not None and any(p["offset"] != [0.0, 0.0] for p in v["pedestrians"])
        own = c.create(1, variations={"rotation_deg": 30.0})["env_ids"][0]
        w = c.reset(own)["variation"]
        assert all(p["offset"] == [0.0, 0.0] for p in w["pedestrians"]), "the env's own wins"


def test_batched_autoresets_report_their_variation_seeds(sim_client):
    env = RemoteBatchedEnv(
        num_envs=4, client=sim_client, split="train", seed=2, variations=BENCHMARK_VARIATIONS
    )
    try:
        env.reset()
        first = list(env.last_variation_seeds)
        assert None not in first and len(set(first)) == 4
        env.rollout(200, break_when_any_done=False)
        assert env.last_variation_seeds != first, (
            "an autoreset draws the next variation and reports its seed"
        )
    finally:
        env.close()


def test_fixed_variation_seeds_pair_episodes_across_envs(sim_client):
    kw = dict(
        num_envs=3,
        client=sim_client,
        split="test",
        scenario_order="sequential",
        variations=BENCHMARK_VARIATIONS,
        variation_seeds=[7, 7, 9],
    )
    a, b = RemoteBatchedEnv(seed=0, **kw), RemoteBatchedEnv(seed=123, **kw)
    try:
        ta, tb = a.reset(), b.reset()
        assert a.last_variation_seeds == [7, 7, 9]
        assert np.array_equal(ta["features"].numpy(), tb["features"].numpy())
    finally:
        a.close()
        b.close()
    with pytest.raises(ValueError, match="need variations"):
        RemoteBatchedEnv(num_envs=1, client=sim_client, variation_seeds=[1])


def test_pettingzoo_and_gymnasium_take_variations(sim_server, sim_client):
    penv = sharedspace.parallel_env(client=sim_client, variations=BENCHMARK_VARIATIONS, seed=4)
    try:
        penv.reset()
        assert penv.variation["seed"] >= 0
        penv.reset(options={"variation": 11})
        assert penv.variation["seed"] == 11
    finally:
        penv.close()
    genv = gym.make(
        "sharedspace/SharedSpace-v0",
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        variations={"rotation_deg": 45.0},
    )
    try:
        genv.reset(seed=1)
        assert abs(genv.unwrapped._parallel.variation["rotation_deg"]) <= 45.0
    finally:
        genv.close()


def test_train_config_takes_variations_as_json():
    cfg = apply_overrides(TrainConfig(), ['variations={"position_sigma": 0.25}'])
    assert cfg.world.variations == {"position_sigma": 0.25}
    assert apply_overrides(cfg, ["variations="]).world.variations == {}
    with pytest.raises(ValueError, match="JSON object"):
        apply_overrides(TrainConfig(), ["variations=[1]"])


def test_a_variation_seed_in_a_reset_request_is_encoded_only_when_given():
    assert requests.encode_reset(7, None) == envelope.encode({"seed": 7, "scenario": None})
    assert msgspec.msgpack.decode(requests.encode_reset(None, None, 5))["variation"] == 5


def test_the_clustered_interval_is_as_wide_as_the_scenes_warrant():
    # Two scenes that disagree completely: 1000 episodes each do not make the mean certain.
    lo, hi = cluster_bootstrap([[1.0] * 1000, [0.0] * 1000])
    assert lo == 0.0 and hi == 1.0
    # Identical scenes: the interval shrinks to the point.
    assert cluster_bootstrap([[0.5, 0.5]] * 10) == (0.5, 0.5)
    a = {(s, v): 1.0 for s in range(4) for v in range(8)}
    b = {(s, v): float(s < 2) for s in range(4) for v in range(8)}
    d = paired_clustered(a, b)
    assert d["diff"] == 0.5 and d["pairs"] == 32 and d["scenes"] == 4
    assert 0.0 <= d["lo"] <= 0.5 <= d["hi"] <= 1.0


def test_two_pools_of_one_name_are_refused_naming_both(tmp_path):
    """A pool is chosen by name, so a second pool of the same name could never be reached: the
    server refuses to start and names both entries."""
    from sharedspace.pool import DEFAULT_POOL_PATH

    first, second = tmp_path / "a.json", tmp_path / "b.json"
    first.write_text(DEFAULT_POOL_PATH.read_text())
    second.write_text(DEFAULT_POOL_PATH.read_text())
    err = _serve_refused([str(first), {"path": str(second)}])
    assert str(first) in err and str(second) in err, err
    assert "hbs-paper" in err


def test_a_pool_entry_with_bad_variations_stops_the_server_naming_the_entry_and_field():
    err = _serve_refused([{"path": "embedded:hbs-paper", "variations": {"rotation_deg": 400}}])
    assert "embedded:hbs-paper" in err and "variations.rotation_deg" in err, err


@pytest.mark.parametrize(
    "spec,message",
    [
        ('{"rotation_deg": 500}', "variations.rotation_deg"),
        ('{"rotate": 5}', "rotate"),
        ("not json", "--variations"),
    ],
)
def test_rollout_refuses_bad_variations_naming_them(spec, message):
    out = subprocess.run(
        [str(sim_server_binary()), "rollout", "--av", "0,0", "--variation", "1"]
        + ["--variations", spec],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode != 0 and message in out.stderr, out.stderr
    assert out.stdout == "", "nothing is written for a refused spec"


def test_variation_seeds_must_match_the_sub_envs(sim_client):
    with pytest.raises(ValueError, match="2 seeds for 3 sub-envs"):
        RemoteBatchedEnv(num_envs=3, client=sim_client, variations={}, variation_seeds=[1, 2])


def _serve_refused(pools) -> str:
    """Starts ``sim-server serve`` with ``pools``, expects it to refuse; its error output."""
    out = subprocess.run(
        [
            str(sim_server_binary()),
            "serve",
            "--cfg",
            'zenoh/listen/endpoints:["tcp/127.0.0.1:0"]',
            "--cfg",
            f"pools:{json.dumps(pools)}",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode != 0
    return out.stderr
