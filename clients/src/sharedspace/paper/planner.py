"""What any driver can reach on a test set: the first-step check and the open-loop planner.

- :func:`unavoidable_first_step`: the test scenarios in which every extreme action collides on
  the first step (no policy avoids them);
- :func:`open_loop_search`: a cross-entropy search over open-loop action sequences per test
  scenario (or per seeded variation of each, the powered test's bound); a successful sequence,
  replayed in a fresh env, proves that success is reachable there.

Table II (:mod:`sharedspace.paper.table2`) and the powered test
(:mod:`sharedspace.paper.powered`) report both. As a command, the planner's bound of a world:

    python -m sharedspace.paper.planner --pool out/table2g/pool-general.json \
        --params params/table2g.json5 --set max_agents=10 --out results/table2g/planner_bound.json
"""

from __future__ import annotations

import itertools
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn

from sharedspace.cli import run_command
from sharedspace.episodes import BENCHMARK_VARIATIONS, MAX_EVAL_ENVS, STATUSES
from sharedspace.names import Feature
from sharedspace.pool import load_pool, split_indices
from sharedspace.train.config import add_overrides_argument, command_parser
from sharedspace.train.envs import make_env
from sharedspace.world_config import WorldConfig

__all__ = [
    "Cell",
    "cell_name",
    "count_candidate",
    "elite_round",
    "first_round",
    "open_loop_search",
    "split_cells",
    "unavoidable_first_step",
]

_GOAL_DIST = Feature.GOAL_DIST  # ego node feature: distance to the goal


class _ConstantAction(nn.Module):
    def __init__(self, action: Sequence[float]):
        super().__init__()
        self.register_buffer("action", torch.tensor(action, dtype=torch.float32))

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.action.expand(*features.shape[:-2], 2)


def unavoidable_first_step(world: WorldConfig) -> list[int]:
    """Test scenarios (pool indices) in which each of the 9 actions of ``{-1, 0, 1}^2`` ends
    the first step in a collision: no action avoids it."""
    pool = load_pool(world.scenario_pool or None)
    indices = split_indices(pool, "test")
    collided = {i: 0 for i in indices}
    for action in itertools.product((-1.0, 0.0, 1.0), repeat=2):
        env = make_env(world, split="test", num_envs=len(indices), scenario_order="sequential")
        try:
            policy = TensorDictModule(
                _ConstantAction(action), in_keys=["features"], out_keys=["action"]
            )
            td = policy(env.reset())
            nxt = env.step(td)["next"]
            scen = td["scenario_index"].reshape(-1).tolist()
            for k, idx in enumerate(scen):
                collided[int(idx)] += int(bool(nxt["episode_collision"][k]))
        finally:
            env.close()
    return sorted(i for i, c in collided.items() if c == 9)


#: A search cell: a scene (pool name) and the variation seed it is played in (None: the
#: recorded scene).
Cell = tuple[str, "int | None"]


def split_cells(pool: Sequence[dict[str, Any]], split: str, variations: int = 0) -> list[Cell]:
    """The cells of every scene of ``split``: each scene once, or in the variations of seeds
    ``0 .. variations - 1``, variation-major (as the powered test plays them)."""
    names = [pool[i]["name"] for i in split_indices(pool, split)]
    if variations <= 0:
        return [(name, None) for name in names]
    return [(name, v) for v in range(variations) for name in names]


def cell_name(cell: Cell) -> str:
    """``"{scene}#{variation}"``, or the scene's name for the recorded scene."""
    return cell[0] if cell[1] is None else f"{cell[0]}#{cell[1]}"


