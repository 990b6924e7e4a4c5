//! Cognitive uncertainty: the predict–observe–update loop of paper Algorithm 1 (model.md 3).
//!
//! Each observer keeps an isotropic Gaussian belief `N(mu, s2 I)` over each perceived agent's
//! velocity. The variance sequence depends only on how many updates a belief has had, so it is
//! tabulated once per parameter set ([`VarianceSchedule`]); the per-pair work is then a few
//! multiply-adds with no logarithm.

use crate::geometry::Vec2;
use crate::params::{CognitionParams, PredictionModel};

/// Number of dimensions of the velocity belief.
pub const DIM: f64 = 2.0;

/// `KL(N(mu_p, s2_p I_k) || N(mu_o, s2_o I_k))` for isotropic `k`-dimensional Gaussians:
/// `0.5 * [k s2_p/s2_o + |mu_o - mu_p|^2/s2_o - k + k ln(s2_o/s2_p)]`.
pub fn kl_isotropic(mu_p: Vec2, s2_p: f64, mu_o: Vec2, s2_o: f64, k: f64) -> f64 {
    0.5 * (k * s2_p / s2_o + (mu_o - mu_p).norm_squared() / s2_o - k + k * (s2_o / s2_p).ln())
}

/// Bayesian fusion of the prior `N(mu_p, s2_p)` with the observation `N(mu_o, s2_o)`:
/// `1/s2_post = 1/s2_p + 1/s2_o`, `mu_post = s2_post (mu_p/s2_p + mu_o/s2_o)`.
pub fn posterior(mu_p: Vec2, s2_p: f64, mu_o: Vec2, s2_o: f64) -> (Vec2, f64) {
    let s2_post = 1.0 / (1.0 / s2_p + 1.0 / s2_o);
    (s2_post * (mu_p / s2_p + mu_o / s2_o), s2_post)
}

/// The variances a belief goes through, indexed by the number of updates it has had.
///
/// `post[0] = s0^2`; update `n >= 1` has prior variance `prior[n] = post[n-1] + q^2` and posterior
/// `post[n]`. The sequence converges; once a value repeats bit for bit the table stops and later
/// updates reuse its last entry, which is exactly what the recurrence would give.
#[derive(Debug, Clone, PartialEq)]
pub struct VarianceSchedule {
    /// Prior variance of update `n` (index 0 unused).
    prior: Vec<f64>,
    /// Posterior variance after `n` updates.
    post: Vec<f64>,
    /// The constants of update `n` (one record: one lookup per update).
    update: Vec<UpdateConsts>,
    /// `0.5 / s2_o`: the KL's factor on the squared mean difference.
    half_inv_s2o: f64,
}

/// What update `n` needs besides the means ([`VarianceSchedule::update_consts`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpdateConsts {
    /// The part of the KL that does not depend on the means.
    pub kl_const: f64,
    /// `s2_post / s2_p` and `s2_post / s2_o`: the weights of the posterior mean.
    pub w_prior: f64,
    pub w_obs: f64,
}

impl UpdateConsts {
    /// The update proper (model.md 3): from the prediction `mu_p` and the observation `v_obs`,
    /// the posterior mean `(s2_post / s2_p) mu_p + (s2_post / s2_o) v_obs` and the uncertainty
    /// `u = KL(N(mu_p, s2_p I) || N(v_obs, s2_o I))`, whose mean term is
    /// `half_inv_s2o |v_obs - mu_p|^2` ([`VarianceSchedule::half_inv_s2o`]).
    #[inline(always)]
    pub fn apply(&self, mu_p: Vec2, v_obs: Vec2, half_inv_s2o: f64) -> (Vec2, f64) {
        let diff = v_obs - mu_p;
        let u = self.kl_const + half_inv_s2o * diff.norm_squared();
        (mu_p * self.w_prior + v_obs * self.w_obs, u)
    }
}

/// Bound on the tabulated length; the recurrence converges long before it for any sane parameters.
const MAX_SCHEDULE: usize = 4096;

