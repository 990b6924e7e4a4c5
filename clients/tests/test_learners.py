"""The one learner design: a plug-in from outside the package (a toy algorithm and a toy network,
clients/tests/toy_plugin.py) trains on one car and on the crossing task and the bench scores it
with nothing but the checkpoint's path; training for a task chains into the bench; an actor
loads with no server; every shipped checkpoint loads; one command line for every algorithm."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

import toy_plugin  # noqa: E402,F401 - registers toy_pg and toy_mean, as a user's import would
from conftest import unique_prefix  # noqa: E402

from sharedspace.marl.task import CrossingTask  # noqa: E402
from sharedspace.marl.train import Cars  # noqa: E402
from sharedspace.train.checkpoint import read_checkpoint  # noqa: E402
from sharedspace.train.config import ConfigError, TrainConfig, load_config  # noqa: E402
from sharedspace.train.learners import load_checkpoint_actor, observation_example  # noqa: E402
from sharedspace.train.loop import train as loop_train  # noqa: E402
from sharedspace.train.registry import ALGORITHMS  # noqa: E402
from sharedspace.train.train import main as train_main  # noqa: E402
from sharedspace.train.train import train  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
TESTS = Path(__file__).resolve().parent
#: The crossing task on 3 of its test scenes (the bench's ``crossing-small`` of test_bench).
SMALL_CROSSING = CrossingTask(test_scenes=3)


def _score_in_a_fresh_process(task_expr: str, ckpt: Path) -> dict:
    """The bench's score of ``ckpt`` in a process that imports nothing but the bench: the
    plug-in is found through the checkpoint alone (its directory on the path, as a user's
    package is installed)."""
    script = "\n".join(
        [
            "import dataclasses, json, sys",
            "from sharedspace.bench import TASKS, score",
            "from sharedspace.marl.task import CrossingTask",
            f"task = {task_expr}",
            f"result = score(task, {str(ckpt)!r})",
            "print(json.dumps({'summary': result.summary, 'sources': result.sources,",
            "    'plugin': 'toy_plugin' in sys.modules}))",
        ]
    )
    return _python(script, env=os.environ | {"PYTHONPATH": str(TESTS)})


def _python(script: str, *args: str, env: dict[str, str]) -> dict:
    """Runs ``script`` in a fresh interpreter (from the repository's root); its last line of
    output, as JSON."""
    out = subprocess.run(
        [sys.executable, "-c", script, *args],
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
        check=False,
        cwd=REPO,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_plugin_algorithm_and_network_train_one_car_and_the_bench_scores_them(tmp_path):
    """toy_pg over toy_mean, registered outside the package, trains for the paper task on a
    local server the trainer starts; the bench scores the checkpoint by its path alone."""
    cfg = load_config(
        None,
        [
            "algorithm=toy_pg",
            "network=toy_mean",
            "task=paper",
            "total_frames=64",
            "validation_variations=1",
            "eval_interval=1",
            "progress=false",
            f"log_dir={tmp_path}",
        ],
    )
    out = train(cfg)
    assert out["counters"]["frames"] == 64
    assert out["eval"]["episodes"] == cfg.world.validation_scenes  # the validation split, once each
    ckpt_path = tmp_path / "checkpoints" / "last.pt"
    ckpt = read_checkpoint(ckpt_path)
    assert (ckpt["algorithm"], ckpt["network"], ckpt["modules"]) == (
        "toy_pg",
        "toy_mean",
        ["toy_plugin"],
    )
    assert ckpt["world"]["task"] == "paper"
    task = "dataclasses.replace(TASKS['paper'], name='paper-small', variations=1)"
    got = _score_in_a_fresh_process(task, ckpt_path)
    assert got["plugin"] and got["summary"]["episodes"] == 18
    assert got["sources"][0]["algorithm"] == "toy_pg"
    assert got["sources"][0]["network"] == "toy_mean"


@pytest.mark.parametrize("algorithm", ["toy_pg", "mappo"])
def test_a_plugin_trains_the_crossing_cars_and_the_bench_scores_them(
    algorithm, tmp_path, sim_server
):
    """The toy network encodes each car, under the toy algorithm (``cars="any"``: the task
    says how many) and under the built-in MAPPO; a few iterations on the crossing task."""
    cfg = TrainConfig(
        algorithm=algorithm,
        task="crossing",
        network="toy_mean",
        total_frames=128,
        num_envs=4,
        eval_interval=10_000,
        validation_scenes=3,
        server_endpoint=sim_server.endpoint,
        server_prefix=sim_server.prefix,
        log_dir=str(tmp_path),
        **({"rollout_steps": 16, "minibatch_size": 32} if algorithm == "mappo" else {}),
    )
    world = Cars(cfg, SMALL_CROSSING)
    out = loop_train(cfg, world=world)
    assert out["counters"]["frames"] == 128
    assert world.summary["car_episodes"] == 3 * 4  # 3 validation scenes x 4 cars
    ckpt_path = tmp_path / "checkpoints" / "last.pt"
    ckpt = read_checkpoint(ckpt_path)
    assert (ckpt["algorithm"], ckpt["network"], ckpt["modules"]) == (
        algorithm,
        "toy_mean",
        ["toy_plugin"],
    )
    task = "dataclasses.replace(TASKS['crossing'], name='crossing-small', " + (
        "crossing=CrossingTask(test_scenes=3))"
    )
    got = _score_in_a_fresh_process(task, ckpt_path)
    assert got["plugin"] and got["summary"]["episodes"] == 3 * 4


def test_train_for_a_task_then_score_with_no_other_flag(tmp_path, monkeypatch, capsys):
    """``python -m sharedspace.train --set task=paper`` (PPO, two iterations), then
    ``python -m sharedspace.bench paper --policy CKPT``: the checkpoint enters as it is. (The
    task is played in 1 of its 128 variations here, to keep the test short.)"""
    from sharedspace.bench import TASKS
    from sharedspace.bench.__main__ import main as bench_main

    log_dir = tmp_path / "run"
    overrides = [
        "algorithm=ppo",
        "task=paper",
        "num_envs=8",
        "rollout_steps=8",
        "minibatch_size=32",
        "total_frames=128",
        "eval_interval=0",
        "progress=false",
        f"log_dir={log_dir}",
    ]
    assert train_main(["--set", *overrides]) == 0
    ckpt = log_dir / "checkpoints" / "last.pt"
    monkeypatch.setitem(TASKS, "paper", dataclasses.replace(TASKS["paper"], variations=1))
    capsys.readouterr()
    assert bench_main(["paper", "--policy", str(ckpt)]) == 0
    assert "| run | 18 |" in capsys.readouterr().out


def _shipped() -> list[Path]:
    found = [
        *REPO.glob("results/bench/policies/*.pt"),
        *REPO.glob("results/table2*/policies/*.pt"),
        *REPO.glob("results/marl/**/policy.pt"),
    ]
    return sorted(found)


def test_every_shipped_checkpoint_reads_and_its_actor_loads_with_no_server(tmp_path):
    """In a process where no server can start (no binary anywhere), every shipped checkpoint
    is read; every one-car actor is built and acts; no local server was started."""
    shipped = _shipped()
    assert len(shipped) >= 9, shipped
    script = "\n".join(
        [
            "import json, sys",
            "import torch",
            "from sharedspace import local_server",
            "from sharedspace.train.checkpoint import read_checkpoint",
            "from sharedspace.train.learners import load_checkpoint_actor, observation_example",
            "from sharedspace.train.registry import get_algorithm",
            "kinds = {}",
            "for path in sys.argv[1:]:",
            "    ckpt = read_checkpoint(path)",
            "    if get_algorithm(ckpt['algorithm']).multi_car:",
            "        kinds[path] = 'many'",
            "        continue",
            "    cfg, actor = load_checkpoint_actor(ckpt)",
            "    with torch.no_grad():",
            "        action = actor(observation_example(cfg.world.max_agents))['action']",
            "    assert action.shape == (1, 2) and bool(torch.isfinite(action).all()), path",
            "    kinds[path] = 'one'",
            "print(json.dumps({'kinds': kinds, 'servers': len(local_server._shared)}))",
        ]
    )
    env = os.environ | {"SHAREDSPACE_SIM_SERVER": str(tmp_path / "no-such-binary")}
    env["PATH"] = "/usr/bin:/bin"
    got = _python(script, *map(str, shipped), env=env)
    assert got["servers"] == 0
    assert len(got["kinds"]) == len(shipped)
    assert "one" in got["kinds"].values() and "many" in got["kinds"].values()


def test_an_actor_loads_with_no_server_and_acts_as_saved(tmp_path):
    """The actor of a shipped residual PPO checkpoint: its weights are the checkpoint's."""
    path = REPO / "results" / "bench" / "policies" / "crowd-residual-s_sac-s0.pt"
    cfg, actor = load_checkpoint_actor(path)
    assert (cfg.algorithm, cfg.net.network, cfg.world.max_agents) == ("ppo", "mlp", 10)
    saved = read_checkpoint(path)["actor"]
    for key, value in actor.state_dict().items():
        assert torch.equal(value, saved[key]), key
    with torch.no_grad():
        assert actor(observation_example(10))["action"].shape == (1, 2)


def test_one_command_line_runs_every_registered_algorithm_and_names_bad_ones(tmp_path):
    """Every algorithm is registered once; the train command refuses an unknown one, a
    multi-car one on a one-car world and an option of another, naming what was wrong."""
    assert {"sac", "ppo", "mappo", "ippo", "masac", "toy_pg"} <= set(ALGORITHMS)
    assert {a.cars for a in ALGORITHMS.values()} == {"one", "many", "any"}
    for args, field in [
        (["algorithm=dqn"], "algorithm"),
        (["algorithm=ppo", "utd_ratio=2"], "utd_ratio"),
        (["algorithm=mappo", "task=paper"], "task"),
        (["algorithm=ppo", "task=crossing"], "task"),
        (["algorithm=mappo", "network=transformer"], "network"),
        (["algorithm=masac", "ppo_epochs=3"], "ppo_epochs"),
    ]:
        with pytest.raises((ConfigError, KeyError), match=field):
            train_main(["--set", *args, f"log_dir={tmp_path}"])


def test_a_shipped_multi_car_checkpoint_scores_as_published():
    """The crossing task's shipped MAPPO policies still load into the bench's policy."""
    from sharedspace.bench.policies import make_policy
    from sharedspace.bench.tasks import TASKS

    found = sorted(REPO.glob("results/marl/**/policy.pt"))
    assert found
    policy = make_policy(found[0], dataclasses.replace(TASKS["crossing"]))
    assert policy.source["algorithm"] in ("mappo", "ippo", "masac")


def test_a_server_of_the_pool_alone_serves_a_trainer_and_one_without_it_is_named(
    server_factory, tmp_path
):
    """The validation split is asked of the server by name: a server of the embedded pools
    only serves a default trainer, evaluations on; a server without the run's pool is a
    ConfigError naming the pool."""
    server = server_factory(unique_prefix(), "plain")  # the embedded pools only
    words = [
        "algorithm=ppo",
        "num_envs=2",
        "total_frames=32",
        "validation_variations=1",
        f"server_endpoint={server.endpoint}",
        f"server_prefix={server.prefix}",
        f"log_dir={tmp_path}",
    ]
    out = train(load_config(None, words))
    assert out["eval"]["episodes"] == 12  # the default carve of hbs-paper, one variation each
    other = server_factory(unique_prefix(), "other", 'pools:["embedded:hbs-general"]')
    words += [f"server_endpoint={other.endpoint}", f"server_prefix={other.prefix}"]
    with pytest.raises(ConfigError, match='unknown pool "hbs-paper".*serve the run\'s pool'):
        train(load_config(None, words))


def test_every_refusal_of_the_registries_and_the_reader_names_what_was_wrong(tmp_path):
    """Registering a taken name or an unknown kind, SAC over an encoder its fused update does
    not know, a checkpoint whose plug-in is gone or whose algorithm nobody registered, a
    validation carve of a missing pool file: each refused, naming it."""
    from sharedspace.bench import BenchError, get_task
    from sharedspace.bench.policies import make_policy
    from sharedspace.train.checkpoint import NotACheckpoint
    from sharedspace.train.networks import Network, register_network
    from sharedspace.train.registry import Algorithm, register_algorithm
    from sharedspace.worlds import held_out_scenes

    with pytest.raises(ValueError, match="'s_sac' is taken by network 'mlp'"):
        register_network(Network("other", "Other", lambda cfg, norm: None, aliases=("s_sac",)))
    with pytest.raises(ValueError, match="algorithm name 'ppo' is taken"):
        register_algorithm(Algorithm("ppo", "somewhere.else"))
    with pytest.raises(ValueError, match="cars must be 'one', 'many' or 'any'"):
        register_algorithm(Algorithm("toy_bad", "toy_plugin", cars="some"))
    with pytest.raises(ValueError, match="family must be 'on' or 'off'"):
        register_algorithm(Algorithm("toy_bad", "toy_plugin", family="both"))
    with pytest.raises(ConfigError, match="network toy_mean: algorithm sac's fused update"):
        TrainConfig(algorithm="sac", network="toy_mean")

    saved = read_checkpoint(REPO / "results" / "bench" / "policies" / "crowd-residual-s_sac-s0.pt")
    gone = tmp_path / "gone.pt"
    torch.save(saved | {"modules": ["no_such_plugin_module"]}, gone)
    with pytest.raises(NotACheckpoint, match="plug-in learner \\(no_such_plugin_module\\)"):
        read_checkpoint(gone)
    nobody = tmp_path / "nobody.pt"
    torch.save(saved | {"algorithm": "nobodys"}, nobody)
    with pytest.raises(BenchError, match="not 'nobodys' \\(register it before scoring\\)"):
        make_policy(nobody, get_task("crowd"))

    with pytest.raises(FileNotFoundError, match="no-pool.json is missing"):
        held_out_scenes(str(tmp_path / "no-pool.json"), 12)
