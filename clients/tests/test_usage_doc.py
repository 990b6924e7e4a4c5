"""docs/USAGE.md held to the code: every info key it names is in a live env's infos, every file
of a run's folder that it lists is written by a run, every reward term it tabulates is one the
server sends, and every ``python -m sharedspace...`` command it shows answers ``--help``."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
USAGE = (REPO / "docs" / "USAGE.md").read_text()


def _section(title: str) -> str:
    start = USAGE.index(f"## {title}")
    end = USAGE.find("\n## ", start + 3)
    return USAGE[start : end if end > 0 else None]


def test_every_info_key_usage_names_is_in_a_live_envs_infos(sim_server):
    import sharedspace

    named = set(re.findall(r'infos\["vehicle_0"\]\["(\w+)"\]', USAGE))
    named |= set(re.findall(r'infos\["(\w+)"\]', USAGE)) - {"vehicle_0"}
    named |= set(re.findall(r"`(reward_\w+)`", _section("The reward and the episode")))
    assert {"reward_progress", "action_clipped"} <= named, named  # the parse found them
    env = sharedspace.parallel_env(endpoint=sim_server.endpoint, prefix=sim_server.prefix)
    try:
        env.reset(seed=0)
        actions = {a: env.action_space(a).sample() for a in env.agents}
        *_, infos = env.step(actions)
    finally:
        env.close()
    missing = named - set(infos["vehicle_0"])
    assert not missing, f"docs/USAGE.md names info keys the env does not give: {missing}"


def test_every_reward_term_usage_tabulates_is_the_servers():
    from sharedspace.names import REWARD_TERMS

    table = _section("The reward and the episode")
    terms = re.findall(r"^\| `(\w+)` \|", table, flags=re.M)
    assert sorted(terms) == sorted(REWARD_TERMS), terms


def test_every_file_of_a_run_usage_lists_is_written(sim_server, tmp_path, capsys):
    """... by ``python -m sharedspace.train``, whose last words name the folder and the split
    of its last scoring."""
    from sharedspace.train.train import main

    table = USAGE[USAGE.index("**What a run writes**") :]
    table = table[: table.index("\n\n", table.index("| file |"))]
    rows = [r for r in table.splitlines() if r.startswith("| `") and "multi-car" not in r]
    patterns = [p for r in rows for p in re.findall(r"`([^`]+)`", r.split("|")[1])]
    assert "metrics.csv" in patterns and "config.json" in patterns, patterns
    words = [
        "algorithm=ppo",
        "num_envs=4",
        "rollout_steps=8",
        "minibatch_size=16",
        "ppo_epochs=1",
        "hidden_sizes=16,16",
        "total_frames=64",
        "checkpoint_interval=32",
        "eval_interval=64",
        "validation_variations=1",
        "progress=false",
        f"server_endpoint={sim_server.endpoint}",
        f"server_prefix={sim_server.prefix}",
        f"log_dir={tmp_path}",
    ]
    assert main(["--set", *words]) == 0
    said = capsys.readouterr().out.strip().splitlines()[-2]
    assert f"run written to {tmp_path}" in said and "last scoring on the validation" in said
    for pattern in patterns:
        glob = re.sub(r"<[^>]+>", "*", pattern)
        assert list(tmp_path.glob(glob)), f"docs/USAGE.md lists {pattern}; the run wrote none"


@pytest.mark.parametrize(
    "module", sorted(set(re.findall(r"python -m (sharedspace(?:\.\w+)+)", USAGE)))
)
def test_every_command_usage_shows_answers_help(module):
    out = subprocess.run(
        [sys.executable, "-m", module, "--help"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, (module, out.stderr[-2000:])
