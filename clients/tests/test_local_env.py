"""LocalBatchedEnv (ENV_CONTRACT.md) and ReferenceWorld.observation (observation.rs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from local_env import LocalBatchedEnv, load_pool, split_indices  # noqa: E402
from reference import ReferenceWorld, wrap_angle  # noqa: E402
from torchrl.envs.utils import check_env_specs  # noqa: E402

POOL = load_pool()


def _scene():
    """Ego vehicle at the origin heading +y, three pedestrians, one out of perception range."""

    def agent(kind, pos, vel, n=6):
        return {
            "record_id": len(pos),
            "kind": kind,
            "start_step": 0,
            "positions": [[pos[0] + vel[0] * 0.5 * t, pos[1] + vel[1] * 0.5 * t] for t in range(n)],
            "velocities": [list(vel)] * n,
        }

    agents = [
        agent("vehicle", (0.0, 0.0), (0.0, 2.0)),
        agent("pedestrian", (3.0, 5.0), (-1.0, 0.0)),
        agent("pedestrian", (-2.0, 2.0), (0.0, 1.0)),
        agent("pedestrian", (30.0, 0.0), (1.0, 0.0)),
        agent("pedestrian", (0.0, -6.0), (0.5, 0.5)),
    ]
    for k, a in enumerate(agents):
        a["record_id"] = 100 + k
    return {"name": "t", "split": "train", "dt": 0.5, "ego": 0, "agents": agents}


def test_observation_by_hand():
    w = ReferenceWorld(_scene())
    obs = w.observation(0, 4)
    f, adj, mask, ids = obs["features"], obs["adjacency"], obs["mask"], obs["node_ids"]
    assert f.dtype == np.float32 and adj.dtype == np.float32 and mask.dtype == bool
    assert f.shape == (4, 11) and adj.shape == (4, 4)
    # In range: 1 (|(3,5)| = 5.83), 2 (2.83), 4 (6.0); 3 is 30 m away. Sorted by clearance, id.
    order = sorted((w.clearance[0, w.slot_of(j)], j) for j in (1, 2, 4))
    assert list(ids) == [0] + [j for _, j in order]
    assert mask.tolist() == [True] * 4
    # Ego node: zero relative terms, own speed, rect bounding radius, goal in ego frame.
    assert f[0, :4].tolist() == [0.0] * 4 and f[0, 5] == 0.0
    assert f[0, 4] == pytest.approx(2.0)
    assert f[0, 6] == pytest.approx(0.5 * math.hypot(4.0, 1.8))
    assert f[0, 7] == 1.0
    goal = np.array([0.0, 5.0])  # last recorded position (t = 2.5 s); heading +y = forward
    assert f[0, 8:11] == pytest.approx([goal[1], -goal[0], 5.0], abs=1e-6)
    # Pedestrian 1 at (3, 5), velocity (-1, 0): ego frame x = world y, y = -world x.
    r = list(ids).index(1)
    assert f[r, :2] == pytest.approx([5.0, -3.0])
    assert f[r, 2:4] == pytest.approx([-2.0, 1.0])  # v_rel = (-1, -2) -> (-2, 1)
    assert f[r, 4] == pytest.approx(1.0)
    assert f[r, 5] == pytest.approx(wrap_angle(math.pi - math.pi / 2))
    assert f[r, 6] == pytest.approx(0.3) and f[r, 7] == 0.0 and f[r, 8:].tolist() == [0.0] * 3
    # Adjacency = A between the nodes, zero diagonal.
    a = w.A
    for x, i in enumerate(ids):
        for y, j in enumerate(ids):
            assert adj[x, y] == np.float32(a[w.slot_of(i), w.slot_of(j)])
    assert np.all(np.diag(adj) == 0.0)


def test_observation_truncates_and_pads():
    w = ReferenceWorld(_scene())
    full = w.observation(0, 8)
    assert full["mask"].tolist() == [True] * 4 + [False] * 4
    assert np.all(full["features"][4:] == 0) and np.all(full["adjacency"][4:] == 0)
    assert np.all(full["adjacency"][:, 4:] == 0) and full["node_ids"][4:].tolist() == [-1] * 4
    two = w.observation(0, 2)
    assert two["node_ids"].tolist() == full["node_ids"][:2].tolist()
    assert np.array_equal(two["adjacency"], full["adjacency"][:2, :2])
    one = w.observation(0, 1)
    assert one["mask"].tolist() == [True] and one["adjacency"].tolist() == [[0.0]]
    with pytest.raises(ValueError):
        w.observation(0, 0)
    assert not w.observation(99, 3)["mask"].any()


def test_check_env_specs():
    env = LocalBatchedEnv(num_envs=3, max_agents=5, seed=0)
    check_env_specs(env, seed=1)


def test_partial_reset_autoreset_and_episode_keys():
    env = LocalBatchedEnv(num_envs=2, max_agents=4, seed=3)
    td = env.reset()
    assert td["features"].shape == (2, 4, 11) and td["mask"][:, 0].all()
    ends = 0
    with torch.no_grad():
        for _ in range(200):
            td["action"] = torch.tensor([[1.0, 0.0], [-1.0, 0.0]])
            td, nxt = env.step_and_maybe_reset(td)
            done = td["next", "done"].reshape(-1)
            flags = torch.cat(
                [td["next", f"episode_{s}"] for s in ("success", "collision", "timeout")], -1
            )
            assert torch.equal(flags.sum(-1) == 1, done)  # exactly one status at an episode end
            assert torch.equal(
                td["next", "done"], td["next", "terminated"] | td["next", "truncated"]
            )
            ends += int(done.sum())
            if done.any():
                # the reset sub-env shows the next episode, the other is untouched
                assert not nxt["done"].any()
            td = nxt
    assert ends >= 2  # sub-env 1 (full brake) times out at the horizon; sub-env 0 ends sooner
    assert env.env_time_s > 0.0


def test_scenario_sequence_split_and_seed():
    test_ids = split_indices(POOL, "test")
    assert len(test_ids) == 18 and len(split_indices(POOL, "train")) == 59
    env = LocalBatchedEnv(
        num_envs=len(test_ids), max_agents=3, split="test", scenario_order="sequential"
    )
    assert sorted(env.reset()["scenario_index"].reshape(-1).tolist()) == test_ids
    a = LocalBatchedEnv(num_envs=2, seed=7).reset()["scenario_index"]
    b = LocalBatchedEnv(num_envs=2, seed=7).reset()["scenario_index"]
    assert torch.equal(a, b)
    train_ids = set(split_indices(POOL, "train"))
    assert set(a.reshape(-1).tolist()) <= train_ids


@pytest.mark.parametrize("model", ["sfm", "ra_sfm", "cr_sfm"])
def test_local_defaults_are_the_servers_shipped_defaults(model, tmp_path):
    """Without params the local env simulates the same world as the server (shipped params)."""
    import json
    import subprocess

    from conftest import sim_server_binary
    from local_env import shipped_params
    from reference import DEFAULT_PARAMS, merge_params

    binary = sim_server_binary()
    if binary is None:
        pytest.skip("sim-server binary not built (cargo build -p sim-server)")
    out = tmp_path / "r.jsonl"
    subprocess.run(
        [str(binary), "rollout", "--scenario", "0", "--model", model, "--out", str(out)],
        check=True,
    )
    server_params = json.loads(out.read_text().splitlines()[0])["params"]
    assert merge_params(DEFAULT_PARAMS, shipped_params(model)) == server_params
