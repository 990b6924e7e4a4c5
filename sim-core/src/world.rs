//! The world and its step pipeline (model.md sections 1–7, order of a step in 5b).
//!
//! A [`World`] owns the state of one episode: the agents present, every observer's beliefs, the
//! sparse risk graph and the scratch buffers a step reuses. [`World::step`] takes the actions of
//! the externally controlled agents and advances the state by `dt`; nothing else changes it.
//!
//! One step, from the state at `t` (whose beliefs `u_t`, risk `psi_t` and graph `A_t` were built
//! when `t` was reached):
//! 1. done external agents of the previous step leave;
//! 2. every agent moves to `t + 1` at once (actions, social forces from `u_t` and `psi_t`, replay);
//! 3. pedestrians at their goal and replayed agents past their record leave; agents recorded from
//!    `t + 1` enter;
//! 4. observe at `t + 1`: beliefs (`u_{t+1}`), clearances, `psi_{t+1}`, the graph;
//! 5. events (collisions, arrivals) and every reward term of the transition.

use std::sync::Arc;

use crate::cognition::{Belief, VarianceSchedule};
use crate::geometry::{clearance_and_normal, Placed, Shape, Vec2};
use crate::grid::Grid;
use crate::metrics::{EpisodeMetrics, EpisodeStatus};
use crate::params::{ParamError, PedestrianModel, WorldParams};
use crate::pedestrian::{self, Interaction};
use crate::risk;
use crate::scenario::{AgentKind, AgentRecord, Scenario};
use crate::vehicle::{self, UnicycleState};

/// An agent's identity: its index in the scenario's agent list. Stable for the whole episode.
pub type AgentId = u32;

/// What moves an agent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Control {
    /// Driven by actions sent to [`World::step`].
    External,
    /// Follows its recorded track.
    Replay,
    /// A simulated pedestrian.
    Model(PedestrianModel),
}

/// Which agents are external and which model moves the others.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeConfig {
    /// Model of every pedestrian that is neither external, non-reactive nor overridden.
    pub pedestrian_model: PedestrianModel,
    /// Per-agent model overrides.
    pub model_overrides: Vec<(AgentId, PedestrianModel)>,
    /// Agents driven by actions. Vehicles not listed replay their record.
    pub external: Vec<AgentId>,
}

impl EpisodeConfig {
    /// The paper's set-up: the scenario's ego vehicle is external, pedestrians use `model`.
    pub fn ego_external(scenario: &Scenario, model: PedestrianModel) -> Self {
        Self {
            pedestrian_model: model,
            model_overrides: Vec::new(),
            external: vec![scenario.ego as AgentId],
        }
    }

    /// Pedestrian-model evaluation (model.md 9): nobody is external, the vehicles replay.
    pub fn replay_vehicles(model: PedestrianModel) -> Self {
        Self {
            pedestrian_model: model,
            model_overrides: Vec::new(),
            external: Vec::new(),
        }
    }
}

/// Why a world could not be created.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorldError {
    #[error(transparent)]
    Param(#[from] ParamError),
    #[error("scenario `{scenario}` is sampled every {got} s but the world steps {want} s")]
    DtMismatch {
        scenario: String,
        got: f64,
        want: f64,
    },
    #[error("scenario `{scenario}`: {reason}")]
    Scenario { scenario: String, reason: String },
    #[error("external agent {agent} is not in scenario `{scenario}`")]
    UnknownAgent { scenario: String, agent: AgentId },
    #[error("external agent {agent} is listed twice")]
    DuplicateExternal { agent: AgentId },
}

/// Why a step was refused. A refused step leaves the world exactly as it was.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StepError {
    #[error("the episode is over; reset before stepping again")]
    EpisodeOver,
    #[error("action for agent {agent}, which is not an active external agent")]
    NotExternal { agent: AgentId },
    #[error("two actions for agent {agent}")]
    DuplicateAction { agent: AgentId },
    #[error("no action for active external agent {agent}")]
    MissingAction { agent: AgentId },
    #[error("action component {index} of agent {agent} is not finite ({value})")]
    NonFiniteAction {
        agent: AgentId,
        index: usize,
        value: f64,
    },
}

/// Every reward term of one transition (model.md 7), already multiplied by its weight.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RewardTerms {
    /// `progress * (d_goal(t) - d_goal(t+1))`.
    pub progress: f64,
    /// `success` on arrival, else 0.
    pub success: f64,
    /// `collision` on a collision, else 0.
    pub collision: f64,
    /// `danger * (c_min - danger_clearance)` when `c_min < danger_clearance`, else 0.
    pub danger: f64,
    /// `-jerk_penalty * jerk^2 - yaw_rate_penalty * omega^2`.
    pub comfort: f64,
}

