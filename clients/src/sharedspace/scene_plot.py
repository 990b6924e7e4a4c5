"""One drawing of a scene, for ``render()``, episode animations and paper-style figures.

:func:`draw_scene` draws a :class:`Frame` on a matplotlib ``Axes``: vehicles as their oriented
rectangles (the controlled ones in blue, with their goal), pedestrians as discs with velocity
arrows, recent trails, the risk graph's strongest ``top_k`` edges per observer (width and colour
by ``A``, so a crowd stays readable), a scale bar, a legend and the time. :func:`scene_rgb`
renders a frame to an RGB array (Agg, no display needed). The view covers every agent and goal
unless told otherwise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Frame", "Agent", "draw_scene", "scene_rgb", "frame_from_publications"]

CONTROLLED = "#1f5fd0"
VEHICLE = "#c62828"
REACTIVE = "#e0a030"
PEDESTRIAN = "#2e7d32"
#: A pedestrian a client drives (model.md 2b), e.g. an adversary: purple, ringed.
EXTERNAL_PEDESTRIAN = "#8e24aa"
GOAL = "#1f5fd0"
EDGE_CMAP = "YlOrRd"


@dataclass
class Agent:
    """One agent at one step: position (m), velocity (m/s), heading (rad), footprint."""

    id: int
    kind: str  # "vehicle" | "pedestrian"
    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    heading: float = 0.0
    controlled: bool = False
    reactive: bool = False  # moved by a reactive vehicle model (docs/MODEL.md "Traffic")
    length: float | None = None  # rectangle footprint, m (vehicles)
    width: float | None = None
    radius: float = 0.3  # disc footprint, m (pedestrians)


@dataclass
class Frame:
    """What one picture shows."""

    agents: list[Agent]
    #: Risk-graph edges ``(observer id, target id, A)``.
    edges: list[tuple[int, int, float]] = field(default_factory=list)
    #: Goals of the controlled vehicles, world frame.
    goals: list[tuple[float, float]] = field(default_factory=list)
    t: float | None = None
    step: int | None = None
    #: Recent positions per agent id (oldest first), drawn as fading trails.
    trails: Mapping[int, Sequence[tuple[float, float]]] = field(default_factory=dict)
    #: Free text under the time (reward terms, outcome, ...).
    note: str = ""


def _bounds(frame: Frame, margin: float = 4.0) -> tuple[float, float, float, float]:
    xs = [a.x for a in frame.agents] + [g[0] for g in frame.goals]
    ys = [a.y for a in frame.agents] + [g[1] for g in frame.goals]
    if not xs:
        return -10.0, 10.0, -10.0, 10.0
    return min(xs) - margin, max(xs) + margin, min(ys) - margin, max(ys) + margin


def _strongest(edges: Sequence[tuple[int, int, float]], top_k: int) -> list[tuple[int, int, float]]:
    by_observer: dict[int, list[tuple[int, int, float]]] = {}
    for e in edges:
        by_observer.setdefault(e[0], []).append(e)
    out = []
    for es in by_observer.values():
        out += sorted(es, key=lambda e: -e[2])[:top_k]
    return out


def _set_window(ax, frame: Frame, view) -> None:
    x0, x1, y0, y1 = view or _bounds(frame)
    # Square-ish window so that rectangles are not distorted.
    span = max(x1 - x0, y1 - y0)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    ax.set_xlim(cx - span / 2, cx + span / 2)
    ax.set_ylim(cy - span / 2, cy + span / 2)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def _draw_edges(ax, frame: Frame, pos: dict, cmap, top_k: int, a_max: float | None) -> None:
    """Each agent's ``top_k`` strongest risk edges, darker and wider the larger ``A``."""
    edges = _strongest(frame.edges, top_k)
    amax = a_max or max((e[2] for e in edges), default=1.0) or 1.0
    for src, dst, a in sorted(edges, key=lambda e: e[2]):
        if src in pos and dst in pos:
            s = min(a / amax, 1.0)
            ax.plot(
                [pos[src].x, pos[dst].x],
                [pos[src].y, pos[dst].y],
                color=cmap(0.25 + 0.75 * s),
                lw=0.6 + 2.4 * s,
                alpha=0.35 + 0.6 * s,
                zorder=1,
            )


