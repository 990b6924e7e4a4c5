"""The learners' throughput, side by side on one server: how many env frames per second each
learner digests end to end (collection plus updates), against the env's own rate.

In one run, against one local ``sim-server`` serving Table II-G's world (hbs-general with
reacting cars, params/table2g.json5, ``max_agents`` 10, the training variations):

- ``env``: the raw env rate, random actions, the same K and the same TorchRL env as PPO;
- ``ppo-mlp``, ``ppo-gcn-cog``: PPO end to end (``sharedspace.train.ppo``), with where the
  time went: collection (of it, the env's round trips) and updates;
- ``sac-gcn-cog``: the paper's SAC-GCN (its defaults: K 8, UTD 0.5, batch 256), after its
  random warm-up;
- ``mappo``: MAPPO on the crossing task (``sharedspace.marl``, its defaults; frames are sub-env
  steps, each moving 4 cars).

Each learner row is also stated as a share of the raw env rate. Prints a markdown table and
one JSON line (docs/BENCHMARKS.md keeps them with the machine and the date).

Usage: python benchmarks/learner_throughput.py [--pool out/table2g/pool-general.json]
       [--envs 256] [--ppo-frames 65536] [--sac-frames 3000] [--mappo-frames 40960]
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import tempfile
import time
from pathlib import Path

import torch

from sharedspace.local_server import LocalServer
from sharedspace.marl.train import train as train_marl
from sharedspace.train.config import TrainConfig, apply_overrides
from sharedspace.train.envs import make_env
from sharedspace.train.train import train

from script_returns import CROWD_WORLD as WORLD  # this folder: Table II-G's world


def env_rate(cfg: TrainConfig, steps: int) -> dict:
    """Random actions through the learner's TorchRL env (``step_and_maybe_reset``)."""
    env = make_env(
        cfg.world, "train", cfg.algo.num_envs, cfg.seed, variations=cfg.world.variations
    )
    td = env.reset()
    for _ in range(5):  # warm-up
        td.set("action", torch.rand(cfg.algo.num_envs, 2) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)
    t0, env0 = time.perf_counter(), env.env_time_s
    for _ in range(steps):
        td.set("action", torch.rand(cfg.algo.num_envs, 2) * 2 - 1)
        _, td = env.step_and_maybe_reset(td)
    wall = time.perf_counter() - t0
    env_s = env.env_time_s - env0
    env.close()
    return {
        "fps": steps * cfg.algo.num_envs / wall,
        "env_share": env_s / wall,
        "frames": steps * cfg.algo.num_envs,
    }


def ppo_rate(base: TrainConfig, variant: str, frames: int, log_dir: Path) -> dict:
    """PPO end to end; the first iteration (allocation, first resets) is left out."""
    cfg = apply_overrides(
        base,
        [
            f"network={variant}",
            f"total_frames={frames}",
            f"log_dir={log_dir}",
            "eval_interval=0",
            "checkpoint_interval=0",
            "progress=false",
        ],
    )
    out = train(cfg)
    rows = _metrics(log_dir)
    iters = [r for r in rows if r["metric"] == "train/collect_s"][1:]
    upd = [r for r in rows if r["metric"] == "train/update_s"][1:]
    collect_s = sum(r["value"] for r in iters)
    update_s = sum(r["value"] for r in upd)
    n = len(iters) * cfg.algo.num_envs * cfg.algo.rollout_steps
    timing = out["timing"]
    return {
        "fps": n / (collect_s + update_s),
        "frames": n,
        "collect_s": collect_s,
        "update_s": update_s,
        "collect_fps": n / collect_s,
        "update_fps": n / update_s,
        "env_share_of_collect": timing["env_s"] / timing["collect_s"],
    }


def sac_rate(base: TrainConfig, frames: int, log_dir: Path) -> dict:
    """SAC-GCN with its defaults, timed over the batches after its random warm-up."""
    warmup = 1000
    world = {
        k: getattr(base, k)
        for k in ("scenario_pool", "server_endpoint", "server_prefix")
    }
    cfg = apply_overrides(
        TrainConfig(device="cpu", eval_split="test", **world, **WORLD),
        [
            "algorithm=sac",
            "network=gcn_risk",
            "num_envs=8",
            "reward=world",
            f"total_frames={frames + warmup}",
            f"init_random_frames={warmup}",
            f"log_dir={log_dir}",
            "eval_interval=0",
            "checkpoint_interval=0",
            "progress=false",
        ],
    )
    train(cfg)
    rows = [
        r
        for r in _metrics(log_dir)
        if r["metric"] == "train/fps" and r["frames"] > warmup + 64
    ]
    wall = [r["wall_s"] for r in _metrics(log_dir) if r["frames"] > warmup + 64]
    n = rows[-1]["frames"] - rows[0]["frames"]
    return {"fps": n / (max(wall) - min(wall)), "frames": n}


