//! What an env publishes (`{p}/env/{env_id}/{topic}`): the gates that say which topics anybody
//! listens to, and the encoded state, uncertainty, risk-graph, events and result messages.

use super::{
    encode, event, to_wire_kind, Control, Env, EnvTopic, Event, EventKind, EventsMsg, F32Array,
    F64Array, RiskGraphMsg, Shape, Slots, StateRewards, StatesMsg, U32Array, U8Array,
    UncertaintyMsg, WireTerms, World,
};

/// Which publications somebody listens to (decided by the network layer from zenoh matching
/// status); a topic nobody matches is neither encoded nor sent.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Gates {
    pub states: bool,
    pub uncertainty: bool,
    pub risk_graph: bool,
    pub events: bool,
    pub result: bool,
}

/// Which envs' publications somebody listens to: the network layer narrows the topic gates
/// per env (a viewer following one env of a batch of 256 must not make the other 255 publish).
pub trait Watch: Sync {
    /// The gates of `env_id`.
    fn gates(&self, env_id: &str) -> Gates;
}

/// The same gates for every env.
impl Watch for Gates {
    fn gates(&self, _env_id: &str) -> Gates {
        *self
    }
}

impl Gates {
    /// Nothing is published.
    pub const NONE: Gates = Gates {
        states: false,
        uncertainty: false,
        risk_graph: false,
        events: false,
        result: false,
    };
    /// Everything is published.
    pub const ALL: Gates = Gates {
        states: true,
        uncertainty: true,
        risk_graph: true,
        events: true,
        result: true,
    };

    /// Whether any of the per-state topics is wanted.
    pub fn any(&self) -> bool {
        self.states || self.uncertainty || self.risk_graph || self.events || self.result
    }
}

/// An encoded publication: key expression and MessagePack payload.
#[derive(Debug, Clone, PartialEq)]
pub struct Publication {
    pub key: String,
    pub topic: EnvTopic,
    pub payload: Vec<u8>,
}

impl Env {
    /// Publications of an episode's first state, if any are wanted.
    pub(super) fn publish_episode_start(&self, gates: Gates, pubs: &mut Vec<Publication>) {
        if !gates.any() {
            return;
        }
        let Some(world) = &self.world else { return };
        let mut ids: Vec<u32> = world.agents().map(|a| a.id).collect();
        ids.sort_unstable();
        let events = vec![event(EventKind::EpisodeStart, 0, 0.0, ids)];
        self.publish_state(gates, &events, None, pubs);
    }

    /// Encodes the wanted publications of the current state; `slots` hold the rewards of the
    /// step that led to it (none after a reset).
    pub(super) fn publish_state(
        &self,
        gates: Gates,
        events: &[Event],
        slots: Option<&Slots<'_>>,
        pubs: &mut Vec<Publication>,
    ) {
        let Some(world) = &self.world else { return };
        let mut push = |topic: EnvTopic, payload: Vec<u8>| {
            if let Ok(key) = self.spec.keys.env_topic(&self.id, topic) {
                pubs.push(Publication {
                    key,
                    topic,
                    payload,
                });
            }
        };
        if gates.states {
            push(EnvTopic::States, encode(&self.states_msg(world, slots)));
        }
        if gates.uncertainty || gates.risk_graph {
            let (uncertainty, risk_graph) = self.graph_msgs(world, gates);
            if let Some(msg) = uncertainty {
                push(EnvTopic::Uncertainty, encode(&msg));
            }
            if let Some(msg) = risk_graph {
                push(EnvTopic::RiskGraph, encode(&msg));
            }
        }
        if gates.events && !events.is_empty() {
            let msg = EventsMsg {
                env_id: self.id.clone(),
                episode: self.episode,
                step: world.step_index(),
                t: world.time(),
                events: events.to_vec(),
            };
            push(EnvTopic::Events, encode(&msg));
        }
    }

