"""Table II machinery: the statistics, the scripted drivers and reachability, and the whole
`python -m sharedspace.paper.table2` over a tiny real run against a live server."""

from __future__ import annotations

import gzip
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from conftest import TINY_TRAIN  # noqa: E402

from sharedspace.names import Feature  # noqa: E402
from sharedspace.paper.drivers import (  # noqa: E402
    CarAwareDriver,
    PursuitDriver,
    VehicleLimits,
    reachability,
)
from sharedspace.paper.table2 import main as table2_main  # noqa: E402
from sharedspace.stats import paired_bootstrap, sign_test, wilson  # noqa: E402
from sharedspace.train.config import load_config  # noqa: E402
from sharedspace.train.train import train  # noqa: E402


def test_wilson_interval_matches_the_closed_form():
    lo, hi = wilson(17, 18)
    # p = 0.9444, n = 18, z = 1.96: the textbook Wilson interval is [0.742, 0.990]
    assert lo == pytest.approx(0.7424, abs=5e-4) and hi == pytest.approx(0.9901, abs=5e-4)
    assert wilson(0, 10)[0] == 0.0 and wilson(10, 10)[1] == pytest.approx(1.0)
    lo, hi = wilson(27, 54)
    assert lo < 0.5 < hi and hi - 0.5 == pytest.approx(0.5 - lo)


def test_sign_test_and_bootstrap():
    assert sign_test(0, 0) == 1.0
    assert sign_test(5, 0) == pytest.approx(2 / 32)  # two-sided, all five one way
    assert sign_test(3, 3) == 1.0
    lo, hi = paired_bootstrap([0.0] * 10)
    assert lo == hi == 0.0
    lo, hi = paired_bootstrap([1.0, -1.0] * 20)
    assert lo < 0.0 < hi


def _straight_scenario(length: float, speed: float, frames: int) -> dict:
    xs = np.linspace(0.0, length, frames)
    return {
        "name": "straight",
        "ego": 0,
        "dt": 0.5,
        "agents": [
            {
                "positions": [[x, 0.0] for x in xs],
                "velocities": [[speed, 0.0]] * frames,
            }
        ],
    }


def test_reachability_of_a_straight_goal_and_of_one_behind_a_tight_turn():
    [r] = reachability([_straight_scenario(30.0, 3.0, 21)])
    assert r["reachable"] and r["recorded_steps"] == 20 and r["horizon_steps"] == 50
    # at 6 m/s (accelerating from 3 at 2 m/s^2) 28 m take about 6 s = 12 steps
    assert r["earliest_arrival_steps"] <= 13
    # a goal 3 m to the side of a car at 6 m/s: the yaw-rate limit forbids the turn at speed,
    # the pursuit law slows down to make it, so it is still reachable within the horizon
    sc = _straight_scenario(30.0, 6.0, 21)
    sc["agents"][0]["positions"][-1] = [0.0, 8.0]
    [r] = reachability([sc])
    assert r["reachable"]


def test_pursuit_driver_steers_to_the_goal_and_brakes_for_a_pedestrian_ahead():
    limits = VehicleLimits()
    f = torch.zeros(2, 3, 11)
    mask = torch.tensor([[True, True, False], [True, True, False]])
    f[:, 0, 4] = 3.0  # speed
    f[:, 0, 8], f[:, 0, 9] = 20.0, 20.0  # goal ahead-left
    f[:, 0, 10] = math.hypot(20.0, 20.0)
    f[:, 1, 0], f[:, 1, 1] = 50.0, 0.0  # a pedestrian far ahead (sub-env 0)
    f[1, 1, 0] = 4.0  # close ahead (sub-env 1)
    action = PursuitDriver(cruise=5.0, limits=limits)(f, mask)
    assert action[0, 1] == pytest.approx(1.0)  # full left turn toward the goal
    assert action[0, 0] > 0  # speeding up toward 5 m/s
    assert action[1, 0] == pytest.approx(-1.0)  # full braking


