"""Where a PPO iteration's time and CPU go, phase by phase, on Table II-G's world: collection
(of it, the env's round trips and the policy's forward passes) and the update, each as wall
seconds and as CPU seconds of the trainer (every thread) and of its local server.

The CPU seconds bound what any overlap of the two phases can give on this machine: a batch
cannot take less wall time than its CPU seconds over the cores, whatever runs beside what.

Usage: python benchmarks/ppo_phases.py [--networks mlp gcn_risk] [--batches 12]
       [--update-threads 0 1] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time

import torch

from sharedspace.train import ppo
from sharedspace.train.config import load_config
from sharedspace.train.loop import make_collector

from overlap_ab import children  # benchmarks/, beside this script
from soak import cpu_s as cpu_of


def server_pids() -> list[int]:
    """This process's children: the local sim-server the run started."""
    return children(os.getpid())


class Meter:
    """Wall, trainer CPU and server CPU seconds between ``start`` and ``stop``."""

    def __init__(self):
        self.rows: list[dict] = []

    def start(self) -> None:
        self.t = time.perf_counter(), time.process_time(), sum(map(cpu_of, server_pids()))

    def stop(self, **more) -> None:
        w, c, s = self.t
        self.rows.append(
            {
                "wall": time.perf_counter() - w,
                "trainer_cpu": time.process_time() - c,
                "server_cpu": sum(map(cpu_of, server_pids())) - s,
            }
            | more
        )

    def median(self) -> dict:
        rows = self.rows[1:]  # the first batch allocates and resets
        return {k: statistics.median(r[k] for r in rows) for k in rows[0]}


def phases(network: str, threads: int, batches: int, more: list[str]) -> dict:
    cfg = load_config(
        None,
        [
            "task=crowd",
            "algorithm=ppo",
            f"network={network}",
            f"update_threads={threads}",
            "overlap=false",
            "eval_interval=0",
            "checkpoint_interval=0",
            "progress=false",
            f"total_frames={batches * 8192}",
            *more,
        ],
    )
    world = ppo.make_world(cfg)
    env = world.make_env(seed=0)
    learner = ppo.make_learner(cfg, world, env)
    forward_s = [0.0]
    inner = learner.actor.forward

    def timed_forward(*a, **k):
        t0 = time.perf_counter()
        out = inner(*a, **k)
        forward_s[0] += time.perf_counter() - t0
        return out

    learner.actor.forward = timed_forward
    collector = make_collector(cfg, env, learner, cfg.total_frames, 0)
    collect, update = Meter(), Meter()
    counters = {"frames": 0, "updates": 0}
    collect.start()
    env0, fwd0 = env.env_time_s, 0.0
    for data in collector:
        collect.stop(env_s=env.env_time_s - env0, forward_s=forward_s[0] - fwd0)
        counters["frames"] += data.numel()
        update.start()
        learner.step(data, counters)
        update.stop()
        collect.start()
        env0, fwd0 = env.env_time_s, forward_s[0]
    collector.shutdown()
    frames = learner.batch_frames
    c, u = collect.median(), update.median()
    cpu = c["trainer_cpu"] + c["server_cpu"] + u["trainer_cpu"] + u["server_cpu"]
    return {
        "network": network,
        "update_threads": threads,
        "collect": c,
        "update": u,
        "fps_alternating": frames / (c["wall"] + u["wall"]),
        "cpu_s_per_batch": cpu,
        "fps_bound_cpu": frames / (cpu / (os.cpu_count() or 1)),
        "fps_bound_phases": frames / max(c["wall"], u["wall"]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--networks", nargs="+", default=["mlp", "gcn_risk"])
    ap.add_argument("--update-threads", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--batches", type=int, default=12)
    ap.add_argument("--set", nargs="*", default=[])
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = []
    for network in args.networks:
        for threads in args.update_threads:
            row = phases(network, threads, args.batches, args.set)
            out.append(row)
            c, u = row["collect"], row["update"]
            print(
                f"{network:9s} threads {threads}: collect {c['wall']:.3f} s "
                f"(env {c['env_s']:.3f}, forward {c['forward_s']:.3f}; cpu trainer "
                f"{c['trainer_cpu']:.3f} server {c['server_cpu']:.3f}) | update {u['wall']:.3f} s "
                f"(cpu trainer {u['trainer_cpu']:.3f}) | alternating {row['fps_alternating']:.0f}"
                f" fr/s, bound by cpu {row['fps_bound_cpu']:.0f}, by phases "
                f"{row['fps_bound_phases']:.0f}",
                flush=True,
            )
    print(json.dumps(out))


if __name__ == "__main__":
    main()
