//! Message types. Every struct is a MessagePack map keyed by field name; every enum is its
//! snake_case variant name as a string. See `SPEC.md` for the normative description.

use std::collections::BTreeMap;
use std::fmt;

use serde::de::{self, DeserializeOwned, Deserializer, MapAccess, Visitor};
use serde::ser::{SerializeMap, Serializer};
use serde::{Deserialize, Serialize};

use crate::array::{
    ArrayError, F32Array, F64Array, FloatArray, NdArray, U32Array, U64Array, U8Array,
};
use crate::keys;
use crate::PROTOCOL_VERSION;

// ---------------------------------------------------------------------------------------------
// Constants
// ---------------------------------------------------------------------------------------------

/// Observation node features, in order (model.md section 7; ego frame, x forward): sim-core's
/// list, the one definition.
pub use sim_core::observation::FEATURE_NAMES;
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

// ---------------------------------------------------------------------------------------------
// Reply envelope
// ---------------------------------------------------------------------------------------------

/// An error reply: `{"code": ErrorCode, "message": str, "env_id": str | nil}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorReply {
    /// Machine-readable code.
    pub code: ErrorCode,
    /// Human-readable explanation (names the offending field / env / value).
    pub message: String,
    /// The env concerned, when there is one (always set for batch errors about one env).
    #[serde(default)]
    pub env_id: Option<String>,
}

impl ErrorReply {
    /// An error without env.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
            env_id: None,
        }
    }

    /// Sets the env concerned.
    pub fn with_env(mut self, env_id: impl Into<String>) -> Self {
        self.env_id = Some(env_id.into());
        self
    }
}

impl fmt::Display for ErrorReply {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.env_id {
            Some(env) => write!(f, "{} (env {env}): {}", self.code, self.message),
            None => write!(f, "{}: {}", self.code, self.message),
        }
    }
}

impl std::error::Error for ErrorReply {}

impl From<crate::ProtocolError> for ErrorReply {
    fn from(e: crate::ProtocolError) -> Self {
        let code = match &e {
            crate::ProtocolError::VersionMismatch { .. } => ErrorCode::VersionMismatch,
            crate::ProtocolError::Array(_) => ErrorCode::WrongShape,
            crate::ProtocolError::Encode { .. } => ErrorCode::Internal,
            _ => ErrorCode::BadRequest,
        };
        ErrorReply::new(code, e.to_string())
    }
}

/// The reply to every query: a map with exactly one key, `"ok"` (the result) or `"error"`
/// (an [`ErrorReply`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Reply<T> {
    /// `{"ok": T}`
    Ok(T),
    /// `{"error": ErrorReply}`
    Err(ErrorReply),
}

impl<T> Reply<T> {
    /// Converts into a `Result`.
    pub fn into_result(self) -> Result<T, ErrorReply> {
        match self {
            Reply::Ok(v) => Ok(v),
            Reply::Err(e) => Err(e),
        }
    }

    /// An error reply.
    pub fn error(code: ErrorCode, message: impl Into<String>) -> Self {
        Reply::Err(ErrorReply::new(code, message))
    }
}

impl<T> From<Result<T, ErrorReply>> for Reply<T> {
    fn from(r: Result<T, ErrorReply>) -> Self {
        match r {
            Ok(v) => Reply::Ok(v),
            Err(e) => Reply::Err(e),
        }
    }
}

impl<T: Serialize> Serialize for Reply<T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut m = serializer.serialize_map(Some(1))?;
        match self {
            Reply::Ok(v) => m.serialize_entry("ok", v)?,
            Reply::Err(e) => m.serialize_entry("error", e)?,
        }
        m.end()
    }
}

impl<'de, T: DeserializeOwned> Deserialize<'de> for Reply<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: DeserializeOwned> Visitor<'de> for V<T> {
            type Value = Reply<T>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a reply map with exactly one of the keys \"ok\" or \"error\"")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Reply<T>, A::Error> {
                let mut out: Option<Reply<T>> = None;
                while let Some(key) = map.next_key::<String>()? {
                    let value = match key.as_str() {
                        "ok" => Reply::Ok(map.next_value::<T>()?),
                        "error" => Reply::Err(map.next_value::<ErrorReply>()?),
                        _ => {
                            map.next_value::<de::IgnoredAny>()?;
                            continue;
                        }
                    };
                    if out.is_some() {
                        return Err(de::Error::custom(
                            "reply has both/duplicate \"ok\" and \"error\" keys",
                        ));
                    }
                    out = Some(value);
                }
                out.ok_or_else(|| de::Error::custom("reply has neither \"ok\" nor \"error\" key"))
            }
        }
        deserializer.deserialize_map(V(std::marker::PhantomData))
    }
}

// ---------------------------------------------------------------------------------------------
// Requests
// ---------------------------------------------------------------------------------------------

fn default_count() -> u32 {
    1
}
fn default_external_agents() -> Vec<String> {
    vec![DEFAULT_EXTERNAL_AGENT.to_string()]
}
fn default_max_agents() -> u32 {
    DEFAULT_MAX_AGENTS
}
fn default_realtime_factor() -> f64 {
    1.0
}

