"""The benchmark (``sharedspace.bench``) against a live server: a policy from outside enters
with no trainer loaded, every form of a policy scores the same episodes the same way, bad input
is refused before any episode is played, results compare only within a task version, and the
frozen tasks still hold the scenes and worlds they were frozen with."""

from __future__ import annotations

import dataclasses
import inspect
import json
import os
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tensordict.nn import TensorDictModule  # noqa: E402

from sharedspace.bench import TASKS, BenchError, get_task, load_result, score  # noqa: E402
from sharedspace.bench.__main__ import main as bench_main  # noqa: E402
from sharedspace.bench.policies import _read_params  # noqa: E402
from sharedspace.marl.task import CrossingTask  # noqa: E402
from sharedspace.scripted import SCRIPTED  # noqa: E402

#: The paper's 18 test scenes in 2 seeded variations: a task small enough for a debug server.
SMALL = dataclasses.replace(TASKS["paper"], name="paper-small", variations=2)
#: The crossing task on 3 of its test scenes.
SMALL_CROSSING = dataclasses.replace(
    TASKS["crossing"], name="crossing-small", crossing=CrossingTask(test_scenes=3)
)


def brake_near(obs):
    """A policy from outside: brake while anyone is within 5 m ahead, else accelerate gently."""
    f, m = obs["features"], obs["mask"].astype(bool)
    ahead = (f[1:, 0] > 0) & (np.hypot(f[1:, 0], f[1:, 1]) < 5.0) & m[1:]
    return np.array([-1.0 if ahead.any() else 0.3, 0.0], dtype=np.float32)


def test_a_plain_function_is_scored_with_no_trainer_imported(tmp_path):
    script = "\n".join(
        [
            "import dataclasses, json, sys",
            "import numpy as np",
            "from sharedspace.bench import TASKS, score",
            inspect.getsource(brake_near),
            'task = dataclasses.replace(TASKS["paper"], name="paper-small", variations=2)',
            'result = score(task, brake_near, name="brake_near")',
            'script = score(task, "car_aware")',
            'loaded = sorted(m for m in sys.modules if m.startswith("sharedspace."))',
            'torch = sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "tensordict"))',
            'out = {"summary": result.summary, "script": script.summary["episodes"]}',
            'print(json.dumps({**out, "loaded": loaded, "torch": torch}))',
        ]
    )
    out = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        env=os.environ.copy(),
        check=True,
    )
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["summary"]["episodes"] == 36
    assert sum(got["summary"][s]["count"] for s in ("success", "collision", "timeout")) == 36
    assert not [m for m in got["loaded"] if m.startswith("sharedspace.train")], got["loaded"]
    assert got["script"] == 36
    assert got["torch"] == [], "a NumPy function and a scripted driver are played without torch"


def test_the_numpy_loop_plays_the_episodes_of_the_torchrl_loop(tmp_path):
    """The bench's torch-free loop (:func:`sharedspace.rollout.play_first_episodes`) and the
    TorchRL env's (:func:`sharedspace.episodes.run_episodes`, the trainers' evaluation) give
    every episode the same outcome, length, return and metrics (the TorchRL env keeps the
    metrics in float32, the NumPy loop as the server sends them)."""
    from sharedspace.bench.scoring import _connection, _single_car_spec
    from sharedspace.episodes import run_episodes, variation_batches
    from sharedspace.torchrl_env import RemoteBatchedEnv

    script = SCRIPTED["car_aware"]()
    driver = TensorDictModule(script, in_keys=["features", "mask"], out_keys=["action"])
    bench = {(e["scene"], e["unit"]): e for e in score(SMALL, "car_aware").episodes}
    scenes = [s["name"] for s in SMALL.check_scenes()]
    client = _connection(SMALL, "", tmp_path).open()  # the task's pool and world
    played = {}
    try:
        for seeds in variation_batches(len(scenes), SMALL.variations):
            env = RemoteBatchedEnv(
                _single_car_spec(SMALL),
                len(seeds),
                scenario_order="sequential",
                variation_seeds=seeds,
                client=client,
            )
            try:
                for e in run_episodes(env, driver):
                    played[(env.scenario_names[e["scenario_index"]], e["variation"])] = e
            finally:
                env.close()
    finally:
        client.shutdown()
    assert len(bench) == len(played) == 36
    for key, e in bench.items():
        torchrl = played[key]
        assert (e["status"], e["steps"]) == (torchrl["status"], torchrl["steps"]), key
        assert e["return"] == pytest.approx(torchrl["return"], rel=1e-12, abs=1e-12), key
        for metric in ("avg_speed", "avg_abs_jerk", "max_abs_acc"):
            assert e[metric] == pytest.approx(torchrl[metric], rel=1e-6, abs=1e-7), (key, metric)


