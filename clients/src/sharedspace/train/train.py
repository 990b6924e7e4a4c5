"""Every learner's command: one config, the algorithm it names, for one car or several.

    python -m sharedspace.train [--config cfg.toml] [--set key=value ...] [--resume [CKPT]]

One config (:class:`~sharedspace.train.config.TrainConfig`: the run's fields, its world, the
algorithm's options with the algorithm's own defaults, its network) for every learner, built
once from the flat ``--set`` keys. ``algorithm`` names a registered algorithm
(:mod:`sharedspace.train.registry`): ``sac`` (the default, the paper's SAC-GCN) and ``ppo``
drive one car per env; ``mappo``, ``ippo`` and ``masac`` drive the crossing task's cars.
``network`` names a registered network (``gcn_risk``, ``gcn_uniform``, ``mlp``; the old names
``g_sac_cog``, ``g_sac_nocog``, ``s_sac`` still work). ``task=paper`` (or ``crowd``) trains
in a benchmark task's world, and ``python -m sharedspace.bench TASK --policy
LOG_DIR/checkpoints/last.pt`` scores the result.

Every run writes into ``log_dir``: ``config.json``, ``metrics.csv`` (long format: frames,
wall_s, metric, value; ``train/`` per iteration, ``eval/`` on the validation split),
TensorBoard events, and ``checkpoints/{step_<frames>,last}.pt``
(:mod:`sharedspace.train.checkpoint`); a multi-car run also ``eval.json`` and ``policy.pt``
(:mod:`sharedspace.marl.train`).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from typing import Any

from sharedspace.cli import run_command
from sharedspace.train.config import (
    TrainConfig,
    add_overrides_argument,
    command_parser,
    load_config,
)

__all__ = ["train", "main"]


def train(cfg: TrainConfig, resume: str | None = None) -> dict[str, Any]:
    """Runs ``cfg.algorithm`` on ``cfg`` (from the checkpoint ``resume`` if given) through the
    one training loop (:mod:`sharedspace.train.loop`); returns the final counters, the last
    scoring and where the time went."""
    from sharedspace.train import loop  # torch: imported once there is a run (not for --help)

    return loop.train(cfg, resume)


def main(argv: Sequence[str] | None = None, default_algorithm: str = "") -> int:
    from sharedspace.train.reference import help_text

    ap = command_parser("python -m sharedspace.train", __doc__)
    ap.epilog = help_text(_named_algorithm(argv, default_algorithm))
    ap.add_argument("--config", default=None, help="TOML or JSON file of config fields")
    add_overrides_argument(ap, "config overrides: KEY=VALUE (every key is listed below)")
    ap.add_argument(
        "--resume",
        nargs="?",
        const=True,
        default=None,
        metavar="CKPT",
        help="continue from this checkpoint (its config, then --config and --set over it); "
        "bare: from log_dir's last checkpoint, if there is one",
    )
    args = ap.parse_args(argv)
    from sharedspace.train.checkpoint import last_checkpoint, read_checkpoint  # torch

    saved = read_checkpoint(args.resume) if isinstance(args.resume, str) else None
    cfg = load_config(
        args.config,
        args.set,
        saved=saved["config"] if saved is not None else None,
        default_algorithm=default_algorithm,
    )
    resume = args.resume
    if resume is True:  # bare: log_dir's last checkpoint, where there is one
        resume = last_checkpoint(cfg.log_dir)
    out = dict(train(cfg, resume)) | {"log_dir": cfg.log_dir, "eval_split": cfg.world.eval_split}
    print(summary_line(out), flush=True)
    print(json.dumps(out, default=float))
    return 0


def _named_algorithm(argv: Sequence[str] | None, default: str) -> str:
    """The algorithm a command line names (``algorithm=NAME`` among its words), for its
    ``--help`` alone: the config itself is built once, by :func:`load_config`."""
    words = sys.argv[1:] if argv is None else argv
    named = [w.split("=", 1)[1] for w in words if w.startswith("algorithm=")]
    return named[-1] if named else default


def summary_line(out: dict[str, Any]) -> str:
    """What a finished run says to a person: where it wrote, and its last scoring's split."""
    line = f"run written to {out['log_dir']} (config.json, metrics.csv, checkpoints/last.pt)"
    scoring = out.get("eval") or {}
    if "success" in scoring:
        rates = ", ".join(f"{k} {scoring[k]:.3f}" for k in ("success", "collision", "timeout"))
        split = out["eval_split"]
        if split == "validation":
            split += " (train scenes carved off, never trained on)"
        line += f"; last scoring on the {split} split: {rates}"
    return line


if __name__ == "__main__":
    sys.exit(run_command(main))