/// Errors with `version_mismatch` unless `v == PROTOCOL_VERSION`.
pub fn check_version(v: u32) -> Result<(), ErrorReply> {
    if v == PROTOCOL_VERSION {
        Ok(())
    } else {
        Err(ErrorReply::new(
            ErrorCode::VersionMismatch,
            format!("server speaks protocol version {PROTOCOL_VERSION}, request has {v}"),
        ))
    }
}

/// Request on `{p}/server/{server_id}/env/create`: create `count` envs with one configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CreateEnv {
    /// Must equal [`PROTOCOL_VERSION`].
    pub protocol_version: u32,
    /// The trainer's client id; its liveliness token is `{p}/trainer/{client_id}`.
    pub client_id: String,
    /// Number of envs K (default 1).
    #[serde(default = "default_count")]
    pub count: u32,
    /// Scenario pool name (nil: the server's default pool, the first of `ServerInfo::pools`).
    #[serde(default)]
    pub pool: Option<String>,
    /// Scenario pool split (default train).
    #[serde(default)]
    pub split: Split,
    /// Base seed; env k of this request uses `seed + k` (wrapping).
    #[serde(default)]
    pub seed: u64,
    /// Pedestrian model (default cr_sfm).
    #[serde(default)]
    pub pedestrian_model: PedestrianModel,
    /// Pedestrian/model parameter overrides by name (empty = defaults).
    #[serde(default)]
    pub pedestrian_params: BTreeMap<String, f64>,
    /// Externally controlled agents, in action order (default `["vehicle_0"]`).
    #[serde(default = "default_external_agents")]
    pub external_agents: Vec<String>,
    /// Reward weight overrides by name (see [`REWARD_WEIGHT_DEFAULTS`]).
    #[serde(default)]
    pub reward_weights: BTreeMap<String, f64>,
    /// Lockstep or realtime (default lockstep).
    #[serde(default)]
    pub mode: Mode,
    /// Observation padding: nodes per observation, ego included (default 8).
    #[serde(default = "default_max_agents")]
    pub max_agents: u32,
    /// Pin every episode to this scenario name (default: drawn from the split's pool).
    #[serde(default)]
    pub scenario: Option<String>,
    /// Reset automatically when an episode ends (default false).
    #[serde(default)]
    pub autoreset: bool,
    /// Realtime mode: simulated seconds per wall-clock second (default 1.0).
    #[serde(default = "default_realtime_factor")]
    pub realtime_factor: f64,
    /// Generated scenes instead of a pool (nil: draw from `pool`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub synthetic: Option<SyntheticScenes>,
    /// Seeded scene variations, one drawn per episode (nil: the pool entry's, if it has
    /// one, else none; SPEC 5.3).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variations: Option<VariationSpec>,
    /// How the vehicles nobody controls move: `replay` or `idm` (docs/MODEL.md "Traffic"; nil:
    /// the pool's, `replay` unless the pool says otherwise; `hbs-general` says `idm`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vehicle_model: Option<VehicleModel>,
}

/// `CreateEnv.synthetic`: the envs play `scenes` generated scenes (seeds `seed`,
/// `seed + 1`, ...; the scenarios crate's `synthetic` module) in the requested split, instead of
/// a pool's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyntheticScenes {
    /// `"crossing"` (pedestrians cross the vehicles' path), `"counter_flow"` (they walk towards
    /// the ego) or `"random"` (any direction).
    pub layout: String,
    /// Pedestrians per scene.
    pub pedestrians: u32,
    /// Vehicles per scene: the ego drives +x through the crowd, the others on parallel lanes
    /// 4 m apart, alternately oncoming.
    pub vehicles: u32,
    /// Pedestrians per square metre of the crowd's square.
    pub density: f64,
    /// Seed of the first scene.
    pub seed: u64,
    /// Number of scenes.
    pub scenes: u32,
}

impl Default for SyntheticScenes {
    fn default() -> Self {
        Self {
            layout: "crossing".into(),
            pedestrians: 10,
            vehicles: 1,
            density: 0.25,
            seed: 0,
            scenes: 1,
        }
    }
}

impl CreateEnv {
    /// A request with every optional field at its default.
    pub fn new(client_id: impl Into<String>) -> Self {
        Self {
            protocol_version: PROTOCOL_VERSION,
            client_id: client_id.into(),
            count: default_count(),
            pool: None,
            split: Split::default(),
            seed: 0,
            pedestrian_model: PedestrianModel::default(),
            pedestrian_params: BTreeMap::new(),
            external_agents: default_external_agents(),
            reward_weights: BTreeMap::new(),
            mode: Mode::default(),
            max_agents: default_max_agents(),
            scenario: None,
            autoreset: false,
            realtime_factor: default_realtime_factor(),
            synthetic: None,
            variations: None,
            vehicle_model: None,
        }
    }

