"""Prior data for the learner: demonstrations recorded on the train split only.

    python -m sharedspace.paper.demos --pool out/table2g/pool-general.json \\
        --params params/table2g.json5 --set max_agents=10 --out out/demos/table2g

(``make demos``). Every scene of the train split is played in seeded variations (the training
env's, ``--variation-spec``) by each source of :data:`RECIPE`:

- the scripted drivers (:mod:`sharedspace.paper.drivers`): the car-aware script, a noisier copy
  of it (Gaussian noise on the normalised action) and ``pursuit_3``;
- the planner (:func:`sharedspace.paper.planner.open_loop_search`) on the cells (scene,
  variation) where the car-aware script did not arrive, started from the script's actions;
  each sequence that arrives is replayed in a fresh env and recorded.

Every transition (observation, action, reward, next observation, its episode's outcome) goes
into one dataset in the format of :mod:`sharedspace.train.prior`, whose header names the world
it was recorded in; the trainer refuses a dataset of another world. A dataset whose header
already holds this world and this recipe is kept (``--force`` records it anew).
"""

from __future__ import annotations

import hashlib
import json
import shlex
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.envs.utils import step_mdp

from sharedspace.cli import run_command
from sharedspace.outcomes import STATUSES
from sharedspace.paper.drivers import make_driver
from sharedspace.paper.planner import Cell, cell_name, open_loop_search
from sharedspace.train.config import add_overrides_argument, command_parser
from sharedspace.train.envs import make_env
from sharedspace.train.prior import KEYS, read_header, world_of, write_prior
from sharedspace.world_config import WorldConfig
from sharedspace.worlds import TRAINING_VARIATIONS  # the learners' variations, the demos' default

__all__ = ["RECIPE", "TRAINING_VARIATIONS", "record_episodes", "record_demos", "main"]


#: The sources of a dataset, in source-code order: name -> driver, action noise (standard
#: deviation on the normalised action), and the first variation seed and count per scene
#: (``planner``: the cells of the ``car_aware`` source it did not solve).
RECIPE: dict[str, dict[str, Any]] = {
    "car_aware": {"driver": "car_aware", "noise_std": 0.0, "first": 0, "variations": 8},
    "car_aware_noisy": {"driver": "car_aware", "noise_std": 0.3, "first": 100, "variations": 4},
    "pursuit_3": {"driver": "pursuit_3", "noise_std": 0.0, "first": 200, "variations": 4},
    "planner": {"driver": "planner", "of": "car_aware", "rounds": 6, "per_round": 32},
}

#: Sub-envs of one recording env (the server's default ``max_batch`` is 1024).
_MAX_ENVS = 512


class _Sequences(nn.Module):
    """Plays fixed action sequences ``[K, T, 2]`` open loop, one per sub-env (then brakes)."""

    def __init__(self, actions: np.ndarray):
        super().__init__()
        self.actions, self.t = torch.as_tensor(actions, dtype=torch.float32), 0

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        if self.t < self.actions.shape[1]:
            out = self.actions[:, self.t]
        else:
            out = torch.tensor([-1.0, 0.0]).expand(self.actions.shape[0], 2)
        self.t += 1
        return out.reshape(*features.shape[:-2], 2).clone()


