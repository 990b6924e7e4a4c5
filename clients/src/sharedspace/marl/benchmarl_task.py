"""The crossing task as a BenchMARL task, and one BenchMARL MAPPO experiment on it.

BenchMARL 1.5.2 pins torchrl < 0.12, so this module runs in its own venv
(``make benchmarl``: ``.venv-benchmarl``, clients/requirements-benchmarl.txt); nothing else in
the package imports it. The env is the same
:class:`~sharedspace.torchrl_multiagent.RemoteMultiAgentEnv` that ``python -m sharedspace.marl``
trains on, with the same residual over the car-aware script,
plus :class:`~sharedspace.marl.task.FlatObservation` (BenchMARL's models read one observation
vector per agent). The per-car outcome flags are the task's info; ``log_info`` turns them into
``collection/vehicle/success`` etc.

    .venv-benchmarl/bin/python -m sharedspace.marl.benchmarl_task --frames 60000 \\
        --out results/marl/benchmarl
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from benchmarl.algorithms import MappoConfig
from benchmarl.environments.common import Task, TaskClass
from benchmarl.experiment import Experiment, ExperimentConfig
from benchmarl.models.mlp import MlpConfig
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.transforms import Compose

from sharedspace.cli import run_command
from sharedspace.client import Connection
from sharedspace.marl.task import CrossingTask, FlatObservation, make_env
from sharedspace.torchrl_multiagent import AGENT_OUTCOME_KEYS
from sharedspace.train.envs import ResidualAction
from sharedspace.train.reward import LEARNER_REWARD

__all__ = ["SharedspaceClass", "SharedspaceTask", "run_mappo", "main"]

GROUP = "vehicle"
_OBSERVED = ("features", "adjacency", "mask", "observation")


class SharedspaceClass(TaskClass):
    """BenchMARL's view of the crossing task. ``config``: ``endpoint`` and ``prefix`` of the
    server, optional ``task`` (CrossingTask fields), ``base_driver`` (default ``car_aware``, ""
    for absolute actions), ``residual_scale`` (default 2.0) and ``reward_weights`` (default
    the learners' own, :data:`~sharedspace.train.reward.LEARNER_REWARD`)."""

    def _task(self) -> CrossingTask:
        return CrossingTask(**self.config.get("task", {}))

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        cfg = dict(self.config)
        task = self._task()

        def make() -> EnvBase:
            client = Connection(endpoint=cfg["endpoint"], prefix=cfg.get("prefix", "sharedspace"))
            env = make_env(
                task,
                "train",
                num_envs,
                client,
                seed=seed or 0,
                reward_weights=cfg.get("reward_weights", LEARNER_REWARD),
            )
            transforms = [FlatObservation(GROUP)]
            if cfg.get("base_driver", "car_aware"):
                transforms.append(
                    ResidualAction(
                        cfg.get("base_driver", "car_aware"), GROUP, cfg.get("residual_scale", 2.0)
                    )
                )
            return TransformedEnv(env, Compose(*transforms))

        return make

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return 100  # an episode's horizon is at most ~60 steps

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return {GROUP: list(self._task().agents)}

    def observation_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched.clone()
        for key in list(spec[GROUP].keys()):
            if key != "observation":
                del spec[(GROUP, key)]
        return spec

    def info_spec(self, env: EnvBase) -> Composite | None:
        spec = env.full_observation_spec_unbatched.clone()
        for key in _OBSERVED:
            del spec[(GROUP, key)]
        return spec

    def state_spec(self, env: EnvBase) -> Composite | None:
        return None

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return "sharedspace"

    def log_info(self, batch: TensorDictBase) -> dict[str, float]:
        """Per-car outcome rates of the episodes that ended in a collected batch."""
        nxt = batch.get(("next", GROUP))
        ended = sum(
            float(nxt.get(f"episode_{s}").sum()) for s in ("success", "collision", "timeout")
        )
        if not ended:
            return {}
        return {
            f"collection/{GROUP}/{key.removeprefix('episode_')}": float(nxt.get(key).sum()) / ended
            for key in AGENT_OUTCOME_KEYS
        }


class SharedspaceTask(Task):
    """The sharedspace tasks BenchMARL can run."""

    CROSSING = None

    @staticmethod
    def associated_class():
        return SharedspaceClass


def run_mappo(
    endpoint: str,
    prefix: str,
    out: Path,
    *,
    frames: int = 60_000,
    frames_per_batch: int = 6_000,
    num_envs: int = 60,
    seed: int = 0,
    task: dict[str, Any] | None = None,
) -> Experiment:
    """One BenchMARL MAPPO experiment on the crossing task against the server at ``endpoint``;
    its CSV logs and JSON go under ``out``."""
    config = {"endpoint": endpoint, "prefix": prefix, "task": task or {}}
    experiment_config = ExperimentConfig.get_from_yaml()
    experiment_config.max_n_frames = frames
    experiment_config.on_policy_collected_frames_per_batch = frames_per_batch
    experiment_config.on_policy_n_envs_per_worker = num_envs
    experiment_config.on_policy_n_minibatch_iters = 4
    experiment_config.on_policy_minibatch_size = min(512, frames_per_batch)
    experiment_config.lr = 3e-4
    experiment_config.evaluation_interval = frames_per_batch * max(
        1, frames // frames_per_batch // 4
    )
    experiment_config.evaluation_episodes = 8
    experiment_config.render = False
    experiment_config.loggers = ["csv"]
    experiment_config.create_json = True
    experiment_config.checkpoint_at_end = True
    out.mkdir(parents=True, exist_ok=True)
    experiment_config.save_folder = str(out)
    experiment = Experiment(
        task=SharedspaceTask.CROSSING.get_task(config=config),
        algorithm_config=MappoConfig.get_from_yaml(),
        model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(),
        seed=seed,
        config=experiment_config,
    )
    experiment.run()
    return experiment


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m sharedspace.marl.benchmarl_task", description=__doc__
    )
    ap.add_argument("--endpoint", default="", help="server endpoint; '' = a local sim-server")
    ap.add_argument("--frames", type=int, default=60_000, help="frames to collect")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/marl/benchmarl", help="experiment folder")
    args = ap.parse_args(argv)
    import benchmarl
    import torch
    import torchrl

    from sharedspace.local_server import LocalServer
    from sharedspace.marl.evaluate import play, policy_act, summarize

    server = None if args.endpoint else LocalServer(prefix="benchmarl")
    endpoint = args.endpoint or server.endpoint
    prefix = "benchmarl" if server else "sharedspace"
    t0 = time.time()
    try:
        experiment = run_mappo(endpoint, prefix, Path(args.out), frames=args.frames, seed=args.seed)
        wall = time.time() - t0
        # The trained policy on the crossing task's test scenes, as the sharedspace.marl rows.
        policy = experiment.policy
        rows = play(
            CrossingTask(),
            policy_act(_ObservationThen(policy), "car_aware", 2.0),
            Connection(endpoint=endpoint, prefix=prefix),
        )
    finally:
        if server is not None:
            server.close()
    summary = summarize(rows)
    report = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "versions": {
            "benchmarl": benchmarl.__version__,
            "torchrl": torchrl.__version__,
            "torch": torch.__version__,
        },
        "frames": args.frames,
        "seed": args.seed,
        "wall_s": wall,
        "summary": summary,
        "rows": rows,
    }
    Path(args.out, "eval.json").write_text(json.dumps(report, indent=1))
    print(
        f"BenchMARL MAPPO ({report['versions']}): "
        f"per-car success {summary['success']['rate']:.3f}, "
        f"collision {summary['collision']['rate']:.3f} on the test scenes; {wall:.0f} s"
    )
    return 0


class _ObservationThen:
    """BenchMARL's policy reads ``(vehicle, observation)``: compute it from the raw
    observation first (what :class:`FlatObservation` adds in the env)."""

    def __init__(self, policy):
        self.policy = policy
        self.flat = FlatObservation(GROUP)

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        return self.policy(self.flat._call(td))


if __name__ == "__main__":
    sys.exit(run_command(main))