    /// Server-independent checks: version, client id and agent names are valid key segments,
    /// agent names unique and non-empty list, `count >= 1`, `max_agents >= 1`, parameters and
    /// weights finite with known reward-weight names, `realtime_factor` finite and > 0.
    /// Server limits (capacity, max_agents, scenario names, parameter names) are the server's.
    pub fn validate(&self) -> Result<(), ErrorReply> {
        check_version(self.protocol_version)?;
        let bad = |m: String| Err(ErrorReply::new(ErrorCode::BadRequest, m));
        if let Err(e) = keys::validate_client_id(&self.client_id) {
            return bad(e.to_string());
        }
        if self.count == 0 {
            return bad("count must be >= 1".into());
        }
        if self.max_agents == 0 {
            return bad("max_agents must be >= 1".into());
        }
        if self.external_agents.is_empty() {
            return bad("external_agents must not be empty".into());
        }
        for (i, a) in self.external_agents.iter().enumerate() {
            if let Err(e) = keys::validate_agent_name(a) {
                return bad(e.to_string());
            }
            if self.external_agents[..i].contains(a) {
                return bad(format!("external agent {a:?} listed twice"));
            }
        }
        for (k, v) in &self.pedestrian_params {
            if !v.is_finite() {
                return bad(format!("pedestrian_params.{k} is not finite"));
            }
        }
        for (k, v) in &self.reward_weights {
            if !REWARD_WEIGHT_DEFAULTS.iter().any(|(n, _)| n == k) {
                let names: Vec<&str> = REWARD_WEIGHT_DEFAULTS.iter().map(|(n, _)| *n).collect();
                return bad(format!(
                    "unknown reward weight {k:?}; known: {}",
                    names.join(", ")
                ));
            }
            if !v.is_finite() {
                return bad(format!("reward_weights.{k} is not finite"));
            }
        }
        if !(self.realtime_factor.is_finite() && self.realtime_factor > 0.0) {
            return bad("realtime_factor must be finite and > 0".into());
        }
        if self.scenario.as_deref() == Some("") {
            return bad("scenario must not be empty".into());
        }
        if self.pool.as_deref() == Some("") {
            return bad("pool must not be empty".into());
        }
        if let Some(v) = &self.variations {
            v.validate()
                .map_err(|e| ErrorReply::new(ErrorCode::BadRequest, e.to_string()))?;
        }
        Ok(())
    }

    /// The effective reward weights: defaults overridden by `reward_weights`.
    pub fn effective_reward_weights(&self) -> BTreeMap<String, f64> {
        REWARD_WEIGHT_DEFAULTS
            .iter()
            .map(|(k, v)| {
                (
                    (*k).to_string(),
                    self.reward_weights.get(*k).copied().unwrap_or(*v),
                )
            })
            .collect()
    }
}

/// Request on `{p}/server/{server_id}/env/{env_id}/reset`. An empty payload equals `{}`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Reset {
    /// Reseed the env's generator before drawing the episode (nil: continue the stream).
    #[serde(default)]
    pub seed: Option<u64>,
    /// Use this scenario for this episode (nil: the env's pinned scenario or a draw).
    #[serde(default)]
    pub scenario: Option<String>,
    /// Play the variation of this seed in this episode (nil: the env's next draw); only for an
    /// env with variations. It does not advance the env's own stream of variation seeds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variation: Option<u64>,
}

/// Validates an action array of shape `[.., n_agents, 2]` with the given leading dims and
/// returns the values as `f64` row-major.
fn check_actions(
    actions: &FloatArray,
    expected: &[Option<u32>],
    what: &str,
) -> Result<Vec<f64>, ErrorReply> {
    if let Err(e) = actions.check_shape(expected) {
        return Err(ErrorReply::new(
            ErrorCode::WrongShape,
            format!("{what}: {e}"),
        ));
    }
    let values = actions.to_f64_vec();
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(ErrorReply::new(
            ErrorCode::NonFiniteAction,
            format!("{what}: element {i} (row-major) is {}", values[i]),
        ));
    }
    Ok(values)
}

/// Request on `{p}/server/{server_id}/env/{env_id}/step` (lockstep mode).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Step {
    /// `[n_ext, 2]`, `<f4` or `<f8`, normalised actions in `[-1, 1]`, rows in
    /// external-agent order.
    pub actions: FloatArray,
}

impl Step {
    /// A step request from `[acc, omega]` rows.
    pub fn from_rows(rows: &[[f32; 2]]) -> Self {
        let flat: Vec<f32> = rows.iter().flatten().copied().collect();
        let n = u32::try_from(rows.len()).expect("too many rows");
        Self {
            actions: F32Array::new(vec![n, ACTION_DIM], &flat)
                .expect("shape matches")
                .into(),
        }
    }

    /// Checks shape `[n_agents, 2]` (`wrong_shape`) and finiteness (`non_finite_action`);
    /// returns the rows as `f64`.
    pub fn checked_actions(&self, n_agents: u32) -> Result<Vec<[f64; 2]>, ErrorReply> {
        let v = check_actions(
            &self.actions,
            &[Some(n_agents), Some(ACTION_DIM)],
            "actions",
        )?;
        Ok(v.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
    }
}

/// Request on `{p}/server/{server_id}/batch/step`: one lockstep step of K envs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchStep {
    /// K env ids, distinct, all on this server, all with the same `n_ext` and `max_agents`.
    pub env_ids: Vec<String>,
    /// `[K, n_ext, 2]`, `<f4` or `<f8`, normalised actions in `[-1, 1]`.
    pub actions: FloatArray,
}

