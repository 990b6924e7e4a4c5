"""MAPPO, IPPO and MASAC on the crossing task, top to bottom.

    python -m sharedspace.marl --set algorithm=mappo --set seed=0 [--resume]

TorchRL's ``sota-implementations/multiagent`` scripts (mappo_ippo.py, sac.py) over a live server:
the cars of :class:`~sharedspace.marl.task.CrossingTask` are one agent group of
:class:`~sharedspace.torchrl_multiagent.RemoteMultiAgentEnv`; each car's policy is a
``MultiAgentMLP`` over its own observation (its node features, flattened), one set of weights
for every car; its action is a residual over the car-aware script (``base_driver``). MAPPO's
critic sees every car's observation (centralised), IPPO's only the car's own; MASAC's two
Q-critics are centralised. Writes ``config.json``, ``metrics.csv`` (``train/*`` per collected
batch, ``eval/*`` on the test scenes every ``eval_every`` frames: curves, never used to pick a
policy), ``checkpoint.pt`` (resumable) and ``eval.json`` (the final policy's per-car rows on the
test scenes) into ``log_dir``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import RandomSampler, SamplerWithoutReplacement
from torchrl.envs import TransformedEnv
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss, SACLoss, SoftUpdate, ValueEstimators

from sharedspace.marl.config import MarlConfig
from sharedspace.train.config import apply_overrides
from sharedspace.marl.evaluate import STATUSES, play, policy_act, summarize
from sharedspace.marl.task import CarObservation, CrossingTask, make_env
from sharedspace.names import NODE_FEATURES
from sharedspace.train.envs import ResidualAction
from sharedspace.train.metrics import MetricLogger

__all__ = ["make_actor", "make_critic", "make_loss", "make_optimizer", "train", "main"]

GROUP = "vehicle"
OBS = (GROUP, "observation")
ACTION = (GROUP, "action")


def _observation() -> TensorDictModule:
    return TensorDictModule(
        CarObservation(), in_keys=[(GROUP, "features"), (GROUP, "mask")], out_keys=[OBS]
    )


def make_actor(cfg: MarlConfig, task: CrossingTask) -> ProbabilisticActor:
    """Tanh-normal policy per car; at initialisation its mean is ~0 (the script's action, for a
    residual learner) and its standard deviation ``init_scale``."""
    obs_dim = task.max_agents * (NODE_FEATURES + 1)
    mlp = MultiAgentMLP(
        n_agent_inputs=obs_dim,
        n_agent_outputs=4,
        n_agents=task.cars,
        centralized=False,
        share_params=cfg.share_params,
        depth=cfg.depth,
        num_cells=cfg.hidden,
        activation_class=nn.Tanh,
    )
    with torch.no_grad():  # the last layer: mean and raw scale start near 0
        for p in list(mlp.parameters())[-2:]:  # the output layer's weight and bias
            p.mul_(0.01)
    head = TensorDictModule(
        nn.Sequential(mlp, NormalParamExtractor(scale_mapping=f"biased_softplus_{cfg.init_scale}")),
        in_keys=[OBS],
        out_keys=[(GROUP, "loc"), (GROUP, "scale")],
    )
    return ProbabilisticActor(
        module=TensorDictSequential(_observation(), head),
        in_keys=[(GROUP, "loc"), (GROUP, "scale")],
        out_keys=[ACTION],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )


def make_critic(cfg: MarlConfig, task: CrossingTask) -> TensorDictSequential:
    """PPO: the state value per car (centralised for MAPPO). MASAC: ``Q(s, a)`` per car over
    every car's observation and action."""
    obs_dim = task.max_agents * (NODE_FEATURES + 1)
    sac = cfg.algorithm == "masac"
    mlp = MultiAgentMLP(
        n_agent_inputs=obs_dim + (2 if sac else 0),
        n_agent_outputs=1,
        n_agents=task.cars,
        centralized=cfg.algorithm != "ippo",
        share_params=cfg.share_params,
        depth=cfg.depth,
        num_cells=cfg.hidden,
        activation_class=nn.Tanh,
    )
    value = ValueOperator(
        module=mlp,
        in_keys=[OBS, ACTION] if sac else [OBS],
        out_keys=[(GROUP, "state_action_value" if sac else "state_value")],
    )
    return TensorDictSequential(_observation(), value)


