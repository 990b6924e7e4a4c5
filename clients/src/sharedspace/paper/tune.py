"""The car-aware script's parameters, chosen on the train split only.

    python -m sharedspace.paper.tune --pool out/table2g/pool-general.json \\
        --params params/table2g.json5 --set max_agents=10 \\
        --out results/table2g/car_aware_tuning.json

Every combination of :data:`GRID` drives every train scene in ``--variations`` seeded
variations (the training env's, :data:`sharedspace.paper.demos.TRAINING_VARIATIONS`; seeds
from 1000 on, apart from the demonstrations'); the highest success wins, the lower collision
share breaks ties. The test split is never played. The winner is what
:data:`sharedspace.paper.drivers.DRIVERS` ``["car_aware"]`` holds (docs/RESULTS.md).
"""

from __future__ import annotations

import itertools
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tensordict.nn import TensorDictModule

from sharedspace.cli import run_command
from sharedspace.episodes import summarize
from sharedspace.paper.demos import TRAINING_VARIATIONS
from sharedspace.paper.drivers import CarAwareDriver
from sharedspace.train.config import add_overrides_argument, command_parser
from sharedspace.train.evaluation import play_variations
from sharedspace.world_config import WorldConfig

__all__ = ["GRID", "tune_car_aware", "main"]

#: The parameters tried (CarAwareDriver's arguments), every combination.
GRID: dict[str, Sequence[float]] = {
    "cruise": (3.5, 4.5),
    "headway": (0.5, 1.0, 1.5),
    "min_gap": (1.5, 2.5, 3.5),
    "margin": (0.0, 0.2),
    "lookahead": (2.0, 4.0),
}


def tune_car_aware(
    world: WorldConfig,
    variations: int = 2,
    grid: dict[str, Sequence[float]] = GRID,
    log=print,
) -> list[dict[str, Any]]:
    """Every combination of ``grid`` on the train split of ``world``, best first: its
    parameters and summary (success, collision, timeout, metrics)."""
    rows = []
    for values in itertools.product(*grid.values()):
        params = dict(zip(grid, values, strict=True))
        policy = TensorDictModule(
            CarAwareDriver(**params), in_keys=["features", "mask"], out_keys=["action"]
        )
        episodes = play_variations(world, policy, variations, "train", TRAINING_VARIATIONS, 1000)
        rows.append({"params": params, **summarize(episodes)})
        log(json.dumps(rows[-1]))
    return sorted(rows, key=lambda r: (-r["success"], r["collision"]))


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.paper.tune", __doc__)
    ap.add_argument("--pool", default="", help="scenario file (default: the paper pool)")
    ap.add_argument("--params", default="params/table2.json5", help="world parameters")
    ap.add_argument("--variations", type=int, default=2, help="seeded variations per scene")
    ap.add_argument("--out", default="", help="write every row here (JSON)")
    add_overrides_argument(ap, "world keys, e.g. max_agents=10")
    args = ap.parse_args(argv)
    t0 = time.time()
    # No endpoint: the envs share this process's server of the pool and parameters.
    sets = [f"scenario_pool={args.pool}", f"server_params={args.params}", *args.set]
    rows = tune_car_aware(WorldConfig.from_words(sets), args.variations)
    result = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "split": "train",
        "variations": args.variations,
        "variation_spec": TRAINING_VARIATIONS,
        "grid": GRID,
        "best": rows[0],
        "rows": rows,
        "minutes": round((time.time() - t0) / 60, 1),
    }
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1))
    print(f"best on the train split: {json.dumps(rows[0])}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