impl BatchStep {
    /// Checks shape `[K, n_agents, 2]` with `K = env_ids.len()` (`wrong_shape`), distinct env
    /// ids (`bad_request`) and finiteness (`non_finite_action`, naming the env); returns per
    /// env its rows as `f64`.
    pub fn checked_actions(&self, n_agents: u32) -> Result<Vec<Vec<[f64; 2]>>, ErrorReply> {
        let mut seen = std::collections::HashSet::with_capacity(self.env_ids.len());
        for id in &self.env_ids {
            if !seen.insert(id.as_str()) {
                return Err(ErrorReply::new(
                    ErrorCode::BadRequest,
                    format!("env id {id:?} listed twice in batch"),
                )
                .with_env(id.clone()));
            }
        }
        let rows = self.checked_action_rows(n_agents)?;
        if n_agents == 0 {
            return Ok(vec![Vec::new(); self.env_ids.len()]);
        }
        Ok(rows
            .chunks(n_agents as usize)
            .map(<[[f64; 2]]>::to_vec)
            .collect())
    }

    /// [`BatchStep::checked_actions`] without the check for distinct env ids (for callers that
    /// check that themselves): the `K * n_agents` rows, env by env, in one vector.
    pub fn checked_action_rows(&self, n_agents: u32) -> Result<Vec<[f64; 2]>, ErrorReply> {
        let k = u32::try_from(self.env_ids.len())
            .map_err(|_| ErrorReply::new(ErrorCode::LimitExceeded, "too many env ids in batch"))?;
        if let Err(e) = self
            .actions
            .check_shape(&[Some(k), Some(n_agents), Some(ACTION_DIM)])
        {
            return Err(ErrorReply::new(
                ErrorCode::WrongShape,
                format!("actions: {e}"),
            ));
        }
        let values = self.actions.to_f64_vec();
        let per_env = (n_agents * ACTION_DIM) as usize;
        for (env, chunk) in self.env_ids.iter().zip(values.chunks(per_env.max(1))) {
            if let Some(i) = chunk.iter().position(|v| !v.is_finite()) {
                return Err(ErrorReply::new(
                    ErrorCode::NonFiniteAction,
                    format!(
                        "actions for env {env}: agent {} component {} is {}",
                        i / 2,
                        i % 2,
                        chunk[i]
                    ),
                )
                .with_env(env.clone()));
            }
        }
        Ok(values.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
    }
}

/// Request on `{p}/server/{server_id}/env/{env_id}/close`. An empty payload equals `{}`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Close {}

/// Request on `{p}/server/{server_id}/info`. An empty payload equals `{}`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct InfoRequest {
    /// The client's protocol version (informational; info is answered for any version).
    #[serde(default)]
    pub protocol_version: Option<u32>,
}

/// Realtime-mode action, published on `{p}/env/{env_id}/action/{agent_name}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActionMsg {
    /// `[2]`, `<f4` or `<f8`: normalised `[acc, omega]` in `[-1, 1]`.
    pub action: FloatArray,
    /// Sender's sequence number (increasing); the server ignores an action older than the
    /// last one it applied for this agent.
    #[serde(default)]
    pub seq: u64,
}

impl ActionMsg {
    /// Checks shape `[2]` and finiteness.
    pub fn checked_action(&self) -> Result<[f64; 2], ErrorReply> {
        let v = check_actions(&self.action, &[Some(ACTION_DIM)], "action")?;
        Ok([v[0], v[1]])
    }
}

// ---------------------------------------------------------------------------------------------
// Replies
// ---------------------------------------------------------------------------------------------

/// Observation layout, in `EnvCreated`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObsLayout {
    /// Nodes per observation `M` (ego node 0 included).
    pub max_agents: u32,
    /// Features per node `F` (11).
    pub n_features: u32,
    /// Feature names, length `F` (see [`FEATURE_NAMES`]).
    pub feature_names: Vec<String>,
}

impl ObsLayout {
    /// The standard layout with `max_agents` nodes.
    pub fn standard(max_agents: u32) -> Self {
        Self {
            max_agents,
            n_features: N_FEATURES,
            feature_names: FEATURE_NAMES.iter().map(|s| (*s).to_string()).collect(),
        }
    }
}

/// Action space of one external agent, in `EnvCreated`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActionSpace {
    /// Component names: `["acc", "omega"]`.
    pub names: Vec<String>,
    /// Normalised lower bounds (`[-1, -1]`).
    pub low: Vec<f64>,
    /// Normalised upper bounds (`[1, 1]`).
    pub high: Vec<f64>,
    /// Physical value at `low` (`[-2.0 m/s², -0.2 rad/s]` by default).
    pub physical_low: Vec<f64>,
    /// Physical value at `high` (`[2.0 m/s², 0.2 rad/s]` by default).
    pub physical_high: Vec<f64>,
    /// Physical units: `["m/s^2", "rad/s"]`.
    pub units: Vec<String>,
}

