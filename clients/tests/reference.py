"""Pure-numpy reference of the sharedspace world step (shared/spec/model.md).

:class:`ReferenceWorld` reproduces ``sim_core::world::World`` of the Rust core: the same step
order, the same decisions and the same floating-point expressions where that is cheap, so that a
rollout of both agrees to round-off (the cross-check test compares them step by step). It works on
dense ``N x N`` arrays over the agents present (no neighbour grid): it is the readable, in-process
baseline, not a fast simulator.

One step from the state at ``t`` (whose beliefs ``u_t``, risk ``psi_t`` and graph ``A_t`` were
built when ``t`` was reached), as ``World::step``:

1. external agents whose episode ended at the previous step leave;
2. every agent moves to ``t + 1`` at once: external actions (unicycle for vehicles), social
   forces weighted by ``u_t`` and ``psi_t`` (``sfm``, ``ra_sfm``, ``cr_sfm``), constant initial
   velocity (``cv``), or the record (``replay``, non-reactive agents, non-external vehicles);
3. simulated pedestrians within ``ped_goal_radius`` of their goal and replayed agents past their
   record leave; agents recorded from ``t + 1`` enter;
4. observe at ``t + 1``: beliefs (``u_{t+1}``), clearances, ``psi_{t+1}`` and ``A_{t+1}`` for every
   ordered pair whose centres are at most ``perception_radius`` apart;
5. events (collisions, whose fault they are, arrivals) and the reward terms of every active
   external agent.

Parameters are the ``WorldParams`` of the Rust core as a nested dict (the ``params`` object of a
rollout header, or any subset of it: missing fields keep model.md's defaults).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from sharedspace.models import PEDESTRIAN_MODELS as _MODELS
from sharedspace.names import FEATURE_NAMES
from sharedspace.pool import recorded_headings

__all__ = [
    "DEFAULT_PARAMS",
    "PEDESTRIAN_MODELS",
    "merge_params",
    "VarianceSchedule",
    "disc_rect_gap",
    "ReferenceWorld",
    "StepRefused",
]

PEDESTRIAN_MODELS = _MODELS

_SFM_DEFAULTS = {
    "tau": 0.5,
    "a_ped": 2.1,
    "b_ped": 0.3,
    "a_veh": 4.0,
    "b_veh": 1.0,
    "lambda1": 1.0,
    "lambda2": 1.0,
    "lambda3": 1.0,
}

#: ``WorldParams::default()`` of the Rust core (model.md's values).
DEFAULT_PARAMS: dict[str, Any] = {
    "dt": 0.5,
    "ped_radius": 0.3,
    "ped_speed_max": 2.0,
    "ped_goal_radius": 0.5,
    "ped_acc_max": 2.0,
    "perception_radius": 15.0,
    "horizon_extra": 15.0,
    "vehicle": {
        "shape": {"type": "rect", "length": 4.0, "width": 1.8},
        "acc_max": 2.0,
        "omega_max": 0.2,
        "speed_max": 6.0,
        "goal_radius": 2.0,
    },
    # The reactive vehicle model's (docs/MODEL.md 11); this reference replays every vehicle, as
    # the paper's set-up does, so it only carries them.
    "traffic": {
        "acc": 1.0,
        "comfortable_decel": 1.5,
        "time_headway": 1.0,
        "min_gap": 2.0,
        "exponent": 4.0,
        "corridor_margin": 0.3,
        "lookahead_max": 40.0,
    },
    "cognition": {"s0": 1.0, "q": 0.3, "s_o": 0.5, "prediction": "constant_velocity"},
    "risk": {"gamma1": 0.5, "gamma2": 1.0, "lambda": 1.0},
    "pedestrians": {
        "sfm": dict(_SFM_DEFAULTS),
        "ra_sfm": dict(_SFM_DEFAULTS),
        "cr_sfm": dict(_SFM_DEFAULTS),
    },
    "reward": {
        "progress": 1.0,
        "success": 10.0,
        "collision": -20.0,
        "danger": 20.0,
        "danger_clearance": 1.0,
        "jerk_penalty": 0.05,
        "yaw_rate_penalty": 0.5,
    },
}


def merge_params(base: Mapping[str, Any], top: Mapping[str, Any] | None) -> dict[str, Any]:
    """``top`` merged over ``base`` field by field (objects recursively; ``shape`` whole)."""
    out = copy.deepcopy(dict(base))
    for key, value in (top or {}).items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping) and key != "shape":
            out[key] = merge_params(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _check_params(p: Mapping[str, Any], ref: Mapping[str, Any] = DEFAULT_PARAMS, path=""):
    for key, value in p.items():
        if key not in ref:
            raise ValueError(f"unknown parameter `{path}{key}`")
        if isinstance(ref[key], Mapping) and key != "shape":
            _check_params(value, ref[key], f"{path}{key}.")


class StepRefused(ValueError):
    """A step the Rust core would refuse (``StepError``); the world is left unchanged."""


# --------------------------------------------------------------------------------------------
# Cognition (model.md 3)


class VarianceSchedule:
    """The variances a belief goes through, indexed by its number of updates.

    Same recurrence and stopping rule as ``sim_core::model::cognition::VarianceSchedule``:
    ``post[0] = s0^2``, ``prior[n] = post[n-1] + q^2``, ``post[n] = 1/(1/prior[n] + 1/s_o^2)``,
    tabulated until a posterior repeats bit for bit (later updates reuse the last entry).
    """

    MAX = 4096

    def __init__(self, s0: float, q: float, s_o: float):
        s2_o = s_o * s_o
        q2 = q * q
        k = 2.0
        prior = [math.nan]
        post = [s0 * s0]
        kl_const = [0.0]
        w_prior = [0.0]
        w_obs = [0.0]
        while True:
            last = post[-1]
            s2_p = last + q2
            s2_post = 1.0 / (1.0 / s2_p + 1.0 / s2_o)
            prior.append(s2_p)
            post.append(s2_post)
            # KL(N(0, s2_p I) || N(0, s2_o I)), written as the Rust expression.
            kl_const.append(0.5 * (k * s2_p / s2_o + 0.0 / s2_o - k + k * math.log(s2_o / s2_p)))
            w_prior.append(s2_post / s2_p)
            w_obs.append(s2_post / s2_o)
            if s2_post == last or len(post) >= self.MAX:
                break
        self.prior = np.array(prior)
        self.post = np.array(post)
        self.kl_const = np.array(kl_const)
        self.w_prior = np.array(w_prior)
        self.w_obs = np.array(w_obs)
        self.half_inv_s2o = 0.5 / s2_o

    def index(self, updates):
        return np.minimum(updates, len(self.post) - 1)


def kl_isotropic(mu_p, s2_p, mu_o, s2_o, k=2.0):
    """``KL(N(mu_p, s2_p I_k) || N(mu_o, s2_o I_k))`` (model.md 3, step 4)."""
    d = np.asarray(mu_o, dtype=float) - np.asarray(mu_p, dtype=float)
    sq = np.sum(d * d, axis=-1)
    return 0.5 * (k * s2_p / s2_o + sq / s2_o - k + k * np.log(s2_o / s2_p))


# --------------------------------------------------------------------------------------------
# Geometry (model.md 1)


def disc_rect_gap(c, r, rect_pos, heading, length, width):
    """Signed gap between discs (centres ``c [..., 2]``, radii ``r``) and oriented rectangles, and
    the unit vector from the rectangle's nearest point towards each disc centre (broadcasting;
    ``sim_core::geometry::disc_rect_gap``)."""
    c = np.asarray(c, dtype=float)
    rect_pos = np.asarray(rect_pos, dtype=float)
    heading = np.asarray(heading, dtype=float)
    s = np.sin(heading)
    co = np.cos(heading)
    dx = c[..., 0] - rect_pos[..., 0]
    dy = c[..., 1] - rect_pos[..., 1]
    lx = co * dx + s * dy
    ly = -s * dx + co * dy
    hx = 0.5 * np.asarray(length, dtype=float)
    hy = 0.5 * np.asarray(width, dtype=float)
    ox = lx - np.clip(lx, -hx, hx)
    oy = ly - np.clip(ly, -hy, hy)
    on = np.sqrt(ox * ox + oy * oy)
    outside = on > 0.0
    safe = np.where(outside, on, 1.0)
    # Centre inside the rectangle: minus the depth to the nearest side.
    depth_x = hx - np.abs(lx)
    depth_y = hy - np.abs(ly)
    x_side = depth_x < depth_y
    sgn_x = np.where(lx < 0.0, -1.0, 1.0)
    sgn_y = np.where(ly < 0.0, -1.0, 1.0)
    gap = np.where(outside, on - r, np.where(x_side, -depth_x - r, -depth_y - r))
    nlx = np.where(outside, ox / safe, np.where(x_side, sgn_x, 0.0))
    nly = np.where(outside, oy / safe, np.where(x_side, 0.0, sgn_y))
    nx = co * nlx - s * nly
    ny = s * nlx + co * nly
    return gap, np.stack([nx, ny], axis=-1)


def _rect_corners(pos, heading, length, width):
    s, c = math.sin(heading), math.cos(heading)
    ax = (c * (0.5 * length), s * (0.5 * length))
    ay = (-s * (0.5 * width), c * (0.5 * width))
    px, py = pos
    return [
        (px + ax[0] + ay[0], py + ax[1] + ay[1]),
        (px - ax[0] + ay[0], py - ax[1] + ay[1]),
        (px - ax[0] - ay[0], py - ax[1] - ay[1]),
        (px + ax[0] - ay[0], py + ax[1] - ay[1]),
    ]


def _point_segment_distance(p, a, b):
    abx, aby = b[0] - a[0], b[1] - a[1]
    t = ((p[0] - a[0]) * abx + (p[1] - a[1]) * aby) / (abx * abx + aby * aby)
    t = min(max(t, 0.0), 1.0)
    qx, qy = p[0] - (a[0] + abx * t), p[1] - (a[1] + aby * t)
    return math.sqrt(qx * qx + qy * qy)


def _point_in_convex(p, poly):
    for k in range(4):
        a, b = poly[k], poly[(k + 1) % 4]
        if (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) < 0.0:
            return False
    return True


def _segments_intersect(a, b, c, d):
    def cross(o, p, q):
        return (p[0] - o[0]) * (q[1] - o[1]) - (p[1] - o[1]) * (q[0] - o[0])

    d1, d2, d3, d4 = cross(c, d, a), cross(c, d, b), cross(a, b, c), cross(a, b, d)
    return ((d1 > 0.0) != (d2 > 0.0)) and ((d3 > 0.0) != (d4 > 0.0))


def rect_rect_gap(pa, ha, la, wa, pb, hb, lb, wb) -> float:
    """Gap between two oriented rectangles, 0 when they touch or overlap."""
    ca = _rect_corners(pa, ha, la, wa)
    cb = _rect_corners(pb, hb, lb, wb)
    overlap = (
        any(_point_in_convex(p, cb) for p in ca)
        or any(_point_in_convex(p, ca) for p in cb)
        or any(
            _segments_intersect(ca[i], ca[(i + 1) % 4], cb[j], cb[(j + 1) % 4])
            for i in range(4)
            for j in range(4)
        )
    )
    if overlap:
        return 0.0
    best = math.inf
    for i in range(4):
        for k in range(4):
            best = min(best, _point_segment_distance(ca[i], cb[k], cb[(k + 1) % 4]))
            best = min(best, _point_segment_distance(cb[i], ca[k], ca[(k + 1) % 4]))
    return best


def _norm2(v):
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1])


def _clip_norm(v, vmax):
    n = _norm2(v)
    scale = np.where(n > vmax, vmax / np.where(n > 0.0, n, 1.0), 1.0)
    return np.where((n > vmax)[..., None], v * scale[..., None], v)


# What a record says without simulating (heading of each sample): read the same way as the
# package reads it.
_recorded_headings = recorded_headings


def _round_half_away(x: float) -> int:
    return int(math.floor(x + 0.5)) if x >= 0 else -int(math.floor(-x + 0.5))


def wrap_angle(a: float) -> float:
    """Wraps an angle into ``(-pi, pi]`` like ``sim_core::model::vehicle::wrap_angle``."""
    w = math.fmod(a, math.tau)
    if w <= -math.pi:
        w += math.tau
    elif w > math.pi:
        w -= math.tau
    return w


# --------------------------------------------------------------------------------------------
# The world


class ReferenceWorld:
    """One episode of a scenario (the scenario-file format of scenarios/FORMAT.md, as a dict).

    ``external`` lists the agents driven by :meth:`step`'s actions (default: the scenario's ego;
    ``[]`` makes every vehicle replay its record, the pedestrian-evaluation set-up).
    ``pedestrian_model`` moves every pedestrian that is neither external nor non-reactive, unless
    ``model_overrides`` (``{agent_id: model}``) says otherwise.
    """

    def __init__(
        self,
        scenario: Mapping[str, Any],
        params: Mapping[str, Any] | None = None,
        pedestrian_model: str = "cr_sfm",
        external: Sequence[int] | None = None,
        model_overrides: Mapping[int, str] | None = None,
    ):
        if params is not None:
            _check_params(params)
        self.params = merge_params(DEFAULT_PARAMS, params)
        p = self.params
        if pedestrian_model not in PEDESTRIAN_MODELS:
            raise ValueError(f"unknown pedestrian model {pedestrian_model!r}")
        self.scenario = scenario
        self.pedestrian_model = pedestrian_model
        self.dt = float(p["dt"])
        if abs(float(scenario["dt"]) - self.dt) > 1e-9:
            raise ValueError(f"scenario dt {scenario['dt']} != world dt {self.dt}")
        cog = p["cognition"]
        self.schedule = VarianceSchedule(cog["s0"], cog["q"], cog["s_o"])
        if cog["prediction"] not in ("constant_velocity", "constant_acceleration"):
            raise ValueError(f"unknown prediction model {cog['prediction']!r}")
        self.ca_prediction = cog["prediction"] == "constant_acceleration"

        # Records.
        self._rec = []
        for k, a in enumerate(scenario["agents"]):
            pos = np.asarray(a["positions"], dtype=float).reshape(-1, 2)
            vel = np.asarray(a["velocities"], dtype=float).reshape(-1, 2)
            if len(pos) == 0 or len(pos) != len(vel):
                raise ValueError(f"agent {k}: empty track or positions/velocities differ")
            speeds = np.hypot(vel[:, 0], vel[:, 1])
            total = 0.0
            for s in speeds:  # sequential sum, as Rust's Iterator::sum
                total += float(s)
            self._rec.append(
                {
                    "kind": a["kind"],
                    "start": int(a["start_step"]),
                    "pos": pos,
                    "vel": vel,
                    "heading": _recorded_headings(vel),
                    "goal": pos[-1].copy(),
                    "v0": total / max(len(vel), 1),
                    "non_reactive": bool(a.get("non_reactive", False)),
                }
            )
        n_total = len(self._rec)

        # Control of every agent.
        overrides = dict(model_overrides or {})
        self.control_of: list[str] = []
        for k, r in enumerate(self._rec):
            if r["kind"] == "vehicle" or r["non_reactive"]:
                c = "replay"
            else:
                c = overrides.get(k, pedestrian_model)
            self.control_of.append(c)
        if external is None:
            external = [int(scenario["ego"])]
        self.external = [int(e) for e in external]
        if len(set(self.external)) != len(self.external):
            raise ValueError("an external agent is listed twice")
        for e in self.external:
            if not 0 <= e < n_total:
                raise ValueError(f"external agent {e} is not in the scenario")
            self.control_of[e] = "external"
        self._ext = {
            e: {
                "active": False,
                "speeds": [],
                "last_acc": None,
                "goal_distance": 0.0,
                "status": None,
            }
            for e in self.external
        }

        recorded = max(r["start"] + len(r["pos"]) for r in self._rec)
        ego = int(scenario["ego"])
        ego_len = (
            self._rec[ego]["start"] + len(self._rec[ego]["pos"]) if ego < n_total else recorded
        )
        self.horizon = max(
            1, _round_half_away((max(ego_len - 1, 0) * self.dt + p["horizon_extra"]) / self.dt)
        )
        self.recorded_steps = recorded
        self.step_index = 0
        self.over = False
        self._pending = sorted(range(n_total), key=lambda i: (self._rec[i]["start"], i))
        self._alloc_empty()
        self.departed: list[tuple[int, np.ndarray]] = []
        events: list[tuple] = []
        self._enter_pending(events)
        self._observe()
        for e, tr in self._ext.items():
            tr["active"] = e in self.ids

    # ----------------------------------------------------------------------------------------
    # State arrays (slot order = order of entry, as the Rust world)

    _AGENT_FIELDS = (
        "ids",
        "is_vehicle",
        "is_rect",
        "radius",
        "length",
        "width",
        "pos",
        "vel",
        "acc",
        "prev_acc",
        "speed",
        "heading",
        "goal",
        "v0",
        "initial_vel",
        "leaving",
    )
    _PAIR_FIELDS = ("edge", "mu", "updates", "clearance", "normal", "psi", "u")

    def _alloc_empty(self):
        self.ids = np.zeros(0, dtype=np.int64)
        self.control: list[str] = []
        self.is_vehicle = np.zeros(0, dtype=bool)
        self.is_rect = np.zeros(0, dtype=bool)
        self.radius = np.zeros(0)
        self.length = np.zeros(0)
        self.width = np.zeros(0)
        self.pos = np.zeros((0, 2))
        self.vel = np.zeros((0, 2))
        self.acc = np.zeros((0, 2))
        self.prev_acc = np.zeros((0, 2))
        self.speed = np.zeros(0)
        self.heading = np.zeros(0)
        self.goal = np.zeros((0, 2))
        self.v0 = np.zeros(0)
        self.initial_vel = np.zeros((0, 2))
        self.leaving = np.zeros(0, dtype=bool)
        self.edge = np.zeros((0, 0), dtype=bool)
        self.mu = np.zeros((0, 0, 2))
        self.updates = np.zeros((0, 0), dtype=np.int64)
        self.clearance = np.zeros((0, 0))
        self.normal = np.zeros((0, 0, 2))
        self.psi = np.zeros((0, 0))
        self.u = np.zeros((0, 0))

    def __len__(self) -> int:
        return len(self.ids)

    def slot_of(self, agent_id: int) -> int | None:
        hits = np.flatnonzero(self.ids == agent_id)
        return int(hits[0]) if len(hits) else None

    def _enter_pending(self, events: list):
        p = self.params
        vshape = p["vehicle"]["shape"]
        while self._pending:
            aid = self._pending[0]
            rec = self._rec[aid]
            if rec["start"] > self.step_index:
                break
            self._pending.pop(0)
            end = rec["start"] + len(rec["pos"]) - 1
            if end < self.step_index:
                continue
            k = self.step_index - rec["start"]
            pos = rec["pos"][k].copy()
            vel = rec["vel"][k].copy()
            speed = float(np.sqrt(vel[0] * vel[0] + vel[1] * vel[1]))
            if rec["kind"] == "vehicle":
                if vshape["type"] == "rect":
                    shape = (True, 0.0, vshape["length"], vshape["width"])
                else:
                    shape = (False, vshape["radius"], 0.0, 0.0)
            else:
                shape = (False, p["ped_radius"], 0.0, 0.0)
            n = len(self.ids)
            self.ids = np.append(self.ids, aid)
            self.control.append(self.control_of[aid])
            self.is_vehicle = np.append(self.is_vehicle, rec["kind"] == "vehicle")
            self.is_rect = np.append(self.is_rect, shape[0])
            self.radius = np.append(self.radius, shape[1])
            self.length = np.append(self.length, shape[2])
            self.width = np.append(self.width, shape[3])
            self.pos = np.vstack([self.pos, pos])
            self.vel = np.vstack([self.vel, vel])
            self.acc = np.vstack([self.acc, np.zeros(2)])
            self.prev_acc = np.vstack([self.prev_acc, np.zeros(2)])
            self.speed = np.append(self.speed, speed)
            self.heading = np.append(self.heading, rec["heading"][k])
            self.goal = np.vstack([self.goal, rec["goal"]])
            self.v0 = np.append(self.v0, rec["v0"])
            self.initial_vel = np.vstack([self.initial_vel, vel])
            self.leaving = np.append(self.leaving, False)
            # Pair arrays grow by one row and column (no belief yet).
            self.edge = np.pad(self.edge, ((0, 1), (0, 1)))
            self.updates = np.pad(self.updates, ((0, 1), (0, 1)))
            self.mu = np.pad(self.mu, ((0, 1), (0, 1), (0, 0)))
            for name in ("clearance", "psi", "u"):
                setattr(self, name, np.pad(getattr(self, name), ((0, 1), (0, 1))))
            self.normal = np.pad(self.normal, ((0, 1), (0, 1), (0, 0)))
            assert len(self.ids) == n + 1
            if self.step_index > 0:
                events.append(("entered", aid))
            if aid in self._ext:
                tr = self._ext[aid]
                tr["active"] = True
                tr["speeds"].append(speed)
                g = rec["goal"]
                d = pos - g
                tr["goal_distance"] = float(np.sqrt(d[0] * d[0] + d[1] * d[1]))

    def _remove_leaving(self, events: list):
        if not self.leaving.any():
            return
        keep = ~self.leaving
        for i in np.flatnonzero(self.leaving):
            events.append(("left", int(self.ids[i])))
            self.departed.append((int(self.ids[i]), self.pos[i].copy()))
        self.control = [c for c, k in zip(self.control, keep, strict=True) if k]
        for name in self._AGENT_FIELDS:
            setattr(self, name, getattr(self, name)[keep])
        for name in self._PAIR_FIELDS:
            setattr(self, name, getattr(self, name)[keep][:, keep])

    # ----------------------------------------------------------------------------------------
    # Observe: beliefs, clearances, risk, graph (model.md 3, 4, 6; 5b steps 1-2)

    def _observe(self):
        n = len(self.ids)
        p = self.params
        r = p["perception_radius"]
        if n == 0:
            return
        pos, vel = self.pos, self.vel
        d = pos[:, None, :] - pos[None, :, :]  # x_i - x_j
        dx, dy = d[..., 0], d[..., 1]
        dist2 = dx * dx + dy * dy
        in_range = ~(dist2 > r * r)
        np.fill_diagonal(in_range, False)
        dist = np.sqrt(dist2)

        # Beliefs (paper Algorithm 1): a belief survives while the pair stays in range.
        sch = self.schedule
        had = self.edge & in_range
        vj = np.broadcast_to(vel[None, :, :], (n, n, 2))
        mu_p = self.mu
        if self.ca_prediction:
            change = self.prev_acc * self.dt  # v(t-1) - v(t-2) of the target
            mu_p = np.where((self.updates > 0)[..., None], self.mu + change[None, :, :], self.mu)
        idx = sch.index(self.updates + 1)
        diff = vj - mu_p
        u_upd = sch.kl_const[idx] + sch.half_inv_s2o * (
            diff[..., 0] * diff[..., 0] + diff[..., 1] * diff[..., 1]
        )
        mu_upd = mu_p * sch.w_prior[idx][..., None] + vj * sch.w_obs[idx][..., None]
        self.mu = np.where(had[..., None], mu_upd, np.where(in_range[..., None], vj, 0.0))
        self.updates = np.where(had, self.updates + 1, 0)
        self.u = np.where(had, u_upd, 0.0)
        self.edge = in_range

        # Clearance and the unit vector from j towards i.
        safe = np.where(dist > 0.0, dist, 1.0)
        centre_dir = np.where((dist > 0.0)[..., None], d / safe[..., None], 0.0)
        rad = self.radius
        clearance = np.maximum(dist - (rad[:, None] + rad[None, :]), 0.0)
        normal = centre_dir.copy()
        rect = self.is_rect
        if rect.any():
            ii, jj = np.nonzero(in_range & ~rect[:, None] & rect[None, :])  # disc i, rect j
            if len(ii):
                gap, nvec = disc_rect_gap(
                    pos[ii], rad[ii], pos[jj], self.heading[jj], self.length[jj], self.width[jj]
                )
                clearance[ii, jj] = np.maximum(gap, 0.0)
                normal[ii, jj] = nvec
            ii, jj = np.nonzero(in_range & rect[:, None] & ~rect[None, :])  # rect i, disc j
            if len(ii):
                gap, nvec = disc_rect_gap(
                    pos[jj], rad[jj], pos[ii], self.heading[ii], self.length[ii], self.width[ii]
                )
                clearance[ii, jj] = np.maximum(gap, 0.0)
                normal[ii, jj] = -nvec
            ii, jj = np.nonzero(in_range & rect[:, None] & rect[None, :])
            for i, j in zip(ii, jj, strict=True):
                clearance[i, j] = rect_rect_gap(
                    pos[i], self.heading[i], self.length[i], self.width[i],
                    pos[j], self.heading[j], self.length[j], self.width[j],
                )  # fmt: skip
        self.clearance = np.where(in_range, clearance, 0.0)
        self.normal = np.where(in_range[..., None], normal, 0.0)

        # Physical risk by virtual distance (model.md 4), in the Rust core's folded form
        # psi = (1 + e) / (1 + e + 2 gamma2 d), e = exp(-2 z), z = gamma1 k (|v_j||cos phi| + |a_j|)
        # (= 1 / (1 + gamma2 d (1 + tanh z))).
        risk = p["risk"]
        acc_norm = _norm2(self.acc)
        along = vj[..., 0] * dx + vj[..., 1] * dy
        radial = np.where(dist > 0.0, np.abs(along) / safe, 0.0)
        k = np.where(along > 0.0, -1.0, 1.0)
        z = risk["gamma1"] * k * (radial + acc_norm[None, :])
        with np.errstate(over="ignore"):
            one_plus_e = 1.0 + np.exp(-2.0 * z)
            psi = np.where(
                np.isinf(one_plus_e),
                1.0,
                one_plus_e / (one_plus_e + 2.0 * risk["gamma2"] * self.clearance),
            )
        self.psi = np.where(in_range, psi, 0.0)

    # ----------------------------------------------------------------------------------------
    # Accessors

    @property
    def A(self) -> np.ndarray:
        """Dense adjacency ``A[i][j] = psi (1 + lambda u)`` over the slots (0 off the graph)."""
        lam = self.params["risk"]["lambda"]
        return np.where(self.edge, self.psi * (1.0 + lam * self.u), 0.0)

    def positions(self) -> dict[int, np.ndarray]:
        return {int(a): self.pos[i].copy() for i, a in enumerate(self.ids)}

    def velocities(self) -> dict[int, np.ndarray]:
        return {int(a): self.vel[i].copy() for i, a in enumerate(self.ids)}

    def headings(self) -> dict[int, float]:
        return {int(a): float(self.heading[i]) for i, a in enumerate(self.ids)}

    def agent_states(self) -> dict[int, tuple[float, float, float, float, float]]:
        """``{id: (x, y, vx, vy, heading)}`` of every agent present."""
        return {
            int(a): (
                float(self.pos[i, 0]),
                float(self.pos[i, 1]),
                float(self.vel[i, 0]),
                float(self.vel[i, 1]),
                float(self.heading[i]),
            )
            for i, a in enumerate(self.ids)
        }

    def edges(self) -> dict[tuple[int, int], tuple[float, float, float]]:
        """The risk graph: ``{(observer, target): (psi, u, A)}``."""
        a = self.A
        out = {}
        for i, j in zip(*np.nonzero(self.edge), strict=True):
            out[(int(self.ids[i]), int(self.ids[j]))] = (
                float(self.psi[i, j]),
                float(self.u[i, j]),
                float(a[i, j]),
            )
        return out

    def edge_arrays(self) -> dict[str, np.ndarray]:
        """The risk graph as COO arrays sorted by (src, dst): src, dst, clearance, psi, u, a."""
        ii, jj = np.nonzero(self.edge)
        src, dst = self.ids[ii], self.ids[jj]
        order = np.lexsort((dst, src))
        ii, jj = ii[order], jj[order]
        a = self.A
        return {
            "src": self.ids[ii].astype(np.uint32),
            "dst": self.ids[jj].astype(np.uint32),
            "clearance": self.clearance[ii, jj],
            "psi": self.psi[ii, jj],
            "u": self.u[ii, jj],
            "a": a[ii, jj],
        }

    #: Node features of :meth:`observation`, in order (the wire protocol's, SPEC.md section 7).
    FEATURE_NAMES = FEATURE_NAMES

    def observation(self, agent_id: int, max_agents: int) -> dict[str, np.ndarray]:
        """Agent ``agent_id``'s observation as ``World::fill_observation`` of the Rust core.

        Returns ``features`` float32 ``[M, 11]`` (ego frame, x forward; :attr:`FEATURE_NAMES`),
        ``adjacency`` float32 ``[M, M]`` (``A`` between the nodes, zero diagonal and padding),
        ``mask`` bool ``[M]`` and ``node_ids`` int64 ``[M]`` (-1 for padding), with
        ``M = max_agents``. Node 0 is the ego; the others are the agents inside its perception
        radius sorted by (clearance, id), the first ``M - 1`` of them. Everything is zero (and
        ``mask`` all false) when the agent is not present.
        """
        m = int(max_agents)
        if m < 1:
            raise ValueError("max_agents must be at least 1")
        nf = len(self.FEATURE_NAMES)
        features = np.zeros((m, nf), dtype=np.float32)
        adjacency = np.zeros((m, m), dtype=np.float32)
        mask = np.zeros(m, dtype=bool)
        node_ids = np.full(m, -1, dtype=np.int64)
        out = {"features": features, "adjacency": adjacency, "mask": mask, "node_ids": node_ids}
        g = self.slot_of(agent_id)
        if g is None:
            return out
        targets = np.flatnonzero(self.edge[g])
        near = sorted(
            ((float(self.clearance[g, j]), int(self.ids[j]), int(j)) for j in targets),
            key=lambda t: (t[0], t[1]),
        )[: m - 1]
        slots = [g] + [t[2] for t in near]
        s, c = math.sin(float(self.heading[g])), math.cos(float(self.heading[g]))

        def to_ego(x: float, y: float) -> tuple[float, float]:
            return c * x + s * y, -s * x + c * y

        gx, gy = float(self.pos[g, 0]), float(self.pos[g, 1])
        gvx, gvy = float(self.vel[g, 0]), float(self.vel[g, 1])
        for node, j in enumerate(slots):
            row = features[node]
            rx, ry = to_ego(float(self.pos[j, 0]) - gx, float(self.pos[j, 1]) - gy)
            rvx, rvy = to_ego(float(self.vel[j, 0]) - gvx, float(self.vel[j, 1]) - gvy)
            vx, vy = float(self.vel[j, 0]), float(self.vel[j, 1])
            row[0], row[1], row[2], row[3] = rx, ry, rvx, rvy
            row[4] = math.sqrt(vx * vx + vy * vy)
            row[5] = wrap_angle(float(self.heading[j]) - float(self.heading[g]))
            if self.is_rect[j]:
                row[6] = 0.5 * math.hypot(float(self.length[j]), float(self.width[j]))
            else:
                row[6] = float(self.radius[j])
            row[7] = 1.0 if self.is_vehicle[j] else 0.0
            if node == 0:
                dx, dy = to_ego(float(self.goal[g, 0]) - gx, float(self.goal[g, 1]) - gy)
                row[8], row[9] = dx, dy
                row[10] = math.sqrt(dx * dx + dy * dy)
            mask[node] = True
            node_ids[node] = int(self.ids[j])
        idx = np.asarray(slots)
        a = self.A[np.ix_(idx, idx)]
        adjacency[: len(slots), : len(slots)] = np.where(self.edge[np.ix_(idx, idx)], a, 0.0)
        return out

    def active_externals(self) -> list[int]:
        return [e for e in self.external if self._ext[e]["active"]]

    @property
    def is_over(self) -> bool:
        return self.over

    @property
    def time(self) -> float:
        return self.step_index * self.dt

    # ----------------------------------------------------------------------------------------
    # Step

    def step(self, actions: Mapping[int, Iterable[float]] | None = None) -> dict[str, Any]:
        """Advances by one step with the normalised actions ``{agent_id: (a0, a1)}`` of the active
        external agents (``[acc, yaw rate]`` for vehicles, ``[forward, left]`` acceleration for
        pedestrians). Returns ``{"step", "agents", "events", "episode_over"}`` where ``agents``
        holds one outcome per active external agent (reward terms, flags, metrics)."""
        if self.over:
            raise StepRefused("the episode is over; reset before stepping again")
        actions = {int(k): tuple(float(x) for x in v) for k, v in (actions or {}).items()}
        active = set(self.active_externals())
        for aid, act in actions.items():
            if aid not in active:
                raise StepRefused(f"action for agent {aid}, which is not an active external agent")
            if len(act) != 2:
                raise StepRefused(f"action for agent {aid} must have 2 components")
            for c, v in enumerate(act):
                if not math.isfinite(v):
                    raise StepRefused(f"action component {c} of agent {aid} is not finite ({v})")
        for e in self.external:
            if e in active and e not in actions:
                raise StepRefused(f"no action for active external agent {e}")

        events: list[tuple] = []
        self.departed = []
        self._remove_leaving(events)  # 1. finished external agents leave

        # 2. Move every agent from t to t + 1.
        p = self.params
        dt = self.dt
        n = len(self.ids)
        new_pos = self.pos.copy()
        new_vel = self.vel.copy()
        new_speed = self.speed.copy()
        new_heading = self.heading.copy()
        clipped_of: dict[int, tuple[bool, float]] = {}
        leaving = self.leaving.copy()

        model_rows = {m: [] for m in ("sfm", "ra_sfm", "cr_sfm")}
        cv_rows = []
        for i in range(n):
            aid = int(self.ids[i])
            c = self.control[i]
            if c == "external":
                pos, vel, speed, heading, clipped, omega = self._move_external(
                    i, actions.get(aid, (0.0, 0.0))
                )
                clipped_of[aid] = (clipped, omega)
                new_pos[i], new_vel[i], new_speed[i], new_heading[i] = pos, vel, speed, heading
            elif c == "replay":
                rec = self._rec[aid]
                k = self.step_index + 1 - rec["start"]
                if 0 <= k < len(rec["pos"]):
                    new_pos[i] = rec["pos"][k]
                    new_vel[i] = rec["vel"][k]
                    v = rec["vel"][k]
                    new_speed[i] = math.sqrt(v[0] * v[0] + v[1] * v[1])
                    new_heading[i] = rec["heading"][k]
                else:
                    leaving[i] = True
            elif c == "cv":
                cv_rows.append(i)
            else:
                model_rows[c].append(i)

        vmax = p["ped_speed_max"]
        if cv_rows:
            rows = np.array(cv_rows)
            v = _clip_norm(self.initial_vel[rows], vmax)
            new_pos[rows] = self.pos[rows] + v * dt
            new_vel[rows] = v
        for model, rows in model_rows.items():
            if rows:
                rows = np.array(rows)
                pos, vel = self._social_force_move(rows, model)
                new_pos[rows] = pos
                new_vel[rows] = vel
        ped_rows = np.array(cv_rows + sum(model_rows.values(), []), dtype=np.int64)
        if len(ped_rows):
            v = new_vel[ped_rows]
            sp = _norm2(v)
            new_speed[ped_rows] = sp
            new_heading[ped_rows] = np.where(
                sp > 0.0, np.arctan2(v[:, 1], v[:, 0]), self.heading[ped_rows]
            )

        self.prev_acc = self.acc.copy()
        self.acc = (new_vel - self.vel) / dt
        self.pos, self.vel, self.speed, self.heading = new_pos, new_vel, new_speed, new_heading
        self.leaving = leaving
        self.step_index += 1

        # 3. Arrivals of simulated pedestrians, departures, entries.
        goal_r = p["ped_goal_radius"]
        for i in range(n):
            if self.control[i] in ("cv", "sfm", "ra_sfm", "cr_sfm") and not self.is_vehicle[i]:
                g = self.pos[i] - self.goal[i]
                if math.sqrt(g[0] * g[0] + g[1] * g[1]) <= goal_r:
                    self.leaving[i] = True
                    events.append(("goal_reached", int(self.ids[i])))
        self._remove_leaving(events)
        self._enter_pending(events)

        # 4. Beliefs, risk and graph at t + 1.
        self._observe()

        # 5. Events and rewards.
        ii, jj = np.nonzero(self.edge & (self.clearance <= 0.0))
        for i, j in zip(ii, jj, strict=True):
            if self.ids[i] < self.ids[j]:
                events.append(("collision", int(self.ids[i]), int(self.ids[j])))
        self._judge_faults(events)
        truncated = self.step_index >= self.horizon
        outcomes = []
        for e in self.external:
            if not self._ext[e]["active"]:
                continue
            clipped, omega = clipped_of.get(e, (False, 0.0))
            outcomes.append(self._external_outcome(e, clipped, omega, truncated, events))
        all_finished = bool(self.external) and all(
            not tr["active"] and tr["speeds"] for tr in self._ext.values()
        )
        self.over = truncated or all_finished
        return {
            "step": self.step_index,
            "agents": outcomes,
            "events": events,
            "episode_over": self.over,
        }

    def _judge_faults(self, events: list) -> None:
        """model.md 2c, from its text: an external vehicle's collision with a pedestrian is its
        fault when the pedestrian was in its path (ahead of the front face, within half the
        width plus its radius of the centreline) with room to stop (gap >= v^2 / 2 acc_max) at
        an earlier step and in the path since, and the vehicle moves at >= 0.5 m/s."""
        braking = self.params["vehicle"]["acc_max"]
        for e in self.external:
            track = self._ext[e]
            slots = np.flatnonzero(self.ids == e)
            if not track["active"] or slots.size == 0 or not self.is_vehicle[slots[0]]:
                continue
            v = int(slots[0])
            in_path = track.setdefault("in_path", set())
            for event in list(events):
                if event[0] != "collision" or e not in event[1:]:
                    continue
                other = event[2] if event[1] == e else event[1]
                if self.speed[v] >= 0.5 and other in in_path:
                    events.append(("at_fault", e, other))
            if not self.is_rect[v]:
                continue
            c, s = np.cos(self.heading[v]), np.sin(self.heading[v])
            d = self.pos - self.pos[v]
            x = c * d[:, 0] + s * d[:, 1]
            y = -s * d[:, 0] + c * d[:, 1]
            half_l, half_w = self.length[v] / 2, self.width[v] / 2
            r = self.radius
            ahead = ~self.is_vehicle & (x > half_l) & (np.abs(y) < half_w + r)
            room = (x - half_l - r) >= self.speed[v] ** 2 / (2 * braking)
            track["in_path"] = {
                int(self.ids[k])
                for k in np.flatnonzero(ahead)
                if int(self.ids[k]) in in_path or room[k]
            }

    def _move_external(self, i: int, act):
        p = self.params
        dt = self.dt
        a0 = min(max(act[0], -1.0), 1.0)
        a1 = min(max(act[1], -1.0), 1.0)
        clipped = a0 != act[0] or a1 != act[1]
        if self.is_vehicle[i]:
            vp = p["vehicle"]
            acc = a0 * vp["acc_max"]
            omega = a1 * vp["omega_max"]
            speed = min(max(float(self.speed[i]) + acc * dt, 0.0), vp["speed_max"])
            heading = float(self.heading[i]) + omega * dt
            s, c = math.sin(heading), math.cos(heading)
            step_len = speed * dt
            pos = np.array([self.pos[i, 0] + c * step_len, self.pos[i, 1] + s * step_len])
            vel = np.array([c * speed, s * speed])
            return pos, vel, speed, heading, clipped, omega
        # An external pedestrian: [forward, left] acceleration in its ego frame.
        s, c = math.sin(self.heading[i]), math.cos(self.heading[i])
        am = p["ped_acc_max"]
        force = np.array([(c * a0 - s * a1) * am, (s * a0 + c * a1) * am])
        v = _clip_norm(self.vel[i] + force * dt, p["ped_speed_max"])
        pos = self.pos[i] + v * dt
        speed = float(_norm2(v))
        heading = math.atan2(v[1], v[0]) if speed > 0.0 else float(self.heading[i])
        return pos, v, speed, heading, clipped, 0.0

    def social_forces(self, rows: np.ndarray, model: str) -> np.ndarray:
        """Resultant force (m/s², unit mass) on the pedestrians in slots ``rows`` under ``model``
        (``sfm``, ``ra_sfm`` or ``cr_sfm``), from the state and graph at the current step."""
        sp = self.params["pedestrians"][model]
        x = self.pos[rows]
        v = self.vel[rows]
        # Goal force (v0 e_goal - v) / tau.
        to_goal = self.goal[rows] - x
        gd = _norm2(to_goal)
        e = np.where((gd > 0.0)[:, None], to_goal / np.where(gd > 0.0, gd, 1.0)[:, None], 0.0)
        f_goal = (e * self.v0[rows][:, None] - v) / sp["tau"]
        # Repulsions A exp(-clearance / B) n from every perceived agent.
        edge = self.edge[rows]
        veh = np.broadcast_to(self.is_vehicle[None, :], edge.shape)
        strength = np.where(veh, sp["a_veh"], sp["a_ped"])
        rng = np.where(veh, sp["b_veh"], sp["b_ped"])
        mag = strength * np.exp(-self.clearance[rows] / rng)
        f = self.normal[rows] * mag[..., None]
        if model == "sfm":
            w = np.ones(edge.shape)
        elif model == "ra_sfm":
            w = self.psi[rows]
        else:
            lam = np.where(veh, sp["lambda1"], sp["lambda2"])
            w = self.psi[rows] * (1.0 + lam * self.u[rows])
        w = np.where(edge, w, 0.0)
        total = np.sum(np.where(edge[..., None], f * w[..., None], 0.0), axis=1)
        if model == "sfm":
            gw = np.ones(len(rows))
        else:
            max_w = np.max(np.where(edge, w, 0.0), axis=1, initial=0.0)
            gw = np.exp(-sp["lambda3"] * max_w)
        return f_goal * gw[:, None] + total

    def _social_force_move(self, rows: np.ndarray, model: str):
        force = self.social_forces(rows, model)
        v = _clip_norm(self.vel[rows] + force * self.dt, self.params["ped_speed_max"])
        return self.pos[rows] + v * self.dt, v

    def _external_outcome(self, aid: int, clipped: bool, omega: float, truncated: bool, events):
        p = self.params
        w = p["reward"]
        dt = self.dt
        tr = self._ext[aid]
        reward = dict.fromkeys(("progress", "success", "collision", "danger", "comfort"), 0.0)
        i = self.slot_of(aid)
        if i is None:
            tr["active"] = False
            return {
                "agent": aid,
                "reward": reward,
                "total": 0.0,
                "terminated": True,
                "truncated": False,
                "action_clipped": clipped,
                "metrics": None,
            }
        is_vehicle = bool(self.is_vehicle[i])
        g = self.pos[i] - self.goal[i]
        d_now = math.sqrt(g[0] * g[0] + g[1] * g[1])
        reward["progress"] = w["progress"] * (tr["goal_distance"] - d_now)
        tr["goal_distance"] = d_now
        goal_radius = p["vehicle"]["goal_radius"] if is_vehicle else p["ped_goal_radius"]
        arrived = d_now <= goal_radius
        targets = np.flatnonzero(self.edge[i])
        other_ped = ~self.is_vehicle[targets]
        cl = self.clearance[i, targets]
        collided = bool(np.any((cl <= 0.0) & (is_vehicle | ~other_ped)))
        c_min = float(np.min(cl[other_ped])) if other_ped.any() else math.inf
        if arrived:
            reward["success"] = w["success"]
            events.append(("goal_reached", aid))
        if collided:
            reward["collision"] = w["collision"]
        if c_min < w["danger_clearance"]:
            reward["danger"] = w["danger"] * (c_min - w["danger_clearance"])
        speed = float(self.speed[i])
        prev_speed = tr["speeds"][-1] if tr["speeds"] else speed
        acc = (speed - prev_speed) / dt
        jerk = 0.0 if tr["last_acc"] is None else (acc - tr["last_acc"]) / dt
        tr["last_acc"] = acc
        tr["speeds"].append(speed)
        reward["comfort"] = -w["jerk_penalty"] * jerk * jerk - w["yaw_rate_penalty"] * omega * omega
        terminated = arrived or collided
        metrics = None
        if terminated or truncated:
            status = "collision" if collided else ("success" if arrived else "timeout")
            tr["status"] = status
            tr["active"] = False
            metrics = episode_metrics(status, tr["speeds"], dt)
            self.leaving[i] = True
        total = (
            reward["progress"]
            + reward["success"]
            + reward["collision"]
            + reward["danger"]
            + reward["comfort"]
        )
        return {
            "agent": aid,
            "reward": reward,
            "total": total,
            "terminated": terminated,
            "truncated": truncated and not terminated,
            "action_clipped": clipped,
            "metrics": metrics,
        }


def episode_metrics(status: str, speeds: Sequence[float], dt: float) -> dict[str, Any]:
    """``EpisodeMetrics::from_speeds``: mean speed after the start, mean |jerk|, max |acc|."""
    steps = max(len(speeds) - 1, 0)
    avg_speed = 0.0
    if steps > 0:
        total = 0.0
        for s in speeds[1:]:
            total += s
        avg_speed = total / steps
    accs = [(b - a) / dt for a, b in zip(speeds[:-1], speeds[1:], strict=True)]
    jerks = [abs((b - a) / dt) for a, b in zip(accs[:-1], accs[1:], strict=True)]
    avg_abs_jerk = 0.0
    if jerks:
        total = 0.0
        for j in jerks:
            total += j
        avg_abs_jerk = total / len(jerks)
    max_abs_acc = 0.0
    for a in accs:
        max_abs_acc = max(max_abs_acc, abs(a))
    return {
        "status": status,
        "avg_speed": avg_speed,
        "avg_abs_jerk": avg_abs_jerk,
        "max_abs_acc": max_abs_acc,
        "steps": steps,
    }
