//! Physical risk by virtual distance (model.md section 4) and the risk-graph adjacency (section 6).

use crate::geometry::Vec2;
use crate::params::RiskParams;

/// Virtual distance from observer `i` at `x_i` to agent `j` at `x_j` moving with `v_j` and
/// acceleration magnitude `acc_j`, at clearance `clearance`:
/// `d_v = d (1 + tanh(gamma1 k (|v_j| |cos phi| + |a_j|)))` where `phi` is the angle between `v_j`
/// and `x_i - x_j`, and `k = -1` when `j` approaches `i` (`v_j . (x_i - x_j) > 0`), else `+1`.
#[inline]
pub fn virtual_distance(
    clearance: f64,
    x_i: Vec2,
    x_j: Vec2,
    v_j: Vec2,
    acc_j: f64,
    gamma1: f64,
) -> f64 {
    let to_i = x_i - x_j;
    let along = v_j.dot(&to_i);
    let dist = to_i.norm();
    // |v_j| |cos phi| = |v_j . to_i| / |to_i|; undefined (taken as 0) for coincident centres.
    let radial_speed = if dist > 0.0 { along.abs() / dist } else { 0.0 };
    let k = if along > 0.0 { -1.0 } else { 1.0 };
    clearance * (1.0 + (gamma1 * k * (radial_speed + acc_j)).tanh())
}

/// Physical risk `psi = 1 / (1 + gamma2 d_virtual)`.
#[inline]
pub fn physical_risk(d_virtual: f64, gamma2: f64) -> f64 {
    1.0 / (1.0 + gamma2 * d_virtual)
}

/// Adjacency entry `A = psi (1 + lambda u)`.
#[inline]
pub fn adjacency(psi: f64, u: f64, lambda: f64) -> f64 {
    psi * (1.0 + lambda * u)
}

/// `psi(i, j)` from the raw quantities, with `params`' gains.
#[inline]
pub fn risk(
    clearance: f64,
    x_i: Vec2,
    x_j: Vec2,
    v_j: Vec2,
    acc_j: f64,
    params: &RiskParams,
) -> f64 {
    physical_risk(
        virtual_distance(clearance, x_i, x_j, v_j, acc_j, params.gamma1),
        params.gamma2,
    )
}