def mappo_rate(endpoint: str, prefix: str, frames: int, log_dir: Path) -> dict:
    """MAPPO on the crossing task (its defaults), timed after its first batch."""
    cfg = TrainConfig(
        algorithm="mappo",
        total_frames=frames,
        log_dir=str(log_dir),
        server_endpoint=endpoint,
        server_prefix=prefix,
        eval_interval=0,
    )
    train_marl(cfg)
    walls = [
        (r["frames"], r["value"])
        for r in _metrics(log_dir)
        if r["metric"] == "train/wall_s"
    ]
    (f0, w0), (f1, w1) = walls[0], walls[-1]
    return {"fps": (f1 - f0) / (w1 - w0), "frames": f1 - f0}


def _metrics(log_dir: Path) -> list[dict]:
    with open(log_dir / "metrics.csv") as f:
        return [
            {
                "frames": int(r["frames"]),
                "wall_s": float(r["wall_s"]),
                "metric": r["metric"],
                "value": float(r["value"]),
            }
            for r in csv.DictReader(f)
        ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--pool", default="out/table2g/pool-general.json", help="Table II-G's pool"
    )
    ap.add_argument("--envs", type=int, default=256, help="K, for the env and PPO")
    ap.add_argument("--rollout-steps", type=int, default=32, help="PPO's T")
    ap.add_argument(
        "--env-steps", type=int, default=200, help="steps of the raw env rate"
    )
    ap.add_argument("--ppo-frames", type=int, default=65536, help="frames per PPO run")
    ap.add_argument(
        "--sac-frames", type=int, default=2000, help="SAC frames after its warm-up"
    )
    ap.add_argument("--mappo-frames", type=int, default=40960, help="MAPPO frames")
    ap.add_argument(
        "--only", default="", help="comma-separated rows to run (default: all)"
    )
    args = ap.parse_args()
    only = set(args.only.split(",")) if args.only else None
    results: dict[str, dict] = {}
    with (
        LocalServer(
            cfg=[
                f"pools:{json.dumps([args.pool])}",
                f'params:"{WORLD["server_params"]}"',
            ],
            prefix="throughput",
        ) as server,
        tempfile.TemporaryDirectory() as tmp,
    ):
        base = TrainConfig(
            algorithm="ppo",
            scenario_pool=args.pool,
            eval_split="test",  # no evaluation here: the pool's train split as it is
            server_endpoint=server.endpoint,
            server_prefix="throughput",
            num_envs=args.envs,
            rollout_steps=args.rollout_steps,
            device="cpu",
            **WORLD,
        )
        runs = {
            "env": lambda: env_rate(base, args.env_steps),
            "ppo-mlp": lambda: ppo_rate(
                base, "s_sac", args.ppo_frames, Path(tmp) / "mlp"
            ),
            "ppo-gcn-cog": lambda: ppo_rate(
                base, "g_sac_cog", args.ppo_frames, Path(tmp) / "gcn"
            ),
            "sac-gcn-cog": lambda: sac_rate(base, args.sac_frames, Path(tmp) / "sac"),
            "mappo": lambda: mappo_rate(
                server.endpoint, "throughput", args.mappo_frames, Path(tmp) / "mappo"
            ),
        }
        for name, run in runs.items():
            if only is None or name in only:
                t0 = time.perf_counter()
                results[name] = run()
                results[name]["run_s"] = time.perf_counter() - t0
                print(f"{name}: {results[name]['fps']:.0f} frames/s", flush=True)
    env_fps = results.get("env", {}).get("fps")
    print(
        f"\nK = {args.envs}, T = {args.rollout_steps}; {platform.processor() or platform.machine()}"
    )
    print(
        "| run | frames/s | share of the env rate | collection frames/s | update frames/s |"
    )
    print("|---|---|---|---|---|")
    for name, r in results.items():
        share = f"{r['fps'] / env_fps:.2f}" if env_fps else "-"
        col = f"{r['collect_fps']:.0f}" if "collect_fps" in r else "-"
        upd = f"{r['update_fps']:.0f}" if "update_fps" in r else "-"
        print(f"| {name} | {r['fps']:.0f} | {share} | {col} | {upd} |")
    if "ppo-mlp" in results and "sac-gcn-cog" in results:
        ratio = results["ppo-mlp"]["fps"] / results["sac-gcn-cog"]["fps"]
        results["ppo_mlp_over_sac"] = {"ratio": ratio}
        print(f"PPO-MLP / SAC-GCN: {ratio:.0f}x")
    print(
        json.dumps({"envs": args.envs, "rollout_steps": args.rollout_steps, **results})
    )


if __name__ == "__main__":
    main()
