"""SimClient / VectorClient / Observer against a live sim-server (conftest's ``sim_server``)."""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
import pytest
from conftest import REPO_ROOT, free_port
from reference import ReferenceWorld

from sharedspace.client import SimClient
from sharedspace.observer import Observer
from sharedspace.transport import Transport
from sharedspace.vector import VectorClient
from sharedspace.wire import envelope, requests
from sharedspace.wire.errors import EnvClosed, NoServer, VersionMismatch, WrongShape

POOL = json.loads((REPO_ROOT / "scenarios" / "data" / "hbs-paper.json").read_text())["scenarios"]


def _actions(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (n, 2)).astype(np.float32)


def test_discovery_and_info(sim_server, sim_client):
    servers = sim_client.servers()
    assert [s["server_id"] for s in servers] == [sim_server.server_id]
    info = servers[0]
    assert info["protocol_version"] == envelope.PROTOCOL_VERSION and info["capacity"] > 0
    assert sim_client.pick_server()["server_id"] == sim_server.server_id
    assert sim_client.info(sim_server.server_id)["server_id"] == sim_server.server_id
    assert sim_server.server_id in sim_client.transport.alive_servers()
    # The server's own tables and its allocator's figures, for soaks (benchmarks/soak.py).
    assert info["tables"]["envs"] == info["load"]
    assert {"trainers", "fair_trainers", "pooled_step_buffers"} <= set(info["tables"])
    assert info["allocator"]["in_use"] > 0
    # The default build runs on jemalloc: its statistics (glibc's mallinfo2 has no `resident`).
    assert {"resident", "active", "metadata", "mapped"} <= set(info["allocator"])


def test_every_lazy_name_of_the_package_resolves():
    import sharedspace

    for name in sharedspace.__all__:
        assert getattr(sharedspace, name) is not None, name


def test_create_reset_step_batch_close(sim_client):
    created = sim_client.create(3, seed=7, max_agents=6)
    ids = created["env_ids"]
    assert len(ids) == 3 and created["observation"]["max_agents"] == 6
    resets = sim_client.reset_many(ids)
    assert all(r["step"] == 0 and r["obs"]["features"].shape == (1, 6, 11) for r in resets)
    single = sim_client.step(ids[0], _actions(1))
    assert single["step"] == 1 and single["reward"].shape == (1,)
    assert single["obs"]["features"].dtype == np.float32
    acts = np.stack([_actions(1, k) for k in range(2)])
    batch = sim_client.batch_step(ids[1:], acts)
    assert batch["obs"]["features"].shape == (2, 1, 6, 11)
    assert batch["reward"].shape == (2, 1) and batch["terminated"].dtype == np.uint8
    for e in ids:
        sim_client.close(e)
    with pytest.raises(EnvClosed):
        sim_client.step(ids[0], _actions(1))


def _episode(client: SimClient, seed: int, steps: int = 15):
    env = client.create(1, seed=seed, max_agents=8)["env_ids"][0]
    r = client.reset(env)
    out = [(r["scenario"], np.array(r["obs"]["features"]))]
    for t in range(steps):
        s = client.step(env, _actions(1, t))
        out.append((float(s["reward"][0]), np.array(s["obs"]["features"])))
        if s["terminated"][0] or s["truncated"][0]:
            break
    client.close(env)
    return out


def test_same_seed_same_episode(sim_client):
    a, b = _episode(sim_client, 11), _episode(sim_client, 11)
    assert a[0][0] == b[0][0]
    assert len(a) == len(b)
    for (x, fx), (y, fy) in zip(a, b, strict=True):
        assert x == y
        np.testing.assert_array_equal(fx, fy)
    # and reset(seed=...) re-seeds: seed s gives the episode of an env created with seed s
    env = sim_client.create(1, seed=999)["env_ids"][0]
    r = sim_client.reset(env, seed=11)
    assert r["scenario"] == a[0][0]
    np.testing.assert_array_equal(r["obs"]["features"], a[0][1])
    sim_client.close(env)


def test_vector_client_batch(sim_client):
    with VectorClient(4, client=sim_client, seed=0, autoreset=True, max_agents=5) as vec:
        vec.reset()
        ends = 0
        for t in range(80):
            res = vec.step(np.random.default_rng(t).uniform(-1, 1, (4, 1, 2)).astype(np.float32))
            assert res["obs"]["mask"].shape == (4, 1, 5)
            ended = np.flatnonzero(res["terminated"][:, 0] | res["truncated"][:, 0])
            ends += len(ended)
            # Every ended env (and only those) restarted, with its new first observation
            # as the next step's start.
            resets = res["resets"]
            np.testing.assert_array_equal(resets["index"], ended)
            assert resets["obs"]["features"].shape == (len(ended), 1, 5, 11)
            assert len(resets["scenario"]) == len(resets["agents"]) == len(ended)
            assert all(e >= 1 for e in resets["episode"])
            start = vec._start_obs()["features"]
            for j, k in enumerate(ended):
                np.testing.assert_array_equal(start[k], resets["obs"]["features"][j])
            live = np.setdiff1d(np.arange(4), ended)
            np.testing.assert_array_equal(start[live], res["obs"]["features"][live])
            assert res["episode"].shape == res["step"].shape == res["t"].shape == (4,)
            assert res["action_clipped"].shape == (4, 1) and len(res["scenario"]) == 4
            assert all(0 <= m["index"] < 4 for m in res["metrics"] + res["events"])
        assert ends > 0
        with pytest.raises(WrongShape, match=r"\[K=4, n_ext=1, 2\]"):
            vec.step(np.zeros((3, 2), np.float32))
    with pytest.raises(EnvClosed):
        vec.step(np.zeros((4, 1, 2), np.float32))


