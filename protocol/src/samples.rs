//! Fixed example values of every message type: the content of the golden files in
//! `tests/golden/` (one `{name}.msgpack` per sample). Changing a value here changes a golden
//! file; the golden test then fails until the files are regenerated deliberately with
//! `UPDATE_GOLDEN=1 cargo test -p protocol`.

use std::collections::BTreeMap;
use std::fmt::Debug;

use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::array::{F32Array, F64Array, U32Array, U8Array};
use crate::codec::{decode, encode};
use crate::messages::*;
use crate::PROTOCOL_VERSION;

/// Server id used by the samples.
pub const SERVER_ID: &str = "s1";
/// Env id used by the samples.
pub const ENV_ID: &str = "s1-0";
/// Second env id used by the batch samples.
pub const ENV_ID_2: &str = "s1-1";
/// Client id used by the samples.
pub const CLIENT_ID: &str = "trainer-a";
/// `max_agents` used by the samples (kept small).
pub const MAX_AGENTS: u32 = 4;

type Verify = Box<dyn Fn(&[u8]) -> Result<(), String> + Send + Sync>;

/// One golden sample.
pub struct Sample {
    /// File stem: the golden file is `{name}.msgpack`.
    pub name: &'static str,
    /// Rust type name, e.g. `Reply<StepResult>`.
    pub type_name: String,
    /// How the message travels: "query payload", "reply", "publication (server)" or
    /// "publication (client)".
    pub role: &'static str,
    /// The key expression it travels on (with the sample ids).
    pub key: &'static str,
    /// One-line description.
    pub description: &'static str,
    /// The encoding of the sample value.
    pub bytes: Vec<u8>,
    verify: Verify,
}

