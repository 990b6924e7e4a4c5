"""Stable-Baselines3's PPO on the Gymnasium env, in the paper task's world, then scored by the
bench beside nothing but its own numbers.

    python examples/sb3_ppo.py --steps 300000               # about 10 minutes on 2 cores
    python examples/sb3_ppo.py --steps 2048 --variations 1  # a smoke test

The observation is a dict (features, risk graph, mask); `FlattenObservation` makes it the flat
vector SB3's `MlpPolicy` takes (a graph encoder would need SB3's `features_extractor_class`;
the project's own PPO has one: `python -m sharedspace.train --set algorithm=ppo`). The envs
play the paper task's train scenes in its world (Table II's parameters, the training
variations), on a local server this process starts; the bench then plays its test scenes,
which training never saw.
"""

from __future__ import annotations

import argparse
import dataclasses

import gymnasium as gym
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

import sharedspace  # noqa: F401 - registers sharedspace/SharedSpace-v0
from sharedspace.bench import get_task, score
from sharedspace.local_server import shared_server
from sharedspace.worlds import TRAINING_VARIATIONS, training_task, world_params_file


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300_000, help="env steps to train for")
    ap.add_argument("--envs", type=int, default=8)
    ap.add_argument("--variations", type=int, default=0, help="fewer test variations")
    args = ap.parse_args()
    server = shared_server(params=world_params_file(training_task("paper")))
    options = {"endpoint": server.endpoint, "prefix": server.prefix}

    def make_env():
        env = gym.make("sharedspace/SharedSpace-v0", variations=TRAINING_VARIATIONS, **options)
        return gym.wrappers.FlattenObservation(env)

    envs = make_vec_env(make_env, n_envs=args.envs, seed=0)
    model = PPO("MlpPolicy", envs, n_steps=256, batch_size=512, seed=0, verbose=0)
    model.learn(total_timesteps=args.steps)
    envs.close()

    space = gym.make("sharedspace/SharedSpace-v0", **options).observation_space

    def act(obs):
        action, _ = model.predict(gym.spaces.flatten(space, obs), deterministic=True)
        return action

    task = get_task("paper")
    if args.variations:
        task = dataclasses.replace(
            task,
            name="paper-quick",
            version=0,
            variations=args.variations,
            description=f"paper's scenes x {args.variations} variation(s): a quick look",
        )
    print(score(task, act, name=f"sb3-ppo-{args.steps}").markdown())


if __name__ == "__main__":
    main()
