"""The failures an adversary found, as animations: an episode of a stress scoring replayed in
a PettingZoo env (same scene, variation, driver and adversary), every step's scene drawn from
the server's publications (:mod:`sharedspace.scene_plot`; the adversary purple and ringed).

    python -m sharedspace.adversary gifs --stress results/adversary/car_aware.json --label own

picks ``--count`` episodes the driver failed against the adversary and passed against CR-SFM
(:func:`found_failures`: at fault first) and writes
``results/adversary/gifs/DRIVER-LABEL-SCENE-vV.gif`` with a still of the last step (``.png``).
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sharedspace.adversary.env import ADVERSARY, DRIVER
from sharedspace.adversary.stress import load_adversary
from sharedspace.adversary.task import AdversaryTask, get_adversary_task, plausible_action
from sharedspace.adversary.train import serve_task
from sharedspace.bench.policies import Policy, make_policy
from sharedspace.names import Feature
from sharedspace.paper.episode import Episode, write_gif
from sharedspace.pool import listed_scenarios
from sharedspace.scene_plot import scene_rgb

__all__ = ["found_failures", "record_stress_episode", "write_failures"]


def found_failures(result: dict[str, Any], label: str, count: int = 3) -> list[dict[str, Any]]:
    """The first ``count`` episodes (pool order) that the driver failed against adversary
    ``label`` and reached its goal in against CR-SFM with the same policy: those where it was
    at fault first, then its other collisions, then its timeouts."""
    base = {
        (e["scene"], e["variation"], e["policy"]): e
        for e in result["conditions"]["CR-SFM"]["episodes"]
    }
    failed = [
        e
        for e in result["conditions"][label]["episodes"]
        if e["driver"] != "success"
        and base.get((e["scene"], e["variation"], e["policy"]), {}).get("driver") == "success"
    ]
    rank = {"collision": 1, "timeout": 2}
    failed.sort(key=lambda e: 0 if e["fault"] else rank.get(e["driver"], 3))
    return failed[:count]


def _td(obs: dict[str, np.ndarray]) -> TensorDict:
    return TensorDict(
        {
            "features": torch.as_tensor(obs["features"])[None],
            "adjacency": torch.as_tensor(obs["adjacency"])[None],
            "mask": torch.as_tensor(obs["mask"]).bool()[None],
        },
        batch_size=[1],
    )


def record_stress_episode(
    driver: Policy, adversary, task: AdversaryTask, scene: str, variation: int, client
) -> Episode:
    """Plays ``scene`` in ``variation`` with ``driver`` against the ``adversary`` actor, as
    :func:`sharedspace.adversary.stress.play` does, and keeps every step's scene."""
    from sharedspace.pettingzoo_env import SharedSpaceParallelEnv

    driving = task.driving
    pool_name, _ = listed_scenarios(str(task.pool_path()))
    env = SharedSpaceParallelEnv(
        client=client,
        pool=pool_name,
        split="test",
        pedestrian_model=driving.pedestrian_model,
        max_agents=driving.max_agents,
        variations=dict(driving.variation_spec),
        external_agents=[DRIVER, ADVERSARY],
        render_mode="rgb_array",
    )
    walking, acc_max = task.walking_range, float(driving.world_params.get("ped_acc_max", 2.0))
    dt = float(driving.world_params.get("dt", 0.5))
    ep = Episode(scenario=scene)
    try:
        obs, _ = env.reset(options={"scenario": scene, "variation": variation})
        while DRIVER in env.agents:
            frame = env.scene_frame()
            if frame is not None:
                ep.frames.append(frame)
            mine = {k: np.asarray(obs[DRIVER][k])[None] for k in ("features", "adjacency", "mask")}
            actions = {DRIVER: np.asarray(driver.act(mine), np.float32).reshape(2)}
            if ADVERSARY in env.agents:
                with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
                    command = adversary(_td(obs[ADVERSARY]))["action"].numpy().reshape(1, 2)
                speed = np.array([obs[ADVERSARY]["features"][0, Feature.SPEED]])
                actions[ADVERSARY] = plausible_action(command, speed, dt, acc_max, walking)[0]
            obs, _, terms, truncs, infos = env.step(actions)
            if terms.get(DRIVER) or truncs.get(DRIVER):
                info = infos[DRIVER]
                ep.outcome = next((o for o in ("success", "collision") if info.get(o)), "timeout")
        frame = env.scene_frame()
        if frame is not None:
            ep.frames.append(frame)
    finally:
        env.close()
    if ep.frames:
        ep.frames[-1].note = f"{scene} v{variation}: the driver's {ep.outcome}"
    return ep


def write_failures(
    result_file: str | Path, label: str, out: str | Path, count: int = 3
) -> list[Path]:
    """GIFs (and a still of the last step) of the failures :func:`found_failures` picks from a
    stress scoring's JSON."""
    result = json.loads(Path(result_file).read_text())
    task = get_adversary_task(result["task"])
    adversary = load_adversary(result["conditions"][label]["adversary"], task)
    specs = result["driver_specs"]
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        client = serve_task(task, Path(tmp)).open()
        try:
            for e in found_failures(result, label, count):
                driver = make_policy(specs[e["policy"]], task.driving)
                ep = record_stress_episode(
                    driver, adversary, task, e["scene"], int(e["variation"]), client
                )
                stem = f"{result['driver']}-{label}-{e['scene']}-v{e['variation']}"
                path = write_gif(ep, Path(out) / f"{stem}.gif")
                from PIL import Image

                Image.fromarray(scene_rgb(ep.frames[-1], size=(480, 480))).save(
                    Path(out) / f"{stem}.png"
                )
                written.append(path)
        finally:
            client.shutdown()
    return written
