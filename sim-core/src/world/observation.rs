//! Observation of an external agent (model.md 7): node features in its ego frame (x forward),
//! padded to `max_agents` with a validity mask, and the risk-graph adjacency among those nodes.
//!
//! Node 0 is the ego agent. The other nodes are the agents inside its perception radius, nearest
//! (by clearance, then by id) first; agents beyond `max_agents - 1` of them are left out.

use std::cell::RefCell;

use crate::geometry::Vec2;
use crate::model::risk;
use crate::model::vehicle::wrap_angle;
use crate::scenario::AgentKind;
use crate::world::{AgentId, World};

/// Features per node.
pub const NODE_FEATURES: usize = 11;

/// Names of the node features, in order. Positions in m, velocities in m/s, angles in rad.
pub const FEATURE_NAMES: [&str; NODE_FEATURES] = [
    "rel_x",
    "rel_y",
    "rel_vx",
    "rel_vy",
    "speed",
    "heading_diff",
    "radius",
    "is_vehicle",
    "goal_dx",
    "goal_dy",
    "goal_dist",
];

thread_local! {
    /// The nearest-agent list and node slots of [`World::fill_observation`], kept per thread:
    /// an observation is filled per external agent and step, two allocations each otherwise.
    #[allow(clippy::type_complexity)]
    static SCRATCH: RefCell<(Vec<(f64, AgentId, usize)>, Vec<usize>)> =
        const { RefCell::new((Vec::new(), Vec::new())) };
}

/// Why an observation could not be written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObservationError {
    #[error("max_agents must be at least 1")]
    NoRoom,
    #[error("buffers have lengths {got:?}, expected {want:?} (features, adjacency, mask)")]
    BufferSize { got: [usize; 3], want: [usize; 3] },
    #[error("node id buffer has length {got}, expected {want}")]
    IdsSize { got: usize, want: usize },
}

/// Lengths of the feature, adjacency and mask buffers for `max_agents` nodes.
pub fn buffer_lengths(max_agents: usize) -> [usize; 3] {
    [
        max_agents * NODE_FEATURES,
        max_agents * max_agents,
        max_agents,
    ]
}

/// The row-major buffers an observation is written into: `features` `[max_agents,
/// NODE_FEATURES]`, `adjacency` `[max_agents, max_agents]` with `adjacency[a][b] = A(node a, node
/// b)`, and `mask` `[max_agents]` (lengths: [`buffer_lengths`]).
pub type ObservationBuffers<'a> = (&'a mut [f32], &'a mut [f32], &'a mut [u8]);

impl World {
    /// Writes agent `ego`'s observation of at most `max_agents` nodes into `buffers`. Returns
    /// `false` (and zeroes everything) when `ego` is not present.
    pub fn fill_observation(
        &self,
        ego: AgentId,
        max_agents: usize,
        buffers: ObservationBuffers,
    ) -> Result<bool, ObservationError> {
        self.fill_observation_impl(ego, max_agents, buffers, None)
    }

    /// [`World::fill_observation`] that also writes the agent id of every node into `node_ids`
    /// (`[max_agents]`, `pad` for padding nodes; all `pad` when `ego` is not present).
    pub fn fill_observation_with_ids(
        &self,
        ego: AgentId,
        max_agents: usize,
        buffers: ObservationBuffers,
        node_ids: &mut [AgentId],
        pad: AgentId,
    ) -> Result<bool, ObservationError> {
        if node_ids.len() != max_agents {
            return Err(ObservationError::IdsSize {
                got: node_ids.len(),
                want: max_agents,
            });
        }
        node_ids.fill(pad);
        self.fill_observation_impl(ego, max_agents, buffers, Some(node_ids))
    }

    fn fill_observation_impl(
        &self,
        ego: AgentId,
        max_agents: usize,
        (features, adjacency, mask): ObservationBuffers,
        node_ids: Option<&mut [AgentId]>,
    ) -> Result<bool, ObservationError> {
        if max_agents == 0 {
            return Err(ObservationError::NoRoom);
        }
        let want = buffer_lengths(max_agents);
        let got = [features.len(), adjacency.len(), mask.len()];
        if got != want {
            return Err(ObservationError::BufferSize { got, want });
        }
        features.fill(0.0);
        adjacency.fill(0.0);
        mask.fill(0);
        let Some(ego_slot) = self.slot_of(ego) else {
            return Ok(false);
        };
        SCRATCH.with(|scratch| {
            let mut scratch = scratch.borrow_mut();
            let (near, slots) = &mut *scratch;
            self.fill_nodes(
                (ego, ego_slot),
                max_agents,
                (features, adjacency, mask),
                node_ids,
                near,
                slots,
            );
        });
        Ok(true)
    }

    /// The part of [`World::fill_observation_impl`] after the checks, with the scratch vectors.
    fn fill_nodes(
        &self,
        (ego, ego_slot): (AgentId, usize),
        max_agents: usize,
        (features, adjacency, mask): ObservationBuffers,
        node_ids: Option<&mut [AgentId]>,
        near: &mut Vec<(f64, AgentId, usize)>,
        slots: &mut Vec<usize>,
    ) {
        near.clear();
        near.extend(
            self.out_edges(ego_slot)
                .map(|e| (e.clearance, e.target, e.target_slot as usize)),
        );
        // Entries with equal (clearance, id) are equal (the id fixes the slot), so an unstable
        // sort, which needs no allocation, orders them as a stable one would.
        near.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.truncate(max_agents - 1);
        slots.clear();
        slots.push(ego_slot);
        slots.extend(near.iter().map(|n| n.2));

        if let Some(ids) = node_ids {
            ids[0] = ego;
            for (k, n) in near.iter().enumerate() {
                ids[k + 1] = n.1;
            }
        }
        let me = self.view(ego_slot);
        let (s, c) = me.heading.sin_cos();
        let to_ego = |v: Vec2| Vec2::new(c * v.x + s * v.y, -s * v.x + c * v.y);
        for (node, &slot) in slots.iter().enumerate() {
            let a = &self.view(slot);
            let rel = to_ego(a.position - me.position);
            let rel_v = to_ego(a.velocity - me.velocity);
            let row = &mut features[node * NODE_FEATURES..(node + 1) * NODE_FEATURES];
            row[0] = rel.x as f32;
            row[1] = rel.y as f32;
            row[2] = rel_v.x as f32;
            row[3] = rel_v.y as f32;
            row[4] = a.velocity.norm() as f32;
            row[5] = wrap_angle(a.heading - me.heading) as f32;
            row[6] = a.shape.bounding_radius() as f32;
            row[7] = f32::from(u8::from(a.kind == AgentKind::Vehicle));
            if node == 0 {
                let g = to_ego(me.goal - me.position);
                row[8] = g.x as f32;
                row[9] = g.y as f32;
                row[10] = g.norm() as f32;
            }
            mask[node] = 1;
        }
        let lambda = self.params().risk.lambda;
        for (na, &sa) in slots.iter().enumerate() {
            for e in self.out_edges(sa) {
                if let Some(nb) = slots.iter().position(|&sb| sb == e.target_slot as usize) {
                    adjacency[na * max_agents + nb] = risk::adjacency(e.psi, e.u, lambda) as f32;
                }
            }
        }
    }
}