def test_car_aware_driver_follows_the_first_agent_in_its_path_car_or_pedestrian():
    """Sub-envs: 0 nothing near; 1 a standing car 8 m ahead in the lane; 2 a car parked
    alongside (3 m to the right, parallel); 3 a pedestrian 6 m ahead, 4 m to the left, walking
    into the path at 2 m/s; 4 the same pedestrian walking away."""
    f = torch.zeros(5, 2, 11)
    mask = torch.ones(5, 2, dtype=torch.bool)
    f[:, 0, Feature.SPEED] = 3.0
    f[:, 0, Feature.GOAL_DX], f[:, 0, Feature.GOAL_DIST] = 40.0, 40.0  # goal straight ahead
    mask[0, 1] = False
    car = {Feature.IS_VEHICLE: 1.0, Feature.RADIUS: 2.19, Feature.REL_VX: -3.0}
    for k, (x, y) in ((1, (8.0, 0.0)), (2, (0.0, -3.0))):
        f[k, 1, Feature.REL_X], f[k, 1, Feature.REL_Y] = x, y
        for col, v in car.items():
            f[k, 1, col] = v
    for k, vy in ((3, -2.0), (4, 2.0)):
        f[k, 1, Feature.REL_X], f[k, 1, Feature.REL_Y] = 6.0, 4.0
        f[k, 1, Feature.REL_VX], f[k, 1, Feature.REL_VY] = -3.0, vy
        f[k, 1, Feature.RADIUS] = 0.3
    action = CarAwareDriver(cruise=3.5)(f, mask)
    assert action[0, 0] == pytest.approx(0.5)  # free road: (3.5 - 3) / dt / acc_max
    assert action[1, 0] == pytest.approx(-1.0)  # closing on a standing car: full braking
    assert action[2, 0] == pytest.approx(action[0, 0])  # a parked car alongside is not ahead
    assert action[3, 0] < -0.5  # a pedestrian crossing into the path
    assert action[4, 0] == pytest.approx(action[0, 0])  # one walking away is not
    assert torch.all(action[:, 1] == 0)  # the goal is straight ahead


def test_table2_over_a_tiny_real_run(sim_server, tmp_path):
    remote = [
        f"server_endpoint={sim_server.endpoint}",
        f"server_prefix={sim_server.prefix}",
    ]
    tiny = [
        *TINY_TRAIN,
        "eval_interval=64",
        "eval_split=test",  # the table2 command's curves (paper tooling)
        "checkpoint_interval=0",
        "total_frames=64",
    ]
    train(load_config(None, [*tiny, *remote, f"log_dir={tmp_path / 'runs' / 'g_sac_cog-s0'}"]))
    doc = tmp_path / "doc.md"
    doc.write_text("# x\n<!-- table2:begin -->\nSTALE-BLOCK\n<!-- table2:end -->\ntail\n")
    out = tmp_path / "table2.json"
    ship = tmp_path / "results" / "policies"
    args = ["--runs", str(tmp_path / "runs"), "--json", str(out), "--doc", str(doc)]
    search = ["--search-rounds", "2", "--search-per-round", "10"]
    assert table2_main([*args, *search, "--ship", str(ship), "--set", *remote]) == 0
    table = json.loads(out.read_text())
    stats = table["variants"]["g_sac_cog"]
    assert stats["seeds"] == [0] and stats["pooled_success"]["n"] == 18
    rates = sum(stats[f"pooled_{s}"]["rate"] for s in ("success", "collision", "timeout"))
    assert rates == pytest.approx(1.0)
    assert set(table["drivers"]) == {
        "hold",
        "stop",
        "pursuit_3",
        "pursuit_5",
        "car_aware",
        "human_replay",
    }
    assert table["human"]["success"] == 1.0
    assert len(table["reachability"]) == 18
    planner = table["planner"]
    assert len(planner) == 18 and all(r["candidates"] == 20 for r in planner.values())
    assert all(r["success"] + r["collision"] + r["timeout"] == 20 for r in planner.values())
    # Round 0 plays constant actions; in some scene one of them (or a later sample) arrives.
    solved = [r for r in planner.values() if r["success"]]
    assert solved and all(r["replayed"] == "success" for r in solved)
    assert all(len(r["best_actions"]) == r["best_steps"] for r in solved)
    train_success = table["generalisation"]["g_sac_cog"]["train"]["success"]["mean"]
    assert 0.0 <= train_success <= 1.0
    assert "64" in table["learning_curves"]["g_sac_cog"]
    terms = table["reward_terms"]["G-SAC-Cog"]
    assert {"progress", "danger", "success", "collision", "comfort"} <= set(terms)
    text = doc.read_text()
    assert "STALE-BLOCK" not in text and "G-SAC-Cog" in text and text.endswith("tail\n")
    assert (ship / "g_sac_cog-s0.pt").is_file() and (ship / "g_sac_cog-s0.json").is_file()
    record = tmp_path / "results" / "runs" / "g_sac_cog-s0"
    assert json.loads((record / "config.json").read_text())["network"] == "gcn_risk"
    assert len(json.loads((record / "eval_test.json").read_text())["episodes"]) == 18
    with gzip.open(record / "metrics.csv.gz", "rt") as f:
        assert f.readline() == "frames,wall_s,metric,value\n" and ",eval/success," in f.read()
