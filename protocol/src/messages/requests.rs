//! Requests (SPEC section 5) and their server-independent validation.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::array::{F32Array, FloatArray};
use crate::keys;
use crate::PROTOCOL_VERSION;

use super::{
    ErrorCode, ErrorReply, Mode, PedestrianModel, Split, VariationSpec, VehicleModel, ACTION_DIM,
    DEFAULT_EXTERNAL_AGENT, DEFAULT_MAX_AGENTS, REWARD_WEIGHT_DEFAULTS,
};

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
    /// Scenarios of the split never drawn, by name: a validation split the trainer holds out
    /// (empty: none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub exclude: Vec<String>,
    /// Scenes composed from the recorded parts of a pool's train scenes, drawn beside (or
    /// instead of) the pool's (nil: none; SPEC 5.2.2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub composed: Option<ComposedScenes>,
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
    /// Vehicles per scene: the ego drives +x through the crowd, the others by `routes`.
    pub vehicles: u32,
    /// `"lanes"` (parallel lanes 4 m apart, alternately oncoming) or `"intersection"` (at most
    /// 4 vehicles heading +x, +y, -x, -y through a crossing at the square's centre, the others
    /// entering 0–2 s late).
    pub routes: String,
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
            routes: "lanes".into(),
            density: 0.25,
            seed: 0,
            scenes: 1,
        }
    }
}

/// `CreateEnv.composed` (SPEC 5.2.2): scenes the server composes from the recorded parts of
/// the train scenes of `source` (the scenarios crate's `composed` module), scene `i` named
/// `composed-s{seed}-{i}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ComposedScenes {
    /// Composed scenes `0..scenes`, drawn beside the split's recorded scenes (each episode one
    /// of the `recorded + scenes`, uniformly); nil: a fresh composed scene every episode.
    pub scenes: Option<u64>,
    /// The generator's seed.
    pub seed: u64,
    /// The served pool whose train scenes give the parts (nil: the request's `pool`).
    pub source: Option<String>,
    /// Scenes of `source` whose agents never enter a composed scene (a validation split); the
    /// agents of its test scenes never do either.
    pub hold_out: Vec<String>,
    /// Pedestrians per scene (nil: as many as the route's recorded scene had).
    pub pedestrians: Option<u32>,
    /// The weights of the pedestrians' roles by name (`crossing`, `along`, `oncoming`,
    /// `background`); a role not named keeps its default (the recorded share).
    pub shares: BTreeMap<String, f64>,
    /// Whether the route's recorded other cars come along.
    pub other_cars: bool,
}

impl Default for ComposedScenes {
    fn default() -> Self {
        Self {
            scenes: None,
            seed: 0,
            source: None,
            hold_out: Vec::new(),
            pedestrians: None,
            shares: BTreeMap::new(),
            other_cars: true,
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
            exclude: Vec::new(),
            composed: None,
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
