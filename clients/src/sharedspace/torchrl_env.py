"""Batched TorchRL env over the sharedspace server (clients/ENV_CONTRACT.md).

:class:`RemoteBatchedEnv` follows the env contract (ENV_CONTRACT.md; the test suite holds it to
an in-process numpy twin, ``clients/tests/local_env.py``): keys and specs of
:func:`set_contract_specs`, batch size ``[K]``. Its K sub-envs are created by one ``CreateEnv``
on the least-loaded server and stepped with one ``BatchStep`` per step.

Scenario order:

- ``"random"``: the envs are created with the server's **autoreset**; sub-env ``k`` is seeded
  with ``seed + k`` and runs through the server's seeded permutations of the split (SPEC 5.2,
  "Scenario sequence": without replacement inside a permutation, unlike the local env's draws
  with replacement; the same seed gives the same sequence). The step that ends an episode
  carries the next episode's ``ResetResult``, so the partial ``_reset`` that follows needs no
  round trip.
- ``"sequential"``: sub-env ``k`` plays the split's scenarios (pool order) ``k, k+K, ...``:
  created without autoreset, and each reset names its scenario (one ``Reset`` query per reset
  sub-env, all in flight at once).

The envs are one :class:`~sharedspace.wire.EnvSpec` (``split`` ``train`` or ``test``: a server
env draws from one split); world parameters are a server setting (``sim-server --cfg params:``),
not a per-env one.

Failover (``failover=True``): when the server dies, the step returns every sub-env
``truncated`` (reward 0, observation = the last one received) and the envs are re-created on a
surviving server; the following partial ``_reset`` starts their first episodes (see
:mod:`sharedspace.client`). :attr:`RemoteBatchedEnv.failovers` counts them.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from . import names
from .client import Connection, EnvOptions, SimClient, env_options
from .pool import listed_scenarios, synthetic_names
from .vector import VectorClient
from .wire.errors import SharedspaceError
from .wire.requests import EnvSpec

__all__ = [
    "EPISODE_FLAG_KEYS",
    "EPISODE_FLOAT_KEYS",
    "NODE_FEATURES",
    "RemoteBatchedEnv",
    "blank_step_columns",
    "contract_tensordict",
    "reset_mask",
    "set_contract_specs",
]

NODE_FEATURES = names.NODE_FEATURES
EPISODE_FLAG_KEYS = ("episode_success", "episode_collision", "episode_timeout")
EPISODE_FLOAT_KEYS = ("episode_avg_speed", "episode_avg_abs_jerk", "episode_max_abs_acc")


def set_contract_specs(env: EnvBase, k: int, m: int) -> None:
    """Sets the specs of clients/ENV_CONTRACT.md on ``env`` (batch size ``[k]``, ``m`` nodes):
    the one definition every batched env uses."""
    dev = env.device
    bool_spec = Categorical(2, shape=(k, 1), dtype=torch.bool, device=dev)
    obs = {
        "features": Unbounded((k, m, NODE_FEATURES), dtype=torch.float32, device=dev),
        "adjacency": Unbounded((k, m, m), dtype=torch.float32, device=dev),
        "mask": Binary(n=m, shape=(k, m), dtype=torch.bool, device=dev),
        "scenario_index": Unbounded((k, 1), dtype=torch.int64, device=dev),
    }
    for key in EPISODE_FLAG_KEYS:
        obs[key] = bool_spec.clone()
    for key in EPISODE_FLOAT_KEYS:
        obs[key] = Unbounded((k, 1), dtype=torch.float32, device=dev)
    env.observation_spec = Composite(obs, shape=(k,), device=dev)
    env.action_spec = Bounded(-1.0, 1.0, (k, 2), dtype=torch.float32, device=dev)
    env.reward_spec = Unbounded((k, 1), dtype=torch.float32, device=dev)
    env.done_spec = Composite(
        done=bool_spec.clone(),
        terminated=bool_spec.clone(),
        truncated=bool_spec.clone(),
        shape=(k,),
        device=dev,
    )


def reset_mask(tensordict: TensorDictBase | None, k: int) -> np.ndarray | None:
    """The ``_reset`` mask of a partial reset of ``k`` sub-envs (None: a full reset)."""
    if tensordict is None or "_reset" not in tensordict.keys():
        return None
    return tensordict.get("_reset").reshape(k).cpu().numpy().astype(bool)


def blank_step_columns(k: int) -> dict[str, np.ndarray]:
    """The ``[k, 1]`` columns of a contract step, zeroed: ``terminated``, ``truncated`` and the
    episode keys (what a step fills in for the sub-envs whose episode ends)."""
    out = {key: np.zeros((k, 1), dtype=bool) for key in ("terminated", "truncated")}
    out.update({key: np.zeros((k, 1), dtype=bool) for key in EPISODE_FLAG_KEYS})
    out.update({key: np.zeros((k, 1), dtype=np.float32) for key in EPISODE_FLOAT_KEYS})
    return out


def contract_tensordict(
    env: EnvBase, out: dict[str, np.ndarray], scenario_index: np.ndarray
) -> TensorDictBase:
    """A contract step's columns ``out`` as ``env``'s TensorDict, with ``done`` (terminated or
    truncated) and each sub-env's ``scenario_index`` added."""
    out["done"] = out["terminated"] | out["truncated"]
    out["scenario_index"] = scenario_index.reshape(-1, 1).copy()
    return TensorDict(
        {key: torch.from_numpy(v) for key, v in out.items()},
        batch_size=env.batch_size,
        device=env.device,
    )


