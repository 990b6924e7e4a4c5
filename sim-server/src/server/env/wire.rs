//! The env's translations from sim-core's results to the protocol's messages: agent kinds,
//! outcomes, events, the observation slots and the agents of a reset.

use protocol::{
    AgentDesc, AgentKind as WireKind, Event, EventKind, Outcome, N_FEATURES, PAD_NODE_ID,
};
use sim_core::geometry::Shape;
use sim_core::metrics::EpisodeStatus;
use sim_core::scenario::AgentKind;
use sim_core::world::{AgentId, Event as SimEvent, World};

use super::super::pools::ServedScenario;
use super::Slots;

pub(super) fn to_wire_kind(k: AgentKind) -> WireKind {
    match k {
        AgentKind::Vehicle => WireKind::Vehicle,
        AgentKind::Pedestrian => WireKind::Pedestrian,
    }
}

pub(super) fn outcome_of(s: EpisodeStatus) -> Outcome {
    match s {
        EpisodeStatus::Success => Outcome::Success,
        EpisodeStatus::Collision => Outcome::Collision,
        EpisodeStatus::Timeout => Outcome::Timeout,
    }
}

/// A sim-core event as the protocol's event at `step`, time `t`.
pub(super) fn sim_event(e: &SimEvent, step: u32, t: f64) -> Event {
    match *e {
        SimEvent::Collision { a, b } => event(EventKind::Collision, step, t, vec![a, b]),
        SimEvent::AtFault {
            vehicle,
            pedestrian,
        } => event(EventKind::AtFault, step, t, vec![vehicle, pedestrian]),
        SimEvent::GoalReached { agent } => event(EventKind::GoalReached, step, t, vec![agent]),
        SimEvent::Entered { agent } => event(EventKind::AgentEntered, step, t, vec![agent]),
        SimEvent::Left { agent } => event(EventKind::AgentLeft, step, t, vec![agent]),
    }
}

pub(super) fn event(kind: EventKind, step: u32, t: f64, agents: Vec<u32>) -> Event {
    Event {
        kind,
        step,
        t,
        agents,
        outcome: None,
    }
}

/// Writes the observations of `ext_ids` into the slots (`node_ids` included).
pub(super) fn write_obs(world: &World, ext_ids: &[AgentId], m: usize, s: &mut Slots<'_>) {
    let f = N_FEATURES as usize;
    for (e, &ego) in ext_ids.iter().enumerate() {
        let feats = &mut s.features[e * m * f..(e + 1) * m * f];
        let adj = &mut s.adjacency[e * m * m..(e + 1) * m * m];
        let mask = &mut s.mask[e * m..(e + 1) * m];
        let ids = &mut s.node_ids[e * m..(e + 1) * m];
        // Buffer sizes are right by construction and m >= 1 is checked at creation.
        let _ = world.fill_observation_with_ids(ego, m, (feats, adj, mask), ids, PAD_NODE_ID);
    }
}

/// The `ResetResult::agents` entries of `world`, in id order.
pub(super) fn agent_descs(
    world: &World,
    served: &ServedScenario,
    ext_ids: &[AgentId],
) -> Vec<AgentDesc> {
    let mut agents: Vec<AgentDesc> = world
        .agents()
        .map(|a| {
            let (length, width) = match a.shape {
                Shape::Rect { length, width } => (Some(length), Some(width)),
                Shape::Disc { .. } => (None, None),
            };
            AgentDesc {
                id: a.id,
                name: served.names[a.id as usize].clone(),
                kind: to_wire_kind(a.kind),
                external: ext_ids.contains(&a.id),
                radius: a.shape.bounding_radius(),
                length,
                width,
            }
        })
        .collect();
    agents.sort_by_key(|a| a.id);
    agents
}