def test_every_form_of_one_driver_plays_the_same_episodes():
    """car_aware by name, as a TorchRL module and as a function over the PettingZoo observation:
    one policy, so the same outcome in every episode."""
    driver = SCRIPTED["car_aware"]()
    module = TensorDictModule(driver, in_keys=["features", "mask"], out_keys=["action"])

    def as_function(obs):
        f = torch.as_tensor(obs["features"])[None]
        m = torch.as_tensor(obs["mask"].astype(bool))[None]
        return driver(f, m)[0].numpy()

    rows = [score(SMALL, p) for p in ("car_aware", module, as_function)]
    keyed = [{(e["scene"], e["unit"]): e["status"] for e in r.episodes} for r in rows]
    assert len(keyed[0]) == 36 and keyed[0] == keyed[1] == keyed[2]
    assert {e["unit"] for e in rows[0].episodes} == {0, 1}, "variations 0 and 1 of every scene"


def test_bad_input_is_refused_before_any_episode_is_played(tmp_path):
    calls = []

    def three_numbers(obs):
        calls.append(1)
        return np.zeros(3, dtype=np.float32)

    with pytest.raises(BenchError, match="unknown task 'crowds'"):
        score("crowds", "car_aware")
    with pytest.raises(BenchError, match=r"shape \(3,\)"):
        score(SMALL, three_numbers)
    assert len(calls) == 1, "only the probe's one observation reached the policy"
    with pytest.raises(BenchError, match="not finite"):
        score(SMALL, lambda obs: np.array([np.nan, 0.0]))
    with pytest.raises(BenchError, match="not a scripted driver"):
        score(SMALL, "car_awar")

    other_world = tmp_path / "other.pt"
    torch.save(
        {
            "actor": {},
            "algorithm": "ppo",
            "config": {"algorithm": "ppo", "max_agents": 10},
            "world": {"max_agents": 10, "server_params": "params/table2g.json5"},
        },
        other_world,
    )
    with pytest.raises(BenchError, match="another world.*max_agents 10, the task's 8"):
        score(SMALL, str(other_world))

    old = score(SMALL, "hold")
    stale = dataclasses.replace(old, task={**old.task, "version": 0})
    with pytest.raises(BenchError, match="not of paper-small@1"):
        score(SMALL, "car_aware", reference=stale)
    assert bench_main(["crowds", "--policy", "car_aware"]) == 2


def test_a_result_pairs_with_a_reference_of_its_task(tmp_path):
    ref = score(SMALL, "pursuit_3")
    path = tmp_path / "ref.json"
    path.write_text(json.dumps(ref.to_json()))
    again = score(SMALL, "pursuit_3", reference=path)
    c = again.comparison
    assert c["diff"] == 0.0 and c["lo"] == 0.0 and c["hi"] == 0.0 and c["pairs"] == 36
    assert "lo_fixed" in c, "the paper's tasks also hold the scenes fixed"
    better = score(SMALL, "car_aware", reference=ref)
    mine, theirs = better.summary["success"]["rate"], ref.summary["success"]["rate"]
    assert better.comparison["diff"] == pytest.approx(mine - theirs)
    assert "Paired success difference, car_aware − pursuit_3" in better.markdown()
    assert load_result(path).episodes == ref.episodes


def test_seeds_pool_into_one_row():
    pooled = score(SMALL, ["car_aware", "hold"], name="two")
    assert pooled.summary["episodes"] == 72 and pooled.policy == "two"
    assert {e["policy"] for e in pooled.episodes} == {0, 1}
    one, other = score(SMALL, "car_aware"), score(SMALL, "hold")
    expected = {
        k: (v + other.success_by_episode()[k]) / 2 for k, v in one.success_by_episode().items()
    }
    assert pooled.success_by_episode() == expected


