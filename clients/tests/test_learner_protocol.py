"""Every learner the loop drives conforms to sharedspace.train.protocol: PPO, SAC, the multi-car
learners and a user's plug-in (toy_pg) have the Learner's members, their worlds the World's,
and each learns from real batches of a live server with the one vocabulary of stats (gradient
steps counted in ``counters["updates"]``, plain names, no counter among them)."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

import toy_plugin  # noqa: E402,F401 - registers toy_pg, as a user's import would

from sharedspace.marl.task import CrossingTask  # noqa: E402
from sharedspace.marl.train import Cars  # noqa: E402
from sharedspace.train.config import TrainConfig  # noqa: E402
from sharedspace.train.loop import make_collector  # noqa: E402
from sharedspace.train.metrics import MetricLogger  # noqa: E402
from sharedspace.train.protocol import Learner, World, check_stats  # noqa: E402
from sharedspace.train.registry import get_algorithm  # noqa: E402

TINY_CROSSING = CrossingTask(cars=2, pedestrians=6, density=0.03, test_scenes=2)
OWN = {
    "ppo": {"rollout_steps": 8, "minibatch_size": 16, "ppo_epochs": 2},
    "sac": {"init_random_frames": 16, "batch_size": 16, "frames_per_batch": 16},
    "mappo": {"rollout_steps": 8, "minibatch_size": 16},
    "masac": {"batch_size": 16, "frames_per_batch": 32, "actor_warmup_frames": 0},
    "toy_pg": {},
}


def _config(algorithm: str, sim_server, tmp_path) -> TrainConfig:
    return TrainConfig(
        algorithm=algorithm,
        num_envs=4,
        hidden_sizes=[16, 16],
        eval_interval=0,
        eval_split="test",
        log_dir=str(tmp_path),
        server_endpoint=sim_server.endpoint,
        server_prefix=sim_server.prefix,
        device="cpu",
        **OWN[algorithm],
    )


@pytest.mark.parametrize("algorithm", list(OWN))
def test_every_learner_conforms_and_learns_in_the_one_vocabulary(algorithm, sim_server, tmp_path):
    cfg = _config(algorithm, sim_server, tmp_path)
    module = get_algorithm(algorithm).load()
    world = Cars(cfg, TINY_CROSSING) if cfg.world.task == "crossing" else module.make_world(cfg)
    env = world.make_env(seed=0)
    learner = module.make_learner(cfg, world, env)
    assert isinstance(world, World) and isinstance(learner, Learner)
    assert isinstance(learner.actor, torch.nn.Module)
    assert learner.batch_frames > 0 and learner.random_frames >= 0
    counters = {"frames": 0, "updates": 0, "episodes": 0, "iterations": 0, "lost_episodes": 0}
    logger = MetricLogger(tmp_path)
    learner.start(counters, logger)
    frames = learner.batch_frames * 3
    collector = make_collector(cfg, env, learner, frames, 0)
    try:
        for data in collector:
            counters["frames"] += data.numel()
            stats = check_stats(learner.step(data, counters))
            collector.update_policy_weights_()
            assert all(isinstance(v, int | float) for v in stats.values()), stats
    finally:
        collector.shutdown()
        logger.close()
        env.close()
        if isinstance(world, Cars):
            world.client.shutdown()
    assert counters["frames"] == frames and counters["updates"] > 0
    assert isinstance(learner.state_dict(), dict) and isinstance(learner.optimizer_state(), dict)


def test_a_stat_named_like_a_counter_or_prefixed_is_refused():
    with pytest.raises(ValueError, match="'gradient_steps'"):
        check_stats({"loss": 1.0, "gradient_steps": 3})
    with pytest.raises(ValueError, match="'train/loss'"):
        check_stats({"train/loss": 1.0})
    assert check_stats({"loss_objective": 0.5}) == {"loss_objective": 0.5}
