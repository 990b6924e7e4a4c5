//! Physical risk by virtual distance (model.md section 4) and the risk-graph adjacency (section 6):
//! [`edge_psi`] is the one implementation of `psi` that runs; the paper's unfolded form
//! (virtual distance, then `1 / (1 + gamma2 d_v)`) lives in sim-core/tests/equations.rs as its
//! oracle.

use crate::geometry::Vec2;
use crate::params::RiskParams;

/// Adjacency entry `A = psi (1 + lambda u)`.
#[inline]
pub fn adjacency(psi: f64, u: f64, lambda: f64) -> f64 {
    psi * (1.0 + lambda * u)
}

/// `psi(i, j)` straight from the centre offset `to_i = x_i - x_j` (length `dist`), through
/// [`edge_psi`]: model.md's `d_v = d (1 + tanh z)` and `psi = 1 / (1 + gamma2 d_v)` folded into
/// one exponential and one division, `psi = (1 + e) / (1 + e + 2 gamma2 d)` with
/// `e = exp(-2z)`. The paper-form composition is the oracle in sim-core/tests/equations.rs.
#[inline]
pub fn risk_with(
    clearance: f64,
    to_i: Vec2,
    dist: f64,
    v_j: Vec2,
    acc_j: f64,
    params: &RiskParams,
) -> f64 {
    edge_psi(params, v_j.dot(&to_i), dist, acc_j, clearance).0
}

/// The world step's `psi` of one edge, and `1 / dist` (1 for coincident centres): the one
/// implementation of model.md section 4 that runs. Inputs: `along = v_j . (x_i - x_j)`, the
/// centre distance, the target's acceleration norm and the clearance.
/// Branch-free (selects only) and with the crate's vectorisable `exp`, so it is inlined into
/// and compiled for each instruction-set variant of the observe pass.
#[inline(always)]
pub fn edge_psi(
    params: &RiskParams,
    along: f64,
    dist: f64,
    acc_norm: f64,
    clearance: f64,
) -> (f64, f64) {
    // |v_j| |cos phi|, 0 for coincident centres (where `along` is 0 too).
    let inv_dist = crate::geometry::inv_distance(dist);
    let radial_speed = along.abs() * inv_dist;
    let k = if along > 0.0 { -1.0 } else { 1.0 };
    let z = params.gamma1 * k * (radial_speed + acc_norm);
    let one_plus_e = 1.0 + crate::support::fastmath::exp(-2.0 * z);
    let psi = one_plus_e / (one_plus_e + 2.0 * params.gamma2 * clearance);
    // d_virtual = 0 (the agent rushes at the observer): psi = 1, as the unfolded form.
    let psi = if one_plus_e == f64::INFINITY {
        1.0
    } else {
        psi
    };
    (psi, inv_dist)
}
