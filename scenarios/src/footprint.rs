//! Footprints of recorded agents (model.md section 1) and the overlap checks built on them.
//!
//! - A pedestrian is a disc of radius [`PED_RADIUS`] (0.3 m).
//! - A vehicle is a rectangle [`VEHICLE_LENGTH`] x [`VEHICLE_WIDTH`] (4.0 m x 1.8 m) centred on
//!   its recorded position, its long side along the direction of motion: the heading at a step is
//!   `atan2(vy, vx)` of the recorded velocity when the speed is at least
//!   [`HEADING_MIN_SPEED`] (0.1 m/s); otherwise it is the heading of the nearest sample of the
//!   *same stored track* whose speed is at least that (the earlier one on a tie); a track that
//!   never moves has heading 0.
//!
//! The heading is computed from the stored track only, so the extractor and the loader always
//! agree on every footprint. Overlap means `clearance <= 0` (model.md section 1).
//!
//! The pairwise checks use a uniform hash grid (cell = the largest footprint diameter), so a
//! step with `n` agents costs about `O(n)` rather than `O(n^2)`.

use std::collections::HashMap;

use sim_core::geometry::{clearance, Placed, Shape, Vec2};
use sim_core::scenario::{AgentKind, AgentRecord};

/// Pedestrian disc radius in metres.
pub const PED_RADIUS: f64 = 0.3;
/// Vehicle rectangle length (along the heading) in metres.
pub const VEHICLE_LENGTH: f64 = 4.0;
/// Vehicle rectangle width in metres.
pub const VEHICLE_WIDTH: f64 = 1.8;
/// Minimum recorded speed (m/s) at which a velocity defines a vehicle's heading.
pub const HEADING_MIN_SPEED: f64 = 0.1;

/// The footprint shape of an agent kind.
pub fn shape_of(kind: AgentKind) -> Shape {
    match kind {
        AgentKind::Pedestrian => Shape::Disc { radius: PED_RADIUS },
        AgentKind::Vehicle => Shape::Rect {
            length: VEHICLE_LENGTH,
            width: VEHICLE_WIDTH,
        },
    }
}

/// Heading (radians) at every sample of a recorded velocity track, by the rule in the module docs.
pub fn track_headings(velocities: &[[f64; 2]]) -> Vec<f64> {
    let moving = |v: &[f64; 2]| v[0].hypot(v[1]) >= HEADING_MIN_SPEED;
    let n = velocities.len();
    // Nearest moving sample at or before / at or after each index.
    let mut before: Vec<Option<usize>> = vec![None; n];
    let mut last = None;
    for (i, v) in velocities.iter().enumerate() {
        if moving(v) {
            last = Some(i);
        }
        before[i] = last;
    }
    let mut after: Vec<Option<usize>> = vec![None; n];
    let mut next = None;
    for i in (0..n).rev() {
        if moving(&velocities[i]) {
            next = Some(i);
        }
        after[i] = next;
    }
    (0..n)
        .map(|i| {
            let pick = match (before[i], after[i]) {
                (Some(b), Some(a)) => Some(if i - b <= a - i { b } else { a }),
                (Some(b), None) => Some(b),
                (None, Some(a)) => Some(a),
                (None, None) => None,
            };
            pick.map_or(0.0, |k| velocities[k][1].atan2(velocities[k][0]))
        })
        .collect()
}

/// One agent's footprints over its track: its shape and (for vehicles) its headings.
#[derive(Debug, Clone)]
pub struct TrackFootprint {
    shape: Shape,
    start_step: u32,
    positions: Vec<[f64; 2]>,
    headings: Vec<f64>,
}

impl TrackFootprint {
    /// Footprints of `agent`'s stored track.
    pub fn new(agent: &AgentRecord) -> Self {
        let headings = match agent.kind {
            AgentKind::Vehicle => track_headings(&agent.velocities),
            AgentKind::Pedestrian => vec![0.0; agent.positions.len()],
        };
        Self {
            shape: shape_of(agent.kind),
            start_step: agent.start_step,
            positions: agent.positions.clone(),
            headings,
        }
    }

    /// The placed footprint at absolute scenario step `step`, if the agent is present then.
    pub fn at(&self, step: u32) -> Option<Placed> {
        let k = step.checked_sub(self.start_step)? as usize;
        let p = self.positions.get(k)?;
        Some(Placed {
            shape: self.shape,
            position: Vec2::new(p[0], p[1]),
            heading: self.headings.get(k).copied().unwrap_or(0.0),
        })
    }
}

/// A pair of agents whose footprints overlap at a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Overlap {
    /// Index of the first agent (the smaller index).
    pub a: usize,
    /// Index of the second agent.
    pub b: usize,
    /// Absolute scenario step.
    pub step: u32,
    /// The clearance found (`<= 0`, floored at 0 by the geometry).
    pub clearance: f64,
}

