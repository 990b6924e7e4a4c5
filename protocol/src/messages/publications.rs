//! Publications (SPEC section 7): what an env publishes on its topics.

use serde::{Deserialize, Serialize};

use crate::array::{F32Array, F64Array, U32Array, U8Array};

use super::{Event, RewardTerms};

/// `{p}/env/{env_id}/states`: every agent's state after a reset or step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatesMsg {
    /// The env.
    pub env_id: String,
    /// Episode counter.
    pub episode: u64,
    /// Step index.
    pub step: u32,
    /// Simulated time, seconds.
    pub t: f64,
    /// `[n]` `<u4` agent ids.
    pub ids: U32Array,
    /// `[n]` `|u1` kinds: 0 vehicle, 1 pedestrian.
    pub kinds: U8Array,
    /// `[n, 2]` `<f8` positions (world frame, m).
    pub positions: F64Array,
    /// `[n, 2]` `<f8` velocities (world frame, m/s).
    pub velocities: F64Array,
    /// `[n]` `<f8` headings (rad, world frame, counter-clockwise from +x).
    pub headings: F64Array,
    /// Scenario of the episode ("" from senders older than this field).
    #[serde(default)]
    pub scenario: String,
    /// `[n, 2]` `<f8` footprints (length, width) in m, length along the heading; a disc's is
    /// (2 r, 2 r).
    #[serde(default)]
    pub sizes: Option<F64Array>,
    /// `[n, 2]` `<f8` goals (world frame, m).
    #[serde(default)]
    pub goals: Option<F64Array>,
    /// `[n]` `|u1`: 1 for an agent a learner controls (external), else 0.
    #[serde(default)]
    pub external: Option<U8Array>,
    /// The reward of the step that led to this state, per external agent (nil after a reset).
    #[serde(default)]
    pub rewards: Option<StateRewards>,
    /// `[n]` `|u1`: 1 for a vehicle that a reactive vehicle model moves (docs/MODEL.md
    /// "Traffic"), else 0; nil when the episode has none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reactive: Option<U8Array>,
}

/// [`StatesMsg::rewards`]: the last step's reward of each external agent, for watching.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateRewards {
    /// `[n_ext]` `<u4` agent ids of the external agents.
    pub agents: U32Array,
    /// `[n_ext]` `<f4` reward of the step.
    pub reward: F32Array,
    /// Its terms (`[n_ext]` each).
    pub terms: RewardTerms,
    /// `[n_ext]` `<f8` return of the episode so far (sum of the rewards, undiscounted).
    pub returns: F64Array,
}

/// `{p}/env/{env_id}/uncertainty`: cognitive uncertainty `u(i, j)` as a COO edge list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UncertaintyMsg {
    /// The env.
    pub env_id: String,
    /// Episode counter.
    pub episode: u64,
    /// Step index.
    pub step: u32,
    /// Simulated time, seconds.
    pub t: f64,
    /// `[E]` `<u4` observer agent ids `i`.
    pub src: U32Array,
    /// `[E]` `<u4` observed agent ids `j`.
    pub dst: U32Array,
    /// `[E]` `<f8` `u(i, j)` (KL divergence, nats).
    pub u: F64Array,
}

/// `{p}/env/{env_id}/risk_graph`: the risk graph as a COO edge list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RiskGraphMsg {
    /// The env.
    pub env_id: String,
    /// Episode counter.
    pub episode: u64,
    /// Step index.
    pub step: u32,
    /// Simulated time, seconds.
    pub t: f64,
    /// The `lambda` used in `a = psi * (1 + lambda * u)`.
    pub lambda: f64,
    /// `[E]` `<u4` observer agent ids `i`.
    pub src: U32Array,
    /// `[E]` `<u4` interacting agent ids `j`.
    pub dst: U32Array,
    /// `[E]` `<f8` physical risk `psi(i, j)` in (0, 1].
    pub psi: F64Array,
    /// `[E]` `<f8` uncertainty `u(i, j)`.
    pub u: F64Array,
    /// `[E]` `<f8` adjacency weight `A[i][j]`.
    pub a: F64Array,
}

/// `{p}/env/{env_id}/events`: the events of one reset or step (published only when non-empty).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EventsMsg {
    /// The env.
    pub env_id: String,
    /// Episode counter.
    pub episode: u64,
    /// Step index.
    pub step: u32,
    /// Simulated time, seconds.
    pub t: f64,
    /// The events.
    pub events: Vec<Event>,
}