def _draw_vehicle(ax, a: Agent) -> None:
    import matplotlib.patches as mpatches

    length, width = a.length or 4.5, a.width or 1.8
    color = CONTROLLED if a.controlled else REACTIVE if a.reactive else VEHICLE
    c, s = np.cos(a.heading), np.sin(a.heading)
    corner = (a.x - (c * length - s * width) / 2, a.y - (s * length + c * width) / 2)
    ax.add_patch(
        mpatches.Rectangle(
            corner, length, width, angle=np.degrees(a.heading), fc=color, ec="black", lw=0.6,
            zorder=4,
        )
    )  # fmt: skip
    ax.plot(
        [a.x, a.x + c * length * 0.5], [a.y, a.y + s * length * 0.5], color="white", lw=1.0,
        zorder=4,
    )  # fmt: skip


def _draw_pedestrian(ax, a: Agent) -> None:
    import matplotlib.patches as mpatches

    color = EXTERNAL_PEDESTRIAN if a.controlled else PEDESTRIAN
    ax.add_patch(mpatches.Circle((a.x, a.y), a.radius, fc=color, ec="black", lw=0.4, zorder=4))
    # A dot of a few pixels, so that a pedestrian stays visible in a wide view.
    ax.plot(a.x, a.y, "o", ms=3.5, color=color, zorder=4)
    if a.controlled:  # ringed, so that it stands out in a crowd
        ax.plot(a.x, a.y, "o", ms=11, mfc="none", mec=color, mew=1.5, zorder=4)
    if abs(a.vx) + abs(a.vy) > 1e-3:
        ax.arrow(a.x, a.y, a.vx, a.vy, width=0.05, head_width=0.3, color=color, zorder=3)


def _draw_scale_and_label(ax, frame: Frame) -> None:
    """A scale bar of a round number of metres (about a fifth of the window), the time."""
    lo_x, hi_x = ax.get_xlim()
    lo_y, _ = ax.get_ylim()
    bar = max(1.0, float(10 ** np.floor(np.log10((hi_x - lo_x) / 5))))
    bar *= 5 if (hi_x - lo_x) / bar >= 25 else (2 if (hi_x - lo_x) / bar >= 10 else 1)
    bx, by = lo_x + 0.04 * (hi_x - lo_x), lo_y + 0.04 * (hi_x - lo_x)
    ax.plot([bx, bx + bar], [by, by], color="black", lw=2.5, zorder=6)
    ax.text(bx + bar / 2, by + 0.01 * (hi_x - lo_x), f"{bar:g} m", ha="center", va="bottom")
    label = []
    if frame.t is not None:
        label.append(f"t = {frame.t:.1f} s")
    if frame.step is not None:
        label.append(f"step {frame.step}")
    if label or frame.note:
        ax.text(
            0.02,
            0.98,
            "   ".join(label) + (f"\n{frame.note}" if frame.note else ""),
            transform=ax.transAxes,
            va="top",
            fontsize=9,
            bbox=dict(fc="white", ec="none", alpha=0.8),
        )


def _draw_legend(ax, frame: Frame, cmap, top_k: int) -> None:
    import matplotlib.patches as mpatches
    from matplotlib.lines import Line2D

    handles = [
        mpatches.Patch(color=CONTROLLED, label="controlled vehicle"),
        mpatches.Patch(color=VEHICLE, label="replayed vehicle"),
        *(
            [mpatches.Patch(color=REACTIVE, label="reactive vehicle")]
            if any(a.reactive for a in frame.agents)
            else []
        ),
        Line2D([], [], marker="o", ls="", color=PEDESTRIAN, label="pedestrian"),
        *(
            [
                Line2D(
                    [], [], marker="o", ls="", color=EXTERNAL_PEDESTRIAN, label="driven pedestrian"
                )
            ]
            if any(a.controlled and a.length is None for a in frame.agents)
            else []
        ),
        Line2D([], [], marker="*", ls="", ms=10, color=GOAL, label="goal"),
        Line2D([], [], color=cmap(0.9), lw=2.5, label=f"risk A (top {top_k} per agent)"),
    ]
    ax.legend(handles=handles, loc="lower right", fontsize=7, framealpha=0.85)


