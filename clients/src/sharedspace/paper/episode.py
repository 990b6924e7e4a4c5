"""One test episode of a policy as pictures: an animation (GIF, MP4) and the paper-style figure.

    python -m sharedspace.paper.episode --checkpoint results/table2/policies/g_sac_cog-s0.pt \\
        --scenario hbs-car1301 --set server_endpoint=tcp/127.0.0.1:7447 \\
        --gif out/ep.gif [--mp4 out/ep.mp4] [--figure out/ep.png]

The episode is played with the deterministic policy in a PettingZoo env on the server (the same
world as ``evaluate``: the checkpoint's pedestrian model, ``max_agents`` and the server's
parameters), recording every step's scene from the server's ``states`` and ``risk_graph``
publications (:mod:`sharedspace.scene_plot` draws them). ``--driver NAME`` plays a scripted
driver instead (``sharedspace.paper.drivers``).

The figure follows the paper's Figs. 6-7: four snapshots of the episode (start, two in between,
end) above the ego's speed, acceleration and heading over time beside the recorded human
driver's in the same scenario.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sharedspace.cli import run_command
from sharedspace.scene_plot import Frame, draw_scene, scene_rgb
from sharedspace.train.config import add_overrides_argument, command_parser

__all__ = ["Episode", "record_episode", "write_gif", "write_mp4", "episode_figure", "main"]


@dataclass
class Episode:
    """A played episode: one :class:`Frame` per step (step 0 first) and the ego's profile."""

    scenario: str
    frames: list[Frame] = field(default_factory=list)
    speeds: list[float] = field(default_factory=list)  # m/s, per step
    headings: list[float] = field(default_factory=list)  # rad, per step
    outcome: str = "timeout"
    dt: float = 0.5


def record_episode(env, policy, scenario: str, seed: int = 0, max_steps: int = 400) -> Episode:
    """Plays ``scenario`` in ``env`` (a :class:`~sharedspace.pettingzoo_env.SharedSpaceParallelEnv`
    made with ``render_mode="rgb_array"``, one controlled vehicle) with ``policy`` (a
    TensorDictModule reading ``features``, ``adjacency``, ``mask`` and writing ``action``)."""
    obs, _ = env.reset(seed=seed, options={"scenario": scenario})
    ep = Episode(scenario=scenario)
    agent = env.possible_agents[0]
    for _ in range(max_steps + 1):
        frame = env.scene_frame()
        if frame is not None:
            ep.frames.append(frame)
        ego = obs[agent]["features"][0]
        ep.speeds.append(float(ego[4]))
        ep.headings.append(_ego_heading(frame))
        if not env.agents:
            break
        td = TensorDict(
            {
                "features": torch.as_tensor(obs[agent]["features"])[None],
                "adjacency": torch.as_tensor(obs[agent]["adjacency"])[None],
                "mask": torch.as_tensor(obs[agent]["mask"]).bool()[None],
                "scenario_index": torch.tensor([[0]]),
            },
            batch_size=[1],
        )
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            action = policy(td)["action"][0].numpy().astype(np.float32)
        obs, _, terms, truncs, infos = env.step({agent: action})
        if terms[agent] or truncs[agent]:
            info = infos[agent]
            ep.outcome = next(
                (o for o in ("success", "collision", "timeout") if info.get(o)),
                "timeout" if truncs[agent] else "collision",
            )
    if ep.frames:
        ep.frames[-1].note = f"{scenario}: {ep.outcome}"
    return ep


def _ego_heading(frame: Frame | None) -> float:
    if frame is None:
        return float("nan")
    ego = next((a for a in frame.agents if a.controlled), None)
    return float("nan") if ego is None else ego.heading


def _view(ep: Episode) -> tuple[float, float, float, float]:
    """One window for the whole episode (every agent at every step), so the camera is still."""
    xs = [a.x for f in ep.frames for a in f.agents] + [g[0] for f in ep.frames for g in f.goals]
    ys = [a.y for f in ep.frames for a in f.agents] + [g[1] for f in ep.frames for g in f.goals]
    return min(xs) - 4, max(xs) + 4, min(ys) - 4, max(ys) + 4


def write_gif(ep: Episode, path: str | Path, size: tuple[int, int] = (480, 480)) -> Path:
    """The episode as an animated GIF at the simulation's rate (2 steps per second)."""
    from PIL import Image

    view = _view(ep)
    images = [Image.fromarray(scene_rgb(f, size=size, view=view)) for f in ep.frames]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=int(1000 * ep.dt),
        loop=0,
        optimize=True,
    )
    return path


def write_mp4(ep: Episode, path: str | Path, size: tuple[int, int] = (480, 480)) -> Path:
    """The episode as an H.264 MP4 (ffmpeg from the ``imageio-ffmpeg`` wheel)."""
    try:
        import imageio_ffmpeg
    except ImportError as exc:  # pragma: no cover - listed in requirements-train.txt
        raise RuntimeError("MP4 needs imageio-ffmpeg (pip install imageio-ffmpeg)") from exc
    view = _view(ep)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = size
    writer = imageio_ffmpeg.write_frames(
        str(path), (w, h), fps=1.0 / ep.dt, macro_block_size=16, quality=7
    )
    writer.send(None)
    for f in ep.frames:
        writer.send(np.ascontiguousarray(scene_rgb(f, size=size, view=view)))
    writer.close()
    return path


