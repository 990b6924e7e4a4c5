"""The fallback picture of ``render()``: one agent's observation graph in its ego frame (from a
step reply: ``features``, ``adjacency``, ``mask``), drawn with numpy only, for when the server's
publications have not arrived. The scene itself is drawn by :mod:`sharedspace.scene_plot`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["render_observation", "Canvas"]

BACKGROUND = (245, 245, 240)
VEHICLE = (200, 40, 40)
EXTERNAL = (30, 90, 220)
PEDESTRIAN = (40, 150, 60)
EDGE = (250, 150, 0)
GRID = (225, 225, 220)


class Canvas:
    """An RGB image with a world → pixel transform (``scale`` px per m, y up)."""

    def __init__(self, width: int, height: int, center: tuple[float, float], scale: float):
        self.w, self.h = int(width), int(height)
        self.img = np.empty((self.h, self.w, 3), dtype=np.uint8)
        self.img[:] = BACKGROUND
        self.cx, self.cy = float(center[0]), float(center[1])
        self.scale = float(scale)
        self._yy, self._xx = np.mgrid[0 : self.h, 0 : self.w]

    def px(self, x: float, y: float) -> tuple[float, float]:
        return (
            (x - self.cx) * self.scale + self.w / 2.0,
            self.h / 2.0 - (y - self.cy) * self.scale,
        )

    def grid(self, step_m: float = 5.0) -> None:
        half_w, half_h = self.w / 2 / self.scale, self.h / 2 / self.scale
        for gx in np.arange(
            np.floor((self.cx - half_w) / step_m) * step_m, self.cx + half_w, step_m
        ):
            c = int(round(self.px(gx, 0)[0]))
            if 0 <= c < self.w:
                self.img[:, c] = GRID
        for gy in np.arange(
            np.floor((self.cy - half_h) / step_m) * step_m, self.cy + half_h, step_m
        ):
            r = int(round(self.px(0, gy)[1]))
            if 0 <= r < self.h:
                self.img[r, :] = GRID

    def disc(self, x: float, y: float, radius_m: float, color, min_px: float = 4.0) -> None:
        u, v = self.px(x, y)
        r = max(radius_m * self.scale, min_px)
        r0, r1 = max(int(v - r - 1), 0), min(int(v + r + 2), self.h)
        c0, c1 = max(int(u - r - 1), 0), min(int(u + r + 2), self.w)
        if r0 >= r1 or c0 >= c1:
            return
        yy, xx = self._yy[r0:r1, c0:c1], self._xx[r0:r1, c0:c1]
        inside = (xx + 0.5 - u) ** 2 + (yy + 0.5 - v) ** 2 <= r * r
        self.img[r0:r1, c0:c1][inside] = color

    def line(
        self,
        x0: float,
        y0: float,
        x1: float,
        y1: float,
        color,
        width_px: float = 1.0,
        alpha: float = 1.0,
    ) -> None:
        u0, v0 = self.px(x0, y0)
        u1, v1 = self.px(x1, y1)
        n = int(max(abs(u1 - u0), abs(v1 - v0)) * 2) + 2
        t = np.linspace(0.0, 1.0, n)
        us, vs = u0 + (u1 - u0) * t, v0 + (v1 - v0) * t
        half = max(int(round(width_px / 2)), 0)
        color = np.asarray(color, dtype=np.float32)
        for du in range(-half, half + 1):
            for dv in range(-half, half + 1):
                c = np.round(us + du).astype(np.int64)
                r = np.round(vs + dv).astype(np.int64)
                ok = (c >= 0) & (c < self.w) & (r >= 0) & (r < self.h)
                if alpha >= 1.0:
                    self.img[r[ok], c[ok]] = color.astype(np.uint8)
                else:
                    cur = self.img[r[ok], c[ok]].astype(np.float32)
                    self.img[r[ok], c[ok]] = (cur * (1 - alpha) + color * alpha).astype(np.uint8)

    def heading(self, x: float, y: float, theta: float, length_m: float, color) -> None:
        self.line(x, y, x + length_m * np.cos(theta), y + length_m * np.sin(theta), color, 1.0)


def render_observation(
    features: np.ndarray,
    adjacency: np.ndarray,
    mask: np.ndarray,
    *,
    size: tuple[int, int] = (480, 480),
    view_m: float = 40.0,
) -> np.ndarray:
    """An RGB picture of one observation graph in the ego frame (ego at the centre, heading
    up-right along +x): nodes at ``rel_x, rel_y``, edges ``adjacency[a, b] > 0``."""
    h, w = size
    feats = np.asarray(features, dtype=np.float64)
    adj = np.asarray(adjacency, dtype=np.float64)
    present = np.flatnonzero(np.asarray(mask).astype(bool))
    canvas = Canvas(w, h, (0.0, 0.0), min(w, h) / float(view_m))
    canvas.grid()
    amax = float(adj.max()) if adj.size and adj.max() > 0 else 1.0
    for a in present:
        for b in present:
            if a != b and adj[a, b] > 0:
                s = adj[a, b] / amax
                canvas.line(
                    feats[a, 0],
                    feats[a, 1],
                    feats[b, 0],
                    feats[b, 1],
                    EDGE,
                    1.0 + 2.0 * s,
                    0.25 + 0.75 * s,
                )
    for node in present:
        x, y, r = feats[node, 0], feats[node, 1], feats[node, 6]
        color = EXTERNAL if node == 0 else (VEHICLE if feats[node, 7] > 0.5 else PEDESTRIAN)
        canvas.disc(x, y, r if r > 0 else 0.3, color)
        canvas.heading(x, y, feats[node, 5], (r if r > 0 else 0.3) + 0.8, (20, 20, 20))
    if len(present):
        canvas.line(0.0, 0.0, feats[0, 8], feats[0, 9], (120, 120, 120), 1.0, 0.5)
    return canvas.img