impl VarianceSchedule {
    pub fn new(p: &CognitionParams) -> Self {
        let s2_o = p.s_o * p.s_o;
        let q2 = p.q * p.q;
        let mut s = Self {
            prior: vec![f64::NAN],
            post: vec![p.s0 * p.s0],
            update: vec![UpdateConsts {
                kl_const: 0.0,
                w_prior: 0.0,
                w_obs: 0.0,
            }],
            half_inv_s2o: 0.5 / s2_o,
        };
        loop {
            let last = *s.post.last().expect("never empty");
            let s2_p = last + q2;
            let s2_post = 1.0 / (1.0 / s2_p + 1.0 / s2_o);
            s.prior.push(s2_p);
            s.post.push(s2_post);
            let c = UpdateConsts {
                kl_const: kl_isotropic(Vec2::zeros(), s2_p, Vec2::zeros(), s2_o, DIM),
                w_prior: s2_post / s2_p,
                w_obs: s2_post / s2_o,
            };
            s.update.push(c);
            if s2_post == last || s.post.len() >= MAX_SCHEDULE {
                break;
            }
        }
        s
    }

    /// Number of tabulated entries (update numbers at or past `len - 1` share the last).
    pub fn len(&self) -> usize {
        self.post.len()
    }

    /// Never: the table holds at least the first sight's entry.
    pub fn is_empty(&self) -> bool {
        false
    }

    fn index(&self, updates: u32) -> usize {
        (updates as usize).min(self.post.len() - 1)
    }

    /// The constants of update number `updates` (>= 1; numbers past the table share its last
    /// entry).
    #[inline(always)]
    pub fn update_consts(&self, updates: u32) -> UpdateConsts {
        self.update[self.index(updates)]
    }

    /// `0.5 / s_o^2`: the KL's factor on the squared mean difference.
    #[inline(always)]
    pub fn half_inv_s2o(&self) -> f64 {
        self.half_inv_s2o
    }

    /// Posterior variance after `updates` updates.
    pub fn posterior_variance(&self, updates: u32) -> f64 {
        self.post[self.index(updates)]
    }

    /// Prior variance used by update number `updates` (>= 1).
    pub fn prior_variance(&self, updates: u32) -> f64 {
        self.prior[self.index(updates.max(1))]
    }
}

/// One observer's belief about one other agent's velocity.
///
/// The belief holds only what is the observer's own; what was observed of the target (its last
/// change of velocity, for the constant-acceleration prediction) is the target's history, the
/// same for every observer, and is passed in by the caller.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Belief {
    /// Posterior mean, m/s.
    pub mu: Vec2,
    /// Number of updates since first sight (the variance is `schedule.posterior_variance(updates)`).
    pub updates: u32,
}

impl Belief {
    /// First sight (or re-entry into range): `mu = v`, `s2 = s0^2`, and `u = 0`.
    pub fn first_sight(v: Vec2) -> Self {
        Self { mu: v, updates: 0 }
    }

    /// The internal model's prediction `v_hat` of the target's velocity. `last_change` is the
    /// target's observed change of velocity over the previous step, `v(t-1) - v(t-2)`; it is only
    /// known once the belief has had an update (before that the prediction is `mu`).
    #[inline]
    pub fn predict(&self, model: PredictionModel, last_change: Vec2) -> Vec2 {
        match model {
            PredictionModel::ConstantAcceleration if self.updates > 0 => self.mu + last_change,
            _ => self.mu,
        }
    }

    /// One observe–update cycle: prior `N(mu_p, s_p^2)` with `mu_p` the prediction, observation
    /// `N(v_obs, s_o^2)`; returns the uncertainty `u_t = KL(prior || observation)` and stores the
    /// posterior.
    #[inline]
    pub fn update(&mut self, mu_p: Vec2, v_obs: Vec2, s: &VarianceSchedule) -> f64 {
        let c = s.update_consts(self.updates.saturating_add(1));
        let (mu, u) = c.apply(mu_p, v_obs, s.half_inv_s2o);
        self.mu = mu;
        self.updates = self.updates.saturating_add(1);
        u
    }
}
