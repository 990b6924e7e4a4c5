//! Pedestrian social forces and their weights (model.md section 5): the one implementation the
//! world step runs.
//!
//! The world's observe pass computes, for each simulated pedestrian, one [`ModelForces::edge_force`]
//! per agent inside its perception radius and sums them with [`lane_sum`] / [`lane_max`]; the
//! move adds the goal force weighted by [`ModelForces::goal_weight`]. [`total_force`] is the same
//! arithmetic over a list of [`Interaction`]s (same bits as the step for the same inputs in the
//! same order). Interactions beyond the perception radius are not perceived: their force is below
//! `A exp(-R_perc / B)` (under 2e-6 m/s² with the defaults).
//!
//! Which models exist, their names and their parameter sets: [`crate::params::PedestrianModel`].

use crate::geometry::Vec2;
use crate::model::risk;
use crate::params::{PedestrianModel, SocialForceParams};
use crate::support::fastmath;

/// Goal force `(v0 e_goal - v) / tau`; `e_goal` is the unit vector to the goal (zero at the goal).
#[inline]
pub fn goal_force(position: Vec2, velocity: Vec2, goal: Vec2, v0: f64, tau: f64) -> Vec2 {
    let to_goal = goal - position;
    let dist = to_goal.norm();
    let e = if dist > 0.0 {
        to_goal / dist
    } else {
        Vec2::zeros()
    };
    (e * v0 - velocity) / tau
}

/// Repulsion magnitude `strength * exp(-clearance / range)`, given `neg_inv_range = -1 / range`
/// (paper's `A exp((r - d) / B)` with `r - d` = minus the clearance), with the crate's
/// vectorisable [`fastmath::exp`].
#[inline(always)]
pub fn repulsion_magnitude(strength: f64, neg_inv_range: f64, clearance: f64) -> f64 {
    strength * fastmath::exp(clearance * neg_inv_range)
}

/// Repulsion `strength * exp(-clearance / range) * n`; `n` points from the other agent to the
/// pedestrian ([`repulsion_magnitude`] along `n`).
#[inline]
pub fn repulsion(strength: f64, range: f64, clearance: f64, n: Vec2) -> Vec2 {
    n * repulsion_magnitude(strength, -1.0 / range, clearance)
}

/// How a social-force model weighs its forces (model.md 5): `sfm` every weight 1; `ra_sfm`
/// repulsion weight `psi` and goal weight `exp(-lambda3 max_w)`; `cr_sfm` repulsion weight
/// `psi (1 + lambda u)` ([`risk::adjacency`], `lambda1` for vehicles, `lambda2` for pedestrians)
/// and the same goal weight. `cv` and `replay` have no forces (`None` from [`ModelForces::new`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelForces {
    /// Every repulsion weight is 1 (`sfm`), else `psi (1 + lambda u)`.
    unit_weight: bool,
    /// The goal force is damped by `exp(-lambda3 max_w)`.
    goal_damping: bool,
    a_veh: f64,
    /// `-1 / B_veh`.
    neg_inv_b_veh: f64,
    a_ped: f64,
    neg_inv_b_ped: f64,
    /// `lambda` of the weight towards a vehicle / a pedestrian (0 for `ra_sfm`, whose weight is
    /// `psi`).
    lambda_veh: f64,
    lambda_ped: f64,
    lambda3: f64,
}

impl ModelForces {
    /// The forces of `model` under its parameters `p`; `None` for a model without social forces.
    pub fn new(model: PedestrianModel, p: &SocialForceParams) -> Option<Self> {
        let w = model.info().weighting?;
        let cognitive = w.risk && w.cognitive;
        Some(Self {
            unit_weight: !w.risk,
            goal_damping: w.risk,
            a_veh: p.a_veh,
            neg_inv_b_veh: -1.0 / p.b_veh,
            a_ped: p.a_ped,
            neg_inv_b_ped: -1.0 / p.b_ped,
            lambda_veh: if cognitive { p.lambda1 } else { 0.0 },
            lambda_ped: if cognitive { p.lambda2 } else { 0.0 },
            lambda3: p.lambda3,
        })
    }

    /// The weight of one repulsion: 1, or `psi (1 + lambda u)`.
    #[inline(always)]
    pub fn repulsion_weight(&self, psi: f64, u: f64, other_is_vehicle: bool) -> f64 {
        let lambda = if other_is_vehicle {
            self.lambda_veh
        } else {
            self.lambda_ped
        };
        let weighted = risk::adjacency(psi, u, lambda);
        if self.unit_weight {
            1.0
        } else {
            weighted
        }
    }

