"""Recorded vs simulated pedestrian trajectories of the four models (like the paper's Fig. 5).

Reads the per-scenario files that ``sim-server eval-peds --trajectories DIR`` writes and saves one
PNG per scenario, ``<out>/table1_<scenario>.png``: one panel per model, each with the AV's recorded
path, the recorded pedestrian tracks and that model's simulated tracks.

Which scenarios (unless ``--scenarios`` names them), chosen by rule from the test results only:
1. *typical*: the scenario whose CR-SFM ADE is the median;
2. *SFM collides, CR-SFM does not* (the paper's qualitative case), if any: the one with the
   largest SFM ADE among them;
3. *collision*: the one in which the most models collide (ties: larger SFM ADE), if any collides;
4. *divergent*: the one where the ADEs of SFM and CR-SFM differ most (until there are three).
Each rule skips scenarios already chosen; a missing case falls back to the next divergent one.

Usage: ``python -m calibration.plot_trajectories --trajectories DIR --out docs/figures``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib
from sharedspace.models import EVALUATED_MODELS, LABELS

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

MODELS = list(EVALUATED_MODELS)
# One colour per model, in sim-core's order (the paper's figure: CV grey, SFM blue, ...).
_PALETTE = ["tab:gray", "tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown"]
COLOURS = dict(zip(MODELS, _PALETTE, strict=False))
PED_MARKERS = ["o", "s", "^", "D", "v", "P"]


def load(dirpath: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted(dirpath.glob("*.json"))}


def choose(scen: dict[str, dict]) -> list[tuple[str, str]]:
    """Three or four (scenario file stem, reason) pairs chosen by the module's rules."""
    names = sorted(scen)
    models = [m for m in MODELS if all(m in scen[n]["models"] for n in names)]
    chosen: list[tuple[str, str]] = []

    def ade(n: str, m: str) -> float:
        return scen[n]["models"][m]["ade"] if m in models else 0.0

    def divergent() -> str | None:
        rest = [n for n in names if n not in {c for c, _ in chosen}]
        return max(rest, key=lambda n: (abs(ade(n, "sfm") - ade(n, "cr_sfm")), n), default=None)

    ranked = sorted(names, key=lambda n: (ade(n, "cr_sfm"), n))
    chosen.append((ranked[len(ranked) // 2], "typical (median CR-SFM ADE)"))
    if "sfm" in models and "cr_sfm" in models:
        contrast = [
            n
            for n in names
            if n not in {c for c, _ in chosen}
            and scen[n]["models"]["sfm"]["collided"]
            and not scen[n]["models"]["cr_sfm"]["collided"]
        ]
        if contrast:
            best = max(contrast, key=lambda n: (ade(n, "sfm"), n))
            chosen.append((best, "SFM's pedestrian collides, CR-SFM's does not"))
    colliding = [
        n
        for n in names
        if n not in {c for c, _ in chosen} and any(scen[n]["models"][m]["collided"] for m in models)
    ]
    if colliding:
        best = max(
            colliding, key=lambda n: (sum(scen[n]["models"][m]["collided"] for m in models), ade(n, "sfm"), n)
        )
        chosen.append((best, "a simulated pedestrian collides"))
    while len(chosen) < 3:
        n = divergent()
        if n is None:
            break
        chosen.append((n, "largest SFM vs CR-SFM difference"))
    return chosen


def plot(data: dict, reason: str, out: Path) -> None:
    agents = data["agents"]
    models = [m for m in MODELS if m in data["models"]]
    cols = 2 if len(models) > 2 else len(models)
    rows = (len(models) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.6 * cols, 5.2 * rows + 0.6), squeeze=False)
    axes = axes.ravel()
    for ax in axes[len(models) :]:
        ax.set_visible(False)
    # One view for every panel, around the pedestrians: their records and the non-CV simulations
    # (the AV's path and CV's straight lines may leave it), at least 12 m wide.
    pts = [p for a in agents if a["kind"] == "pedestrian" for p in a["recorded"]]
    pts += [p for m in models if m != "cv" for t in data["models"][m]["tracks"] for p in t["positions"]]
    cx = 0.5 * (min(p[0] for p in pts) + max(p[0] for p in pts))
    cy = 0.5 * (min(p[1] for p in pts) + max(p[1] for p in pts))
    half = max(
        6.0,
        0.5
        * max(
            max(p[0] for p in pts) - min(p[0] for p in pts), max(p[1] for p in pts) - min(p[1] for p in pts)
        )
        + 2.0,
    )
    x0, x1, y0, y1 = cx - half, cx + half, cy - half, cy + half
    peds = [a for a in agents if a["kind"] == "pedestrian"]
    ped_index = {a["id"]: k for k, a in enumerate(peds)}
    for ax, m in zip(axes, models, strict=False):
        for a in agents:
            xs = [p[0] for p in a["recorded"]]
            ys = [p[1] for p in a["recorded"]]
            if a["kind"] == "vehicle":
                ax.plot(
                    xs,
                    ys,
                    ".-",
                    color="tab:red",
                    lw=5,
                    ms=4,
                    alpha=0.3,
                    solid_capstyle="round",
                    label="AV (recorded, dot per 0.5 s)" if a["ego"] else "vehicle (recorded)",
                )
                ax.annotate(
                    "",
                    xy=(xs[-1], ys[-1]),
                    xytext=(xs[-2], ys[-2]),
                    arrowprops={"arrowstyle": "->", "color": "tab:red"},
                )
            else:
                k = ped_index[a["id"]]
                ax.plot(xs, ys, "x--", color="black", ms=4, lw=0.8, label="recorded" if k == 0 else None)
                ax.plot(xs[0], ys[0], PED_MARKERS[k % len(PED_MARKERS)], color="black", ms=8, mfc="none")
        res = data["models"][m]
        for t in res["tracks"]:
            k = ped_index.get(t["id"], 0)
            xs = [p[0] for p in t["positions"]]
            ys = [p[1] for p in t["positions"]]
            ax.plot(
                xs,
                ys,
                "-",
                marker=PED_MARKERS[k % len(PED_MARKERS)],
                color=COLOURS[m],
                ms=3.5,
                lw=1.4,
                label="simulated" if k == 0 else None,
            )
        flag = "  COLLISION" if res["collided"] else ""
        ax.set_title(
            f"{LABELS[m]}: ADE {res['ade']:.2f} m, FDE {res['fde']:.2f} m{flag}",
            fontsize=10,
            color="tab:red" if res["collided"] else "black",
        )
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
        ax.set_aspect("equal", adjustable="box")
        ax.grid(True, lw=0.3)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(loc="best", fontsize=7)
    fig.suptitle(
        f"{data['scenario']} ({data['split']} split, pool {data['pool']}): recorded (black x)"
        f" vs simulated pedestrians, start = open marker\nchosen as: {reason}",
        fontsize=11,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--trajectories",
        type=Path,
        required=True,
        help="folder written by eval-peds --trajectories (test split)",
    )
    ap.add_argument("--out", type=Path, default=Path("docs/figures"))
    ap.add_argument("--scenarios", default=None, help="comma-separated names instead of the rules")
    args = ap.parse_args()
    scen = load(args.trajectories)
    if not scen:
        ap.error(f"no scenario files in {args.trajectories}")
    if args.scenarios:
        chosen = [(n.strip(), "named on the command line") for n in args.scenarios.split(",")]
    else:
        chosen = choose(scen)
    for name, reason in chosen:
        out = args.out / f"table1_{name}.png"
        plot(scen[name], reason, out)
        print(f"{out}: {reason}")


if __name__ == "__main__":
    main()
