"""The scene drawing (scene_plot): what render(), the animations and the figures show."""

from __future__ import annotations

import numpy as np

from sharedspace.scene_plot import CONTROLLED, PEDESTRIAN, VEHICLE, Agent, Frame, scene_rgb


def _pixels_near(img: np.ndarray, hex_color: str, tol: int = 12) -> int:
    rgb = tuple(int(hex_color[i : i + 2], 16) for i in (1, 3, 5))
    return int((np.abs(img.astype(int) - rgb).sum(-1) < tol).sum())


def test_the_view_covers_every_agent_and_goal_however_far_apart():
    frame = Frame(
        agents=[
            Agent(0, "vehicle", 0.0, 0.0, heading=0.3, controlled=True, length=4.5, width=1.8),
            Agent(1, "vehicle", 80.0, 5.0, heading=3.0, length=4.5, width=1.8),
            Agent(2, "pedestrian", 40.0, -60.0, vx=1.0),
        ],
        goals=[(-30.0, 40.0)],
        t=3.5,
        step=7,
    )
    img = scene_rgb(frame, size=(400, 400), legend=False)
    assert img.shape == (400, 400, 3) and img.dtype == np.uint8
    for color in (CONTROLLED, VEHICLE, PEDESTRIAN):
        assert _pixels_near(img, color) > 5, color


def test_a_vehicle_is_its_rectangle_not_a_disc():
    # A long thin car along +x covers a wide, flat patch of pixels.
    frame = Frame(agents=[Agent(0, "vehicle", 0.0, 0.0, length=8.0, width=1.0, controlled=True)])
    img = scene_rgb(frame, size=(300, 300), view=(-6, 6, -6, 6), legend=False)
    rows, cols = np.nonzero(np.abs(img.astype(int) - (31, 95, 208)).sum(-1) < 12)
    assert (cols.max() - cols.min()) > 4 * (rows.max() - rows.min())


def test_a_crowds_risk_graph_keeps_only_the_strongest_edges_per_agent():
    from sharedspace.scene_plot import _strongest

    edges = [(i, j, float(i * 100 + j)) for i in range(40) for j in range(40) if i != j]
    kept = _strongest(edges, top_k=2)
    assert len(kept) == 80
    assert all(e[1] in (38, 39) or (e[0] >= 38 and e[1] in (37, 38, 39)) for e in kept)
