"""The adversarial stress test (issue 60, docs/MODEL.md 2c) against a live server: the
adversary is held to the walking range, an adversary standing in the path of a driver who does
not brake is hit at the driver's fault, one walking into the car's side is to blame, and an
adversary trains (the real TorchRL loop, tiny) and is scored against a driver."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torchrl")

from sharedspace.adversary.env import AdversaryEnv  # noqa: E402
from sharedspace.adversary.task import (  # noqa: E402
    WALKING_RANGE,
    AdversaryTask,
    adversary_pool,
    plausible_action,
)
from sharedspace.adversary.train import serve_task  # noqa: E402
from sharedspace.bench.tasks import scenes_fingerprint  # noqa: E402


def record(kind, rid, p0, v, n=40):
    """A straight recorded track from ``p0`` at velocity ``v``, ``n`` steps of 0.5 s."""
    pos = [[p0[0] + v[0] * 0.5 * t, p0[1] + v[1] * 0.5 * t] for t in range(n)]
    return {
        "record_id": rid,
        "kind": kind,
        "start_step": 0,
        "positions": pos,
        "velocities": [list(v)] * n,
        "non_reactive": False,
    }


def scene(name, car_v, ped, ped_v, split="test"):
    agents = [
        record("vehicle", 0, [0.0, 0.0], car_v),
        record("pedestrian", 2, [40.0, 30.0], [0.0, 0.5]),  # far away
        record("pedestrian", 1, ped, ped_v),
    ]
    return {"name": name, "split": split, "dt": 0.5, "ego": 0, "agents": agents}


def make_task(folder: Path) -> AdversaryTask:
    """``crowd-adversary`` over a hand-made pool: a pedestrian standing 20 m ahead of a car at
    4 m/s, one walking into the side of a car at 1 m/s, and one standing 3 m beside the path of a
    car at 4 m/s, 30 m ahead of it."""
    pool = adversary_pool(
        {
            "version": 1,
            "name": "adversary-test",
            "provenance": "tests",
            "vehicle_model": "replay",
            "scenarios": [
                scene("in-the-path", [4.0, 0.0], [20.0, 0.0], [0.0, 0.05]),
                scene("into-the-side", [1.0, 0.0], [1.0, -3.0], [0.0, 1.5]),
                scene("off-the-path", [4.0, 0.0], [30.0, 3.0], [0.0, 0.05]),
                scene("train-0", [4.0, 0.0], [20.0, 0.0], [0.0, 0.05], split="train"),
            ],
        }
    )
    path = folder / "pool.json"
    path.write_text(json.dumps(pool))
    tests = [s for s in pool["scenarios"] if s["split"] == "test"]
    return AdversaryTask(
        "adversary-test", 1, "tests", "crowd", str(path), scenes_fingerprint(tests)
    )


def test_the_adversary_is_the_pedestrian_nearest_the_cars_path_and_comes_first():
    pool = adversary_pool(
        {"name": "p", "scenarios": [scene("s", [4.0, 0.0], [20.0, 1.0], [0.0, 0.05])]}
    )
    agents = pool["scenarios"][0]["agents"]
    assert [a["record_id"] for a in agents] == [0, 1, 2]  # the near one is pedestrian_0
    assert pool["scenarios"][0]["ego"] == 0


def test_plausible_actions_stay_in_the_walking_range():
    rng = np.random.default_rng(0)
    action = rng.uniform(-3, 3, size=(4000, 2))
    speed = rng.uniform(0, WALKING_RANGE["speed_max"], size=4000)
    dt, server_acc = 0.5, 2.0
    sent = plausible_action(action, speed, dt, server_acc, WALKING_RANGE)
    assert np.all(np.abs(sent) <= 1.0)
    acc = sent.astype(np.float64) * server_acc  # the server's acceleration (model.md 2b)
    v_new = np.stack([speed, np.zeros_like(speed)], 1) + acc * dt
    assert np.linalg.norm(acc, axis=1).max() <= WALKING_RANGE["acc_max"] + 1e-5
    assert np.linalg.norm(v_new, axis=1).max() <= WALKING_RANGE["speed_max"] + 1e-5


def play(task, client, scene_name, command):
    """One episode of ``scene_name`` in variation 0, the driver holding its speed and heading,
    the adversary commanding ``command`` (a fixed ``[2]``, or a module that writes ``action``):
    the env's record and the adversary's rewards."""
    import torch

    env = AdversaryEnv(
        lambda obs: np.zeros(2),
        task,
        1,
        split="test",
        scenarios=[scene_name],
        variation_seeds=[0],
        until="driver",
        client=client,
    )
    try:
        td = env.reset()
        rewards = []
        for _ in range(200):
            if callable(command):
                td = command(td)
            else:
                td["action"] = torch.tensor([command], dtype=torch.float32)
            out = env.step(td)
            rewards.append(dict(env.last_reward_terms))
            if out["next", "done"].all():
                return env.finished[0], rewards, out["next"]
            td = out["next"]
        raise AssertionError("the episode never ended")
    finally:
        env.close()


def test_a_driver_who_drives_into_an_adversary_in_its_path_is_at_fault(sim_server):
    with tempfile.TemporaryDirectory() as tmp:
        task = make_task(Path(tmp))
        client = serve_task(task, Path(tmp)).open()
        try:
            rec, rewards, last = play(task, client, "in-the-path", [0.0, 0.0])
            assert rec["driver"] == "collision" and rec["fault"] and not rec["blame"]
            assert rewards[-1]["fault"][0] == task.reward["fault"]
            assert bool(last["episode_success"].item())  # the adversary's success

            rec, rewards, last = play(task, client, "into-the-side", [1.0, 0.0])
            assert rec["driver"] == "collision" and not rec["fault"] and rec["blame"]
            assert rewards[-1]["blame"][0] == task.reward["blame"]
            assert bool(last["episode_collision"].item())
        finally:
            client.shutdown()


def test_the_intercepting_adversary_walks_into_the_path_of_a_car_that_does_not_brake(
    sim_server,
):
    from sharedspace.adversary.scripted import Intercept

    with tempfile.TemporaryDirectory() as tmp:
        task = make_task(Path(tmp))
        client = serve_task(task, Path(tmp)).open()
        try:
            jaywalker = Intercept(task.walking_range)
            rec, rewards, last = play(task, client, "off-the-path", jaywalker)
            # it steps into the path with room for the car to stop: the car's fault
            assert rec["driver"] == "collision" and rec["fault"] and not rec["blame"]
            assert bool(last["episode_success"].item())
            # standing still it is never in the path, and the car drives past
            rec, _, _ = play(task, client, "off-the-path", [0.0, 0.0])
            assert rec["driver"] != "collision" and not rec["fault"]
        finally:
            client.shutdown()


def test_an_adversary_trains_and_a_driver_is_scored_against_it(sim_server, tmp_path):
    from sharedspace.adversary.stress import stress_row
    from sharedspace.adversary.table import stress_markdown
    from sharedspace.adversary.train import train

    task = make_task(tmp_path)
    run = tmp_path / "run"
    out = train(
        "car_aware",
        run,
        512,
        [
            "num_envs=4",
            "rollout_steps=16",
            "minibatch_size=64",
            "eval_interval=0",
            "progress=false",
        ],
        task,
    )
    assert out["counters"]["frames"] >= 512
    ckpt = run / "checkpoints" / "last.pt"
    assert ckpt.is_file()
    adversaries = {"CR-SFM": None, "own": ckpt, "jaywalker": "intercept"}
    result = stress_row(["car_aware"], adversaries, task, "car_aware")
    table = stress_markdown(result)
    for label in ("CR-SFM", "own", "jaywalker"):
        assert result["conditions"][label]["summary"]["episodes"] == 3 * 4  # scenes x variations
        assert f"| {label} |" in table
    assert "drop" in result["conditions"]["own"]

    # two drivers compared on the pedestrians both met, matched by what they are, not by label
    from sharedspace.adversary.compare import compare_drivers, compare_markdown

    hold = stress_row(["hold"], {"CR-SFM": None, "intercept": "intercept"}, task, "hold")
    cmp = compare_drivers(result, hold)
    assert list(cmp["by"]) == ["CR-SFM", "jaywalker"]
    rate = {
        name: {label: cond["summary"]["success"]["rate"] for label, cond in r["conditions"].items()}
        for name, r in (("car_aware", result), ("hold", hold))
    }
    jay = cmp["by"]["jaywalker"]
    want = rate["car_aware"]["jaywalker"] - rate["hold"]["intercept"]
    assert jay["success"]["diff"] == pytest.approx(want)
    want_drop = (rate["car_aware"]["CR-SFM"] - rate["car_aware"]["jaywalker"]) - (
        rate["hold"]["CR-SFM"] - rate["hold"]["intercept"]
    )
    assert jay["drop"]["diff"] == pytest.approx(want_drop)
    assert cmp["by"]["CR-SFM"]["at_fault"]["diff"] == pytest.approx(
        result["conditions"]["CR-SFM"]["summary"]["at_fault"]["rate"]
        - hold["conditions"]["CR-SFM"]["summary"]["at_fault"]["rate"]
    )
    assert "| jaywalker | `intercept` |" in compare_markdown(cmp)
    with pytest.raises(ValueError, match="different tasks"):
        compare_drivers(result, {**hold, "fingerprint": "other"})
    no_baseline = {**hold, "conditions": {"intercept": hold["conditions"]["intercept"]}}
    with pytest.raises(ValueError, match="needs its CR-SFM baseline"):
        compare_drivers(result, no_baseline)

    # an episode of it as pictures: the adversary drawn apart, a GIF written
    from sharedspace.adversary.pictures import record_stress_episode
    from sharedspace.adversary.stress import load_adversary
    from sharedspace.bench.policies import make_policy
    from sharedspace.paper.episode import write_gif

    client = serve_task(task, tmp_path).open()
    try:
        driver = make_policy(lambda obs: np.zeros(2), task.driving)
        ep = record_stress_episode(
            driver, load_adversary(ckpt, task), task, "in-the-path", 0, client
        )
    finally:
        client.shutdown()
    assert len(ep.frames) >= 3
    assert any(a.controlled and a.length is None for f in ep.frames for a in f.agents)
    assert write_gif(ep, tmp_path / "ep.gif").stat().st_size > 0


def test_bad_adversary_inputs_are_refused_by_name(capsys):
    from sharedspace.adversary.__main__ import main
    from sharedspace.adversary.task import get_adversary_task

    with pytest.raises(ValueError, match="until must be 'either' or 'driver'"):
        AdversaryEnv("car_aware", until="forever")
    with pytest.raises(ValueError, match=r"unknown terms \['faults'\]"):
        AdversaryEnv("car_aware", reward_weights={"faults": 1.0})
    with pytest.raises(ValueError, match="unknown task 'crowd-adversaries'"):
        get_adversary_task("crowd-adversaries")
    with pytest.raises(ValueError, match="at version 1, not 2"):
        get_adversary_task("crowd-adversary@2")
    with pytest.raises(SystemExit):
        main(["stress", "--name", "x", "--driver", "car_aware", "--adversary", "own"])
    assert "--adversary 'own': give LABEL=CHECKPOINT" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["stress", "--name", "x", "--driver", "car_aware", "--adversary", "own=jaywalk"])
    assert "'jaywalk' is neither a checkpoint file nor a scripted adversary (intercept)" in (
        capsys.readouterr().err
    )
