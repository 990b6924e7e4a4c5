"""A tiny SAC-GCN run on the local env: checkpoint, evaluate (Table II), resume, plots."""

from __future__ import annotations

import csv
import json

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from sharedspace.paper.evaluate import main as evaluate_main  # noqa: E402
from sharedspace.train.config import load_config  # noqa: E402
from sharedspace.train.train import main as train_main  # noqa: E402
from sharedspace.train.train import train  # noqa: E402

TINY = [
    "num_envs=2",
    "max_agents=5",
    "frames_per_batch=16",
    "init_random_frames=64",
    "utd_ratio=0.25",
    "batch_size=16",
    "buffer_size=2000",
    "hidden_sizes=16,16",
    "gcn_hidden=8",
    "eval_interval=0",
    "checkpoint_interval=96",
    "progress=false",
]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp("run")
    cfg = load_config(None, [*TINY, "total_frames=192", f"log_dir={log_dir}", "save_buffer=true"])
    out = train(cfg)
    return log_dir, out


def test_tiny_run_writes_logs_and_checkpoints(run):
    log_dir, out = run
    assert out["counters"]["frames"] == 192
    assert out["counters"]["updates"] > 0
    timing = out["timing"]
    assert 0.0 < timing["env_s"] < timing["collect_s"] + timing["update_s"]
    ckpts = log_dir / "checkpoints"
    assert (ckpts / "last.pt").exists() and (ckpts / "step_96.pt").exists()
    rows = list(csv.DictReader((log_dir / "metrics.csv").open()))
    names = {r["metric"] for r in rows}
    assert {"train/env_time_share_cum", "train/fps", "train/loss_qvalue", "train/alpha"} <= names
    assert any((log_dir / "tb").iterdir())


def test_evaluate_checkpoint(run, tmp_path, capsys):
    log_dir, _ = run
    out = tmp_path / "eval.json"
    assert (
        evaluate_main(
            [
                "--checkpoint",
                str(log_dir / "checkpoints" / "last.pt"),
                "--split",
                "test",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "G-SAC-Cog" in text and "human" in text and "Success" in text
    rec = json.loads(out.read_text())
    assert len(rec["episodes"]) == 18 and len(rec["human"]) == 18
    row = rec["table"]["G-SAC-Cog"]
    assert row["success"] + row["collision"] + row["timeout"] == pytest.approx(1.0)
    assert rec["table"]["human"]["success"] == 1.0 and rec["table"]["human"]["avg_speed"] > 0
    ep = rec["episodes"][0]
    assert len(ep["speeds"]) == ep["steps"] + 1 == len(ep["actions"]) + 1

    from sharedspace.paper.plots import main as plots_main

    assert (
        plots_main(
            [
                "--run",
                str(log_dir),
                "--eval-json",
                str(out),
                "--scene",
                "60",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    for name in ("learning_curves.png", "profiles.png", "scene_60_t6.png"):
        assert (tmp_path / name).stat().st_size > 1000


def test_resume_continues_counters(run, tmp_path):
    log_dir, first = run
    ckpt = log_dir / "checkpoints" / "last.pt"
    new_dir = tmp_path / "resumed"
    assert (
        train_main(["--resume", str(ckpt), "--set", "total_frames=256", f"log_dir={new_dir}"]) == 0
    )
    state = torch.load(new_dir / "checkpoints" / "last.pt", weights_only=False)
    assert state["counters"]["frames"] == 256
    assert state["counters"]["updates"] > first["counters"]["updates"]
    assert state["counters"]["iterations"] == first["counters"]["iterations"] + 4
    before = torch.load(ckpt, weights_only=False)
    assert not torch.equal(before["learner"]["log_alpha"], state["learner"]["log_alpha"])