def record_episodes(
    env, policy, noise_std: float = 0.0, seed: int = 0, max_steps: int = 10_000
) -> tuple[TensorDict, list[dict[str, Any]]]:
    """Plays the first episode of every sub-env of ``env`` with ``policy`` (plus Gaussian
    noise of ``noise_std`` on the normalised action, clipped to ``[-1, 1]``); returns its
    transitions (:data:`~sharedspace.train.prior.KEYS` and the labels ``scenario_index``,
    ``variation``, ``episode`` = sub-env, ``step``, ``episode_success``) and per sub-env its
    outcome (scene, variation, status, steps, actions)."""
    k = env.batch_size[0]
    gen = torch.Generator().manual_seed(seed)
    alive = torch.ones(k, dtype=torch.bool)
    outcome: list[dict[str, Any] | None] = [None] * k
    actions: list[list[list[float]]] = [[] for _ in range(k)]
    chunks = []
    td = env.reset()
    seeds = [-1 if s is None else int(s) for s in env.last_variation_seeds]
    for t in range(max_steps):
        with torch.no_grad():
            td = policy(td)
        if noise_std > 0:
            noise = noise_std * torch.randn(td["action"].shape, generator=gen)
            td["action"] = (td["action"] + noise).clamp(-1.0, 1.0)
        td = env.step(td)
        rows = torch.nonzero(alive).squeeze(-1)
        chunk = td[rows].select(*KEYS).clone()
        chunk["scenario_index"] = td["scenario_index"][rows].reshape(-1)
        chunk["variation"] = torch.tensor(seeds)[rows]
        chunk["episode"] = rows
        chunk["step"] = torch.full((len(rows),), t)
        chunks.append(chunk)
        nxt = td["next"]
        for i in rows.tolist():
            actions[i].append(td["action"][i].tolist())
            if bool(nxt["done"][i]):
                status = next((s for s in STATUSES if bool(nxt[f"episode_{s}"][i])), "timeout")
                outcome[i] = {
                    "scenario_index": int(td["scenario_index"][i]),
                    "variation": seeds[i],
                    "status": status,
                    "steps": t + 1,
                    "actions": actions[i],
                }
                alive[i] = False
        if not bool(alive.any()):
            break
        td = env.maybe_reset(step_mdp(td))
    transitions = torch.cat(chunks)
    ok = torch.tensor([o is not None and o["status"] == "success" for o in outcome])
    transitions["episode_success"] = ok[transitions["episode"]]
    return transitions, [o for o in outcome if o is not None]


def _play_cells(
    world: WorldConfig,
    cells: Sequence[Cell],
    spec: dict[str, Any],
    make_policy,
    noise_std: float,
    seed: int,
) -> tuple[list[TensorDict], list[dict[str, Any]]]:
    """Records the first episode of each (train) cell with ``make_policy(cells_of_env)``, in
    envs of at most :data:`_MAX_ENVS` sub-envs."""
    parts, episodes = [], []
    for start in range(0, len(cells), _MAX_ENVS):
        part = cells[start : start + _MAX_ENVS]
        env = make_env(
            world,
            split="train",
            num_envs=len(part),
            scenarios=[c[0] for c in part],
            variations=dict(spec),
            variation_seeds=[int(c[1] or 0) for c in part],
        )
        try:
            got, eps = record_episodes(env, make_policy(start, part), noise_std, seed + start)
        finally:
            env.close()
        got["episode"] += start
        parts.append(got)
        episodes += eps
    return parts, episodes


def record_demos(
    world: WorldConfig,
    recipe: dict[str, dict[str, Any]] = RECIPE,
    spec: dict[str, Any] = TRAINING_VARIATIONS,
    log=print,
) -> tuple[TensorDict, dict[str, dict[str, Any]]]:
    """Every source of ``recipe`` on the train split of ``world``'s world (without the scenes
    carved off as its validation split, :meth:`WorldConfig.scene_indices`); returns the
    transitions (labelled with their ``source`` code, episodes numbered across sources) and
    the per-source summary of the header."""
    pool = world.pool_scenes()
    names = [pool[i]["name"] for i in world.scene_indices("train")]  # the validation split left out
    parts: list[TensorDict] = []
    sources: dict[str, dict[str, Any]] = {}
    failed: dict[str, list[dict[str, Any]]] = {}  # source -> its episodes that did not arrive
    episodes_so_far = 0
    for code, (source, how) in enumerate(recipe.items()):
        t0 = time.perf_counter()
        if how["driver"] == "planner":
            got, eps, extra = _planner_source(world, pool, failed.get(how["of"], []), spec, how)
        else:
            cells = [(n, how["first"] + v) for v in range(how["variations"]) for n in names]
            got, eps = _play_cells(
                world,
                cells,
                spec,
                lambda start, part, how=how: make_driver(how["driver"]),
                how["noise_std"],
                seed=1000 * code,
            )
            extra = {}
        failed[source] = [e for e in eps if e["status"] != "success"]
        for part in got:
            part["source"] = torch.full((part.shape[0],), code)
            part["episode"] += episodes_so_far
        episodes_so_far += len(eps)
        parts += got
        n_trans = sum(p.shape[0] for p in got)
        sources[source] = {
            **how,
            **extra,
            "episodes": len(eps),
            "transitions": n_trans,
            "success": sum(e["status"] == "success" for e in eps) / max(1, len(eps)),
            "collision": sum(e["status"] == "collision" for e in eps) / max(1, len(eps)),
            "wall_s": round(time.perf_counter() - t0, 1),
        }
        log(f"{source}: {len(eps)} episodes, {n_trans} transitions, {sources[source]}")
    return torch.cat(parts), sources