def make_loss(cfg: MarlConfig, actor, critic) -> nn.Module:
    """TorchRL's ``ClipPPOLoss`` with GAE, or ``SACLoss`` with TD(0), on the group's keys."""
    keys = dict(
        reward=(GROUP, "reward"),
        action=ACTION,
        done=(GROUP, "done"),
        terminated=(GROUP, "terminated"),
    )
    if cfg.algorithm == "masac":
        loss = SACLoss(
            actor_network=actor,
            qvalue_network=critic,
            num_qvalue_nets=2,
            delay_qvalue=True,
            alpha_init=cfg.alpha_init,
            target_entropy=-2.0,  # per car: -|A|
        )
        loss.set_keys(state_action_value=(GROUP, "state_action_value"), **keys)
        loss.make_value_estimator(ValueEstimators.TD0, gamma=cfg.gamma)
        return loss
    loss = ClipPPOLoss(
        actor_network=actor,
        critic_network=critic,
        clip_epsilon=cfg.clip_epsilon,
        entropy_coeff=cfg.entropy_coeff,
        normalize_advantage=True,
        normalize_advantage_exclude_dims=(-2,),  # each car's advantages normalised apart
    )
    loss.set_keys(value=(GROUP, "state_value"), **keys)
    loss.make_value_estimator(ValueEstimators.GAE, gamma=cfg.gamma, lmbda=cfg.lmbda)
    return loss


def make_optimizer(cfg: MarlConfig, loss: nn.Module) -> torch.optim.Optimizer:
    """Adam over the loss's parameters. MASAC's actor gets its own, smaller rate: Adam moves
    each weight by about the rate per step whatever the gradient's size, and 40 steps at the
    critics' rate shift the residual's mean by about 1 (measured: the residual turned the
    script's 0.70 success into 0.03 within one batch)."""
    if cfg.algorithm != "masac":
        return torch.optim.Adam(loss.parameters(), cfg.lr)
    actor = list(loss.actor_network_params.values(True, True))
    others = [p for p in loss.parameters() if all(p is not a for a in actor)]
    return torch.optim.Adam([{"params": actor, "lr": cfg.actor_lr}, {"params": others}], cfg.lr)


def batch_outcomes(data: TensorDictBase) -> dict[str, float]:
    """``train/*``: per-car episode outcomes that ended in a collected batch, and its reward."""
    nxt = data["next", GROUP]
    ended = sum(int(nxt[f"episode_{s}"].sum()) for s in STATUSES)
    out = {"train/reward": float(nxt["reward"].mean()), "train/car_episodes": float(ended)}
    if ended:
        for s in (*STATUSES, "car_collision"):
            out[f"train/{s}"] = float(nxt[f"episode_{s}"].sum()) / ended
    return out


def make_buffer(cfg: MarlConfig, frames_per_batch: int) -> TensorDictReplayBuffer:
    """SAC: a replay buffer sampled at random. PPO: the last batch, in minibatches without
    replacement."""
    if cfg.algorithm == "masac":
        return TensorDictReplayBuffer(
            storage=LazyTensorStorage(cfg.buffer_size),
            sampler=RandomSampler(),
            batch_size=cfg.batch_size,
        )
    return TensorDictReplayBuffer(
        storage=LazyTensorStorage(frames_per_batch),
        sampler=SamplerWithoutReplacement(),
        batch_size=cfg.minibatch_size,
    )


