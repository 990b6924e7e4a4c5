//! Scenario builders shared by the integration tests (not a test file itself).
#![allow(dead_code)]

use std::sync::Arc;

use sim_core::scenario::{AgentKind, AgentRecord, Scenario, Split};
use sim_core::{EpisodeConfig, PedestrianModel, World, WorldParams};

/// The only sampling interval a world accepts by default, s.
pub const DT: f64 = 0.5;

/// A record that starts at `start_step` at `p0` and moves with constant velocity `v` for `n`
/// samples (positions `p0 + k * v * dt`).
pub fn line(kind: AgentKind, start_step: u32, p0: [f64; 2], v: [f64; 2], n: usize) -> AgentRecord {
    let positions = (0..n)
        .map(|k| {
            let t = k as f64 * DT;
            [p0[0] + v[0] * t, p0[1] + v[1] * t]
        })
        .collect();
    AgentRecord {
        record_id: 0,
        kind,
        start_step,
        positions,
        velocities: vec![v; n],
        non_reactive: false,
        desired_speed: None,
    }
}

/// A record with explicit positions and velocities.
pub fn track(
    kind: AgentKind,
    start_step: u32,
    positions: Vec<[f64; 2]>,
    velocities: Vec<[f64; 2]>,
) -> AgentRecord {
    AgentRecord {
        record_id: 0,
        kind,
        start_step,
        positions,
        velocities,
        non_reactive: false,
        desired_speed: None,
    }
}

/// A scenario (dt 0.5, train split) with `agents`; `ego` indexes `agents`. Record ids are set to
/// the agent indices.
pub fn scenario(ego: usize, mut agents: Vec<AgentRecord>) -> Arc<Scenario> {
    for (k, a) in agents.iter_mut().enumerate() {
        a.record_id = k as u64;
    }
    Arc::new(Scenario {
        name: "test".into(),
        split: Split::Train,
        dt: DT,
        ego,
        agents,
    })
}

/// A tiny deterministic generator (xorshift64*) so that tests need no random crate.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in `[lo, hi)`.
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let u = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * u
    }
}

/// The paper's set-up with default parameters in a scenario of `agents` (agent 0 the ego):
/// the ego driven by actions, pedestrians moved by `model`.
pub fn paper_world(agents: Vec<AgentRecord>, model: PedestrianModel) -> World {
    let sc = scenario(0, agents);
    let config = EpisodeConfig::ego_external(&sc, model);
    World::new(sc, WorldParams::default(), config).unwrap()
}

/// CR-SFM pedestrians and replaying vehicles; the agents `external` driven by actions.
pub fn with_external(external: Vec<u32>) -> EpisodeConfig {
    EpisodeConfig {
        pedestrian_model: PedestrianModel::CrSfm,
        model_overrides: Vec::new(),
        external,
        vehicle_model: Default::default(),
        vehicle_overrides: Vec::new(),
    }
}

/// Agent 0 driven by actions, CR-SFM pedestrians except the `model_overrides`, vehicles
/// replaying: the mixed-model set-up of the determinism and threading tests.
pub fn mixed_models(model_overrides: Vec<(u32, PedestrianModel)>) -> EpisodeConfig {
    EpisodeConfig {
        model_overrides,
        ..with_external(vec![0])
    }
}

/// Every number of one step as bits (positions, velocities, accelerations, headings, graph
/// clearance/psi/u/A, rewards) plus events.
pub fn fingerprint(w: &sim_core::World, out: Option<&sim_core::StepOutcome>) -> Vec<u64> {
    let mut f = vec![u64::from(w.step_index()), w.len() as u64];
    for a in w.agents() {
        f.push(u64::from(a.id));
        for v in [a.position, a.velocity, a.acceleration] {
            f.extend([v.x.to_bits(), v.y.to_bits()]);
        }
        f.push(a.heading.to_bits());
    }
    for e in w.graph_edges() {
        f.push(u64::from(e.observer) << 32 | u64::from(e.target));
        for x in [e.clearance, e.psi, e.u, e.a] {
            f.push(x.to_bits());
        }
    }
    if let Some(out) = out {
        for a in &out.agents {
            let r = a.reward;
            for x in [r.progress, r.success, r.collision, r.danger, r.comfort] {
                f.push(x.to_bits());
            }
            f.push(u64::from(a.terminated) | u64::from(a.truncated) << 1);
        }
        for e in &out.events {
            f.push(match *e {
                sim_core::world::Event::Collision { a, b } => {
                    1 << 60 | u64::from(a) << 32 | u64::from(b)
                }
                sim_core::world::Event::GoalReached { agent } => 2 << 60 | u64::from(agent),
                sim_core::world::Event::Entered { agent } => 3 << 60 | u64::from(agent),
                sim_core::world::Event::Left { agent } => 4 << 60 | u64::from(agent),
                sim_core::world::Event::AtFault {
                    vehicle,
                    pedestrian,
                } => 5 << 60 | u64::from(vehicle) << 32 | u64::from(pedestrian),
            });
        }
        f.push(u64::from(out.episode_over));
    }
    f
}
