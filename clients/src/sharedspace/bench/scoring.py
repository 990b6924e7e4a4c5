"""Scoring a policy on a task: its episodes played batched, their outcomes with Wilson
intervals, and the paired difference against a reference result of the same task version.

Every policy plays the same episodes of a task: variation ``j`` (seed ``j``) of every test
scene for the single-car tasks, every car of every test scene for ``crossing``, so that two
results pair up episode by episode. Several policies given together (a learner's seeds) make one
pooled row: their episodes all count, and in a paired difference each episode's outcome is the
mean over them.
"""

from __future__ import annotations

import json
import re
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sharedspace.bench.policies import Policy, make_policy
from sharedspace.bench.tasks import BenchError, Task, get_task
from sharedspace.client import Connection
from sharedspace.outcomes import STATUSES, mean_by_episode, outcome_rates
from sharedspace.pool import listed_scenarios
from sharedspace.rollout import play_first_episodes, variation_batches
from sharedspace.stats import paired_clustered
from sharedspace.wire.requests import EnvSpec

__all__ = ["Result", "compare", "file_name", "load_result", "score"]


def file_name(name: str) -> str:
    """``name`` as a file or folder name that every file system takes: each character other
    than letters, digits, ``.``, ``_`` and ``-`` becomes ``_`` (a row named after
    ``mypkg.mod:act`` or an env id ``sharedspace:sharedspace/SharedSpace-v0``); never empty,
    never hidden."""
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", name).lstrip(".")
    return safe or "_"


@dataclass
class Result:
    """One row of a task's leaderboard: what played, every episode, and the summary."""

    task: dict[str, Any]  # name, version, fingerprint, description, scenes_fixed_interval
    policy: str  # the row's name
    sources: list[dict[str, Any]]  # what each pooled policy is (driver, checkpoint, function)
    episodes: list[dict[str, Any]]  # scene, unit (variation or car), status, policy index, ...
    summary: dict[str, Any]  # per status: rate, count, ci95; episodes
    wall_s: float  # seconds the plays took
    comparison: dict[str, Any] | None = None  # the paired difference against a reference
    when: str = field(default_factory=lambda: time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()))

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    def save(self, out: str | Path) -> Path:
        """Writes ``out/TASK/ROW.json`` (every episode) and ``.md``, ``ROW`` the row's name made
        safe on every file system (:func:`file_name`); returns the JSON's path."""
        folder = Path(out) / self.task["name"]
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"{file_name(self.policy)}.md").write_text(self.markdown())
        path = folder / f"{file_name(self.policy)}.json"
        path.write_text(json.dumps(self.to_json()))
        return path

    def markdown(self) -> str:
        """The row as a markdown table (success, collision, timeout with Wilson 95 %), and the
        paired difference where there is a reference."""
        s = self.summary
        cells = [
            f"{s[k]['rate']:.3f} [{s[k]['ci95'][0]:.3f}, {s[k]['ci95'][1]:.3f}]" for k in STATUSES
        ]
        lines = [
            f"Task `{self.task['name']}@{self.task['version']}` ({self.task['description']}; "
            f"fingerprint {self.task['fingerprint']}):",
            "",
            "| policy | episodes | success [95 %] | collision [95 %] | timeout [95 %] | wall s |",
            "|---|---:|---|---|---|---:|",
            f"| {self.policy} | {s['episodes']} | " + " | ".join(cells) + f" | {self.wall_s:.0f} |",
        ]
        if self.comparison:
            c = self.comparison
            line = (
                f"Paired success difference, {self.policy} − {c['reference']}: "
                f"{c['diff']:+.3f} [{c['lo']:+.3f}, {c['hi']:+.3f}] (95 %, scenes resampled; "
                f"{c['pairs']} episode pairs over {c['scenes']} scenes)"
            )
            if "lo_fixed" in c:
                line += f"; scenes fixed [{c['lo_fixed']:+.3f}, {c['hi_fixed']:+.3f}]"
            lines += ["", line + "."]
        return "\n".join(lines) + "\n"

    def success_by_episode(self) -> dict[tuple[str, int], float]:
        """Each episode's success, averaged over the pooled policies."""
        return mean_by_episode(
            self.episodes,
            lambda e: (e["scene"], int(e["unit"])),
            lambda e: e["status"] == "success",
        )


