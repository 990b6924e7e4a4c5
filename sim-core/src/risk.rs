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
    virtual_distance_with(clearance, to_i, to_i.norm(), v_j, acc_j, gamma1)
}

/// [`virtual_distance`] with the centre offset `to_i = x_i - x_j` and its length already known.
///
/// Uses `1 + tanh(z) = 2 / (1 + exp(-2z))`: the same value with one exponential instead of the
/// two of `tanh`, on the hottest line of a step.
#[inline]
pub fn virtual_distance_with(
    clearance: f64,
    to_i: Vec2,
    dist: f64,
    v_j: Vec2,
    acc_j: f64,
    gamma1: f64,
) -> f64 {
    let along = v_j.dot(&to_i);
    // |v_j| |cos phi| = |v_j . to_i| / |to_i|; undefined (taken as 0) for coincident centres.
    let radial_speed = if dist > 0.0 { along.abs() / dist } else { 0.0 };
    let k = if along > 0.0 { -1.0 } else { 1.0 };
    let z = gamma1 * k * (radial_speed + acc_j);
    clearance * (2.0 / (1.0 + (-2.0 * z).exp()))
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

/// `psi(i, j)` straight from the centre offset `to_i = x_i - x_j` (length `dist`): the
/// composition of [`virtual_distance_with`] and [`physical_risk`] folded into one exponential and
/// one division, `psi = (1 + e) / (1 + e + 2 gamma2 d)` with `e = exp(-2z)`, as [`edge_psi`]
/// computes it for every edge of the world step.
#[inline]
pub fn risk_with(
    clearance: f64,
    to_i: Vec2,
    dist: f64,
    v_j: Vec2,
    acc_j: f64,
    params: &RiskParams,
) -> f64 {
    let along = v_j.dot(&to_i);
    edge_psi(
        params.gamma1,
        2.0 * params.gamma2,
        along,
        dist,
        acc_j,
        clearance,
    )
    .0
}

/// The world step's `psi` of one edge, and `1 / dist` (1 for coincident centres): the one
/// implementation of model.md section 4 that runs. Inputs: `along = v_j . (x_i - x_j)`, the
/// centre distance, the target's acceleration norm and the clearance; `two_gamma2 = 2 gamma2`.
/// Branch-free (selects only) and with the crate's vectorisable `exp`, so it is inlined into
/// and compiled for each instruction-set variant of the observe pass.
#[inline(always)]
pub fn edge_psi(
    gamma1: f64,
    two_gamma2: f64,
    along: f64,
    dist: f64,
    acc_norm: f64,
    clearance: f64,
) -> (f64, f64) {
    // |v_j| |cos phi|, 0 for coincident centres (where `along` is 0 too); an unconditional
    // division keeps the loop vectorisable.
    let inv_dist = 1.0 / if dist > 0.0 { dist } else { 1.0 };
    let radial_speed = along.abs() * inv_dist;
    let k = if along > 0.0 { -1.0 } else { 1.0 };
    let z = gamma1 * k * (radial_speed + acc_norm);
    let one_plus_e = 1.0 + crate::fastmath::exp(-2.0 * z);
    let psi = one_plus_e / (one_plus_e + two_gamma2 * clearance);
    // d_virtual = 0 (the agent rushes at the observer): psi = 1, as the unfolded form.
    let psi = if one_plus_e == f64::INFINITY {
        1.0
    } else {
        psi
    };
    (psi, inv_dist)
}
