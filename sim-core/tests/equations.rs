//! Every equation of `shared/spec/model.md` gives the value worked out by hand next to each check.

mod common;

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use common::{line, paper_world, track};
use sim_core::geometry::{clearance, clearance_and_normal, disc_rect_gap, Placed, Shape, Vec2};
use sim_core::metrics::{
    displacement_errors, DisplacementErrors, EpisodeMetrics, EpisodeStatus, MetricsSummary,
    PedestrianEvalSummary,
};
use sim_core::model::cognition::{kl_isotropic, posterior, Belief, VarianceSchedule, DIM};
use sim_core::model::pedestrian::{
    clip_norm, goal_force, goal_weight, integrate, repulsion, repulsion_weight, total_force,
    Interaction,
};
use sim_core::model::risk::adjacency;
use sim_core::model::vehicle::{
    map_action, unicycle_step, wrap_angle, UnicycleState, VehicleCommand,
};
use sim_core::params::RiskParams;
use sim_core::params::{CognitionParams, PredictionModel, SocialForceParams, VehicleParams};
use sim_core::scenario::{AgentKind, AgentRecord};
use sim_core::world::{Event, RewardTerms};
use sim_core::{PedestrianModel, StepOutcome, World};

const EPS: f64 = 1e-12;

// model.md section 4 in the paper's unfolded form: the oracle that `sim_core::model::risk::edge_psi`
// (the one implementation the world step runs) is checked against.