impl ActionSpace {
    /// The normalised `[-1, 1]²` space mapped onto the given physical limits.
    pub fn normalised(acc_max: f64, omega_max: f64) -> Self {
        Self {
            names: ACTION_NAMES.iter().map(|s| (*s).to_string()).collect(),
            low: vec![-1.0, -1.0],
            high: vec![1.0, 1.0],
            physical_low: vec![-acc_max, -omega_max],
            physical_high: vec![acc_max, omega_max],
            units: vec!["m/s^2".to_string(), "rad/s".to_string()],
        }
    }
}

impl Default for ActionSpace {
    fn default() -> Self {
        Self::normalised(2.0, 0.2)
    }
}

/// Reply to `CreateEnv`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvCreated {
    /// K new env ids (`{server_id}-{counter}`), in order; env k uses seed `seed + k`.
    pub env_ids: Vec<String>,
    /// External agent names in action / observation order.
    pub external_agents: Vec<String>,
    /// Observation layout.
    pub observation: ObsLayout,
    /// Action space of each external agent.
    pub action: ActionSpace,
    /// Simulation step in seconds.
    pub dt: f64,
    /// Echo of the request's mode.
    pub mode: Mode,
    /// Echo of the request's split.
    pub split: Split,
    /// Echo of the request's pedestrian model.
    pub pedestrian_model: PedestrianModel,
    /// Echo of the request's autoreset.
    pub autoreset: bool,
}

/// One agent of an episode, in `ResetResult`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentDesc {
    /// Agent id, unique within the episode, used in publications and `node_ids`.
    pub id: u32,
    /// Name: `vehicle_{k}` or `pedestrian_{k}`.
    pub name: String,
    /// Kind.
    pub kind: AgentKind,
    /// Whether a learner controls it.
    pub external: bool,
    /// Footprint radius in m (disc radius; for a rectangle, half its diagonal).
    pub radius: f64,
    /// Rectangle footprint length in m (nil for a disc).
    #[serde(default)]
    pub length: Option<f64>,
    /// Rectangle footprint width in m (nil for a disc).
    #[serde(default)]
    pub width: Option<f64>,
}

/// Observations of the external agents.
///
/// Shapes below are for one env; in `BatchStepResult` every array has an extra leading K axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObsBatch {
    /// `[n_ext, M, F]` `<f4`: node features (see [`FEATURE_NAMES`]); padding rows are 0.
    pub features: F32Array,
    /// `[n_ext, M, M]` `<f4`: `A` restricted to the included nodes; zero diagonal and padding.
    pub adjacency: F32Array,
    /// `[n_ext, M]` `|u1`: 1 for a present node, 0 for padding.
    pub mask: U8Array,
    /// `[n_ext, M]` `<u4`: agent id of each node, [`PAD_NODE_ID`] for padding.
    pub node_ids: U32Array,
}

impl ObsBatch {
    /// All-padding observations (every node absent).
    pub fn empty(n_ext: u32, max_agents: u32) -> Result<Self, ArrayError> {
        let n = crate::array::shape_len(&[n_ext, max_agents])?;
        Ok(Self {
            features: F32Array::zeros(vec![n_ext, max_agents, N_FEATURES])?,
            adjacency: F32Array::zeros(vec![n_ext, max_agents, max_agents])?,
            mask: U8Array::zeros(vec![n_ext, max_agents])?,
            node_ids: U32Array::new(vec![n_ext, max_agents], &vec![PAD_NODE_ID; n])?,
        })
    }

    /// Checks that the shapes are consistent with `n_ext` agents and `max_agents` nodes
    /// (optionally after a leading `k` axis).
    pub fn check(&self, k: Option<u32>, n_ext: u32, max_agents: u32) -> Result<(), ArrayError> {
        let lead: Vec<Option<u32>> = k.into_iter().map(Some).collect();
        let with = |rest: &[u32]| -> Vec<Option<u32>> {
            lead.iter()
                .copied()
                .chain(rest.iter().map(|&d| Some(d)))
                .collect()
        };
        self.features
            .check_shape(&with(&[n_ext, max_agents, N_FEATURES]))?;
        self.adjacency
            .check_shape(&with(&[n_ext, max_agents, max_agents]))?;
        self.mask.check_shape(&with(&[n_ext, max_agents]))?;
        self.node_ids.check_shape(&with(&[n_ext, max_agents]))?;
        Ok(())
    }

    /// Stacks per-env observations along a new leading K axis.
    pub fn stack(parts: &[ObsBatch]) -> Result<Self, ArrayError> {
        let f: Vec<F32Array> = parts.iter().map(|p| p.features.clone()).collect();
        let a: Vec<F32Array> = parts.iter().map(|p| p.adjacency.clone()).collect();
        let m: Vec<U8Array> = parts.iter().map(|p| p.mask.clone()).collect();
        let n: Vec<U32Array> = parts.iter().map(|p| p.node_ids.clone()).collect();
        Ok(Self {
            features: F32Array::stack(&f)?,
            adjacency: F32Array::stack(&a)?,
            mask: U8Array::stack(&m)?,
            node_ids: U32Array::stack(&n)?,
        })
    }
}

