"""Training an adversary against a named driver: the one training loop
(:func:`sharedspace.train.loop.train`) with PPO, in the world of :class:`AdversaryWorld`.

    python -m sharedspace.adversary train --driver car_aware --frames 1000000

The adversary trains on the task's train scenes, in drawn variations, against the frozen
driver; its curve (``eval/*`` in ``metrics.csv``) is its outcomes on 64 fixed train episodes
(``success``: the driver hit it at fault). Nothing is chosen on them: the budget is fixed
before the run and its last checkpoint is the adversary.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

from sharedspace.adversary.env import AdversaryEnv
from sharedspace.adversary.task import AdversaryTask, get_adversary_task
from sharedspace.bench.policies import Policy, make_policy
from sharedspace.client import Connection
from sharedspace.episodes import run_episodes, summarize
from sharedspace.train.checkpoint import last_checkpoint
from sharedspace.train.config import TrainConfig, apply_overrides
from sharedspace.train.loop import OneCar
from sharedspace.train.loop import train as train_loop

__all__ = ["ADVERSARY_DEFAULTS", "AdversaryWorld", "adversary_config", "serve_task", "train"]

#: The adversary's learner: PPO over the MLP (the cheapest network; the graph is the same one
#: a driver sees), 64 sub-envs x 32 steps per batch, a scoring every 262 144 frames.
ADVERSARY_DEFAULTS = {
    "algorithm": "ppo",
    "network": "mlp",
    "num_envs": 64,
    "base_driver": "",
    "eval_interval": 262_144,
    "checkpoint_interval": 262_144,
    "minibatch_size": 1024,
    "entropy_coeff": 0.001,
}

#: Train episodes of each scoring of the curve.
CURVE_EPISODES = 64


def adversary_config(task: AdversaryTask, overrides: list[str] | dict) -> TrainConfig:
    """The adversary's :class:`~sharedspace.train.config.TrainConfig`: the defaults above,
    the driving task's ``max_agents``, then ``overrides`` (``KEY=VALUE``)."""
    base = TrainConfig.from_dict(
        ADVERSARY_DEFAULTS | {"max_agents": task.driving.max_agents, "device": "cpu"}
    )
    return apply_overrides(base, overrides)


def serve_task(task: AdversaryTask, folder: Path) -> Connection:
    """A local ``sim-server`` serving the task's pool in its world (parameters in ``folder``)."""
    params = folder / f"{task.name}-v{task.version}-params.json"
    params.write_text(json.dumps(task.driving.world_params))
    return Connection.resolve(local_pools=[str(task.pool_path())], local_params=str(params))


class AdversaryWorld(OneCar):
    """The training loop's world of an adversary of ``driver`` on ``task``: its envs on
    ``client`` and its curve; the ended episodes are counted as :class:`~sharedspace.train.
    loop.OneCar` counts a car's (the episode keys read as the adversary's outcomes)."""

    def __init__(self, cfg: TrainConfig, task: AdversaryTask, driver: Policy, client):
        super().__init__(cfg)
        self.task, self.driver, self.client = task, driver, client
        pool = json.loads(task.pool_path().read_text())
        self.curve_scenes = [s["name"] for s in pool["scenarios"] if s["split"] == "train"][
            :CURVE_EPISODES
        ]

    def make_env(self, seed: int) -> AdversaryEnv:
        return AdversaryEnv(
            self.driver,
            self.task,
            self.cfg.algo.num_envs,
            seed=seed,
            reward_weights=self.cfg.algo.reward_weights,
            client=self.client,
        )

    def evaluate(self, actor) -> dict[str, Any]:
        env = AdversaryEnv(
            self.driver,
            self.task,
            len(self.curve_scenes),
            scenarios=self.curve_scenes,
            variation_seeds=[0] * len(self.curve_scenes),
            reward_weights=self.cfg.algo.reward_weights,
            client=self.client,
        )
        try:
            return summarize(run_episodes(env, actor))
        finally:
            env.close()

    def record(self) -> dict[str, Any]:
        return {
            "adversary": {
                "task": self.task.tag,
                "fingerprint": self.task.fingerprint(),
                "driver": self.driver.name,
                "driver_source": self.driver.source,
            },
            "max_agents": self.cfg.world.max_agents,
        }


def train(
    driver: Any,
    log_dir: str | Path,
    frames: int,
    overrides: list[str] = (),
    task: str | AdversaryTask = "crowd-adversary",
    resume: bool = True,
) -> dict[str, Any]:
    """Trains an adversary of ``driver`` (a policy spec) for ``frames`` frames into
    ``log_dir``, from its ``checkpoints/last.pt`` when there is one and ``resume``."""
    task = get_adversary_task(task) if isinstance(task, str) else task
    cfg = adversary_config(task, [*overrides, f"total_frames={frames}", f"log_dir={Path(log_dir)}"])
    policy = driver if isinstance(driver, Policy) else make_policy(driver, task.driving)
    with tempfile.TemporaryDirectory() as tmp:
        client = serve_task(task, Path(tmp)).open()
        try:
            world = AdversaryWorld(cfg, task, policy, client)
            start = last_checkpoint(log_dir) if resume else None
            return train_loop(cfg, resume=start, world=world)
        finally:
            client.shutdown()