impl Sample {
    fn new<T>(name: &'static str, key: &'static str, description: &'static str, value: T) -> Self
    where
        T: Serialize + DeserializeOwned + PartialEq + Debug + Send + Sync + 'static,
    {
        let bytes = encode(&value);
        let type_name = crate::codec::type_label::<T>();
        let role = if name.starts_with("reply_") {
            "reply"
        } else if name == "action" {
            "publication (client)"
        } else if key.starts_with("sharedspace/server/") {
            "query payload"
        } else {
            "publication (server)"
        };
        let verify: Verify = Box::new(move |b: &[u8]| {
            let got: T = decode(b).map_err(|e| e.to_string())?;
            if got != value {
                return Err(format!(
                    "decoded value differs from the sample:\n  got:      {got:?}\n  expected: {value:?}"
                ));
            }
            if encode(&got) != b {
                return Err("re-encoding the decoded value is not byte-identical".to_string());
            }
            Ok(())
        });
        Self {
            name,
            type_name,
            role,
            key,
            description,
            bytes,
            verify,
        }
    }

    /// Decodes `bytes` as this sample's type, compares with the sample value and checks that
    /// re-encoding gives the same bytes.
    pub fn verify(&self, bytes: &[u8]) -> Result<(), String> {
        (self.verify)(bytes)
    }
}

fn f32a(shape: &[u32], v: &[f32]) -> F32Array {
    F32Array::new(shape.to_vec(), v).expect("sample shape")
}
fn f64a(shape: &[u32], v: &[f64]) -> F64Array {
    F64Array::new(shape.to_vec(), v).expect("sample shape")
}

/// The sample `CreateEnv`.
pub fn create_env() -> CreateEnv {
    CreateEnv {
        protocol_version: PROTOCOL_VERSION,
        client_id: CLIENT_ID.to_string(),
        count: 2,
        pool: Some("hbs_3ped".to_string()),
        split: Split::Train,
        seed: 42,
        pedestrian_model: PedestrianModel::CrSfm,
        pedestrian_params: BTreeMap::from([("lambda1".to_string(), 1.5), ("tau".to_string(), 0.5)]),
        external_agents: vec!["vehicle_0".to_string()],
        reward_weights: BTreeMap::from([("collision".to_string(), -25.0)]),
        mode: Mode::Lockstep,
        max_agents: MAX_AGENTS,
        scenario: None,
        autoreset: true,
        realtime_factor: 1.0,
        synthetic: None,
        exclude: Vec::new(),
        composed: None,
        variations: None,
        vehicle_model: None,
    }
}

/// The sample `CreateEnv` with every optional field set: a client's typed spec of the same
/// values encodes to these bytes (clients/tests/test_codec.py), so both sides hold the same
/// fields in the same order.
pub fn create_env_full() -> CreateEnv {
    CreateEnv {
        pool: None,
        split: Split::Test,
        external_agents: vec!["vehicle_0".to_string(), "vehicle_1".to_string()],
        mode: Mode::Realtime,
        scenario: Some("synthetic-counter_flow-n12-v2-intersection-seed3".to_string()),
        realtime_factor: 2.0,
        synthetic: Some(SyntheticScenes {
            layout: "counter_flow".to_string(),
            pedestrians: 12,
            vehicles: 2,
            routes: "intersection".to_string(),
            density: 0.5,
            seed: 3,
            scenes: 4,
        }),
        exclude: vec!["hbs-car1130".to_string()],
        composed: Some(ComposedScenes {
            scenes: Some(1000),
            seed: 7,
            source: Some("hbs-paper".to_string()),
            hold_out: vec!["hbs-car1116".to_string()],
            pedestrians: Some(3),
            shares: BTreeMap::from([("crossing".to_string(), 0.5)]),
            other_cars: false,
        }),
        variations: Some(VariationSpec {
            position_sigma: 0.25,
            start_offset_steps: 1,
            desired_speed_scale: 0.1,
            param_noise: BTreeMap::from([("tau".to_string(), 0.2)]),
            mirror: true,
            rotation_deg: 15.0,
        }),
        vehicle_model: Some(VehicleModel::Idm),
        ..create_env()
    }
}

/// The sample observation of one env (n_ext = 1, M = 4): ego id 0, pedestrian id 2
/// (nearest), pedestrian id 1, one padding node.
pub fn obs(offset: f32) -> ObsBatch {
    #[rustfmt::skip]
    let features = [
        // node 0 = ego (vehicle id 0 at (10, 5), velocity (4, 0), heading 0, goal (22, 10))
        0.0, 0.0, 0.0, 0.0, 4.0 + offset, 0.0, vehicle_radius() as f32, 1.0, 12.0, 5.0, 13.0,
        // node 1 = pedestrian id 2 at (16.5, 6.25), velocity (-0.6, -0.8)
        6.5, 1.25, -4.6, -0.8, 1.0, -2.214_297_5, 0.3, 0.0, 0.0, 0.0, 0.0,
        // node 2 = pedestrian id 1 at (24.5, -1.5), velocity (-1.0, 0.5)
        14.5, -6.5, -5.0, 0.5, 1.118_034, 2.677_945_1, 0.3, 0.0, 0.0, 0.0, 0.0,
        // node 3 = padding
        0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    ];
    // A[i][j] between the nodes (ids 0, 2, 1); ids 0 and 1 are more than 15 m apart.
    #[rustfmt::skip]
    let adjacency = [
        0.0,   0.3125, 0.0,     0.0,
        0.375, 0.0,    0.53125, 0.0,
        0.0,   0.5625, 0.0,     0.0,
        0.0,   0.0,    0.0,     0.0,
    ];
    ObsBatch {
        features: f32a(&[1, MAX_AGENTS, N_FEATURES], &features),
        adjacency: f32a(&[1, MAX_AGENTS, MAX_AGENTS], &adjacency),
        mask: U8Array::new(vec![1, MAX_AGENTS], &[1, 1, 1, 0]).expect("sample shape"),
        node_ids: U32Array::new(vec![1, MAX_AGENTS], &[0, 2, 1, PAD_NODE_ID])
            .expect("sample shape"),
    }
}

/// Half the diagonal of the default 4.0 m x 1.8 m vehicle rectangle.
fn vehicle_radius() -> f64 {
    (4.0f64 * 4.0 + 1.8 * 1.8).sqrt() / 2.0
}

fn agents() -> Vec<AgentDesc> {
    vec![
        AgentDesc {
            id: 0,
            name: "vehicle_0".to_string(),
            kind: AgentKind::Vehicle,
            external: true,
            radius: vehicle_radius(),
            length: Some(4.0),
            width: Some(1.8),
        },
        AgentDesc {
            id: 1,
            name: "pedestrian_0".to_string(),
            kind: AgentKind::Pedestrian,
            external: false,
            radius: 0.3,
            length: None,
            width: None,
        },
        AgentDesc {
            id: 2,
            name: "pedestrian_1".to_string(),
            kind: AgentKind::Pedestrian,
            external: false,
            radius: 0.3,
            length: None,
            width: None,
        },
    ]
}

/// The sample `ResetResult`.
pub fn reset_result() -> ResetResult {
    ResetResult {
        env_id: ENV_ID.to_string(),
        episode: 1,
        scenario: "hbs_0007".to_string(),
        step: 0,
        t: 0.0,
        horizon_steps: 70,
        agents: agents(),
        obs: obs(0.0),
        variation: None,
    }
}

fn reward_terms(progress: f32, danger: f32) -> RewardTerms {
    RewardTerms {
        progress: F32Array::from_slice(&[progress]),
        success: F32Array::from_slice(&[0.0]),
        collision: F32Array::from_slice(&[0.0]),
        danger: F32Array::from_slice(&[danger]),
        comfort: F32Array::from_slice(&[-0.125]),
    }
}

/// The sample `StepResult` (a plain step, no episode end).
pub fn step_result() -> StepResult {
    StepResult {
        env_id: ENV_ID.to_string(),
        episode: 1,
        scenario: "hbs_0007".to_string(),
        step: 5,
        t: 2.5,
        obs: obs(0.0),
        reward: F32Array::from_slice(&[-0.125 + 2.0 - 3.0]),
        reward_terms: reward_terms(2.0, -3.0),
        terminated: U8Array::from_slice(&[0]),
        truncated: U8Array::from_slice(&[0]),
        info: StepInfo {
            action_clipped: vec![true],
            events: vec![Event {
                kind: EventKind::ActionClipped,
                step: 5,
                t: 2.5,
                agents: vec![0],
                outcome: None,
            }],
            metrics: vec![],
        },
        reset: None,
    }
}

/// The sample episode-ending `StepResult` of env `ENV_ID_2` (success, with autoreset).
pub fn step_result_done() -> StepResult {
    let mut reset = reset_result();
    reset.env_id = ENV_ID_2.to_string();
    reset.episode = 4;
    reset.scenario = "hbs_0012".to_string();
    StepResult {
        env_id: ENV_ID_2.to_string(),
        episode: 3,
        scenario: "hbs_0031".to_string(),
        step: 40,
        t: 20.0,
        obs: obs(0.5),
        reward: F32Array::from_slice(&[11.875]),
        reward_terms: RewardTerms {
            progress: F32Array::from_slice(&[2.0]),
            success: F32Array::from_slice(&[10.0]),
            collision: F32Array::from_slice(&[0.0]),
            danger: F32Array::from_slice(&[0.0]),
            comfort: F32Array::from_slice(&[-0.125]),
        },
        terminated: U8Array::from_slice(&[1]),
        truncated: U8Array::from_slice(&[0]),
        info: StepInfo {
            action_clipped: vec![false],
            events: vec![
                Event {
                    kind: EventKind::GoalReached,
                    step: 40,
                    t: 20.0,
                    agents: vec![0],
                    outcome: None,
                },
                Event {
                    kind: EventKind::EpisodeEnd,
                    step: 40,
                    t: 20.0,
                    agents: vec![0],
                    outcome: Some(Outcome::Success),
                },
            ],
            metrics: vec![EpisodeMetrics {
                agent: "vehicle_0".to_string(),
                outcome: Outcome::Success,
                steps: 40,
                duration: 20.0,
                episode_return: 31.5,
                avg_speed: 4.25,
                avg_abs_jerk: 0.5,
                max_abs_acc: 1.75,
            }],
        },
        reset: Some(reset),
    }
}

/// The step results the sample `BatchStepResult` stacks: `step_result()` and
/// `step_result_done()`.
pub fn batch_steps() -> Vec<StepResult> {
    vec![step_result(), step_result_done()]
}

/// The sample `BatchStepResult` (K = 2, [`batch_steps`]).
pub fn batch_step_result() -> BatchStepResult {
    BatchStepResult::from_results(batch_steps()).expect("equal shapes")
}

/// The sample `ServerInfo`.
pub fn server_info() -> ServerInfo {
    ServerInfo {
        protocol_version: PROTOCOL_VERSION,
        server_id: SERVER_ID.to_string(),
        version: "0.1.0".to_string(),
        capacity: 256,
        load: 2,
        max_batch: 64,
        max_agents: 32,
        dt: 0.5,
        pedestrian_models: PedestrianModel::ALL.to_vec(),
        pools: vec![
            PoolSummary {
                name: "hbs_3ped".to_string(),
                train: 60,
                test: 18,
                scenarios: vec![
                    ScenarioSummary {
                        name: "hbs-car1203".to_string(),
                        split: Split::Train,
                    },
                    ScenarioSummary {
                        name: "hbs-car1251".to_string(),
                        split: Split::Test,
                    },
                ],
            },
            PoolSummary {
                name: "hbs_all".to_string(),
                train: 120,
                test: 36,
                scenarios: vec![],
            },
        ],
        envs: vec![
            OpenEnv {
                env_id: format!("{SERVER_ID}-0"),
                client_id: "trainer-a".to_string(),
            },
            OpenEnv {
                env_id: format!("{SERVER_ID}-1"),
                client_id: "trainer-a".to_string(),
            },
        ],
        tables: [("envs", 2), ("trainers", 1)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect(),
        allocator: [("in_use", 12_000_000), ("free_retained", 3_000_000)]
            .into_iter()
            .map(|(k, v)| (k.to_string(), v))
            .collect(),
    }
}

/// The sample `StatesMsg` (3 agents).
pub fn states() -> StatesMsg {
    StatesMsg {
        env_id: ENV_ID.to_string(),
        episode: 1,
        step: 5,
        t: 2.5,
        ids: U32Array::from_slice(&[0, 1, 2]),
        kinds: U8Array::from_slice(&[KIND_VEHICLE, KIND_PEDESTRIAN, KIND_PEDESTRIAN]),
        positions: f64a(&[3, 2], &[10.0, 5.0, 24.5, -1.5, 16.5, 6.25]),
        velocities: f64a(&[3, 2], &[4.0, 0.0, -1.0, 0.5, -0.6, -0.8]),
        headings: f64a(&[3], &[0.0, 2.677_945_044_588_987, -2.214_297_435_588_181]),
        scenario: "hbs-car1138".to_string(),
        sizes: Some(f64a(&[3, 2], &[4.5, 1.8, 0.6, 0.6, 0.6, 0.6])),
        goals: Some(f64a(&[3, 2], &[40.0, 5.0, 0.0, 10.0, 2.0, -20.0])),
        external: Some(U8Array::from_slice(&[1, 0, 0])),
        rewards: Some(StateRewards {
            agents: U32Array::from_slice(&[0]),
            reward: F32Array::from_slice(&[0.375]),
            terms: RewardTerms {
                progress: F32Array::from_slice(&[0.5]),
                success: F32Array::from_slice(&[0.0]),
                collision: F32Array::from_slice(&[0.0]),
                danger: F32Array::from_slice(&[-0.125]),
                comfort: F32Array::from_slice(&[0.0]),
            },
            returns: f64a(&[1], &[2.25]),
        }),
        reactive: None,
    }
}

/// The sample `UncertaintyMsg` (4 edges).
pub fn uncertainty() -> UncertaintyMsg {
    UncertaintyMsg {
        env_id: ENV_ID.to_string(),
        episode: 1,
        step: 5,
        t: 2.5,
        src: U32Array::from_slice(&[0, 1, 2, 2]),
        dst: U32Array::from_slice(&[2, 2, 0, 1]),
        u: f64a(&[4], &[0.25, 0.125, 0.5, 0.0625]),
    }
}

/// The sample `RiskGraphMsg` (same 4 edges, lambda = 1).
pub fn risk_graph() -> RiskGraphMsg {
    RiskGraphMsg {
        env_id: ENV_ID.to_string(),
        episode: 1,
        step: 5,
        t: 2.5,
        lambda: 1.0,
        src: U32Array::from_slice(&[0, 1, 2, 2]),
        dst: U32Array::from_slice(&[2, 2, 0, 1]),
        psi: f64a(&[4], &[0.25, 0.5, 0.25, 0.5]),
        u: f64a(&[4], &[0.25, 0.125, 0.5, 0.0625]),
        a: f64a(&[4], &[0.3125, 0.5625, 0.375, 0.53125]),
    }
}

/// The sample `EventsMsg`.
pub fn events() -> EventsMsg {
    EventsMsg {
        env_id: ENV_ID.to_string(),
        episode: 1,
        step: 6,
        t: 3.0,
        events: vec![
            Event {
                kind: EventKind::Collision,
                step: 6,
                t: 3.0,
                agents: vec![0, 2],
                outcome: None,
            },
            Event {
                kind: EventKind::EpisodeEnd,
                step: 6,
                t: 3.0,
                agents: vec![0],
                outcome: Some(Outcome::Collision),
            },
        ],
    }
}

/// Every golden sample, in README order.
pub fn all() -> Vec<Sample> {
    vec![
        // ---- requests
        Sample::new(
            "info_request",
            "sharedspace/server/s1/info",
            "InfoRequest with protocol_version 2.",
            InfoRequest {
                protocol_version: Some(PROTOCOL_VERSION),
            },
        ),
        Sample::new(
            "create_env",
            "sharedspace/server/s1/env/create",
            "CreateEnv: 2 envs from pool hbs_3ped split train, seed 42, cr_sfm with two parameter overrides, one reward-weight override, max_agents 4, autoreset.",
            create_env(),
        ),
        Sample::new(
            "create_env_full",
            "sharedspace/server/s1/env/create",
            "CreateEnv with every optional field set: generated counter-flow scenes with two cars through an intersection, seeded variations, reactive traffic, two controlled vehicles, realtime.",
            create_env_full(),
        ),
        Sample::new(
            "reset",
            "sharedspace/server/s1/env/s1-0/reset",
            "Reset with seed 7 and no pinned scenario (nil).",
            Reset {
                seed: Some(7),
                scenario: None,
                variation: None,
            },
        ),
        Sample::new(
            "step",
            "sharedspace/server/s1/env/s1-0/step",
            "Step with one agent's action [0.5, -1.25] as <f4 [1, 2] (-1.25 is out of range and will be clipped).",
            Step {
                actions: f32a(&[1, 2], &[0.5, -1.25]).into(),
            },
        ),
        Sample::new(
            "step_f64",
            "sharedspace/server/s1/env/s1-0/step",
            "Step with the same action as <f8 [1, 2] (senders may use float64).",
            Step {
                actions: f64a(&[1, 2], &[0.5, -1.25]).into(),
            },
        ),
        Sample::new(
            "batch_step",
            "sharedspace/server/s1/batch/step",
            "BatchStep of envs s1-0 and s1-1, actions <f4 [2, 1, 2].",
            BatchStep {
                env_ids: vec![ENV_ID.to_string(), ENV_ID_2.to_string()],
                actions: f32a(&[2, 1, 2], &[0.5, -1.25, -0.25, 0.0]).into(),
            },
        ),
        Sample::new(
            "close",
            "sharedspace/server/s1/env/s1-0/close",
            "Close: an empty map.",
            Close {},
        ),
        Sample::new(
            "action",
            "sharedspace/env/s1-0/action/vehicle_0",
            "Realtime ActionMsg [0.25, 0.0] as <f4 [2], seq 17.",
            ActionMsg {
                action: F32Array::from_slice(&[0.25, 0.0]).into(),
                seq: 17,
            },
        ),
        // ---- replies
        Sample::new(
            "reply_server_info",
            "sharedspace/server/s1/info",
            "Reply ok ServerInfo of server s1.",
            Reply::Ok(server_info()),
        ),
        Sample::new(
            "reply_env_created",
            "sharedspace/server/s1/env/create",
            "Reply ok EnvCreated for the create_env sample.",
            Reply::Ok(EnvCreated {
                env_ids: vec![ENV_ID.to_string(), ENV_ID_2.to_string()],
                external_agents: vec!["vehicle_0".to_string()],
                observation: ObsLayout::standard(MAX_AGENTS),
                action: ActionSpace::default(),
                dt: 0.5,
                mode: Mode::Lockstep,
                split: Split::Train,
                pedestrian_model: PedestrianModel::CrSfm,
                autoreset: true,
            }),
        ),
        Sample::new(
            "reply_reset",
            "sharedspace/server/s1/env/s1-0/reset",
            "Reply ok ResetResult: scenario hbs_0007, 3 agents, first observation.",
            Reply::Ok(reset_result()),
        ),
        Sample::new(
            "reply_step",
            "sharedspace/server/s1/env/s1-0/step",
            "Reply ok StepResult: step 5, action clipped, no episode end.",
            Reply::Ok(step_result()),
        ),
        Sample::new(
            "reply_batch_step",
            "sharedspace/server/s1/batch/step",
            "Reply ok BatchStepResult (K = 2): s1-0 as in reply_step; s1-1 ends by success and autoresets.",
            Reply::Ok(batch_step_result()),
        ),
        Sample::new(
            "reply_closed",
            "sharedspace/server/s1/env/s1-0/close",
            "Reply ok Closed for s1-0.",
            Reply::Ok(Closed {
                env_ids: vec![ENV_ID.to_string()],
            }),
        ),
        Sample::new(
            "reply_error",
            "sharedspace/server/s1/batch/step",
            "Reply error non_finite_action about env s1-1.",
            Reply::<BatchStepResult>::Err(
                ErrorReply::new(
                    ErrorCode::NonFiniteAction,
                    "actions for env s1-1: agent 0 component 1 is NaN",
                )
                .with_env(ENV_ID_2),
            ),
        ),
        // ---- publications
        Sample::new(
            "states",
            "sharedspace/env/s1-0/states",
            "StatesMsg of 3 agents at step 5.",
            states(),
        ),
        Sample::new(
            "uncertainty",
            "sharedspace/env/s1-0/uncertainty",
            "UncertaintyMsg with 4 edges.",
            uncertainty(),
        ),
        Sample::new(
            "risk_graph",
            "sharedspace/env/s1-0/risk_graph",
            "RiskGraphMsg with the same 4 edges (a = psi * (1 + lambda * u)).",
            risk_graph(),
        ),
        Sample::new(
            "events",
            "sharedspace/env/s1-0/events",
            "EventsMsg: a collision of agents 0 and 2 ending the episode.",
            events(),
        ),
        Sample::new(
            "result",
            "sharedspace/env/s1-0/result",
            "Realtime StepResult publication (same value as reply_step's ok).",
            step_result(),
        ),
    ]
}
