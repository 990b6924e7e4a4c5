"""Prior data (sharedspace.train.prior, sharedspace.paper.demos): the recorded transitions are
the env's, the mirror augmentation is a symmetry of the real simulator, a dataset of another
world is refused by name, and the trainer learns from one (RLPD batches, BC)."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from conftest import TINY_TRAIN  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from sharedspace.names import Feature  # noqa: E402
from sharedspace.paper.demos import record_demos, record_episodes  # noqa: E402
from sharedspace.paper.drivers import make_driver  # noqa: E402
from sharedspace.train.config import TrainConfig, apply_overrides, load_config  # noqa: E402
from sharedspace.train.envs import make_env  # noqa: E402
from sharedspace.train.prior import (  # noqa: E402
    KEYS,
    PriorDataError,
    load_prior,
    mirrored,
    world_of,
    write_prior,
)
from sharedspace.train.train import train  # noqa: E402
from sharedspace.world_config import WorldConfig  # noqa: E402

M = 5
TINY_RECIPE = {
    "car_aware": {"driver": "car_aware", "noise_std": 0.0, "first": 0, "variations": 1},
    "car_aware_noisy": {"driver": "car_aware", "noise_std": 0.3, "first": 100, "variations": 1},
    "planner": {"driver": "planner", "of": "car_aware", "rounds": 1, "per_round": 10},
}


def remote(server) -> list[str]:
    return [f"server_endpoint={server.endpoint}", f"server_prefix={server.prefix}"]


def synthetic_transitions(n: int = 12, m: int = M) -> TensorDict:
    gen = torch.Generator().manual_seed(0)

    def obs():
        return {
            "features": torch.randn(n, m, 11, generator=gen),
            "adjacency": torch.rand(n, m, m, generator=gen),
            "mask": torch.ones(n, m, dtype=torch.bool),
        }

    nxt = {
        **obs(),
        "reward": torch.randn(n, 1, generator=gen),
        "terminated": torch.zeros(n, 1, dtype=torch.bool),
        "done": torch.zeros(n, 1, dtype=torch.bool),
    }
    labels = {k: torch.zeros(n, dtype=torch.int64) for k in ("source", "scenario_index", "step")}
    labels["variation"] = torch.full((n,), -1)
    labels["episode"] = torch.arange(n)
    labels["episode_success"] = torch.ones(n, dtype=torch.bool)
    td = {**obs(), "action": torch.rand(n, 2, generator=gen) * 2 - 1, **labels}
    return TensorDict({**td, "next": TensorDict(nxt, [n])}, [n])


def test_a_dataset_recorded_in_another_world_is_refused_naming_what_differs(tmp_path):
    params_a, params_b = tmp_path / "a.json5", tmp_path / "b.json5"
    params_a.write_text("{}")
    params_b.write_text('{risk: {"lambda": 2.0}}')
    cfg = TrainConfig(max_agents=M, server_params=str(params_a))
    write_prior(
        tmp_path / "ds",
        synthetic_transitions(),
        world_of(cfg.world, cfg.reward_weights),
        {"car_aware": {}},
    )
    assert len(load_prior(tmp_path / "ds", cfg)) == 12  # its own world loads

    other = apply_overrides(cfg, [f"server_params={params_b}", "max_agents=6"])
    with pytest.raises(PriorDataError) as err:
        load_prior(tmp_path / "ds", other)
    msg = str(err.value)
    assert "another world" in msg
    assert "world.params.sha256" in msg and "world.max_agents: dataset 5, trainer 6" in msg
    assert "pool" not in msg.split("another world")[1]  # the same pool is not named

    reweighted = apply_overrides(cfg, ['reward_weights={"danger": 5.0}'])
    with pytest.raises(PriorDataError, match="world.reward_weights"):
        load_prior(tmp_path / "ds", reweighted)

    # A trainer given it refuses before it collects anything.
    with pytest.raises(PriorDataError, match="max_agents"):
        train(apply_overrides(other, [f"prior_data={tmp_path / 'ds'}", "total_frames=16"]))


def test_a_dataset_of_another_format_version_or_none_is_refused(tmp_path):
    cfg = TrainConfig(max_agents=M)
    with pytest.raises(PriorDataError, match="not a prior dataset"):
        load_prior(tmp_path, cfg)
    write_prior(
        tmp_path / "ds",
        synthetic_transitions(),
        world_of(cfg.world, cfg.reward_weights),
        {"car_aware": {}},
    )
    header = json.loads((tmp_path / "ds" / "header.json").read_text())
    header["version"] = 99
    (tmp_path / "ds" / "header.json").write_text(json.dumps(header))
    with pytest.raises(PriorDataError, match="version 99"):
        load_prior(tmp_path / "ds", cfg)


def test_the_mirror_flips_lateral_features_and_the_yaw_rate_only():
    batch = synthetic_transitions()
    flipped = mirrored(batch)
    lateral = [Feature.REL_Y, Feature.REL_VY, Feature.HEADING_DIFF, Feature.GOAL_DY]
    same = [i for i in range(11) if i not in lateral]
    for key in ("features", ("next", "features")):
        f, g = batch.get(key), flipped.get(key)
        assert torch.equal(g[..., lateral], -f[..., lateral])
        assert torch.equal(g[..., same], f[..., same])
    assert torch.equal(flipped["action"][:, 1], -batch["action"][:, 1])
    assert torch.equal(flipped["action"][:, 0], batch["action"][:, 0])
    assert torch.equal(flipped["adjacency"], batch["adjacency"])
    assert torch.equal(flipped["next", "reward"], batch["next", "reward"])
    assert (mirrored(flipped) == batch.select(*KEYS)).all()


def test_the_mirror_is_a_symmetry_of_the_simulator(sim_server):
    """A scene and its mirror image (the same variation seed with and without ``mirror``),
    driven by the mirror-symmetric car-aware script: every observation of one is the mirror of
    the other's, the risk graphs and the rewards are equal. So mirrored prior data is data the
    simulator could have produced."""
    world = WorldConfig.from_words([*remote(sim_server), "max_agents=6"])
    spec = {"position_sigma": 0.3, "start_offset_steps": 1, "desired_speed_scale": 0.1}
    seeds = list(range(8))
    runs = []
    for mirror in (False, True):
        env = make_env(
            world,
            split="train",
            num_envs=len(seeds),
            scenario_order="sequential",
            variations={**spec, "mirror": mirror},
            variation_seeds=seeds,
        )
        try:
            got, _ = record_episodes(env, make_driver("car_aware"), max_steps=12)
        finally:
            env.close()
        runs.append(got[got["step"] < 12])
    plain, maybe_mirrored = runs
    assert plain.shape == maybe_mirrored.shape
    mirrored_episodes = 0
    for k in range(len(seeds)):
        a = plain[plain["episode"] == k]
        b = maybe_mirrored[maybe_mirrored["episode"] == k]
        if torch.allclose(a["features"], b["features"], atol=1e-4):
            continue  # u_m >= 1/2: this seed is not mirrored
        mirrored_episodes += 1
        flipped = mirrored(a)
        for key in ("features", ("next", "features"), "adjacency", ("next", "reward"), "action"):
            assert torch.allclose(flipped.get(key), b.get(key), atol=2e-3), (k, key)
    assert 0 < mirrored_episodes < len(seeds)


def test_recorded_transitions_are_the_env_steps(sim_server):
    cfg = apply_overrides(TrainConfig(), [*remote(sim_server), f"max_agents={M}"])
    env = make_env(cfg.world, "train", 4, scenario_order="sequential", driving=cfg.driving)
    try:
        got, episodes = record_episodes(env, make_driver("pursuit_3"))
    finally:
        env.close()
    assert len(episodes) == 4 and got.shape[0] == sum(e["steps"] for e in episodes)
    for k, ep in enumerate(episodes):
        rows = got[got["episode"] == k]
        assert rows["step"].tolist() == list(range(ep["steps"]))
        assert rows["next", "done"].reshape(-1).tolist() == [False] * (ep["steps"] - 1) + [True]
        assert bool(rows["episode_success"].all()) == (ep["status"] == "success")
        # Each step starts where the last one ended.
        assert torch.equal(rows["features"][1:], rows["next", "features"][:-1])
        assert np.allclose(rows["action"].numpy(), np.asarray(ep["actions"]), atol=1e-6)


def test_the_trainer_learns_from_recorded_demonstrations(sim_server, tmp_path):
    """``make demos`` in miniature (the scripts, a noisy copy and the planner on the train
    split), then RLPD batches with a BC term and a cloned start against the live server."""
    cfg = apply_overrides(TrainConfig(), [*remote(sim_server), f"max_agents={M}"])
    transitions, sources = record_demos(cfg.world, TINY_RECIPE, log=lambda *_: None)
    assert list(sources) == list(TINY_RECIPE)
    train_scenes = (
        59 - cfg.world.validation_scenes
    )  # the paper pool's, the validation ones left out
    assert sources["car_aware"]["episodes"] == train_scenes
    assert set(transitions["source"].tolist()) <= {0, 1, 2}
    failed = round(train_scenes * (1 - sources["car_aware"]["success"]))
    assert sources["planner"]["cells"] == failed
    write_prior(tmp_path / "demos", transitions, world_of(cfg.world, cfg.reward_weights), sources)

    log_dir = tmp_path / "run"
    run = load_config(
        None,
        [
            *TINY_TRAIN,
            *remote(sim_server),
            "eval_interval=0",
            "total_frames=64",
            f"log_dir={log_dir}",
            f"prior_data={tmp_path / 'demos'}",
            "prior_sources=car_aware",
            "prior_successes_only=true",
            "bc_steps=20",
            "bc_weight=0.5",
            "critic_layer_norm=true",
        ],
    )
    out = train(run)
    assert out["counters"]["clone_steps"] == 20 and out["counters"]["updates"] > 0
    metrics = (log_dir / "metrics.csv").read_text()
    assert "train/loss_clone" in metrics and "train/loss_bc" in metrics


def test_a_fresh_residual_actor_drives_exactly_as_its_script(sim_server):
    """``base_driver``: the env executes the script's action plus the policy's; a fresh actor's
    deterministic residual is 0, so its episodes are the script's, step for step, while the
    replay buffer sees the residual."""
    from sharedspace.episodes import run_episodes
    from sharedspace.train.sac import make_actor

    base = apply_overrides(TrainConfig(), [*remote(sim_server), f"max_agents={M}"])
    residual = apply_overrides(base, ["base_driver=car_aware"])
    env = make_env(
        residual.world, "train", 4, scenario_order="sequential", driving=residual.driving
    )
    try:
        actor = make_actor(residual, env.action_spec_unbatched)
        learned = run_episodes(env, actor)
    finally:
        env.close()
    env = make_env(base.world, "train", 4, scenario_order="sequential", driving=base.driving)
    try:
        scripted = run_episodes(env, make_driver("car_aware"))
    finally:
        env.close()
    for a, b in zip(learned, scripted, strict=True):
        assert (a["status"], a["steps"]) == (b["status"], b["steps"])
        assert np.allclose(a["speeds"], b["speeds"], atol=1e-5)
        assert np.allclose(a["actions"], 0.0)  # what the learner chose: no correction


def test_a_residual_learner_reads_prior_actions_as_residuals_over_its_script(sim_server, tmp_path):
    """With ``base_driver`` the prior actions become residuals over the script: the residual env
    turns each back into the recorded action, the residual of a mirrored transition is the
    mirrored residual (the script is mirror-symmetric), and a residual trainer with a BC term
    learns from them against the live server."""
    from sharedspace.train.prior import make_prior

    world = [*remote(sim_server), f"max_agents={M}"]
    cfg = apply_overrides(TrainConfig(), world)
    env = make_env(cfg.world, "train", 4, scenario_order="sequential", driving=cfg.driving)
    try:  # pursuit_3 with noise: actions far from car_aware's
        got, _ = record_episodes(env, make_driver("pursuit_3"), noise_std=0.3, max_steps=30)
    finally:
        env.close()
    got["source"] = torch.zeros(got.shape[0], dtype=torch.int64)
    write_prior(tmp_path / "demos", got, world_of(cfg.world, cfg.reward_weights), {"pursuit_3": {}})
    residual_cfg = apply_overrides(
        cfg, [f"prior_data={tmp_path / 'demos'}", "base_driver=car_aware"]
    )
    residual = make_prior(residual_cfg).transitions
    script = make_driver("car_aware")
    base = script(got["features"], got["mask"])
    recorded = got["action"]
    within = (recorded - base).abs() <= 1.0  # where a residual in [-1, 1] reaches the action
    executed = (base + residual["action"]).clamp(-1, 1)
    assert torch.allclose(executed[within], recorded[within], atol=1e-5)
    assert torch.equal(residual["action"][~within].abs(), torch.ones(int((~within).sum())))
    assert within.float().mean() > 0.5
    assert not torch.allclose(residual["action"], recorded, atol=1e-2)
    flipped = mirrored(got)  # the script's action in the mirrored state is its mirror image
    base_of_flipped = script(flipped["features"], flipped["mask"])
    flipped_base = mirrored(got.clone().set("action", base.to(recorded.dtype)))["action"]
    assert torch.allclose(base_of_flipped, flipped_base, atol=1e-5)

    run = load_config(
        None,
        [
            *TINY_TRAIN,
            *world,
            "eval_interval=0",
            "total_frames=64",
            f"log_dir={tmp_path / 'run'}",
            f"prior_data={tmp_path / 'demos'}",
            "base_driver=car_aware",
            "bc_steps=10",
            "bc_weight=0.5",
        ],
    )
    out = train(run)
    assert out["counters"]["clone_steps"] == 10 and out["counters"]["updates"] > 0


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"prior_ratio": 1.0}, "prior_ratio must be in"),
        ({"prior_ratio": -0.1}, "prior_ratio must be in"),
        ({"bc_steps": 10}, "bc_steps clone the prior data"),
        ({"bc_weight": 0.5}, "bc_weight imitates the prior data or the base driver"),
        ({"base_driver": "pursuit_9"}, "base_driver must be one of"),
    ],
)
def test_prior_and_residual_settings_that_cannot_work_are_refused_by_name(fields, message):
    with pytest.raises(ValueError, match=message):
        TrainConfig(**fields)
    TrainConfig(bc_weight=0.5, base_driver="car_aware")  # a residual imitates its script


def test_a_selection_of_no_transitions_or_of_an_unknown_source_is_refused(tmp_path):
    cfg = TrainConfig(max_agents=M)
    bad = synthetic_transitions()
    with pytest.raises(PriorDataError, match="lack"):
        write_prior(
            tmp_path / "bad",
            bad.exclude("episode_success"),
            world_of(cfg.world, cfg.reward_weights),
            {},
        )
    failed = synthetic_transitions()
    failed["episode_success"] = torch.zeros(12, dtype=torch.bool)
    write_prior(tmp_path / "ds", failed, world_of(cfg.world, cfg.reward_weights), {"car_aware": {}})
    prior = load_prior(tmp_path / "ds", cfg)
    with pytest.raises(PriorDataError, match=r"no source \['planner'\]"):
        prior.select(["planner"])
    with pytest.raises(PriorDataError, match="no transition"):
        prior.select(successes_only=True)