def open_loop_search(
    world: WorldConfig,
    rounds: int = 8,
    per_round: int = 48,
    elites: int = 8,
    seed: int = 0,
    max_steps: int = 200,
    variations: int = 0,
    spec: dict[str, Any] | None = None,
    *,
    split: str = "test",
    cells: Sequence[Cell] | None = None,
    initial: dict[str, np.ndarray] | None = None,
) -> dict[str, dict[str, Any]]:
    """A planner's answer to "can any driver succeed here?": for every test scenario, a
    cross-entropy search over open-loop action sequences. Round 0 plays the 9 constant actions
    of ``{-1, 0, 1}^2`` and random piecewise-constant sequences; every later round samples
    ``per_round`` sequences from a per-step Gaussian fitted to that scenario's ``elites`` best
    sequences so far (success first and sooner, then a timeout closer to the goal, then a later
    collision). The world is deterministic given the actions (the pedestrians react to the
    vehicle the same way every time), so one successful sequence proves that a collision-free
    arrival exists; a scenario without one is where a failure may be unavoidable (not proven:
    the search is finite). Keyed by scenario name: counts of ``success`` / ``collision`` /
    ``timeout`` over the ``candidates`` played and ``best_steps`` (the fewest steps of a
    successful sequence, or None).

    With ``variations`` = M > 0 the search runs on each of the M seeded variations of every test
    scenario (seeds 0..M-1 of ``spec``, as :func:`sharedspace.train.evaluation.play_variations`
    plays them), keyed ``"{name}#{seed}"``: the bound of the powered test. ``split`` names
    another split, ``cells`` any list of (scene, variation seed) instead; ``initial`` maps a
    cell's name to a sequence ``[T, 2]`` that round 0 plays among its first candidates (a
    driver's actions, from which the search starts)."""
    pool = load_pool(world.scenario_pool or None)
    cells = list(cells) if cells is not None else split_cells(pool, split, variations)
    n = len(cells)  # search cells: (scenario, variation)
    names = [cell_name(c) for c in cells]
    rng = np.random.default_rng(seed)
    played: dict[str, list[tuple[float, np.ndarray]]] = {}  # name -> (score, actions)
    found: dict[str, dict[str, Any]] = {}
    for round_ in range(rounds):
        shape = (n * per_round, max_steps, 2)
        if round_ == 0:
            actions = first_round(shape, n, rng)
            _start_from(actions, names, initial or {})
        else:
            actions = elite_round(shape, n, [played[name] for name in names], elites, rng)
        outcome = _play_open_loop(world, split, cells, actions, spec)
        for k, cell in enumerate(cells * per_round):
            name = cell_name(cell)
            status, steps, goal_dist = outcome[k] or ("timeout", max_steps, float("inf"))
            count_candidate(found, name, status, steps, actions[k])
            score = {"success": 1e4 - steps, "timeout": -goal_dist, "collision": -1e4 + steps}
            played.setdefault(name, []).append((score[status], actions[k]))
    # Replayed in fresh envs, every best sequence must arrive again: the bound rests on it.
    replay = np.zeros((n, max_steps, 2), dtype=np.float32)
    for j, name in enumerate(names):
        best = found.get(name, {}).get("best_actions")
        if best:
            replay[j, : len(best)] = best
    outcome = _play_open_loop(world, split, cells, replay, spec)
    for name, result in zip(names, outcome, strict=True):
        if found.get(name, {}).get("best_actions"):
            found[name]["replayed"] = result[0] if result else "timeout"
    return found


#: The constant actions of ``{-1, 0, 1}^2``, each cell's first candidates.
_CONSTANTS = np.array(list(itertools.product((-1.0, 0.0, 1.0), repeat=2)), dtype=np.float32)
#: The levels of round 0's random piecewise-constant sequences.
_LEVELS = np.array([-1.0, -0.5, 0.0, 0.5, 1.0], dtype=np.float32)


def first_round(shape: tuple[int, int, int], n: int, rng) -> np.ndarray:
    """Round 0: sub-env ``k`` (cell ``k % n``, candidate ``k // n``) plays a constant action of
    :data:`_CONSTANTS`, then random piecewise-constant sequences."""
    actions = np.empty(shape, dtype=np.float32)
    for k in range(shape[0]):
        c = k // n  # sub-env k plays cell k % n
        if c < len(_CONSTANTS):
            actions[k] = _CONSTANTS[c]
            continue
        t = 0
        while t < shape[1]:
            length = int(rng.integers(1, 7))
            actions[k, t : t + length] = rng.choice(_LEVELS, size=2)
            t += length
    return actions


def _start_from(actions: np.ndarray, names: Sequence[str], initial: dict[str, np.ndarray]):
    """Round 0's first random candidate of each cell of ``initial`` becomes its sequence (held
    at its last action after it ends)."""
    n, slot = len(names), len(_CONSTANTS)
    for j, name in enumerate(names):
        seq = initial.get(name)
        if seq is None or len(seq) == 0 or (slot + 1) * n > len(actions):
            continue
        seq = np.asarray(seq, dtype=np.float32)[: actions.shape[1]]
        row = actions[slot * n + j]
        row[: len(seq)] = seq
        row[len(seq) :] = seq[-1]


def elite_round(shape, n: int, played: list[list[tuple[float, np.ndarray]]], elites: int, rng):
    """A later round: each cell's candidates from a per-step Gaussian fitted to its ``elites``
    best sequences so far (``played[c]``: cell ``c``'s scored sequences)."""
    actions = np.empty(shape, dtype=np.float32)
    for k in range(shape[0]):
        best = sorted(played[k % n], key=lambda e: -e[0])[:elites]
        stack = np.stack([a for _, a in best])
        mean, std = stack.mean(0), np.maximum(stack.std(0), 0.15)
        actions[k] = np.clip(mean + std * rng.standard_normal(mean.shape), -1.0, 1.0)
    return actions