/// Reply to `Reset` (and, with autoreset, the `reset` field of a step result).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResetResult {
    /// The env.
    pub env_id: String,
    /// Episode counter of this env: 1 for the first episode, +1 per reset.
    pub episode: u64,
    /// Scenario name.
    pub scenario: String,
    /// Step index (always 0).
    pub step: u32,
    /// Simulated time in seconds (always 0.0).
    pub t: f64,
    /// Steps until truncation (horizon / dt).
    pub horizon_steps: u32,
    /// Every agent of the episode at its start.
    pub agents: Vec<AgentDesc>,
    /// First observations.
    pub obs: ObsBatch,
    /// The scene variation of this episode: its seed and every value applied (absent for an
    /// env without variations).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variation: Option<Variation>,
}

/// Reward decomposition; each array is `[n_ext]` `<f4` (`[K, n_ext]` in a batch) and
/// `reward = progress + success + collision + danger + comfort` (weights applied).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RewardTerms {
    /// `w_progress * (d_goal(t-1) - d_goal(t))`.
    pub progress: F32Array,
    /// `w_success` on the success step, else 0.
    pub success: F32Array,
    /// `w_collision` (negative) on the collision step, else 0.
    pub collision: F32Array,
    /// `w_danger * (c_min - danger_clearance)` when `c_min < danger_clearance`, else 0.
    pub danger: F32Array,
    /// `-(w_comfort_jerk * jerk² + w_comfort_omega * omega²)`.
    pub comfort: F32Array,
}

impl RewardTerms {
    /// Stacks along a new leading K axis.
    pub fn stack(parts: &[RewardTerms]) -> Result<Self, ArrayError> {
        let s = |f: fn(&RewardTerms) -> &F32Array| -> Result<F32Array, ArrayError> {
            F32Array::stack(&parts.iter().map(|p| f(p).clone()).collect::<Vec<_>>())
        };
        Ok(Self {
            progress: s(|p| &p.progress)?,
            success: s(|p| &p.success)?,
            collision: s(|p| &p.collision)?,
            danger: s(|p| &p.danger)?,
            comfort: s(|p| &p.comfort)?,
        })
    }
}

/// Something that happened during a step (also published on `{p}/env/{env_id}/events`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// What happened.
    pub kind: EventKind,
    /// Step index at which it is observed (state `t + 1` of the transition).
    pub step: u32,
    /// Simulated time in seconds.
    pub t: f64,
    /// Agent ids involved.
    pub agents: Vec<u32>,
    /// For `episode_end`: the outcome; nil otherwise.
    #[serde(default)]
    pub outcome: Option<Outcome>,
}

/// Per-episode metrics of one external agent (model.md section 7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeMetrics {
    /// External agent name.
    pub agent: String,
    /// How it ended.
    pub outcome: Outcome,
    /// Steps taken.
    pub steps: u32,
    /// Simulated duration in seconds.
    pub duration: f64,
    /// Sum of rewards.
    pub episode_return: f64,
    /// Mean speed in m/s.
    pub avg_speed: f64,
    /// Mean `|acc_t - acc_{t-1}| / dt` in m/s³.
    pub avg_abs_jerk: f64,
    /// Maximum `|acc|` in m/s².
    pub max_abs_acc: f64,
}

/// Step details.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepInfo {
    /// `[n_ext]`: whether each agent's action was clipped into range.
    pub action_clipped: Vec<bool>,
    /// Events of this step.
    pub events: Vec<Event>,
    /// Metrics of the agents whose episode ended at this step (empty otherwise).
    pub metrics: Vec<EpisodeMetrics>,
}

/// Reply to `Step` (and the realtime `{p}/env/{env_id}/result` publication).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepResult {
    /// The env.
    pub env_id: String,
    /// Episode counter (as in `ResetResult`).
    pub episode: u64,
    /// Scenario name.
    pub scenario: String,
    /// Step index after the transition (1 after the first step).
    pub step: u32,
    /// Simulated time after the transition, seconds (`step * dt`).
    pub t: f64,
    /// Observations at the new state.
    pub obs: ObsBatch,
    /// `[n_ext]` `<f4`: reward of the transition.
    pub reward: F32Array,
    /// Decomposition of `reward`.
    pub reward_terms: RewardTerms,
    /// `[n_ext]` `|u1`: 1 if the agent's episode ended by success or collision.
    pub terminated: U8Array,
    /// `[n_ext]` `|u1`: 1 if the agent's episode was cut by the horizon.
    pub truncated: U8Array,
    /// Details.
    pub info: StepInfo,
    /// With autoreset, when this step ended the episode: the new episode's reset result.
    #[serde(default)]
    pub reset: Option<ResetResult>,
}

/// An event of one env of a batch (`BatchStepResult::events`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchEvent {
    /// Position of the env in `env_ids`.
    pub index: u32,
    /// The event, as in `StepInfo::events`.
    pub event: Event,
}

