"""Unit tests of the numpy reference against model.md's formulas (no Rust binary needed)."""

from __future__ import annotations

import json
import math

import crosscheck
import numpy as np
import pytest
import synthetic
from reference import (
    DEFAULT_PARAMS,
    ReferenceWorld,
    StepRefused,
    VarianceSchedule,
    disc_rect_gap,
    kl_isotropic,
    merge_params,
)

HBS = json.loads(crosscheck.POOL_PATH.read_text())


def test_variance_schedule_is_the_bayes_recurrence():
    s = VarianceSchedule(1.0, 0.3, 0.5)
    assert s.post[0] == 1.0
    s2 = 1.0
    for n in range(1, 6):
        prior = s2 + 0.09
        s2 = 1.0 / (1.0 / prior + 1.0 / 0.25)
        assert s.prior[n] == pytest.approx(prior, rel=1e-15)
        assert s.post[n] == pytest.approx(s2, rel=1e-15)
        # u for an exact prediction is the KL's constant part.
        assert s.kl_const[n] == pytest.approx(kl_isotropic([0, 0], prior, [0, 0], 0.25), rel=1e-14)
    assert s.post[-1] == s.post[-2]  # tabulated until it converges bit for bit


def test_kl_matches_model_md():
    mu_p, s2_p, mu_o, s2_o = np.array([1.0, 0.5]), 0.4, np.array([0.2, -0.1]), 0.25
    d2 = float(np.sum((mu_o - mu_p) ** 2))
    want = 0.5 * (2 * s2_p / s2_o + d2 / s2_o - 2 + 2 * math.log(s2_o / s2_p))
    assert kl_isotropic(mu_p, s2_p, mu_o, s2_o) == pytest.approx(want, rel=1e-15)


def test_disc_rect_gap():
    # Rectangle 4 x 1.8 at the origin heading +x; a disc of radius 0.3.
    gap, n = disc_rect_gap([5.0, 0.0], 0.3, [0.0, 0.0], 0.0, 4.0, 1.8)
    assert gap == pytest.approx(2.7) and np.allclose(n, [1.0, 0.0])
    gap, n = disc_rect_gap([0.0, 3.0], 0.3, [0.0, 0.0], math.pi / 2, 4.0, 1.8)
    assert gap == pytest.approx(3.0 - 2.0 - 0.3) and np.allclose(n, [0.0, 1.0])
    gap, n = disc_rect_gap([3.0, 4.0], 0.3, [0.0, 0.0], 0.0, 4.0, 1.8)  # corner region
    assert gap == pytest.approx(math.hypot(1.0, 3.1) - 0.3)
    assert np.allclose(n, np.array([1.0, 3.1]) / math.hypot(1.0, 3.1))
    gap, n = disc_rect_gap([1.5, 0.2], 0.3, [0.0, 0.0], 0.0, 4.0, 1.8)  # centre inside
    assert gap == pytest.approx(-0.5 - 0.3) and np.allclose(n, [1.0, 0.0])


def _scene(agents):
    return {"name": "t", "split": "train", "dt": 0.5, "ego": 0, "agents": agents}


def _rec(kind, pos, vel, n=10, start=0):
    p, v = synthetic._track(pos, lambda k: vel, n)
    return synthetic._agent(len(pos), kind, start, p, v)


def test_psi_is_model_md_virtual_distance():
    scen = _scene(
        [_rec("vehicle", (0.0, 0.0), (3.0, 0.0)), _rec("pedestrian", (8.0, 1.0), (-1.0, 0.5))]
    )
    w = ReferenceWorld(scen, external=[])
    p = DEFAULT_PARAMS["risk"]
    for i, j in ((0, 1), (1, 0)):
        d = w.clearance[i, j]
        vj, to_i = w.vel[j], w.pos[i] - w.pos[j]
        cos_phi = vj @ to_i / (np.linalg.norm(vj) * np.linalg.norm(to_i))
        k = -1.0 if vj @ to_i > 0 else 1.0
        dv = d * (1 + math.tanh(p["gamma1"] * k * (np.linalg.norm(vj) * abs(cos_phi) + 0.0)))
        assert w.psi[i, j] == pytest.approx(1 / (1 + p["gamma2"] * dv), rel=1e-13)
    assert w.u[0, 1] == 0.0 and w.A[0, 1] == w.psi[0, 1]  # first sight


def test_cv_pedestrian_is_capped_and_leaves_at_goal():
    scen = _scene(
        [
            _rec("vehicle", (-40.0, 0.0), (1.0, 0.0), n=20),
            _rec("pedestrian", (0.0, 0.0), (3.0, 0.0), n=4),
        ]
    )
    w = ReferenceWorld(scen, pedestrian_model="cv", external=[])
    out = w.step()
    assert np.allclose(w.velocities()[1], [2.0, 0.0])  # 3 m/s clipped to v_ped_max
    # Goal at x = 4.5: reached (within 0.5 m) at x = 4.0 after 4 steps.
    for _ in range(3):
        out = w.step()
    assert ("goal_reached", 1) in out["events"] and ("left", 1) in out["events"]
    assert 1 not in w.positions()


def test_external_vehicle_unicycle_and_refusals():
    scen = _scene(
        [
            _rec("vehicle", (0.0, 0.0), (2.0, 0.0), n=30),
            _rec("pedestrian", (30.0, 30.0), (0.0, 0.0)),
        ]
    )
    w = ReferenceWorld(scen, pedestrian_model="sfm")
    with pytest.raises(StepRefused):
        w.step({})
    with pytest.raises(StepRefused):
        w.step({0: (math.nan, 0.0)})
    with pytest.raises(StepRefused):
        w.step({1: (0.0, 0.0), 0: (0.0, 0.0)})
    out = w.step({0: (2.0, 1.0)})  # clipped to (1, 1): acc 2, omega 0.2
    assert out["agents"][0]["action_clipped"]
    speed, heading = 2.0 + 2.0 * 0.5, 0.2 * 0.5
    assert w.headings()[0] == pytest.approx(heading)
    assert np.allclose(
        w.positions()[0], [speed * math.cos(heading) * 0.5, speed * math.sin(heading) * 0.5]
    )
    assert out["agents"][0]["reward"]["comfort"] == pytest.approx(-0.5 * 0.2**2)


def test_merge_params_and_unknown_names():
    p = merge_params(DEFAULT_PARAMS, {"vehicle": {"shape": {"type": "disc", "radius": 1.0}}})
    assert p["vehicle"]["shape"] == {"type": "disc", "radius": 1.0}
    assert p["vehicle"]["acc_max"] == 2.0
    with pytest.raises(ValueError):
        ReferenceWorld(HBS["scenarios"][0], {"risk": {"gama1": 1.0}})


@pytest.mark.parametrize("model", ["cv", "sfm", "ra_sfm", "cr_sfm", "replay"])
def test_hbs_episode_runs_to_the_horizon(model):
    w = ReferenceWorld(HBS["scenarios"][3], pedestrian_model=model)
    steps = 0
    while not w.is_over:
        out = w.step({e: (0.2, 0.0) for e in w.active_externals()})
        steps += 1
        assert all(np.isfinite(v).all() for v in w.positions().values())
    assert steps <= w.horizon
    assert out["episode_over"] and out["agents"][0]["metrics"] is not None