def count_candidate(
    found: dict[str, dict[str, Any]], name: str, status: str, steps: int, actions
) -> None:
    """One played candidate of cell ``name``: its outcome counted, a faster success kept."""
    rec = found.setdefault(
        name, {"candidates": 0, "success": 0, "collision": 0, "timeout": 0, "best_steps": None}
    )
    rec["candidates"] += 1
    rec[status] += 1
    if status == "success" and (rec["best_steps"] is None or steps < rec["best_steps"]):
        rec["best_steps"] = steps
        rec["best_actions"] = actions[:steps].tolist()  # float32 values, exact


def _play_open_loop(
    world: WorldConfig,
    split: str,
    cells: Sequence[Cell],
    actions: np.ndarray,
    spec: dict[str, Any] | None = None,
) -> list[tuple[str, int, float] | None]:
    """Plays ``actions[k]`` (``[K, T, 2]``) open loop in sub-env ``k``, on cell ``k % n`` of the
    ``n`` ``cells`` (scenes of ``split``), until every sub-env's first episode has ended; per
    sub-env ``(status, steps, goal distance)``. Envs of at most :data:`MAX_EVAL_ENVS` sub-envs."""
    n = len(cells)
    outcome: list[tuple[str, int, float] | None] = []
    for start in range(0, actions.shape[0], MAX_EVAL_ENVS):
        part = actions[start : start + MAX_EVAL_ENVS]
        part_cells = [cells[(start + k) % n] for k in range(len(part))]
        outcome += _play_open_loop_env(world, split, part_cells, part, spec)
    return outcome


def _play_open_loop_env(
    world: WorldConfig,
    split: str,
    cells: Sequence[Cell],
    actions: np.ndarray,
    spec: dict[str, Any] | None,
) -> list[tuple[str, int, float] | None]:
    k_envs, max_steps = actions.shape[:2]
    seeds = [c[1] for c in cells]
    varied = any(s is not None for s in seeds)
    env = make_env(
        world,
        split=split,
        num_envs=k_envs,
        scenarios=[c[0] for c in cells],
        variations=dict(spec or BENCHMARK_VARIATIONS) if varied else None,
        variation_seeds=[0 if s is None else s for s in seeds] if varied else None,
    )
    try:
        td = env.reset()
        outcome: list[tuple[str, int, float] | None] = [None] * k_envs
        for t in range(max_steps):
            td["action"] = torch.from_numpy(np.ascontiguousarray(actions[:, t]))
            stepped, td = env.step_and_maybe_reset(td)
            nxt = stepped["next"]
            for k in range(k_envs):
                if outcome[k] is None and bool(nxt["done"][k]):
                    status = next((s for s in STATUSES if bool(nxt[f"episode_{s}"][k])), "timeout")
                    outcome[k] = (status, t + 1, float(nxt["features"][k, 0, _GOAL_DIST]))
            if all(o is not None for o in outcome):
                break
    finally:
        env.close()
    return outcome


def main(argv: Sequence[str] | None = None) -> int:
    """The planner's bound on a world: can any driver succeed on its test scenes?"""
    ap = command_parser("python -m sharedspace.paper.planner", __doc__)
    ap.add_argument("--rounds", type=int, default=8, help="search rounds per scene")
    ap.add_argument("--per-round", type=int, default=48, help="sequences per scene and round")
    ap.add_argument("--pool", default="", help="scenario file of the test scenes (default: paper)")
    ap.add_argument("--params", default="params/table2.json5", help="world parameters")
    ap.add_argument("--out", default="", help="write the summary here (JSON)")
    add_overrides_argument(ap, "config overrides, e.g. max_agents=10")
    args = ap.parse_args(argv)
    t0 = time.time()
    # No endpoint: the envs share this process's server of the pool and parameters.
    sets = [f"scenario_pool={args.pool}", f"server_params={args.params}", *args.set]
    found = open_loop_search(
        WorldConfig.from_words(sets), rounds=args.rounds, per_round=args.per_round
    )
    solved = sorted(n for n, r in found.items() if r.get("replayed") == "success")
    summary = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "rounds": args.rounds,
        "per_round": args.per_round,
        "scenes": len(found),
        "solved": len(solved),
        "success_reachable": len(solved) / max(1, len(found)),
        "unsolved": sorted(set(found) - set(solved)),
        "minutes": round((time.time() - t0) / 60, 1),
        "per_scene": {
            n: {k: v for k, v in r.items() if k != "best_actions"} for n, r in found.items()
        },
    }
    if args.out:
        Path(args.out).write_text(json.dumps(summary, indent=1))
    print(
        f"planner bound: a replayed collision-free arrival in {len(solved)} of {len(found)} "
        f"test scenes ({summary['success_reachable']:.3f}); {summary['minutes']} min"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
