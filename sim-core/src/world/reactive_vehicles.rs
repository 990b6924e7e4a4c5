//! Stage 2, last part: the reactive vehicles move ([`crate::model::traffic`], docs/MODEL.md "Traffic").
//!
//! They move after every other agent, one after the other in slot order, each against the
//! footprints as they already are at `t + 1` (and, for the reactive vehicles after it, as they
//! still are at `t`). That is what lets a car promise never to drive into anything: whatever it
//! checked its move against has already moved, or will move checking against it.

use super::agents::v2;
use super::{Control, World};
use crate::geometry::{clearance, Placed, Vec2};
use crate::model::traffic::{self, AdvanceInputs, RecordedPath};
use crate::params::VehicleModel;

/// Spacing of the poses at which the corridor ahead is checked, m.
const SAMPLE_SPACING: f64 = 0.25;
/// Clearance a car keeps when it stops short of a footprint in its way, m.
const STOP_CLEARANCE: f64 = 0.05;

/// One agent's new state at `t + 1`: position, velocity, speed, heading.
pub(super) type Moved = (Vec2, Vec2, f64, f64);

/// What the corridor ahead of a car holds.
struct Corridor {
    /// Free distance along the path to the nearest agent in the corridor, m, and that agent's
    /// speed along the path there, m/s.
    leader: Option<(f64, f64)>,
    /// How far the car can move before its footprint comes within [`STOP_CLEARANCE`] of one that
    /// it approaches, m (as far as the scan reached when nothing is in the way).
    free_room: f64,
}

impl World {
    /// Moves every reactive vehicle, in slot order. `moved` holds every agent's state at `t + 1`,
    /// and, for the reactive vehicles, their state at `t` until they move.
    pub(super) fn move_traffic(&mut self, moved: &mut [Moved]) {
        for i in 0..self.agents.len() {
            match self.agents.control[i] {
                Control::Vehicle(VehicleModel::Idm) => self.move_idm(i, moved),
                // `replay` vehicles are `Control::Replay`.
                Control::Vehicle(VehicleModel::Replay) => unreachable!("replay is Control::Replay"),
                _ => {}
            }
        }
    }

    /// One step of [`VehicleModel::Idm`] for the vehicle in slot `i`.
    fn move_idm(&mut self, i: usize, moved: &mut [Moved]) {
        let id = self.agents.id[i] as usize;
        let rec = &self.scenario.agents[id];
        let path = self.paths[id]
            .as_ref()
            .expect("every reactive vehicle has a path");
        let (dt, tp) = (self.params.dt, &self.params.traffic);
        let acc_max = self.params.vehicle.acc_max;
        let s = self.agents.path_s[i];
        let last = rec.positions.len() - 1;
        let k_next = (self.step + 1 - rec.start_step) as usize;
        if k_next > last && s >= path.length() {
            // At the end of its path and of its record: it stays and leaves (as a replayed agent).
            self.agents.leaving[i] = true;
            return;
        }
        let speed = self.agents.speed[i];
        let behind_schedule = (path.scheduled(k_next) - s).max(0.0);
        let record_step = if k_next <= last {
            path.scheduled(k_next) - path.scheduled(k_next - 1)
        } else {
            0.0
        };
        // The corridor reaches as far as the car could move this step, and beyond it as far as
        // the IDM's desired gap to a standing leader, 1.5 times over (at most lookahead_max).
        let a = tp.acc.min(acc_max);
        let max_step = record_step.max((speed + a * dt) * dt);
        let standing_gap = tp.min_gap
            + speed * tp.time_headway
            + speed * speed / (2.0 * (a * tp.comfortable_decel).sqrt());
        let reach = (max_step + (1.5 * standing_gap).min(tp.lookahead_max))
            .min(path.length() - s)
            .max(0.0);
        let corridor = self.scan_corridor(i, path, s, reach, moved);
        let inputs = AdvanceInputs {
            speed,
            desired_speed: path.desired_speed,
            leader: corridor.leader,
            behind_schedule,
            record_step,
            free_room: corridor.free_room,
        };
        let mut d = traffic::advance(&inputs, tp, acc_max, dt);
        let mut state = self.pose_after(i, path, s, d, behind_schedule, k_next);
        if !self.is_clear(i, &state, moved) {
            // Between two checked poses: back to the last one checked (all clear), or stay.
            d = (d / SAMPLE_SPACING).floor() * SAMPLE_SPACING;
            let (pos, _, _, heading) = moved[i];
            state = if d > 0.0 {
                let (pos, heading) = path.pose(rec, s + d);
                let (sin, cos) = heading.sin_cos();
                (pos, Vec2::new(cos, sin) * (d / dt), d / dt, heading)
            } else {
                (pos, Vec2::zeros(), 0.0, heading)
            };
        }
        moved[i] = state;
        self.agents.path_s[i] = s + d;
    }