/// The metrics of one ended episode of a batch (`BatchStepResult::metrics`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchMetrics {
    /// Position of the env in `env_ids`.
    pub index: u32,
    /// As in `StepInfo::metrics`.
    pub metrics: EpisodeMetrics,
}

/// The autoresets of a batch step, stacked along a leading axis R (the envs whose episode ended
/// at this step and restarted), in `env_ids` order. Each entry holds the fields of that env's
/// `ResetResult` (`env_id` is `env_ids[index]`; `step` and `t` are 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchResets {
    /// `[R]` `<u4`: positions of the reset envs in `env_ids`, increasing.
    pub index: U32Array,
    /// `[R]` `<u8`: the new episodes' counters.
    pub episode: U64Array,
    /// R scenario names.
    pub scenario: Vec<String>,
    /// `[R]` `<u4`: steps until truncation of each new episode.
    pub horizon_steps: U32Array,
    /// R lists: every agent of each new episode at its start.
    pub agents: Vec<Vec<AgentDesc>>,
    /// The new episodes' first observations, shapes `[R, n_ext, M, F]` etc.
    pub obs: ObsBatch,
    /// R variation seeds (nil for an env without variations; `Reset.variation` replays one);
    /// absent when no reset env has variations.
    #[serde(default, skip_serializing_if = "no_variation")]
    pub variation: Vec<Option<u64>>,
}

/// Whether no entry of a `BatchResets::variation` column is set (the column is then left out).
pub fn no_variation(seeds: &[Option<u64>]) -> bool {
    seeds.iter().all(Option::is_none)
}

/// Reply to `BatchStep`: the K step results with arrays stacked along a leading K axis,
/// in `env_ids` order. Per-env values are columns (arrays of K); events, metrics and autoresets
/// are listed only for the envs that have them, each naming its env by `index` in `env_ids`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchStepResult {
    /// The K envs, as requested.
    pub env_ids: Vec<String>,
    /// Shapes `[K, n_ext, M, F]`, `[K, n_ext, M, M]`, `[K, n_ext, M]`, `[K, n_ext, M]`.
    pub obs: ObsBatch,
    /// `[K, n_ext]` `<f4`.
    pub reward: F32Array,
    /// Each `[K, n_ext]` `<f4`.
    pub reward_terms: RewardTerms,
    /// `[K, n_ext]` `|u1`.
    pub terminated: U8Array,
    /// `[K, n_ext]` `|u1`.
    pub truncated: U8Array,
    /// `[K]` `<u8`: episode counter of each env's transition.
    pub episode: U64Array,
    /// K scenario names (of each env's transition).
    pub scenario: Vec<String>,
    /// `[K]` `<u4`: step index after the transition.
    pub step: U32Array,
    /// `[K]` `<f8`: simulated time after the transition, s.
    pub t: F64Array,
    /// `[K, n_ext]` `|u1`: 1 where the agent's action was clipped into range.
    pub action_clipped: U8Array,
    /// Events of this step, env by env in `env_ids` order.
    pub events: Vec<BatchEvent>,
    /// Metrics of the episodes that ended at this step, in `env_ids` order.
    pub metrics: Vec<BatchMetrics>,
    /// With autoreset: the envs that restarted at this step (R = 0 when none did).
    pub resets: BatchResets,
}

