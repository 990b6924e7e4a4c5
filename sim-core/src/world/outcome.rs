//! Stage 5 of a step: collision events and every reward term of each external agent's
//! transition (model.md 7), and whether the episode is over.

use super::{AgentOutcome, Event, RewardTerms, StepOutcome, World};
use crate::geometry::Shape;
use crate::metrics::{EpisodeMetrics, EpisodeStatus};
use crate::model::fault::{gap_in_path, room_to_stop, FAULT_MIN_SPEED};
use crate::scenario::AgentKind;

impl World {
    /// The step's outcome from the events so far: collisions added, each active external agent's
    /// rewards, the episode's end.
    pub(super) fn outcome(&mut self, mut events: Vec<Event>) -> StepOutcome {
        for i in 0..self.agents.len() {
            if !self.contact[i] {
                continue;
            }
            let range = self.out_range(i);
            let (targets, clearances) = (
                &self.edges.target[range.clone()],
                &self.edges.clearance[range],
            );
            let me = self.agents.id[i];
            for (&target, &clearance) in targets.iter().zip(clearances) {
                if clearance <= 0.0 && me < target {
                    events.push(Event::Collision { a: me, b: target });
                }
            }
        }
        self.judge_faults(&mut events);
        let mut outcome = StepOutcome {
            step: self.step,
            agents: Vec::with_capacity(self.externals.len()),
            events,
            episode_over: false,
        };
        let truncated = self.step >= self.horizon;
        let clipped_of = std::mem::take(&mut self.clipped_of);
        for k in 0..self.externals.len() {
            if !self.externals[k].active {
                continue;
            }
            let id = self.externals[k].id;
            let (clipped, omega) = clipped_of
                .iter()
                .find(|(a, _, _)| *a == id)
                .map_or((false, 0.0), |c| (c.1, c.2));
            let agent_outcome =
                self.external_outcome(k, clipped, omega, truncated, &mut outcome.events);
            outcome.agents.push(agent_outcome);
        }
        self.clipped_of = clipped_of;
        // Over when every external agent has entered and finished (one whose record starts
        // later keeps the episode running until it enters), or at the horizon.
        let all_finished = !self.externals.is_empty()
            && self
                .externals
                .iter()
                .all(|e| !e.active && !e.speeds.is_empty());
        self.over = truncated || all_finished;
        outcome.episode_over = self.over;
        outcome
    }

    /// Adds an [`Event::AtFault`] after each collision of an external vehicle with a pedestrian
    /// that is the vehicle's fault (model.md 2c), judged on the pedestrians in its path up to
    /// the last step; then updates each active external vehicle's pedestrians in its path.
    fn judge_faults(&mut self, events: &mut Vec<Event>) {
        let braking = self.params.vehicle.acc_max;
        for k in 0..self.externals.len() {
            let vehicle = self.externals[k].id;
            let Some(v) = self.slot_of(vehicle) else {
                continue;
            };
            if !self.externals[k].active || self.agents.kind[v] != AgentKind::Vehicle {
                continue;
            }
            let a = &self.agents;
            let speed = a.speed[v];
            let before = events.len();
            for e in 0..before {
                let Event::Collision { a: x, b: y } = events[e] else {
                    continue;
                };
                let pedestrian = if x == vehicle {
                    y
                } else if y == vehicle {
                    x
                } else {
                    continue;
                };
                if speed >= FAULT_MIN_SPEED && self.externals[k].in_path.contains(&pedestrian) {
                    events.push(Event::AtFault {
                        vehicle,
                        pedestrian,
                    });
                }
            }
            let Shape::Rect { length, width } = a.shape[v] else {
                continue; // a disc-shaped vehicle has no front face
            };
            // Both lists live in the track and swap each step: a step allocates nothing here.
            let track = &mut self.externals[k];
            std::mem::swap(&mut track.in_path, &mut track.in_path_before);
            track.in_path.clear();
            for p in 0..a.len() {
                if a.kind[p] != AgentKind::Pedestrian {
                    continue;
                }
                let radius = a.shape[p].bounding_radius();
                let Some(gap) =
                    gap_in_path(a.pos[v], a.heading[v], length, width, a.pos[p], radius)
                else {
                    continue;
                };
                if track.in_path_before.contains(&a.id[p]) || room_to_stop(gap, speed, braking) {
                    track.in_path.push(a.id[p]);
                }
            }
        }
    }

    fn external_outcome(
        &mut self,
        k: usize,
        action_clipped: bool,
        omega: f64,
        truncated: bool,
        events: &mut Vec<Event>,
    ) -> AgentOutcome {
        let w = self.params.reward;
        let dt = self.params.dt;
        let id = self.externals[k].id;
        let mut reward = RewardTerms::default();
        let Some(i) = self.slot_of(id) else {
            // Left with its record (cannot happen to an external agent, kept total for safety).
            self.externals[k].active = false;
            return AgentOutcome {
                agent: id,
                reward,
                terminated: true,
                truncated: false,
                action_clipped,
                metrics: None,
            };
        };
        let is_vehicle = self.agents.kind[i] == AgentKind::Vehicle;
        let goal = self.agents.goal[i];
        let d_now = (self.agents.pos[i] - goal).norm();
        reward.progress = w.progress * (self.externals[k].goal_distance - d_now);
        self.externals[k].goal_distance = d_now;
        let goal_radius = if is_vehicle {
            self.params.vehicle.goal_radius
        } else {
            self.params.ped_goal_radius
        };
        let arrived = d_now <= goal_radius;
        let mut collided = false;
        let mut c_min = f64::INFINITY;
        for e in self.out_edges(i) {
            let other_is_ped = self.agents.kind[e.target_slot as usize] == AgentKind::Pedestrian;
            // Vehicles collide with pedestrians and with other vehicles; a pedestrian with vehicles.
            if e.clearance <= 0.0 && (is_vehicle || !other_is_ped) {
                collided = true;
            }
            if other_is_ped {
                c_min = c_min.min(e.clearance);
            }
        }
        if arrived {
            reward.success = w.success;
            events.push(Event::GoalReached { agent: id });
        }
        if collided {
            reward.collision = w.collision;
        }
        if c_min < w.danger_clearance {
            reward.danger = w.danger * (c_min - w.danger_clearance);
        }
        let speed = self.agents.speed[i];
        let track = &mut self.externals[k];
        let prev_speed = track.speeds.last().copied().unwrap_or(speed);
        let acc = (speed - prev_speed) / dt;
        let jerk = track.last_acc.map_or(0.0, |a| (acc - a) / dt);
        track.last_acc = Some(acc);
        track.speeds.push(speed);
        reward.comfort = -w.jerk_penalty * jerk * jerk - w.yaw_rate_penalty * omega * omega;
        let terminated = arrived || collided;
        let mut metrics = None;
        if terminated || truncated {
            let status = if collided {
                EpisodeStatus::Collision
            } else if arrived {
                EpisodeStatus::Success
            } else {
                EpisodeStatus::Timeout
            };
            track.status = Some(status);
            track.active = false;
            metrics = Some(EpisodeMetrics::from_speeds(status, &track.speeds, dt));
            self.agents.leaving[i] = true;
        }
        AgentOutcome {
            agent: id,
            reward,
            terminated,
            truncated: truncated && !terminated,
            action_clipped,
            metrics,
        }
    }
}
