//! Seeded scene variations (docs/MODEL.md section 10): a recorded scene played with each
//! pedestrian moved, shifted in time and given another desired speed, the crowd's social-force
//! parameters perturbed, and the whole scene mirrored about the ego's initial heading or rotated
//! about its initial position.
//!
//! A variation is an exact function of (scene, [`VariationSpec`], seed): [`VariationSpec::draw`]
//! turns a seed into the values applied ([`Variation`], which a server reports with the reset),
//! and [`Variation::apply`] / [`Variation::apply_params`] turn those values into the scene and
//! parameters a world starts from. The spec with every field at its default is the identity:
//! the varied scene is the recorded one, to the bit.
//!
//! What is varied and what is not:
//! - per pedestrian (every pedestrian of the record, replayed or simulated): its whole track is
//!   offset by `(dx, dy) ~ N(0, position_sigma^2)` per axis; its first step moves by an integer
//!   uniform in `[-start_offset_steps, +start_offset_steps]` (a track that would start before
//!   step 0 starts at step 0 with its earlier samples dropped); its desired speed is scaled by a
//!   factor uniform in `[1 - desired_speed_scale, 1 + desired_speed_scale]`;
//! - per episode: each social-force parameter named in `param_noise` (of every model) is scaled
//!   by a factor uniform in `[1 - r, 1 + r]`, one factor for the whole crowd (sim-core's model
//!   parameters are per world, not per agent);
//! - the whole scene (vehicles too): mirrored with probability 1/2 when `mirror` is set, then
//!   rotated by an angle uniform in `[-rotation_deg, rotation_deg]`, both about the ego's first
//!   recorded position and heading, so that ego-frame observations change only by the mirror.
//!
//! The vehicles' records are never perturbed otherwise. A pedestrian whose draw would overlap
//! another agent where the two first meet (the later of their first steps, on their records)
//! is drawn again from its own stream, up to [`REDRAWS`] times; if every draw overlaps it keeps
//! its recorded track. So no episode starts with two agents in contact.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::geometry::{clearance, Placed, Shape, Vec2};
use crate::params::{SocialForceParams, WorldParams};
use crate::scenario::{AgentKind, AgentRecord, Scenario};
use crate::support::rng::{derive_seed, SplitMix64};

/// Largest accepted `position_sigma`, m.
pub const MAX_POSITION_SIGMA: f64 = 10.0;
/// Largest accepted `start_offset_steps`.
pub const MAX_START_OFFSET_STEPS: u32 = 20;
/// Draws a pedestrian gets after its first one overlapped.
pub const REDRAWS: u32 = 32;
/// Clearance (m) a moved pedestrian keeps from a vehicle where they first meet: a margin over
/// contact, so that a footprint whose heading another tool computes a little differently
/// (scenarios/src/footprint.rs) does not touch either.
pub const VEHICLE_MARGIN: f64 = 0.05;

/// How scenes vary from episode to episode (`CreateEnv.variations`, a pool entry's
/// `variations`). Every field defaults to "no variation".
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VariationSpec {
    /// Standard deviation of each pedestrian's position offset, per axis, m. Default 0;
    /// at most [`MAX_POSITION_SIGMA`].
    pub position_sigma: f64,
    /// Each pedestrian's first step moves by up to this many steps either way. Default 0; at
    /// most [`MAX_START_OFFSET_STEPS`].
    pub start_offset_steps: u32,
    /// Half-width `s` of each pedestrian's desired-speed factor, uniform in `[1 - s, 1 + s]`.
    /// Default 0; in `[0, 1)`.
    pub desired_speed_scale: f64,
    /// Per social-force parameter (`tau`, `a_ped`, `b_ped`, `a_veh`, `b_veh`, `lambda1`,
    /// `lambda2`, `lambda3`), the half-width `r` of its factor, uniform in `[1 - r, 1 + r]`,
    /// drawn once per episode. Default none; each `r` in `[0, 1)`.
    pub param_noise: BTreeMap<String, f64>,
    /// Mirror the scene about the line through the ego's first position along its first
    /// heading, in half of the episodes. Default false.
    pub mirror: bool,
    /// Rotate the scene about the ego's first position by an angle uniform in
    /// `[-rotation_deg, rotation_deg]`, degrees. Default 0; in `[0, 180]`.
    pub rotation_deg: f64,
}

/// A refused [`VariationSpec`] value, named by its field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("variations.{field} = {value}: {reason}")]
pub struct VariationError {
    /// The field (`param_noise.<name>` for a parameter's noise).
    pub field: String,
    pub value: String,
    pub reason: String,
}