impl BatchStepResult {
    /// Stacks per-env step results (which must have equal shapes).
    pub fn from_results(results: Vec<StepResult>) -> Result<Self, ArrayError> {
        fn stack<T: crate::Element>(
            results: &[StepResult],
            f: impl Fn(&StepResult) -> &NdArray<T>,
        ) -> Result<NdArray<T>, ArrayError> {
            NdArray::stack(&results.iter().map(|r| f(r).clone()).collect::<Vec<_>>())
        }
        let obs = ObsBatch::stack(&results.iter().map(|r| r.obs.clone()).collect::<Vec<_>>())?;
        let reward = stack(&results, |r| &r.reward)?;
        let reward_terms = RewardTerms::stack(
            &results
                .iter()
                .map(|r| r.reward_terms.clone())
                .collect::<Vec<_>>(),
        )?;
        let terminated = stack(&results, |r| &r.terminated)?;
        let truncated = stack(&results, |r| &r.truncated)?;
        let k = results.len() as u32;
        let n_ext = results.first().map_or(0, |r| r.info.action_clipped.len()) as u32;
        let clipped: Vec<u8> = results
            .iter()
            .flat_map(|r| r.info.action_clipped.iter().map(|&c| u8::from(c)))
            .collect();
        let mut out = Self {
            env_ids: Vec::with_capacity(results.len()),
            obs,
            reward,
            reward_terms,
            terminated,
            truncated,
            episode: U64Array::from_slice(&results.iter().map(|r| r.episode).collect::<Vec<_>>()),
            scenario: Vec::with_capacity(results.len()),
            step: U32Array::from_slice(&results.iter().map(|r| r.step).collect::<Vec<_>>()),
            t: F64Array::from_slice(&results.iter().map(|r| r.t).collect::<Vec<_>>()),
            action_clipped: U8Array::new(vec![k, n_ext], &clipped)?,
            events: Vec::new(),
            metrics: Vec::new(),
            resets: match results.first() {
                Some(r) => BatchResets::default_for(&r.obs)?,
                None => BatchResets::default_for(&ObsBatch::empty(0, 0)?)?,
            },
        };
        let mut resets: Vec<(u32, ResetResult)> = Vec::new();
        for (i, r) in results.into_iter().enumerate() {
            let index = i as u32;
            out.env_ids.push(r.env_id);
            out.scenario.push(r.scenario);
            out.events.extend(
                r.info
                    .events
                    .into_iter()
                    .map(|event| BatchEvent { index, event }),
            );
            out.metrics.extend(
                r.info
                    .metrics
                    .into_iter()
                    .map(|metrics| BatchMetrics { index, metrics }),
            );
            if let Some(reset) = r.reset {
                resets.push((index, reset));
            }
        }
        if !resets.is_empty() {
            out.resets = BatchResets {
                index: U32Array::from_slice(&resets.iter().map(|r| r.0).collect::<Vec<_>>()),
                episode: U64Array::from_slice(
                    &resets.iter().map(|r| r.1.episode).collect::<Vec<_>>(),
                ),
                scenario: resets.iter().map(|r| r.1.scenario.clone()).collect(),
                horizon_steps: U32Array::from_slice(
                    &resets.iter().map(|r| r.1.horizon_steps).collect::<Vec<_>>(),
                ),
                agents: resets.iter().map(|r| r.1.agents.clone()).collect(),
                obs: ObsBatch::stack(&resets.iter().map(|r| r.1.obs.clone()).collect::<Vec<_>>())?,
                variation: resets
                    .iter()
                    .map(|r| r.1.variation.as_ref().map(|v| v.seed))
                    .collect(),
            };
            if no_variation(&out.resets.variation) {
                // As decoded: a column the encoding leaves out comes back empty.
                out.resets.variation.clear();
            }
        }
        Ok(out)
    }
}

impl BatchResets {
    /// No resets, for envs whose observations have the shapes of `like` (one env's).
    pub fn default_for(like: &ObsBatch) -> Result<Self, ArrayError> {
        let zero_lead = |shape: &[u32]| -> Vec<u32> {
            std::iter::once(0).chain(shape.iter().copied()).collect()
        };
        Ok(Self {
            index: U32Array::zeros(vec![0])?,
            episode: U64Array::zeros(vec![0])?,
            scenario: Vec::new(),
            horizon_steps: U32Array::zeros(vec![0])?,
            agents: Vec::new(),
            obs: ObsBatch {
                features: F32Array::zeros(zero_lead(like.features.shape()))?,
                adjacency: F32Array::zeros(zero_lead(like.adjacency.shape()))?,
                mask: U8Array::zeros(zero_lead(like.mask.shape()))?,
                node_ids: U32Array::zeros(zero_lead(like.node_ids.shape()))?,
            },
            variation: Vec::new(),
        })
    }
}

/// Reply to `Close`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Closed {
    /// The env(s) closed.
    pub env_ids: Vec<String>,
}

/// A scenario pool, in `ServerInfo`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct PoolSummary {
    /// Pool name.
    pub name: String,
    /// Scenarios in the train split.
    pub train: u32,
    /// Scenarios in the test split.
    pub test: u32,
    /// Every scenario of the pool in pool order (a scenario's index in this list is its
    /// `scenario_index` on the client side): what `CreateEnv.scenario` and `Reset.scenario`
    /// name. Absent in replies of servers older than this field: empty.
    #[serde(default)]
    pub scenarios: Vec<ScenarioSummary>,
}

/// One scenario of a pool, in `PoolSummary`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ScenarioSummary {
    /// Scenario name, unique in its pool.
    pub name: String,
    /// Its split.
    pub split: Split,
}

/// Reply to `InfoRequest`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ServerInfo {
    /// The server's protocol version.
    pub protocol_version: u32,
    /// Server id (a key segment).
    pub server_id: String,
    /// Server software version (semver string).
    pub version: String,
    /// Maximum simultaneously open envs.
    pub capacity: u32,
    /// Currently open envs.
    pub load: u32,
    /// Maximum K of a `BatchStep` (and `count` of a `CreateEnv`).
    pub max_batch: u32,
    /// Maximum `max_agents` a `CreateEnv` may ask for.
    pub max_agents: u32,
    /// Simulation step in seconds.
    pub dt: f64,
    /// Pedestrian models offered.
    pub pedestrian_models: Vec<PedestrianModel>,
    /// Scenario pools.
    pub pools: Vec<PoolSummary>,
    /// Every open env, in creation order (absent from servers before it was added).
    #[serde(default)]
    pub envs: Vec<OpenEnv>,
}

/// [`ServerInfo::envs`]: an open env and the trainer that created it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OpenEnv {
    /// The env (its publications are under `{p}/env/{env_id}/...`).
    pub env_id: String,
    /// `CreateEnv.client_id` of its creator.
    pub client_id: String,
}

// ---------------------------------------------------------------------------------------------
// Publications
// ---------------------------------------------------------------------------------------------

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
