"""PPO on batched envs against a live server: a few iterations for each network, its loss is
TorchRL's, the checkpoint format, resuming, evaluating a PPO checkpoint, and the config errors
that name their field."""

from __future__ import annotations

import csv

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from sharedspace.scripted import SCRIPTED  # noqa: E402
from sharedspace.train import ppo  # noqa: E402
from sharedspace.train.checkpoint import FORMAT, read_checkpoint  # noqa: E402
from sharedspace.train.config import (  # noqa: E402
    ConfigError,
    TrainConfig,
    apply_overrides,
    load_config,
)
from sharedspace.train.envs import make_env  # noqa: E402
from sharedspace.train.gcn import FeatureNorm  # noqa: E402
from sharedspace.train.learners import load_checkpoint_actor  # noqa: E402
from sharedspace.train.reward import LEARNER_REWARD  # noqa: E402
from sharedspace.train.train import train  # noqa: E402

TINY = [
    "algorithm=ppo",
    "num_envs=4",
    "max_agents=5",
    "rollout_steps=8",
    "minibatch_size=16",
    "ppo_epochs=2",
    "hidden_sizes=16,16",
    "gcn_hidden=8",
    "eval_interval=0",
    "checkpoint_interval=0",
    "progress=false",
]


def _remote(sim_server) -> list[str]:
    return [f"server_endpoint={sim_server.endpoint}", f"server_prefix={sim_server.prefix}"]


@pytest.mark.parametrize("network", ["gcn_risk", "gcn_uniform", "mlp"])
def test_ppo_iterations_learn_for_every_network(network, sim_server, tmp_path):
    """Three iterations (96 frames) against the live server: every gradient step moves the
    actor, the losses are finite, the feature normalisation has seen the batches, and the
    metrics name where the time went."""
    cfg = load_config(
        None,
        [
            *TINY,
            *_remote(sim_server),
            f"network={network}",
            "total_frames=96",
            f"log_dir={tmp_path}",
        ],
    )
    out = train(cfg)
    assert out["counters"]["frames"] == 96 and out["counters"]["iterations"] == 3
    assert out["counters"]["updates"] == 3 * 2 * 2  # iterations x epochs x minibatches
    rows = list(csv.DictReader((tmp_path / "metrics.csv").open()))
    names = {r["metric"] for r in rows}
    assert {
        "train/fps",
        "train/collect_s",
        "train/update_s",
        "train/loss_objective",
        "train/loss_critic",
        "train/env_time_share_cum",
        "train/kl_approx",
    } <= names
    for r in rows:
        assert torch.isfinite(torch.tensor(float(r["value"]))), r
    ckpt = read_checkpoint(tmp_path / "checkpoints" / "last.pt")
    assert (ckpt["format"], ckpt["algorithm"], ckpt["network"]) == (FORMAT, "ppo", network)
    assert ckpt["world"]["reward"]["name"] == "learner"
    assert ckpt["world"]["max_agents"] == 5
    norm = {k: v for k, v in ckpt["actor"].items() if k.endswith("norm.count")}
    assert norm and all(float(v.min()) > 0 for v in norm.values())


@pytest.mark.parametrize("overlap", ["false", "true"])
def test_ppo_resumes_from_its_checkpoint_and_evaluates(overlap, sim_server, tmp_path):
    words = [*TINY, *_remote(sim_server), "total_frames=32", f"overlap={overlap}"]
    cfg = load_config(None, [*words, f"log_dir={tmp_path}"])
    train(cfg)
    last = tmp_path / "checkpoints" / "last.pt"
    before = read_checkpoint(last)
    out = train(apply_overrides(cfg, ["total_frames=64"]), resume=str(last))
    assert out["counters"]["frames"] == 64 and out["counters"]["iterations"] == 2
    after = read_checkpoint(last)
    key = next(k for k in after["actor"] if k.endswith("head.0.weight"))
    assert not torch.equal(before["actor"][key], after["actor"][key])
    loaded_cfg, actor = load_checkpoint_actor(str(last), _remote(sim_server))
    assert loaded_cfg.algorithm == "ppo"
    assert torch.equal(actor.state_dict()[key], after["actor"][key])


