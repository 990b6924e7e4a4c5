//! The agents present at the current step, one slot each (structure of arrays), and the
//! episode record of each external agent.

use super::{AgentId, Control};
use crate::geometry::{Shape, Vec2};
use crate::metrics::EpisodeStatus;
use crate::scenario::AgentKind;

#[derive(Debug, Clone)]
pub(super) struct ExternalTrack {
    pub(super) id: AgentId,
    pub(super) active: bool,
    /// Speed at every step of its episode so far (the metrics' input).
    pub(super) speeds: Vec<f64>,
    pub(super) last_acc: Option<f64>,
    /// Centre distance to the goal at the current step, m.
    pub(super) goal_distance: f64,
    pub(super) status: Option<EpisodeStatus>,
    /// For a vehicle: the pedestrians in its path at the current step that have been there
    /// since a step when it had room to stop short of them (model.md 2c).
    pub(super) in_path: Vec<AgentId>,
    /// `in_path` of the step before, while the current one is built.
    pub(super) in_path_before: Vec<AgentId>,
}

/// Structure-of-arrays state of the agents present at the current step.
#[derive(Debug, Clone, Default)]
pub(super) struct Agents {
    pub(super) id: Vec<AgentId>,
    pub(super) kind: Vec<AgentKind>,
    pub(super) control: Vec<Control>,
    pub(super) shape: Vec<Shape>,
    pub(super) pos: Vec<Vec2>,
    pub(super) vel: Vec<Vec2>,
    pub(super) acc: Vec<Vec2>,
    /// Acceleration at the previous step (what the constant-acceleration prediction extrapolates).
    pub(super) prev_acc: Vec<Vec2>,
    /// Unicycle speed for vehicles, `|v|` for pedestrians.
    pub(super) speed: Vec<f64>,
    pub(super) heading: Vec<f64>,
    pub(super) goal: Vec<Vec2>,
    pub(super) v0: Vec<f64>,
    pub(super) initial_vel: Vec<Vec2>,
    /// `edges[edge_start[i]..edge_start[i] + edge_len[i]]` are agent `i`'s out-edges.
    pub(super) edge_start: Vec<u32>,
    pub(super) edge_len: Vec<u32>,
    pub(super) leaving: Vec<bool>,
    /// Arc length along its recorded path of a reactive vehicle, m (0 for every other agent).
    pub(super) path_s: Vec<f64>,
}

impl Agents {
    pub(super) fn len(&self) -> usize {
        self.id.len()
    }

    pub(super) fn retain(&mut self, keep: &[bool]) {
        fn r<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut k = 0;
            v.retain(|_| {
                k += 1;
                keep[k - 1]
            });
        }
        r(&mut self.id, keep);
        r(&mut self.kind, keep);
        r(&mut self.control, keep);
        r(&mut self.shape, keep);
        r(&mut self.pos, keep);
        r(&mut self.vel, keep);
        r(&mut self.acc, keep);
        r(&mut self.prev_acc, keep);
        r(&mut self.speed, keep);
        r(&mut self.heading, keep);
        r(&mut self.goal, keep);
        r(&mut self.v0, keep);
        r(&mut self.initial_vel, keep);
        r(&mut self.edge_start, keep);
        r(&mut self.edge_len, keep);
        r(&mut self.leaving, keep);
        r(&mut self.path_s, keep);
    }
}

pub(super) fn v2(a: [f64; 2]) -> Vec2 {
    Vec2::new(a[0], a[1])
}