def test_wrong_action_shape(sim_client):
    env = sim_client.create(1)["env_ids"][0]
    sim_client.reset(env)
    with pytest.raises(WrongShape, match=r"\[1, 2\]"):
        sim_client.step(env, np.zeros((2, 2), np.float32))
    # the server's check too (bypassing the client's): wrong_shape error reply
    t = sim_client.transport
    key = t.key("server", sim_client.env_server[env], "env", env, "step")
    with pytest.raises(WrongShape):
        t.request(key, envelope.encode({"actions": np.zeros((3, 2), np.float32)}))
    sim_client.close(env)


def test_closed_env(sim_client):
    env = sim_client.create(1)["env_ids"][0]
    sim_client.reset(env)
    sim_client.close(env)
    with pytest.raises(EnvClosed):
        sim_client.reset(env)
    # the server says env_closed as well
    t = sim_client.transport
    sid = sim_client.pick_server()["server_id"]
    with pytest.raises(EnvClosed):
        t.request(t.key("server", sid, "env", env, "step"), requests.encode_step(np.zeros((1, 2))))


def test_version_mismatch(sim_server):
    with SimClient(sim_server.endpoint, sim_server.prefix, protocol_version=99) as c:
        with pytest.raises(VersionMismatch, match="99"):
            c.create(1)
        with pytest.raises(VersionMismatch):
            c.create(1, server_id=sim_server.server_id)


def test_no_server():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    with SimClient(endpoint, "nobody", timeout=0.5) as c:
        with pytest.raises(NoServer) as err:
            c.create(1)
    assert time.monotonic() - t0 < 10
    assert endpoint in str(err.value) and "0.5 s" in str(err.value)
    assert err.value.endpoint == endpoint and err.value.timeout == 0.5
    with SimClient(endpoint, "nobody", timeout=0.5) as c:
        with pytest.raises(NoServer, match="nosuch"):
            c.create(1, server_id="nosuch")
    with pytest.raises(NoServer, match=endpoint):  # client mode fails at once
        Transport(endpoint, "nobody", mode="client")


def test_unreachable_endpoint_is_a_connection_error_not_a_timeout():
    # Nothing listens there: the error comes after the 1 s connection grace, not after the
    # 5 s query timeout, and says it could not connect.
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    with SimClient(endpoint, "nobody", timeout=5.0) as c:
        with pytest.raises(NoServer, match="cannot connect") as err:
            c.create(1)
    assert time.monotonic() - t0 < 4.0
    assert endpoint in str(err.value)


def test_observer_receives(sim_server, sim_client):
    got: dict[str, dict] = {}
    with Observer(transport=sim_client.transport, env_id="*") as obs:
        env = sim_client.create(1, seed=3)["env_ids"][0]
        sim_client.reset(env)
        deadline = time.monotonic() + 10
        step = 0
        while time.monotonic() < deadline and not {"states", "uncertainty", "risk_graph"} <= set(
            got
        ):
            sim_client.step(env, np.zeros((1, 2), np.float32))
            step += 1
            while (m := obs.get(0.05)) is not None:
                if m["env_id"] == env:
                    got.setdefault(m["topic"], m)
        sim_client.close(env)
    assert {"states", "uncertainty", "risk_graph"} <= set(got)
    st = got["states"]
    assert st["positions"].dtype == np.float64 and st["positions"].shape == (len(st["ids"]), 2)
    rg = got["risk_graph"]
    assert rg["a"].shape == rg["src"].shape and np.all(rg["psi"] > 0)


def test_events_callback(sim_client):
    events = []
    with Observer(transport=sim_client.transport, topics=("events",), callback=events.append):
        env = sim_client.create(1, seed=5)["env_ids"][0]
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not events:
            sim_client.reset(env)
            time.sleep(0.05)
        sim_client.close(env)
    assert events and events[0]["topic"] == "events"
    assert any(e["kind"] == "episode_start" for e in events[0]["events"])


@pytest.fixture(scope="module")
def server_params(sim_server, tmp_path_factory):
    """The world parameters the server runs with (its defaults): the header of a one-scenario
    ``sim-server rollout`` of the same binary (the Rust defaults are the calibrated values)."""
    out = tmp_path_factory.mktemp("params") / "r.jsonl"
    subprocess.run(
        [str(sim_server.binary), "rollout", "--scenario", "0", "--model", "cv", "--av=replay"]
        + ["--out", str(out)],
        check=True,
        capture_output=True,
        timeout=60,
    )
    return json.loads(out.read_text().splitlines()[0])["params"]