impl RewardTerms {
    pub fn total(&self) -> f64 {
        self.progress + self.success + self.collision + self.danger + self.comfort
    }
}

/// The result of one step for one external agent.
#[derive(Debug, Clone, PartialEq)]
pub struct AgentOutcome {
    pub agent: AgentId,
    pub reward: RewardTerms,
    /// The agent's episode ended by arrival or collision.
    pub terminated: bool,
    /// The agent's episode was cut at the horizon.
    pub truncated: bool,
    /// A finite out-of-range action component was clipped into `[-1, 1]`.
    pub action_clipped: bool,
    /// Episode metrics, present on the step that ends the agent's episode.
    pub metrics: Option<EpisodeMetrics>,
}

/// Something that happened on reaching `t + 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Event {
    /// Two footprints overlap (clearance `<= 0`); `a < b`.
    Collision { a: AgentId, b: AgentId },
    /// An agent arrived at its goal.
    GoalReached { agent: AgentId },
    /// An agent entered the scene at its first recorded step.
    Entered { agent: AgentId },
    /// An agent left the scene (at its goal, at the end of its record, or after its episode ended).
    Left { agent: AgentId },
}

/// What one step produced.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepOutcome {
    /// The step reached (`t + 1`).
    pub step: u32,
    /// One entry per external agent active during the step, in [`EpisodeConfig::external`] order.
    pub agents: Vec<AgentOutcome>,
    pub events: Vec<Event>,
    /// Every external agent has entered and finished its episode, or the horizon was reached.
    pub episode_over: bool,
}

/// One directed edge `i -> j` of the risk graph with `i`'s belief about `j`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Edge {
    pub target: AgentId,
    /// Slot of the target in the current state.
    pub target_slot: u32,
    pub belief: Belief,
    pub clearance: f64,
    pub psi: f64,
    pub u: f64,
}

/// One edge of the risk graph as published: `A = psi (1 + lambda u)` is the influence of
/// `target` on `observer`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GraphEdge {
    pub observer: AgentId,
    pub target: AgentId,
    /// Clearance between the two footprints, m.
    pub clearance: f64,
    pub psi: f64,
    pub u: f64,
    pub a: f64,
}

/// A read-only view of one present agent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgentView {
    pub id: AgentId,
    pub kind: AgentKind,
    pub control: Control,
    pub shape: Shape,
    pub position: Vec2,
    pub velocity: Vec2,
    /// Acceleration `(v_t - v_{t-1}) / dt`, m/s².
    pub acceleration: Vec2,
    pub heading: f64,
    pub goal: Vec2,
}

#[derive(Debug, Clone)]
struct ExternalTrack {
    id: AgentId,
    active: bool,
    /// Speed at every step of its episode so far (the metrics' input).
    speeds: Vec<f64>,
    last_acc: Option<f64>,
    /// Centre distance to the goal at the current step, m.
    goal_distance: f64,
    status: Option<EpisodeStatus>,
}

/// Structure-of-arrays state of the agents present at the current step.
#[derive(Debug, Clone, Default)]
struct Agents {
    id: Vec<AgentId>,
    kind: Vec<AgentKind>,
    control: Vec<Control>,
    shape: Vec<Shape>,
    pos: Vec<Vec2>,
    vel: Vec<Vec2>,
    acc: Vec<Vec2>,
    /// Acceleration at the previous step (what the constant-acceleration prediction extrapolates).
    prev_acc: Vec<Vec2>,
    /// Unicycle speed for vehicles, `|v|` for pedestrians.
    speed: Vec<f64>,
    heading: Vec<f64>,
    goal: Vec<Vec2>,
    v0: Vec<f64>,
    initial_vel: Vec<Vec2>,
    /// `edges[edge_start[i]..edge_start[i] + edge_len[i]]` are agent `i`'s out-edges.
    edge_start: Vec<u32>,
    edge_len: Vec<u32>,
    leaving: Vec<bool>,
}

impl Agents {
    fn len(&self) -> usize {
        self.id.len()
    }

    fn retain(&mut self, keep: &[bool]) {
        fn r<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut k = 0;
            v.retain(|_| {
                k += 1;
                keep[k - 1]
            });
        }
        r(&mut self.id, keep);
        r(&mut self.kind, keep);
        r(&mut self.control, keep);
        r(&mut self.shape, keep);
        r(&mut self.pos, keep);
        r(&mut self.vel, keep);
        r(&mut self.acc, keep);
        r(&mut self.prev_acc, keep);
        r(&mut self.speed, keep);
        r(&mut self.heading, keep);
        r(&mut self.goal, keep);
        r(&mut self.v0, keep);
        r(&mut self.initial_vel, keep);
        r(&mut self.edge_start, keep);
        r(&mut self.edge_len, keep);
        r(&mut self.leaving, keep);
    }
}

