"""The single-car learner's command: one config, the algorithm it names.

    python -m sharedspace.train [--config cfg.toml] [--set key=value ...] [--resume CKPT]

``algorithm=sac`` (the default) is the paper's SAC-GCN (:mod:`sharedspace.train.sac`);
``algorithm=ppo`` is PPO on wide batches of envs (:mod:`sharedspace.train.ppo`). ``variant``
names the network either way (``g_sac_cog`` = ``gcn_cog``, ``g_sac_nocog`` = ``gcn_nocog``,
``s_sac`` = ``mlp``). Both write into ``log_dir``: ``config.json``, ``metrics.csv`` (long format:
frames, wall_s, metric, value; metrics namespaced ``train/`` and ``eval/``), TensorBoard events,
and ``checkpoints/{step_<frames>,last}.pt`` (:mod:`sharedspace.train.checkpoint`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from typing import Any

from sharedspace.train.checkpoint import load_checkpoint
from sharedspace.train.config import (
    TrainConfig,
    _read_table,
    add_overrides_argument,
    apply_overrides,
    command_parser,
    load_config,
)
from sharedspace.train.learners import learner

__all__ = ["train", "main"]


def train(cfg: TrainConfig, resume: str | None = None) -> dict[str, Any]:
    """Runs ``cfg.algorithm`` on ``cfg`` (from the checkpoint ``resume`` if given); returns
    the final counters and the last evaluation summary."""
    return learner(cfg.algorithm).train(cfg, resume=resume)


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.train", __doc__)
    ap.add_argument("--config", default=None, help="TOML or JSON file of TrainConfig fields")
    add_overrides_argument(ap, "overrides")
    ap.add_argument("--resume", default=None, help="checkpoint to continue from")
    args = ap.parse_args(argv)
    if args.resume:  # the checkpoint's config, then the file and the overrides over it
        cfg = TrainConfig.from_dict(load_checkpoint(args.resume)["config"])
        if args.config:
            cfg = apply_overrides(cfg, _read_table(args.config))
        cfg = apply_overrides(cfg, args.set)
    else:
        cfg = load_config(args.config, args.set)
    out = train(cfg, resume=args.resume)
    print(json.dumps({k: v for k, v in out.items()}, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
