//! Stages 1 and 3 of a step: agents enter at their first recorded step, simulated pedestrians
//! leave at their goal, replayed agents at the end of their record and external agents after
//! their episode (model.md 1, 5b).

use super::agents::v2;
use super::Edge;
use super::{AgentId, Control, Event, StepScratch, World, NO_SLOT};
use crate::geometry::{clearance, Placed, Shape, Vec2};
use crate::scenario::AgentKind;

impl World {
    /// Flags the simulated pedestrians within the goal radius of their goal as leaving.
    pub(super) fn mark_arrivals(&mut self, events: &mut Vec<Event>) {
        let goal_r = self.params.ped_goal_radius;
        let a = &mut self.agents;
        for i in 0..a.len() {
            let simulated_ped =
                a.kind[i] == AgentKind::Pedestrian && matches!(a.control[i], Control::Model(_));
            if simulated_ped && (a.pos[i] - a.goal[i]).norm() <= goal_r {
                a.leaving[i] = true;
                events.push(Event::GoalReached { agent: a.id[i] });
            }
        }
    }

    /// Agents recorded from the current step enter (after the reactive vehicles still waiting
    /// for their entry to clear, which enter first, in id order). A reactive vehicle whose
    /// entry footprint overlaps a vehicle present waits (docs/MODEL.md, "Traffic").
    pub(super) fn enter_pending(&mut self, events: &mut Vec<Event>) {
        let mut due = std::mem::take(&mut self.deferred);
        let late = due.len();
        while let Some(&id) = self.pending.last() {
            let rec = &self.scenario.agents[id as usize];
            if rec.start_step > self.step {
                break;
            }
            self.pending.pop();
            if rec.end_step() < self.step {
                continue; // entirely in the past: never present.
            }
            due.push(id);
        }
        for (n, id) in due.into_iter().enumerate() {
            let reactive = matches!(self.control_of[id as usize], Control::Vehicle(_));
            if reactive && self.entry_blocked(id) {
                self.deferred.push(id);
            } else {
                self.enter(id, n < late, events);
            }
        }
    }

    /// Whether the record's first footprint of vehicle `id` overlaps a vehicle present.
    fn entry_blocked(&self, id: AgentId) -> bool {
        let rec = &self.scenario.agents[id as usize];
        let me = Placed {
            shape: self.params.vehicle.shape,
            position: v2(rec.positions[0]),
            heading: rec.heading_at(0),
        };
        let a = &self.agents;
        (0..a.len()).any(|j| {
            a.kind[j] == AgentKind::Vehicle
                && clearance(
                    &me,
                    &Placed {
                        shape: a.shape[j],
                        position: a.pos[j],
                        heading: a.heading[j],
                    },
                ) <= 0.0
        })
    }

    /// Agent `id` enters at its recorded state at the current step; a reactive vehicle whose
    /// entry was held up (`late`) enters standing at the start of its path.
    fn enter(&mut self, id: AgentId, late: bool, events: &mut Vec<Event>) {
        let rec = &self.scenario.agents[id as usize];
        let k = if late {
            0
        } else {
            (self.step - rec.start_step) as usize
        };
        let pos = v2(rec.positions[k]);
        let vel = if late {
            Vec2::zeros()
        } else {
            v2(rec.velocities[k])
        };
        let heading = rec.heading_at(k);
        let path_s = self.paths[id as usize]
            .as_ref()
            .map_or(0.0, |p| p.scheduled(k));
        let control = self.control_of[id as usize];
        let (shape, speed) = match rec.kind {
            AgentKind::Vehicle => (self.params.vehicle.shape, vel.norm()),
            AgentKind::Pedestrian => (
                Shape::Disc {
                    radius: self.params.ped_radius,
                },
                vel.norm(),
            ),
        };
        let a = &mut self.agents;
        a.id.push(id);
        a.kind.push(rec.kind);
        a.control.push(control);
        a.shape.push(shape);
        a.pos.push(pos);
        a.vel.push(vel);
        a.acc.push(Vec2::zeros());
        a.prev_acc.push(Vec2::zeros());
        a.speed.push(speed);
        a.heading.push(heading);
        a.goal.push(v2(rec.goal()));
        a.v0.push(rec.desired_speed());
        a.initial_vel.push(vel);
        a.edge_start.push(0);
        a.edge_len.push(0);
        a.leaving.push(false);
        a.path_s.push(path_s);
        if self.step > 0 {
            events.push(Event::Entered { agent: id });
        }
        if let Some(e) = self.externals.iter_mut().find(|e| e.id == id) {
            e.active = true;
            e.speeds.push(speed);
            e.goal_distance = (pos - v2(rec.goal())).norm();
        }
    }

    /// Removes the agents flagged `leaving`, keeping the graph consistent (edges to them dropped,
    /// target slots renumbered).
    pub(super) fn remove_leaving(&mut self, s: &mut StepScratch, events: &mut Vec<Event>) {
        if !self.agents.leaving.iter().any(|&l| l) {
            return;
        }
        let n = self.agents.len();
        s.keep.clear();
        s.keep.extend(self.agents.leaving.iter().map(|&l| !l));
        s.slot_map.clear();
        let mut next = 0u32;
        for i in 0..n {
            if s.keep[i] {
                s.slot_map.push(next);
                next += 1;
            } else {
                s.slot_map.push(NO_SLOT);
                events.push(Event::Left {
                    agent: self.agents.id[i],
                });
                self.departed.push((self.agents.id[i], self.agents.pos[i]));
            }
        }
        self.forces_valid = false;
        s.next_edges.clear();
        for i in 0..n {
            let start = s.next_edges.len() as u32;
            if s.keep[i] {
                let first = self.agents.edge_start[i] as usize;
                for k in first..first + self.agents.edge_len[i] as usize {
                    let e = self.edges.get(k);
                    let t = s.slot_map[e.target_slot as usize];
                    if t != NO_SLOT {
                        s.next_edges.push(Edge {
                            target_slot: t,
                            ..e
                        });
                    }
                }
            }
            self.agents.edge_start[i] = start;
            self.agents.edge_len[i] = s.next_edges.len() as u32 - start;
        }
        std::mem::swap(&mut self.edges, &mut s.next_edges);
        self.agents.retain(&s.keep);
    }
}
