"""The other end of the TorchRL range the package supports (torchrl 0.11, BenchMARL's pin), in
.venv-benchmarl against a live server: both TorchRL envs pass TorchRL's own spec check, and a
BenchMARL MAPPO experiment on the crossing task runs a few iterations (``make test`` runs this
file with .venv-benchmarl's pytest)."""

from __future__ import annotations

import json

import pytest
import torchrl
from torchrl.envs.utils import check_env_specs

from sharedspace.client import Connection
from sharedspace.local_server import LocalServer
from sharedspace.marl.benchmarl_task import SharedspaceTask, run_mappo
from sharedspace.marl.task import CrossingTask, FlatObservation, make_env
from sharedspace.torchrl_env import RemoteBatchedEnv

TINY = {"cars": 2, "pedestrians": 6, "density": 0.03, "test_scenes": 2}


@pytest.fixture(scope="module")
def server():
    with LocalServer(prefix="benchmarltest") as s:
        yield s


def test_this_venv_holds_the_old_end_of_the_range():
    major, minor = (int(x) for x in torchrl.__version__.split(".")[:2])
    assert (major, minor) < (0, 12), torchrl.__version__


def test_both_envs_pass_torchrls_spec_check(server):
    env = RemoteBatchedEnv(num_envs=2, endpoint=server.endpoint, prefix=server.prefix)
    check_env_specs(env)
    env.close()
    connection = Connection(endpoint=server.endpoint, prefix=server.prefix)
    multi = make_env(CrossingTask(**TINY), "train", 2, connection)
    check_env_specs(multi)
    td = multi.rollout(6, break_when_any_done=False)
    assert td["next", "vehicle", "episode_car_collision"].shape == (2, 6, 2, 1)
    multi.close()


def test_the_benchmarl_task_builds_the_env_its_models_read(server):
    task = SharedspaceTask.CROSSING.get_task(
        config={"endpoint": server.endpoint, "prefix": server.prefix, "task": TINY}
    )
    env = task.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    assert task.group_map(env) == {"vehicle": ["vehicle_0", "vehicle_1"]}
    obs = task.observation_spec(env)
    assert list(obs["vehicle"].keys()) == ["observation"]
    assert obs["vehicle", "observation"].shape == (2, 10 * 12)
    assert "episode_success" in task.info_spec(env)["vehicle"].keys()
    assert isinstance(env.transform[0], FlatObservation)
    check_env_specs(env)
    env.close()


def test_a_benchmarl_mappo_experiment_runs_a_few_iterations(server, tmp_path):
    experiment = run_mappo(
        server.endpoint,
        server.prefix,
        tmp_path,
        frames=3 * 120,
        frames_per_batch=120,
        num_envs=6,
        task=TINY,
    )
    assert experiment.n_iters_performed == 3
    assert experiment.total_frames == 360
    logs = list(tmp_path.rglob("*.json"))
    assert logs, "BenchMARL wrote no JSON results"
    assert json.loads(logs[0].read_text())