def draw_scene(
    ax,
    frame: Frame,
    *,
    top_k: int = 2,
    view: tuple[float, float, float, float] | None = None,
    legend: bool = True,
    a_max: float | None = None,
) -> None:
    """Draws ``frame`` on ``ax`` (equal aspect, metres). ``view`` = (x0, x1, y0, y1) fixes the
    window (default: every agent and goal with a margin); ``a_max`` fixes the edge colour scale
    (default: this frame's largest ``A``)."""
    import matplotlib.patches as mpatches
    from matplotlib import colormaps

    _set_window(ax, frame, view)
    pos = {a.id: a for a in frame.agents}
    cmap = colormaps[EDGE_CMAP]
    _draw_edges(ax, frame, pos, cmap, top_k, a_max)
    for aid, trail in frame.trails.items():
        if len(trail) > 1 and aid in pos:
            xy = np.asarray(trail)
            color = CONTROLLED if pos[aid].controlled else "#777777"
            ax.plot(xy[:, 0], xy[:, 1], color=color, lw=1.0, alpha=0.5, zorder=2)
    for gx, gy in frame.goals:
        ax.plot(gx, gy, marker="*", ms=14, color=GOAL, mec="white", zorder=5)
        ax.add_patch(mpatches.Circle((gx, gy), 2.0, fill=False, ec=GOAL, ls="--", lw=0.8))
    for a in frame.agents:
        (_draw_vehicle if a.kind == "vehicle" else _draw_pedestrian)(ax, a)
    _draw_scale_and_label(ax, frame)
    if legend:
        _draw_legend(ax, frame, cmap, top_k)


def scene_rgb(frame: Frame, size: tuple[int, int] = (480, 480), **kw) -> np.ndarray:
    """``frame`` as an RGB ``uint8 [H, W, 3]`` picture (``size`` = (H, W) pixels)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    h, w = size
    fig = Figure(figsize=(w / 100, h / 100), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0, 0, 1, 1))
    draw_scene(ax, frame, **kw)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def _flags(values, n: int) -> np.ndarray:
    """A ``[n]`` ``|u1`` array of a message as booleans (all false when the message has none)."""
    return np.zeros(n, bool) if values is None else np.asarray(values).reshape(-1).astype(bool)


def frame_from_publications(
    states: Mapping,
    risk_graph: Mapping | None,
    agents: Mapping[int, Mapping] | None = None,
    note: str = "",
    trails: Mapping[int, Sequence[tuple[float, float]]] | None = None,
) -> Frame:
    """A :class:`Frame` from a ``StatesMsg`` and a ``RiskGraphMsg`` (protocol/SPEC.md). The
    message's footprints, goals and external flags draw the agents, the controlled vehicles'
    goals and their colour; ``agents`` (the episode's ``AgentDesc`` by id) stands in for them
    in messages from senders that leave those fields out."""
    agents = agents or {}
    ids = np.asarray(states["ids"], dtype=np.int64)
    n = len(ids)
    kinds = np.asarray(states["kinds"])
    pos = np.asarray(states["positions"], dtype=np.float64).reshape(-1, 2)
    vel = np.asarray(states.get("velocities", np.zeros_like(pos)), dtype=np.float64).reshape(-1, 2)
    heads = np.asarray(states["headings"], dtype=np.float64).reshape(-1)
    reactive = _flags(states.get("reactive"), n)
    sent_sizes = states.get("sizes")
    sizes = None if sent_sizes is None else np.asarray(sent_sizes, np.float64).reshape(-1, 2)
    sent_external = states.get("external")
    external = (
        _flags(sent_external, n)
        if sent_external is not None
        else np.array([bool(agents.get(int(a), {}).get("external")) for a in ids], bool)
    )
    sent_goals = states.get("goals")
    goal_of = None if sent_goals is None else np.asarray(sent_goals, np.float64).reshape(-1, 2)
    out, goals = [], []
    for i, aid in enumerate(ids.tolist()):
        desc = agents.get(aid, {})
        vehicle = int(kinds[i]) == 0
        if sizes is not None:
            length, width = float(sizes[i, 0]), float(sizes[i, 1])
            radius = 0.5 * length
        else:
            length, width = desc.get("length"), desc.get("width")
            radius = float(desc.get("radius") or 0.3)
        out.append(
            Agent(
                id=aid,
                kind="vehicle" if vehicle else "pedestrian",
                x=float(pos[i, 0]),
                y=float(pos[i, 1]),
                vx=float(vel[i, 0]),
                vy=float(vel[i, 1]),
                heading=float(heads[i]),
                controlled=bool(external[i]),
                reactive=bool(reactive[i]),
                length=length if vehicle else None,
                width=width if vehicle else None,
                radius=radius,
            )
        )
        if external[i] and vehicle and goal_of is not None:
            goals.append((float(goal_of[i, 0]), float(goal_of[i, 1])))
    edges = []
    if risk_graph is not None:
        edges = [
            (int(s), int(d), float(a))
            for s, d, a in zip(risk_graph["src"], risk_graph["dst"], risk_graph["a"], strict=False)
        ]
    t = states.get("t")
    step = states.get("step")
    return Frame(
        agents=out,
        edges=edges,
        goals=goals,
        t=None if t is None else float(t),
        step=None if step is None else int(step),
        trails=trails or {},
        note=note,
    )