class _ServerEnvs(EnvBase):
    """What both remote envs share: K server envs behind one ``VectorClient`` (``self.vec``),
    and copies (pickle, deepcopy) that make their own connection and server envs."""

    def _connect(self, num_envs: int, opts: EnvOptions, **decided: Any) -> EnvSpec:
        """Creates the K server envs of ``opts`` (the constructor's sorted options,
        :func:`~sharedspace.client.env_options`) with what the adapter ``decided`` over its spec,
        keeps what a copy needs (``_init_args``, see ``__reduce__``) and returns the envs' spec."""
        spec, where, failover = opts
        shared = isinstance(where, SimClient)
        self._init_args = {
            "spec": spec,
            "client": Connection.of_client(where, failover) if shared else where,
        }
        self.vec = VectorClient(num_envs, spec.replace(**decided), client=where, failover=failover)
        return self.vec.spec

    def __reduce__(self):
        """Pickling and copying make a new env from the constructor's arguments: its own
        connection and its own K server envs, seeded like this one at creation."""
        return (_rebuild, (self.__class__, self._init_kwargs | self._init_args))

    def close(self, *, raise_if_closed: bool = True) -> None:
        try:
            self.vec.close()
        except SharedspaceError:
            pass
        try:
            super().close(raise_if_closed=raise_if_closed)
        except TypeError:  # older signature
            super().close()