def episode_figure(
    ep: Episode,
    path: str | Path,
    human_speeds: Sequence[float] | None = None,
    human_headings: Sequence[float] | None = None,
) -> Path:
    """Four snapshots above speed / acceleration / heading profiles (policy vs human)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    view = _view(ep)
    n = len(ep.frames)
    picks = sorted({0, n // 3, (2 * n) // 3, n - 1})
    fig = plt.figure(figsize=(16, 8.5))
    grid = fig.add_gridspec(2, max(len(picks), 3), height_ratios=[1.6, 1])
    for col, k in enumerate(picks):
        ax = fig.add_subplot(grid[0, col])
        draw_scene(ax, ep.frames[k], view=view, legend=col == len(picks) - 1)
        ax.set_title(f"t = {k * ep.dt:.1f} s", fontsize=10)
    dt = ep.dt
    t = np.arange(len(ep.speeds)) * dt
    speeds = np.asarray(ep.speeds)
    panels = [
        ("speed (m/s)", speeds, None if human_speeds is None else np.asarray(human_speeds)),
        (
            "acceleration (m/s²)",
            np.diff(speeds) / dt,
            None if human_speeds is None else np.diff(np.asarray(human_speeds)) / dt,
        ),
        (
            "heading (rad)",
            np.unwrap(np.asarray(ep.headings)),
            None if human_headings is None else np.unwrap(np.asarray(human_headings)),
        ),
    ]
    for col, (label, policy, human) in enumerate(panels):
        ax = fig.add_subplot(grid[1, col])
        ax.plot(t[: len(policy)], policy, label=f"policy ({ep.outcome})")
        if human is not None:
            ax.plot(np.arange(len(human)) * dt, human, "--", label="human")
        ax.set_xlabel("t (s)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if col == 0:
            ax.legend(fontsize=8)
    fig.suptitle(ep.scenario)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _human_profile(scenario: str, pool: Any = None) -> tuple[list[float], list[float]] | None:
    """The recorded ego's speeds and headings of ``scenario`` (the embedded pool file)."""
    from sharedspace.pool import load_pool, recorded_headings

    try:
        scenarios = load_pool(pool)
    except (OSError, ValueError):
        return None
    for sc in scenarios:
        if sc["name"] == scenario:
            vel = np.asarray(sc["agents"][int(sc["ego"])]["velocities"], dtype=float).reshape(-1, 2)
            return np.hypot(vel[:, 0], vel[:, 1]).tolist(), list(recorded_headings(vel))
    return None


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.paper.episode", __doc__)
    who = ap.add_mutually_exclusive_group(required=True)
    who.add_argument("--checkpoint", help="checkpoint or shipped policy (.pt)")
    who.add_argument("--driver", help="a scripted driver (sharedspace.paper.drivers)")
    ap.add_argument("--scenario", required=True, help="scenario name, e.g. hbs-car1301")
    ap.add_argument("--split", default="test", help="the scenario's split")
    ap.add_argument("--gif", default="", help="write the animation here (GIF)")
    ap.add_argument("--mp4", default="", help="write the animation here (MP4)")
    ap.add_argument("--figure", default="", help="write the four-snapshot figure here (PNG)")
    add_overrides_argument(ap, "config overrides (server_endpoint=..., server_prefix=...)")
    args = ap.parse_args(argv)
    from sharedspace.paper.drivers import make_driver
    from sharedspace.pettingzoo_env import SharedSpaceParallelEnv
    from sharedspace.train.learners import load_checkpoint_actor
    from sharedspace.world_config import WorldConfig

    if args.checkpoint:
        cfg, policy = load_checkpoint_actor(args.checkpoint, args.set)
        world, seed = cfg.world, cfg.seed
    else:
        world, seed, policy = WorldConfig.from_words(args.set), 0, make_driver(args.driver)
    env = SharedSpaceParallelEnv(
        world.env_spec(args.split, seed), client=world.connection(), render_mode="rgb_array"
    )
    try:
        ep = record_episode(env, policy, args.scenario, seed=seed)
    finally:
        env.close()
    print(
        f"{args.scenario}: {ep.outcome} after {len(ep.speeds) - 1} steps "
        f"({len(ep.frames)} frames recorded)"
    )
    if args.gif:
        print("wrote", write_gif(ep, args.gif))
    if args.mp4:
        print("wrote", write_mp4(ep, args.mp4))
    if args.figure:
        human = _human_profile(args.scenario, world.scenario_pool or None)
        speeds, headings = human if human else (None, None)
        print("wrote", episode_figure(ep, args.figure, speeds, headings))
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
