//! Stage 2 of a step: every agent moves from `t` to `t + 1` at once (model.md 1, 2, 5): external
//! agents by their action ([`crate::model::vehicle`], [`crate::model::pedestrian::integrate`]), replayed agents
//! by their record, simulated pedestrians by their social forces ([`crate::model::pedestrian`]), and
//! then the reactive vehicles, one after the other (`reactive_vehicles.rs`).

use super::agents::v2;
use super::AgentId;
use super::{observe, Control, StepScratch, World};
use crate::geometry::Vec2;
use crate::model::pedestrian::{self, ModelForces};
use crate::model::vehicle::{self, UnicycleState};
use crate::params::PedestrianModel;
use crate::scenario::AgentKind;
use crate::support::fastmath;

impl World {
    /// Moves every agent; records, per external agent, whether its action was clipped and its yaw
    /// rate (in `clipped_of`, for the rewards).
    pub(super) fn move_agents(
        &mut self,
        scratch: &mut StepScratch,
        actions: &[(AgentId, [f64; 2])],
    ) {
        let dt = self.params.dt;
        let n = self.agents.len();
        let mut clipped_of = std::mem::take(&mut self.clipped_of);
        clipped_of.clear();
        // Every move reads the state at `t`: the new states are collected first, then written.
        let mut moved = std::mem::take(&mut scratch.moved);
        moved.clear();
        for i in 0..n {
            let id = self.agents.id[i];
            let (pos, vel, speed, heading) = match self.agents.control[i] {
                Control::External => {
                    let act = actions
                        .iter()
                        .find(|(a, _)| *a == id)
                        .map(|(_, a)| *a)
                        .unwrap_or([0.0; 2]);
                    self.move_external(i, act, &mut clipped_of)
                }
                Control::Replay => match self.replay_state(i, self.step + 1) {
                    Some(s) => s,
                    None => {
                        // Past its record: it stays where it was and leaves below.
                        self.agents.leaving[i] = true;
                        (
                            self.agents.pos[i],
                            self.agents.vel[i],
                            self.agents.speed[i],
                            self.agents.heading[i],
                        )
                    }
                },
                Control::Model(m) => self.move_pedestrian(i, m),
                // Reactive vehicles move last (`move_traffic`); until then, their state at t.
                Control::Vehicle(_) => (
                    self.agents.pos[i],
                    self.agents.vel[i],
                    self.agents.speed[i],
                    self.agents.heading[i],
                ),
            };
            moved.push((pos, vel, speed, heading));
        }
        self.move_traffic(&mut moved);
        let a = &mut self.agents;
        for (i, &(pos, vel, speed, heading)) in moved.iter().enumerate() {
            a.prev_acc[i] = a.acc[i];
            a.acc[i] = (vel - a.vel[i]) / dt;
            a.pos[i] = pos;
            a.vel[i] = vel;
            a.speed[i] = speed;
            a.heading[i] = heading;
        }
        scratch.moved = moved;
        self.clipped_of = clipped_of;
    }

    fn move_external(
        &self,
        i: usize,
        act: [f64; 2],
        clipped_of: &mut Vec<(AgentId, bool, f64)>,
    ) -> (Vec2, Vec2, f64, f64) {
        let a = &self.agents;
        let dt = self.params.dt;
        match a.kind[i] {
            AgentKind::Vehicle => {
                let (cmd, clipped) = vehicle::map_action(act, &self.params.vehicle);
                clipped_of.push((a.id[i], clipped, cmd.omega));
                let s = vehicle::unicycle_step(
                    UnicycleState {
                        position: a.pos[i],
                        speed: a.speed[i],
                        heading: a.heading[i],
                    },
                    cmd,
                    dt,
                    self.params.vehicle.speed_max,
                );
                let vel = Vec2::new(s.heading.cos(), s.heading.sin()) * s.speed;
                (s.position, vel, s.speed, s.heading)
            }
            AgentKind::Pedestrian => {
                let f = act[0].clamp(-1.0, 1.0);
                let l = act[1].clamp(-1.0, 1.0);
                clipped_of.push((a.id[i], f != act[0] || l != act[1], 0.0));
                let (s, c) = a.heading[i].sin_cos();
                let acc = Vec2::new(c * f - s * l, s * f + c * l) * self.params.ped_acc_max;
                let (pos, vel) =
                    pedestrian::integrate(a.pos[i], a.vel[i], acc, dt, self.params.ped_speed_max);
                let speed = vel.norm();
                let heading = if speed > 0.0 {
                    fastmath::atan2(vel.y, vel.x)
                } else {
                    a.heading[i]
                };
                (pos, vel, speed, heading)
            }
        }
    }

    fn replay_state(&self, i: usize, step: u32) -> Option<(Vec2, Vec2, f64, f64)> {
        let rec = &self.scenario.agents[self.agents.id[i] as usize];
        let k = step.checked_sub(rec.start_step)? as usize;
        let pos = v2(*rec.positions.get(k)?);
        let vel = v2(rec.velocities[k]);
        Some((pos, vel, vel.norm(), rec.heading_at(k)))
    }