def score(
    task: str | Task,
    policies: Any,
    *,
    name: str = "",
    endpoint: str = "",
    reference: Result | str | Path | None = None,
) -> Result:
    """Plays ``task`` with ``policies`` (one spec or a list pooled into one row; see
    :mod:`sharedspace.bench.policies`) and returns the :class:`Result`, compared with
    ``reference`` (a result or its JSON file) if given. Every input is checked before any
    episode is played. ``endpoint``: a server that serves the task's pool with its world
    parameters; by default a local ``sim-server`` is started with them."""
    task = get_task(task)
    specs = list(policies) if isinstance(policies, list | tuple) else [policies]
    if not specs:
        raise BenchError("no policy to score")
    made = [make_policy(spec, task) for spec in specs]
    ref = load_result(reference) if isinstance(reference, str | Path) else reference
    if ref is not None:
        _check_same_task(ref, _task_record(task))
    with tempfile.TemporaryDirectory() as tmp:
        connection = _connection(task, endpoint, Path(tmp))
        client = connection.open()
        try:
            for policy in made:
                _probe(task, policy, client)
            t0 = time.perf_counter()
            episodes = []
            for index, policy in enumerate(made):
                for e in _play(task, policy, client):
                    episodes.append({**e, "policy": index})
            wall = time.perf_counter() - t0
        finally:
            client.shutdown()
    result = Result(
        task=_task_record(task),
        policy=name or made[0].name,
        sources=[p.source for p in made],
        episodes=episodes,
        summary={"episodes": len(episodes), **outcome_rates(episodes)},
        wall_s=wall,
    )
    if ref is not None:
        result.comparison = compare(result, ref)
    return result


def compare(result: Result, reference: Result) -> dict[str, Any]:
    """``result − reference`` success over the episodes both played: the mean and its 95 %
    interval with the scenes resampled (:func:`sharedspace.stats.paired_clustered`), and, for
    a task that reports it (``paper``), the interval with the scenes held fixed. Both must be
    results of one task version."""
    _check_same_task(reference, result.task)
    c = paired_clustered(result.success_by_episode(), reference.success_by_episode())
    out = {"reference": reference.policy, **c}
    if not result.task.get("scenes_fixed_interval"):
        for key in ("lo_fixed", "hi_fixed", "half_width_fixed"):
            out.pop(key)
    return out


def load_result(path: str | Path) -> Result:
    """A :class:`Result` from its JSON file."""
    try:
        data = json.loads(Path(path).read_text())
        return Result(**data)
    except (OSError, ValueError, TypeError) as err:
        raise BenchError(f"reference {path}: not a benchmark result ({err})") from err


def _task_record(task: Task) -> dict[str, Any]:
    return {
        "name": task.name,
        "version": task.version,
        "fingerprint": task.fingerprint(),
        "description": task.description,
        "scenes_fixed_interval": task.scenes_fixed_interval,
    }


def _check_same_task(ref: Result, task: dict[str, Any]) -> None:
    """``ref`` is a result of the task ``task`` records (name, version, fingerprint)."""
    keys = ("name", "version", "fingerprint")
    if tuple(ref.task.get(k) for k in keys) != tuple(task.get(k) for k in keys):
        raise BenchError(
            f"the reference {ref.policy!r} is a result of task {ref.task.get('name')}@"
            f"{ref.task.get('version')} ({ref.task.get('fingerprint')}), not of "
            f"{task['name']}@{task['version']} ({task['fingerprint']})"
        )


def _connection(task: Task, endpoint: str, tmp: Path) -> Connection:
    """The given server, or a local one serving the task's pool with its world parameters."""
    if endpoint:
        return Connection.resolve(endpoint)
    if task.crossing is not None:
        return Connection.resolve()
    params = tmp / f"{task.name}-v{task.version}-params.json"
    params.write_text(json.dumps(task.world_params))
    return Connection.resolve(local_pools=[str(task.pool_path())], local_params=str(params))


