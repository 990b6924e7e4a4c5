"""TorchRL env with several controlled agents per sub-env (ENV_CONTRACT.md "Several vehicles"):
:class:`RemoteMultiAgentEnv`, TorchRL's grouped multi-agent layout over the same server envs as
:class:`~sharedspace.torchrl_env.RemoteBatchedEnv`, the agents grouped by kind: ``vehicle`` and
``pedestrian``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Binary, Bounded, Categorical, Composite, Unbounded

from .client import Connection, SimClient, env_options
from .names import AGENT_GROUPS, agent_group
from .torchrl_env import NODE_FEATURES, _ServerEnvs
from .wire.requests import EnvSpec

__all__ = ["AGENT_OUTCOME_KEYS", "RemoteMultiAgentEnv"]


#: Per-agent flags ``[K, A, 1]`` under the group, set on the step that ends that agent's
#: episode: how it ended, and ``episode_car_collision`` when its collision was with a vehicle.
AGENT_OUTCOME_KEYS = (
    "episode_success",
    "episode_collision",
    "episode_timeout",
    "episode_car_collision",
)


class RemoteMultiAgentEnv(_ServerEnvs):
    """K server envs with several controlled agents each, in TorchRL's multi-agent layout.

    The agents of ``external_agents`` are grouped by kind (as TorchRL's PettingZoo and VMAS
    wrappers group agents): the A vehicles under ``"vehicle"``, the pedestrians, if any, under
    ``"pedestrian"`` (:attr:`groups`: each group's columns of ``external_agents``; ``group``:
    the first). Under each group ``features [K, A, M, F]``,
    ``adjacency [K, A, M, M]``, ``mask [K, A, M]`` (bool: which nodes are real), ``action
    [K, A, 2]``, ``reward [K, A, 1]`` and the per-agent ``done`` / ``terminated`` /
    ``truncated [K, A, 1]``. An agent's flags stay set once its own episode has ended (the
    server then ignores its actions and gives it reward 0, SPEC 8.3); the root ``done`` /
    ``terminated`` / ``truncated [K, 1]`` are set when every agent's episode has ended (the
    sub-env's episode is over; ``truncated`` when some agent ran into the horizon). On the step
    that ends an agent's episode its :data:`AGENT_OUTCOME_KEYS` say how (a collision with another
    vehicle also sets ``episode_car_collision``), so per-car rates need no second channel.
    Sub-envs are created with the server's autoreset (unless ``scenarios`` pins them), so the
    partial ``_reset`` after an episode needs no round trip. With one agent it is the
    single-vehicle env in group form.

    Args:
        spec: the envs (:class:`~sharedspace.wire.EnvSpec`); its ``external_agents`` are the
            controlled vehicles (``vehicle_0`` is the scenario's ego, then the scenario's other
            vehicles; episodes come only from scenarios that have all of them, SPEC 5.2;
            default here: ``vehicle_0`` and ``vehicle_1``). ``**options`` naming its fields or
            :class:`~sharedspace.client.Connection` fields apply over it and ``client``.
        num_envs: K.
        scenarios: scenario names to play instead of the server's draws: sub-env ``k`` plays
            ``scenarios[k]`` at every reset (no autoreset then; an evaluation's fixed set).
        client: a :class:`~sharedspace.client.SimClient` to share, or the ``Connection`` to
            open.
        device: the device of the env's tensors.
    """

    batch_locked = True

    def __init__(
        self,
        spec: EnvSpec | None = None,
        num_envs: int = 4,
        *,
        scenarios: Sequence[str] | None = None,
        client: SimClient | Connection | None = None,
        device: str | torch.device = "cpu",
        **options: Any,
    ):
        if num_envs < 1:
            raise ValueError("num_envs must be at least 1")
        if scenarios is not None and len(scenarios) != num_envs:
            raise ValueError(f"scenarios: {len(scenarios)} names for {num_envs} sub-envs")
        self._init_kwargs = {"num_envs": num_envs, "device": device, "scenarios": scenarios}
        self._scenarios = None if scenarios is None else [str(n) for n in scenarios]
        spec = spec or EnvSpec(external_agents=("vehicle_0", "vehicle_1"))
        opts = env_options(options, spec, client)
        if not opts.spec.external_agents:
            raise ValueError("external_agents must not be empty")
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        spec = self._connect(num_envs, opts, autoreset=scenarios is None)
        self.num_envs = k = int(num_envs)
        self.n_agents = a = len(spec.external_agents)
        self.max_agents = m = spec.max_agents
        self.agent_names = list(spec.external_agents)
        #: Each group's columns of ``external_agents``, vehicles first.
        self.groups: dict[str, list[int]] = {}
        for i, name in enumerate(self.agent_names):
            self.groups.setdefault(agent_group(name), []).append(i)
        self.groups = {g: self.groups[g] for g in AGENT_GROUPS if g in self.groups}
        #: The first group (``"vehicle"`` unless only pedestrians are driven).
        self.group = next(iter(self.groups))
        #: Scenario name of each sub-env's current episode.
        self.scenarios: list[str | None] = [None] * k
        self._obs = {
            "features": np.zeros((k, a, m, NODE_FEATURES), dtype=np.float32),
            "adjacency": np.zeros((k, a, m, m), dtype=np.float32),
            "mask": np.zeros((k, a, m), dtype=bool),
        }
        self._agent_done = np.zeros((k, a), dtype=bool)
        self._agent_term = np.zeros((k, a), dtype=bool)
        self._agent_trunc = np.zeros((k, a), dtype=bool)
        # Per sub-env: the ids of the episode's vehicles, and each external agent's id.
        self._vehicle_ids: list[frozenset[int]] = [frozenset()] * k
        self._external_ids: list[dict[int, int]] = [{}] * k
        self._pending: list[dict[str, Any] | None] = [None] * k
        self._needs_reset = np.ones(k, dtype=bool)
        self._reseed: int | None = None
        self._set_specs()

    def _set_specs(self) -> None:
        k, m, dev = self.num_envs, self.max_agents, self.device

        def flags(shape):
            return {
                key: Categorical(2, shape=shape, dtype=torch.bool, device=dev)
                for key in ("done", "terminated", "truncated")
            }

        def grouped(make) -> Composite:
            """``make(a)``'s specs (each ``[k, a, ...]``) under each agent group of ``a``
            agents, as TorchRL's multi-agent envs nest them: batch ``[k]`` outside, ``[k, a]``
            inside."""
            return Composite(
                {
                    g: Composite(make(len(cols)), shape=(k, len(cols)), device=dev)
                    for g, cols in self.groups.items()
                },
                shape=(k,),
                device=dev,
            )

        self.observation_spec = grouped(
            lambda a: {
                "features": Unbounded((k, a, m, NODE_FEATURES), dtype=torch.float32, device=dev),
                "adjacency": Unbounded((k, a, m, m), dtype=torch.float32, device=dev),
                "mask": Binary(n=m, shape=(k, a, m), dtype=torch.bool, device=dev),
                **{
                    key: Categorical(2, shape=(k, a, 1), dtype=torch.bool, device=dev)
                    for key in AGENT_OUTCOME_KEYS
                },
            }
        )
        self.action_spec = grouped(
            lambda a: {"action": Bounded(-1.0, 1.0, (k, a, 2), dtype=torch.float32, device=dev)}
        )
        self.reward_spec = grouped(
            lambda a: {"reward": Unbounded((k, a, 1), dtype=torch.float32, device=dev)}
        )
        done = grouped(lambda a: flags((k, a, 1)))
        done.update(flags((k, 1)))
        self.done_spec = done

    def _take_reset(self, k: int, result: Mapping[str, Any]) -> None:
        for key in ("features", "adjacency", "mask"):
            self._obs[key][k] = result["obs"][key]
        self.scenarios[k] = result["scenario"]
        agents = result.get("agents") or []
        self._vehicle_ids[k] = frozenset(int(d["id"]) for d in agents if d["kind"] == "vehicle")
        names = {d["name"]: int(d["id"]) for d in agents}
        self._external_ids[k] = {names[n]: i for i, n in enumerate(self.agent_names) if n in names}
        self._agent_done[k] = self._agent_term[k] = self._agent_trunc[k] = False
        self._needs_reset[k] = False

    def _td(
        self, reward: np.ndarray | None = None, outcomes: dict[str, np.ndarray] | None = None
    ) -> TensorDictBase:
        k, a = self.num_envs, self.n_agents
        over = self._agent_done.all(1, keepdims=True)
        trunc = over & self._agent_trunc.any(1, keepdims=True)
        columns = {
            "features": self._obs["features"],
            "adjacency": self._obs["adjacency"],
            "mask": self._obs["mask"],
            "done": self._agent_done.reshape(k, a, 1),
            "terminated": self._agent_term.reshape(k, a, 1),
            "truncated": self._agent_trunc.reshape(k, a, 1),
        }
        if reward is not None:
            columns["reward"] = reward.reshape(k, a, 1).astype(np.float32)
        if outcomes is None:
            outcomes = {key: np.zeros((k, a), dtype=bool) for key in AGENT_OUTCOME_KEYS}
        for key, flags in outcomes.items():
            columns[key] = flags.reshape(k, a, 1)
        groups = {
            g: TensorDict(
                {key: torch.from_numpy(v[:, cols].copy()) for key, v in columns.items()},
                batch_size=(k, len(cols)),
            )
            for g, cols in self.groups.items()
        }
        return TensorDict(
            {
                **groups,
                "done": torch.from_numpy(over),
                "terminated": torch.from_numpy(over & ~trunc),
                "truncated": torch.from_numpy(trunc),
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(self.num_envs).cpu().numpy().astype(bool)
        todo = [k for k in range(self.num_envs) if mask is None or mask[k] or self._needs_reset[k]]
        queries = []
        for k in todo:
            pending, self._pending[k] = self._pending[k], None
            if pending is not None and mask is not None:
                self._take_reset(k, pending)
            else:
                queries.append(k)
        if queries:
            ids = self.vec.env_ids
            named = None if self._scenarios is None else [self._scenarios[k] for k in queries]
            results = self.vec.client.reset_many([ids[k] for k in queries], scenarios=named)
            for k, r in zip(queries, results, strict=True):
                self._take_reset(k, r)
        return self._td()

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self._needs_reset.any():
            k = int(np.flatnonzero(self._needs_reset)[0])
            raise RuntimeError(f"sub-env {k} is done: reset it (with `_reset`) before stepping")
        action = np.zeros((self.num_envs, self.n_agents, 2), dtype=np.float32)
        for g, cols in self.groups.items():
            action[:, cols] = tensordict.get((g, "action")).detach().cpu().numpy()
        res = self.vec.step(np.clip(action, -1.0, 1.0))
        for key in ("features", "adjacency", "mask"):
            self._obs[key][:] = res["obs"][key]
        term = res["terminated"].astype(bool)
        trunc = res["truncated"].astype(bool)
        self._agent_term |= term
        self._agent_trunc |= trunc
        self._agent_done |= term | trunc
        td = self._td(np.asarray(res["reward"], dtype=np.float32), self._outcomes(res))
        resets = res["resets"]
        agents = resets.get("agents") or [[] for _ in resets["index"]]
        for j, k in enumerate(resets["index"]):
            k = int(k)
            self._pending[k] = {
                "obs": {key: resets["obs"][key][j] for key in ("features", "adjacency", "mask")},
                "scenario": resets["scenario"][j],
                "agents": agents[j],
            }
        over = self._agent_done.all(1)
        self._needs_reset |= over
        return td

    def _outcomes(self, res: Mapping[str, Any]) -> dict[str, np.ndarray]:
        """The :data:`AGENT_OUTCOME_KEYS` flags ``[K, A]`` of one ``BatchStep`` reply, from its
        episode metrics (how each ended) and collision events (with whom)."""
        out = {
            key: np.zeros((self.num_envs, self.n_agents), dtype=bool) for key in AGENT_OUTCOME_KEYS
        }
        column = {name: i for i, name in enumerate(self.agent_names)}
        for entry in res["metrics"]:
            met = entry["metrics"]
            i = column.get(met.get("agent"))
            if i is not None and met.get("outcome") in ("success", "collision", "timeout"):
                out["episode_" + met["outcome"]][int(entry["index"]), i] = True
        for entry in res["events"]:
            event, k = entry["event"], int(entry["index"])
            if event.get("kind") != "collision":
                continue
            pair = [int(x) for x in event.get("agents", ())]
            if not all(x in self._vehicle_ids[k] for x in pair):
                continue
            for x in pair:
                i = self._external_ids[k].get(x)
                if i is not None:
                    out["episode_car_collision"][k, i] = True
        return out

    def _set_seed(self, seed: int | None) -> None:
        # Sub-env k is re-seeded with seed + k at its next reset (SPEC 5.3).
        self._reseed = 0 if seed is None else int(seed)
        self._needs_reset[:] = True
        self._pending = [None] * self.num_envs
