//! The reactive vehicle model's equations (docs/MODEL.md, "Traffic"): a car nobody controls
//! follows the path of its record and controls only its speed along it.
//!
//! - [`RecordedPath`]: the record's positions as a polyline parameterised by arc length `s`, the
//!   pose at any `s`, and the record's own schedule `s_rec(k)` (where the record was at sample
//!   `k`);
//! - [`idm_acceleration`]: the intelligent driver model (Treiber, Hennecke & Helbing, *Phys. Rev.
//!   E* 62, 1805, 2000), the car's longitudinal law towards the nearest agent in its corridor;
//! - [`advance`]: how far the car moves in one step, from the IDM, its record's schedule and the
//!   free room ahead.
//!
//! The corridor scan that finds the leader and the free room needs the other agents' footprints
//! and lives with the world's stages (`world/reactive_vehicles.rs`).

use crate::geometry::Vec2;
use crate::params::TrafficParams;
use crate::scenario::AgentRecord;

/// IDM acceleration, m/s²:
///
/// `a_idm = a [1 - (v / v0)^delta - (s* / gap)^2]`,
/// `s* = s0 + max(0, v T + v dv / (2 sqrt(a b)))`,
///
/// with `v` the car's speed, `v0` its desired speed, `gap` the free distance to the leader along
/// the path (`f64::INFINITY` without a leader: the free-road term alone) and `dv = v - v_leader`
/// the approach rate. `a` is `traffic.acc` capped by `acc_max` (the AV's limit), and the result
/// is clamped to `[-acc_max, a]`: the car brakes no harder than the AV may. A gap of 0 or less
/// asks for the hardest braking.
pub fn idm_acceleration(
    v: f64,
    v0: f64,
    gap: f64,
    dv: f64,
    p: &TrafficParams,
    acc_max: f64,
) -> f64 {
    let a = p.acc.min(acc_max);
    let free = 1.0 - (v / v0.max(MIN_DESIRED_SPEED)).powf(p.exponent);
    let interaction = if gap.is_finite() {
        if gap <= 0.0 {
            return -acc_max;
        }
        let s_star = p.min_gap
            + (v * p.time_headway + v * dv / (2.0 * (a * p.comfortable_decel).sqrt())).max(0.0);
        (s_star / gap).powi(2)
    } else {
        0.0
    };
    (a * (free - interaction)).clamp(-acc_max, a)
}

/// The smallest desired speed the IDM divides by, m/s (a record that never moves still has one).
pub const MIN_DESIRED_SPEED: f64 = 0.5;

/// What limits one step's advance of a reactive car ([`advance`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdvanceInputs {
    /// Speed at `t`, m/s.
    pub speed: f64,
    /// Desired speed, m/s ([`RecordedPath::desired_speed`]).
    pub desired_speed: f64,
    /// The nearest agent in the corridor: free distance along the path to it, m, and its speed
    /// along the path, m/s. `None`: the road is free as far as the corridor reaches.
    pub leader: Option<(f64, f64)>,
    /// How far the record is ahead of the car at `t + 1`, m (`s_rec(k + 1) - s`, at least 0).
    pub behind_schedule: f64,
    /// How far the record itself moves from `k` to `k + 1`, m (0 past its end).
    pub record_step: f64,
    /// The farthest the car can move before its footprint would touch another agent, m.
    pub free_room: f64,
}

/// How far a reactive car moves along its path in one step, m (never negative: it never
/// reverses):
///
/// `d = min(s_rec(k + 1) - s, room, leader ? v' dt : max(v' dt, s_rec(k + 1) - s_rec(k)))`,
/// `v' = max(0, v + a_idm dt)`.
///
/// On a free road the car keeps to its record: on schedule it moves exactly as the record does,
/// behind schedule it catches up under the IDM's free-road law (never faster than the record
/// itself moves at that time, or its desired speed), and it never runs ahead of the record. With
/// an agent in its corridor the IDM decides, and `room` is the last word: the car never drives
/// into a footprint, even when that takes harder braking than the IDM's limit (docs/MODEL.md).
pub fn advance(x: &AdvanceInputs, p: &TrafficParams, acc_max: f64, dt: f64) -> f64 {
    let (gap, dv) = match x.leader {
        Some((gap, leader_speed)) => (gap, x.speed - leader_speed),
        None => (f64::INFINITY, 0.0),
    };
    let acc = idm_acceleration(x.speed, x.desired_speed, gap, dv, p, acc_max);
    let idm_step = (x.speed + acc * dt).max(0.0) * dt;
    let wanted = if x.leader.is_some() {
        idm_step
    } else {
        idm_step.max(x.record_step)
    };
    wanted.min(x.behind_schedule).min(x.free_room).max(0.0)
}