def test_the_crossing_task_scores_every_car():
    result = score(SMALL_CROSSING, brake_near)
    assert result.summary["episodes"] == 3 * 4
    assert {e["unit"] for e in result.episodes} == {0, 1, 2, 3}
    scripted = score(SMALL_CROSSING, "car_aware", reference=score(SMALL_CROSSING, "car_aware"))
    assert scripted.comparison["diff"] == 0.0


def test_the_frozen_tasks_keep_their_scenes_worlds_and_versions():
    """A task changes only with a new version: its fingerprint is committed here."""
    assert {t.tag: t.fingerprint() for t in TASKS.values()} == {
        "paper@1": "6980e1352c852b61",
        "crowd@1": "a5fb92d7a56c6916",
        "crossing@1": "05534396a44be26b",
    }
    assert len(TASKS["paper"].check_scenes()) == 18
    assert TASKS["paper"].world_params == _read_params("params/table2.json5")
    assert TASKS["crowd"].world_params == _read_params("params/table2g.json5")
    assert get_task("crowd@1") is TASKS["crowd"]
    with pytest.raises(BenchError, match="version 1, not 2"):
        get_task("crowd@2")


def test_the_crowd_task_holds_the_extracted_general_pool():
    """The pool file is extracted from the committed recordings (`make test` makes it)."""
    assert len(TASKS["crowd"].check_scenes()) == 76


def test_a_leaderboard_ranks_the_rows_and_pairs_them_with_the_script(tmp_path):
    from sharedspace.bench.leaderboard import main as leaderboard_main

    for driver in ("car_aware", "hold"):
        result = score(SMALL, driver)
        (tmp_path / f"{driver}.json").write_text(json.dumps(result.to_json()))
    (tmp_path / "runs.json").write_text("{}")  # not a result: passed over
    out = tmp_path / "LEADERBOARD.md"
    assert leaderboard_main([str(tmp_path), "--out", str(out)]) == 0
    lines = [line for line in out.read_text().splitlines() if line.startswith("| ")]
    assert [line.split(" | ")[0] for line in lines[1:]] == ["| car_aware", "| hold"]
    assert lines[2].count("[") == 3, "hold's success interval, and both paired intervals"


def _checkpoint(tmp_path, name: str, **fields) -> str:
    path = tmp_path / f"{name}.pt"
    torch.save({"actor": {}, **fields}, path)
    return str(path)


def test_every_policy_the_bench_cannot_play_is_named_before_a_server_starts(tmp_path):
    """Each refusal of make_policy and score: the spec, the file, the world, the task kind."""
    bad = [
        (42, "give a driver name, a checkpoint, a callable or a module"),
        ([], "no policy to score"),
        ("no_such_module_x:act", "cannot import it"),
        (str(tmp_path / "gone.pt"), "no such checkpoint"),
        (_checkpoint(tmp_path, "junk"), "is not a sharedspace checkpoint"),
        (
            _checkpoint(tmp_path, "cars", algorithm="mappo", config={"algorithm": "mappo"}),
            "a multi-car checkpoint \\(mappo\\), task paper-small@1 has one car",
        ),
        (
            _checkpoint(
                tmp_path,
                "crowd",
                algorithm="ppo",
                config={"algorithm": "ppo"},
                world={"max_agents": 8, "server_params": "params/table2g.json5"},
            ),
            "world parameters of params/table2g.json5 differ",
        ),
        (
            _checkpoint(
                tmp_path,
                "paperpool",
                algorithm="ppo",
                config={"algorithm": "ppo"},
                world={
                    "max_agents": 8,
                    "server_params": "params/table2.json5",
                    "scenario_pool": "out/table2g/pool-general.json",
                },
            ),
            "pool out/table2g/pool-general.json, whose test scenes are not the task's",
        ),
    ]
    # the refusals that need a task of another kind than SMALL
    bad_for_task = [
        (
            "crowd",
            _checkpoint(
                tmp_path,
                "default",
                algorithm="ppo",
                config={"algorithm": "ppo"},
                world={
                    "max_agents": 10,
                    "server_params": "params/table2g.json5",
                    "scenario_pool": "",
                },
            ),
            "pool default, whose test scenes are not the task's",
        ),
        (
            SMALL_CROSSING,
            _checkpoint(tmp_path, "one", algorithm="ppo", config={"algorithm": "ppo"}),
            "a single-car checkpoint \\(ppo\\); task crossing-small@1 has 4 cars",
        ),
        (
            SMALL_CROSSING,
            _checkpoint(
                tmp_path,
                "three",
                algorithm="mappo",
                config={"algorithm": "mappo"},
                world={"task": {**vars(CrossingTask()), "cars": 3}},
            ),
            "another crossing task \\(differs in cars, test_scenes\\)",
        ),
    ]
    for task, spec, message in [(SMALL, spec, message) for spec, message in bad] + bad_for_task:
        with pytest.raises(BenchError, match=message):
            score(task, spec)


