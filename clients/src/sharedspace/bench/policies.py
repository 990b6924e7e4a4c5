"""Any policy, as the benchmark plays it: one NumPy ``act(obs) -> actions`` over a batch of
observations ``{"features" [*, M, F], "adjacency" [*, M, M], "mask" [*, M]}`` (``*`` is ``K``
for one car per env, ``K, A`` for the crossing task's cars), giving ``[*, 2]``.

A policy spec is one of:

- a scripted driver's name (:data:`sharedspace.scripted.SCRIPTED`: ``car_aware``,
  ``pursuit_3``, ...), the one registry of drivers;
- a checkpoint file (``.pt``) written by ``python -m sharedspace.train`` (SAC, PPO) or
  ``python -m sharedspace.marl`` (MAPPO, IPPO, MASAC), residual learners with their script;
  its recorded world must be the task's;
- ``module:function``, an importable callable;
- a callable ``(obs) -> action`` over one agent's PettingZoo observation (a dict of numpy
  arrays ``features [M, 11]``, ``adjacency [M, M]``, ``mask [M]``) returning ``[2]`` in
  ``[-1, 1]``;
- a TorchRL module (a ``TensorDictModuleBase``) that reads the env's tensordict and writes
  ``action`` (``("vehicle", "action")`` on the crossing task); played deterministically.

Only a checkpoint or a module loads torch: a scripted driver or a function is played with NumPy
alone. Only a checkpoint builds a learner's network (:mod:`sharedspace.train.learners`,
:mod:`sharedspace.marl.networks`).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sharedspace.bench.tasks import REPO, BenchError, Task, scenes_fingerprint, test_scenes
from sharedspace.cli import did_you_mean
from sharedspace.pool import DEFAULT_POOL_PATH
from sharedspace.scripted import SCRIPTED

__all__ = ["Policy", "make_policy"]

#: The crossing task's agent group (TorchRL's multi-agent layout).
GROUP = "vehicle"


@dataclass
class Policy:
    """A policy the benchmark can play: ``act(obs)`` gives the actions of a batch (see the
    module's doc); ``name`` and ``source`` say what it is in a result."""

    name: str
    source: dict[str, Any]
    act: Callable[[dict[str, np.ndarray]], np.ndarray]


def make_policy(spec: Any, task: Task, name: str = "") -> Policy:
    """The :class:`Policy` of ``spec`` (see the module's doc) for ``task``; a
    :class:`~sharedspace.bench.tasks.BenchError` for a spec it cannot play."""
    if isinstance(spec, str | Path):
        text = str(spec)
        if text in SCRIPTED:
            return _scripted(text, name)
        if text.endswith(".pt") or Path(text).is_file():
            return _checkpoint(Path(text), task, name)
        if ":" in text:
            return _imported(text, task, name)
        raise BenchError(
            f"policy {text!r}: not a scripted driver ({', '.join(sorted(SCRIPTED))}), "
            f"a checkpoint file (.pt) or module:function{did_you_mean(text, SCRIPTED)}"
        )
    if _is_module(spec):
        act = _module_act(spec, task)
        return Policy(name or type(spec).__name__, {"kind": "module"}, act)
    if callable(spec):
        label = getattr(spec, "__qualname__", type(spec).__name__)
        return Policy(name or label, {"kind": "function", "function": label}, _function_act(spec))
    raise BenchError(f"policy {spec!r}: give a driver name, a checkpoint, a callable or a module")


def _scripted(driver: str, name: str) -> Policy:
    script = SCRIPTED[driver]()

    def act(obs: dict[str, np.ndarray]) -> np.ndarray:
        return script(obs["features"], obs["mask"])

    return Policy(name or driver, {"kind": "driver", "driver": driver}, act)


def _function_act(fn: Callable[[dict[str, np.ndarray]], Any]) -> Callable:
    """Calls ``fn`` on each agent's observation, as a PettingZoo env hands it over."""

    def act(obs: dict[str, np.ndarray]) -> np.ndarray:
        features, adjacency, mask = obs["features"], obs["adjacency"], obs["mask"]
        lead = features.shape[:-2]
        f = features.reshape(-1, *features.shape[-2:])
        a = adjacency.reshape(-1, *adjacency.shape[-2:])
        m = mask.reshape(-1, mask.shape[-1]).astype(np.int8)
        out = np.empty((len(f), 2), dtype=np.float32)
        for i in range(len(f)):
            action = np.asarray(fn({"features": f[i], "adjacency": a[i], "mask": m[i]}))
            if action.shape != (2,):
                raise BenchError(
                    f"the policy returned an action of shape {action.shape}: "
                    "one action is [acceleration, yaw rate], shape (2,), in [-1, 1]"
                )
            out[i] = action
        return out.reshape(*lead, 2)

    return act


def _is_module(spec: Any) -> bool:
    """Whether ``spec`` is a TensorDict module (only a caller holding one has tensordict
    loaded, so no other spec imports it)."""
    if "tensordict" not in sys.modules:
        return False
    from tensordict.nn import TensorDictModuleBase

    return isinstance(spec, TensorDictModuleBase)


def as_tensordict(obs: dict[str, np.ndarray], crossing: bool):
    """A batch of NumPy observations as the env's tensordict: the three observation keys, under
    the group ``vehicle`` with batch ``[K, A]`` for the crossing task, else at the root."""
    import torch
    from tensordict import TensorDict

    # a copy: the replies' arrays are read-only views
    data = {k: torch.from_numpy(np.array(v)) for k, v in obs.items()}
    data["mask"] = data["mask"].bool()
    batch = list(obs["features"].shape[:-2])
    if crossing:
        return TensorDict({GROUP: TensorDict(data, batch_size=batch)}, batch_size=batch[:1])
    return TensorDict(data, batch_size=batch)


def _td_act(act_td: Callable, crossing: bool) -> Callable:
    """A tensordict policy ``act_td(td) -> actions`` as a NumPy one."""

    def act(obs: dict[str, np.ndarray]) -> np.ndarray:
        return act_td(as_tensordict(obs, crossing)).detach().cpu().numpy()

    return act


def _module_act(module: Any, task: Task) -> Callable:
    """A TorchRL module's deterministic action (what it writes at ``action``, or at
    ``("vehicle", "action")`` on the crossing task), as a NumPy policy."""
    crossing = task.crossing is not None
    return _td_act(_module_td_act(module, (GROUP, "action") if crossing else "action"), crossing)


def _module_td_act(module: Any, key: str | tuple[str, str]) -> Callable:
    """A TorchRL module's deterministic action, what it writes at ``key``, of a tensordict."""
    import torch
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    def act_td(td):
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            out = module(td.clone(False))
        if key not in out.keys(include_nested=True):
            raise BenchError(f"the module wrote no {key!r} into the tensordict")
        return out.get(key)

    return act_td


def _imported(target: str, task: Task, name: str) -> Policy:
    module_name, _, attr = target.partition(":")
    try:
        obj = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as err:
        raise BenchError(f"policy {target!r}: cannot import it ({err})") from err
    policy = make_policy(obj, task, name or target)
    policy.source = {**policy.source, "import": target}
    return policy


def _checkpoint(path: Path, task: Task, name: str) -> Policy:
    from sharedspace.train.checkpoint import NotACheckpoint, read_checkpoint
    from sharedspace.train.registry import UnknownAlgorithm, get_algorithm

    try:
        ckpt = read_checkpoint(path)
    except NotACheckpoint as err:
        raise BenchError(f"policy {err}") from None
    algorithm = ckpt["algorithm"]
    try:
        algo = get_algorithm(algorithm)
    except UnknownAlgorithm as err:
        raise BenchError(f"policy {path}: {err} (register it before scoring)") from None
    # several cars: an algorithm of several only, or one of any whose world is the crossing task
    multi_car = algo.multi_car or isinstance(ckpt["world"].get("task"), dict)
    source = {"kind": "checkpoint", "path": str(path), "algorithm": algorithm}
    source["network"] = ckpt["network"]
    if multi_car:
        if task.crossing is None:
            raise BenchError(
                f"policy {path}: a multi-car checkpoint ({algorithm}), task {task.tag} has one car"
            )
        return Policy(name or _run_name(path), source, _td_act(_marl_act(ckpt, task, path), True))
    if task.crossing is not None:
        raise BenchError(
            f"policy {path}: a single-car checkpoint ({algorithm}); task {task.tag} has "
            f"{task.cars} cars"
        )
    mismatches = world_mismatches(ckpt["world"], ckpt["config"], task)
    if mismatches:
        raise BenchError(
            f"policy {path}: trained in another world than task {task.tag}: "
            + "; ".join(mismatches)
        )
    return Policy(name or _run_name(path), source, _single_car_act(ckpt))


def _run_name(path: Path) -> str:
    """``runs/NAME/checkpoints/last.pt`` or ``runs/NAME/policy.pt`` -> NAME; else the stem."""
    if path.parent.name == "checkpoints":
        return path.parent.parent.name
    return path.parent.name if path.stem == "policy" else path.stem


def world_mismatches(world: dict[str, Any], config: dict[str, Any], task: Task) -> list[str]:
    """How a single-car checkpoint's recorded world differs from ``task``'s: ``max_agents``,
    the pedestrian model, the world parameters (by content where the file is at hand) and the
    pool (its test scenes, where the file is at hand). Checkpoints older than the ``world``
    record (the shipped Table II policies) name no parameters file: those are not checked."""
    get = lambda key: world.get(key, config.get(key))  # noqa: E731 - older checkpoints: config
    out = []
    if int(get("max_agents") or 0) != task.max_agents:
        out.append(f"max_agents {get('max_agents')}, the task's {task.max_agents}")
    if (get("pedestrian_model") or "cr_sfm") != task.pedestrian_model:
        out.append(
            f"pedestrian model {get('pedestrian_model')}, the task's {task.pedestrian_model}"
        )
    params = str(get("server_params") or "")
    if params:
        found = _read_params(params)
        if found is not None and found != task.world_params:
            out.append(f"world parameters of {params} differ from the task's")
    elif task.world_params and world:  # a checkpoint recording no world is taken at its word
        out.append("the server's default world parameters, not the task's")
    pool = str(get("scenario_pool") or "")
    if not pool:
        pool_file = DEFAULT_POOL_PATH  # the server's embedded pool, as a file
    else:
        pool_file = Path(pool) if Path(pool).is_absolute() else REPO / pool
    if pool_file.is_file() and scenes_fingerprint(test_scenes(pool_file)) != task.scenes_sha256:
        out.append(f"pool {pool or 'default'}, whose test scenes are not the task's")
    return out


def _read_params(path: str) -> dict[str, Any] | None:
    """A world parameters file (JSON5), or None where it is not at hand."""
    import json5

    file = Path(path) if Path(path).is_absolute() else REPO / path
    return json5.loads(file.read_text()) if file.is_file() else None


def _single_car_act(ckpt: dict[str, Any]) -> Callable:
    """A single-car checkpoint's deterministic action (its actor built with no server); a
    residual learner's goes through the one residual transform
    (:class:`~sharedspace.train.envs.ResidualAction`) as in training."""
    from sharedspace.train.envs import ResidualAction
    from sharedspace.train.learners import load_checkpoint_actor

    cfg, actor = load_checkpoint_actor(ckpt)
    act = _module_td_act(actor, "action")
    if not cfg.algo.base_driver:
        return _td_act(act, False)
    residual = ResidualAction(cfg.algo.base_driver, scale=cfg.algo.residual_scale)
    return _td_act(
        lambda td: residual._inv_call(td.clone(False).set("action", act(td))).get("action"), False
    )


def _marl_act(ckpt: dict[str, Any], task: Task, path: Path) -> Callable:
    """A multi-car checkpoint's cars, as the multi-car trainer evaluates them
    (:func:`sharedspace.marl.evaluate.policy_act`)."""
    from sharedspace.marl.evaluate import policy_act
    from sharedspace.marl.networks import make_actor
    from sharedspace.train.config import TrainConfig

    recorded = (ckpt.get("world") or {}).get("task")
    mine = dict(vars(task.crossing))
    if recorded is not None and recorded != mine:
        differing = sorted(k for k in mine if recorded.get(k) != mine[k])
        raise BenchError(
            f"policy {path}: trained on another crossing task (differs in {', '.join(differing)})"
        )
    cfg = TrainConfig.from_dict(ckpt["config"] | {"device": "cpu"})
    actor = make_actor(cfg, task.crossing)
    actor.load_state_dict(ckpt["actor"])
    act = policy_act(actor, cfg.algo.base_driver, cfg.algo.residual_scale)
    return lambda td: act(td, 0)
