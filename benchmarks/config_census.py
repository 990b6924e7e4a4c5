"""Where a run's config travels: the modules of the package that receive the config or one
of its parts (a ``TrainConfig``, ``WorldConfig``, algorithm config or ``NetworkConfig`` among
a call's arguments, ``self`` included) on its way from the command line to the first
collected batch, in order, and how often it comes back to a module it had left.

Traced with ``sys.setprofile`` over ``python -m sharedspace.train``'s ``main`` (the command
line builds the config, then the one loop makes the world, env, learner and collector), up to
the first batch, twice: following the run config alone, then the run config or any of its
parts. Consecutive calls in one module count once; a *comeback* is an entry into a module the
config had already left. Also counts the lines of ``train/``, ``marl/`` and
``bench/``, and of the reference arms (``arms/``). Run it on an old checkout too
(``PYTHONPATH=OLD/clients/src``) for before and after.

Usage: python benchmarks/config_census.py [--set task=crowd algorithm=ppo network=gcn_risk]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import sharedspace
from sharedspace.train import loop
from sharedspace.train.config import TrainConfig
from sharedspace.train.train import main as train_main

PACKAGE = Path(sharedspace.__file__).parent


def config_classes() -> tuple[type, ...]:
    """The run config and its parts (an old checkout, before the parts: the run config and
    the network config)."""
    classes: list[type] = [TrainConfig]
    for module, name in (
        ("sharedspace.world_config", "WorldConfig"),
        ("sharedspace.train.algorithm_configs", "AlgorithmConfig"),
        ("sharedspace.train.networks", "NetworkConfig"),
    ):
        try:
            classes.append(getattr(__import__(module, fromlist=[name]), name))
        except (ImportError, AttributeError):
            pass
    return tuple(classes)


class FirstBatch(Exception):
    """Raised when the loop has its first batch: the trace ends there."""


def trace(words: list[str], parts: bool = False) -> list[str]:
    """The modules (package-relative) that received the run config (with ``parts``: or one of
    its parts), in order, consecutive repeats merged."""
    seen: list[str] = []
    configs = config_classes() if parts else (TrainConfig,)

    def profile(frame, event, arg):
        if event != "call":
            return
        path = frame.f_code.co_filename
        if not path.startswith(str(PACKAGE)):
            return
        code = frame.f_code
        names = code.co_varnames[: code.co_argcount + code.co_kwonlyargcount]
        if any(isinstance(frame.f_locals.get(n), configs) for n in names):
            module = str(Path(path).relative_to(PACKAGE)).removesuffix(".py")
            if not seen or seen[-1] != module:
                seen.append(module)

    def first_batch(self):
        raise FirstBatch

    loop.Clock.collected = first_batch
    sys.setprofile(profile)
    try:
        train_main(["--set", *words])
    except FirstBatch:
        pass
    finally:
        sys.setprofile(None)
    return seen


def comebacks(sequence: list[str]) -> int:
    """Entries into a module already left before."""
    left, count = set(), 0
    for before, module in zip(sequence, sequence[1:], strict=False):
        left.add(before)
        count += module in left
    return count


def lines(*folders: str) -> dict[str, int]:
    return {
        f: sum(len(p.read_text().splitlines()) for p in (PACKAGE / f).rglob("*.py"))
        for f in folders
        if (PACKAGE / f).is_dir()
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", nargs="*", default=["task=crowd", "algorithm=ppo", "network=gcn_risk"])
    args = ap.parse_args()
    out = {"lines": lines("train", "marl", "bench", "arms")}
    for name, parts in (("config", False), ("config_or_part", True)):
        with tempfile.TemporaryDirectory() as tmp:
            words = [*args.set, "progress=false", "eval_interval=0", f"log_dir={tmp}"]
            sequence = trace(words, parts)
        out[name] = {
            "modules": sorted(set(sequence)),
            "sequence": sequence,
            "comebacks": comebacks(sequence),
        }
        print(f"{name}: " + " -> ".join(sequence))
        print(f"  {len(set(sequence))} modules, {comebacks(sequence)} comebacks")
    print(f"lines {out['lines']}")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
