"""SAC update cost, old and new side by side: TorchRL's ``SACLoss`` (the trainer's learner until
2026-12-03) against :class:`sharedspace.train.update.SACUpdate`, on the same networks, batch
size and thread count, in interleaved rounds (docs/BENCHMARKS.md, "Learner").

    .venv/bin/python bench/sac_update.py [--variant g_sac_cog] [--batch 256] [--rounds 5]
        [--updates 50] [--threads 1] [--json out.json]

Each round times ``--updates`` gradient steps of each learner (replay sampling excluded: both
get the same pre-sampled batches) and reports ms per update; the summary is the median and
minimum over rounds and the ratio old / new of the medians.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time

import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from sharedspace.train.config import VARIANTS, TrainConfig
from sharedspace.train.sac import (
    make_actor,
    make_critic,
    make_loss,
    make_optimizers,
    make_update,
)


def fake_batch(batch: int, max_agents: int = 8, features: int = 11) -> TensorDict:
    """A replay batch with the trainer's keys and shapes (ENV_CONTRACT.md)."""

    def obs():
        mask = torch.rand(batch, max_agents) < 0.6
        mask[:, 0] = True
        return {
            "features": torch.randn(batch, max_agents, features) * 3,
            "adjacency": torch.rand(batch, max_agents, max_agents),
            "mask": mask,
        }

    nxt = TensorDict(
        {
            **obs(),
            "reward": torch.randn(batch, 1),
            "terminated": torch.rand(batch, 1) < 0.05,
            "done": torch.rand(batch, 1) < 0.05,
        },
        [batch],
    )
    return TensorDict(
        {**obs(), "action": torch.rand(batch, 2) * 2 - 1, "next": nxt}, [batch]
    )


def torchrl_learner(cfg: TrainConfig):
    """The old learner: SACLoss + three Adams + SoftUpdate, stepped as the trainer did."""
    spec = Bounded(-1.0, 1.0, (2,))
    actor, critic = make_actor(cfg, spec), make_critic(cfg, spec)
    probe = fake_batch(2)
    with torch.no_grad():
        critic(actor(probe))
    loss, target_update = make_loss(cfg, actor, critic)
    optimizers = make_optimizers(cfg, loss)

    def step(batch):
        out = loss(batch)
        for o in optimizers.values():
            o.zero_grad(set_to_none=True)
        (out["loss_qvalue"] + out["loss_actor"] + out["loss_alpha"]).backward()
        for o in optimizers.values():
            o.step()
        target_update.step()

    return step


def fused_learner(cfg: TrainConfig):
    spec = Bounded(-1.0, 1.0, (2,))
    actor = make_actor(cfg, spec)
    with torch.no_grad():
        actor(fake_batch(2))
    update = make_update(cfg, actor, spec)
    return update.step


def time_updates(step, batches) -> float:
    t0 = time.perf_counter()
    for b in batches:
        step(b)
    return (time.perf_counter() - t0) * 1e3 / len(batches)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--variant", default="g_sac_cog", choices=VARIANTS, help="network variant"
    )
    ap.add_argument("--batch", type=int, default=256, help="replay minibatch size")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds")
    ap.add_argument(
        "--updates", type=int, default=50, help="updates per learner per round"
    )
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--json", default="", help="write the figures to this file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = TrainConfig(variant=args.variant, batch_size=args.batch)
    learners = {"torchrl": torchrl_learner(cfg), "fused": fused_learner(cfg)}
    batches = [fake_batch(args.batch) for _ in range(args.updates)]
    for step in learners.values():  # warm-up: allocator, oneDNN primitives
        time_updates(step, batches[:5])
    ms: dict[str, list[float]] = {k: [] for k in learners}
    for r in range(args.rounds):
        for name, step in learners.items():
            ms[name].append(time_updates(step, batches))
        print(
            f"round {r}: " + ", ".join(f"{k} {v[-1]:.2f} ms" for k, v in ms.items()),
            flush=True,
        )
    med = {k: statistics.median(v) for k, v in ms.items()}
    result = {
        "variant": args.variant,
        "batch": args.batch,
        "threads": args.threads,
        "torch": torch.__version__,
        "machine": platform.processor() or platform.machine(),
        "ms_per_update": ms,
        "median_ms": med,
        "min_ms": {k: min(v) for k, v in ms.items()},
        "speedup_of_medians": med["torchrl"] / med["fused"],
    }
    print(
        f"{args.variant} batch {args.batch}, {args.threads} thread(s): torchrl {med['torchrl']:.2f}"
        f" ms, fused {med['fused']:.2f} ms per update (median of {args.rounds} rounds):"
        f" {result['speedup_of_medians']:.2f}x"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
