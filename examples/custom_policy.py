"""A driver of your own, scored beside the floor (`hold`) and the car-aware script.

    python examples/custom_policy.py                    # the paper task: 18 scenes x 128 variations
    python examples/custom_policy.py --variations 2     # a quick look (fewer variations: not the
                                                        # frozen task, so not a leaderboard row)

`cautious(obs)` maps one car's observation (the PettingZoo dict: `features` [M, 11] in the car's
own frame, x ahead; `mask` [M]) to its action `[acc, omega]` in [-1, 1]: it steers towards its
goal and brakes while a pedestrian is ahead of it within 6 m and 1.5 m to either side. The bench
plays it, `hold` and `car_aware` on the same episodes and prints each row with its intervals,
and the paired difference of `cautious` against `car_aware`.
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from sharedspace.bench import get_task, score
from sharedspace.bench.leaderboard import legend
from sharedspace.names import Feature


def cautious(obs: dict[str, np.ndarray]) -> list[float]:
    """Steer to the goal; brake for a pedestrian in the box ahead."""
    f, mask = obs["features"], obs["mask"].astype(bool)
    ego = f[0]
    heading_error = np.arctan2(ego[Feature.GOAL_DY], ego[Feature.GOAL_DX])
    others = f[1:][mask[1:]]
    pedestrians = others[others[:, Feature.IS_VEHICLE] < 0.5]
    ahead = (pedestrians[:, Feature.REL_X] > 0) & (pedestrians[:, Feature.REL_X] < 6.0)
    beside = np.abs(pedestrians[:, Feature.REL_Y]) < 1.5
    brake = bool(np.any(ahead & beside))
    speed = ego[Feature.SPEED]
    acc = -1.0 if brake else (0.5 if speed < 4.0 else 0.0)
    return [acc, float(np.clip(heading_error, -1.0, 1.0))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="paper", choices=("paper", "crowd"))
    ap.add_argument("--variations", type=int, default=0, help="fewer variations per scene")
    args = ap.parse_args()
    task = get_task(args.task)
    if args.variations:  # a smaller copy of the task, named so that nobody mistakes it
        task = dataclasses.replace(
            task,
            name=f"{task.name}-quick",
            version=0,
            variations=args.variations,
            description=f"{task.name}'s scenes x {args.variations} variation(s): a quick look",
        )
    script = score(task, "car_aware")
    rows = [score(task, "hold"), script, score(task, cautious, reference=script)]
    for row in rows:
        print(row.markdown())
    if not args.variations:
        print(legend(rows[0].task))


if __name__ == "__main__":
    main()