/// Largest footprint diameter: the grid cell size for the broad phase.
fn cell_size() -> f64 {
    2.0 * shape_of(AgentKind::Vehicle)
        .bounding_radius()
        .max(shape_of(AgentKind::Pedestrian).bounding_radius())
}

/// First overlapping pair among `placed` (pairs in ascending `(a, b)` order), where `placed`
/// holds `(agent index, footprint)`, and only pairs with at least one member in `focus` (when
/// given) are checked.
fn first_overlap_among(
    placed: &[(usize, Placed)],
    focus: Option<&dyn Fn(usize) -> bool>,
) -> Option<(usize, usize, f64)> {
    let cell = cell_size();
    let key = |p: &Placed| -> (i64, i64) {
        (
            (p.position.x / cell).floor() as i64,
            (p.position.y / cell).floor() as i64,
        )
    };
    let mut grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for (slot, (_, p)) in placed.iter().enumerate() {
        grid.entry(key(p)).or_default().push(slot);
    }
    let mut best: Option<(usize, usize, f64)> = None;
    for (slot, (ia, pa)) in placed.iter().enumerate() {
        let (cx, cy) = key(pa);
        for dx in -1..=1 {
            for dy in -1..=1 {
                let Some(cands) = grid.get(&(cx + dx, cy + dy)) else {
                    continue;
                };
                for &other in cands {
                    if other <= slot {
                        continue;
                    }
                    let (ib, pb) = &placed[other];
                    if let Some(f) = focus {
                        if !f(*ia) && !f(*ib) {
                            continue;
                        }
                    }
                    let c = clearance(pa, pb);
                    if c <= 0.0 || !c.is_finite() {
                        let pair = ((*ia).min(*ib), (*ia).max(*ib), c);
                        if best.is_none_or(|b| (pair.0, pair.1) < (b.0, b.1)) {
                            best = Some(pair);
                        }
                    }
                }
            }
        }
    }
    best
}

/// Footprints of every agent of a scenario.
pub fn footprints(agents: &[AgentRecord]) -> Vec<TrackFootprint> {
    agents.iter().map(TrackFootprint::new).collect()
}

/// Spawn check: every pair of agents is checked at the first step at which both are present
/// (the later of their two start steps). Returns the first offending pair, ordered by step and
/// then by agent indices.
pub fn first_spawn_overlap(agents: &[AgentRecord]) -> Option<Overlap> {
    let fps = footprints(agents);
    let mut spawn_steps: Vec<u32> = agents.iter().map(|a| a.start_step).collect();
    spawn_steps.sort_unstable();
    spawn_steps.dedup();
    for step in spawn_steps {
        let placed: Vec<(usize, Placed)> = fps
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f.at(step).map(|p| (i, p)))
            .collect();
        let spawning = |i: usize| agents[i].start_step == step;
        if let Some((a, b, c)) = first_overlap_among(&placed, Some(&spawning)) {
            return Some(Overlap {
                a,
                b,
                step,
                clearance: c,
            });
        }
    }
    None
}

/// All-steps check: every pair of agents at every step at which both are present. Returns the
/// first offending pair, ordered by step and then by agent indices.
pub fn first_overlap_any_step(agents: &[AgentRecord]) -> Option<Overlap> {
    let fps = footprints(agents);
    let first = agents.iter().map(|a| a.start_step).min().unwrap_or(0);
    let end = agents
        .iter()
        .map(|a| a.start_step as u64 + a.positions.len() as u64)
        .max()
        .unwrap_or(0)
        .min(u32::MAX as u64) as u32;
    for step in first..end {
        let placed: Vec<(usize, Placed)> = fps
            .iter()
            .enumerate()
            .filter_map(|(i, f)| f.at(step).map(|p| (i, p)))
            .collect();
        if let Some((a, b, c)) = first_overlap_among(&placed, None) {
            return Some(Overlap {
                a,
                b,
                step,
                clearance: c,
            });
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headings_fill_stationary_samples_from_nearest_moving() {
        let v = [
            [0.0, 0.0],
            [0.0, 1.0],
            [0.0, 0.0],
            [0.0, 0.0],
            [-1.0, 0.0],
            [0.0, 0.0],
        ];
        let h = track_headings(&v);
        let q = std::f64::consts::FRAC_PI_2;
        assert_eq!(h[0], q);
        assert_eq!(h[1], q);
        assert_eq!(h[2], q); // tie-free: 1 away from index 1, 2 away from index 4
        assert_eq!(h[3], std::f64::consts::PI); // 1 away from index 4
        assert_eq!(h[5], std::f64::consts::PI);
        assert_eq!(track_headings(&[[0.0, 0.0]]), vec![0.0]);
    }
}