fn v2(a: [f64; 2]) -> Vec2 {
    Vec2::new(a[0], a[1])
}

/// Heading of a recorded agent at sample `k`: the direction of its recorded velocity, or, when it
/// stands still, of the nearest sample where it moves (0 if it never does).
fn recorded_heading(rec: &AgentRecord, k: usize) -> f64 {
    const MOVING: f64 = 1e-6;
    let n = rec.velocities.len();
    for d in 0..n {
        for idx in [k.checked_sub(d), k.checked_add(d).filter(|&i| i < n)]
            .into_iter()
            .flatten()
        {
            let v = rec.velocities[idx];
            if v[0].hypot(v[1]) > MOVING {
                return v[1].atan2(v[0]);
            }
        }
    }
    0.0
}

/// One episode's world.
#[derive(Debug, Clone)]
pub struct World {
    params: WorldParams,
    schedule: VarianceSchedule,
    scenario: Arc<Scenario>,
    config: EpisodeConfig,
    control_of: Vec<Control>,
    step: u32,
    horizon: u32,
    over: bool,
    agents: Agents,
    edges: Vec<Edge>,
    /// Agents not yet entered, by descending start step (the next to enter is last).
    pending: Vec<AgentId>,
    externals: Vec<ExternalTrack>,
    /// Agents removed during the last step, with their position when they left.
    departed: Vec<(AgentId, Vec2)>,
    // Scratch reused by every step.
    grid: Grid,
    next: Agents,
    next_edges: Vec<Edge>,
    stamp: Vec<u64>,
    stamp_edge: Vec<u32>,
    epoch: u64,
    keep: Vec<bool>,
    slot_map: Vec<u32>,
    acc_norm: Vec<f64>,
}

const NO_SLOT: u32 = u32::MAX;

impl World {
    /// Starts an episode of `scenario` at its first step.
    pub fn new(
        scenario: Arc<Scenario>,
        params: WorldParams,
        config: EpisodeConfig,
    ) -> Result<Self, WorldError> {
        params.validate()?;
        let name = || scenario.name.clone();
        if (scenario.dt - params.dt).abs() > 1e-9 {
            return Err(WorldError::DtMismatch {
                scenario: name(),
                got: scenario.dt,
                want: params.dt,
            });
        }
        let n_total = scenario.agents.len();
        if n_total >= NO_SLOT as usize {
            return Err(WorldError::Scenario {
                scenario: name(),
                reason: "too many agents".into(),
            });
        }
        for (k, a) in scenario.agents.iter().enumerate() {
            if a.positions.is_empty() || a.positions.len() != a.velocities.len() {
                return Err(WorldError::Scenario {
                    scenario: name(),
                    reason: format!(
                        "agent {k}: empty track or positions/velocities of different length"
                    ),
                });
            }
            let finite = a
                .positions
                .iter()
                .chain(&a.velocities)
                .all(|p| p[0].is_finite() && p[1].is_finite());
            if !finite {
                return Err(WorldError::Scenario {
                    scenario: name(),
                    reason: format!("agent {k}: non-finite position or velocity"),
                });
            }
        }
        let mut control_of = Vec::with_capacity(n_total);
        for (k, a) in scenario.agents.iter().enumerate() {
            let overridden = config
                .model_overrides
                .iter()
                .rev()
                .find(|(id, _)| *id as usize == k);
            let c = match (a.kind, a.non_reactive, overridden) {
                (AgentKind::Vehicle, _, _) => Control::Replay,
                (AgentKind::Pedestrian, true, _) => Control::Replay,
                (AgentKind::Pedestrian, false, Some((_, m))) => Control::Model(*m),
                (AgentKind::Pedestrian, false, None) => Control::Model(config.pedestrian_model),
            };
            control_of.push(match c {
                Control::Model(PedestrianModel::Replay) => Control::Replay,
                c => c,
            });
        }
        let mut externals: Vec<ExternalTrack> = Vec::new();
        for &id in &config.external {
            if id as usize >= n_total {
                return Err(WorldError::UnknownAgent {
                    scenario: name(),
                    agent: id,
                });
            }
            if externals.iter().any(|e| e.id == id) {
                return Err(WorldError::DuplicateExternal { agent: id });
            }
            control_of[id as usize] = Control::External;
            externals.push(ExternalTrack {
                id,
                active: false,
                speeds: Vec::new(),
                last_acc: None,
                goal_distance: 0.0,
                status: None,
            });
        }
        let recorded = scenario.recorded_steps();
        let ego_len = scenario
            .agents
            .get(scenario.ego)
            .map_or(recorded, |a| a.end_step() + 1);
        let horizon = (((ego_len.saturating_sub(1)) as f64 * params.dt + params.horizon_extra)
            / params.dt)
            .round() as u32;
        let mut pending: Vec<AgentId> = (0..n_total as AgentId).collect();
        pending.sort_by_key(|&id| {
            (
                std::cmp::Reverse(scenario.agents[id as usize].start_step),
                std::cmp::Reverse(id),
            )
        });
        let mut w = World {
            schedule: VarianceSchedule::new(&params.cognition),
            params,
            scenario,
            config,
            control_of,
            step: 0,
            horizon: horizon.max(1),
            over: false,
            agents: Agents::default(),
            edges: Vec::new(),
            pending,
            externals,
            departed: Vec::new(),
            grid: Grid::default(),
            next: Agents::default(),
            next_edges: Vec::new(),
            stamp: vec![0; n_total],
            stamp_edge: vec![0; n_total],
            epoch: 0,
            keep: Vec::new(),
            slot_map: Vec::new(),
            acc_norm: Vec::new(),
        };
        let mut events = Vec::new();
        w.enter_pending(&mut events);
        w.observe();
        for e in &mut w.externals {
            e.active = w.agents.id.contains(&e.id);
        }
        Ok(w)
    }