def test_the_loss_is_torchrls_clip_ppo_loss(sim_server):
    cfg = apply_overrides(TrainConfig(), [*TINY, *_remote(sim_server)])
    env = make_env(cfg.world, "train", cfg.algo.num_envs, driving=cfg.driving)
    actor = ppo.make_actor(cfg, env.action_spec_unbatched)
    update = ppo.make_update(cfg, actor)
    from torchrl.objectives import ClipPPOLoss

    assert isinstance(update.loss, ClipPPOLoss)
    with torch.no_grad():
        data = env.rollout(8, actor, break_when_any_done=False)
    stats = update.step(data)
    env.close()
    assert stats["gradient_steps"] == 2 * (4 * 8 // 16)
    assert 0.0 <= stats["clip_fraction"] <= 1.0


def test_a_residual_ppo_policy_starts_at_its_script(sim_server):
    """With a base driver the deterministic action of a fresh PPO actor is 0: the env drives
    the script's action."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    cfg = apply_overrides(TrainConfig(), [*TINY, *_remote(sim_server), "base_driver=car_aware"])
    env = make_env(cfg.world, "train", cfg.algo.num_envs, driving=cfg.driving)
    actor = ppo.make_actor(cfg, env.action_spec_unbatched)
    td = env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        action = actor(td)["action"]
    assert torch.allclose(action, torch.zeros_like(action), atol=1e-6)
    sent = env.transform.inv(td)["action"]
    assert torch.allclose(sent, SCRIPTED["car_aware"]()(td["features"], td["mask"]))
    env.close()


def test_feature_norm_tracks_present_nodes_by_role():
    norm = FeatureNorm(num_features=2)
    h = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [100.0, 100.0]]]).repeat(4, 1, 1)
    m = torch.tensor([1.0, 1.0, 0.0]).reshape(1, 3, 1).repeat(4, 1, 1)
    h[2:, 0] += 2.0  # the ego's features vary
    norm.update(h[:2], m[:2])
    norm.update(h[2:], m[2:])  # merged in two batches as in one
    assert torch.allclose(norm.mean[0], torch.tensor([2.0, 3.0]))
    assert torch.allclose(norm.var[0], torch.tensor([1.0, 1.0]))
    assert torch.allclose(norm.mean[1], torch.tensor([3.0, 4.0]))  # padding left out
    out = norm(h, m)
    assert torch.all(out[:, 2] == 0)  # padding stays 0


@pytest.mark.parametrize(
    "overrides, field",
    [
        (["algorithm=dqn"], "algorithm"),
        (["algorithm=sac", "ppo_epochs=8"], "ppo_epochs"),
        (["algorithm=sac", "clip_epsilon=0.1"], "clip_epsilon"),
        (["algorithm=ppo", "utd_ratio=2"], "utd_ratio"),
        (["residual_scale=2"], "residual_scale"),
        (["algorithm=ppo", "base_driver=nobody"], "base_driver"),
        (["algorithm=ppo", "reward=kind"], "reward"),
        (["algorithm=ppo", "rollout_steps=0"], "rollout_steps"),
        (["algorithm=ppo", "minibatch_size=lots"], "minibatch_size"),
        (["network=transformer"], "network"),
        (["variant=transformer"], "network"),  # the old name of the field
        (["algorithm=mappo", "max_agents=12"], "max_agents"),  # the crossing task sets M
        (["task=nowhere"], "task"),
        (["task=crossing"], "task"),
        (["task=paper", "max_agents=12"], "max_agents"),
        (["eval_split=train"], "eval_split"),
        # each part checks its own values: the world's, the network's, the algorithm's
        (["max_agents=0"], "max_agents"),
        (["validation_scenes=0"], "validation_scenes"),
        (["scenes=-2"], "scenes"),
        (["readout=sum"], "readout"),
        (["algorithm=ppo", "anneal_start=1.5"], "anneal_start"),
        (["prior_ratio=1"], "prior_ratio"),
        (["bc_steps=10"], "bc_steps"),
        (["total_frames=0"], "total_frames"),
        (["default_network=mlp"], "default_network"),  # a class attribute, no key
    ],
)
def test_a_bad_config_names_its_field(overrides, field):
    with pytest.raises(ConfigError, match=field):
        load_config(None, overrides)


def test_the_algorithm_fills_in_what_was_left_to_it():
    """``num_envs`` and ``reward`` left unset take the algorithm's own defaults, also when an
    override changes the algorithm of a config already made; set, they stay."""
    ppo_cfg = apply_overrides(TrainConfig(), ["algorithm=ppo"])
    assert (ppo_cfg.algo.num_envs, ppo_cfg.algo.reward) == (256, "learner")
    assert ppo_cfg.reward_weights == LEARNER_REWARD
    sac_cfg = apply_overrides(ppo_cfg, ["algorithm=sac"])
    assert (sac_cfg.algo.num_envs, sac_cfg.algo.reward, sac_cfg.reward_weights) == (8, "world", {})
    kept = apply_overrides(TrainConfig(), ["num_envs=32", "reward=learner", "algorithm=sac"])
    assert (kept.algo.num_envs, kept.algo.reward) == (32, "learner")
    assert apply_overrides(TrainConfig(), ["variant=s_sac"]).net.network == "mlp"
    assert (ppo_cfg.algo.eval_interval, sac_cfg.algo.eval_interval) == (524_288, 20_000)