def learn(
    cfg: MarlConfig, loss, optim, buffer, data: TensorDictBase, target_update, frames: int
) -> dict:
    """One collected batch's gradient steps: PPO's epochs of minibatches over the batch (its
    advantages by GAE first), or SAC's ``utd_ratio`` updates per frame from the replay buffer.
    SAC trains only its critics for the first ``actor_warmup_frames``: Adam moves the actor's
    mean by about ``lr`` per weight and step whatever the gradient's size, so an untrained
    critic would drag the residual far off the script within one batch. Returns the last
    step's losses (``train/loss_*``)."""
    sac = cfg.algorithm == "masac"
    warmup = sac and frames < cfg.actor_warmup_frames
    if sac:
        buffer.extend(data.reshape(-1))
        updates = max(1, round(cfg.utd_ratio * data.numel()))
    else:
        with torch.no_grad():
            loss.value_estimator(
                data,
                params=loss.critic_network_params,
                target_params=loss.target_critic_network_params,
            )
        buffer.extend(data.reshape(-1))
        updates = cfg.ppo_epochs * max(1, data.numel() // cfg.minibatch_size)
    for _ in range(updates):
        sample = buffer.sample()
        out = loss(sample)
        if sac and cfg.residual_penalty and not warmup:
            # keeps the residual near 0 (the script) unless the critics disagree by more
            loc = loss.actor_network(sample.clone())[GROUP, "loc"]
            out["loss_residual"] = cfg.residual_penalty * loc.pow(2).mean()
        total = (
            out["loss_qvalue"]
            if warmup
            else sum(v for k, v in out.items() if k.startswith("loss_"))
        )
        optim.zero_grad()
        total.backward()
        nn.utils.clip_grad_norm_(loss.parameters(), cfg.max_grad_norm)
        optim.step()
        if target_update is not None:
            target_update.step()
    return {f"train/{k}": float(v.detach().mean()) for k, v in out.items() if k.startswith("loss_")}


def _evaluate(task, actor, cfg, client) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    rows = play(task, policy_act(actor, cfg.base_driver, cfg.residual_scale), client)
    return rows, summarize(rows)


def train(cfg: MarlConfig, task: CrossingTask | None = None, resume: bool = False) -> dict:
    """One run; returns the final evaluation's summary."""
    task = task or CrossingTask()
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(max(1, cfg.num_threads))
    log_dir = Path(cfg.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "config.json").write_text(
        json.dumps({"config": cfg.to_dict(), "task": _task_dict(task)}, indent=1)
    )

    client = cfg.connection().open()
    try:
        return _train(cfg, task, client, log_dir, resume)
    finally:
        client.shutdown()


def _train(cfg, task, client, log_dir: Path, resume: bool) -> dict:
    env = make_env(
        task, "train", cfg.num_envs, client, seed=cfg.seed, reward_weights=cfg.world_reward_weights
    )
    if cfg.base_driver:
        env = TransformedEnv(env, ResidualAction(cfg.base_driver, GROUP, cfg.residual_scale))
    actor = make_actor(cfg, task)
    critic = make_critic(cfg, task)
    loss = make_loss(cfg, actor, critic)
    optim = make_optimizer(cfg, loss)
    sac = cfg.algorithm == "masac"
    target_update = SoftUpdate(loss, eps=1.0 - cfg.tau) if sac else None

    frames, iteration, wall = 0, 0, 0.0
    ckpt_path = log_dir / "checkpoint.pt"
    if resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, weights_only=False)
        loss.load_state_dict(ckpt["loss"])
        optim.load_state_dict(ckpt["optim"])
        frames, iteration, wall = ckpt["frames"], ckpt["iteration"], ckpt["wall_s"]
    if frames >= cfg.total_frames:
        env.close()
        return json.loads((log_dir / "eval.json").read_text())["summary"]

    frames_per_batch = cfg.frames_per_batch - cfg.frames_per_batch % cfg.num_envs
    collector = Collector(
        env,
        actor,
        frames_per_batch=max(frames_per_batch, cfg.num_envs),
        total_frames=cfg.total_frames - frames,
    )
    buffer = make_buffer(cfg, frames_per_batch)
    logger = MetricLogger(log_dir, tensorboard=False)
    next_eval = (frames // cfg.eval_every + 1) * cfg.eval_every
    t0 = time.perf_counter() - wall
    for data in collector:
        frames += data.numel()
        iteration += 1
        metrics = batch_outcomes(data)
        metrics.update(learn(cfg, loss, optim, buffer, data, target_update, frames))
        collector.update_policy_weights_()
        wall = time.perf_counter() - t0
        metrics["train/wall_s"] = wall
        if frames >= next_eval or frames >= cfg.total_frames:
            _, summary = _evaluate(task, actor, cfg, client)
            for key in (*STATUSES, "car_collision"):
                metrics[f"eval/{key}"] = summary[key]["rate"]
            next_eval += cfg.eval_every
            torch.save(
                {
                    "loss": loss.state_dict(),
                    "optim": optim.state_dict(),
                    "frames": frames,
                    "iteration": iteration,
                    "wall_s": wall,
                },
                ckpt_path,
            )
        logger.log(metrics, frames)
    collector.shutdown()
    rows, summary = _evaluate(task, actor, cfg, client)
    summary["wall_s"] = time.perf_counter() - t0
    summary["frames"] = frames
    torch.save(actor.state_dict(), log_dir / "policy.pt")
    (log_dir / "eval.json").write_text(
        json.dumps({"summary": summary, "rows": rows, "config": cfg.to_dict()}, indent=1)
    )
    logger.close()
    if not env.is_closed:
        env.close()
    return summary


def _task_dict(task: CrossingTask) -> dict[str, Any]:
    return {k: v for k, v in vars(task).items()}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sharedspace.marl", description=__doc__)
    ap.add_argument("--set", action="append", default=[], help="key=value (MarlConfig field)")
    ap.add_argument("--resume", action="store_true", help="continue from log_dir's checkpoint")
    args = ap.parse_args(argv)
    cfg = apply_overrides(MarlConfig(), args.set)
    summary = train(cfg, resume=args.resume)
    print(
        f"{cfg.algorithm} seed {cfg.seed}: per-car success {summary['success']['rate']:.3f}, "
        f"collision {summary['collision']['rate']:.3f}, "
        f"car-car {summary['car_collision']['rate']:.3f} on the test scenes; "
        f"{summary.get('wall_s', 0):.0f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