/// What one draw changed for one pedestrian.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PedestrianVariation {
    /// The pedestrian's agent id (its index in the scenario).
    pub agent: u32,
    /// Offset of the whole track, m, before the scene's mirror and rotation.
    pub offset: [f64; 2],
    /// Steps its first step moved by (negative: earlier).
    pub start_shift: i32,
    /// Factor on its desired speed.
    pub speed_scale: f64,
    /// Draws refused for overlap before this one; [`REDRAWS`] + 1 means every draw overlapped
    /// and the pedestrian keeps its record.
    pub redraws: u32,
}

/// The values one seed drew: with the scene and the world's parameters, everything needed to
/// replay the episode (`Reset.variation` = `seed`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variation {
    pub seed: u64,
    /// Whether the scene is mirrored about the ego's first heading.
    pub mirrored: bool,
    /// Rotation of the scene about the ego's first position, degrees (after the mirror).
    pub rotation_deg: f64,
    /// Factor on each named social-force parameter.
    pub param_scales: BTreeMap<String, f64>,
    /// One entry per pedestrian, in agent order.
    pub pedestrians: Vec<PedestrianVariation>,
}

impl VariationSpec {
    /// The benchmark's variations (docs/RESULTS.md, the powered test): pedestrians moved by
    /// N(0, 0.25 m) per axis, started up to one step earlier or later, desired speeds within
    /// ±10 %; no parameter noise, no mirror, no rotation.
    pub fn benchmark() -> Self {
        Self {
            position_sigma: 0.25,
            start_offset_steps: 1,
            desired_speed_scale: 0.1,
            ..Self::default()
        }
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), VariationError> {
        let bad = |field: &str, value: String, reason: &str| {
            Err(VariationError {
                field: field.to_string(),
                value,
                reason: reason.to_string(),
            })
        };
        let s = self.position_sigma;
        if !(s.is_finite() && (0.0..=MAX_POSITION_SIGMA).contains(&s)) {
            return bad(
                "position_sigma",
                s.to_string(),
                &format!("must be finite, in [0, {MAX_POSITION_SIGMA}] m"),
            );
        }
        if self.start_offset_steps > MAX_START_OFFSET_STEPS {
            return bad(
                "start_offset_steps",
                self.start_offset_steps.to_string(),
                &format!("must be at most {MAX_START_OFFSET_STEPS}"),
            );
        }
        let d = self.desired_speed_scale;
        if !(d.is_finite() && (0.0..1.0).contains(&d)) {
            return bad(
                "desired_speed_scale",
                d.to_string(),
                "must be finite, in [0, 1)",
            );
        }
        for (name, &r) in &self.param_noise {
            if !SocialForceParams::NAMES.contains(&name.as_str()) {
                return bad(
                    &format!("param_noise.{name}"),
                    r.to_string(),
                    &format!(
                        "unknown social-force parameter; known: {}",
                        SocialForceParams::NAMES.join(", ")
                    ),
                );
            }
            if !(r.is_finite() && (0.0..1.0).contains(&r)) {
                return bad(
                    &format!("param_noise.{name}"),
                    r.to_string(),
                    "must be finite, in [0, 1)",
                );
            }
        }
        let a = self.rotation_deg;
        if !(a.is_finite() && (0.0..=180.0).contains(&a)) {
            return bad(
                "rotation_deg",
                a.to_string(),
                "must be finite, in [0, 180] degrees",
            );
        }
        Ok(())
    }

