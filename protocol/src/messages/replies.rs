//! Replies (SPEC section 6), and the stacking of a batch's per-env results.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::array::{ArrayError, F32Array, F64Array, NdArray, U32Array, U64Array, U8Array};

use super::{
    AgentKind, EventKind, Mode, Outcome, PedestrianModel, Split, Variation, ACTION_NAMES,
    FEATURE_NAMES, N_FEATURES, PAD_NODE_ID,
};

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
    /// Entries in each of the server's own tables, by table name (a diagnostic: each table is
    /// back to its idle size once the trainers are gone; names may change between versions).
    /// Absent from servers before it was added: empty.
    #[serde(default)]
    pub tables: BTreeMap<String, u64>,
    /// The memory allocator's own figures in bytes, by name (`in_use`, `free_retained`,
    /// `mmapped`; empty where the allocator does not report them). Absent from servers before
    /// it was added: empty.
    #[serde(default)]
    pub allocator: BTreeMap<String, u64>,
}

/// [`ServerInfo::envs`]: an open env and the trainer that created it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct OpenEnv {
    /// The env (its publications are under `{p}/env/{env_id}/...`).
    pub env_id: String,
    /// `CreateEnv.client_id` of its creator.
    pub client_id: String,
}
