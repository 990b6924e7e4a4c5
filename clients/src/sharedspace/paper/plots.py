"""PNG figures: learning curves, test-episode profiles against the human driver (paper Figs. 6-7),
and a scene with its risk graph.

    python -m sharedspace.paper.plots --run RUN_DIR [--eval-json EVAL.json] [--scene 0 --step 6]
        [--out DIR]
"""

from __future__ import annotations

import csv
import json
import math
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sharedspace.cli import run_command
from sharedspace.local_server import rollout  # noqa: E402
from sharedspace.models import DEFAULT_MODEL  # noqa: E402
from sharedspace.pool import load_pool  # noqa: E402
from sharedspace.train.config import command_parser  # noqa: E402

__all__ = ["read_metrics", "plot_learning_curves", "plot_profiles", "plot_scene", "main"]

CURVES = (
    "train/episode_return",
    "train/success",
    "train/collision",
    "eval/success",
    "eval/collision",
    "eval/avg_speed",
    "train/loss_qvalue",
    "train/alpha",
    "train/env_time_share",
)


def read_metrics(csv_path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{metric: (frames, values)}`` from a run's long-format metrics.csv."""
    series: dict[str, list[tuple[float, float]]] = defaultdict(list)
    with open(csv_path, newline="") as f:
        for row in csv.DictReader(f):
            series[row["metric"]].append((float(row["frames"]), float(row["value"])))
    return {
        k: (np.array([a for a, _ in v]), np.array([b for _, b in v])) for k, v in series.items()
    }


def _smooth(y: np.ndarray, n: int = 10) -> np.ndarray:
    if len(y) < n:
        return y
    c = np.cumsum(np.insert(y, 0, 0.0))
    head = c[1:n] / np.arange(1, n)
    return np.concatenate([head, (c[n:] - c[:-n]) / n])


def plot_learning_curves(csv_path: str | Path, out: str | Path, metrics: Sequence[str] = CURVES):
    data = read_metrics(csv_path)
    names = [m for m in metrics if m in data]
    cols = 3
    rows = max(1, math.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.8 * rows), squeeze=False)
    for ax, name in zip(axes.flat, names, strict=False):
        x, y = data[name]
        if len(x) < 20:  # sparse series (evaluations): points, no smoothing
            ax.plot(x, y, "o-", color="C0")
        else:
            ax.plot(x, y, alpha=0.3, color="C0")
            ax.plot(x, _smooth(y), color="C0")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("frames", fontsize=8)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(names) :]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _policy_profile(
    ep: dict[str, Any], heading0: float, dt: float, omega_max: float
) -> dict[str, np.ndarray]:
    """Speed, acceleration and heading of a policy episode: speed from the ego node feature,
    heading integrated from the yaw-rate actions as the unicycle does."""
    speeds = np.asarray(ep["speeds"])
    heading = [heading0]
    for a in ep["actions"]:
        heading.append(heading[-1] + min(max(a[1], -1.0), 1.0) * omega_max * dt)
    return {"speed": speeds, "acc": np.diff(speeds) / dt, "heading": np.unwrap(np.array(heading))}


