//! Message types. Every struct is a MessagePack map keyed by field name; every enum is its
//! snake_case variant name as a string. See `SPEC.md` for the normative description.
//!
//! One file per kind of message: `envelope.rs` (the reply envelope and error codes' reply),
//! `requests.rs` (requests and their validation), `replies.rs` (replies, batch stacking),
//! `publications.rs` (what envs publish); constants and shared enums here.

use std::fmt;

use serde::{Deserialize, Serialize};

mod envelope;
mod publications;
mod replies;
mod requests;

pub use envelope::*;
pub use publications::*;
pub use replies::*;
pub use requests::*;

// ---------------------------------------------------------------------------------------------
// Constants
// ---------------------------------------------------------------------------------------------

/// Observation node features, in order (model.md section 7; ego frame, x forward): sim-core's
/// list, the one definition.
pub use sim_core::world::observation::FEATURE_NAMES;
/// The reward terms, in order: sim-core's list.
pub use sim_core::world::REWARD_TERM_NAMES;
/// Number of node features `F`.
pub const N_FEATURES: u32 = FEATURE_NAMES.len() as u32;
/// Default observation padding `max_agents` (nodes per observation, ego included).
pub const DEFAULT_MAX_AGENTS: u32 = 8;
/// Action dimension per external agent: `[acc, omega]`.
pub const ACTION_DIM: u32 = 2;
/// Action component names.
pub const ACTION_NAMES: [&str; 2] = ["acc", "omega"];
/// The default external agent list.
pub const DEFAULT_EXTERNAL_AGENT: &str = "vehicle_0";
/// Node id used in `ObsBatch::node_ids` for padding slots.
pub const PAD_NODE_ID: u32 = u32::MAX;
/// Agent kind code of a vehicle in `StatesMsg::kinds`.
pub const KIND_VEHICLE: u8 = 0;
/// Agent kind code of a pedestrian in `StatesMsg::kinds`.
pub const KIND_PEDESTRIAN: u8 = 1;
/// Reward weight names accepted in `CreateEnv::reward_weights` with their defaults
/// (model.md section 7).
pub const REWARD_WEIGHT_DEFAULTS: [(&str, f64); 7] = [
    ("progress", 1.0),
    ("success", 10.0),
    ("collision", -20.0),
    ("danger", 20.0),
    ("danger_clearance", 1.0),
    ("comfort_jerk", 0.05),
    ("comfort_omega", 0.5),
];

// ---------------------------------------------------------------------------------------------
// Enums
// ---------------------------------------------------------------------------------------------

/// Scenario pool split.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// `"train"`
    #[default]
    Train,
    /// `"test"`
    Test,
}

/// Pedestrian model (model.md section 5): sim-core's one list of models, on the wire by name
/// (`"cv"`, `"sfm"`, `"ra_sfm"`, `"cr_sfm"`, `"replay"`; default `cr_sfm`).
pub use sim_core::params::{PedestrianModel, VehicleModel};
pub use sim_core::variation::{PedestrianVariation, Variation, VariationSpec};

/// How an env advances.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// `"lockstep"`: one step per `Step` / `BatchStep` request.
    #[default]
    Lockstep,
    /// `"realtime"`: the server steps on a wall clock; actions arrive as publications.
    Realtime,
}

/// Agent kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AgentKind {
    /// `"vehicle"` (kind code 0)
    Vehicle,
    /// `"pedestrian"` (kind code 1)
    Pedestrian,
}

impl AgentKind {
    /// The `u8` code used in `StatesMsg::kinds`.
    pub fn code(self) -> u8 {
        match self {
            AgentKind::Vehicle => KIND_VEHICLE,
            AgentKind::Pedestrian => KIND_PEDESTRIAN,
        }
    }

    /// Inverse of [`AgentKind::code`].
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            KIND_VEHICLE => Some(AgentKind::Vehicle),
            KIND_PEDESTRIAN => Some(AgentKind::Pedestrian),
            _ => None,
        }
    }
}

/// How an external agent's episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// `"success"`: reached the goal.
    Success,
    /// `"collision"`: collided with a pedestrian.
    Collision,
    /// `"timeout"`: horizon reached.
    Timeout,
}

/// Error codes of [`ErrorReply`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// `"bad_request"`: undecodable payload, invalid field value, unknown scenario/parameter name.
    BadRequest,
    /// `"version_mismatch"`: `protocol_version` differs from the server's.
    VersionMismatch,
    /// `"unknown_env"`: no such env on this server (never created, or reaped).
    UnknownEnv,
    /// `"non_finite_action"`: an action contains NaN or ±inf.
    NonFiniteAction,
    /// `"wrong_shape"`: an array has the wrong shape/dtype, or a batch mixes incompatible envs.
    WrongShape,
    /// `"limit_exceeded"`: capacity, `max_batch`, `max_agents` or another server limit.
    LimitExceeded,
    /// `"env_closed"`: the env was closed (by `Close` or by reaping).
    EnvClosed,
    /// `"needs_reset"`: step before the first reset, or after the episode ended (no autoreset).
    NeedsReset,
    /// `"wrong_mode"`: request not valid in this env's mode (e.g. `Step` on a realtime env).
    WrongMode,
    /// `"internal"`: server bug or unexpected failure.
    Internal,
    /// Any code this version does not know (decoding only; never sent).
    #[serde(other)]
    Unknown,
}

impl ErrorCode {
    /// The snake_case wire string.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::BadRequest => "bad_request",
            ErrorCode::VersionMismatch => "version_mismatch",
            ErrorCode::UnknownEnv => "unknown_env",
            ErrorCode::NonFiniteAction => "non_finite_action",
            ErrorCode::WrongShape => "wrong_shape",
            ErrorCode::LimitExceeded => "limit_exceeded",
            ErrorCode::EnvClosed => "env_closed",
            ErrorCode::NeedsReset => "needs_reset",
            ErrorCode::WrongMode => "wrong_mode",
            ErrorCode::Internal => "internal",
            ErrorCode::Unknown => "unknown",
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Kinds of [`Event`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// `"episode_start"`: after a reset; `agents` = all agents present.
    EpisodeStart,
    /// `"collision"`: two agents overlap; `agents` = the pair.
    Collision,
    /// `"at_fault"`: the collision just listed of an external vehicle and a pedestrian is the
    /// vehicle's fault (model.md 2c); `agents` = `[vehicle, pedestrian]`.
    AtFault,
    /// `"goal_reached"`: an agent reached its goal; `agents` = `[id]`.
    GoalReached,
    /// `"agent_entered"`: an agent entered the scene; `agents` = `[id]`.
    AgentEntered,
    /// `"agent_left"`: an agent left the scene; `agents` = `[id]`.
    AgentLeft,
    /// `"action_clipped"`: an external agent's finite action was out of range; `agents` = `[id]`.
    ActionClipped,
    /// `"episode_end"`: an external agent's episode ended; `agents` = `[id]`, `outcome` set.
    EpisodeEnd,
    /// Any kind this version does not know (decoding only; never sent).
    #[serde(other)]
    Unknown,
}