    /// Every agent's state (in id order), and the rewards of the step that led to it.
    fn states_msg(&self, world: &World, slots: Option<&Slots<'_>>) -> StatesMsg {
        let mut agents: Vec<_> = world.agents().collect();
        agents.sort_by_key(|a| a.id);
        let n = agents.len() as u32;
        let ids: Vec<u32> = agents.iter().map(|a| a.id).collect();
        let kinds: Vec<u8> = agents.iter().map(|a| to_wire_kind(a.kind).code()).collect();
        let pos: Vec<f64> = agents
            .iter()
            .flat_map(|a| [a.position.x, a.position.y])
            .collect();
        let vel: Vec<f64> = agents
            .iter()
            .flat_map(|a| [a.velocity.x, a.velocity.y])
            .collect();
        let hd: Vec<f64> = agents.iter().map(|a| a.heading).collect();
        let sizes: Vec<f64> = agents
            .iter()
            .flat_map(|a| match a.shape {
                Shape::Rect { length, width } => [length, width],
                Shape::Disc { radius } => [2.0 * radius, 2.0 * radius],
            })
            .collect();
        let goals: Vec<f64> = agents.iter().flat_map(|a| [a.goal.x, a.goal.y]).collect();
        let external: Vec<u8> = agents
            .iter()
            .map(|a| u8::from(self.ext_ids.contains(&a.id)))
            .collect();
        let reactive: Vec<u8> = agents
            .iter()
            .map(|a| u8::from(matches!(a.control, Control::Vehicle(_))))
            .collect();
        let rewards = slots.map(|slots| StateRewards {
            agents: U32Array::from_slice(&self.ext_ids),
            reward: F32Array::from_slice(slots.reward),
            terms: WireTerms {
                progress: F32Array::from_slice(slots.terms[0]),
                success: F32Array::from_slice(slots.terms[1]),
                collision: F32Array::from_slice(slots.terms[2]),
                danger: F32Array::from_slice(slots.terms[3]),
                comfort: F32Array::from_slice(slots.terms[4]),
            },
            returns: F64Array::from_slice(&self.returns),
        });
        StatesMsg {
            env_id: self.id.clone(),
            episode: self.episode,
            step: world.step_index(),
            t: world.time(),
            ids: U32Array::from_slice(&ids),
            kinds: U8Array::from_slice(&kinds),
            positions: F64Array::new(vec![n, 2], &pos).expect("shape"),
            velocities: F64Array::new(vec![n, 2], &vel).expect("shape"),
            headings: F64Array::from_slice(&hd),
            scenario: self.scenario_name().to_string(),
            sizes: Some(F64Array::new(vec![n, 2], &sizes).expect("shape")),
            goals: Some(F64Array::new(vec![n, 2], &goals).expect("shape")),
            external: Some(U8Array::from_slice(&external)),
            rewards,
            reactive: reactive
                .contains(&1)
                .then(|| U8Array::from_slice(&reactive)),
        }
    }

    /// The uncertainty and the risk graph of the current state (those `gates` want), edges
    /// by (observer, target).
    fn graph_msgs(
        &self,
        world: &World,
        gates: Gates,
    ) -> (Option<UncertaintyMsg>, Option<RiskGraphMsg>) {
        let mut edges: Vec<_> = world.graph_edges().collect();
        edges.sort_by_key(|e| (e.observer, e.target));
        let column =
            |f: fn(&_) -> f64| F64Array::from_slice(&edges.iter().map(f).collect::<Vec<_>>());
        let src = U32Array::from_slice(&edges.iter().map(|e| e.observer).collect::<Vec<_>>());
        let dst = U32Array::from_slice(&edges.iter().map(|e| e.target).collect::<Vec<_>>());
        let u = column(|e| e.u);
        let (episode, step, t) = (self.episode, world.step_index(), world.time());
        let uncertainty = gates.uncertainty.then(|| UncertaintyMsg {
            env_id: self.id.clone(),
            episode,
            step,
            t,
            src: src.clone(),
            dst: dst.clone(),
            u: u.clone(),
        });
        let risk_graph = gates.risk_graph.then(|| RiskGraphMsg {
            env_id: self.id.clone(),
            episode,
            step,
            t,
            lambda: world.params().risk.lambda,
            src,
            dst,
            psi: column(|e| e.psi),
            u,
            a: column(|e| e.a),
        });
        (uncertainty, risk_graph)
    }
}