/// A record's positions as a polyline parameterised by arc length.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedPath {
    /// `cumulative[k]`: arc length from the first sample to sample `k`, m (non-decreasing).
    cumulative: Vec<f64>,
    /// Desired speed, m/s: the record's `desired_speed` if set, else the 85th percentile of its
    /// recorded speeds (traffic engineering's free-flow speed), at least [`MIN_DESIRED_SPEED`].
    pub desired_speed: f64,
}

impl RecordedPath {
    pub fn new(rec: &AgentRecord) -> Self {
        let mut cumulative = Vec::with_capacity(rec.positions.len());
        let mut total = 0.0;
        for (k, p) in rec.positions.iter().enumerate() {
            if k > 0 {
                let q = rec.positions[k - 1];
                total += (p[0] - q[0]).hypot(p[1] - q[1]);
            }
            cumulative.push(total);
        }
        let desired_speed = rec
            .desired_speed
            .unwrap_or_else(|| percentile_speed(rec, 0.85))
            .max(MIN_DESIRED_SPEED);
        Self {
            cumulative,
            desired_speed,
        }
    }

    /// Length of the whole path, m.
    pub fn length(&self) -> f64 {
        *self.cumulative.last().expect("records are never empty")
    }

    /// Where the record was at sample `k` (clamped to its last sample), m along the path.
    pub fn scheduled(&self, k: usize) -> f64 {
        self.cumulative[k.min(self.cumulative.len() - 1)]
    }

    /// Position and heading at arc length `s` (clamped to the path): at a recorded sample, that
    /// sample's position and [`AgentRecord::heading_at`] (so a car on schedule is exactly where its
    /// record is); between samples, on the segment and along it.
    pub fn pose(&self, rec: &AgentRecord, s: f64) -> (Vec2, f64) {
        let n = self.cumulative.len();
        let s = s.clamp(0.0, self.length());
        // The last sample at or before `s`.
        let k = self
            .cumulative
            .partition_point(|&c| c <= s)
            .saturating_sub(1);
        let p = rec.positions[k];
        let start = Vec2::new(p[0], p[1]);
        if k + 1 >= n || s == self.cumulative[k] {
            return (start, rec.heading_at(k));
        }
        let q = rec.positions[k + 1];
        let seg = Vec2::new(q[0], q[1]) - start;
        let len = self.cumulative[k + 1] - self.cumulative[k];
        let t = (s - self.cumulative[k]) / len; // len > 0: cumulative[k] <= s < cumulative[k + 1]
        (
            start + seg * t,
            crate::support::fastmath::atan2(seg.y, seg.x),
        )
    }
}

