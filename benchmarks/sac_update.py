"""SAC update cost, old and new side by side: the trainer's learner as it was at git revision
``--baseline`` (TorchRL's ``SACLoss`` over that revision's networks, stepped as that revision's
trainer stepped it) against today's :class:`sharedspace.train.update.SACUpdate`, on the same
network shapes, batch size and thread count, in interleaved rounds (docs/BENCHMARKS.md,
"Learner").

    .venv/bin/python benchmarks/sac_update.py [--variant gcn_risk] [--batch 256] [--rounds 5]
        [--updates 50] [--threads 1] [--baseline 3dd5f1a] [--json out.json]

The baseline's ``gcn.py`` and ``sac.py`` are read with ``git show`` into a scratch package, so
the "old" column is that code, not today's code with a flag. Each round times ``--updates``
gradient steps of each learner (replay sampling excluded: both get the same pre-sampled
batches) and reports ms per update; the summary is the median and minimum over rounds and the
ratio old / new of the medians.
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data import Bounded

from sharedspace.train.config import TrainConfig
from sharedspace.train.networks import NETWORKS
from sharedspace.train.sac import make_actor, make_update

REPO = Path(__file__).resolve().parents[1]


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


def env_batches(count: int, batch: int, seed: int = 0) -> list[TensorDict]:
    """``count`` replay batches sampled from transitions of the paper pool's train split
    (the trainer's env on a local sim-server, a uniform random policy): real observations,
    whose masks fill 4 of the 8 nodes as the paper's scenes do."""
    from sharedspace.world_config import WorldConfig
    from sharedspace.train.envs import make_env

    env = make_env(WorldConfig(max_agents=8), "train", 16, seed)
    torch.manual_seed(seed)
    data = env.rollout(64, break_when_any_done=False).reshape(-1)
    env.close()
    gen = torch.Generator().manual_seed(seed)
    return [
        data[torch.randint(len(data), (batch,), generator=gen)] for _ in range(count)
    ]


def baseline_modules(rev: str):
    """``(gcn, sac)`` modules of the trainer at git revision ``rev``, importable side by side
    with today's package (their ``sharedspace.train.gcn`` imports point at the copies)."""
    scratch = Path(tempfile.mkdtemp(prefix="sac_baseline_")) / "baseline_train"
    scratch.mkdir()
    (scratch / "__init__.py").write_text("")
    for name in ("gcn", "sac"):
        text = subprocess.run(
            ["git", "show", f"{rev}:clients/src/sharedspace/train/{name}.py"],
            cwd=REPO,
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        text = text.replace(
            "from sharedspace.train.gcn import", "from baseline_train.gcn import"
        )
        (scratch / f"{name}.py").write_text(text)
    sys.path.insert(0, str(scratch.parent))
    return importlib.import_module("baseline_train.gcn"), importlib.import_module(
        "baseline_train.sac"
    )


def baseline_learner(cfg: TrainConfig, rev: str):
    """The old learner: SACLoss + three Adams + SoftUpdate, stepped as the trainer did."""
    _, sac = baseline_modules(rev)
    spec = Bounded(-1.0, 1.0, (2,))
    actor, critic = sac.make_actor(cfg, spec), sac.make_critic(cfg, spec)
    with torch.no_grad():
        critic(actor(fake_batch(2)))
    loss, target_update = sac.make_loss(cfg, actor, critic)
    optimizers = sac.make_optimizers(cfg, loss)

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


def gemm_floor(cfg: TrainConfig, batch: int, dtype: torch.dtype = torch.float32):
    """The dense matrix products of one update of the default G-SAC networks (two critics,
    4 present nodes), alone: a floor under any fp32 implementation of the same algorithm and
    shapes. Forward: actor and target critics on the next observation, critics (twice: the
    replayed and the new action) and actor on the observation; backward: input and weight
    gradients where the update needs them. Returns a step-like callable."""
    h, g, nodes, feats = cfg.algo.hidden_sizes[0], cfg.net.gcn_hidden, 4, 11
    emb = 2 * g  # ego ++ mean readout

    def mat(*shape):
        return torch.randn(*shape, dtype=dtype)

    head_in = mat(batch, emb)
    hidden = mat(batch, h)
    w_in, w_hid, w_out = mat(emb, h), mat(h, h), mat(h, 4)
    gcn_x0, gcn_x1 = mat(batch * nodes, feats), mat(batch * nodes, g)
    w_g0, w_g1 = mat(feats, g), mat(g, g)
    # (products of a forward pass of one network, count in the update)
    fwd = [
        (head_in, w_in),
        (hidden, w_hid),
        (hidden, w_out),
        (gcn_x0, w_g0),
        (gcn_x1, w_g1),
    ]
    # actor next + target x2 + critics x2 + actor = 6 full forwards; the critics' second head
    # pass (2 x [hidden, out]); backward ~2 x forward for critics x2 and actor, 1 x for the
    # critics' second pass (input gradients only).
    plan = [(fwd, 6), (fwd[1:3], 2), (fwd, 6), (fwd[1:3], 2)]

    def step(_batch=None):
        for products, times in plan:
            for _ in range(times):
                for a, b in products:
                    a @ b

    return step


def time_updates(step, batches) -> float:
    t0 = time.perf_counter()
    for b in batches:
        step(b)
    return (time.perf_counter() - t0) * 1e3 / len(batches)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--variant", default="gcn_risk", choices=list(NETWORKS), help="network"
    )
    ap.add_argument("--batch", type=int, default=256, help="replay minibatch size")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds")
    ap.add_argument(
        "--updates", type=int, default=50, help="updates per learner per round"
    )
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument(
        "--baseline", default="3dd5f1a", help="git revision of the old learner"
    )
    ap.add_argument(
        "--data",
        default="env",
        choices=("env", "random"),
        help="env: observations of the paper pool; random: every node present or not at random",
    )
    ap.add_argument("--json", default="", help="write the figures to this file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    cfg = TrainConfig(network=args.variant, batch_size=args.batch)
    learners = {
        "old": baseline_learner(cfg, args.baseline),
        "new": fused_learner(cfg),
        "gemm_floor_fp32": gemm_floor(cfg, args.batch),
        "gemm_floor_bf16": gemm_floor(cfg, args.batch, torch.bfloat16),
    }
    if args.data == "env":
        batches = env_batches(args.updates, args.batch)
    else:
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
        "data": args.data,
        "threads": args.threads,
        "torch": torch.__version__,
        "machine": platform.processor() or platform.machine(),
        "ms_per_update": ms,
        "median_ms": med,
        "min_ms": {k: min(v) for k, v in ms.items()},
        "baseline": args.baseline,
        "speedup_of_medians": med["old"] / med["new"],
    }
    print(
        f"{args.variant} batch {args.batch}, {args.threads} thread(s): old ({args.baseline})"
        f" {med['old']:.2f} ms, new {med['new']:.2f} ms per update (median of {args.rounds} rounds):"
        f" {result['speedup_of_medians']:.2f}x; the update's matrix products alone:"
        f" {med['gemm_floor_fp32']:.2f} ms fp32, {med['gemm_floor_bf16']:.2f} ms bf16"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