def test_a_policy_that_fails_or_writes_nothing_is_stopped_at_the_probe(tmp_path):
    def broken(obs):
        raise ZeroDivisionError("my bug")

    with pytest.raises(BenchError, match="failed on the task's observation: ZeroDivisionError"):
        score(SMALL, broken)
    writes_elsewhere = TensorDictModule(
        lambda features: features[..., 0, :2], in_keys=["features"], out_keys=["not_action"]
    )
    with pytest.raises(BenchError, match="wrote no 'action'"):
        score(SMALL, writes_elsewhere)
    junk = tmp_path / "junk.json"
    junk.write_text("{}")
    with pytest.raises(BenchError, match="not a benchmark result"):
        score(SMALL, "hold", reference=junk)


def test_a_task_whose_pool_is_missing_or_changed_is_refused():
    missing = dataclasses.replace(SMALL, pool="out/nowhere/pool.json", pool_hint="make it so")
    with pytest.raises(BenchError, match="missing: make it so"):
        score(missing, "hold")
    changed = dataclasses.replace(SMALL, scenes_sha256="0" * 64)
    with pytest.raises(BenchError, match="the pool changed, so the task needs a new version"):
        score(changed, "hold")


def test_a_run_is_stable_when_its_last_three_scorings_agree_over_a_million_frames(tmp_path):
    from sharedspace.arms.rows import stability

    def run(name, scorings):
        folder = tmp_path / name
        folder.mkdir()
        lines = [f"{f},1.0,train/success,0.5" for f, _ in scorings]
        for frames, success in scorings:
            lines += [f"{frames},2.0,eval/success,{success}", f"{frames},2.0,eval/episodes,960"]
        (folder / "metrics.csv").write_text("\n".join(lines) + "\n")
        return stability(folder)

    m = 524_288
    steady = run("steady", [(m, 0.5), (4 * m, 0.80), (5 * m, 0.82), (6 * m, 0.81)])
    assert steady["stable"] and steady["success"] == [0.80, 0.82, 0.81]
    assert steady["episodes"] == [960] * 3 and steady["range"] == 0.02
    assert not run("swings", [(4 * m, 0.80), (5 * m, 0.72), (6 * m, 0.75)])["stable"]
    assert not run("short span", [(4 * m, 0.80), (4 * m + 8192, 0.80), (5 * m, 0.80)])["stable"]
    off = run("last off", [(4 * m, 0.80), (5 * m, 0.80), (6 * m, 0.848)])  # range 0.048
    assert off["range"] <= 0.05 and off["last_minus_mean"] > 0.03 and not off["stable"]
    assert not run("too few", [(5 * m, 0.80), (6 * m, 0.80)])["stable"]


def test_the_numpy_loop_refuses_a_mismatch_by_name(tmp_path):
    """``play_first_episodes``: variations that do not match the scenes, and a policy whose
    actions are not ``[K, 2]``, are refused with what was wrong."""
    from sharedspace.bench.scoring import _connection, _single_car_spec
    from sharedspace.rollout import play_first_episodes

    scenes = [s["name"] for s in SMALL.check_scenes()[:2]]
    hold = lambda obs: np.zeros((len(obs["features"]), 2), dtype=np.float32)  # noqa: E731
    client = _connection(SMALL, "", tmp_path).open()
    try:
        spec = _single_car_spec(SMALL)
        with pytest.raises(ValueError, match="1 variations for 2 scenes"):
            play_first_episodes(client, spec, hold, scenes, [0])
        with pytest.raises(ValueError, match=r"actions of shape \(2, 3\), wanted \(2, 2\)"):
            play_first_episodes(client, spec, lambda obs: np.zeros((2, 3)), scenes, [0, 0])
        played = play_first_episodes(client, spec, hold, scenes, [0, 1])
        assert [(e["scene"], e["variation"]) for e in played] == [(scenes[0], 0), (scenes[1], 1)]
    finally:
        client.shutdown()