class RemoteBatchedEnv(_ServerEnvs):
    """K server envs as one TorchRL env of batch size ``[K]`` (ENV_CONTRACT.md).

    Args:
        spec: the envs (:class:`~sharedspace.wire.EnvSpec`: pool, split, seed, crowd model,
            ``max_agents`` M, variations, ...; one external agent); ``**options`` naming its
            fields (``max_agents=6``) or :class:`~sharedspace.client.Connection` fields
            (``endpoint``, ``prefix``, ``timeout``, ``failover``) apply over it and ``client``.
            ``pool`` may also be the path of the scenario file the server serves (or its
            scenario dicts), whose ``name`` selects the pool; the pool's order gives
            ``scenario_index``.
        num_envs: K.
        scenario_order: ``random`` (the server's seeded permutations, autoreset) or
            ``sequential`` (sub-env ``k`` plays the split's scenarios ``k, k+K, ...``).
        scenarios: scenario names (or pool indices) to play instead of drawing from the
            split: sub-env ``k`` plays ``scenarios[k], [k + K], ...`` cycling (each must be
            in the split).
        variation_seeds: per sub-env, the variation seed every episode of that sub-env plays
            (``Reset.variation``; needs ``variations``): a fixed, replayable set of variations,
            as the evaluator uses. None: each episode draws its own.
        client: a :class:`~sharedspace.client.SimClient` to share, or the ``Connection`` to
            open (default: ``tcp/127.0.0.1:7447``).
        device: the device of the env's tensors.

    ``last_variation_seeds`` (K ints, None without variations; seeds are unsigned 64-bit) is
    each sub-env's current episode's variation seed: a side channel, like
    ``last_reward_terms``.
    """

    batch_locked = True

    def __init__(
        self,
        spec: EnvSpec | None = None,
        num_envs: int = 4,
        *,
        scenario_order: str = "random",
        scenarios: str | Sequence[str | int] | None = None,
        variation_seeds: Sequence[int] | None = None,
        client: SimClient | Connection | None = None,
        device: str | torch.device = "cpu",
        **options: Any,
    ):
        if num_envs < 1:
            raise ValueError("num_envs must be at least 1")
        if scenario_order not in ("random", "sequential"):
            raise ValueError(f"unknown scenario_order {scenario_order!r}")
        if isinstance(scenarios, str):
            scenarios = [scenarios]
        if scenarios is not None:
            if not scenarios:
                raise ValueError("scenarios: an empty list")
            scenario_order = "sequential"  # sub-env k plays scenarios[k], [k + K], ...
        self._init_kwargs = dict(
            num_envs=num_envs,
            scenario_order=scenario_order,
            scenarios=scenarios,
            variation_seeds=variation_seeds,
            device=device,
        )
        opts = env_options(options, spec, client)
        spec_pool, pool_name, pool_list = _pool_of(opts.spec)
        spec = opts.spec.replace(pool=spec_pool)
        if len(spec.external_agents) != 1:
            raise ValueError("RemoteBatchedEnv drives one external agent per sub-env")
        self._variation_seeds = _checked_variation_seeds(variation_seeds, spec, num_envs)
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        spec = self._connect(
            num_envs,
            opts._replace(spec=spec),
            # Fixed variation seeds are sent with each reset, so their sub-envs reset by request.
            autoreset=scenario_order == "random" and variation_seeds is None,
        )
        self.num_envs, self.max_agents = int(num_envs), spec.max_agents
        self.split, self.scenario_order = spec.split, scenario_order
        self.pedestrian_model = spec.pedestrian_model
        self._take_pool(pool_name, pool_list, scenarios)
        self._init_state()
        set_contract_specs(self, self.num_envs, self.max_agents)

    def _take_pool(
        self,
        pool_name: str | None,
        pool_list: list[tuple[str, str]] | None,
        scenarios: Sequence[str | int] | None,
    ) -> None:
        """The pool's scenarios in pool order (asked of the server when the caller holds no
        list) and the split's names this env plays; closes the envs on a wrong choice."""
        self.pool_name = pool_name
        if pool_list is None:  # a pool the server names: it lists the scenarios
            self.pool_name, pool_list = self.vec.client.scenarios(pool_name, self.vec.server_id)
        self._scenario_index = {name: i for i, (name, _) in enumerate(pool_list)}
        self._split_names = [name for name, s in pool_list if s == self.split]
        if scenarios is not None:
            names = [pool_list[i][0] if isinstance(i, int) else str(i) for i in scenarios]
            wrong = [n for n in names if n not in self._split_names]
            if wrong:
                self.vec.close()
                raise ValueError(
                    f"scenarios {wrong} are not {self.split} scenarios of pool {self.pool_name!r}"
                )
            self._split_names = names
        if self.scenario_order == "sequential" and not self._split_names:
            self.vec.close()
            raise ValueError(f"scenario_order='sequential': no {self.split} scenarios in the pool")

    def _init_state(self) -> None:
        """The per-sub-env state before the first reset, and what ``CreateEnv`` answered."""
        k, m = self.num_envs, self.max_agents
        action = self.vec.created["action"]
        self.dt = float(self.vec.created["dt"])
        self.vehicle_params = {
            "acc_max": float(action["physical_high"][0]),
            "omega_max": float(action["physical_high"][1]),
        }
        self.env_time_s = 0.0
        #: Each reward term of the last step, ``{term: [K]}`` (weighted, model.md 7; ``reward``
        #: is their sum): a side channel for analyses, not part of the specs.
        self.last_reward_terms: dict[str, np.ndarray] = {}
        self.last_variation_seeds: list[int | None] = [None] * k
        self._seed = self.vec.spec.seed
        self._reseed_pending = False
        self._cursor = [0] * k
        self._pending: list[dict[str, Any] | None] = [None] * k
        self._done = np.ones(k, dtype=bool)  # every sub-env needs a reset first
        self._scenario = np.full(k, -1, dtype=np.int64)
        self._obs = {
            "features": np.zeros((k, m, NODE_FEATURES), dtype=np.float32),
            "adjacency": np.zeros((k, m, m), dtype=np.float32),
            "mask": np.zeros((k, m), dtype=bool),
        }

    # ----------------------------------------------------------------------------------------

    @property
    def env_ids(self) -> list[str]:
        return list(self.vec.env_ids)

    @property
    def scenario_names(self) -> list[str]:
        """The pool's scenario names in pool order: ``scenario_index`` indexes this list."""
        return sorted(self._scenario_index, key=self._scenario_index.__getitem__)

    @property
    def server_id(self) -> str:
        return self.vec.server_id

    @property
    def failovers(self) -> int:
        return self.vec.failovers

    def _set_seed(self, seed: int | None) -> None:
        self._seed = 0 if seed is None else int(seed)
        self._reseed_pending = True
        self._pending = [None] * self.num_envs
        self._cursor = [0] * self.num_envs

    def _index_of(self, scenario: str) -> int:
        return self._scenario_index.get(scenario, -1)

    def _take_reset(self, k: int, result: Mapping[str, Any]) -> None:
        obs = result["obs"]
        self._obs["features"][k] = obs["features"][0]
        self._obs["adjacency"][k] = obs["adjacency"][0]
        self._obs["mask"][k] = obs["mask"][0].astype(bool)
        self._scenario[k] = self._index_of(result["scenario"])
        self._done[k] = False
        variation = result.get("variation")
        if isinstance(variation, Mapping):
            variation = variation.get("seed")
        self.last_variation_seeds[k] = None if variation is None else int(variation)

    def _to_td(self, out: dict[str, np.ndarray]) -> TensorDictBase:
        out["features"] = self._obs["features"].copy()
        out["adjacency"] = self._obs["adjacency"].copy()
        out["mask"] = self._obs["mask"].copy()
        return contract_tensordict(self, out, self._scenario)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        t0 = time.perf_counter()
        mask = reset_mask(tensordict, self.num_envs)
        todo = [k for k in range(self.num_envs) if mask is None or mask[k] or self._done[k]]
        queries: list[int] = []
        for k in todo:
            pending = self._pending[k]
            self._pending[k] = None
            if pending is not None and mask is not None:
                self._take_reset(k, pending)
            else:
                queries.append(k)
        if queries:
            seeds = scen = None
            if self._reseed_pending:
                seeds = [self._seed + k for k in queries]
            if self.scenario_order == "sequential":
                n = len(self._split_names)
                scen = []
                for k in queries:
                    scen.append(self._split_names[(k + self._cursor[k] * self.num_envs) % n])
                    self._cursor[k] += 1
            ids = self.vec.env_ids
            fixed = self._variation_seeds
            results = self.vec.client.reset_many(
                [ids[k] for k in queries],
                seeds=seeds,
                scenarios=scen,
                variations=None if fixed is None else [fixed[k] for k in queries],
            )
            for k, r in zip(queries, results, strict=True):
                self._take_reset(k, r)
            if self._reseed_pending and len(queries) == self.num_envs:
                self._reseed_pending = False
        td = self._to_td(blank_step_columns(self.num_envs))
        self.env_time_s += time.perf_counter() - t0
        return td

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        t0 = time.perf_counter()
        if self._done.any():
            k = int(np.flatnonzero(self._done)[0])
            raise RuntimeError(f"sub-env {k} is done: reset it (with `_reset`) before stepping")
        actions = tensordict.get("action").detach().cpu().numpy().astype(np.float32, copy=False)
        actions = np.clip(actions, -1.0, 1.0).reshape(self.num_envs, 1, 2)
        res = self.vec.step(actions)
        out = blank_step_columns(self.num_envs)
        obs = res["obs"]
        self._obs["features"][:] = obs["features"][:, 0]
        self._obs["adjacency"][:] = obs["adjacency"][:, 0]
        self._obs["mask"][:] = obs["mask"][:, 0]
        out["reward"] = np.array(res["reward"], dtype=np.float32).reshape(-1, 1)
        self.last_reward_terms = {
            term: np.array(v, dtype=np.float64).reshape(-1)
            for term, v in res.get("reward_terms", {}).items()
        }
        out["terminated"] = res["terminated"].reshape(-1, 1).astype(bool)
        out["truncated"] = res["truncated"].reshape(-1, 1).astype(bool)
        for entry in res["metrics"]:
            k, met = int(entry["index"]), entry["metrics"]
            outcome = met.get("outcome")
            if outcome in ("success", "collision", "timeout"):
                out["episode_" + outcome][k, 0] = True
            out["episode_avg_speed"][k, 0] = met.get("avg_speed", 0.0)
            out["episode_avg_abs_jerk"][k, 0] = met.get("avg_abs_jerk", 0.0)
            out["episode_max_abs_acc"][k, 0] = met.get("max_abs_acc", 0.0)
        resets = res["resets"]
        seeds = resets.get("variation") or [None] * len(resets["index"])
        first = {
            int(k): {
                "obs": {key: resets["obs"][key][j] for key in ("features", "adjacency", "mask")},
                "scenario": resets["scenario"][j],
                "variation": seeds[j],
            }
            for j, k in enumerate(resets["index"])
        }
        if res.get("failover"):
            for k in range(self.num_envs):
                self._pending[k] = first.get(k) if self.scenario_order == "random" else None
            self._done[:] = True
        else:
            # An env's scenario only changes with a reset, where `_take_reset` records it.
            ended = np.flatnonzero(out["terminated"][:, 0] | out["truncated"][:, 0])
            for k in ended:
                self._done[k] = True
                self._pending[k] = first.get(int(k))
        if res.get("failover"):
            out["truncated"][:] = True
            self._cursor = [0] * self.num_envs
        td = self._to_td(out)
        self.env_time_s += time.perf_counter() - t0
        return td


def _pool_of(spec: EnvSpec) -> tuple[str | None, str | None, list[tuple[str, str]] | None]:
    """``(the pool CreateEnv names, the pool's name, [(scenario, split), ...] or None)`` of a
    spec: its generated scenes, the scenario file its ``pool`` names (by path), or a pool the
    server lists (None: the server's default)."""
    if spec.synthetic is not None:
        if spec.pool is not None:
            raise ValueError("synthetic scenes and a pool exclude each other")
        return None, "synthetic", synthetic_names(spec.synthetic, spec.split)
    name, listed = listed_scenarios(spec.pool)
    return name, name, listed


def _checked_variation_seeds(
    seeds: Sequence[int] | None, spec: EnvSpec, num_envs: int
) -> list[int] | None:
    if seeds is None:
        return None
    if spec.variations is None:
        raise ValueError("variation_seeds need variations (the spec they draw from)")
    if len(seeds) != num_envs:
        raise ValueError(f"variation_seeds: {len(seeds)} seeds for {num_envs} sub-envs")
    return [int(s) for s in seeds]


def _rebuild(cls, kwargs: dict[str, Any]) -> RemoteBatchedEnv:
    return cls(**kwargs)
