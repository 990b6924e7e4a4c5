"""The calibration objectives (calibration/calibrate.py): the paper's and the collision-priced."""

from __future__ import annotations

import sys

import pytest
from conftest import REPO_ROOT

sys.path.insert(0, str(REPO_ROOT))
pytest.importorskip("bayes_opt")

from calibration.calibrate import describe, objective_of  # noqa: E402


def test_the_collision_objective_prices_the_collision_rate_in_metres():
    result = {"ade": 0.8, "fde": 0.3, "collision_rate": 0.25}
    assert objective_of(result, "ade_fde", 2.0) == pytest.approx(1.1)
    assert objective_of(result, "collisions", 2.0) == pytest.approx(1.6)
    assert objective_of(result, "collisions", 0.0) == objective_of(result, "ade_fde", 2.0)
    assert "2 m x collision rate" in describe("collisions", 2.0)
    assert describe("ade_fde", 2.0).startswith("ADE + FDE (m)")