def _play(task: Task, policy: Policy, client) -> list[dict[str, Any]]:
    if task.crossing is not None:
        return _play_crossing(task, policy, client)
    scenes = [s["name"] for s in task.check_scenes()]
    keep = ("status", "avg_speed", "avg_abs_jerk", "max_abs_acc", "steps", "return")
    episodes = []
    for seeds in variation_batches(len(scenes), max(task.variations, 1)):
        names = [scenes[k % len(scenes)] for k in range(len(seeds))]
        played = play_first_episodes(
            client, _single_car_spec(task), policy.act, names, seeds if task.variations else None
        )
        for e in played:
            unit = e["variation"] if task.variations else 0
            episodes.append({"scene": e["scene"], "unit": unit, **_keep(e, keep)})
    return episodes


def _play_crossing(task: Task, policy: Policy, client) -> list[dict[str, Any]]:
    """Every car of every test scene of the crossing task (torch: its env is TorchRL's)."""
    import torch

    from sharedspace.marl.evaluate import play

    def act(td, step: int):
        obs = {k: td.get(("vehicle", k)).numpy() for k in ("features", "adjacency", "mask")}
        return torch.as_tensor(policy.act(obs))

    rows = play(task.crossing, act, client)
    cars = {car: k for k, car in enumerate(task.crossing.agents)}
    return [
        {"scene": r["scene"], "unit": cars[r["car"]], **_keep(r, ("status", "car_collision"))}
        for r in rows
    ]


def _keep(record: dict[str, Any], keys: Sequence[str]) -> dict[str, Any]:
    return {k: record[k] for k in keys if k in record}


def _single_car_spec(task: Task) -> EnvSpec:
    """The task's envs, its pool named as the server serving the file knows it."""
    return EnvSpec(
        pool=listed_scenarios(task.pool_path())[0],
        split="test",
        seed=0,
        pedestrian_model=task.pedestrian_model,
        max_agents=task.max_agents,
        variations=dict(task.variation_spec) if task.variations else None,
    )


def _first_observation(task: Task, client) -> tuple[dict[str, np.ndarray], tuple[int, ...]]:
    """One observation of the task's first test scene (its cars grouped on the crossing task),
    and the actions' shape it wants."""
    if task.crossing is not None:
        from sharedspace.marl.task import make_env

        env = make_env(
            task.crossing, "test", 1, client, scenarios=task.crossing.scene_names("test")[:1]
        )
        try:
            td = env.reset()
            obs = {k: td.get(("vehicle", k)).numpy() for k in ("features", "adjacency", "mask")}
        finally:
            env.close()
        return obs, (1, task.cars, 2)
    from sharedspace.vector import VectorClient

    vec = VectorClient(1, _single_car_spec(task), client=client)
    try:
        first = task.check_scenes()[0]["name"]
        variation = [0] if task.variations else None
        reset = vec.client.reset_many(vec.env_ids, scenarios=[first], variations=variation)[0]
    finally:
        vec.close()
    obs = {k: np.asarray(reset["obs"][k][:1]) for k in ("features", "adjacency", "mask")}
    obs["mask"] = obs["mask"].astype(bool)
    return obs, (1, 2)


def _probe(task: Task, policy: Policy, client) -> None:
    """One observation of the task through the policy: the action's shape and finiteness are
    checked before any episode is played."""
    obs, want = _first_observation(task, client)
    try:
        action = np.asarray(policy.act(obs))
    except BenchError:
        raise
    except Exception as err:  # a user's policy: say which and why, then stop
        raise BenchError(
            f"policy {policy.name!r} failed on the task's observation: {err!r}"
        ) from err
    if tuple(action.shape) != want:
        raise BenchError(
            f"policy {policy.name!r} gave actions of shape {tuple(action.shape)} for a batch of "
            f"shape {want[:-1]}; task {task.tag} wants {want}: [acceleration, yaw rate] per car"
        )
    if not bool(np.isfinite(action).all()):  # the server clips finite ones into [-1, 1]
        raise BenchError(f"policy {policy.name!r} gave an action that is not finite: {action}")