    /// The weighted repulsion `(fx, fy)` of one perceived agent and its weight `w`, branch-free
    /// (selects only) so that the observe pass vectorises it. `veh` is 1 for a vehicle, 0 for a
    /// pedestrian; the direction is `(nnx, nny) * (rect + (1 - rect) inv_dist)`: the centre offset
    /// times `1 / dist` between two discs (`rect` = 0), a unit footprint normal (`rect` = 1).
    #[inline(always)]
    pub fn edge_force(
        &self,
        psi: f64,
        u: f64,
        veh: f64,
        inv_dist: f64,
        (nnx, nny, rect): (f64, f64, f64),
        clearance: f64,
    ) -> (f64, f64, f64) {
        let veh = veh != 0.0;
        let strength = if veh { self.a_veh } else { self.a_ped };
        let neg_inv_range = if veh {
            self.neg_inv_b_veh
        } else {
            self.neg_inv_b_ped
        };
        let w = self.repulsion_weight(psi, u, veh);
        // Exactly `inv_dist` (rect = 0) or 1 (rect = 1), without a select on loads.
        let scale = rect + (1.0 - rect) * inv_dist;
        let nx = nnx * scale;
        let ny = nny * scale;
        let rep = repulsion_magnitude(strength, neg_inv_range, clearance);
        (nx * rep * w, ny * rep * w, w)
    }

    /// Goal weight: 1 for `sfm`; `exp(-lambda3 * max_weight)` for `ra_sfm` and `cr_sfm`, where
    /// `max_weight` is the largest repulsion weight (0 with nobody perceived).
    #[inline]
    pub fn goal_weight(&self, max_weight: f64) -> f64 {
        if self.goal_damping {
            (-self.lambda3 * max_weight).exp()
        } else {
            1.0
        }
    }
}

/// What a pedestrian perceives of one other agent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interaction {
    pub other_is_vehicle: bool,
    /// Clearance between the two footprints, m.
    pub clearance: f64,
    /// Unit vector from the other agent to the pedestrian.
    pub normal: Vec2,
    /// Physical risk `psi(pedestrian, other)`.
    pub psi: f64,
    /// Cognitive uncertainty `u(pedestrian, other)`.
    pub u: f64,
}

/// Weight of one repulsion under `model` ([`ModelForces::repulsion_weight`]; 1 for a model
/// without forces).
pub fn repulsion_weight(model: PedestrianModel, p: &SocialForceParams, it: &Interaction) -> f64 {
    ModelForces::new(model, p).map_or(1.0, |f| {
        f.repulsion_weight(it.psi, it.u, it.other_is_vehicle)
    })
}

/// Goal weight under `model` ([`ModelForces::goal_weight`]; 1 for a model without forces).
pub fn goal_weight(model: PedestrianModel, p: &SocialForceParams, max_weight: f64) -> f64 {
    ModelForces::new(model, p).map_or(1.0, |f| f.goal_weight(max_weight))
}

/// The resultant force `w_goal F_goal + sum_j w_j F_j` (m/s², unit mass): the step's arithmetic
/// ([`ModelForces::edge_force`] per interaction, in order, summed by [`lane_sum`] and
/// [`lane_max`]). `F_goal` alone for a model without forces.
pub fn total_force(
    model: PedestrianModel,
    p: &SocialForceParams,
    f_goal: Vec2,
    interactions: impl IntoIterator<Item = Interaction>,
) -> Vec2 {
    let Some(forces) = ModelForces::new(model, p) else {
        return f_goal;
    };
    let (mut fx, mut fy, mut w) = (Vec::new(), Vec::new(), Vec::new());
    for it in interactions {
        let veh = if it.other_is_vehicle { 1.0 } else { 0.0 };
        let (x, y, weight) = forces.edge_force(
            it.psi,
            it.u,
            veh,
            1.0,
            (it.normal.x, it.normal.y, 1.0),
            it.clearance,
        );
        fx.push(x);
        fy.push(y);
        w.push(weight);
    }
    f_goal * forces.goal_weight(lane_max(&w)) + Vec2::new(lane_sum(&fx), lane_sum(&fy))
}

/// Sum in four interleaved lanes, then the lanes and the tail in a fixed order (vectorisable,
/// deterministic): how the step sums one pedestrian's repulsions.
#[inline(always)]
pub fn lane_sum(v: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let chunks = v.chunks_exact(4);
    let tail = chunks.remainder();
    for ch in chunks {
        for l in 0..4 {
            acc[l] += ch[l];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for &x in tail {
        s += x;
    }
    s
}

/// Largest of `v` and 0 (weights are non-negative), in four lanes.
#[inline(always)]
pub fn lane_max(v: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let chunks = v.chunks_exact(4);
    let tail = chunks.remainder();
    for ch in chunks {
        for l in 0..4 {
            if ch[l] > acc[l] {
                acc[l] = ch[l];
            }
        }
    }
    let mut m = acc[0].max(acc[1]).max(acc[2].max(acc[3]));
    for &x in tail {
        if x > m {
            m = x;
        }
    }
    m
}

/// Scales `v` down to norm `max` when it is longer.
#[inline]
pub fn clip_norm(v: Vec2, max: f64) -> Vec2 {
    let n = v.norm();
    if n > max {
        v * (max / n)
    } else {
        v
    }
}

/// Explicit social-force integration: `v' = clip_norm(v + F dt, v_max)`, `x' = x + v' dt`.
#[inline]
pub fn integrate(position: Vec2, velocity: Vec2, force: Vec2, dt: f64, v_max: f64) -> (Vec2, Vec2) {
    let v = clip_norm(velocity + force * dt, v_max);
    (position + v * dt, v)
}
