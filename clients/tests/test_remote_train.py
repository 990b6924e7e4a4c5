"""The trainer's tiny smoke run on the remote env: checkpoint + evaluate."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("torchrl")

from conftest import TINY_TRAIN  # noqa: E402

from sharedspace.paper.evaluate import main as evaluate_main  # noqa: E402
from sharedspace.train.config import load_config  # noqa: E402
from sharedspace.train.train import train  # noqa: E402

TINY = [*TINY_TRAIN, "eval_interval=0", "checkpoint_interval=64"]


def test_remote_train_and_evaluate(sim_server, tmp_path, capsys):
    log_dir = tmp_path / "run"
    remote = [
        f"server_endpoint={sim_server.endpoint}",
        f"server_prefix={sim_server.prefix}",
    ]
    cfg = load_config(None, [*TINY, *remote, "total_frames=96", f"log_dir={log_dir}"])
    out = train(cfg)
    assert out["counters"]["frames"] == 96 and out["counters"]["updates"] > 0
    timing = out["timing"]
    assert 0.0 < timing["env_s"] < timing["collect_s"] + timing["update_s"]
    ckpt = log_dir / "checkpoints" / "last.pt"
    assert ckpt.exists()
    eval_json = tmp_path / "eval.json"
    assert (
        evaluate_main(
            [
                "--checkpoint",
                str(ckpt),
                "--split",
                "test",
                "--json",
                str(eval_json),
                "--set",
                *remote,
            ]
        )
        == 0
    )
    assert "G-SAC-Cog" in capsys.readouterr().out
    rec = json.loads(eval_json.read_text())
    assert len(rec["episodes"]) == 18
    assert sorted(e["scenario_index"] for e in rec["episodes"]) == sorted(
        h["scenario_index"] for h in rec["human"]
    )
    row = rec["table"]["G-SAC-Cog"]
    assert row["success"] + row["collision"] + row["timeout"] == pytest.approx(1.0)


def test_remote_train_with_a_zenoh_config_file(sim_server, tmp_path):
    """`zenoh_config` (a file like deploy/trainer.json5) configures the trainer's session."""
    zcfg = tmp_path / "trainer.json5"
    zcfg.write_text(
        "// the trainer's zenoh session\n"
        f'{{ mode: "peer", connect: {{ endpoints: ["{sim_server.endpoint}"] }},\n'
        "  scouting: { multicast: { enabled: false } } }\n"
    )
    cfg = load_config(
        None,
        [
            *TINY,
            f"zenoh_config={zcfg}",
            f"server_prefix={sim_server.prefix}",
            "total_frames=32",
            f"log_dir={tmp_path / 'run'}",
        ],
    )
    out = train(cfg)
    assert out["counters"]["frames"] == 32


def test_same_seed_same_machine_trains_bit_identical_weights(sim_server, tmp_path):
    """Determinism (docs/RESULTS.md): the same seed, config and machine give the same weights
    bit for bit: the server's worlds are deterministic and the trainer seeds torch."""
    import torch

    remote = [
        f"server_endpoint={sim_server.endpoint}",
        f"server_prefix={sim_server.prefix}",
    ]
    weights = []
    for run in ("a", "b"):
        cfg = load_config(None, [*TINY, *remote, "total_frames=96", f"log_dir={tmp_path / run}"])
        train(cfg)
        state = torch.load(tmp_path / run / "checkpoints" / "last.pt", weights_only=False)
        weights.append(state["learner"])
    assert weights[0].keys() == weights[1].keys()
    for key in weights[0]:
        assert torch.equal(weights[0][key], weights[1][key]), key


def test_without_an_endpoint_the_trainer_starts_its_own_server():
    """No ``server_endpoint`` (the default): ``make_env`` starts a local ``sim-server`` on a free
    loopback port and steps the Rust core through it."""
    from conftest import sim_server_binary

    from sharedspace import local_server
    from sharedspace.train.envs import make_env

    if sim_server_binary() is None:
        pytest.skip("sim-server binary not found")
    cfg = load_config(None, ["num_envs=2", "max_agents=4"])
    assert cfg.world.server_endpoint == ""
    env = make_env(cfg.world, "test", cfg.algo.num_envs)
    try:
        td = env.reset()
        assert tuple(td["features"].shape) == (2, 4, 11)
        td = env.rand_step(td)
        assert td["next", "reward"].shape == (2, 1)
        server = local_server.shared_server()
        assert server.proc.poll() is None and server.endpoint.startswith("tcp/127.0.0.1:")
    finally:
        env.close()