def _planner_source(
    world: WorldConfig,
    pool: Sequence[dict[str, Any]],
    failures: Sequence[dict[str, Any]],
    spec: dict[str, Any],
    how: dict[str, Any],
) -> tuple[list[TensorDict], list[dict[str, Any]], dict[str, Any]]:
    """The planner on the cells of ``failures`` (a driver's episodes that did not arrive),
    started from their actions; its replayed arrivals recorded."""
    if not failures:
        return [], [], {"cells": 0, "solved": 0}
    cells: list[Cell] = [(pool[e["scenario_index"]]["name"], e["variation"]) for e in failures]
    initial = {cell_name(c): np.asarray(e["actions"]) for c, e in zip(cells, failures, strict=True)}
    found = open_loop_search(
        world,
        rounds=how["rounds"],
        per_round=how["per_round"],
        spec=spec,
        split="train",
        cells=cells,
        initial=initial,
    )
    solved = [c for c in cells if found.get(cell_name(c), {}).get("replayed") == "success"]
    if not solved:
        return [], [], {"cells": len(cells), "solved": 0}
    best = [found[cell_name(c)]["best_actions"] for c in solved]
    steps = max(len(b) for b in best)
    actions = np.zeros((len(solved), steps, 2), dtype=np.float32)
    for j, b in enumerate(best):
        actions[j, : len(b)] = b

    def sequences(start: int, part: Sequence[Cell]) -> TensorDictModule:
        seq = _Sequences(actions[start : start + len(part)])
        return TensorDictModule(seq, in_keys=["features"], out_keys=["action"])

    got, eps = _play_cells(world, solved, spec, sequences, 0.0, seed=0)
    return got, eps, {"cells": len(cells), "solved": len(solved)}


def recipe_digest(world: dict[str, Any], recipe: dict[str, Any], spec: dict[str, Any]) -> str:
    """What a cached dataset must match: the world, the recipe and the variations."""
    text = json.dumps({"world": world, "recipe": recipe, "spec": spec}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.paper.demos", __doc__)
    ap.add_argument("--pool", default="", help="scenario file (default: the paper pool)")
    ap.add_argument("--params", default="params/table2.json5", help="world parameters")
    ap.add_argument("--out", required=True, help="dataset directory (sharedspace.train.prior)")
    ap.add_argument(
        "--variation-spec",
        type=json.loads,
        default=TRAINING_VARIATIONS,
        metavar="JSON",
        help=f"the variations the scenes are played in; default {json.dumps(TRAINING_VARIATIONS)}",
    )
    ap.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="multiply every source's variations per scene (the paper pool's 59 train "
        "scenes want more than hbs-general's 229)",
    )
    ap.add_argument("--force", action="store_true", help="record anew even if cached")
    add_overrides_argument(ap, "world keys, e.g. max_agents=10")
    args = ap.parse_args(argv)
    world = WorldConfig.from_words(
        [f"scenario_pool={args.pool}", f"server_params={args.params}", *args.set]
    )
    recipe = {
        name: {**how, "variations": max(1, round(how["variations"] * args.scale))}
        if "variations" in how
        else dict(how)
        for name, how in RECIPE.items()
    }
    identity = world_of(world, {})
    digest = recipe_digest(identity, recipe, args.variation_spec)
    out = Path(args.out)
    if not args.force and (out / "header.json").is_file():
        header = read_header(out)
        if header.get("recipe_digest") == digest:
            print(f"{out}: cached ({header['transitions']} transitions, {header['created']})")
            return 0
    t0 = time.perf_counter()
    # No endpoint: the envs share this process's server of the pool and parameters.
    transitions, sources = record_demos(world, recipe, args.variation_spec)
    if out.exists():
        shutil.rmtree(out)
    command = "python -m sharedspace.paper.demos " + shlex.join(
        sys.argv[1:] if argv is None else argv
    )
    header = write_prior(out, transitions, identity, sources, command)
    header["recipe_digest"] = digest
    header["variation_spec"] = args.variation_spec
    header["minutes"] = round((time.perf_counter() - t0) / 60, 1)
    header["bytes"] = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    (out / "header.json").write_text(json.dumps(header, indent=1))
    print(
        f"{out}: {header['transitions']} transitions, {header['bytes'] / 2**20:.0f} MiB, "
        f"{header['minutes']} min"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