    /// The values `seed` draws for `scenario` in a world with `params` (whose pedestrian
    /// radius and vehicle shape decide overlaps). The spec must be valid.
    pub fn draw(&self, scenario: &Scenario, params: &WorldParams, seed: u64) -> Variation {
        let mut rng = SplitMix64::new(seed);
        // Every draw is consumed whatever the spec says, so that a seed's other values do not
        // depend on which variations are switched on.
        let (u_mirror, u_rotation) = (rng.next_f64(), rng.next_f64());
        let mirrored = self.mirror && u_mirror < 0.5;
        let rotation_deg = self.rotation_deg * (2.0 * u_rotation - 1.0);
        let param_scales = self
            .param_noise
            .iter()
            .map(|(name, &r)| (name.clone(), 1.0 + r * (2.0 * rng.next_f64() - 1.0)))
            .collect();
        let shapes = Shapes::of(params);
        let mut placed: Vec<AgentRecord> = scenario.agents.clone();
        let mut pedestrians = Vec::new();
        for (k, rec) in scenario.agents.iter().enumerate() {
            if rec.kind != AgentKind::Pedestrian {
                continue;
            }
            // Each pedestrian draws from its own stream: its values do not depend on how
            // often the others were drawn again.
            let mut own = SplitMix64::new(derive_seed(seed, k as u64 + 1));
            let mut chosen = None;
            for redraws in 0..=REDRAWS {
                let (zx, zy) = own.normal_pair();
                let shift = own.symmetric_int(self.start_offset_steps);
                let u_speed = own.next_f64();
                let v = PedestrianVariation {
                    agent: k as u32,
                    offset: [self.position_sigma * zx, self.position_sigma * zy],
                    start_shift: shift,
                    speed_scale: 1.0 + self.desired_speed_scale * (2.0 * u_speed - 1.0),
                    redraws,
                };
                let candidate = v.apply(rec);
                if !shapes.overlaps_any(&candidate, k, &placed) {
                    chosen = Some((v, candidate));
                    break;
                }
            }
            let (v, candidate) = chosen.unwrap_or_else(|| {
                let keep = PedestrianVariation {
                    agent: k as u32,
                    offset: [0.0, 0.0],
                    start_shift: 0,
                    speed_scale: 1.0,
                    redraws: REDRAWS + 1,
                };
                (keep, rec.clone())
            });
            placed[k] = candidate;
            pedestrians.push(v);
        }
        Variation {
            seed,
            mirrored,
            rotation_deg,
            param_scales,
            pedestrians,
        }
    }
}

impl PedestrianVariation {
    /// `rec` with this pedestrian's offset, time shift and desired speed.
    pub fn apply(&self, rec: &AgentRecord) -> AgentRecord {
        let mut out = rec.clone();
        let start = i64::from(rec.start_step) + i64::from(self.start_shift);
        if start < 0 {
            let drop = ((-start) as usize).min(rec.positions.len() - 1);
            out.positions.drain(..drop);
            out.velocities.drain(..drop);
            out.start_step = 0;
        } else {
            out.start_step = start as u32;
        }
        for p in &mut out.positions {
            p[0] += self.offset[0];
            p[1] += self.offset[1];
        }
        out.desired_speed = Some(rec.desired_speed() * self.speed_scale);
        out
    }
}

impl Variation {
    /// The scene this variation plays: `scenario` with every pedestrian's values, then the
    /// mirror and the rotation.
    pub fn apply(&self, scenario: &Scenario) -> Scenario {
        let mut out = scenario.clone();
        for v in &self.pedestrians {
            let k = v.agent as usize;
            out.agents[k] = v.apply(&scenario.agents[k]);
        }
        if self.mirrored || self.rotation_deg != 0.0 {
            let ego = &scenario.agents[scenario.ego];
            let centre = Vec2::new(ego.positions[0][0], ego.positions[0][1]);
            let m = self.linear_map(ego.heading_at(0));
            for a in &mut out.agents {
                for p in &mut a.positions {
                    let d = m * (Vec2::new(p[0], p[1]) - centre) + centre;
                    *p = [d.x, d.y];
                }
                for v in &mut a.velocities {
                    let d = m * Vec2::new(v[0], v[1]);
                    *v = [d.x, d.y];
                }
            }
        }
        out
    }

    /// `params` with the drawn factors on the social-force parameters of every model.
    pub fn apply_params(&self, params: &WorldParams) -> WorldParams {
        let mut out = *params;
        for set in out.pedestrians.social_force_sets_mut() {
            for (name, &scale) in &self.param_scales {
                if let Some(x) = set.get_mut(name) {
                    *x *= scale;
                }
            }
        }
        out
    }

    /// The mirror (about the line at angle `heading`), then the rotation, as one matrix.
    fn linear_map(&self, heading: f64) -> nalgebra::Matrix2<f64> {
        let mirror = if self.mirrored {
            let (s, c) = (2.0 * heading).sin_cos();
            nalgebra::Matrix2::new(c, s, s, -c)
        } else {
            nalgebra::Matrix2::identity()
        };
        let (s, c) = self.rotation_deg.to_radians().sin_cos();
        nalgebra::Matrix2::new(c, -s, s, c) * mirror
    }
}

/// The footprints a world with these parameters gives its agents.
struct Shapes {
    pedestrian: Shape,
    vehicle: Shape,
}

impl Shapes {
    fn of(params: &WorldParams) -> Self {
        Self {
            pedestrian: Shape::Disc {
                radius: params.ped_radius,
            },
            vehicle: params.vehicle.shape,
        }
    }

