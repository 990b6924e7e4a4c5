"""A user's mistake on a command line is one line that names it, exit status 2, no traceback;
``--debug`` shows the traceback. Each command runs as a user types it (a fresh process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _run(*words: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, *words], cwd=cwd, capture_output=True, text=True, timeout=120
    )


def _one_line(out: subprocess.CompletedProcess, *needles: str) -> str:
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert "Traceback" not in out.stderr, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), out.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize(
    "words, needles",
    [
        (["netwrok=mlp"], ["unknown config key 'netwrok'", "did you mean 'network'"]),
        (["task=crwod"], ["task must be one of", "did you mean 'crowd'"]),
        (["algorithm=ppo", "network=gcn_rsk"], ["network must be one of", "'gcn_risk'"]),
        (["algorithm=mapo"], ["algorithm must be one of", "did you mean 'mappo'"]),
        (["algorithm=sac", "rollout_steps=5"], ["rollout_steps is an option of algorithm=ppo"]),
        (["seed=abc"], ["--set seed=abc"]),
    ],
)
def test_a_wrong_training_word_is_one_line(words, needles):
    _one_line(_run("-m", "sharedspace.train", "--set", *words), *needles)


def test_a_file_that_is_not_a_checkpoint_is_refused_by_name(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"\x80\x04not a pickle at all" * 10)
    line = _one_line(_run("-m", "sharedspace.bench", "paper", "--policy", str(junk)))
    assert str(junk) in line and "not a sharedspace checkpoint" in line
    line = _one_line(_run("-m", "sharedspace.train", "--resume", str(junk)))
    assert str(junk) in line


def test_a_typo_in_a_task_or_driver_of_the_bench_suggests_the_name():
    _one_line(_run("-m", "sharedspace.bench", "crwod", "--policy", "hold"), "did you mean 'crowd'")
    _one_line(
        _run("-m", "sharedspace.bench", "paper", "--policy", "car_awar"),
        "did you mean 'car_aware'",
    )


def test_debug_shows_the_traceback():
    out = _run("-m", "sharedspace.train", "--debug", "--set", "netwrok=mlp")
    assert out.returncode != 0 and "Traceback" in out.stderr and "netwrok" in out.stderr


def test_a_config_file_missing_or_with_an_unknown_key_is_one_line(tmp_path):
    missing = tmp_path / "none.toml"
    _one_line(_run("-m", "sharedspace.train", "--config", str(missing)), str(missing))
    table = tmp_path / "mine.toml"
    table.write_text('netwrok = "mlp"\n')
    _one_line(
        _run("-m", "sharedspace.train", "--config", str(table)), "did you mean 'network'"
    )
    _one_line(_run("-m", "sharedspace.train", "--set", "seed"), "expected KEY=VALUE")


def test_the_debug_variable_shows_the_traceback_too():
    out = subprocess.run(
        [sys.executable, "-m", "sharedspace.train", "--set", "netwrok=mlp"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        env=os.environ | {"SHAREDSPACE_DEBUG": "1"},
    )
    assert out.returncode != 0 and "Traceback" in out.stderr


def test_the_time_to_a_driver_resumes_only_its_own_settings(tmp_path):
    """benchmarks/time_to_driver.py: the shipped runs give back their published summary, and
    a rerun with other settings is refused rather than mixed in."""
    shipped = REPO / "results" / "time_to_driver" / "ppo_epochs2.json"
    out = tmp_path / "ttd.json"
    out.write_bytes(shipped.read_bytes())
    script = str(REPO / "benchmarks" / "time_to_driver.py")
    same = _run(script, "--before", "x", "--after-set", "ppo_epochs=2", "--out", str(out))
    assert same.returncode == 0, same.stderr
    assert json.loads(out.read_text())["summary"] == json.loads(shipped.read_text())["summary"]
    other = _run(script, "--before", "x", "--out", str(out))
    assert other.returncode == 1 and "keeps runs of other settings" in other.stderr
    assert json.loads(out.read_text())["after_settings"] == ["ppo_epochs=2"]


def test_a_trainer_pointed_where_no_server_answers_is_one_line(sim_server):
    """A deployment's mistake: the right endpoint, a key prefix nobody serves."""
    words = ["algorithm=ppo", "total_frames=64", "progress=false", "eval_interval=0"]
    words += [f"server_endpoint={sim_server.endpoint}", "server_prefix=nobodyserves"]
    _one_line(_run("-m", "sharedspace.train", "--set", *words), "prefix 'nobodyserves'")


def test_the_bench_and_its_tasks_import_no_torch():
    """``import sharedspace.bench`` (and ``--help``) leave torch out: it loads only once there
    is something to play."""
    probe = (
        "import sys, sharedspace.bench as b; b.get_task('crowd'); b.TASKS['crossing'].episodes; "
        "assert 'torch' not in sys.modules, sorted(m for m in sys.modules if 'torch' in m)[:5]"
    )
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    out = _run("-m", "sharedspace.bench", "--help")
    assert out.returncode == 0 and "crossing" in out.stdout
