"""The examples run as a user runs them, at small sizes: the custom policy and the
Stable-Baselines3 script as commands, the tutorial notebook through a real kernel (nbclient)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _run(*args: str) -> str:
    proc = subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=600, cwd=EXAMPLES.parent
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_the_custom_policy_is_scored_beside_the_floor_and_the_script():
    out = _run(str(EXAMPLES / "custom_policy.py"), "--variations", "1")
    for row in ("| hold |", "| car_aware |", "| cautious |", "cautious − car_aware"):
        assert row in out, out


def test_stable_baselines3_trains_on_the_gymnasium_env_and_is_scored():
    pytest.importorskip("stable_baselines3")
    out = _run(str(EXAMPLES / "sb3_ppo.py"), "--steps", "1024", "--envs", "2", "--variations", "1")
    assert "| sb3-ppo-1024 | 18 |" in out, out


def test_the_tutorial_notebook_runs(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    monkeypatch.setenv("TUTORIAL_FRAMES", "4096")
    monkeypatch.setenv("TUTORIAL_VARIATIONS", "1")
    monkeypatch.setenv("TUTORIAL_LOG_DIR", str(tmp_path / "run"))
    nb = nbformat.read(EXAMPLES / "tutorial.ipynb", as_version=4)
    where = {"metadata": {"path": str(EXAMPLES.parent)}}
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources=where).execute()
    printed = "".join(
        o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
    )
    assert "validation:" in printed and "| mine | 18 |" in printed, printed
    assert (tmp_path / "run" / "episode.png").is_file()
    assert os.path.getsize(tmp_path / "run" / "checkpoints" / "last.pt") > 0
