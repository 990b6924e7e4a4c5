"""In-process batched TorchRL environment over the numpy oracle (``reference.ReferenceWorld``),
for tests only: the package's envs all step the Rust core through ``sim-server``.

:class:`LocalBatchedEnv` steps ``K`` numpy reference worlds (one scenario episode each, the
scenario's ego vehicle driven by the action) in the calling process. It follows the env contract
of ``clients/ENV_CONTRACT.md``, which the remote (Zenoh) env follows as well, so a trainer written
against one runs on the other. It is the "in-process numpy env" baseline: readable and exact, not
fast.

Autoreset follows TorchRL's convention for batched envs with partial resets: the step on which
an episode ends returns that transition (``done`` set, the last observation of the ending
episode); the next call is ``reset`` with a ``"_reset"`` mask ``[K, 1]`` (``Collector`` and
``EnvBase.step_and_maybe_reset`` do this), which starts the next scenario in the masked sub-envs
only. The next world is built eagerly on the step that ends the episode (as the server's
autoreset does), so that its cost counts as step time.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from reference import ReferenceWorld, merge_params
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from sharedspace.pool import load_pool, split_indices
from sharedspace.torchrl_env import (
    NODE_FEATURES,
    blank_step_columns,
    contract_tensordict,
    set_contract_specs,
)

__all__ = ["LocalBatchedEnv", "load_pool", "shipped_params", "split_indices"]

#: The server's shipped default parameters (calibrated on the HBS train split, docs/RESULTS.md).
SHIPPED_PARAMS_PATH = Path(__file__).resolve().parents[2] / "params" / "calibrated.json5"


def shipped_params(pedestrian_model: str) -> dict[str, Any]:
    """The parameters ``sim-server`` uses when given none: ``params/calibrated.json5`` with
    ``pedestrian_model``'s overlay from its ``models`` section applied, as
    sim-server/src/params_file.rs does, so that local and remote envs simulate the same world."""
    import json5

    doc = json5.loads(SHIPPED_PARAMS_PATH.read_text())
    overlay = doc.pop("models", {}).get(pedestrian_model, {})
    return merge_params(doc, overlay)


class LocalBatchedEnv(EnvBase):
    """``K`` reference worlds as one TorchRL env of batch size ``[K]`` (ENV_CONTRACT.md).

    Args:
        num_envs: ``K``.
        max_agents: ``M``, nodes per observation (ego + ``M - 1`` nearest agents).
        split: scenarios drawn from (``"train"``, ``"test"`` or ``"all"``).
        seed: seed of the scenario sequence (sub-env ``k`` draws from ``default_rng([seed, k])``).
        scenario_order: ``"random"`` (uniform draws with replacement) or ``"sequential"``
            (sub-env ``k`` plays the split's scenarios ``k, k + K, k + 2K, ...``, cycling; with
            ``K`` = split size every scenario is played exactly once by the first episodes).
        scenarios: explicit pool indices to use instead of ``split``.
        pool: scenario dicts or the path of a scenario file (default: hbs-paper.json).
        pedestrian_model: ``cr_sfm`` (default), ``ra_sfm``, ``sfm``, ``cv`` or ``replay``.

    Its worlds run the server's shipped parameters (:func:`shipped_params`), on the CPU.
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int = 4,
        max_agents: int = 8,
        split: str | None = "train",
        seed: int = 0,
        scenario_order: str = "random",
        scenarios: Sequence[int] | None = None,
        pool: str | Path | Sequence[Mapping[str, Any]] | None = None,
        pedestrian_model: str = "cr_sfm",
    ):
        if num_envs < 1 or max_agents < 1:
            raise ValueError("num_envs and max_agents must be at least 1")
        if scenario_order not in ("random", "sequential"):
            raise ValueError(f"unknown scenario_order {scenario_order!r}")
        super().__init__(device="cpu", batch_size=torch.Size([num_envs]))
        self.num_envs = k = int(num_envs)
        self.max_agents = m = int(max_agents)
        self.pool = load_pool(pool) if pool is None or isinstance(pool, str | Path) else list(pool)
        self.scenario_ids = (
            [int(i) for i in scenarios]
            if scenarios is not None
            else split_indices(self.pool, split)
        )
        self.split = split
        self.scenario_order = scenario_order
        # The server's shipped defaults, not model.md's starting values.
        self.world_params = shipped_params(pedestrian_model)
        self.pedestrian_model = pedestrian_model
        probe = ReferenceWorld(self.pool[self.scenario_ids[0]], self.world_params, pedestrian_model)
        self.dt = probe.dt
        self.vehicle_params = dict(probe.params["vehicle"])
        #: Cumulative wall time (s) spent inside ``_step`` and ``_reset`` (ENV_CONTRACT.md).
        self.env_time_s = 0.0
        self._seed = 0
        self._rngs: list[np.random.Generator] = []
        self._cursor = [0] * k
        self._worlds: list[ReferenceWorld | None] = [None] * k
        self._pending: list[tuple[int, ReferenceWorld] | None] = [None] * k
        self._scenario = np.zeros(k, dtype=np.int64)
        self._reseed(seed)

        set_contract_specs(self, k, m)

    # ----------------------------------------------------------------------------------------
    # Scenario sequence

    def _reseed(self, seed: int) -> None:
        self._seed = int(seed)
        self._rngs = [
            np.random.default_rng([self._seed & 0xFFFFFFFF, k]) for k in range(self.num_envs)
        ]
        self._cursor = [0] * self.num_envs
        self._pending = [None] * self.num_envs

    def _set_seed(self, seed: int | None) -> None:
        self._reseed(0 if seed is None else seed)

    def _next_world(self, k: int) -> tuple[int, ReferenceWorld]:
        n = len(self.scenario_ids)
        if self.scenario_order == "random":
            pos = int(self._rngs[k].integers(n))
        else:
            pos = (k + self._cursor[k] * self.num_envs) % n
            self._cursor[k] += 1
        idx = self.scenario_ids[pos]
        world = ReferenceWorld(self.pool[idx], self.world_params, self.pedestrian_model)
        return idx, world

    def world(self, k: int) -> ReferenceWorld | None:
        """The world sub-env ``k`` is playing (the finished one until it is reset)."""
        return self._worlds[k]

    # ----------------------------------------------------------------------------------------
    # EnvBase

    def _observe(self, out: dict[str, np.ndarray], k: int) -> None:
        world = self._worlds[k]
        obs = world.observation(int(world.scenario["ego"]), self.max_agents)
        out["features"][k] = obs["features"]
        out["adjacency"][k] = obs["adjacency"]
        out["mask"][k] = obs["mask"]

    def _blank(self) -> dict[str, np.ndarray]:
        k, m = self.num_envs, self.max_agents
        out = blank_step_columns(k)
        out.update(
            features=np.zeros((k, m, NODE_FEATURES), dtype=np.float32),
            adjacency=np.zeros((k, m, m), dtype=np.float32),
            mask=np.zeros((k, m), dtype=bool),
            reward=np.zeros((k, 1), dtype=np.float32),
        )
        return out

    def _to_td(self, out: dict[str, np.ndarray], with_reward: bool) -> TensorDictBase:
        if not with_reward:
            del out["reward"]
        return contract_tensordict(self, out, self._scenario)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        t0 = time.perf_counter()
        reset = None
        if tensordict is not None and "_reset" in tensordict.keys():
            reset = tensordict.get("_reset").reshape(self.num_envs).cpu().numpy()
        out = self._blank()
        for k in range(self.num_envs):
            if reset is None or reset[k] or self._worlds[k] is None:
                pending = self._pending[k]
                self._pending[k] = None
                idx, world = pending if pending is not None else self._next_world(k)
                self._worlds[k] = world
                self._scenario[k] = idx
            self._observe(out, k)
        td = self._to_td(out, with_reward=False)
        self.env_time_s += time.perf_counter() - t0
        return td

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        t0 = time.perf_counter()
        actions = tensordict.get("action").detach().cpu().numpy().astype(np.float64)
        out = self._blank()
        for k in range(self.num_envs):
            world = self._worlds[k]
            if world is None or world.is_over:
                raise RuntimeError(f"sub-env {k} is done: reset it (with `_reset`) before stepping")
            ego = int(world.scenario["ego"])
            a = np.clip(actions[k], -1.0, 1.0)
            res = world.step({ego: (float(a[0]), float(a[1]))})
            outcome = next((o for o in res["agents"] if o["agent"] == ego), None)
            if outcome is not None:
                out["reward"][k, 0] = outcome["total"]
                out["terminated"][k, 0] = outcome["terminated"]
                out["truncated"][k, 0] = outcome["truncated"]
                metrics = outcome["metrics"]
                if metrics is not None:
                    out["episode_" + metrics["status"]][k, 0] = True
                    out["episode_avg_speed"][k, 0] = metrics["avg_speed"]
                    out["episode_avg_abs_jerk"][k, 0] = metrics["avg_abs_jerk"]
                    out["episode_max_abs_acc"][k, 0] = metrics["max_abs_acc"]
            if res["episode_over"] and not (out["terminated"][k, 0] or out["truncated"][k, 0]):
                out["truncated"][k, 0] = True  # the ego left without a flag: end it anyway
            self._observe(out, k)
            if res["episode_over"]:
                self._pending[k] = self._next_world(k)  # eager autoreset, as the server's
        td = self._to_td(out, with_reward=True)
        self.env_time_s += time.perf_counter() - t0
        return td
