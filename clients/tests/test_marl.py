"""Several learning cars per scene (sharedspace.marl) against a live server: MAPPO, IPPO and MASAC
train a few iterations and resume, per-car outcomes count car-car collisions apart, and the
planner's per-car bound starts from the script's own drive."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from sharedspace.client import Connection
from sharedspace.marl import masac
from sharedspace.marl.bound import per_car_bound
from sharedspace.marl.evaluate import paired_difference, play, scripted_act, summarize
from sharedspace.marl.networks import make_actor
from sharedspace.marl.task import CrossingTask, make_env
from sharedspace.marl.train import train
from sharedspace.train.checkpoint import FORMAT, read_checkpoint
from sharedspace.train.config import TrainConfig, apply_overrides
from sharedspace.train.envs import ResidualAction

#: Two cars through the crossing, two test scenes: a few seconds per run.
TINY_TASK = CrossingTask(cars=2, pedestrians=6, density=0.03, test_scenes=2)


def _connection(sim_server) -> Connection:
    return Connection(endpoint=sim_server.endpoint, prefix=sim_server.prefix)


def _tiny(algorithm: str, sim_server, log_dir, total_frames: int) -> TrainConfig:
    own = (
        {"batch_size": 32, "utd_ratio": 0.25, "actor_warmup_frames": 128, "frames_per_batch": 64}
        if algorithm == "masac"
        else {"minibatch_size": 32, "rollout_steps": 16}
    )
    return TrainConfig(
        algorithm=algorithm,
        total_frames=total_frames,
        num_envs=4,
        hidden_sizes=[16, 16],
        eval_interval=128,
        validation_scenes=2,
        log_dir=str(log_dir),
        server_endpoint=sim_server.endpoint,
        server_prefix=sim_server.prefix,
        **own,
    )


def _frames_logged(log_dir) -> list[int]:
    rows = (log_dir / "metrics.csv").read_text().splitlines()[1:]
    return sorted({int(r.split(",")[0]) for r in rows})


@pytest.mark.parametrize("algorithm", ["mappo", "ippo", "masac"])
def test_each_algorithm_trains_against_a_live_server_and_resumes(algorithm, sim_server, tmp_path):
    cfg = _tiny(algorithm, sim_server, tmp_path, total_frames=192)
    summary = train(cfg, TINY_TASK)
    assert summary["car_episodes"] == 2 * 2  # every (test scene, car)
    rows = json.loads((tmp_path / "eval.json").read_text())["rows"]
    assert {(r["scene"], r["car"]) for r in rows} == {
        (s, c) for s in TINY_TASK.scene_names("validation", 2) for c in TINY_TASK.agents
    }
    metrics = (tmp_path / "metrics.csv").read_text()
    losses = {"mappo": "loss_objective", "ippo": "loss_critic", "masac": "loss_qvalue"}
    assert f"train/{losses[algorithm]}" in metrics and "eval/success" in metrics
    assert _frames_logged(tmp_path)[-1] == 192
    ckpt = read_checkpoint(tmp_path / "checkpoints" / "last.pt")  # every learner's format
    assert (ckpt["format"], ckpt["algorithm"]) == (FORMAT, algorithm)
    assert ckpt["world"]["reward"]["name"] == "learner" and "task" in ckpt["world"]
    # Resumed with a larger budget, the run goes on from its checkpoint's frames.
    train(apply_overrides(cfg, ["total_frames=320"]), TINY_TASK, resume=True)
    frames = _frames_logged(tmp_path)
    assert frames[-1] == 320 and 192 < frames[-2] < 320, frames


def test_masac_moves_only_its_critics_until_the_actor_warmup_ends(sim_server, tmp_path):
    cfg = _tiny("masac", sim_server, tmp_path, total_frames=64)
    env = make_env(TINY_TASK, "train", 4, _connection(sim_server))
    actor, critic = make_actor(cfg, TINY_TASK), masac.make_critic(cfg, TINY_TASK)
    loss = masac.make_loss(cfg, actor, critic)
    optim = masac.make_optimizer(cfg, loss)
    buffer = masac.make_buffer(cfg, 64)
    with torch.no_grad():  # as a collector gathers its batches
        data = env.rollout(8, actor)
    env.close()

    def snapshot(module):
        return [p.detach().clone() for p in module.parameters()]

    def moved(before, module):
        return any(not torch.equal(a, b) for a, b in zip(before, module.parameters(), strict=True))

    actor_before, critic_before = snapshot(actor), snapshot(loss.qvalue_network_params)
    masac.learn(cfg, loss, optim, buffer, data, None, frames=cfg.algo.actor_warmup_frames - 1)
    assert not moved(actor_before, actor), "the actor moved during the critics' warm-up"
    assert moved(critic_before, loss.qvalue_network_params)
    masac.learn(cfg, loss, optim, buffer, data, None, frames=cfg.algo.actor_warmup_frames)
    assert moved(actor_before, actor)


def test_a_residual_policy_at_zero_drives_like_its_script(sim_server):
    env = make_env(TINY_TASK, "test", 2, _connection(sim_server), scenarios=None)
    wrapped = ResidualAction("car_aware", group="vehicle")
    td = env.reset()
    td.set(("vehicle", "action"), torch.zeros(2, 2, 2))
    sent = wrapped.inv(td)[("vehicle", "action")]
    want = scripted_act("car_aware")(td, 0)
    assert torch.allclose(sent, want)
    assert torch.equal(td["vehicle", "action"], torch.zeros(2, 2, 2))  # the data keep the residual
    env.close()


def test_car_collisions_are_counted_apart_from_pedestrian_ones(sim_server):
    """Cars that hold their speed through the crossing (action 0) run into each other in some
    scenes: those rows are collisions with ``car_collision`` set, two cars of one scene at one
    step; a collision with a pedestrian leaves it unset."""
    task = CrossingTask(cars=2, pedestrians=2, density=0.01, test_scenes=40)

    def hold(td, step):
        return torch.zeros(td["vehicle", "features"].shape[:-2] + (2,))

    rows = play(task, hold, _connection(sim_server))
    hits = [r for r in rows if r["car_collision"]]
    assert hits, "no car-car collision among 40 scenes of cars holding their speed"
    assert all(r["status"] == "collision" for r in hits)
    for scene in {r["scene"] for r in hits}:
        pair = [r for r in hits if r["scene"] == scene]
        assert len(pair) == 2 and pair[0]["steps"] == pair[1]["steps"]
    summary = summarize(rows)
    assert summary["car_collision"]["count"] == len(hits)
    assert summary["collision"]["count"] >= len(hits)


def test_the_per_car_bound_is_at_least_the_scripts_own_success(sim_server):
    client = _connection(sim_server).open()
    try:
        script = play(TINY_TASK, scripted_act("car_aware"), client)
        found = per_car_bound(TINY_TASK, client, rounds=1, per_round=10, max_steps=60)
    finally:
        client.shutdown()
    for r in script:
        if r["status"] == "success":
            assert found[f"{r['scene']}/{r['car']}"]["replayed"] == "success", r


def test_paired_difference_resamples_scenes_and_pairs_cells():
    base = [
        {"scene": f"s{i}", "car": c, "status": "success" if i % 2 else "timeout"}
        for i in range(10)
        for c in ("a", "b")
    ]
    same = paired_difference(base, base)
    assert same["mean"] == 0.0 and same["ci95"] == [0.0, 0.0]
    better = [dict(r, status="success") for r in base] * 3  # three seeds, each every cell
    diff = paired_difference(better, base)
    assert diff["mean"] == pytest.approx(0.5)
    assert 0.0 < diff["ci95"][0] <= 0.5 <= diff["ci95"][1] <= 1.0
    with pytest.raises(KeyError):
        paired_difference([{"scene": "other", "car": "a", "status": "success"}], base)


def test_bad_configs_name_what_was_wrong():
    mappo = TrainConfig(algorithm="mappo")
    with pytest.raises(ValueError, match="algorithm"):
        TrainConfig(algorithm="qmix")
    with pytest.raises(ValueError, match="total_frames"):
        apply_overrides(mappo, ["total_frames=lots"])
    with pytest.raises(ValueError, match="unknown config key .frames."):
        apply_overrides(mappo, ["frames=3"])
    assert apply_overrides(mappo, ['reward_weights={"danger": 2}']).algo.reward_weights == {
        "danger": 2
    }
    assert np.isclose(apply_overrides(mappo, ["lr=1"]).algo.lr, 1.0)
    with pytest.raises(ValueError, match="utd_ratio is an option of algorithm=sac|masac"):
        apply_overrides(mappo, ["utd_ratio=1"])
    # a multi-car run saved in its own config: every option, its own names, retired fields
    saved = TrainConfig.from_dict(
        {"algorithm": "mappo", "utd_ratio": 5, "eval_every": 7, "hidden": 16, "depth": 3}
    )
    assert saved.algorithm == "mappo" and not hasattr(saved.algo, "utd_ratio")  # masac's
    assert (saved.algo.eval_interval, saved.algo.hidden_sizes) == (7, [16, 16, 16])
    with pytest.raises(ValueError, match="ppo_epochs is an option of algorithm=ppo|mappo|ippo"):
        TrainConfig(algorithm="masac", ppo_epochs=2)
    with pytest.raises(ValueError, match="a residual without a script"):
        apply_overrides(mappo, ["base_driver=", "residual_scale=1"])
    with pytest.raises(ValueError, match="reward"):
        apply_overrides(mappo, ["reward=sparse"])
    with pytest.raises(ValueError, match="task paper has 1 learning car"):
        apply_overrides(mappo, ["task=paper"])
    # the multi-car defaults: a residual over the car-aware script, each car's nodes flattened
    assert (
        mappo.world.task,
        mappo.algo.base_driver,
        mappo.algo.residual_scale,
        mappo.net.network,
    ) == (
        "crossing",
        "car_aware",
        2.0,
        "",
    )
