//! Pedestrian social forces and their weights (model.md section 5).
//!
//! The world gathers, for each simulated pedestrian, one [`Interaction`] per agent inside its
//! perception radius and calls [`total_force`]. Interactions beyond the perception radius are
//! not perceived: their force is below `A exp(-R_perc / B)` (under 2e-6 m/s² with the defaults).

use crate::geometry::Vec2;
use crate::params::{PedestrianModel, SocialForceParams};

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

/// Repulsion `strength * exp(-clearance / range) * n`; `n` points from the other agent to the
/// pedestrian. Equals paper's `A exp((r - d)/B) n` with `r - d` = minus the clearance.
#[inline]
pub fn repulsion(strength: f64, range: f64, clearance: f64, n: Vec2) -> Vec2 {
    n * (strength * (-clearance / range).exp())
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

/// Weight of one repulsion under `model`: `sfm` 1; `ra_sfm` `psi`; `cr_sfm` `psi (1 + lambda u)`
/// with `lambda1` for vehicles and `lambda2` for pedestrians.
#[inline]
pub fn repulsion_weight(model: PedestrianModel, p: &SocialForceParams, it: &Interaction) -> f64 {
    match model {
        PedestrianModel::RaSfm => it.psi,
        PedestrianModel::CrSfm => {
            let lambda = if it.other_is_vehicle {
                p.lambda1
            } else {
                p.lambda2
            };
            it.psi * (1.0 + lambda * it.u)
        }
        _ => 1.0,
    }
}

/// Goal weight: 1 for `sfm`; `exp(-lambda3 * max_weight)` for `ra_sfm` and `cr_sfm`, where
/// `max_weight` is the largest repulsion weight (0 with nobody perceived).
#[inline]
pub fn goal_weight(model: PedestrianModel, p: &SocialForceParams, max_weight: f64) -> f64 {
    match model {
        PedestrianModel::RaSfm | PedestrianModel::CrSfm => (-p.lambda3 * max_weight).exp(),
        _ => 1.0,
    }
}

/// The resultant force `w_goal F_goal + sum_j w_j F_j` (m/s², unit mass).
pub fn total_force(
    model: PedestrianModel,
    p: &SocialForceParams,
    f_goal: Vec2,
    interactions: impl IntoIterator<Item = Interaction>,
) -> Vec2 {
    let mut sum = Vec2::zeros();
    let mut max_w: f64 = 0.0;
    for it in interactions {
        let w = repulsion_weight(model, p, &it);
        let f = if it.other_is_vehicle {
            repulsion(p.a_veh, p.b_veh, it.clearance, it.normal)
        } else {
            repulsion(p.a_ped, p.b_ped, it.clearance, it.normal)
        };
        max_w = max_w.max(w);
        sum += f * w;
    }
    f_goal * goal_weight(model, p, max_w) + sum
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
