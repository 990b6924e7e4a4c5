"""Step-by-step comparison of a Rust rollout (``sim-server rollout``) with ReferenceWorld."""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from reference import ReferenceWorld

REPO_ROOT = Path(__file__).resolve().parents[2]
POOL_PATH = REPO_ROOT / "scenarios" / "data" / "hbs-paper.json"


def server_binary() -> Path | None:
    """The release ``sim-server`` (``$SHAREDSPACE_SIM_SERVER`` overrides), or None if absent."""
    env = os.environ.get("SHAREDSPACE_SIM_SERVER")
    path = Path(env) if env else REPO_ROOT / "target" / "release" / "sim-server"
    return path if path.is_file() and os.access(path, os.X_OK) else None


def run_rollout(
    binary: Path,
    out: Path,
    scenario: str,
    model: str,
    av: str,
    pool: Path | None = None,
    params: Path | None = None,
) -> list[dict]:
    # `--av=...` so that a negative action is not taken for a flag.
    cmd = [str(binary), "rollout", "--scenario", scenario, "--model", model, f"--av={av}"]
    cmd += ["--out", str(out)]
    if pool is not None:
        cmd += ["--pool", str(pool)]
    if params is not None:
        cmd += ["--params", str(params)]
    subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=300)
    return [json.loads(line) for line in out.read_text().splitlines() if line.strip()]


@dataclass
class Comparison:
    steps: int = 0
    max_pos: float = 0.0
    max_vel: float = 0.0
    max_heading: float = 0.0
    max_psi: float = 0.0
    max_u: float = 0.0
    max_a: float = 0.0
    max_reward: float = 0.0
    problems: list[str] = field(default_factory=list)

    def problem(self, text: str):
        if len(self.problems) < 20:
            self.problems.append(text)


def _event_key(e: dict) -> tuple:
    if e["event"] == "collision":
        return ("collision", e["a"], e["b"])
    if e["event"] == "at_fault":
        return ("at_fault", e["vehicle"], e["pedestrian"])
    return (e["event"], e["agent"])


def compare_rollout(lines: list[dict], scenario: dict, params_override=None) -> Comparison:
    """Replays the rollout's set-up in ReferenceWorld and compares every step."""
    header, steps, end = lines[0], lines[1:-1], lines[-1]
    assert header["type"] == "header" and end["type"] == "end"
    ego_drive = header["ego_drive"]
    external = [] if ego_drive == "replay" else [header["ego"]]
    params = header["params"] if params_override is None else params_override
    world = ReferenceWorld(scenario, params, header["model"], external=external)
    cmp = Comparison()
    if world.horizon != header["horizon"]:
        cmp.problem(f"horizon {world.horizon} != {header['horizon']}")
    for a in header["agents"]:
        if world.control_of[a["id"]] != a["control"]:
            cmp.problem(f"agent {a['id']}: control {world.control_of[a['id']]} != {a['control']}")
    last_recorded = world.recorded_steps - 1
    outcome = None
    for k, line in enumerate(steps):
        if k > 0:
            if world.is_over:
                cmp.problem(f"reference episode over before Rust step {line['step']}")
                break
            if ego_drive == "replay" and world.step_index >= last_recorded:
                cmp.problem("reference record ended before the Rust rollout")
                break
            actions = {e: ego_drive for e in world.active_externals()}
            outcome = world.step(actions if ego_drive != "replay" else {})
        _compare_step(cmp, world, line, outcome)
        cmp.steps = line["step"]
    # Same stopping point.
    if end["reason"] == "episode_over" and not world.is_over:
        cmp.problem("Rust episode over, reference not")
    if end["reason"] == "record_ended" and world.step_index < last_recorded:
        cmp.problem("Rust record ended before the reference")
    return cmp


def _compare_step(cmp: Comparison, world: ReferenceWorld, line: dict, outcome):
    t = line["step"]
    if world.step_index != t:
        cmp.problem(f"step index {world.step_index} != {t}")
    ref = world.agent_states()
    rust = {a["id"]: a for a in line["agents"]}
    if set(ref) != set(rust):
        cmp.problem(f"step {t}: agents {sorted(ref)} != Rust {sorted(rust)}")
    for aid in set(ref) & set(rust):
        x, y, vx, vy, h = ref[aid]
        a = rust[aid]
        cmp.max_pos = max(cmp.max_pos, abs(x - a["x"]), abs(y - a["y"]))
        cmp.max_vel = max(cmp.max_vel, abs(vx - a["vx"]), abs(vy - a["vy"]))
        cmp.max_heading = max(cmp.max_heading, abs(h - a["heading"]))
    ref_edges = world.edges()
    rust_edges = {(e[0], e[1]): (e[2], e[3], e[4]) for e in line["edges"]}
    if set(ref_edges) != set(rust_edges):
        cmp.problem(
            f"step {t}: edge sets differ: only reference {sorted(set(ref_edges) - set(rust_edges))}"
            f", only Rust {sorted(set(rust_edges) - set(ref_edges))}"
        )
    for key in set(ref_edges) & set(rust_edges):
        (p0, u0, a0), (p1, u1, a1) = ref_edges[key], rust_edges[key]
        cmp.max_psi = max(cmp.max_psi, abs(p0 - p1))
        cmp.max_u = max(cmp.max_u, abs(u0 - u1))
        cmp.max_a = max(cmp.max_a, abs(a0 - a1))
    if outcome is None:
        return
    ref_events = sorted(_event_key_ref(e) for e in outcome["events"])
    rust_events = sorted(_event_key(e) for e in line["events"])
    if ref_events != rust_events:
        cmp.problem(f"step {t}: events {ref_events} != Rust {rust_events}")
    ref_rewards = {o["agent"]: o for o in outcome["agents"]}
    rust_rewards = {r["agent"]: r for r in line["rewards"]}
    if set(ref_rewards) != set(rust_rewards):
        cmp.problem(f"step {t}: reward agents {sorted(ref_rewards)} != {sorted(rust_rewards)}")
    for aid in set(ref_rewards) & set(rust_rewards):
        o, r = ref_rewards[aid], rust_rewards[aid]
        for term in ("progress", "success", "collision", "danger", "comfort"):
            cmp.max_reward = max(cmp.max_reward, abs(o["reward"][term] - r[term]))
        cmp.max_reward = max(cmp.max_reward, abs(o["total"] - r["total"]))
        for flag in ("terminated", "truncated", "action_clipped"):
            if o[flag] != r[flag]:
                cmp.problem(f"step {t}: agent {aid} {flag} {o[flag]} != {r[flag]}")


def _event_key_ref(e: tuple) -> tuple:
    return e


#: Per-run maxima collected by the cross-check tests (printed by conftest's terminal summary).
RESULTS: list[dict] = []


def record(set_name: str, model: str, cmp: Comparison):
    RESULTS.append(
        {
            "set": set_name,
            "model": model,
            "steps": cmp.steps,
            "pos": cmp.max_pos,
            "vel": cmp.max_vel,
            "psi": cmp.max_psi,
            "u": cmp.max_u,
            "a": cmp.max_a,
            "reward": cmp.max_reward,
        }
    )
