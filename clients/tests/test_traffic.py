"""Reactive traffic (docs/MODEL.md 11) through a live server and the clients: the general pool's
cars react by default and are marked in the published states, ``vehicle_model`` selects the
model per env, a bad one is refused naming the field, and the envs and TrainConfig take it."""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
import pytest
from conftest import sim_server_binary, unique_prefix

from sharedspace.client import SimClient
from sharedspace.models import DEFAULT_VEHICLE_MODEL, VEHICLE_MODELS
from sharedspace.observer import Observer
from sharedspace.pettingzoo_env import SharedSpaceParallelEnv
from sharedspace.scene_plot import frame_from_publications
from sharedspace.train.config import TrainConfig
from sharedspace.wire import EnvSpec, requests
from sharedspace.wire.envelope import encode
from sharedspace.wire.errors import BadRequest

GENERAL = "hbs-general"
#: A general-pool test scene with other cars from the first step.
SCENE = "hbs-car1138"


def _first_states(client, **create) -> dict:
    """The states published after the first step of a new env on :data:`SCENE`."""
    with Observer(transport=client.transport, env_id="*", topics=("states",)) as obs:
        env = client.create(1, pool=GENERAL, split="test", scenario=SCENE, **create)["env_ids"][0]
        try:
            client.reset(env)
            client.step(env, np.zeros((1, 2), np.float32))
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                m = obs.get(0.1)
                if m is not None and m["env_id"] == env and m["step"] >= 1:
                    return m
        finally:
            client.close(env)
    raise AssertionError("no states published")


def test_the_vehicle_models_come_from_the_sim_core_table():
    assert VEHICLE_MODELS == ("replay", "idm") and DEFAULT_VEHICLE_MODEL == "replay"


def test_general_pool_cars_react_by_default_and_are_marked_in_the_states(sim_client):
    states = _first_states(sim_client)
    reactive = np.asarray(states["reactive"], bool)
    kinds = np.asarray(states["kinds"])
    external = np.asarray(states["external"], bool)
    assert reactive.any(), "no reactive car in the general pool's scene"
    # Only vehicles nobody controls are reactive: never a pedestrian, never the learner's car.
    assert not (reactive & (kinds != 0)).any()
    assert not (reactive & external).any()
    assert (reactive == ((kinds == 0) & ~external)).all()


def test_vehicle_model_replay_gives_replayed_cars_and_no_reactive_column(sim_client):
    states = _first_states(sim_client, vehicle_model="replay")
    assert states.get("reactive") is None


def test_the_paper_pool_replays_its_cars(sim_client):
    env = sim_client.create(1, split="test")["env_ids"][0]
    try:
        assert sim_client.reset(env)["obs"] is not None
    finally:
        sim_client.close(env)


def test_a_bad_vehicle_model_is_refused_naming_the_field(sim_client):
    # by the client's spec, where it is written ...
    with pytest.raises(ValueError, match="EnvSpec.vehicle_model"):
        sim_client.create(1, pool=GENERAL, vehicle_model="teleport")
    # ... and by the server, for a client that sends it anyway
    request = requests.create_env(EnvSpec(pool=GENERAL), sim_client.client_id)
    sid = str(sim_client.pick_server()["server_id"])
    key = sim_client.transport.key("server", sid, "env", "create")
    with pytest.raises(BadRequest, match="vehicle_model"):
        sim_client.request(sid, key, encode(request | {"vehicle_model": "teleport"}))


def test_scene_plots_mark_reactive_cars():
    states = {
        "ids": np.array([0, 1, 2]),
        "kinds": np.array([0, 0, 1]),
        "positions": np.zeros((3, 2)),
        "velocities": np.zeros((3, 2)),
        "headings": np.zeros(3),
        "reactive": np.array([0, 1, 0], np.uint8),
    }
    frame = frame_from_publications(states, None, {0: {"external": True}})
    assert [a.reactive for a in frame.agents] == [False, True, False]
    states.pop("reactive")
    assert not any(a.reactive for a in frame_from_publications(states, None, {}).agents)


def test_the_pettingzoo_env_takes_a_vehicle_model(sim_server):
    env = SharedSpaceParallelEnv(
        endpoint=sim_server.endpoint,
        prefix=sim_server.prefix,
        pool=GENERAL,
        split="test",
        scenario=SCENE,
        vehicle_model="replay",
    )
    try:
        obs, _ = env.reset(seed=1)
        assert obs
    finally:
        env.close()


def test_train_config_checks_the_vehicle_model():
    assert TrainConfig(vehicle_model="idm").world.vehicle_model == "idm"
    assert TrainConfig().world.vehicle_model == ""  # the pool's
    with pytest.raises(ValueError, match="vehicle_model"):
        TrainConfig(vehicle_model="teleport")


def test_a_server_pool_entry_sets_the_vehicle_model(server_factory):
    spec = json.dumps([{"path": f"embedded:{GENERAL}", "vehicle_model": "replay"}])
    s = server_factory(unique_prefix(), "vm", f"pools:{spec}")
    with SimClient(s.endpoint, s.prefix, timeout=10) as c:
        assert _first_states(c).get("reactive") is None  # the entry's replay
        assert np.asarray(_first_states(c, vehicle_model="idm")["reactive"]).any()


@pytest.mark.parametrize(
    "entry, named",
    [
        ({"vehicle_model": "teleport"}, "teleport"),
        ({"vehicles": "idm"}, "unknown field `vehicles`"),
    ],
)
def test_a_bad_pool_entry_stops_the_server_naming_it(entry, named):
    spec = json.dumps([{"path": f"embedded:{GENERAL}", **entry}])
    out = subprocess.run(
        [str(sim_server_binary()), "serve", "--cfg", f"pools:{spec}"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert out.returncode != 0
    assert named in out.stderr, out.stderr