    fn placed(&self, rec: &AgentRecord, step: u32) -> Option<Placed> {
        let k = step.checked_sub(rec.start_step)? as usize;
        let p = rec.positions.get(k)?;
        let shape = match rec.kind {
            AgentKind::Pedestrian => self.pedestrian,
            AgentKind::Vehicle => self.vehicle,
        };
        Some(Placed {
            shape,
            position: Vec2::new(p[0], p[1]),
            heading: rec.heading_at(k),
        })
    }

    /// Whether `candidate` (agent `k`) touches any other of `agents` at the later of their two
    /// first steps (with [`VEHICLE_MARGIN`] towards vehicles).
    fn overlaps_any(&self, candidate: &AgentRecord, k: usize, agents: &[AgentRecord]) -> bool {
        agents.iter().enumerate().any(|(j, other)| {
            if j == k {
                return false;
            }
            let step = candidate.start_step.max(other.start_step);
            let (Some(a), Some(b)) = (self.placed(candidate, step), self.placed(other, step))
            else {
                return false;
            };
            let margin = match other.kind {
                AgentKind::Vehicle => VEHICLE_MARGIN,
                AgentKind::Pedestrian => 0.0,
            };
            let c = clearance(&a, &b);
            !(c.is_finite() && c > margin)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn walker(start: u32, p0: [f64; 2], n: usize) -> AgentRecord {
        AgentRecord {
            record_id: 0,
            kind: AgentKind::Pedestrian,
            start_step: start,
            positions: (0..n).map(|i| [p0[0] + 0.5 * i as f64, p0[1]]).collect(),
            velocities: vec![[1.0, 0.0]; n],
            non_reactive: false,
            desired_speed: None,
        }
    }

    #[test]
    fn a_track_shifted_before_step_zero_drops_its_first_samples() {
        let rec = walker(0, [0.0, 0.0], 5);
        let v = PedestrianVariation {
            agent: 0,
            offset: [0.0, 0.0],
            start_shift: -2,
            speed_scale: 1.0,
            redraws: 0,
        };
        let out = v.apply(&rec);
        assert_eq!(out.start_step, 0);
        assert_eq!(out.positions, rec.positions[2..]);
        assert_eq!(out.end_step(), 2);
    }

    #[test]
    fn a_later_start_keeps_the_whole_track() {
        let rec = walker(3, [0.0, 0.0], 5);
        let v = PedestrianVariation {
            agent: 0,
            offset: [1.0, -1.0],
            start_shift: 1,
            speed_scale: 1.1,
            redraws: 0,
        };
        let out = v.apply(&rec);
        assert_eq!(out.start_step, 4);
        assert_eq!(out.positions[0], [1.0, -1.0]);
        assert!((out.desired_speed() - 1.1 * rec.mean_speed()).abs() < 1e-15);
    }

    #[test]
    fn every_refused_value_names_its_field() {
        let cases: [(VariationSpec, &str); 8] = [
            (
                VariationSpec {
                    position_sigma: -0.1,
                    ..Default::default()
                },
                "position_sigma",
            ),
            (
                VariationSpec {
                    position_sigma: f64::NAN,
                    ..Default::default()
                },
                "position_sigma",
            ),
            (
                VariationSpec {
                    start_offset_steps: MAX_START_OFFSET_STEPS + 1,
                    ..Default::default()
                },
                "start_offset_steps",
            ),
            (
                VariationSpec {
                    desired_speed_scale: 1.0,
                    ..Default::default()
                },
                "desired_speed_scale",
            ),
            (
                VariationSpec {
                    param_noise: [("a_pedd".to_string(), 0.1)].into(),
                    ..Default::default()
                },
                "param_noise.a_pedd",
            ),
            (
                VariationSpec {
                    param_noise: [("tau".to_string(), f64::INFINITY)].into(),
                    ..Default::default()
                },
                "param_noise.tau",
            ),
            (
                VariationSpec {
                    rotation_deg: 181.0,
                    ..Default::default()
                },
                "rotation_deg",
            ),
            (
                VariationSpec {
                    rotation_deg: -1.0,
                    ..Default::default()
                },
                "rotation_deg",
            ),
        ];
        for (spec, field) in cases {
            let e = spec.validate().unwrap_err();
            assert_eq!(e.field, field);
            assert!(e.to_string().starts_with(&format!("variations.{field} = ")));
        }
        assert!(VariationSpec::default().validate().is_ok());
    }
}