    fn move_pedestrian(&self, i: usize, model: PedestrianModel) -> (Vec2, Vec2, f64, f64) {
        let a = &self.agents;
        let dt = self.params.dt;
        let vmax = self.params.ped_speed_max;
        let params = self.params.pedestrians.for_model(model);
        let Some((p, forces)) = params.and_then(|p| Some((p, ModelForces::new(model, p)?))) else {
            // `cv`: the initial velocity vector for the whole episode, under the pedestrian
            // speed cap (model.md 1) like every simulated pedestrian.
            let v = pedestrian::clip_norm(a.initial_vel[i], vmax);
            return finish_move((a.pos[i] + v * dt, v), a.heading[i]);
        };
        let xi = a.pos[i];
        let f_goal = pedestrian::goal_force(xi, a.vel[i], a.goal[i], a.v0[i], p.tau);
        let (repulsion, max_w) = if self.forces_valid {
            // Summed by the observe pass that built the edges.
            (self.rep_force[i], self.rep_max_w[i])
        } else {
            // Agents left since: the same sum over the edges that remain, edge by edge as the
            // observe pass computes it (so a step rounds the same whoever left).
            let (mut fx, mut fy, mut w) = (Vec::new(), Vec::new(), Vec::new());
            for e in self.out_edges(i) {
                let j = e.target_slot as usize;
                let (direction, inv_dist) = observe::edge_direction(a, i, j);
                let veh = if a.kind[j] == AgentKind::Vehicle {
                    1.0
                } else {
                    0.0
                };
                let (x, y, weight) =
                    forces.edge_force(e.psi, e.u, veh, inv_dist, direction, e.clearance);
                fx.push(x);
                fy.push(y);
                w.push(weight);
            }
            (
                Vec2::new(pedestrian::lane_sum(&fx), pedestrian::lane_sum(&fy)),
                pedestrian::lane_max(&w),
            )
        };
        let force = f_goal * forces.goal_weight(max_w) + repulsion;
        finish_move(
            pedestrian::integrate(xi, a.vel[i], force, dt, vmax),
            a.heading[i],
        )
    }
}

/// Speed and heading of a moved pedestrian (the heading is kept while it stands still).
fn finish_move((pos, vel): (Vec2, Vec2), heading: f64) -> (Vec2, Vec2, f64, f64) {
    let speed = vel.norm();
    let heading = if speed > 0.0 {
        fastmath::atan2(vel.y, vel.x)
    } else {
        heading
    };
    (pos, vel, speed, heading)
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use crate::params::{PedestrianModel, WorldParams};
    use crate::scenario::{AgentKind, AgentRecord, Scenario, Split};
    use crate::world::{Control, EpisodeConfig, World};

    fn walker(kind: AgentKind, p0: [f64; 2], v: [f64; 2]) -> AgentRecord {
        let n = 40;
        AgentRecord {
            record_id: 0,
            kind,
            start_step: 0,
            positions: (0..n)
                .map(|k| [p0[0] + v[0] * 0.5 * k as f64, p0[1] + v[1] * 0.5 * k as f64])
                .collect(),
            velocities: vec![v; n],
            non_reactive: false,
            desired_speed: None,
        }
    }

    /// A move after agents left sums the remaining edges' forces again; with no one gone it must
    /// give exactly the observe pass's sums, for discs and for the car's rectangle alike: the
    /// same model rounds the same whoever left.
    #[test]
    fn summing_the_edges_again_gives_the_observe_pass_forces() {
        let mut agents = vec![walker(AgentKind::Vehicle, [-4.0, 0.3], [1.5, 0.0])];
        for k in 0..24 {
            let (x, y) = ((k % 6) as f64 * 1.1 - 2.0, (k / 6) as f64 * 1.3 - 2.0);
            let v = [0.3 * ((k % 5) as f64 - 2.0), 0.9 - 0.1 * (k % 4) as f64];
            agents.push(walker(AgentKind::Pedestrian, [x, y], v));
        }
        let scenario = Arc::new(Scenario {
            name: "forces".into(),
            split: Split::Train,
            dt: 0.5,
            ego: 0,
            agents,
        });
        for model in [
            PedestrianModel::Sfm,
            PedestrianModel::RaSfm,
            PedestrianModel::CrSfm,
        ] {
            let config = EpisodeConfig::replay_vehicles(model);
            let mut w = World::new(scenario.clone(), WorldParams::default(), config).unwrap();
            for _ in 0..3 {
                w.step(&[]).unwrap();
            }
            assert!(w.forces_valid && w.edge_count() > 100);
            let peds: Vec<usize> = (0..w.len())
                .filter(|&i| w.agents.control[i] == Control::Model(model))
                .collect();
            assert!(peds.len() > 10);
            let summed: Vec<_> = peds.iter().map(|&i| w.move_pedestrian(i, model)).collect();
            w.forces_valid = false;
            for (&i, by_observe) in peds.iter().zip(&summed) {
                let again = w.move_pedestrian(i, model);
                let bits = |s: (crate::Vec2, crate::Vec2, f64, f64)| {
                    [s.0.x, s.0.y, s.1.x, s.1.y, s.2, s.3].map(f64::to_bits)
                };
                assert_eq!(bits(again), bits(*by_observe), "{model:?}, slot {i}");
            }
        }
    }
}