@pytest.mark.parametrize("scenario", ["hbs-car1116", "hbs-car1391"])
def test_observation_matches_reference(sim_client, server_params, scenario):
    """The server's observation of vehicle_0 equals ReferenceWorld.observation (1e-5, f32)."""
    m = 8
    spec = next(s for s in POOL if s["name"] == scenario)
    world = ReferenceWorld(spec, server_params, "cr_sfm")
    ego = int(spec["ego"])
    env = sim_client.create(1, scenario=scenario, split=spec["split"], max_agents=m)["env_ids"][0]
    r = sim_client.reset(env)
    assert r["scenario"] == scenario
    rng = np.random.default_rng(0)

    def check(obs, when):
        ref = world.observation(ego, m)
        np.testing.assert_array_equal(obs["mask"][0].astype(bool), ref["mask"], err_msg=when)
        ids = obs["node_ids"][0].astype(np.int64)
        ids[ids == envelope.PADDING_ID] = -1
        np.testing.assert_array_equal(ids, ref["node_ids"], err_msg=when)
        np.testing.assert_allclose(obs["features"][0], ref["features"], atol=1e-5, err_msg=when)
        np.testing.assert_allclose(obs["adjacency"][0], ref["adjacency"], atol=1e-5, err_msg=when)

    check(r["obs"], "reset")
    for t in range(20):
        a = rng.uniform(-1, 1, 2).astype(np.float32)
        s = sim_client.step(env, a.reshape(1, 2))
        res = world.step({ego: (float(a[0]), float(a[1]))})
        check(s["obs"], f"step {t + 1}")
        if res["episode_over"]:
            break
    sim_client.close(env)


def test_oversized_request_is_refused_and_the_server_serves_on(sim_server, sim_client):
    from sharedspace.wire.errors import LimitExceeded

    t = sim_client.transport
    sid = sim_client.pick_server()["server_id"]
    big = b"\x00" * (2 << 20)  # 2 MiB of garbage: over the default 1 MiB, never decoded
    with pytest.raises(LimitExceeded, match="not decoded"):
        t.request(t.key("server", sid, "env", "create"), big)
    env = sim_client.create(1)["env_ids"][0]  # the server goes on serving
    sim_client.reset(env)
    sim_client.close(env)


def test_per_trainer_quota_names_itself_and_spares_other_trainers(server_factory):
    from sharedspace.wire.errors import LimitExceeded

    srv = server_factory(f"quota{free_port()}", "q0", "max_envs_per_trainer:2")
    with (
        SimClient(srv.endpoint, srv.prefix) as greedy,
        SimClient(srv.endpoint, srv.prefix) as other,
    ):
        greedy.create(2)
        with pytest.raises(LimitExceeded, match="max_envs_per_trainer"):
            greedy.create(1)
        env = other.create(2)["env_ids"][0]
        other.reset(env)
        out = other.step(env, np.zeros((1, 2), np.float32))
        assert np.isfinite(out["reward"]).all()


def test_a_trainer_flooding_the_server_with_batches_does_not_starve_another(server_factory):
    """Fair share of batch work (SPEC 4, `batch_slots`): with one slot, a trainer that keeps six
    512-env batches in flight waits behind its own queue; another trainer's batch is served
    after at most the flooder's batches already granted, not after all of them."""
    import threading

    srv = server_factory(f"fair{free_port()}", "f0", "batch_slots:1", "batch_threads:1")
    with (
        SimClient(srv.endpoint, srv.prefix, timeout=60) as flooder,
        SimClient(srv.endpoint, srv.prefix, timeout=60) as small,
    ):
        groups = [flooder.create(512)["env_ids"] for _ in range(6)]
        for ids in groups:
            flooder.reset_many(ids)
        mine = small.create(8)["env_ids"]
        small.reset_many(mine)
        done: list[str] = []
        lock = threading.Lock()

        def flood(ids: list[str], k: int) -> None:
            flooder.batch_step(ids, np.zeros((len(ids), 1, 2), np.float32))
            with lock:
                done.append(f"flooder-{k}")

        threads = [threading.Thread(target=flood, args=(ids, k)) for k, ids in enumerate(groups)]
        for t in threads:
            t.start()
        out = small.batch_step(mine, np.zeros((8, 1, 2), np.float32))
        with lock:
            done.append("small")
        for t in threads:
            t.join(timeout=60)
        assert np.isfinite(out["reward"]).all()
        assert len(done) == 7
        assert done.index("small") <= 2, done


def test_an_unknown_client_option_is_refused_by_name():
    # SimClient forwards its connection options to Transport: a misspelt one is named, before
    # any connection is opened.
    with pytest.raises(TypeError, match="multicats"):
        SimClient("tcp/127.0.0.1:1", multicats=True)
