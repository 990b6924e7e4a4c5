//! Scenarios: the recorded initial states, goals and ground-truth tracks a world starts from.
//!
//! A scenario holds every agent's recorded track sampled at the simulation step (`dt`). An agent
//! enters the scene at `start_step` (its first recorded frame relative to the scenario start) and
//! its goal is its last recorded position (model.md sections 5 and 7).

use serde::{Deserialize, Serialize};

use crate::params::VehicleModel;

/// Version of the scenario file format ([`ScenarioPool`]); bumped on any incompatible change.
pub const SCENARIO_FORMAT_VERSION: u32 = 1;

/// What kind of road user an agent is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AgentKind {
    Pedestrian,
    Vehicle,
}

/// Which split of a pool a scenario belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    Train,
    Test,
}

/// One agent's recorded track.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentRecord {
    /// Identifier of the agent in the source data (for example the HBS `agent_id`).
    pub record_id: u64,
    pub kind: AgentKind,
    /// Step (relative to the scenario's first step) of the first recorded sample.
    pub start_step: u32,
    /// Recorded positions `[x, y]` in metres, one per step from `start_step`. Never empty.
    pub positions: Vec<[f64; 2]>,
    /// Recorded velocities `[vx, vy]` in m/s, same length as `positions`.
    pub velocities: Vec<[f64; 2]>,
    /// A non-reactive pedestrian always replays its record, whatever model the world assigns.
    /// Vehicles nobody controls follow the episode's vehicle model (`replay` by default) whatever
    /// this says: the HBS extraction marks every other car non-reactive.
    #[serde(default)]
    pub non_reactive: bool,
    /// Desired speed `v0` of a simulated pedestrian in m/s; absent: the mean recorded speed
    /// (model.md 5). Set by scene variations (`variation.rs`) that scale it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub desired_speed: Option<f64>,
}

impl AgentRecord {
    /// Last step (relative to the scenario start) at which the agent was recorded.
    pub fn end_step(&self) -> u32 {
        self.start_step + self.positions.len() as u32 - 1
    }

    /// The goal: the last recorded position.
    pub fn goal(&self) -> [f64; 2] {
        *self
            .positions
            .last()
            .expect("validated: tracks are never empty")
    }

    /// The desired speed `v0` in m/s: [`AgentRecord::desired_speed`] if set, else the mean
    /// recorded speed.
    pub fn desired_speed(&self) -> f64 {
        self.desired_speed.unwrap_or_else(|| self.mean_speed())
    }

    /// Heading at sample `k`: the direction of the recorded velocity, or, when the agent stands
    /// still, of the nearest sample where it moves (0 if it never does).
    pub fn heading_at(&self, k: usize) -> f64 {
        const MOVING: f64 = 1e-6;
        let n = self.velocities.len();
        for d in 0..n {
            for idx in [k.checked_sub(d), k.checked_add(d).filter(|&i| i < n)]
                .into_iter()
                .flatten()
            {
                let v = self.velocities[idx];
                if v[0].hypot(v[1]) > MOVING {
                    return crate::support::fastmath::atan2(v[1], v[0]);
                }
            }
        }
        0.0
    }

    /// Mean recorded speed in m/s.
    pub fn mean_speed(&self) -> f64 {
        let n = self.velocities.len().max(1) as f64;
        self.velocities
            .iter()
            .map(|v| v[0].hypot(v[1]))
            .sum::<f64>()
            / n
    }

    /// Recorded position at absolute scenario step `step`, if recorded then.
    pub fn position_at(&self, step: u32) -> Option<[f64; 2]> {
        step.checked_sub(self.start_step)
            .and_then(|k| self.positions.get(k as usize).copied())
    }

    /// Recorded velocity at absolute scenario step `step`, if recorded then.
    pub fn velocity_at(&self, step: u32) -> Option<[f64; 2]> {
        step.checked_sub(self.start_step)
            .and_then(|k| self.velocities.get(k as usize).copied())
    }
}

/// One scenario: a window of recorded data with one or more vehicles and any number of pedestrians.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    /// Unique name inside its pool (for example `hbs-car1203`).
    pub name: String,
    pub split: Split,
    /// Sampling interval of the tracks in seconds; must equal the world's `dt`.
    pub dt: f64,
    /// Index into `agents` of the ego vehicle (the AV a learner drives by default).
    pub ego: usize,
    pub agents: Vec<AgentRecord>,
}

impl Scenario {
    /// Number of recorded steps (the last recorded step of any agent, plus one).
    pub fn recorded_steps(&self) -> u32 {
        self.agents
            .iter()
            .map(|a| a.end_step() + 1)
            .max()
            .unwrap_or(0)
    }
}

/// A versioned collection of scenarios with its provenance: the scenario file format.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScenarioPool {
    /// Must equal [`SCENARIO_FORMAT_VERSION`].
    pub version: u32,
    /// Name of the pool (for example `hbs-paper`).
    pub name: String,
    /// Where the data came from, how it was extracted, and whom to cite.
    pub provenance: String,
    /// How the pool's vehicles that nobody controls move, unless an env asks otherwise
    /// (`CreateEnv.vehicle_model`); absent: `replay`.
    #[serde(default, skip_serializing_if = "is_replay")]
    pub vehicle_model: VehicleModel,
    pub scenarios: Vec<Scenario>,
}

fn is_replay(m: &VehicleModel) -> bool {
    *m == VehicleModel::Replay
}

impl ScenarioPool {
    /// The scenarios of one split, in pool order.
    pub fn split(&self, split: Split) -> impl Iterator<Item = &Scenario> {
        self.scenarios.iter().filter(move |s| s.split == split)
    }
}