/// Virtual distance from observer `i` at `x_i` to agent `j` at `x_j` moving with `v_j` and
/// acceleration magnitude `acc_j`, at clearance `clearance`:
/// `d_v = d (1 + tanh(gamma1 k (|v_j| |cos phi| + |a_j|)))` where `phi` is the angle between `v_j`
/// and `x_i - x_j`, and `k = -1` when `j` approaches `i` (`v_j . (x_i - x_j) > 0`), else `+1`.
fn virtual_distance(
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
fn virtual_distance_with(
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
fn physical_risk(d_virtual: f64, gamma2: f64) -> f64 {
    1.0 / (1.0 + gamma2 * d_virtual)
}

/// `psi(i, j)` from the raw quantities, with `params`' gains.
fn risk(
    clearance: f64,
    x_i: Vec2,
    x_j: Vec2,
    v_j: Vec2,
    acc_j: f64,
    params: &sim_core::params::RiskParams,
) -> f64 {
    physical_risk(
        virtual_distance(clearance, x_i, x_j, v_j, acc_j, params.gamma1),
        params.gamma2,
    )
}

fn close(got: f64, want: f64) {
    assert!(
        (got - want).abs() <= EPS * want.abs().max(1.0),
        "got {got}, want {want} (diff {})",
        got - want
    );
}

fn close_v(got: Vec2, want: [f64; 2]) {
    close(got.x, want[0]);
    close(got.y, want[1]);
}

fn v(x: f64, y: f64) -> Vec2 {
    Vec2::new(x, y)
}

fn disc(x: f64, y: f64, r: f64) -> Placed {
    Placed {
        shape: Shape::Disc { radius: r },
        position: v(x, y),
        heading: 0.0,
    }
}

/// The default AV footprint (4.0 x 1.8: half-extents 2.0 along, 0.9 across the heading).
fn car(x: f64, y: f64, heading: f64) -> Placed {
    Placed {
        shape: Shape::Rect {
            length: 4.0,
            width: 1.8,
        },
        position: v(x, y),
        heading,
    }
}

// ---------------------------------------------------------------- clearance (model.md 1)

#[test]
fn clearance_disc_disc_is_centre_distance_minus_radii() {
    // d = 5 - 0.3 - 0.3 = 4.4
    close(clearance(&disc(0.0, 0.0, 0.3), &disc(5.0, 0.0, 0.3)), 4.4);
    // d = |(3, 4)| - 0.3 - 0.5 = 5 - 0.8 = 4.2
    close(clearance(&disc(1.0, 1.0, 0.3), &disc(4.0, 5.0, 0.5)), 4.2);
    // normal from b to a: (a - b) / |a - b| = (-3, -4) / 5 = (-0.6, -0.8)
    let (_, n) = clearance_and_normal(&disc(1.0, 1.0, 0.3), &disc(4.0, 5.0, 0.5));
    close_v(n, [-0.6, -0.8]);
}

#[test]
fn clearance_disc_disc_overlap_is_floored_at_zero() {
    // 0.4 - 0.3 - 0.3 = -0.2 -> floored to 0
    assert_eq!(clearance(&disc(0.0, 0.0, 0.3), &disc(0.4, 0.0, 0.3)), 0.0);
    // exactly touching: 0.6 - 0.6 = 0
    assert_eq!(clearance(&disc(0.0, 0.0, 0.3), &disc(0.6, 0.0, 0.3)), 0.0);
    // coincident centres: 0 - 0.6 -> 0, and the normal is the zero vector
    let (c, n) = clearance_and_normal(&disc(2.0, 2.0, 0.3), &disc(2.0, 2.0, 0.3));
    assert_eq!(c, 0.0);
    assert_eq!(n, Vec2::zeros());
}

#[test]
fn clearance_disc_rectangle_side() {
    // disc above the long side: 3 - 0.9 (half width) - 0.3 = 1.8
    close(clearance(&disc(0.0, 3.0, 0.3), &car(0.0, 0.0, 0.0)), 1.8);
    // disc ahead of the front: 5 - 2.0 (half length) - 0.3 = 2.7
    close(clearance(&disc(5.0, 0.0, 0.3), &car(0.0, 0.0, 0.0)), 2.7);
    // disc behind, off-centre but within the width: 5 - 2.0 - 0.3 = 2.7
    close(clearance(&disc(-5.0, 0.5, 0.3), &car(0.0, 0.0, 0.0)), 2.7);
    // normal from the rectangle's nearest point to the disc: straight up (0, 1)
    let (_, n) = clearance_and_normal(&disc(0.0, 3.0, 0.3), &car(0.0, 0.0, 0.0));
    close_v(n, [0.0, 1.0]);
}

#[test]
fn clearance_disc_rectangle_corner() {
    // nearest point is the corner (2, 0.9); disc at (5, 4.9): |(3, 4)| - 0.3 = 5 - 0.3 = 4.7
    close(clearance(&disc(5.0, 4.9, 0.3), &car(0.0, 0.0, 0.0)), 4.7);
    // normal = (3, 4) / 5 = (0.6, 0.8)
    let (_, n) = clearance_and_normal(&disc(5.0, 4.9, 0.3), &car(0.0, 0.0, 0.0));
    close_v(n, [0.6, 0.8]);
    // rear-right corner (-2, -0.9) to (-5, -4.9): again 5 - 0.3 = 4.7
    close(clearance(&disc(-5.0, -4.9, 0.3), &car(0.0, 0.0, 0.0)), 4.7);
}

#[test]
fn clearance_disc_rotated_rectangle() {
    // heading pi/2: the long side runs along y. Disc at (0, 5): 5 - 2.0 - 0.3 = 2.7
    close(
        clearance(&disc(0.0, 5.0, 0.3), &car(0.0, 0.0, FRAC_PI_2)),
        2.7,
    );
    // disc at (3, 0) is beside it: 3 - 0.9 - 0.3 = 1.8
    close(
        clearance(&disc(3.0, 0.0, 0.3), &car(0.0, 0.0, FRAC_PI_2)),
        1.8,
    );
    // heading pi/4, disc 5 m ahead along the heading from a car at (1, 1):
    // centre (1 + 5 cos 45deg, 1 + 5 sin 45deg): 5 - 2.0 - 0.3 = 2.7
    let c = 5.0 * FRAC_PI_4.cos();
    close(
        clearance(&disc(1.0 + c, 1.0 + c, 0.3), &car(1.0, 1.0, FRAC_PI_4)),
        2.7,
    );
    // ... and its normal points along the heading (cos 45deg, sin 45deg)
    let (_, n) = clearance_and_normal(&disc(1.0 + c, 1.0 + c, 0.3), &car(1.0, 1.0, FRAC_PI_4));
    close_v(n, [FRAC_PI_4.cos(), FRAC_PI_4.sin()]);
    // the same disc for an unrotated car: nearest point is the corner (3, 1.9) of the car at
    // (1, 1); offset (1 + c - 3, 1 + c - 1.9) = (c - 2, c - 0.9)
    let want = (c - 2.0).hypot(c - 0.9) - 0.3;
    close(
        clearance(&disc(1.0 + c, 1.0 + c, 0.3), &car(1.0, 1.0, 0.0)),
        want,
    );
}

#[test]
fn clearance_disc_centre_inside_rectangle() {
    // centre (1.5, 0.2) inside: depth to the front 2 - 1.5 = 0.5, to the side 0.9 - 0.2 = 0.7;
    // signed gap = -0.5 - 0.3 = -0.8 pushing along +x; clearance floors it at 0
    let (gap, n) = disc_rect_gap(v(1.5, 0.2), 0.3, v(0.0, 0.0), 0.0, 4.0, 1.8);
    close(gap, -0.8);
    close_v(n, [1.0, 0.0]);
    assert_eq!(clearance(&disc(1.5, 0.2, 0.3), &car(0.0, 0.0, 0.0)), 0.0);
    // centre (-0.5, -0.6): depth to rear 2 - 0.5 = 1.5, to the right side 0.9 - 0.6 = 0.3;
    // gap = -0.3 - 0.3 = -0.6, pushing along -y
    let (gap, n) = disc_rect_gap(v(-0.5, -0.6), 0.3, v(0.0, 0.0), 0.0, 4.0, 1.8);
    close(gap, -0.6);
    close_v(n, [0.0, -1.0]);
    // disc partially overlapping from outside: centre (2.1, 0): 0.1 - 0.3 = -0.2 -> 0
    assert_eq!(clearance(&disc(2.1, 0.0, 0.3), &car(0.0, 0.0, 0.0)), 0.0);
}

#[test]
fn clearance_rectangle_disc_is_the_disc_rectangle_clearance_with_reversed_normal() {
    let (c1, n1) = clearance_and_normal(&disc(5.0, 4.9, 0.3), &car(0.0, 0.0, 0.0));
    let (c2, n2) = clearance_and_normal(&car(0.0, 0.0, 0.0), &disc(5.0, 4.9, 0.3));
    // 4.7 both ways; the normal points from the disc to the car: -(0.6, 0.8)
    close(c1, 4.7);
    close(c2, 4.7);
    close_v(n2, [-n1.x, -n1.y]);
    close_v(n2, [-0.6, -0.8]);
}

#[test]
fn clearance_rectangle_rectangle() {
    // in line: 10 - 2.0 - 2.0 = 6
    close(clearance(&car(0.0, 0.0, 0.0), &car(10.0, 0.0, 0.0)), 6.0);
    // side by side: 3 - 0.9 - 0.9 = 1.2
    close(clearance(&car(0.0, 0.0, 0.0), &car(0.0, 3.0, 0.0)), 1.2);
    // second rotated by pi/2 (its half-extent along x is 0.9): 10 - 2.0 - 0.9 = 7.1
    close(
        clearance(&car(0.0, 0.0, 0.0), &car(10.0, 0.0, FRAC_PI_2)),
        7.1,
    );
    // corner to corner: (2, 0.9) and (7 - 2, 5.8 - 0.9) = (5, 4.9): |(3, 4)| = 5
    close(clearance(&car(0.0, 0.0, 0.0), &car(7.0, 5.8, 0.0)), 5.0);
    // overlapping: 3 - 4 < 0 -> 0
    assert_eq!(clearance(&car(0.0, 0.0, 0.0), &car(3.0, 0.0, 0.0)), 0.0);
    // crossing without any corner inside the other (a plus sign): 0
    let long = Placed {
        shape: Shape::Rect {
            length: 10.0,
            width: 1.0,
        },
        position: v(0.0, 0.0),
        heading: 0.0,
    };
    let cross = Placed {
        heading: FRAC_PI_2,
        ..long
    };
    assert_eq!(clearance(&long, &cross), 0.0);
    // one inside the other: 0
    let small = Placed {
        shape: Shape::Rect {
            length: 1.0,
            width: 0.5,
        },
        position: v(0.5, 0.1),
        heading: 0.3,
    };
    assert_eq!(clearance(&car(0.0, 0.0, 0.0), &small), 0.0);
    assert_eq!(clearance(&small, &car(0.0, 0.0, 0.0)), 0.0);
}

#[test]
fn bounding_radius_of_shapes() {
    // rectangle: 0.5 * sqrt(4^2 + 1.8^2) = 0.5 * sqrt(19.24)
    close(
        Shape::Rect {
            length: 4.0,
            width: 1.8,
        }
        .bounding_radius(),
        0.5 * 19.24f64.sqrt(),
    );
    close(Shape::Disc { radius: 0.3 }.bounding_radius(), 0.3);
}

// ---------------------------------------------------------------- cognition (model.md 3)

#[test]
fn kl_of_two_isotropic_gaussians() {
    // mu_p = (1, 0), s_p^2 = 0.5, mu_o = (1.5, 0.5), s_o^2 = 0.25, k = 2; |mu_o - mu_p|^2 = 0.5
    // KL = 0.5 [2*0.5/0.25 + 0.5/0.25 - 2 + 2 ln(0.25/0.5)] = 0.5 [4 + 2 - 2 - 2 ln 2] = 2 - ln 2
    close(
        kl_isotropic(v(1.0, 0.0), 0.5, v(1.5, 0.5), 0.25, DIM),
        2.0 - 2f64.ln(),
    );
    // identical distributions: 0.5 [2 + 0 - 2 + 2 ln 1] = 0
    close(kl_isotropic(v(3.0, -1.0), 0.7, v(3.0, -1.0), 0.7, 2.0), 0.0);
    // same means, s_p^2 = 1.09, s_o^2 = 0.25: 0.5 [2*4.36 - 2 + 2 ln(0.25/1.09)]
    close(
        kl_isotropic(v(0.0, 0.0), 1.09, v(0.0, 0.0), 0.25, 2.0),
        0.5 * (8.72 - 2.0 + 2.0 * (0.25f64 / 1.09).ln()),
    );
    assert_eq!(DIM, 2.0);
}

#[test]
fn bayesian_posterior_mean_and_variance() {
    // 1/s2 = 1/1 + 1/0.25 = 5 -> s2 = 0.2; mu = 0.2 ((1, 0)/1 + (0, 2)/0.25) = 0.2 (1, 8) = (0.2, 1.6)
    let (mu, s2) = posterior(v(1.0, 0.0), 1.0, v(0.0, 2.0), 0.25);
    close(s2, 0.2);
    close_v(mu, [0.2, 1.6]);
    // equal variances 0.5 and 0.5: s2 = 0.25, mu = the midpoint of (2, 2) and (4, 0) = (3, 1)
    let (mu, s2) = posterior(v(2.0, 2.0), 0.5, v(4.0, 0.0), 0.5);
    close(s2, 0.25);
    close_v(mu, [3.0, 1.0]);
}

/// Variances of the default parameters (s0 = 1, q = 0.3, s_o = 0.5), by hand.
struct Hand {
    prior1: f64,
    post1: f64,
    prior2: f64,
    post2: f64,
    prior3: f64,
    post3: f64,
}

/// u written out for isotropic 2-D Gaussians (model.md 4): prior variance `prior`, observation
/// noise variance 0.25 (the default), squared distance `miss2` between prediction and
/// observation.
fn kl_by_hand(prior: f64, miss2: f64) -> f64 {
    let s2o = 0.25;
    0.5 * (2.0 * prior / s2o + miss2 / s2o - 2.0 + 2.0 * (s2o / prior).ln())
}

fn hand_variances() -> Hand {
    // post0 = s0^2 = 1; prior1 = 1 + 0.3^2 = 1.09
    let prior1 = 1.09;
    // post1 = 1 / (1/1.09 + 1/0.25) = 1.09 / (1 + 4 * 1.09) = 1.09 / 5.36 ~ 0.203358
    let post1 = 1.09 / 5.36;
    // prior2 = post1 + 0.09 ~ 0.293358; post2 = prior2 / (1 + 4 prior2) ~ 0.134977
    let prior2 = post1 + 0.09;
    let post2 = prior2 / (1.0 + 4.0 * prior2);
    let prior3 = post2 + 0.09;
    let post3 = prior3 / (1.0 + 4.0 * prior3);
    Hand {
        prior1,
        post1,
        prior2,
        post2,
        prior3,
        post3,
    }
}

#[test]
fn variance_schedule_follows_the_recurrence() {
    let s = VarianceSchedule::new(&CognitionParams::default());
    let h = hand_variances();
    close(s.posterior_variance(0), 1.0);
    close(s.prior_variance(1), h.prior1);
    close(s.posterior_variance(1), h.post1);
    close(s.prior_variance(2), h.prior2);
    close(s.posterior_variance(2), h.post2);
    close(s.prior_variance(3), h.prior3);
    close(s.posterior_variance(3), h.post3);
    // fixed point: s = (s + q^2) s_o^2 / (s + q^2 + s_o^2) <=> s^2 + q^2 s - q^2 s_o^2 = 0
    // s = (-0.09 + sqrt(0.0081 + 4 * 0.09 * 0.25)) / 2 = (-0.09 + sqrt(0.0981)) / 2 ~ 0.111605
    let fixed = (-0.09 + 0.0981f64.sqrt()) / 2.0;
    close(s.posterior_variance(100_000), fixed);
    close(s.prior_variance(u32::MAX), fixed + 0.09);
}

#[test]
fn belief_first_sight_is_the_observed_velocity_with_no_updates() {
    // mu = v_j, s2 = s0^2 (posterior variance after 0 updates), no change observed yet
    let b = Belief::first_sight(v(1.0, -2.0));
    assert_eq!(b.mu, v(1.0, -2.0));
    assert_eq!(b.updates, 0);
    // before any update even the constant-acceleration model predicts the mean
    assert_eq!(
        b.predict(PredictionModel::ConstantAcceleration, v(9.0, 9.0)),
        v(1.0, -2.0)
    );
}

#[test]
fn belief_update_constant_velocity_over_three_steps() {
    let sched = VarianceSchedule::new(&CognitionParams::default());
    let h = hand_variances();
    let s2o = 0.25;
    let mut b = Belief::first_sight(v(1.0, 0.0));

    // step 1: mu_p = (1, 0), s_p^2 = 1.09, o = (1.5, 0): |o - mu_p|^2 = 0.25
    // u1 = 0.5 [2*1.09/0.25 + 0.25/0.25 - 2 + 2 ln(0.25/1.09)]
    let u1 = b.update(
        b.predict(PredictionModel::ConstantVelocity, Vec2::zeros()),
        v(1.5, 0.0),
        &sched,
    );
    close(u1, kl_by_hand(h.prior1, 0.25));
    // mu1 = post1 ((1, 0)/1.09 + (1.5, 0)/0.25) = post1 (1/1.09 + 6, 0)
    let mu1x = h.post1 * (1.0 / h.prior1 + 6.0);
    close_v(b.mu, [mu1x, 0.0]);
    assert_eq!(b.updates, 1);

    // step 2: mu_p = mu1, s_p^2 = prior2, o = (1.5, 0.5): |o - mu_p|^2 = (1.5 - mu1x)^2 + 0.25
    let u2 = b.update(
        b.predict(PredictionModel::ConstantVelocity, Vec2::zeros()),
        v(1.5, 0.5),
        &sched,
    );
    let d2 = (1.5 - mu1x).powi(2) + 0.25;
    close(u2, kl_by_hand(h.prior2, d2));
    // mu2 = post2 (mu1/prior2 + o/0.25)
    let mu2 = [
        h.post2 * (mu1x / h.prior2 + 1.5 / s2o),
        h.post2 * (0.0 / h.prior2 + 0.5 / s2o),
    ];
    close_v(b.mu, mu2);

    // step 3: observation equal to the belief mean: only the variance part of the KL remains
    let obs = b.mu;
    let u3 = b.update(obs, obs, &sched);
    close(u3, kl_by_hand(h.prior3, 0.0));
    // mu3 = post3 (mu2/prior3 + mu2/0.25) = mu2 * post3 (1/prior3 + 4) = mu2
    close_v(b.mu, mu2);
    assert_eq!(b.updates, 3);
}

#[test]
fn belief_update_constant_acceleration_over_three_steps() {
    let sched = VarianceSchedule::new(&CognitionParams::default());
    let h = hand_variances();
    let ca = PredictionModel::ConstantAcceleration;
    // observations accelerate by 0.5 m/s per step along x: 1.0 (first sight), 1.5, 2.0, 2.5
    let mut b = Belief::first_sight(v(1.0, 0.0));

    // step 1: no change observed yet: mu_p = mu0 = (1, 0); |(1.5,0) - (1,0)|^2 = 0.25
    // the observed change of velocity is the target's history, supplied by the caller
    let u1 = b.update(b.predict(ca, Vec2::zeros()), v(1.5, 0.0), &sched);
    close(u1, kl_by_hand(h.prior1, 0.25));
    // mu1 = post1 (1/1.09 + 1.5/0.25) = post1 (1/1.09 + 6)
    let mu1 = h.post1 * (1.0 / h.prior1 + 6.0);
    close_v(b.mu, [mu1, 0.0]);

    // step 2: mu_p = mu1 + (1.5 - 1.0) = mu1 + 0.5; o = 2.0
    let u2 = b.update(b.predict(ca, v(0.5, 0.0)), v(2.0, 0.0), &sched);
    let mp2 = mu1 + 0.5;
    close(u2, kl_by_hand(h.prior2, (2.0 - mp2).powi(2)));
    // mu2 = post2 (mp2/prior2 + 2.0/0.25)
    let mu2 = h.post2 * (mp2 / h.prior2 + 8.0);
    close_v(b.mu, [mu2, 0.0]);

    // step 3: mu_p = mu2 + (2.0 - 1.5) = mu2 + 0.5; o = 2.5
    let u3 = b.update(b.predict(ca, v(0.5, 0.0)), v(2.5, 0.0), &sched);
    let mp3 = mu2 + 0.5;
    close(u3, kl_by_hand(h.prior3, (2.5 - mp3).powi(2)));
    // mu3 = post3 (mp3/prior3 + 2.5/0.25)
    close_v(b.mu, [h.post3 * (mp3 / h.prior3 + 10.0), 0.0]);

    // the constant-velocity model would have predicted mu2 for step 3 and been further off
    let mut cv = Belief::first_sight(v(1.0, 0.0));
    let mut u_cv = 0.0;
    for o in [1.5, 2.0, 2.5] {
        u_cv = cv.update(
            cv.predict(PredictionModel::ConstantVelocity, Vec2::zeros()),
            v(o, 0.0),
            &sched,
        );
    }
    assert!(u3 < u_cv, "CA {u3} should be less surprised than CV {u_cv}");
}

// ---------------------------------------------------------------- physical risk (model.md 4, 6)

#[test]
fn virtual_distance_approaching_uses_k_minus_one() {
    // i at (0,0), j at (5,0) moving (-1,0): v_j . (x_i - x_j) = (-1)(-5) = 5 > 0 -> k = -1;
    // |v_j| |cos phi| = 1; |a_j| = 0.4; d_v = 4.4 (1 + tanh(0.5 * -1 * (1 + 0.4))) = 4.4 (1 + tanh(-0.7))
    close(
        virtual_distance(4.4, v(0.0, 0.0), v(5.0, 0.0), v(-1.0, 0.0), 0.4, 0.5),
        4.4 * (1.0 + (-0.7f64).tanh()),
    );
    // oblique approach v_j = (-1, 1): |v_j| |cos phi| = |(-1,1).(-5,0)| / 5 = 1 (= sqrt2 cos 45deg)
    // d_v = 4.4 (1 + tanh(-0.5 * 1)) = 4.4 (1 + tanh(-0.5))
    close(
        virtual_distance(4.4, v(0.0, 0.0), v(5.0, 0.0), v(-1.0, 1.0), 0.0, 0.5),
        4.4 * (1.0 + (-0.5f64).tanh()),
    );
}

#[test]
fn virtual_distance_moving_away_uses_k_plus_one() {
    // v_j = (1, 0) away from i: v_j . (x_i - x_j) = -5 <= 0 -> k = +1;
    // d_v = 4.4 (1 + tanh(0.5 * (1 + 0.4))) = 4.4 (1 + tanh(0.7))
    close(
        virtual_distance(4.4, v(0.0, 0.0), v(5.0, 0.0), v(1.0, 0.0), 0.4, 0.5),
        4.4 * (1.0 + 0.7f64.tanh()),
    );
    // moving perpendicular (0, 2): dot = 0 -> k = +1, |cos phi| = 0: d_v = 4.4 (1 + tanh(0.5*0.4))
    close(
        virtual_distance(4.4, v(0.0, 0.0), v(5.0, 0.0), v(0.0, 2.0), 0.4, 0.5),
        4.4 * (1.0 + 0.2f64.tanh()),
    );
}

#[test]
fn virtual_distance_still_agent_is_the_clearance() {
    // v_j = 0, a_j = 0: k = +1, tanh(0) = 0 -> d_v = d = 4.4
    close(
        virtual_distance(4.4, v(0.0, 0.0), v(5.0, 0.0), v(0.0, 0.0), 0.0, 0.5),
        4.4,
    );
    // still but accelerating 1 m/s^2: k = +1 -> d_v = 4.4 (1 + tanh(0.5))
    close(
        virtual_distance(4.4, v(0.0, 0.0), v(5.0, 0.0), v(0.0, 0.0), 1.0, 0.5),
        4.4 * (1.0 + 0.5f64.tanh()),
    );
    // zero clearance stays zero: 0 * (...) = 0
    assert_eq!(
        virtual_distance(0.0, v(0.0, 0.0), v(0.1, 0.0), v(-3.0, 0.0), 2.0, 0.5),
        0.0
    );
}

#[test]
fn physical_risk_psi() {
    // psi = 1 / (1 + 1.0 * 3) = 0.25
    close(physical_risk(3.0, 1.0), 0.25);
    // psi = 1 / (1 + 2 * 0.5) = 0.5
    close(physical_risk(0.5, 2.0), 0.5);
    // zero distance: psi = 1
    close(physical_risk(0.0, 1.0), 1.0);
    // the composed `risk`: d = 4.4 approaching at 1 m/s, a = 0.4:
    // psi = 1 / (1 + 1.0 * 4.4 (1 + tanh(-0.7)))
    let p = RiskParams::default();
    close(
        risk(4.4, v(0.0, 0.0), v(5.0, 0.0), v(-1.0, 0.0), 0.4, &p),
        1.0 / (1.0 + 4.4 * (1.0 + (-0.7f64).tanh())),
    );
}

#[test]
fn adjacency_is_psi_times_one_plus_lambda_u() {
    // A = 0.25 (1 + 1.0 * 0.6) = 0.4
    close(adjacency(0.25, 0.6, 1.0), 0.4);
    // A = 0.5 (1 + 2 * 0.25) = 0.75
    close(adjacency(0.5, 0.25, 2.0), 0.75);
    // u = 0 at first sight: A = psi
    close(adjacency(0.3, 0.0, 1.0), 0.3);
}

// ---------------------------------------------------------------- pedestrian models (model.md 5)

fn sf_params() -> SocialForceParams {
    SocialForceParams {
        lambda1: 2.0,
        lambda2: 3.0,
        lambda3: 2.0,
        ..SocialForceParams::default()
    }
}

fn interaction(vehicle: bool) -> Interaction {
    Interaction {
        other_is_vehicle: vehicle,
        clearance: 1.0,
        normal: v(0.0, 1.0),
        psi: 0.4,
        u: 0.5,
    }
}

/// `model`'s repulsion weight for the `interaction(vehicle)` fixture under `sf_params()`.
fn w_rep(model: PedestrianModel, vehicle: bool) -> f64 {
    repulsion_weight(model, &sf_params(), &interaction(vehicle))
}

/// `model`'s goal weight under `sf_params()` when the largest perceived weight is `max_w`.
fn w_goal(model: PedestrianModel, max_w: f64) -> f64 {
    goal_weight(model, &sf_params(), max_w)
}

#[test]
fn sfm_weights_are_all_one() {
    assert_eq!(w_rep(PedestrianModel::Sfm, true), 1.0);
    assert_eq!(w_rep(PedestrianModel::Sfm, false), 1.0);
    assert_eq!(w_goal(PedestrianModel::Sfm, 0.8), 1.0);
}

#[test]
fn ra_sfm_weights_are_psi_and_goal_exp_minus_lambda3_max() {
    // w_veh = w_ped = psi = 0.4
    close(w_rep(PedestrianModel::RaSfm, true), 0.4);
    close(w_rep(PedestrianModel::RaSfm, false), 0.4);
    // w_goal = exp(-2.0 * 0.4) = exp(-0.8)
    close(w_goal(PedestrianModel::RaSfm, 0.4), (-0.8f64).exp());
    // nobody perceived: exp(0) = 1
    close(w_goal(PedestrianModel::RaSfm, 0.0), 1.0);
}

#[test]
fn cr_sfm_weights_use_lambda1_for_vehicles_and_lambda2_for_pedestrians() {
    // w_veh = 0.4 (1 + 2.0 * 0.5) = 0.8
    close(w_rep(PedestrianModel::CrSfm, true), 0.8);
    // w_ped = 0.4 (1 + 3.0 * 0.5) = 1.0
    close(w_rep(PedestrianModel::CrSfm, false), 1.0);
    // w_goal = exp(-2.0 * max(0.8, 1.0)) = exp(-2)
    close(w_goal(PedestrianModel::CrSfm, 1.0), (-2.0f64).exp());
}

#[test]
fn goal_force_relaxes_towards_desired_velocity() {
    // e_goal = (3, 4)/5 = (0.6, 0.8); v0 e = (0.9, 1.2); ((0.9, 1.2) - (0.5, 0)) / 0.5 = (0.8, 2.4)
    close_v(
        goal_force(v(0.0, 0.0), v(0.5, 0.0), v(3.0, 4.0), 1.5, 0.5),
        [0.8, 2.4],
    );
    // at the goal e = 0: -v / tau = -(0.5, -1) / 0.5 = (-1, 2)
    close_v(
        goal_force(v(2.0, 2.0), v(0.5, -1.0), v(2.0, 2.0), 1.5, 0.5),
        [-1.0, 2.0],
    );
}

#[test]
fn repulsion_is_a_exp_minus_clearance_over_b() {
    // 2.1 exp(-0.6 / 0.3) (0, 1) = (0, 2.1 e^-2)
    close_v(
        repulsion(2.1, 0.3, 0.6, v(0.0, 1.0)),
        [0.0, 2.1 * (-2.0f64).exp()],
    );
    // zero clearance: full strength 4.0 along n = (0.6, -0.8): (2.4, -3.2)
    close_v(repulsion(4.0, 1.0, 0.0, v(0.6, -0.8)), [2.4, -3.2]);
}

#[test]
fn total_force_sums_weighted_goal_and_repulsions() {
    let p = SocialForceParams::default(); // a_veh 4, b_veh 1, a_ped 2.1, b_ped 0.3, lambdas 1
    let f_goal = v(1.0, 0.0);
    let veh = Interaction {
        other_is_vehicle: true,
        clearance: 1.0,
        normal: v(0.0, 1.0),
        psi: 0.5,
        u: 0.2,
    };
    let ped = Interaction {
        other_is_vehicle: false,
        clearance: 0.3,
        normal: v(-1.0, 0.0),
        psi: 0.8,
        u: 0.0,
    };
    let e1 = (-1.0f64).exp();
    // F_veh = 4 e^-1 (0, 1); F_ped = 2.1 e^(-0.3/0.3) (-1, 0) = 2.1 e^-1 (-1, 0)
    // sfm: (1, 0) + F_veh + F_ped = (1 - 2.1 e^-1, 4 e^-1)
    close_v(
        total_force(PedestrianModel::Sfm, &p, f_goal, [veh, ped]),
        [1.0 - 2.1 * e1, 4.0 * e1],
    );
    // ra_sfm: w_veh = 0.5, w_ped = 0.8, w_goal = exp(-0.8)
    // F = (exp(-0.8) - 0.8 * 2.1 e^-1, 0.5 * 4 e^-1)
    close_v(
        total_force(PedestrianModel::RaSfm, &p, f_goal, [veh, ped]),
        [(-0.8f64).exp() - 0.8 * 2.1 * e1, 0.5 * 4.0 * e1],
    );
    // cr_sfm: w_veh = 0.5 (1 + 0.2) = 0.6, w_ped = 0.8 (1 + 0) = 0.8, w_goal = exp(-0.8)
    // F = (exp(-0.8) - 0.8 * 2.1 e^-1, 0.6 * 4 e^-1)
    close_v(
        total_force(PedestrianModel::CrSfm, &p, f_goal, [veh, ped]),
        [(-0.8f64).exp() - 0.8 * 2.1 * e1, 0.6 * 4.0 * e1],
    );
    // nobody perceived: w_goal = exp(0) = 1, F = F_goal
    close_v(
        total_force(PedestrianModel::CrSfm, &p, f_goal, []),
        [1.0, 0.0],
    );
}

#[test]
fn clip_norm_scales_down_only_when_longer() {
    // |(3, 4)| = 5 > 2: (3, 4) * 2/5 = (1.2, 1.6)
    close_v(clip_norm(v(3.0, 4.0), 2.0), [1.2, 1.6]);
    // |(0.3, 0.4)| = 0.5 <= 2: unchanged
    assert_eq!(clip_norm(v(0.3, 0.4), 2.0), v(0.3, 0.4));
    assert_eq!(clip_norm(v(0.0, 0.0), 2.0), v(0.0, 0.0));
}

#[test]
fn integrate_is_explicit_with_speed_cap() {
    // v' = (1, 0) + (0, 2) * 0.5 = (1, 1) (|v'| = 1.414 < 2); x' = (1, 1) + (1, 1) * 0.5 = (1.5, 1.5)
    let (x, vel) = integrate(v(1.0, 1.0), v(1.0, 0.0), v(0.0, 2.0), 0.5, 2.0);
    close_v(vel, [1.0, 1.0]);
    close_v(x, [1.5, 1.5]);
    // v = (2, 0) + (0, 4) * 0.5 = (2, 2), |v| = 2 sqrt2 > 2 -> (sqrt2, sqrt2);
    // x' = (1, 1) + (sqrt2, sqrt2) * 0.5
    let s = 2f64.sqrt();
    let (x, vel) = integrate(v(1.0, 1.0), v(2.0, 0.0), v(0.0, 4.0), 0.5, 2.0);
    close_v(vel, [s, s]);
    close_v(x, [1.0 + 0.5 * s, 1.0 + 0.5 * s]);
}

// ---------------------------------------------------------------- AV (model.md 2)

fn uni(speed: f64, heading: f64) -> UnicycleState {
    UnicycleState {
        position: v(0.0, 0.0),
        speed,
        heading,
    }
}

#[test]
fn unicycle_step_is_semi_implicit() {
    // speed' = 2 + 1 * 0.5 = 2.5; theta' = 0 + 0.2 * 0.5 = 0.1;
    // x' = 2.5 * 0.5 * (cos 0.1, sin 0.1) = 1.25 (cos 0.1, sin 0.1) (new heading, new speed)
    let s = unicycle_step(
        uni(2.0, 0.0),
        VehicleCommand {
            acc: 1.0,
            omega: 0.2,
        },
        0.5,
        6.0,
    );
    close(s.speed, 2.5);
    close(s.heading, 0.1);
    close_v(s.position, [1.25 * 0.1f64.cos(), 1.25 * 0.1f64.sin()]);
}

#[test]
fn unicycle_speed_is_clipped_at_zero_and_six() {
    // 0.5 - 2 * 0.5 = -0.5 -> 0: no reversing, the position stays
    let s = unicycle_step(
        uni(0.5, 1.0),
        VehicleCommand {
            acc: -2.0,
            omega: 0.0,
        },
        0.5,
        6.0,
    );
    assert_eq!(s.speed, 0.0);
    assert_eq!(s.position, v(0.0, 0.0));
    // 5.8 + 2 * 0.5 = 6.8 -> 6; x' = 6 * 0.5 (1, 0) = (3, 0)
    let s = unicycle_step(
        uni(5.8, 0.0),
        VehicleCommand {
            acc: 2.0,
            omega: 0.0,
        },
        0.5,
        6.0,
    );
    assert_eq!(s.speed, 6.0);
    close_v(s.position, [3.0, 0.0]);
}

#[test]
fn map_action_is_linear_and_clips() {
    let p = VehicleParams::default(); // acc_max 2, omega_max 0.2
                                      // [0.5, -0.25] -> (0.5 * 2, -0.25 * 0.2) = (1.0, -0.05), not clipped
    let (c, clipped) = map_action([0.5, -0.25], &p);
    close(c.acc, 1.0);
    close(c.omega, -0.05);
    assert!(!clipped);
    // exactly at the bounds is not a clip: (-2, 0.2)
    let (c, clipped) = map_action([-1.0, 1.0], &p);
    assert_eq!((c.acc, c.omega), (-2.0, 0.2));
    assert!(!clipped);
    // [3, -1] -> [1, -1] -> (2, -0.2), clipped
    let (c, clipped) = map_action([3.0, -1.0], &p);
    assert_eq!((c.acc, c.omega), (2.0, -0.2));
    assert!(clipped);
    // huge values: [-1e300, 1e300] -> (-2, 0.2), clipped
    let (c, clipped) = map_action([-1e300, 1e300], &p);
    assert_eq!((c.acc, c.omega), (-2.0, 0.2));
    assert!(clipped);
}

#[test]
fn wrap_angle_maps_into_minus_pi_pi() {
    close(wrap_angle(0.0), 0.0);
    close(wrap_angle(PI), PI);
    // -pi is outside (-pi, pi]: -pi + 2pi = pi
    close(wrap_angle(-PI), PI);
    // 3pi/2 - 2pi = -pi/2
    close(wrap_angle(1.5 * PI), -0.5 * PI);
    // -3pi/2 + 2pi = pi/2
    close(wrap_angle(-1.5 * PI), 0.5 * PI);
    // 2pi + 0.5 -> 0.5; -4pi - 0.5 -> -0.5
    close(wrap_angle(2.0 * PI + 0.5), 0.5);
    close(wrap_angle(-4.0 * PI - 0.5), -0.5);
}

// ---------------------------------------------------------------- reward (model.md 7)

fn terms(out: &sim_core::StepOutcome) -> RewardTerms {
    assert_eq!(out.agents.len(), 1);
    out.agents[0].reward
}

/// The ego's step outcome and reward terms after one step with action [0, 0] (speed and
/// heading kept) in the paper's set-up of `agents`.
fn coasting_step(agents: Vec<AgentRecord>, model: PedestrianModel) -> (StepOutcome, RewardTerms) {
    let out = paper_world(agents, model).step(&[(0, [0.0, 0.0])]).unwrap();
    let r = terms(&out);
    (out, r)
}

/// Ego car 0 at (0, 0) driving (2, 0), goal (10, 0); pedestrian 1 (`cv`) at (3.25, -2) walking
/// (0, 0.2).
fn reward_world() -> World {
    paper_world(
        vec![
            // 11 samples at 2 m/s: (0,0) .. (10,0); goal (10, 0)
            line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11),
            line(AgentKind::Pedestrian, 0, [3.25, -2.0], [0.0, 0.2], 11),
        ],
        PedestrianModel::Cv,
    )
}

#[test]
fn reward_progress_danger_and_comfort_of_two_steps() {
    let mut w = reward_world();
    // step 1, action [0.5, 0]: acc = 1, omega = 0; speed 2 + 0.5 = 2.5; x = (1.25, 0)
    let out = w.step(&[(0, [0.5, 0.0])]).unwrap();
    let r = terms(&out);
    close_v(w.agent(0).unwrap().position, [1.25, 0.0]);
    // progress = d(0) - d(1) = 10 - 8.75 = 1.25
    close(r.progress, 1.25);
    // pedestrian at (3.25, -1.9); relative to the car (2.0, -1.9): the nearest point is
    // (2.0, -0.9): gap 1.0 - 0.3 = 0.7 < 1 -> danger = 20 (0.7 - 1) = -6
    close_v(w.agent(1).unwrap().position, [3.25, -1.9]);
    close(r.danger, -6.0);
    // first transition: no previous acceleration, jerk 0; omega 0 -> comfort 0
    assert_eq!(r.comfort, 0.0);
    assert_eq!((r.success, r.collision), (0.0, 0.0));
    close(r.total(), 1.25 - 6.0);

    // step 2, action [-0.25, 1]: acc = -0.5, omega = 0.2; speed 2.5 - 0.25 = 2.25;
    // theta = 0.1; x = (1.25, 0) + 1.125 (cos 0.1, sin 0.1)
    let out = w.step(&[(0, [-0.25, 1.0])]).unwrap();
    let r = terms(&out);
    let x = [1.25 + 1.125 * 0.1f64.cos(), 1.125 * 0.1f64.sin()];
    close_v(w.agent(0).unwrap().position, x);
    // progress = 8.75 - |(10, 0) - x|
    close(r.progress, 8.75 - (10.0 - x[0]).hypot(x[1]));
    // acc_0 = (2.5 - 2)/0.5 = 1, acc_1 = (2.25 - 2.5)/0.5 = -0.5; jerk = (-0.5 - 1)/0.5 = -3
    // comfort = -0.05 * 9 - 0.5 * 0.2^2 = -0.45 - 0.02 = -0.47
    close(r.comfort, -0.47);
    // pedestrian at (3.25, -1.8); in the car frame (heading 0.1, centre x):
    // local = R(-0.1) ((3.25, -1.8) - x); nearest point clamps to (+-2, +-0.9)
    let (s, c) = 0.1f64.sin_cos();
    let (dx, dy) = (3.25 - x[0], -1.8 - x[1]);
    let (lx, ly) = (c * dx + s * dy, -s * dx + c * dy);
    let gap = (lx - lx.clamp(-2.0, 2.0)).hypot(ly - ly.clamp(-0.9, 0.9)) - 0.3;
    assert!(gap > 0.0 && gap < 1.0);
    close(r.danger, 20.0 * (gap - 1.0));
}

#[test]
fn reward_success_on_arrival_within_two_metres() {
    // car at (0,0) with speed 4 along x, goal (3, 0): d(0) = 3
    let positions = vec![[0.0, 0.0], [3.0, 0.0]];
    let car = track(AgentKind::Vehicle, 0, positions, vec![[4.0, 0.0]; 2]);
    // action [0, 0]: speed 4, x = (2, 0), d(1) = 1 <= 2 -> success
    let (out, r) = coasting_step(vec![car], PedestrianModel::CrSfm);
    close(r.progress, 2.0); // 3 - 1
    assert_eq!(r.success, 10.0);
    assert_eq!(r.collision, 0.0);
    assert_eq!(r.danger, 0.0); // nobody around: no minimum clearance
    assert_eq!(r.comfort, 0.0);
    close(r.total(), 12.0);
    assert!(out.agents[0].terminated);
    assert!(out.events.contains(&Event::GoalReached { agent: 0 }));
}

#[test]
fn reward_collision_and_full_danger_on_overlap() {
    // car at (0,0) speed 2; a standing pedestrian (cv with zero velocity) at (3.2, 0) whose goal
    // is elsewhere (so it does not leave): after one step the car's front is at 1 + 2 = 3.0,
    // gap 3.2 - 3.0 - 0.3 = -0.1 -> clearance 0 -> collision
    let car = line(AgentKind::Vehicle, 0, [0.0, 0.0], [2.0, 0.0], 11);
    let positions = vec![[3.2, 0.0], [3.2, 5.0]];
    let standing = track(AgentKind::Pedestrian, 0, positions, vec![[0.0, 0.0]; 2]);
    let (out, r) = coasting_step(vec![car, standing], PedestrianModel::Cv);
    close(r.progress, 1.0); // 10 - 9
    assert_eq!(r.collision, -20.0);
    assert_eq!(r.danger, -20.0); // 20 (0 - 1)
    assert_eq!(r.success, 0.0);
    assert!(out.events.contains(&Event::Collision { a: 0, b: 1 }));
    assert!(out.agents[0].terminated);
}

// ---------------------------------------------------------------- metrics (model.md 7, 9)

#[test]
fn episode_metrics_from_speeds() {
    // speeds 2, 3, 5, 4 at dt 0.5: 3 transitions; avg speed (3 + 5 + 4)/3 = 4
    // acc = (1/0.5, 2/0.5, -1/0.5) = (2, 4, -2); jerk = |4 - 2|/0.5 = 4, |-2 - 4|/0.5 = 12 -> 8
    // max |acc| = 4
    let m = EpisodeMetrics::from_speeds(EpisodeStatus::Success, &[2.0, 3.0, 5.0, 4.0], 0.5);
    assert_eq!(m.steps, 3);
    assert_eq!(m.status, EpisodeStatus::Success);
    close(m.avg_speed, 4.0);
    close(m.avg_abs_jerk, 8.0);
    close(m.max_abs_acc, 4.0);
    // a single transition: avg speed 1, acc (1 - 3)/0.5 = -2 -> max |acc| 2, no jerk
    let m = EpisodeMetrics::from_speeds(EpisodeStatus::Timeout, &[3.0, 1.0], 0.5);
    assert_eq!(m.steps, 1);
    close(m.avg_speed, 1.0);
    assert_eq!(m.avg_abs_jerk, 0.0);
    close(m.max_abs_acc, 4.0);
    // no transition at all: everything 0
    let m = EpisodeMetrics::from_speeds(EpisodeStatus::Collision, &[3.0], 0.5);
    assert_eq!(
        (m.steps, m.avg_speed, m.avg_abs_jerk, m.max_abs_acc),
        (0, 0.0, 0.0, 0.0)
    );
    let m = EpisodeMetrics::from_speeds(EpisodeStatus::Collision, &[], 0.5);
    assert_eq!(m.steps, 0);
}

#[test]
fn metrics_summary_is_the_mean_over_episodes() {
    let ep = |status, avg_speed, avg_abs_jerk, max_abs_acc| EpisodeMetrics {
        status,
        avg_speed,
        avg_abs_jerk,
        max_abs_acc,
        steps: 10,
    };
    let s = MetricsSummary::of(&[
        ep(EpisodeStatus::Success, 4.0, 8.0, 4.0),
        ep(EpisodeStatus::Collision, 2.0, 1.0, 3.0),
        ep(EpisodeStatus::Timeout, 3.0, 0.0, 2.0),
        ep(EpisodeStatus::Success, 3.0, 3.0, 3.0),
    ]);
    assert_eq!(s.episodes, 4);
    close(s.success, 0.5); // 2/4
    close(s.collision, 0.25); // 1/4
    close(s.timeout, 0.25); // 1/4
    close(s.avg_speed, 3.0); // (4 + 2 + 3 + 3)/4
    close(s.avg_abs_jerk, 3.0); // (8 + 1 + 0 + 3)/4
    close(s.max_abs_acc, 3.0); // (4 + 3 + 2 + 3)/4
    assert_eq!(MetricsSummary::of(&[]), MetricsSummary::default());
}

#[test]
fn displacement_errors_ade_and_fde() {
    let p = |x: f64, y: f64| v(x, y);
    let sim = vec![
        vec![p(0.0, 0.0), p(1.0, 0.0)],
        vec![p(0.0, 0.0), p(0.0, 0.0), p(0.0, 0.0)],
    ];
    let rec = vec![
        vec![p(0.0, 0.0), p(1.0, 1.0), p(9.0, 9.0)], // longer record: only the common 2 steps count
        vec![p(3.0, 4.0), p(0.0, 1.0), p(0.0, 2.0)],
    ];
    // errors: pedestrian 0: 0, 1; pedestrian 1: 5, 1, 2 -> ADE = 9/5 = 1.8
    // FDE = (1 + 2)/2 = 1.5
    let e = displacement_errors(&sim, &rec);
    close(e.ade, 1.8);
    close(e.fde, 1.5);
    assert_eq!(displacement_errors(&[], &[]), DisplacementErrors::default());
}

#[test]
fn pedestrian_eval_summary_means_and_collision_rate() {
    let de = |ade, fde| DisplacementErrors { ade, fde };
    let s = PedestrianEvalSummary::of(&[
        (de(1.0, 2.0), true),
        (de(3.0, 4.0), false),
        (de(2.0, 6.0), false),
        (de(2.0, 0.0), false),
    ]);
    assert_eq!(s.episodes, 4);
    close(s.ade, 2.0); // (1 + 3 + 2 + 2)/4
    close(s.fde, 3.0); // (2 + 4 + 6 + 0)/4
    close(s.collision_rate, 0.25); // 1 of 4
    assert_eq!(
        PedestrianEvalSummary::of(&[]),
        PedestrianEvalSummary::default()
    );
}

#[test]
fn belief_update_count_saturates_instead_of_overflowing() {
    // after u32::MAX updates the variance is the converged one and the count stays at the maximum
    let sched = VarianceSchedule::new(&CognitionParams::default());
    let mut b = Belief {
        updates: u32::MAX,
        ..Belief::first_sight(v(1.0, 0.0))
    };
    // observation equal to the mean: u = 0.5 [2 s_p^2/0.25 - 2 + 2 ln(0.25/s_p^2)] at the
    // steady prior s_p^2 = fixed + 0.09
    let sp = (-0.09 + 0.0981f64.sqrt()) / 2.0 + 0.09;
    let u = b.update(
        b.predict(PredictionModel::ConstantVelocity, Vec2::zeros()),
        v(1.0, 0.0),
        &sched,
    );
    close(u, kl_by_hand(sp, 0.0));
    assert_eq!(b.updates, u32::MAX);
}

#[test]
fn folded_risk_equals_the_virtual_distance_composition() {
    // risk_with folds d_v = d (1 + tanh z) and psi = 1 / (1 + gamma2 d_v) into
    // psi = (1 + e) / (1 + e + 2 gamma2 d), e = exp(-2z); both must agree to rounding.
    let params = sim_core::params::RiskParams::default();
    for (x_j, v_j, acc, d) in [
        (v(5.0, 0.0), v(-1.0, 0.0), 0.4, 4.4),
        (v(5.0, 0.0), v(1.0, 0.0), 0.0, 4.4),
        (v(0.0, 3.0), v(0.3, -2.0), 1.5, 2.1),
        (v(0.0, 3.0), v(0.0, 0.0), 0.0, 0.0),
        (v(1.0, 1.0), v(-300.0, -300.0), 50.0, 0.7),
    ] {
        let x_i = v(0.0, 0.0);
        let to_i = x_i - x_j;
        let unfolded = physical_risk(
            virtual_distance(d, x_i, x_j, v_j, acc, params.gamma1),
            params.gamma2,
        );
        let folded = sim_core::model::risk::risk_with(d, to_i, to_i.norm(), v_j, acc, &params);
        assert!((folded - unfolded).abs() <= 1e-14, "{folded} vs {unfolded}");
    }
}