    pub fn params(&self) -> &WorldParams {
        &self.params
    }

    pub fn scenario(&self) -> &Arc<Scenario> {
        &self.scenario
    }

    pub fn config(&self) -> &EpisodeConfig {
        &self.config
    }

    /// The current step index `t` (0 at the start).
    pub fn step_index(&self) -> u32 {
        self.step
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.step as f64 * self.params.dt
    }

    /// The step at which the episode is truncated.
    pub fn horizon(&self) -> u32 {
        self.horizon
    }

    pub fn is_over(&self) -> bool {
        self.over
    }

    /// External agents whose episode is still running (they need an action next step).
    pub fn active_externals(&self) -> impl Iterator<Item = AgentId> + '_ {
        self.externals.iter().filter(|e| e.active).map(|e| e.id)
    }

    /// The agents that left the scene during the last step (one [`Event::Left`] each), with
    /// their position when they left: for a pedestrian at its goal, its arrival position, which
    /// is no longer visible through [`World::agent`].
    pub fn departed(&self) -> &[(AgentId, Vec2)] {
        &self.departed
    }

    /// How agent `id` is controlled.
    pub fn control(&self, id: AgentId) -> Option<Control> {
        self.control_of.get(id as usize).copied()
    }

    /// Number of agents present.
    pub fn len(&self) -> usize {
        self.agents.len()
    }

    pub fn is_empty(&self) -> bool {
        self.agents.len() == 0
    }

    fn view(&self, i: usize) -> AgentView {
        let a = &self.agents;
        AgentView {
            id: a.id[i],
            kind: a.kind[i],
            control: a.control[i],
            shape: a.shape[i],
            position: a.pos[i],
            velocity: a.vel[i],
            acceleration: a.acc[i],
            heading: a.heading[i],
            goal: a.goal[i],
        }
    }

    /// The agents present, in slot order.
    pub fn agents(&self) -> impl Iterator<Item = AgentView> + '_ {
        (0..self.agents.len()).map(|i| self.view(i))
    }

    /// Slot of agent `id`, if present.
    pub fn slot_of(&self, id: AgentId) -> Option<usize> {
        self.agents.id.iter().position(|&x| x == id)
    }

    /// Agent `id`, if present.
    pub fn agent(&self, id: AgentId) -> Option<AgentView> {
        self.slot_of(id).map(|i| self.view(i))
    }

    /// Number of directed edges of the risk graph.
    pub fn edge_count(&self) -> usize {
        self.agents.edge_len.iter().map(|&l| l as usize).sum()
    }

    /// The risk graph at the current step as a sparse edge list, grouped by observer in slot
    /// order.
    pub fn graph_edges(&self) -> impl Iterator<Item = GraphEdge> + '_ {
        let lambda = self.params.risk.lambda;
        (0..self.agents.len()).flat_map(move |i| {
            let observer = self.agents.id[i];
            self.out_edges(i).iter().map(move |e| GraphEdge {
                observer,
                target: e.target,
                clearance: e.clearance,
                psi: e.psi,
                u: e.u,
                a: risk::adjacency(e.psi, e.u, lambda),
            })
        })
    }

    pub(crate) fn out_edges(&self, slot: usize) -> &[Edge] {
        let s = self.agents.edge_start[slot] as usize;
        &self.edges[s..s + self.agents.edge_len[slot] as usize]
    }

    /// Dense `n x n` adjacency over the present agents in slot order (for small scenes only: the
    /// world itself never stores it).
    pub fn dense_adjacency(&self) -> Vec<Vec<f64>> {
        let n = self.agents.len();
        let mut m = vec![vec![0.0; n]; n];
        let lambda = self.params.risk.lambda;
        for (i, row) in m.iter_mut().enumerate() {
            for e in self.out_edges(i) {
                row[e.target_slot as usize] = risk::adjacency(e.psi, e.u, lambda);
            }
        }
        m
    }

    fn enter_pending(&mut self, events: &mut Vec<Event>) {
        while let Some(&id) = self.pending.last() {
            let rec = &self.scenario.agents[id as usize];
            if rec.start_step > self.step {
                break;
            }
            self.pending.pop();
            if rec.end_step() < self.step {
                continue; // entirely in the past: never present.
            }
            let k = (self.step - rec.start_step) as usize;
            let pos = v2(rec.positions[k]);
            let vel = v2(rec.velocities[k]);
            let heading = recorded_heading(rec, k);
            let control = self.control_of[id as usize];
            let (shape, speed) = match rec.kind {
                AgentKind::Vehicle => (self.params.vehicle.shape, vel.norm()),
                AgentKind::Pedestrian => (
                    Shape::Disc {
                        radius: self.params.ped_radius,
                    },
                    vel.norm(),
                ),
            };
            let a = &mut self.agents;
            a.id.push(id);
            a.kind.push(rec.kind);
            a.control.push(control);
            a.shape.push(shape);
            a.pos.push(pos);
            a.vel.push(vel);
            a.acc.push(Vec2::zeros());
            a.prev_acc.push(Vec2::zeros());
            a.speed.push(speed);
            a.heading.push(heading);
            a.goal.push(v2(rec.goal()));
            a.v0.push(rec.mean_speed());
            a.initial_vel.push(vel);
            a.edge_start.push(0);
            a.edge_len.push(0);
            a.leaving.push(false);
            if self.step > 0 {
                events.push(Event::Entered { agent: id });
            }
            if let Some(e) = self.externals.iter_mut().find(|e| e.id == id) {
                e.active = true;
                e.speeds.push(speed);
                e.goal_distance = (pos - v2(rec.goal())).norm();
            }
        }
    }

    /// Removes the agents flagged `leaving`, keeping the graph consistent (edges to them dropped,
    /// target slots renumbered).
    fn remove_leaving(&mut self, events: &mut Vec<Event>) {
        if !self.agents.leaving.iter().any(|&l| l) {
            return;
        }
        let n = self.agents.len();
        self.keep.clear();
        self.keep.extend(self.agents.leaving.iter().map(|&l| !l));
        self.slot_map.clear();
        let mut next = 0u32;
        for i in 0..n {
            if self.keep[i] {
                self.slot_map.push(next);
                next += 1;
            } else {
                self.slot_map.push(NO_SLOT);
                events.push(Event::Left {
                    agent: self.agents.id[i],
                });
                self.departed.push((self.agents.id[i], self.agents.pos[i]));
            }
        }
        self.next_edges.clear();
        for i in 0..n {
            let start = self.next_edges.len() as u32;
            if self.keep[i] {
                let s = self.agents.edge_start[i] as usize;
                for e in &self.edges[s..s + self.agents.edge_len[i] as usize] {
                    let t = self.slot_map[e.target_slot as usize];
                    if t != NO_SLOT {
                        self.next_edges.push(Edge {
                            target_slot: t,
                            ..*e
                        });
                    }
                }
            }
            self.agents.edge_start[i] = start;
            self.agents.edge_len[i] = self.next_edges.len() as u32 - start;
        }
        std::mem::swap(&mut self.edges, &mut self.next_edges);
        let keep = std::mem::take(&mut self.keep);
        self.agents.retain(&keep);
        self.keep = keep;
    }

    /// Builds beliefs, clearances, risk and the graph for the current state (model.md 5b 1–2).
    fn observe(&mut self) {
        let n = self.agents.len();
        let r = self.params.perception_radius;
        let r2 = r * r;
        self.grid.rebuild(&self.agents.pos, r);
        self.next_edges.clear();
        let a = &self.agents;
        let model = self.params.cognition.prediction;
        let risk_params = &self.params.risk;
        let dt = self.params.dt;
        self.acc_norm.clear();
        self.acc_norm.extend(a.acc.iter().map(|v| v.norm()));
        let acc_norm = &self.acc_norm;
        let mut new_start = Vec::with_capacity(n);
        let mut new_len = Vec::with_capacity(n);
        for i in 0..n {
            // Mark this observer's existing beliefs so they can be found by target id in O(1).
            self.epoch += 1;
            let s = a.edge_start[i] as usize;
            for (k, e) in self.edges[s..s + a.edge_len[i] as usize].iter().enumerate() {
                self.stamp[e.target as usize] = self.epoch;
                self.stamp_edge[e.target as usize] = (s + k) as u32;
            }
            let start = self.next_edges.len();
            let xi = a.pos[i];
            let placed_i = Placed {
                shape: a.shape[i],
                position: xi,
                heading: a.heading[i],
            };
            let edges = &self.edges;
            let stamp = &self.stamp;
            let stamp_edge = &self.stamp_edge;
            let epoch = self.epoch;
            let schedule = &self.schedule;
            let out = &mut self.next_edges;
            self.grid.for_each_candidate(i, |j| {
                if j == i {
                    return;
                }
                let xj = a.pos[j];
                let d = xi - xj;
                if d.norm_squared() > r2 {
                    return;
                }
                let target = a.id[j];
                let vj = a.vel[j];
                let (belief, u) = if stamp[target as usize] == epoch {
                    let mut b = edges[stamp_edge[target as usize] as usize].belief;
                    let mu_p = b.predict(model, a.prev_acc[j] * dt);
                    let u = b.update(mu_p, vj, schedule);
                    (b, u)
                } else {
                    (Belief::first_sight(vj), 0.0)
                };
                let dist = d.norm();
                let clearance = match (a.shape[i], a.shape[j]) {
                    (Shape::Disc { radius: ri }, Shape::Disc { radius: rj }) => {
                        (dist - (ri + rj)).max(0.0)
                    }
                    _ => {
                        let placed_j = Placed {
                            shape: a.shape[j],
                            position: xj,
                            heading: a.heading[j],
                        };
                        clearance_and_normal(&placed_i, &placed_j).0
                    }
                };
                let psi = risk::risk_with(clearance, d, dist, vj, acc_norm[j], risk_params);
                out.push(Edge {
                    target,
                    target_slot: j as u32,
                    belief,
                    clearance,
                    psi,
                    u,
                });
            });
            new_start.push(start as u32);
            new_len.push((self.next_edges.len() - start) as u32);
        }
        std::mem::swap(&mut self.edges, &mut self.next_edges);
        self.agents.edge_start = new_start;
        self.agents.edge_len = new_len;
    }

    /// Advances the world by one step with the actions of the active external agents.
    ///
    /// `actions` are normalised to `[-1, 1]^2`: `[acceleration, yaw rate]` for vehicles,
    /// `[forward, left]` acceleration in the ego frame for pedestrians. A refused step changes
    /// nothing.
    pub fn step(&mut self, actions: &[(AgentId, [f64; 2])]) -> Result<StepOutcome, StepError> {
        if self.over {
            return Err(StepError::EpisodeOver);
        }
        for (k, (id, act)) in actions.iter().enumerate() {
            if !self.externals.iter().any(|e| e.id == *id && e.active) {
                return Err(StepError::NotExternal { agent: *id });
            }
            if actions[..k].iter().any(|(other, _)| other == id) {
                return Err(StepError::DuplicateAction { agent: *id });
            }
            for (index, &value) in act.iter().enumerate() {
                if !value.is_finite() {
                    return Err(StepError::NonFiniteAction {
                        agent: *id,
                        index,
                        value,
                    });
                }
            }
        }
        if let Some(e) = self
            .externals
            .iter()
            .find(|e| e.active && !actions.iter().any(|(id, _)| *id == e.id))
        {
            return Err(StepError::MissingAction { agent: e.id });
        }

        let mut events = Vec::new();
        self.departed.clear();
        // 1. External agents whose episode ended last step leave now.
        self.remove_leaving(&mut events);

        // 2. Move every agent from t to t + 1.
        let dt = self.params.dt;
        let n = self.agents.len();
        let mut clipped_of: Vec<(AgentId, bool, f64)> = Vec::with_capacity(actions.len());
        let mut next = std::mem::take(&mut self.next);
        next.clone_from(&self.agents);
        for i in 0..n {
            let id = self.agents.id[i];
            let (pos, vel, speed, heading) = match self.agents.control[i] {
                Control::External => {
                    let act = actions
                        .iter()
                        .find(|(a, _)| *a == id)
                        .map(|(_, a)| *a)
                        .unwrap_or([0.0; 2]);
                    self.move_external(i, act, &mut clipped_of)
                }
                Control::Replay => match self.replay_state(i, self.step + 1) {
                    Some(s) => s,
                    None => {
                        next.leaving[i] = true;
                        (
                            self.agents.pos[i],
                            self.agents.vel[i],
                            self.agents.speed[i],
                            self.agents.heading[i],
                        )
                    }
                },
                Control::Model(m) => self.move_pedestrian(i, m),
            };
            next.prev_acc[i] = self.agents.acc[i];
            next.acc[i] = (vel - self.agents.vel[i]) / dt;
            next.pos[i] = pos;
            next.vel[i] = vel;
            next.speed[i] = speed;
            next.heading[i] = heading;
        }
        std::mem::swap(&mut self.agents, &mut next);
        self.next = next;
        self.step += 1;

        // 3. Arrivals and departures of pedestrians, entries.
        let goal_r = self.params.ped_goal_radius;
        for i in 0..n {
            let simulated_ped = self.agents.kind[i] == AgentKind::Pedestrian
                && matches!(self.agents.control[i], Control::Model(_));
            if simulated_ped && (self.agents.pos[i] - self.agents.goal[i]).norm() <= goal_r {
                self.agents.leaving[i] = true;
                events.push(Event::GoalReached {
                    agent: self.agents.id[i],
                });
            }
        }
        self.remove_leaving(&mut events);
        self.enter_pending(&mut events);

        // 4. Beliefs, risk and graph at t + 1.
        self.observe();

        // 5. Events and rewards.
        for i in 0..self.agents.len() {
            for e in self.out_edges(i) {
                if e.clearance <= 0.0 && self.agents.id[i] < e.target {
                    events.push(Event::Collision {
                        a: self.agents.id[i],
                        b: e.target,
                    });
                }
            }
        }
        let mut outcome = StepOutcome {
            step: self.step,
            agents: Vec::new(),
            events,
            episode_over: false,
        };
        let truncated = self.step >= self.horizon;
        for k in 0..self.externals.len() {
            if !self.externals[k].active {
                continue;
            }
            let id = self.externals[k].id;
            let (clipped, omega) = clipped_of
                .iter()
                .find(|(a, _, _)| *a == id)
                .map_or((false, 0.0), |c| (c.1, c.2));
            let agent_outcome =
                self.external_outcome(k, clipped, omega, truncated, &mut outcome.events);
            outcome.agents.push(agent_outcome);
        }
        // Over when every external agent has entered and finished (one whose record starts
        // later keeps the episode running until it enters), or at the horizon.
        let all_finished = !self.externals.is_empty()
            && self
                .externals
                .iter()
                .all(|e| !e.active && !e.speeds.is_empty());
        self.over = truncated || all_finished;
        outcome.episode_over = self.over;
        Ok(outcome)
    }

    fn move_external(
        &self,
        i: usize,
        act: [f64; 2],
        clipped_of: &mut Vec<(AgentId, bool, f64)>,
    ) -> (Vec2, Vec2, f64, f64) {
        let a = &self.agents;
        let dt = self.params.dt;
        match a.kind[i] {
            AgentKind::Vehicle => {
                let (cmd, clipped) = vehicle::map_action(act, &self.params.vehicle);
                clipped_of.push((a.id[i], clipped, cmd.omega));
                let s = vehicle::unicycle_step(
                    UnicycleState {
                        position: a.pos[i],
                        speed: a.speed[i],
                        heading: a.heading[i],
                    },
                    cmd,
                    dt,
                    self.params.vehicle.speed_max,
                );
                let vel = Vec2::new(s.heading.cos(), s.heading.sin()) * s.speed;
                (s.position, vel, s.speed, s.heading)
            }
            AgentKind::Pedestrian => {
                let f = act[0].clamp(-1.0, 1.0);
                let l = act[1].clamp(-1.0, 1.0);
                clipped_of.push((a.id[i], f != act[0] || l != act[1], 0.0));
                let (s, c) = a.heading[i].sin_cos();
                let acc = Vec2::new(c * f - s * l, s * f + c * l) * self.params.ped_acc_max;
                let (pos, vel) =
                    pedestrian::integrate(a.pos[i], a.vel[i], acc, dt, self.params.ped_speed_max);
                let speed = vel.norm();
                let heading = if speed > 0.0 {
                    vel.y.atan2(vel.x)
                } else {
                    a.heading[i]
                };
                (pos, vel, speed, heading)
            }
        }
    }

    fn replay_state(&self, i: usize, step: u32) -> Option<(Vec2, Vec2, f64, f64)> {
        let rec = &self.scenario.agents[self.agents.id[i] as usize];
        let k = step.checked_sub(rec.start_step)? as usize;
        let pos = v2(*rec.positions.get(k)?);
        let vel = v2(rec.velocities[k]);
        Some((pos, vel, vel.norm(), recorded_heading(rec, k)))
    }

    fn move_pedestrian(&self, i: usize, model: PedestrianModel) -> (Vec2, Vec2, f64, f64) {
        let a = &self.agents;
        let dt = self.params.dt;
        let vmax = self.params.ped_speed_max;
        let (pos, vel) = match self.params.pedestrians.for_model(model) {
            None => {
                // `cv`: the initial velocity vector for the whole episode, under the pedestrian
                // speed cap (model.md 1) like every simulated pedestrian.
                let v = pedestrian::clip_norm(a.initial_vel[i], vmax);
                (a.pos[i] + v * dt, v)
            }
            Some(p) => {
                let xi = a.pos[i];
                let f_goal = pedestrian::goal_force(xi, a.vel[i], a.goal[i], a.v0[i], p.tau);
                let interactions = self.out_edges(i).iter().map(|e| {
                    let j = e.target_slot as usize;
                    let normal = match a.shape[j] {
                        Shape::Disc { .. } => {
                            let d = xi - a.pos[j];
                            let n = d.norm();
                            if n > 0.0 {
                                d / n
                            } else {
                                Vec2::zeros()
                            }
                        }
                        Shape::Rect { .. } => {
                            let me = Placed {
                                shape: a.shape[i],
                                position: xi,
                                heading: a.heading[i],
                            };
                            let other = Placed {
                                shape: a.shape[j],
                                position: a.pos[j],
                                heading: a.heading[j],
                            };
                            clearance_and_normal(&me, &other).1
                        }
                    };
                    Interaction {
                        other_is_vehicle: a.kind[j] == AgentKind::Vehicle,
                        clearance: e.clearance,
                        normal,
                        psi: e.psi,
                        u: e.u,
                    }
                });
                let force = pedestrian::total_force(model, p, f_goal, interactions);
                pedestrian::integrate(xi, a.vel[i], force, dt, vmax)
            }
        };
        let speed = vel.norm();
        let heading = if speed > 0.0 {
            vel.y.atan2(vel.x)
        } else {
            a.heading[i]
        };
        (pos, vel, speed, heading)
    }

    fn external_outcome(
        &mut self,
        k: usize,
        action_clipped: bool,
        omega: f64,
        truncated: bool,
        events: &mut Vec<Event>,
    ) -> AgentOutcome {
        let w = self.params.reward;
        let dt = self.params.dt;
        let id = self.externals[k].id;
        let mut reward = RewardTerms::default();
        let Some(i) = self.slot_of(id) else {
            // Left with its record (cannot happen to an external agent, kept total for safety).
            self.externals[k].active = false;
            return AgentOutcome {
                agent: id,
                reward,
                terminated: true,
                truncated: false,
                action_clipped,
                metrics: None,
            };
        };
        let is_vehicle = self.agents.kind[i] == AgentKind::Vehicle;
        let goal = self.agents.goal[i];
        let d_now = (self.agents.pos[i] - goal).norm();
        reward.progress = w.progress * (self.externals[k].goal_distance - d_now);
        self.externals[k].goal_distance = d_now;
        let goal_radius = if is_vehicle {
            self.params.vehicle.goal_radius
        } else {
            self.params.ped_goal_radius
        };
        let arrived = d_now <= goal_radius;
        let mut collided = false;
        let mut c_min = f64::INFINITY;
        for e in self.out_edges(i) {
            let other_is_ped = self.agents.kind[e.target_slot as usize] == AgentKind::Pedestrian;
            // Vehicles collide with pedestrians and with other vehicles; a pedestrian with vehicles.
            if e.clearance <= 0.0 && (is_vehicle || !other_is_ped) {
                collided = true;
            }
            if other_is_ped {
                c_min = c_min.min(e.clearance);
            }
        }
        if arrived {
            reward.success = w.success;
            events.push(Event::GoalReached { agent: id });
        }
        if collided {
            reward.collision = w.collision;
        }
        if c_min < w.danger_clearance {
            reward.danger = w.danger * (c_min - w.danger_clearance);
        }
        let speed = self.agents.speed[i];
        let track = &mut self.externals[k];
        let prev_speed = track.speeds.last().copied().unwrap_or(speed);
        let acc = (speed - prev_speed) / dt;
        let jerk = track.last_acc.map_or(0.0, |a| (acc - a) / dt);
        track.last_acc = Some(acc);
        track.speeds.push(speed);
        reward.comfort = -w.jerk_penalty * jerk * jerk - w.yaw_rate_penalty * omega * omega;
        let terminated = arrived || collided;
        let mut metrics = None;
        if terminated || truncated {
            let status = if collided {
                EpisodeStatus::Collision
            } else if arrived {
                EpisodeStatus::Success
            } else {
                EpisodeStatus::Timeout
            };
            track.status = Some(status);
            track.active = false;
            metrics = Some(EpisodeMetrics::from_speeds(status, &track.speeds, dt));
            self.agents.leaving[i] = true;
        }
        AgentOutcome {
            agent: id,
            reward,
            terminated,
            truncated: truncated && !terminated,
            action_clipped,
            metrics,
        }
    }
}
