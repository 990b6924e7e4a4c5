"""Cross-check of the numpy reference (the numpy oracle (tests/reference.py)) against the Rust core.

For each case the release ``sim-server rollout`` writes every step of an episode as JSON lines
(docs/ROLLOUT.md); ReferenceWorld replays the same set-up (same scenario, the parameters from the
rollout header, same pedestrian model, same AV drive) and every step is compared: positions to
1e-6 m, velocities and headings to 1e-9, the risk graph (edge set, psi, u, A) to 1e-9, events and
reward terms. Skipped (with the reason) only when the binary has not been built:
``cargo build --release -p sim-server`` (the Makefile builds it before the tests).
Set ``SHAREDSPACE_CROSSCHECK_ALL=1`` to run every scenario of the HBS pool instead of a sample.
"""

from __future__ import annotations

import json
import os

import crosscheck
import pytest
import synthetic

MODELS = ("cv", "sfm", "ra_sfm", "cr_sfm", "replay")
AV_DRIVES = ("replay", "0.3,0.1")

POS_TOL = 1e-6
VEL_TOL = 1e-9
EDGE_TOL = 1e-9
REWARD_TOL = 1e-9

BINARY = crosscheck.server_binary()
needs_binary = pytest.mark.skipif(
    BINARY is None,
    reason=f"{crosscheck.REPO_ROOT / 'target/release/sim-server'} is missing: build it with "
    "`cargo build --release -p sim-server` to run the reference cross-check",
)

HBS = json.loads(crosscheck.POOL_PATH.read_text())
if os.environ.get("SHAREDSPACE_CROSSCHECK_ALL"):
    HBS_CASES = list(range(len(HBS["scenarios"])))
else:  # a spread over the pool, both splits
    HBS_CASES = sorted({0, 5, 11, 19, 28, 37, 46, 55, 63, 70, len(HBS["scenarios"]) - 1})


def _check(cmp: crosscheck.Comparison, what: str):
    assert not cmp.problems, f"{what}: " + "; ".join(cmp.problems)
    assert cmp.steps > 0, f"{what}: no step compared"
    assert cmp.max_pos <= POS_TOL, f"{what}: position error {cmp.max_pos:.3e} m"
    assert cmp.max_vel <= VEL_TOL, f"{what}: velocity error {cmp.max_vel:.3e}"
    assert cmp.max_heading <= VEL_TOL, f"{what}: heading error {cmp.max_heading:.3e}"
    assert cmp.max_psi <= EDGE_TOL, f"{what}: psi error {cmp.max_psi:.3e}"
    assert cmp.max_u <= EDGE_TOL, f"{what}: u error {cmp.max_u:.3e}"
    assert cmp.max_a <= EDGE_TOL, f"{what}: A error {cmp.max_a:.3e}"
    assert cmp.max_reward <= REWARD_TOL, f"{what}: reward error {cmp.max_reward:.3e}"


@needs_binary
@pytest.mark.parametrize("av", AV_DRIVES)
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("index", HBS_CASES)
def test_hbs_scenario(tmp_path, index, model, av):
    lines = crosscheck.run_rollout(BINARY, tmp_path / "r.jsonl", str(index), model, av)
    scenario = HBS["scenarios"][index]
    assert lines[0]["scenario"] == scenario["name"]
    cmp = crosscheck.compare_rollout(lines, scenario)
    crosscheck.record("hbs", model, cmp)
    _check(cmp, f"{scenario['name']} model={model} av={av}")


PARAM_SETS = {
    "default": None,
    # Constant-acceleration internal prediction (model.md 3).
    "ca": "{cognition: {prediction: 'constant_acceleration'}}",
    # Everything off its default: disc AV, short perception radius (beliefs lost and re-made),
    # CA prediction, other gains and social-force parameters, shorter horizon.
    "mixed": """{
        perception_radius: 8.0,
        vehicle: {shape: {type: 'disc', radius: 1.2}, goal_radius: 3.0, acc_max: 1.5},
        cognition: {prediction: 'constant_acceleration', s0: 0.7, q: 0.2, s_o: 0.6},
        risk: {gamma1: 0.8, gamma2: 1.5, lambda: 0.5},
        pedestrians: {cr_sfm: {lambda1: 2.0, lambda2: 0.5, lambda3: 1.5, tau: 0.7},
                      ra_sfm: {a_veh: 6.0, b_ped: 0.5}, sfm: {a_ped: 3.0}},
        ped_goal_radius: 0.8, ped_speed_max: 1.8, horizon_extra: 5.0,
    }""",
}
SYNTHETIC = [
    synthetic.crossing_scene(),
    synthetic.random_scene(1),
    synthetic.random_scene(2, 20, 20.0),
]


@pytest.fixture(scope="module")
def synthetic_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("synthetic")
    pool = d / "pool.json"
    pool.write_text(json.dumps(synthetic.pool(SYNTHETIC)))
    params = {}
    for name, text in PARAM_SETS.items():
        if text is not None:
            params[name] = d / f"{name}.json5"
            params[name].write_text(text)
    return pool, params


@needs_binary
@pytest.mark.parametrize("params", list(PARAM_SETS))
@pytest.mark.parametrize("av", ("replay", "0.3,0.05", "-0.5,-1"))
@pytest.mark.parametrize("model", MODELS)
@pytest.mark.parametrize("index", range(len(SYNTHETIC)))
def test_synthetic_scene(tmp_path, synthetic_files, index, model, av, params):
    pool, param_files = synthetic_files
    lines = crosscheck.run_rollout(
        BINARY,
        tmp_path / "r.jsonl",
        str(index),
        model,
        av,
        pool=pool,
        params=param_files.get(params),
    )
    header = lines[0]
    if params == "ca":
        assert header["params"]["cognition"]["prediction"] == "constant_acceleration"
    cmp = crosscheck.compare_rollout(lines, SYNTHETIC[index])
    crosscheck.record(f"syn-{params}", model, cmp)
    _check(cmp, f"{SYNTHETIC[index]['name']} model={model} av={av} params={params}")


@needs_binary
def test_synthetic_scenes_exercise_the_rare_paths(tmp_path, synthetic_files):
    """The synthetic scenes do produce what they are for: entries, departures, collisions."""
    pool, _ = synthetic_files
    seen = set()
    for index in range(len(SYNTHETIC)):
        for av in ("replay", "0.3,0.05"):
            lines = crosscheck.run_rollout(
                BINARY, tmp_path / "r.jsonl", str(index), "cr_sfm", av, pool=pool
            )
            for line in lines[1:-1]:
                seen.update(e["event"] for e in line["events"])
    assert {"entered", "left", "goal_reached", "collision"} <= seen