    /// The state of the car in slot `i` after moving `d` along its path from `s`: its record's
    /// state at `k_next` when that is where it arrives (`d == behind_schedule`), else the pose
    /// on the path, moving along it at `d / dt`.
    fn pose_after(
        &self,
        i: usize,
        path: &RecordedPath,
        s: f64,
        d: f64,
        behind_schedule: f64,
        k_next: usize,
    ) -> Moved {
        let rec = &self.scenario.agents[self.agents.id[i] as usize];
        if d == behind_schedule && k_next < rec.positions.len() {
            let vel = v2(rec.velocities[k_next]);
            return (
                v2(rec.positions[k_next]),
                vel,
                vel.norm(),
                rec.heading_at(k_next),
            );
        }
        let (pos, heading) = path.pose(rec, s + d);
        let speed = d / self.params.dt;
        let (sin, cos) = heading.sin_cos();
        (pos, Vec2::new(cos, sin) * speed, speed, heading)
    }

    /// Whether the car in slot `i` at `state` keeps [`STOP_CLEARANCE`] from every agent it is
    /// not already closer to.
    fn is_clear(&self, i: usize, state: &Moved, moved: &[Moved]) -> bool {
        let a = &self.agents;
        let me = |pos, heading| Placed {
            shape: a.shape[i],
            position: pos,
            heading,
        };
        let (now, then) = (me(moved[i].0, moved[i].3), me(state.0, state.3));
        (0..a.len()).filter(|&j| j != i).all(|j| {
            let other = Placed {
                shape: a.shape[j],
                position: moved[j].0,
                heading: moved[j].3,
            };
            let reach = now.shape.bounding_radius() + other.shape.bounding_radius();
            if (then.position - other.position).norm() > reach + STOP_CLEARANCE {
                return true;
            }
            let c = clearance(&then, &other);
            c >= STOP_CLEARANCE || c >= clearance(&now, &other)
        })
    }

    /// Sweeps the footprint of the car in slot `i` along its path from `s` to `s + reach`, every
    /// [`SAMPLE_SPACING`], against the other agents' footprints in `moved`. An agent is in the
    /// way where the swept footprint comes within `corridor_margin` of it and closer than it is
    /// now (agents beside or behind, which the car does not approach, are not).
    fn scan_corridor(
        &self,
        i: usize,
        path: &RecordedPath,
        s: f64,
        reach: f64,
        moved: &[Moved],
    ) -> Corridor {
        let a = &self.agents;
        let rec = &self.scenario.agents[a.id[i] as usize];
        let margin = self.params.traffic.corridor_margin;
        let shape = a.shape[i];
        let here = Placed {
            shape,
            position: moved[i].0,
            heading: moved[i].3,
        };
        let r_me = shape.bounding_radius();
        // The agents the swept footprint can come near, with their clearance now.
        let near: Vec<(usize, Placed, f64)> = (0..a.len())
            .filter(|&j| j != i)
            .filter_map(|j| {
                let other = Placed {
                    shape: a.shape[j],
                    position: moved[j].0,
                    heading: moved[j].3,
                };
                let r = r_me + other.shape.bounding_radius() + margin;
                ((other.position - here.position).norm() <= reach + r)
                    .then(|| (j, other, clearance(&here, &other)))
            })
            .collect();
        let mut leader = None;
        let samples = (reach / SAMPLE_SPACING).ceil() as usize;
        for k in 1..=samples {
            let d = (k as f64 * SAMPLE_SPACING).min(reach);
            let before = (k - 1) as f64 * SAMPLE_SPACING;
            let (position, heading) = path.pose(rec, s + d);
            let swept = Placed {
                shape,
                position,
                heading,
            };
            for (j, other, now) in &near {
                let r = r_me + other.shape.bounding_radius() + margin;
                if (other.position - position).norm() > r {
                    continue;
                }
                let c = clearance(&swept, other);
                if c >= margin || c >= *now {
                    continue;
                }
                if leader.is_none() {
                    let along = Vec2::new(heading.cos(), heading.sin());
                    leader = Some((before, moved[*j].1.dot(&along)));
                }
                if c < STOP_CLEARANCE {
                    return Corridor {
                        leader,
                        free_room: before,
                    };
                }
            }
        }
        Corridor {
            leader,
            free_room: reach,
        }
    }
}