def plot_profiles(
    eval_json: str | Path,
    out: str | Path,
    omega_max: float,
    max_episodes: int = 4,
    dt: float = 0.5,
):
    """Speed / acceleration / heading over time of test episodes, policy vs recorded human
    (``omega_max``: the vehicle's yaw-rate limit, rad/s, which maps the actions)."""
    rec = json.loads(Path(eval_json).read_text())
    human = {h["scenario_index"]: h for h in rec["human"]}
    eps = rec["episodes"][:max_episodes]
    fig, axes = plt.subplots(len(eps), 3, figsize=(12, 2.6 * len(eps)), squeeze=False)
    for row, ep in zip(axes, eps, strict=True):
        h = human[ep["scenario_index"]]
        pol = _policy_profile(ep, h["headings"][0], dt, omega_max)
        hs = np.asarray(h["speeds"])
        hum = {
            "speed": hs,
            "acc": np.diff(hs) / dt,
            "heading": np.unwrap(np.asarray(h["headings"])),
        }
        for ax, key, unit in zip(
            row, ("speed", "acc", "heading"), ("m/s", "m/s²", "rad"), strict=True
        ):
            ax.plot(np.arange(len(pol[key])) * dt, pol[key], label=f"policy ({ep['status']})")
            ax.plot(np.arange(len(hum[key])) * dt, hum[key], "--", label="human")
            ax.set_title(f"scenario {ep['scenario_index']}: {key}", fontsize=9)
            ax.set_xlabel("t (s)", fontsize=8)
            ax.set_ylabel(unit, fontsize=8)
            ax.grid(alpha=0.3)
        row[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_scene(
    scenario: dict[str, Any], step: int, out: str | Path, pedestrian_model: str = DEFAULT_MODEL
):
    """The scene at ``step`` (every vehicle replaying its record, pedestrians simulated by the
    Rust core through ``sim-server rollout``) with the directed risk-graph edges coloured by
    ``A = psi (1 + lambda u)``."""
    header, steps = rollout(scenario, pedestrian_model, steps=step)
    state = steps[-1]
    shape = header["params"]["vehicle"]["shape"]  # {"type": "rect", "length", "width"}
    fig, ax = plt.subplots(figsize=(7, 6))
    pos = {a["id"]: (a["x"], a["y"]) for a in state["agents"]}
    edges = state["edges"]
    a_vals = [e[4] for e in edges] or [0.0, 1.0]
    norm = matplotlib.colors.Normalize(vmin=0.0, vmax=max(a_vals))
    cmap = plt.get_cmap("inferno_r")
    for i, j, _psi, _u, a in edges:
        ax.annotate(
            "",
            xy=pos[j],
            xytext=pos[i],
            arrowprops=dict(
                arrowstyle="->",
                color=cmap(norm(a)),
                lw=0.8 + 3.0 * norm(a),
                alpha=0.85,
                shrinkA=6,
                shrinkB=6,
                connectionstyle="arc3,rad=0.12",
            ),
        )
    ego = int(scenario["ego"])
    ped_radius = header["params"]["ped_radius"]
    for agent in state["agents"]:
        aid, x, y = agent["id"], agent["x"], agent["y"]
        vx, vy, th = agent["vx"], agent["vy"], agent["heading"]
        if scenario["agents"][aid]["kind"] == "vehicle":
            length = shape.get("length", 2 * shape.get("radius", 0.0))
            width = shape.get("width", length)
            rect = matplotlib.patches.Rectangle(
                (x - length / 2, y - width / 2),
                length,
                width,
                angle=math.degrees(th),
                rotation_point="center",
                color="C3" if aid == ego else "C1",
                alpha=0.7,
            )
            ax.add_patch(rect)
        else:
            ax.add_patch(matplotlib.patches.Circle((x, y), ped_radius, color="C0", alpha=0.8))
        ax.arrow(x, y, vx * 0.5, vy * 0.5, width=0.05, color="k", alpha=0.6)
        ax.text(x + 0.4, y + 0.4, ("ego " if aid == ego else "") + str(aid), fontsize=8)
    xs = [p[0] for p in pos.values()]
    ys = [p[1] for p in pos.values()]
    pad = 4.0
    ax.set_xlim(min(xs) - pad, max(xs) + pad)
    ax.set_ylim(min(ys) - pad, max(ys) + pad)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, label="A(i, j)")
    ax.set_title(f"{scenario['name']} at t = {state['time']:.1f} s: risk graph (edge i -> j)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    ap = command_parser("python -m sharedspace.paper.plots", __doc__)
    ap.add_argument("--run", default="", help="run directory (its metrics.csv)")
    ap.add_argument("--eval-json", default="", help="JSON written by evaluate --json")
    ap.add_argument("--scene", type=int, default=-1, help="pool index of a scenario to draw")
    ap.add_argument("--step", type=int, default=6, help="step of the scene")
    ap.add_argument("--pool", default="", help="scenario file (default hbs-paper.json)")
    ap.add_argument("--out", default=".", help="output directory")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.run:
        plot_learning_curves(Path(args.run) / "metrics.csv", out / "learning_curves.png")
    pool = load_pool(args.pool or None)
    if args.eval_json:
        # The yaw-rate limit the server maps actions with (its shipped parameters).
        omega_max = rollout(pool[0], DEFAULT_MODEL, steps=0)[0]["params"]["vehicle"]["omega_max"]
        plot_profiles(args.eval_json, out / "profiles.png", omega_max)
    if args.scene >= 0:
        plot_scene(pool[args.scene], args.step, out / f"scene_{args.scene}_t{args.step}.png")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(main))
