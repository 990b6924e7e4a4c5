"""The benchmark: named, frozen tasks, and one evaluation for any policy.

    python -m sharedspace.bench crowd --policy car_aware --out results/bench
    python -m sharedspace.bench crowd --policy runs/x/checkpoints/last.pt --reference \\
        results/bench/crowd/car_aware.json

    from sharedspace.bench import score
    result = score("crowd", lambda obs: [0.0, 0.0])      # any (obs) -> action
    print(result.markdown())

A task (:mod:`.tasks`: ``paper``, ``crowd``, ``crossing``) fixes its scenes, world, variations
and version; a policy (:mod:`.policies`) is a scripted driver's name, a checkpoint, a
function over the PettingZoo observation or a TorchRL module; a result (:mod:`.scoring`) holds
every episode, the outcomes with Wilson intervals and, against a reference result of the same
task version, the paired difference with the scene-resampled interval.
"""

from typing import Any

from sharedspace.bench.tasks import TASKS, BenchError, Task, get_task

#: What playing needs (torch, TorchRL), imported when first asked for: ``import
#: sharedspace.bench`` and the tasks stay free of torch.
_LAZY = {
    "Policy": "sharedspace.bench.policies",
    "make_policy": "sharedspace.bench.policies",
    "Result": "sharedspace.bench.scoring",
    "compare": "sharedspace.bench.scoring",
    "load_result": "sharedspace.bench.scoring",
    "score": "sharedspace.bench.scoring",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sharedspace.bench' has no attribute {name!r}")


__all__ = [
    "TASKS",
    "BenchError",
    "Policy",
    "Result",
    "Task",
    "compare",
    "get_task",
    "load_result",
    "make_policy",
    "score",
]