/// The `q`-quantile of a record's speeds (nearest rank), m/s.
fn percentile_speed(rec: &AgentRecord, q: f64) -> f64 {
    let mut speeds: Vec<f64> = rec.velocities.iter().map(|v| v[0].hypot(v[1])).collect();
    speeds.sort_by(f64::total_cmp);
    let rank = ((q * speeds.len() as f64).ceil() as usize).clamp(1, speeds.len());
    speeds[rank - 1]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::AgentKind;

    fn p() -> TrafficParams {
        TrafficParams::default()
    }

    /// The IDM against a hand-computed case: v = 4, v0 = 8, gap = 10, dv = 2 (closing), city
    /// parameters a = 1, b = 1.5, T = 1, s0 = 2, delta = 4:
    /// s* = 2 + 4 * 1 + 4 * 2 / (2 sqrt(1.5)) = 6 + 3.265986 = 9.265986;
    /// a = 1 - (0.5)^4 - (0.9265986)^2 = 1 - 0.0625 - 0.858585 = 0.078915.
    #[test]
    fn idm_matches_a_hand_computed_case() {
        let a = idm_acceleration(4.0, 8.0, 10.0, 2.0, &p(), 2.0);
        let s_star = 6.0 + 8.0 / (2.0 * 1.5f64.sqrt());
        let want = 1.0 - 0.0625 - (s_star / 10.0).powi(2);
        assert!((a - want).abs() < 1e-12, "{a} vs {want}");
        assert!((a - 0.078915).abs() < 1e-5);
    }

    #[test]
    fn bad_traffic_parameters_are_refused_by_name() {
        for (field, bad) in [
            ("traffic.acc", 0.0),
            ("traffic.min_gap", -1.0),
            ("traffic.lookahead_max", f64::NAN),
        ] {
            let mut params = crate::params::WorldParams::default();
            let t = &mut params.traffic;
            *match field {
                "traffic.acc" => &mut t.acc,
                "traffic.min_gap" => &mut t.min_gap,
                _ => &mut t.lookahead_max,
            } = bad;
            let err = params.validate().unwrap_err();
            assert_eq!(err.name, field, "{err}");
        }
    }

    #[test]
    fn idm_free_road_accelerates_to_the_desired_speed_and_no_further() {
        assert_eq!(
            idm_acceleration(0.0, 5.0, f64::INFINITY, 0.0, &p(), 2.0),
            1.0
        );
        assert_eq!(
            idm_acceleration(5.0, 5.0, f64::INFINITY, 0.0, &p(), 2.0),
            0.0
        );
        assert!(idm_acceleration(6.0, 5.0, f64::INFINITY, 0.0, &p(), 2.0) < 0.0);
    }

    #[test]
    fn idm_brakes_no_harder_than_the_av_limit() {
        assert_eq!(idm_acceleration(6.0, 6.0, 0.5, 6.0, &p(), 2.0), -2.0);
        assert_eq!(idm_acceleration(6.0, 6.0, 0.0, 0.0, &p(), 2.0), -2.0);
        // The IDM's maximum acceleration is capped by the AV's.
        assert_eq!(
            idm_acceleration(0.0, 6.0, f64::INFINITY, 0.0, &p(), 0.5),
            0.5
        );
    }

    fn inputs() -> AdvanceInputs {
        AdvanceInputs {
            speed: 3.0,
            desired_speed: 3.0,
            leader: None,
            behind_schedule: 1.5,
            record_step: 1.5,
            free_room: f64::INFINITY,
        }
    }

    #[test]
    fn on_a_free_road_on_schedule_the_car_moves_as_its_record() {
        assert_eq!(advance(&inputs(), &p(), 2.0, 0.5), 1.5);
        // A record that accelerates harder than the IDM would: still the record's step.
        let x = AdvanceInputs {
            speed: 0.0,
            behind_schedule: 1.0,
            record_step: 1.0,
            ..inputs()
        };
        assert_eq!(advance(&x, &p(), 2.0, 0.5), 1.0);
    }

    #[test]
    fn behind_schedule_the_car_catches_up_under_the_free_road_law_and_never_overtakes_its_record() {
        let x = AdvanceInputs {
            speed: 0.0,
            behind_schedule: 20.0,
            record_step: 0.0,
            ..inputs()
        };
        // v' = 0 + 1.0 * 0.5 = 0.5 m/s: 0.25 m.
        assert_eq!(advance(&x, &p(), 2.0, 0.5), 0.25);
        let y = AdvanceInputs {
            speed: 3.0,
            behind_schedule: 0.1,
            ..x
        };
        assert_eq!(advance(&y, &p(), 2.0, 0.5), 0.1);
    }

    #[test]
    fn a_car_never_moves_past_its_free_room_nor_backwards() {
        let x = AdvanceInputs {
            free_room: 0.2,
            ..inputs()
        };
        assert_eq!(advance(&x, &p(), 2.0, 0.5), 0.2);
        let stopped = AdvanceInputs {
            speed: 0.0,
            leader: Some((0.0, 0.0)),
            ..inputs()
        };
        assert_eq!(advance(&stopped, &p(), 2.0, 0.5), 0.0);
    }

    fn record(points: &[[f64; 2]]) -> AgentRecord {
        AgentRecord {
            record_id: 1,
            kind: AgentKind::Vehicle,
            start_step: 0,
            positions: points.to_vec(),
            velocities: vec![[1.0, 0.0]; points.len()],
            non_reactive: false,
            desired_speed: None,
        }
    }

    #[test]
    fn the_path_is_parameterised_by_arc_length() {
        let rec = record(&[[0.0, 0.0], [3.0, 0.0], [3.0, 0.0], [3.0, 4.0]]);
        let path = RecordedPath::new(&rec);
        assert_eq!(path.length(), 7.0);
        assert_eq!(path.scheduled(1), 3.0);
        assert_eq!(path.scheduled(9), 7.0);
        let (pos, heading) = path.pose(&rec, 5.0);
        assert!((pos - Vec2::new(3.0, 2.0)).norm() < 1e-12);
        assert!((heading - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
        // At a sample: the recorded position and heading.
        let (pos, heading) = path.pose(&rec, 3.0);
        assert_eq!(pos, Vec2::new(3.0, 0.0));
        assert_eq!(heading, rec.heading_at(2));
        assert_eq!(path.pose(&rec, 100.0).0, Vec2::new(3.0, 4.0));
    }

    #[test]
    fn the_desired_speed_is_the_85th_percentile_of_the_record() {
        let mut rec = record(&[[0.0, 0.0]; 20]);
        for (k, v) in rec.velocities.iter_mut().enumerate() {
            *v = [k as f64 * 0.5, 0.0];
        }
        // Speeds 0, 0.5, ..., 9.5; rank ceil(0.85 * 20) = 17: 8.0.
        assert_eq!(RecordedPath::new(&rec).desired_speed, 8.0);
        rec.desired_speed = Some(3.0);
        assert_eq!(RecordedPath::new(&rec).desired_speed, 3.0);
    }
}
