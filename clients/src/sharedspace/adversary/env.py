"""The adversary's env: K server envs of an adversarial task, each with the driver
(``vehicle_0``) and the adversary (``pedestrian_0``) as external agents; the driver's frozen
policy acts inside the env, the learner drives the adversary.

To a learner it is the batched env of clients/ENV_CONTRACT.md, seen from the adversary: its
observation graph, its ``[K, 2]`` command (an acceleration along and to the left of its
heading, as a fraction of the walking range's, :func:`~sharedspace.adversary.task.
plausible_action`), the adversary's reward (``last_reward_terms`` holds its terms), and the
episode keys read as the adversary's outcomes: ``episode_success`` the driver hit it at fault,
``episode_collision`` it touched a vehicle that was not at fault, ``episode_timeout`` neither.

An episode ends for the adversary when its own episode or the driver's ends
(``until="either"``, for training), or only when the driver's does (``until="driver"``, for
scoring the driver: an adversary that reached its goal has left, and the driver drives on).
With ``adversary=False`` the pedestrian is the crowd's own CR-SFM pedestrian: the baseline
the drop is measured from, on the same scenes and variations. :attr:`AdversaryEnv.finished`
keeps one record per ended episode: scene, variation, the driver's outcome, whether the driver
was at fault with the adversary (``fault``) or with anyone (``fault_any``), and whether the
adversary was to blame.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from sharedspace.adversary.task import AdversaryTask, get_adversary_task, plausible_action
from sharedspace.bench.policies import Policy, make_policy
from sharedspace.client import Connection, SimClient, env_options
from sharedspace.names import Feature
from sharedspace.pool import listed_scenarios
from sharedspace.torchrl_env import (
    _ServerEnvs,
    blank_step_columns,
    contract_tensordict,
    reset_mask,
    set_contract_specs,
)
from sharedspace.wire.requests import EnvSpec

__all__ = ["DRIVER", "ADVERSARY", "AdversaryEnv"]

#: The driver's and the adversary's names in every scene of an adversarial task's pool.
DRIVER, ADVERSARY = "vehicle_0", "pedestrian_0"
_OBS = ("features", "adjacency", "mask")
#: The corridor of the ``ahead`` shaping term, in the driver's frame: up to this far ahead of
#: its centre (m) and this far to either side of its centreline (m).
AHEAD_RANGE, AHEAD_HALF_WIDTH = 15.0, 1.5


class AdversaryEnv(_ServerEnvs):
    """K envs of ``task`` as one TorchRL env of batch size ``[K]`` seen from the adversary.

    Args:
        driver: the frozen driver (any policy spec of :mod:`sharedspace.bench.policies`, or a
            made :class:`~sharedspace.bench.policies.Policy`).
        task: the adversarial task (its pool, world, variations, walking range, reward).
        num_envs: K.
        split: ``train`` or ``test`` scenes of the task's pool.
        seed: sub-env ``k`` draws its scenes and variations from seed ``seed + k``.
        scenarios, variation_seeds: sub-env ``k`` plays ``scenarios[k]`` in variation
            ``variation_seeds[k]`` (scoring); None: drawn.
        until: ``either`` or ``driver`` (module doc).
        adversary: False: the pedestrian is the crowd's CR-SFM pedestrian (the baseline).
        reward_weights: adversary reward weights overriding the task's, by name.
        client: a :class:`~sharedspace.client.SimClient` to share, or the connection to open
            (a server that serves the task's pool with its world parameters).
    """

    batch_locked = True

    def __init__(
        self,
        driver: Any = "car_aware",
        task: AdversaryTask | str = "crowd-adversary",
        num_envs: int = 8,
        *,
        split: str = "train",
        seed: int = 0,
        scenarios: Sequence[str] | None = None,
        variation_seeds: Sequence[int] | None = None,
        until: str = "either",
        adversary: bool = True,
        reward_weights: dict[str, float] | None = None,
        client: SimClient | Connection | None = None,
        device: str | torch.device = "cpu",
    ):
        if until not in ("either", "driver"):
            raise ValueError(f"until must be 'either' or 'driver', not {until!r}")
        self.task = get_adversary_task(task) if isinstance(task, str) else task
        self._init_kwargs = dict(
            driver=driver,
            task=self.task,
            num_envs=num_envs,
            split=split,
            seed=seed,
            scenarios=scenarios,
            variation_seeds=variation_seeds,
            until=until,
            adversary=adversary,
            reward_weights=reward_weights,
            device=device,
        )
        driving = self.task.driving
        self.driver = driver if isinstance(driver, Policy) else make_policy(driver, driving)
        unknown = set(reward_weights or {}) - set(self.task.reward)
        if unknown:
            raise ValueError(
                f"reward_weights: unknown terms {sorted(unknown)}; "
                f"the adversary's are {sorted(self.task.reward)}"
            )
        self.weights = dict(self.task.reward) | dict(reward_weights or {})
        self.until, self.adversary = until, adversary
        pool_file = self.task.pool_path()
        pool_name, listed = listed_scenarios(str(pool_file))
        # An agent's id is its index in the scene (SPEC 6.3), also for one entering late.
        self._roles = {
            s["name"]: (_first(s["agents"], "vehicle"), _first(s["agents"], "pedestrian"))
            for s in json.loads(pool_file.read_text())["scenarios"]
        }
        spec = EnvSpec(
            pool=pool_name,
            split=split,
            seed=seed,
            pedestrian_model=driving.pedestrian_model,
            max_agents=driving.max_agents,
            variations=dict(driving.variation_spec),
            external_agents=[DRIVER, ADVERSARY] if adversary else [DRIVER],
        )
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self._connect(num_envs, env_options({}, spec, client), autoreset=False)
        self.num_envs, self.max_agents = int(num_envs), driving.max_agents
        self.scenario_names = [name for name, _ in listed]
        self._index = {name: i for i, name in enumerate(self.scenario_names)}
        self._scenes = list(scenarios) if scenarios is not None else None
        self._variations = list(variation_seeds) if variation_seeds is not None else None
        self.dt = float(self.vec.created["dt"])
        self.ped_acc_max = float(driving.world_params.get("ped_acc_max", 2.0))
        self._init_state()
        set_contract_specs(self, self.num_envs, self.max_agents)

    def _init_state(self) -> None:
        k, m, f = self.num_envs, self.max_agents, len(Feature)
        self.env_time_s = 0.0
        self.last_reward_terms: dict[str, np.ndarray] = {}
        #: One record per ended episode (module doc), in the order they ended.
        self.finished: list[dict[str, Any]] = []
        self._obs = {
            who: {
                "features": np.zeros((k, m, f), dtype=np.float32),
                "adjacency": np.zeros((k, m, m), dtype=np.float32),
                "mask": np.zeros((k, m), dtype=bool),
                "node_ids": np.full((k, m), 0xFFFFFFFF, dtype=np.uint32),
            }
            for who in ("driver", "adversary")
        }
        self._done = np.ones(k, dtype=bool)
        self._scenario = np.full(k, -1, dtype=np.int64)
        self._variation = [-1] * k
        self._ids: list[tuple[int, int]] = [(-1, -1)] * k  # (driver, adversary) agent ids
        self._ped_active = np.zeros(k, dtype=bool)
        self._near = np.full(k, np.nan)
        self._open: list[dict[str, Any]] = [{} for _ in range(k)]

    # ------------------------------------------------------------------------------------

    def _set_seed(self, seed: int | None) -> None:
        self._reseed = 0 if seed is None else int(seed)

    def _take_obs(self, k: int, obs: dict[str, np.ndarray]) -> None:
        """Sub-env ``k``'s observations from its reset."""
        for j, who in enumerate(("driver", "adversary")[: 2 if self.adversary else 1]):
            for key in (*_OBS, "node_ids"):
                self._obs[who][key][k] = obs[key][j]

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        t0 = time.perf_counter()
        mask = reset_mask(tensordict, self.num_envs)
        todo = [k for k in range(self.num_envs) if mask is None or mask[k] or self._done[k]]
        if todo:
            scen = var = None
            if self._scenes is not None:
                scen = [self._scenes[k % len(self._scenes)] for k in todo]
            if self._variations is not None:
                var = [self._variations[k % len(self._variations)] for k in todo]
            results = self.vec.client.reset_many(
                [self.vec.env_ids[k] for k in todo], scenarios=scen, variations=var
            )
            for k, r in zip(todo, results, strict=True):
                self._take_obs(k, r["obs"])
                self._scenario[k] = self._index.get(r["scenario"], -1)
                variation = r.get("variation")
                self._variation[k] = int(variation["seed"]) if variation else -1
                self._ids[k] = self._roles[r["scenario"]]
                self._ped_active[k] = self.adversary
                self._near[k] = self._distance_to_driver(k)
                self._done[k] = False
                self._open[k] = {
                    "scene": r["scenario"],
                    "variation": self._variation[k],
                    "driver": "",
                    "adversary": "",
                    "fault": False,
                    "fault_any": False,
                    "blame": False,
                }
        td = self._to_td(blank_step_columns(self.num_envs))
        self.env_time_s += time.perf_counter() - t0
        return td

    def _to_td(self, out: dict[str, np.ndarray]) -> TensorDictBase:
        seen = self._obs["adversary" if self.adversary else "driver"]
        for key in _OBS:
            out[key] = seen[key].copy()
        return contract_tensordict(self, out, self._scenario)

    def _driver_action(self) -> np.ndarray:
        obs = self._obs["driver"]
        action = np.asarray(self.driver.act({key: obs[key].copy() for key in _OBS}), np.float32)
        return action.reshape(self.num_envs, 2)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        t0 = time.perf_counter()
        if self._done.any():
            k = int(np.flatnonzero(self._done)[0])
            raise RuntimeError(f"sub-env {k} is done: reset it (with `_reset`) before stepping")
        actions = np.zeros((self.num_envs, 2 if self.adversary else 1, 2), dtype=np.float32)
        actions[:, 0] = self._driver_action()
        if self.adversary:
            command = tensordict.get("action").detach().cpu().numpy().reshape(self.num_envs, 2)
            speed = self._obs["adversary"]["features"][:, 0, Feature.SPEED]
            walk = plausible_action(
                command, speed, self.dt, self.ped_acc_max, self.task.walking_range
            )
            actions[:, 1] = np.where(self._ped_active[:, None], walk, 0.0)
        res = self.vec.step(actions)
        out = blank_step_columns(self.num_envs)
        for j, who in enumerate(("driver", "adversary")[: 2 if self.adversary else 1]):
            for key in (*_OBS, "node_ids"):
                self._obs[who][key][:] = res["obs"][key][:, j]
        terms = self._adversary_terms(res)
        self.last_reward_terms = terms
        out["reward"] = sum(terms.values()).astype(np.float32).reshape(-1, 1)
        self._record_ends(res, out, terms)
        td = self._to_td(out)
        self.env_time_s += time.perf_counter() - t0
        return td

    def _adversary_terms(self, res: dict[str, Any]) -> dict[str, np.ndarray]:
        """The adversary's weighted reward terms of the step, ``{term: [K]}``."""
        k = self.num_envs
        fault, blame = np.zeros(k), np.zeros(k)
        for entry in res["events"]:
            i, event = int(entry["index"]), entry["event"]
            if event["kind"] != "at_fault":
                continue
            if tuple(event["agents"]) == self._ids[i]:
                fault[i] = 1.0
            if event["agents"][0] == self._ids[i][0]:
                self._open[i]["fault_any"] = True
        for entry in res["metrics"]:
            i, met = int(entry["index"]), entry["metrics"]
            if met["agent"] == ADVERSARY and met["outcome"] == "collision" and not fault[i]:
                blame[i] = 1.0
        near = np.array([self._distance_to_driver(i) for i in range(k)])
        closing = np.nan_to_num(self._near - near, nan=0.0).clip(-2.0, 2.0)
        closing = np.where(self._ped_active, closing, 0.0)
        self._near = near
        ahead = np.array([self._ahead_of_driver(i) for i in range(k)]) & self._ped_active
        w = self.weights
        return {
            "fault": w["fault"] * fault,
            "blame": w["blame"] * blame,
            "approach": w["approach"] * closing,
            "ahead": w["ahead"] * ahead,
        }

    def _node(self, who: str, k: int, agent: int) -> np.ndarray | None:
        """The node features of ``agent`` in sub-env ``k``'s observation of ``who``, if seen."""
        obs = self._obs[who]
        hit = np.flatnonzero(obs["mask"][k] & (obs["node_ids"][k] == agent))
        return obs["features"][k, hit[0]] if hit.size else None

    def _distance_to_driver(self, k: int) -> float:
        """The adversary's centre distance to the driver, as it sees it (NaN: unseen)."""
        node = self._node("adversary", k, self._ids[k][0])
        return (
            float("nan")
            if node is None
            else float(np.hypot(node[Feature.REL_X], node[Feature.REL_Y]))
        )

    def _ahead_of_driver(self, k: int) -> bool:
        """Whether the driver sees the adversary in the corridor ahead of it (the ``ahead``
        shaping term; the fault itself is the server's judgement, model.md 2c)."""
        node = self._node("driver", k, self._ids[k][1])
        if node is None:
            return False
        x, y = float(node[Feature.REL_X]), float(node[Feature.REL_Y])
        return 0.0 < x < AHEAD_RANGE and abs(y) < AHEAD_HALF_WIDTH

    def _record_ends(self, res: dict[str, Any], out: dict, terms: dict) -> None:
        """Marks the sub-envs whose episode ended (module doc) and records each: the episode
        is truncated when every agent that ended did so at the horizon, else terminated."""
        ended: dict[int, dict[str, str]] = {}
        for entry in res["metrics"]:
            i, met = int(entry["index"]), entry["metrics"]
            ended.setdefault(i, {})[met["agent"]] = met["outcome"]
        for i in range(self.num_envs):
            rec = self._open[i]
            rec["fault"] |= bool(terms["fault"][i])
            rec["blame"] |= bool(terms["blame"][i])
            agents = ended.get(i)
            if not agents:
                continue
            if ADVERSARY in agents:
                self._ped_active[i] = False
                rec["adversary"] = agents[ADVERSARY]
            if DRIVER in agents:
                rec["driver"] = agents[DRIVER]
            elif self.until == "driver" or ADVERSARY not in agents:
                continue
            cut = all(outcome == "timeout" for outcome in agents.values())
            out["truncated" if cut else "terminated"][i, 0] = True
            outcome = "success" if rec["fault"] else "collision" if rec["blame"] else "timeout"
            out["episode_" + outcome][i, 0] = True
            self.finished.append(dict(rec))
            self._done[i] = True

    def __reduce__(self):
        """A copy makes its own connection and server envs (as the other remote envs)."""
        return (_rebuild, (self._init_kwargs | {"client": self._init_args["client"]},))


def _rebuild(kwargs: dict[str, Any]) -> AdversaryEnv:
    return AdversaryEnv(**kwargs)


def _first(agents: list[dict[str, Any]], kind: str) -> int:
    """The index of a scene's first agent of ``kind`` (``vehicle_0``, ``pedestrian_0``)."""
    return next(i for i, a in enumerate(agents) if a["kind"] == kind)
