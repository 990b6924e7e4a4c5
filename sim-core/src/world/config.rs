//! Which agents are external and what moves each of the others ([`EpisodeConfig`],
//! [`Control`]).

use crate::params::{PedestrianModel, VehicleModel};
use crate::scenario::{AgentKind, Scenario};

use super::AgentId;

/// What moves an agent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    /// Driven by actions sent to [`World::step`].
    External,
    /// Follows its recorded track.
    Replay,
    /// A simulated pedestrian.
    Model(PedestrianModel),
    /// A vehicle nobody controls, moved by a reactive vehicle model (never
    /// [`VehicleModel::Replay`], which is [`Control::Replay`]).
    Vehicle(VehicleModel),
}

/// Which agents are external and which model moves the others.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeConfig {
    /// Model of every pedestrian that is neither external, non-reactive nor overridden.
    pub pedestrian_model: PedestrianModel,
    /// Per-agent model overrides.
    pub model_overrides: Vec<(AgentId, PedestrianModel)>,
    /// Agents driven by actions.
    pub external: Vec<AgentId>,
    /// Model of every vehicle that is neither external, non-reactive nor overridden.
    pub vehicle_model: VehicleModel,
    /// Per-agent vehicle model overrides.
    pub vehicle_overrides: Vec<(AgentId, VehicleModel)>,
}

impl EpisodeConfig {
    /// The paper's set-up: the scenario's ego vehicle is external, pedestrians use `model`.
    pub fn ego_external(scenario: &Scenario, model: PedestrianModel) -> Self {
        Self {
            pedestrian_model: model,
            model_overrides: Vec::new(),
            external: vec![scenario.ego as AgentId],
            vehicle_model: VehicleModel::Replay,
            vehicle_overrides: Vec::new(),
        }
    }

    /// Pedestrian-model evaluation (model.md 9): nobody is external, the vehicles replay.
    pub fn replay_vehicles(model: PedestrianModel) -> Self {
        Self {
            pedestrian_model: model,
            model_overrides: Vec::new(),
            external: Vec::new(),
            vehicle_model: VehicleModel::Replay,
            vehicle_overrides: Vec::new(),
        }
    }
}

impl EpisodeConfig {
    /// What moves each agent of `scenario`, by agent index, before the external agents are
    /// marked ([`World::new`](super::World::new) marks them).
    pub(super) fn controls(&self, scenario: &Scenario) -> Vec<Control> {
        scenario
            .agents
            .iter()
            .enumerate()
            .map(|(k, a)| match a.kind {
                // A vehicle's model is the episode's: `non_reactive` is a pedestrian's mark (the
                // HBS extraction marks every other car with it, as replayed by default).
                AgentKind::Vehicle => {
                    match last_override(&self.vehicle_overrides, k).unwrap_or(self.vehicle_model) {
                        VehicleModel::Replay => Control::Replay,
                        m => Control::Vehicle(m),
                    }
                }
                AgentKind::Pedestrian if a.non_reactive => Control::Replay,
                AgentKind::Pedestrian => {
                    match last_override(&self.model_overrides, k).unwrap_or(self.pedestrian_model) {
                        PedestrianModel::Replay => Control::Replay,
                        m => Control::Model(m),
                    }
                }
            })
            .collect()
    }
}

/// The last override for agent `k`, if any (a later entry wins).
fn last_override<M: Copy>(overrides: &[(AgentId, M)], k: usize) -> Option<M> {
    overrides
        .iter()
        .rev()
        .find(|(id, _)| *id as usize == k)
        .map(|&(_, m)| m)
}
