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

use std::mem::MaybeUninit;
use std::ops::Range;
use std::sync::Arc;

use crate::cognition::{Belief, VarianceSchedule};
use crate::fastmath;
use crate::geometry::{
    self, clearance_and_normal, clearance_and_normal_oriented, Placed, Shape, Vec2,
};
use crate::grid::Grid;
use crate::helpers::Helpers;
use crate::metrics::{EpisodeMetrics, EpisodeStatus};
use crate::params::{ParamError, PedestrianModel, SocialForceParams, WorldParams};
use crate::pedestrian::{self, Interaction};
use crate::risk;
use crate::scenario::{AgentKind, AgentRecord, Scenario};
use crate::vehicle::{self, UnicycleState};

#[cfg(target_arch = "x86_64")]
mod avx512;

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

/// One directed edge `i -> j` of the risk graph with `i`'s belief about `j` (a copy read out of
/// the [`EdgeStore`]).
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

/// Every edge of the risk graph, structure of arrays (one entry per edge in each), grouped by
/// observer in slot order. The observe pass writes each field as one contiguous run.
#[derive(Debug, Default)]
struct EdgeStore {
    target: Vec<AgentId>,
    slot: Vec<u32>,
    /// The observer's belief about the target, by field ([`Belief::mu`] and
    /// [`Belief::updates`]): the vectorised observe pass loads and stores each as one run.
    mu_x: Vec<f64>,
    mu_y: Vec<f64>,
    updates: Vec<u32>,
    clearance: Vec<f64>,
    psi: Vec<f64>,
    u: Vec<f64>,
}

/// Room an edge store is given beyond `len` edges when (re)allocated: the graph of the next
/// steps is about as large, and a store that is short must be allocated afresh (megabytes of
/// untouched pages at large `N`).
fn edge_room(len: usize) -> usize {
    len + len / 4 + 64
}

impl Clone for EdgeStore {
    /// A copy with room to grow (see [`edge_room`]), and at least the original's, so that
    /// stepping a cloned world does not reallocate its stores.
    fn clone(&self) -> Self {
        fn copy<T: Copy>(v: &[T], capacity: usize) -> Vec<T> {
            let mut c = Vec::with_capacity(capacity);
            c.extend_from_slice(v);
            c
        }
        let capacity = edge_room(self.len()).max(self.target.capacity());
        Self {
            target: copy(&self.target, capacity),
            slot: copy(&self.slot, capacity),
            mu_x: copy(&self.mu_x, capacity),
            mu_y: copy(&self.mu_y, capacity),
            updates: copy(&self.updates, capacity),
            clearance: copy(&self.clearance, capacity),
            psi: copy(&self.psi, capacity),
            u: copy(&self.u, capacity),
        }
    }
}

impl EdgeStore {
    fn len(&self) -> usize {
        self.target.len()
    }

    fn clear(&mut self) {
        self.truncate(0);
    }

    fn truncate(&mut self, len: usize) {
        self.target.truncate(len);
        self.slot.truncate(len);
        self.mu_x.truncate(len);
        self.mu_y.truncate(len);
        self.updates.truncate(len);
        self.clearance.truncate(len);
        self.psi.truncate(len);
        self.u.truncate(len);
    }

    /// Empties the store and makes room for about `len` edges, and some, without reallocating
    /// (a fresh allocation, not a copy, when the capacity is short: the old contents are dead).
    fn clear_with_capacity(&mut self, len: usize) {
        fn fresh<T>(v: &mut Vec<T>, len: usize) {
            v.clear();
            if v.capacity() < len + len / 16 + 64 {
                *v = Vec::with_capacity(edge_room(len));
            }
        }
        fresh(&mut self.target, len);
        fresh(&mut self.slot, len);
        fresh(&mut self.mu_x, len);
        fresh(&mut self.mu_y, len);
        fresh(&mut self.updates, len);
        fresh(&mut self.clearance, len);
        fresh(&mut self.psi, len);
        fresh(&mut self.u, len);
    }

    /// Makes room for `m` more edges in every field.
    fn reserve(&mut self, m: usize) {
        self.target.reserve(m);
        self.slot.reserve(m);
        self.mu_x.reserve(m);
        self.mu_y.reserve(m);
        self.updates.reserve(m);
        self.clearance.reserve(m);
        self.psi.reserve(m);
        self.u.reserve(m);
    }

    /// A sink over the next `m` entries of every field's spare capacity (reserve them first).
    fn sink(&mut self, m: usize) -> EdgeSink<'_> {
        EdgeSink {
            target: &mut self.target.spare_capacity_mut()[..m],
            slot: &mut self.slot.spare_capacity_mut()[..m],
            mu_x: &mut self.mu_x.spare_capacity_mut()[..m],
            mu_y: &mut self.mu_y.spare_capacity_mut()[..m],
            updates: &mut self.updates.spare_capacity_mut()[..m],
            clearance: &mut self.clearance.spare_capacity_mut()[..m],
            psi: &mut self.psi.spare_capacity_mut()[..m],
            u: &mut self.u.spare_capacity_mut()[..m],
        }
    }

    /// Makes the next `m` entries of every field part of the store.
    ///
    /// # Safety
    /// Those entries must have been written, every field of each (through [`EdgeStore::sink`]).
    unsafe fn commit(&mut self, m: usize) {
        let len = self.len() + m;
        self.target.set_len(len);
        self.slot.set_len(len);
        self.mu_x.set_len(len);
        self.mu_y.set_len(len);
        self.updates.set_len(len);
        self.clearance.set_len(len);
        self.psi.set_len(len);
        self.u.set_len(len);
    }

    fn push(&mut self, e: Edge) {
        self.target.push(e.target);
        self.slot.push(e.target_slot);
        self.mu_x.push(e.belief.mu.x);
        self.mu_y.push(e.belief.mu.y);
        self.updates.push(e.belief.updates);
        self.clearance.push(e.clearance);
        self.psi.push(e.psi);
        self.u.push(e.u);
    }

    #[inline(always)]
    fn belief(&self, k: usize) -> Belief {
        Belief {
            mu: Vec2::new(self.mu_x[k], self.mu_y[k]),
            updates: self.updates[k],
        }
    }

    #[inline]
    fn get(&self, k: usize) -> Edge {
        Edge {
            target: self.target[k],
            target_slot: self.slot[k],
            belief: self.belief(k),
            clearance: self.clearance[k],
            psi: self.psi[k],
            u: self.u[k],
        }
    }
}

/// Entries of an [`EdgeStore`] still to be written, one run per field, the same length each.
/// The observe pass writes edges through it; a threaded pass splits one sink into disjoint
/// runs, one per worker, so that every worker writes its edges where they belong and none are
/// copied afterwards.
struct EdgeSink<'a> {
    target: &'a mut [MaybeUninit<AgentId>],
    slot: &'a mut [MaybeUninit<u32>],
    mu_x: &'a mut [MaybeUninit<f64>],
    mu_y: &'a mut [MaybeUninit<f64>],
    updates: &'a mut [MaybeUninit<u32>],
    clearance: &'a mut [MaybeUninit<f64>],
    psi: &'a mut [MaybeUninit<f64>],
    u: &'a mut [MaybeUninit<f64>],
}

impl<'a> EdgeSink<'a> {
    fn len(&self) -> usize {
        self.target.len()
    }

    /// The first `m` entries as a sink of their own; `self` keeps the rest.
    fn split_front(&mut self, m: usize) -> EdgeSink<'a> {
        fn split<'a, T>(v: &mut &'a mut [T], m: usize) -> &'a mut [T] {
            let (front, rest) = std::mem::take(v).split_at_mut(m);
            *v = rest;
            front
        }
        EdgeSink {
            target: split(&mut self.target, m),
            slot: split(&mut self.slot, m),
            mu_x: split(&mut self.mu_x, m),
            mu_y: split(&mut self.mu_y, m),
            updates: split(&mut self.updates, m),
            clearance: split(&mut self.clearance, m),
            psi: split(&mut self.psi, m),
            u: split(&mut self.u, m),
        }
    }
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
                return fastmath::atan2(v[1], v[0]);
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
    edges: EdgeStore,
    /// Agents not yet entered, by descending start step (the next to enter is last).
    pending: Vec<AgentId>,
    externals: Vec<ExternalTrack>,
    /// Agents removed during the last step, with their position when they left.
    departed: Vec<(AgentId, Vec2)>,
    /// The buffers [`World::step`] works in ([`World::step_in`] is given others).
    scratch: StepScratch,
    /// Per slot, the sum of the weighted social-force repulsions on a simulated pedestrian and its
    /// largest repulsion weight, from the edges the last observe pass built (valid while
    /// `forces_valid`: until agents are removed).
    rep_force: Vec<Vec2>,
    rep_max_w: Vec<f64>,
    forces_valid: bool,
    /// Per slot, whether the observer has an edge of clearance `<= 0` (from the last observe).
    contact: Vec<bool>,
    /// Per external agent moved by the step: whether its action was clipped, and its yaw rate.
    clipped_of: Vec<(AgentId, bool, f64)>,
    /// Threads the observe pass may use (1 by default); see [`World::set_threads`].
    threads: usize,
    /// The threads a step of more than one thread runs its other workers on (shared by clones).
    helpers: Option<Arc<Helpers>>,
    /// The observe pass's instruction-set variant (the widest the CPU runs, by default).
    kernels: Kernels,
}

const NO_SLOT: u32 = u32::MAX;

/// The buffers one step works in. They carry nothing from one step to the next, so any world
/// may step in any scratch: a thread that steps many small worlds in turn (a server's batch)
/// gives them one scratch ([`World::step_in`]), which stays in the nearer caches, instead of
/// each world touching its own. Cloning gives an empty scratch.
#[derive(Debug, Default)]
pub struct StepScratch {
    grid: Grid,
    /// The new position, velocity, speed and heading of every agent, collected by the move.
    moved: Vec<(Vec2, Vec2, f64, f64)>,
    next_edges: EdgeStore,
    keep: Vec<bool>,
    slot_map: Vec<u32>,
    targets: Vec<TargetInfo>,
    /// `prev_acc * dt` of every agent: its last observed change of velocity (for the
    /// constant-acceleration prediction; apart from `targets`, which the common case reads).
    last_change: Vec<Vec2>,
    /// [`geometry::axes`] of every agent (computed once per step, not once per edge).
    axes: Vec<(f64, f64)>,
    /// One per observe worker (thread).
    workers: Vec<ObserveWorker>,
}

impl Clone for StepScratch {
    /// An empty scratch: the contents are dead between steps, so a cloned world (an autoreset
    /// copies a fresh world every episode) need not copy them.
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl StepScratch {
    pub fn new() -> Self {
        Self::default()
    }
}

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
            edges: EdgeStore::default(),
            pending,
            externals,
            departed: Vec::new(),
            scratch: StepScratch::default(),
            rep_force: Vec::new(),
            rep_max_w: Vec::new(),
            forces_valid: false,
            contact: Vec::new(),
            clipped_of: Vec::new(),
            threads: 1,
            helpers: None,
            kernels: Kernels::detect(),
        };
        let mut events = Vec::new();
        w.enter_pending(&mut events);
        let mut scratch = StepScratch::default();
        w.observe(&mut scratch);
        // The first step's observe fills the store the initial graph was built in (now the
        // worker's): give it room now rather than in that step.
        scratch.workers[0].edges.clear_with_capacity(w.edges.len());
        w.scratch = scratch;
        for e in &mut w.externals {
            e.active = w.agents.id.contains(&e.id);
        }
        Ok(w)
    }

    pub fn params(&self) -> &WorldParams {
        &self.params
    }

    /// Sets how many threads a step may use (at least 1; default 1). Only large scenes (at least
    /// [`PARALLEL_MIN_AGENTS`] agents) are split; results are bit-identical for every thread
    /// count. Not part of the world's parameters: a server running many worlds keeps 1.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.max(1);
        let wanted = self.threads - 1;
        if self.helpers.as_ref().map_or(0, |h| h.len()) != wanted {
            // Fewer may start (the rest of a step then runs on the stepping thread).
            self.helpers = (wanted > 0).then(|| Arc::new(Helpers::new(wanted, "sim-step")));
        }
    }

    /// Steps with the `kernels` variant of the observe pass from now on (same results, other
    /// speed); refused, changing nothing, when the CPU does not run it.
    pub fn use_kernels(&mut self, kernels: Kernels) -> Result<(), KernelsUnavailable> {
        if !kernels.is_available() {
            return Err(KernelsUnavailable(kernels));
        }
        self.kernels = kernels;
        Ok(())
    }

    /// The variant of the observe pass this world steps with ([`Kernels::detect`] unless
    /// changed).
    pub fn kernels(&self) -> Kernels {
        self.kernels
    }

    /// The thread count set by [`World::set_threads`].
    pub fn threads(&self) -> usize {
        self.threads
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

    pub(crate) fn view(&self, i: usize) -> AgentView {
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
            self.out_edges(i).map(move |e| GraphEdge {
                observer,
                target: e.target,
                clearance: e.clearance,
                psi: e.psi,
                u: e.u,
                a: risk::adjacency(e.psi, e.u, lambda),
            })
        })
    }

    pub(crate) fn out_edges(&self, slot: usize) -> impl Iterator<Item = Edge> + '_ {
        self.out_range(slot).map(move |k| self.edges.get(k))
    }

    /// Indices of agent `slot`'s out-edges in the edge store.
    fn out_range(&self, slot: usize) -> Range<usize> {
        let s = self.agents.edge_start[slot] as usize;
        s..s + self.agents.edge_len[slot] as usize
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
    fn remove_leaving(&mut self, s: &mut StepScratch, events: &mut Vec<Event>) {
        if !self.agents.leaving.iter().any(|&l| l) {
            return;
        }
        let n = self.agents.len();
        s.keep.clear();
        s.keep.extend(self.agents.leaving.iter().map(|&l| !l));
        s.slot_map.clear();
        let mut next = 0u32;
        for i in 0..n {
            if s.keep[i] {
                s.slot_map.push(next);
                next += 1;
            } else {
                s.slot_map.push(NO_SLOT);
                events.push(Event::Left {
                    agent: self.agents.id[i],
                });
                self.departed.push((self.agents.id[i], self.agents.pos[i]));
            }
        }
        self.forces_valid = false;
        s.next_edges.clear();
        for i in 0..n {
            let start = s.next_edges.len() as u32;
            if s.keep[i] {
                let first = self.agents.edge_start[i] as usize;
                for k in first..first + self.agents.edge_len[i] as usize {
                    let e = self.edges.get(k);
                    let t = s.slot_map[e.target_slot as usize];
                    if t != NO_SLOT {
                        s.next_edges.push(Edge {
                            target_slot: t,
                            ..e
                        });
                    }
                }
            }
            self.agents.edge_start[i] = start;
            self.agents.edge_len[i] = s.next_edges.len() as u32 - start;
        }
        std::mem::swap(&mut self.edges, &mut s.next_edges);
        self.agents.retain(&s.keep);
    }

    /// Builds beliefs, clearances, risk and the graph for the current state (model.md 5b 1–2),
    /// and the social-force repulsions the next move will use (they depend only on the graph).
    fn observe(&mut self, s: &mut StepScratch) {
        let n = self.agents.len();
        let r = self.params.perception_radius;
        s.grid.rebuild(&self.agents.pos, r);
        let a = &self.agents;
        let dt = self.params.dt;
        s.targets.clear();
        s.targets.extend((0..n).map(|j| TargetInfo {
            pos: a.pos[j],
            vel: a.vel[j],
            acc_norm: a.acc[j].norm(),
            radius: match a.shape[j] {
                Shape::Disc { radius } => radius,
                Shape::Rect { .. } => f64::NAN,
            },
            id: a.id[j],
            veh: if a.kind[j] == AgentKind::Vehicle {
                1.0
            } else {
                0.0
            },
        }));
        s.last_change.clear();
        s.last_change.extend(a.prev_acc.iter().map(|&p| p * dt));
        s.axes.clear();
        s.axes
            .extend((0..n).map(|j| geometry::axes(a.shape[j], a.heading[j])));
        let threads = if n >= PARALLEL_MIN_AGENTS {
            self.threads.min(n)
        } else {
            1
        };
        let n_total = self.scenario.agents.len();
        while s.workers.len() < threads {
            s.workers.push(ObserveWorker::new(n_total));
        }
        for w in &mut s.workers[..threads] {
            w.fit_agents(n_total);
        }
        let inputs = ObserveInputs {
            targets: &s.targets,
            last_change: &s.last_change,
            axes: &s.axes,
            agents: &self.agents,
            old: &self.edges,
            grid: &s.grid,
            schedule: &self.schedule,
            params: &self.params,
            r2: r * r,
            kernels: self.kernels,
            forces: PedestrianModel::ALL.map(|m| {
                debug_assert_eq!(PedestrianModel::ALL[model_index(m)], m);
                self.params
                    .pedestrians
                    .for_model(m)
                    .map(|p| ForceConsts::new(m, p))
            }),
        };
        let workers = &mut s.workers[..threads];
        if threads == 1 {
            workers[0].run(&inputs, 0..n);
        } else {
            // Two parallel halves: the targets of every observer (so that each worker knows
            // where in the store its edges go), then the edges, each worker writing its own
            // run of one store. Copying the workers' stores together instead cost about a
            // fifth of a two-thread step at N = 1 000.
            // Observers split by last step's edge counts (and a fixed cost per observer), so
            // that the workers finish together; any split gives the same bits.
            let weight = |i: usize| u64::from(self.agents.edge_len[i]) + 8;
            let total_weight: u64 = (0..n).map(weight).sum();
            let mut bounds = vec![0; threads + 1];
            let (mut t, mut acc) = (1, 0);
            for i in 0..n {
                acc += weight(i);
                while t < threads && acc * threads as u64 >= total_weight * t as u64 {
                    bounds[t] = i + 1;
                    t += 1;
                }
            }
            // Every bound below `threads` is set by the last observer (`acc` is then the total).
            bounds[threads] = n;
            debug_assert!(bounds.windows(2).all(|b| b[0] <= b[1]));
            let range = |t: usize| bounds[t]..bounds[t + 1];
            let helpers = self
                .helpers
                .as_deref()
                .expect("`set_threads` starts the helpers of a world of several threads");
            let run = |jobs: Vec<Box<dyn FnOnce() + Send + '_>>, here: &mut dyn FnMut()| {
                let ok = helpers.run(jobs, here);
                assert!(ok.iter().all(|&ok| ok), "an observe worker panicked");
            };
            {
                let (first, rest) = workers.split_first_mut().expect("at least one worker");
                let inputs = &inputs;
                let jobs = rest
                    .iter_mut()
                    .enumerate()
                    .map(|(t, w)| {
                        Box::new(move || w.gather_all(inputs, range(t + 1)))
                            as Box<dyn FnOnce() + Send + '_>
                    })
                    .collect();
                run(jobs, &mut || first.gather_all(inputs, range(0)));
            }
            let total: usize = workers.iter().map(|w| w.cands.len()).sum();
            let mut store = std::mem::take(&mut workers[0].edges);
            store.clear_with_capacity(total); // room for `total` and more: no reserve needed
            let mut sink = store.sink(total);
            {
                let (first, rest) = workers.split_first_mut().expect("at least one worker");
                let inputs = &inputs;
                let first_out = sink.split_front(first.cands.len());
                let jobs = rest
                    .iter_mut()
                    .enumerate()
                    .map(|(t, w)| {
                        let out = sink.split_front(w.cands.len());
                        Box::new(move || w.edges_into(inputs, range(t + 1), out))
                            as Box<dyn FnOnce() + Send + '_>
                    })
                    .collect();
                let mut first_out = Some(first_out);
                run(jobs, &mut || {
                    let out = first_out.take().expect("runs once");
                    first.edges_into(inputs, range(0), out)
                });
            }
            // SAFETY: the workers' runs cover the `total` entries (their lengths add up), and
            // each worker wrote every field of every entry of its run (`observer_edges`).
            unsafe { store.commit(total) };
            workers[0].edges = store;
        }
        // The workers' outputs are in observer order.
        std::mem::swap(&mut self.edges, &mut s.workers[0].edges);
        self.rep_force.clear();
        self.rep_max_w.clear();
        self.contact.clear();
        let a = &mut self.agents;
        let mut start = 0u32;
        let mut i = 0;
        for w in &s.workers[..threads] {
            for &len in &w.len {
                a.edge_start[i] = start;
                a.edge_len[i] = len;
                start += len;
                i += 1;
            }
            self.rep_force.extend_from_slice(&w.force);
            self.rep_max_w.extend_from_slice(&w.max_w);
            self.contact.extend_from_slice(&w.contact);
        }
        debug_assert_eq!(i, n);
        debug_assert_eq!(start as usize, self.edges.len());
        self.forces_valid = true;
    }

    /// Advances the world by one step with the actions of the active external agents.
    ///
    /// `actions` are normalised to `[-1, 1]^2`: `[acceleration, yaw rate]` for vehicles,
    /// `[forward, left]` acceleration in the ego frame for pedestrians. A refused step changes
    /// nothing.
    pub fn step(&mut self, actions: &[(AgentId, [f64; 2])]) -> Result<StepOutcome, StepError> {
        let mut scratch = std::mem::take(&mut self.scratch);
        let out = self.step_in(&mut scratch, actions);
        self.scratch = scratch;
        out
    }

    /// [`World::step`] working in `scratch` instead of the world's own buffers (same result, to
    /// the bit): for a thread that steps many worlds in turn.
    pub fn step_in(
        &mut self,
        scratch: &mut StepScratch,
        actions: &[(AgentId, [f64; 2])],
    ) -> Result<StepOutcome, StepError> {
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
        self.remove_leaving(scratch, &mut events);

        // 2. Move every agent from t to t + 1.
        let dt = self.params.dt;
        let n = self.agents.len();
        let mut clipped_of = std::mem::take(&mut self.clipped_of);
        clipped_of.clear();
        // Every move reads the state at `t`: the new states are collected first, then written.
        let mut moved = std::mem::take(&mut scratch.moved);
        moved.clear();
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
                        // Past its record: it stays where it was and leaves below.
                        self.agents.leaving[i] = true;
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
            moved.push((pos, vel, speed, heading));
        }
        let a = &mut self.agents;
        for (i, &(pos, vel, speed, heading)) in moved.iter().enumerate() {
            a.prev_acc[i] = a.acc[i];
            a.acc[i] = (vel - a.vel[i]) / dt;
            a.pos[i] = pos;
            a.vel[i] = vel;
            a.speed[i] = speed;
            a.heading[i] = heading;
        }
        scratch.moved = moved;
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
        self.remove_leaving(scratch, &mut events);
        self.enter_pending(&mut events);

        // 4. Beliefs, risk and graph at t + 1.
        self.observe(scratch);

        // 5. Events and rewards.
        for i in 0..self.agents.len() {
            if !self.contact[i] {
                continue;
            }
            let range = self.out_range(i);
            let (targets, clearances) = (
                &self.edges.target[range.clone()],
                &self.edges.clearance[range],
            );
            let me = self.agents.id[i];
            for (&target, &clearance) in targets.iter().zip(clearances) {
                if clearance <= 0.0 && me < target {
                    events.push(Event::Collision { a: me, b: target });
                }
            }
        }
        let mut outcome = StepOutcome {
            step: self.step,
            agents: Vec::with_capacity(self.externals.len()),
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
        self.clipped_of = clipped_of;
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
                    fastmath::atan2(vel.y, vel.x)
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
                if self.forces_valid {
                    // The repulsions were summed by the observe pass that built the edges.
                    let force = f_goal * pedestrian::goal_weight(model, p, self.rep_max_w[i])
                        + self.rep_force[i];
                    return finish_move(
                        pedestrian::integrate(xi, a.vel[i], force, dt, vmax),
                        a.heading[i],
                    );
                }
                let interactions = self.out_edges(i).map(|e| {
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
        finish_move((pos, vel), a.heading[i])
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

/// Scenes with at least this many agents split the observe pass over the threads set by
/// [`World::set_threads`]; smaller ones always run on the caller's thread.
pub const PARALLEL_MIN_AGENTS: usize = 512;

/// Speed and heading of a moved pedestrian (the heading is kept while it stands still).
fn finish_move((pos, vel): (Vec2, Vec2), heading: f64) -> (Vec2, Vec2, f64, f64) {
    let speed = vel.norm();
    let heading = if speed > 0.0 {
        fastmath::atan2(vel.y, vel.x)
    } else {
        heading
    };
    (pos, vel, speed, heading)
}

/// What an observer reads of a target, gathered once per observe pass into one record per slot
/// (one cache line and one bounds check per edge instead of one per field). `repr(C)`, as the
/// AVX-512 pass gathers its fields by offset, and one cache line each.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
struct TargetInfo {
    pos: Vec2,
    vel: Vec2,
    acc_norm: f64,
    /// Disc radius; NaN for a rectangle.
    radius: f64,
    /// 1 for a vehicle, 0 for a pedestrian (as the force loop selects on it).
    veh: f64,
    id: AgentId,
}

const _: () = assert!(std::mem::size_of::<TargetInfo>() == 64);

/// What every observe worker reads: the state, the previous edges (beliefs), the grid.
struct ObserveInputs<'a> {
    targets: &'a [TargetInfo],
    /// Each target's last observed change of velocity, by slot.
    last_change: &'a [Vec2],
    /// [`geometry::axes`] by slot.
    axes: &'a [(f64, f64)],
    agents: &'a Agents,
    old: &'a EdgeStore,
    grid: &'a Grid,
    schedule: &'a VarianceSchedule,
    params: &'a WorldParams,
    r2: f64,
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    kernels: Kernels,
    /// Social-force constants per pedestrian model (by [`model_index`]), computed outside the
    /// worker: in memory, the force loop selects between loaded constants (built in the loop,
    /// `-1/B` was folded into one division per edge).
    forces: [Option<ForceConsts>; PedestrianModel::ALL.len()],
}

/// Index of `model` in [`PedestrianModel::ALL`].
fn model_index(model: PedestrianModel) -> usize {
    match model {
        PedestrianModel::Cv => 0,
        PedestrianModel::Sfm => 1,
        PedestrianModel::RaSfm => 2,
        PedestrianModel::CrSfm => 3,
        PedestrianModel::Replay => 4,
    }
}

/// Which compiled variant of the observe pass a world runs. Every variant computes the same
/// bits; they differ only in speed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kernels {
    /// Baseline instructions of the build target.
    Portable,
    /// AVX2 (x86-64 CPUs that report it at run time): the per-edge loops four lanes wide.
    Avx2,
    /// AVX-512 F, DQ and VL besides AVX2: the per-edge loops eight lanes wide, and the belief
    /// updates by gathers.
    Avx512,
}

impl Kernels {
    /// The widest variant this CPU runs (what a new world uses).
    pub fn detect() -> Self {
        [Kernels::Avx512, Kernels::Avx2]
            .into_iter()
            .find(|k| k.is_available())
            .unwrap_or(Kernels::Portable)
    }

    /// Whether this CPU runs the variant.
    pub fn is_available(self) -> bool {
        match self {
            Kernels::Portable => true,
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx2 => std::is_x86_feature_detected!("avx2"),
            #[cfg(target_arch = "x86_64")]
            Kernels::Avx512 => {
                std::is_x86_feature_detected!("avx2")
                    && std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx512dq")
                    && std::is_x86_feature_detected!("avx512vl")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// Every variant this CPU runs, narrowest first.
    pub fn available() -> Vec<Self> {
        [Kernels::Portable, Kernels::Avx2, Kernels::Avx512]
            .into_iter()
            .filter(|k| k.is_available())
            .collect()
    }
}

/// [`World::use_kernels`] with a variant this CPU does not run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("this CPU does not run the {0:?} kernels")]
pub struct KernelsUnavailable(pub Kernels);

/// Social-force constants of one observing simulated pedestrian.
#[derive(Clone, Copy)]
struct ForceConsts {
    /// `sfm`: every repulsion weight is 1.
    unit_weight: bool,
    a_veh: f64,
    /// `-1 / B`: the repulsion is `A exp(-clearance / B)`.
    neg_inv_b_veh: f64,
    a_ped: f64,
    neg_inv_b_ped: f64,
    /// Uncertainty gains in the weight `psi (1 + lambda u)`: `lambda1`/`lambda2` for `cr_sfm`,
    /// 0 for `ra_sfm` (whose weight is `psi`).
    lam_veh: f64,
    lam_ped: f64,
}

impl ForceConsts {
    fn new(model: PedestrianModel, p: &SocialForceParams) -> Self {
        let cr = model == PedestrianModel::CrSfm;
        Self {
            unit_weight: !matches!(model, PedestrianModel::RaSfm | PedestrianModel::CrSfm),
            a_veh: p.a_veh,
            neg_inv_b_veh: -1.0 / p.b_veh,
            a_ped: p.a_ped,
            neg_inv_b_ped: -1.0 / p.b_ped,
            lam_veh: if cr { p.lambda1 } else { 0.0 },
            lam_ped: if cr { p.lambda2 } else { 0.0 },
        }
    }
}

/// Scratch and output of one observe worker: it handles a contiguous range of observers.
///
/// Each observer is done in three passes over its edges: a gather of the candidates within the
/// perception radius (branch-free compaction; four at a time with AVX2, eight with AVX-512), a
/// pass that reads the targets' state and updates the beliefs (random access: scalar, or by
/// gathers eight edges at a time with AVX-512, `avx512::edge_states`), writing the edges
/// straight into the edge store, and one branch-free loop over structure-of-arrays scratch for
/// the risk and the social forces, which the compiler vectorises (with [`fastmath::exp`]). The
/// whole pass is compiled three times, portable, AVX2 and AVX-512 ([`Kernels`], chosen at run
/// time), with identical arithmetic.
/// A threaded pass runs in two halves ([`ObserveWorker::gather_all`], then
/// [`ObserveWorker::edges_into`]) so that the workers write into one store.
#[derive(Debug, Clone, Default)]
struct ObserveWorker {
    /// `stamp[id].0 == epoch` when the current observer had a belief about agent `id`, held by
    /// edge `stamp[id].1` of the previous graph.
    stamp: Vec<(u32, u32)>,
    epoch: u32,
    /// Slots of the current observer's targets.
    cand: Vec<u32>,
    /// Where in the old store each of them has its belief (the AVX-512 pass's scratch).
    belief_at: Vec<u32>,
    /// A threaded pass's targets of all the worker's observers, in order, and how many each.
    cands: Vec<u32>,
    counts: Vec<u32>,
    // Per edge of the current observer.
    /// `v_j . (x_i - x_j)`: the target's velocity along the centre offset.
    along: Vec<f64>,
    dist: Vec<f64>,
    accn: Vec<f64>,
    /// 1 when the target is a vehicle.
    veh: Vec<f64>,
    /// The unit vector from the target to the observer (the repulsion direction) is
    /// `(nnx, nny) * (rect + (1 - rect) inv_dist)`: the centre offset over the centre distance
    /// between two discs, the footprint normal (`rect` = 1) when either is a rectangle.
    nnx: Vec<f64>,
    nny: Vec<f64>,
    rect: Vec<f64>,
    fx: Vec<f64>,
    fy: Vec<f64>,
    w: Vec<f64>,
    // Output for the worker's observers, in order.
    edges: EdgeStore,
    len: Vec<u32>,
    /// Whether some clearance of the observer's is `<= 0` (a collision event to report).
    contact: Vec<bool>,
    force: Vec<Vec2>,
    max_w: Vec<f64>,
}

impl ObserveWorker {
    fn new(n_total: usize) -> Self {
        Self {
            stamp: vec![(0, 0); n_total],
            ..Self::default()
        }
    }

    /// Room in the stamp table for agent ids below `n_total` (a worker shared by worlds of
    /// several sizes). New entries hold epoch 0, which no observer uses.
    fn fit_agents(&mut self, n_total: usize) {
        if self.stamp.len() < n_total {
            self.stamp.resize(n_total, (0, 0));
        }
    }

    /// The whole observe pass of `observers`, into the worker's own edge store.
    fn run(&mut self, inp: &ObserveInputs, observers: Range<usize>) {
        self.dispatch(inp, Phase::Whole(observers));
    }

    /// First half of a threaded pass: the targets of each of `observers`, into `cands` and
    /// `counts` (how many each).
    fn gather_all(&mut self, inp: &ObserveInputs, observers: Range<usize>) {
        self.dispatch(inp, Phase::Gather(observers));
    }

    /// Second half of a threaded pass: the edges of `observers` from the targets
    /// [`ObserveWorker::gather_all`] found, written into `out`, which has room for exactly
    /// them.
    fn edges_into(&mut self, inp: &ObserveInputs, observers: Range<usize>, out: EdgeSink) {
        self.dispatch(inp, Phase::Edges(observers, out));
    }

    fn dispatch(&mut self, inp: &ObserveInputs, phase: Phase) {
        // Small scenes run the AVX2 variant even where the CPU has AVX-512: with ten or so
        // edges per observer the eight-lane loops are mostly set-up and remainder.
        #[cfg(target_arch = "x86_64")]
        if inp.kernels == Kernels::Avx512 && inp.agents.len() >= AVX512_MIN_AGENTS {
            // SAFETY: `Kernels::Avx512` is only chosen where the CPU has these features
            // (`World::use_kernels`, `Kernels::detect`).
            unsafe { self.dispatch_avx512(inp, phase) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if matches!(inp.kernels, Kernels::Avx2 | Kernels::Avx512) {
            // SAFETY: `Kernels::Avx2` and `Kernels::Avx512` are only chosen where the CPU has
            // AVX2 (`World::use_kernels`, `Kernels::detect`).
            unsafe { self.dispatch_avx2(inp, phase) };
            return;
        }
        self.dispatch_body::<false, false>(inp, phase);
    }

    /// [`ObserveWorker::dispatch`] compiled for AVX2: the per-edge loops run four lanes wide.
    /// AVX2 alone, no FMA: every operation rounds as in the portable build, so results are
    /// bit-identical.
    ///
    /// # Safety
    /// The CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn dispatch_avx2(&mut self, inp: &ObserveInputs, phase: Phase) {
        self.dispatch_body::<true, false>(inp, phase);
    }

    /// [`ObserveWorker::dispatch`] compiled for AVX-512 (F, DQ, VL): the per-edge loops run
    /// eight lanes wide. No FMA, as in [`ObserveWorker::dispatch_avx2`].
    ///
    /// # Safety
    /// The CPU must support AVX2, AVX-512F, AVX-512DQ and AVX-512VL.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,avx512f,avx512dq,avx512vl")]
    unsafe fn dispatch_avx512(&mut self, inp: &ObserveInputs, phase: Phase) {
        self.dispatch_body::<true, true>(inp, phase);
    }

    /// The observe pass proper, inlined into each instruction-set variant of `dispatch`
    /// (`AVX2`, `AVX512`: only called where the CPU has them).
    #[inline(always)]
    fn dispatch_body<const AVX2: bool, const AVX512: bool>(
        &mut self,
        inp: &ObserveInputs,
        phase: Phase,
    ) {
        let n = inp.agents.len();
        if self.cand.len() < n {
            self.resize_scratch(n);
        }
        match phase {
            Phase::Whole(observers) => {
                // Room for as many edges as these observers had last step, and some.
                let last: usize = inp.agents.edge_len[observers.clone()]
                    .iter()
                    .map(|&l| l as usize)
                    .sum();
                self.clear_output();
                let mut edges = std::mem::take(&mut self.edges);
                let mut cand = std::mem::take(&mut self.cand);
                edges.clear_with_capacity(last);
                for i in observers {
                    let epoch = self.index_beliefs::<AVX512>(inp, i);
                    let m = gather_targets::<AVX2, AVX512>(inp, i, &mut cand);
                    edges.reserve(m);
                    self.observer_edges::<AVX2, AVX512>(inp, i, &cand[..m], epoch, edges.sink(m));
                    // SAFETY: `observer_edges` writes every field of each of the `m` entries.
                    unsafe { edges.commit(m) };
                }
                self.edges = edges;
                self.cand = cand;
            }
            Phase::Gather(observers) => {
                self.cands.clear();
                self.counts.clear();
                for i in observers {
                    let m = gather_targets::<AVX2, AVX512>(inp, i, &mut self.cand);
                    self.cands.extend_from_slice(&self.cand[..m]);
                    self.counts.push(m as u32);
                }
            }
            Phase::Edges(observers, mut out) => {
                assert_eq!(observers.len(), self.counts.len());
                assert_eq!(out.len(), self.cands.len());
                self.clear_output();
                let cands = std::mem::take(&mut self.cands);
                let counts = std::mem::take(&mut self.counts);
                let mut from = 0;
                for (i, &m) in observers.zip(&counts) {
                    let m = m as usize;
                    let epoch = self.index_beliefs::<AVX512>(inp, i);
                    let part = out.split_front(m);
                    self.observer_edges::<AVX2, AVX512>(
                        inp,
                        i,
                        &cands[from..from + m],
                        epoch,
                        part,
                    );
                    from += m;
                }
                self.cands = cands;
                self.counts = counts;
            }
        }
    }

    fn clear_output(&mut self) {
        self.len.clear();
        self.contact.clear();
        self.force.clear();
        self.max_w.clear();
    }

    /// Sizes the per-edge scratch for at least `n` agents (an observer has fewer than `n` edges;
    /// a worker shared by several worlds keeps the largest size).
    #[cold]
    fn resize_scratch(&mut self, n: usize) {
        self.cand.resize(n, 0);
        self.belief_at.resize(n, 0);
        for v in [
            &mut self.along,
            &mut self.dist,
            &mut self.accn,
            &mut self.veh,
            &mut self.nnx,
            &mut self.nny,
            &mut self.rect,
            &mut self.fx,
            &mut self.fy,
            &mut self.w,
        ] {
            v.resize(n, 0.0);
        }
    }

    /// Indexes observer `i`'s beliefs of the previous graph by target id (in `stamp`, under a
    /// new epoch, which it returns) and starts fetching them.
    #[inline(always)]
    fn index_beliefs<const AVX512: bool>(&mut self, inp: &ObserveInputs, i: usize) -> u32 {
        let a = inp.agents;
        let old = inp.old;
        if self.epoch == u32::MAX {
            self.stamp.fill((0, 0));
            self.epoch = 0;
        }
        self.epoch += 1;
        let epoch = self.epoch;
        let s = a.edge_start[i] as usize;
        let old_range = s..s + a.edge_len[i] as usize;
        let old_targets = &old.target[old_range.clone()];
        if AVX512 && old_targets.len() >= VECTOR_STATE_MIN_EDGES {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `AVX512` is only set in `dispatch_avx512`, which runs where the CPU has
            // these features.
            unsafe {
                avx512::index_stamps(old_targets, s as u32, epoch, &mut self.stamp)
            };
        } else {
            for (k, &t) in old_targets.iter().enumerate() {
                self.stamp[t as usize] = (epoch, (s + k) as u32);
            }
        }
        // The update reads these beliefs in the new grid order: start fetching them now (the
        // old graph is megabytes at large N, out of the nearer caches; a short run is a few
        // lines, and the loop would cost more than it saves).
        #[cfg(target_arch = "x86_64")]
        if old_range.len() >= PREFETCH_MIN_EDGES {
            let r = old_range;
            let runs: [(*const i8, usize); 3] = [
                (old.mu_x[r.clone()].as_ptr().cast(), 8 * r.len()),
                (old.mu_y[r.clone()].as_ptr().cast(), 8 * r.len()),
                (old.updates[r.clone()].as_ptr().cast(), 4 * r.len()),
            ];
            for (start, bytes) in runs {
                for offset in (0..bytes).step_by(64) {
                    // SAFETY: a prefetch only hints the cache (it never faults); the address
                    // lies inside the run.
                    unsafe {
                        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                            start.add(offset),
                        )
                    };
                }
            }
        }
        epoch
    }

    /// Observer `i`'s edges to its targets `cand` (slots, in grid order), written into `out`
    /// (room for exactly `cand.len()`), and its contact flag, repulsion sum and largest weight
    /// pushed onto the worker's outputs. Its beliefs are indexed under `epoch`.
    #[inline(always)]
    fn observer_edges<const AVX2: bool, const AVX512: bool>(
        &mut self,
        inp: &ObserveInputs,
        i: usize,
        cand: &[u32],
        epoch: u32,
        out: EdgeSink,
    ) {
        let m = cand.len();
        assert_eq!(out.len(), m);
        if m <= SMALL_OBSERVER_EDGES {
            self.small_observer_edges(inp, i, cand, epoch, out);
            return;
        }
        let a = inp.agents;

        // 3. Targets' state, beliefs, clearances. The edges are written straight into their
        // place in the edge store (no zero-fill or copy first).
        let EdgeSink {
            target: e_target,
            slot: e_slot,
            mu_x: e_mu_x,
            mu_y: e_mu_y,
            updates: e_updates,
            clearance: e_clear,
            psi: e_psi,
            u: e_u,
        } = out;
        // Sliced to `m` so that the compiler knows every length (no bound checks in the loops).
        let (e_target, e_slot) = (&mut e_target[..m], &mut e_slot[..m]);
        let (e_mu_x, e_mu_y, e_updates) = (&mut e_mu_x[..m], &mut e_mu_y[..m], &mut e_updates[..m]);
        let (e_clear, e_psi, e_u) = (&mut e_clear[..m], &mut e_psi[..m], &mut e_u[..m]);
        let alongs = &mut self.along[..m];
        let dists = &mut self.dist[..m];
        let accns = &mut self.accn[..m];
        let vehs = &mut self.veh[..m];
        let nnxs = &mut self.nnx[..m];
        let nnys = &mut self.nny[..m];
        let rects = &mut self.rect[..m];
        let model = inp.params.cognition.prediction;
        let observer = Observer::of(inp, i);
        let mut contact = false;
        // Below about two chunks of eight the gathers' set-up costs more than they save.
        if AVX512 && m >= VECTOR_STATE_MIN_EDGES {
            #[cfg(target_arch = "x86_64")]
            {
                let out = EdgeSink {
                    target: &mut *e_target,
                    slot: &mut *e_slot,
                    mu_x: &mut *e_mu_x,
                    mu_y: &mut *e_mu_y,
                    updates: &mut *e_updates,
                    clearance: &mut *e_clear,
                    psi: &mut *e_psi,
                    u: &mut *e_u,
                };
                let cols = avx512::StateColumns {
                    along: &mut *alongs,
                    dist: &mut *dists,
                    accn: &mut *accns,
                    veh: &mut *vehs,
                    nnx: &mut *nnxs,
                    nny: &mut *nnys,
                    rect: &mut *rects,
                    belief_at: &mut self.belief_at[..m],
                };
                // SAFETY: `AVX512` is only set in `dispatch_avx512`, which runs where the CPU
                // has these features.
                contact = unsafe {
                    avx512::edge_states(inp, &self.stamp, epoch, &observer, cand, out, cols)
                };
            }
        } else {
            for c in 0..m {
                let j = cand[c] as usize;
                let t = &inp.targets[j];
                let st = edge_state(inp, &self.stamp, epoch, model, &observer, t, j);
                contact |= st.clearance <= 0.0;
                e_target[c] = MaybeUninit::new(t.id);
                e_slot[c] = MaybeUninit::new(j as u32);
                e_mu_x[c] = MaybeUninit::new(st.belief.mu.x);
                e_mu_y[c] = MaybeUninit::new(st.belief.mu.y);
                e_updates[c] = MaybeUninit::new(st.belief.updates);
                e_clear[c] = MaybeUninit::new(st.clearance);
                e_u[c] = MaybeUninit::new(st.u);
                alongs[c] = st.along;
                dists[c] = st.dist;
                accns[c] = t.acc_norm;
                vehs[c] = t.veh;
                nnxs[c] = st.normal.x;
                nnys[c] = st.normal.y;
                rects[c] = st.rect;
            }
        }

        // 4. Physical risk (risk::edge_psi) and 5. the social forces on a
        // simulated pedestrian (pedestrian::total_force without the goal term, summed in four
        // interleaved lanes), in one loop over the edges.
        // SAFETY: the loop above wrote every entry of these two (each `c` in `0..m` once), and
        // `MaybeUninit<f64>` has the layout of `f64`.
        let (clears, us) = unsafe {
            (
                &*(&*e_clear as *const [MaybeUninit<f64>] as *const [f64]),
                &*(&*e_u as *const [MaybeUninit<f64>] as *const [f64]),
            )
        };
        let (alongs, dists, accns) = (&self.along[..m], &self.dist[..m], &self.accn[..m]);
        let gamma1 = inp.params.risk.gamma1;
        let two_gamma2 = 2.0 * inp.params.risk.gamma2;
        let fc = match a.control[i] {
            Control::Model(model) => inp.forces[model_index(model)],
            _ => None,
        };
        let (force, max_w) = match fc {
            None => {
                for c in 0..m {
                    let (psi, _) = risk::edge_psi(
                        gamma1, two_gamma2, alongs[c], dists[c], accns[c], clears[c],
                    );
                    e_psi[c] = MaybeUninit::new(psi);
                }
                (Vec2::zeros(), 0.0)
            }
            Some(fc) => {
                let vehs = &self.veh[..m];
                let (nnxs, nnys, rects) = (&self.nnx[..m], &self.nny[..m], &self.rect[..m]);
                let fxs = &mut self.fx[..m];
                let fys = &mut self.fy[..m];
                let ws = &mut self.w[..m];
                for c in 0..m {
                    let (psi, inv_dist) = risk::edge_psi(
                        gamma1, two_gamma2, alongs[c], dists[c], accns[c], clears[c],
                    );
                    e_psi[c] = MaybeUninit::new(psi);
                    let (fx, fy, w) = edge_force(
                        &fc,
                        psi,
                        us[c],
                        vehs[c],
                        inv_dist,
                        (nnxs[c], nnys[c], rects[c]),
                        clears[c],
                    );
                    fxs[c] = fx;
                    fys[c] = fy;
                    ws[c] = w;
                }
                (Vec2::new(lane_sum(fxs), lane_sum(fys)), lane_max(ws))
            }
        };
        self.len.push(m as u32);
        self.contact.push(contact);
        self.force.push(force);
        self.max_w.push(max_w);
    }

    /// Steps 3 to 5 of [`ObserveWorker::observer_edges`] for an observer with at most
    /// [`SMALL_OBSERVER_EDGES`] targets: one loop over the edges instead of three passes over
    /// structure-of-arrays scratch whose set-up costs more than a few edges' work (most
    /// observers of a small scene). Both paths compute each edge with [`edge_state`],
    /// [`risk::edge_psi`] and [`edge_force`] and sum with the same lane functions, so the result is
    /// bit-identical to the three passes.
    #[inline(always)]
    fn small_observer_edges(
        &mut self,
        inp: &ObserveInputs,
        i: usize,
        cand: &[u32],
        epoch: u32,
        out: EdgeSink,
    ) {
        let m = cand.len();
        let a = inp.agents;
        let model = inp.params.cognition.prediction;
        let observer = Observer::of(inp, i);
        let gamma1 = inp.params.risk.gamma1;
        let two_gamma2 = 2.0 * inp.params.risk.gamma2;
        let fc = match a.control[i] {
            Control::Model(model) => inp.forces[model_index(model)],
            _ => None,
        };
        let mut fxs = [0.0; SMALL_OBSERVER_EDGES];
        let mut fys = [0.0; SMALL_OBSERVER_EDGES];
        let mut ws = [0.0; SMALL_OBSERVER_EDGES];
        let mut contact = false;
        for c in 0..m {
            let j = cand[c] as usize;
            let t = &inp.targets[j];
            let st = edge_state(inp, &self.stamp, epoch, model, &observer, t, j);
            contact |= st.clearance <= 0.0;
            let (psi, inv_dist) = risk::edge_psi(
                gamma1,
                two_gamma2,
                st.along,
                st.dist,
                t.acc_norm,
                st.clearance,
            );
            if let Some(fc) = fc {
                (fxs[c], fys[c], ws[c]) = edge_force(
                    &fc,
                    psi,
                    st.u,
                    t.veh,
                    inv_dist,
                    (st.normal.x, st.normal.y, st.rect),
                    st.clearance,
                );
            }
            out.target[c] = MaybeUninit::new(t.id);
            out.slot[c] = MaybeUninit::new(j as u32);
            out.mu_x[c] = MaybeUninit::new(st.belief.mu.x);
            out.mu_y[c] = MaybeUninit::new(st.belief.mu.y);
            out.updates[c] = MaybeUninit::new(st.belief.updates);
            out.clearance[c] = MaybeUninit::new(st.clearance);
            out.psi[c] = MaybeUninit::new(psi);
            out.u[c] = MaybeUninit::new(st.u);
        }
        let (force, max_w) = match fc {
            None => (Vec2::zeros(), 0.0),
            Some(_) => (
                Vec2::new(lane_sum(&fxs[..m]), lane_sum(&fys[..m])),
                lane_max(&ws[..m]),
            ),
        };
        self.len.push(m as u32);
        self.contact.push(contact);
        self.force.push(force);
        self.max_w.push(max_w);
    }
}

/// What [`ObserveWorker::dispatch`] does.
enum Phase<'a> {
    /// The whole pass of these observers, into the worker's own store.
    Whole(Range<usize>),
    /// Only their targets ([`ObserveWorker::gather_all`]).
    Gather(Range<usize>),
    /// Their edges from the gathered targets, into this sink ([`ObserveWorker::edges_into`]).
    Edges(Range<usize>, EdgeSink<'a>),
}

/// Writes into `cand` the slots of every agent within the perception radius of observer `i`,
/// in grid order; returns how many (`cand` has room for every agent).
#[inline(always)]
fn gather_targets<const AVX2: bool, const AVX512: bool>(
    inp: &ObserveInputs,
    i: usize,
    cand: &mut [u32],
) -> usize {
    let (slots, gx, gy) = inp.grid.sorted();
    let (ranges, rows) = inp.grid.candidate_ranges(i);
    let xi = inp.agents.pos[i];
    let r2 = inp.r2;
    let mut m = 0;
    for &(lo, hi) in &ranges[..rows] {
        let (gx, gy, slots) = (&gx[lo..hi], &gy[lo..hi], &slots[lo..hi]);
        #[cfg(target_arch = "x86_64")]
        if AVX512 {
            // SAFETY: `AVX512` is only set where the CPU has AVX-512 (`dispatch_avx512`).
            m = unsafe { avx512::gather(gx, gy, slots, xi, r2, i as u32, cand, m) };
            continue;
        }
        #[cfg(target_arch = "x86_64")]
        if AVX2 {
            // SAFETY: `AVX2` is only set where the CPU has AVX2 (`dispatch_avx2`,
            // `dispatch_avx512`).
            m = unsafe { gather_avx2(gx, gy, slots, xi, r2, i as u32, cand, m) };
            continue;
        }
        m = gather(gx, gy, slots, xi, r2, i as u32, cand, m);
    }
    m
}

/// Observers with fewer edges in the old graph do not prefetch their beliefs.
#[cfg(target_arch = "x86_64")]
const PREFETCH_MIN_EDGES: usize = 32;

/// Scenes with fewer agents step with the AVX2 variant where the CPU has AVX-512.
#[cfg(target_arch = "x86_64")]
const AVX512_MIN_AGENTS: usize = 32;

/// Observers with at least this many targets update their beliefs eight edges at a time
/// (`avx512::edge_states`) where the CPU has AVX-512 (`AVX512` is only set on x86-64).
const VECTOR_STATE_MIN_EDGES: usize = 16;

/// Observers with at most this many targets take [`ObserveWorker::small_observer_edges`].
const SMALL_OBSERVER_EDGES: usize = 4;

/// Appends to `cand[m..]` the slots `slots[k]` other than `i` whose positions `(xs[k], ys[k])`
/// lie within `sqrt(r2)` of `xi`, in order; returns the new count. `cand` has room for every
/// slot (`m + slots.len() <= cand.len()`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn gather(
    xs: &[f64],
    ys: &[f64],
    slots: &[u32],
    xi: Vec2,
    r2: f64,
    i: u32,
    cand: &mut [u32],
    mut m: usize,
) -> usize {
    for ((&x, &y), &j) in xs.iter().zip(ys).zip(slots) {
        let (dx, dy) = (xi.x - x, xi.y - y);
        let inside = (dx * dx + dy * dy <= r2) & (j != i);
        // Written unconditionally, kept by advancing `m` (m < candidates <= n).
        cand[m] = j;
        m += usize::from(inside);
    }
    m
}

/// For each of the 16 masks of four lanes, the lanes that are set, in order (the rest 0): the
/// permutation that packs the kept slots of a group of four to its front.
#[cfg(target_arch = "x86_64")]
const PACK: [[i32; 4]; 16] = {
    let mut t = [[0; 4]; 16];
    let mut mask = 0;
    while mask < 16 {
        let (mut lane, mut k) = (0, 0);
        while lane < 4 {
            if mask & (1 << lane) != 0 {
                t[mask][k] = lane;
                k += 1;
            }
            lane += 1;
        }
        mask += 1;
    }
    t
};

/// [`gather`] four candidates at a time: the same distance test (same operations, no FMA), the
/// kept slots of each group packed by a permutation and stored as one vector.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
#[allow(clippy::too_many_arguments)]
unsafe fn gather_avx2(
    xs: &[f64],
    ys: &[f64],
    slots: &[u32],
    xi: Vec2,
    r2: f64,
    i: u32,
    cand: &mut [u32],
    mut m: usize,
) -> usize {
    use std::arch::x86_64::*;
    let n = slots.len();
    assert!(xs.len() == n && ys.len() == n && m + n <= cand.len());
    let (px, py, pr2) = (
        _mm256_set1_pd(xi.x),
        _mm256_set1_pd(xi.y),
        _mm256_set1_pd(r2),
    );
    let me = _mm_set1_epi32(i as i32);
    let groups = n / 4;
    for g in 0..groups {
        let o = 4 * g;
        // SAFETY: lanes `o..o + 4` are in bounds of `xs`, `ys` and `slots` (`o + 4 <= n`), and
        // the store writes `cand[m..m + 4]` with `m <= m_0 + o` (at most one kept per
        // candidate), so `m + 4 <= m_0 + n <= cand.len()` (asserted above).
        let (x, y, j) = (
            _mm256_loadu_pd(xs.as_ptr().add(o)),
            _mm256_loadu_pd(ys.as_ptr().add(o)),
            _mm_loadu_si128(slots.as_ptr().add(o).cast()),
        );
        let dx = _mm256_sub_pd(px, x);
        let dy = _mm256_sub_pd(py, y);
        let d2 = _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy));
        let inside = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(d2, pr2));
        let is_me = _mm_movemask_ps(_mm_castsi128_ps(_mm_cmpeq_epi32(j, me)));
        let keep = (inside & !is_me) as usize;
        let perm = _mm_loadu_si128(PACK[keep].as_ptr().cast());
        let packed = _mm_permutevar_ps(_mm_castsi128_ps(j), perm);
        _mm_storeu_si128(cand.as_mut_ptr().add(m).cast(), _mm_castps_si128(packed));
        m += keep.count_ones() as usize;
    }
    let o = 4 * groups;
    gather(&xs[o..], &ys[o..], &slots[o..], xi, r2, i, cand, m)
}

/// The observing agent of an observe pass's edges.
struct Observer {
    placed: Placed,
    /// Disc radius; NaN for a rectangle.
    radius: f64,
    /// [`geometry::axes`] of `placed`.
    axes: (f64, f64),
}

impl Observer {
    #[inline(always)]
    fn of(inp: &ObserveInputs, i: usize) -> Self {
        let a = inp.agents;
        Self {
            placed: Placed {
                shape: a.shape[i],
                position: a.pos[i],
                heading: a.heading[i],
            },
            radius: inp.targets[i].radius,
            axes: inp.axes[i],
        }
    }

    /// Clearance to the agent in slot `j` and the push direction, by the footprints' exact
    /// geometry (what an edge with a rectangle on either side takes).
    #[inline]
    fn footprint_clearance(&self, inp: &ObserveInputs, j: usize) -> (f64, Vec2) {
        let a = inp.agents;
        let placed_j = Placed {
            shape: a.shape[j],
            position: a.pos[j],
            heading: a.heading[j],
        };
        clearance_and_normal_oriented(&self.placed, self.axes, &placed_j, inp.axes[j])
    }
}

/// What an observer learns of one target in step 3 of [`ObserveWorker::observer`].
struct EdgeState {
    /// The updated belief and its uncertainty `u`.
    belief: Belief,
    u: f64,
    /// `v_j . (x_i - x_j)`: the target's velocity along the centre offset.
    along: f64,
    /// Centre distance.
    dist: f64,
    clearance: f64,
    /// The repulsion direction before scaling: the centre offset between two discs (`rect` =
    /// 0), the footprint normal when either is a rectangle (`rect` = 1).
    normal: Vec2,
    rect: f64,
}

/// The belief update, distance and clearance of the edge from `observer` to target `t` in slot
/// `j`. Shared by the three-pass
/// and the small observer paths, so both compute the same bits.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn edge_state(
    inp: &ObserveInputs,
    stamp: &[(u32, u32)],
    epoch: u32,
    model: crate::params::PredictionModel,
    observer: &Observer,
    t: &TargetInfo,
    j: usize,
) -> EdgeState {
    let placed_i = &observer.placed;
    let d = placed_i.position - t.pos;
    let vj = t.vel;
    let (seen, k) = stamp[t.id as usize];
    let (belief, u) = if seen == epoch {
        let mut b = inp.old.belief(k as usize);
        let mu_p = b.predict(model, inp.last_change[j]);
        let u = b.update(mu_p, vj, inp.schedule);
        (b, u)
    } else {
        (Belief::first_sight(vj), 0.0)
    };
    let dist = d.norm();
    // `radius_i + radius_j` is NaN when either footprint is a rectangle.
    let radii = observer.radius + t.radius;
    let (clearance, normal, rect) = if !radii.is_nan() {
        ((dist - radii).max(0.0), d, 0.0)
    } else {
        let (c, n) = observer.footprint_clearance(inp, j);
        (c, n, 1.0)
    };
    EdgeState {
        belief,
        u,
        along: vj.x * d.x + vj.y * d.y,
        dist,
        clearance,
        normal,
        rect,
    }
}

/// The social force `(fx, fy)` of one edge on a simulated pedestrian and its weight `w`
/// (pedestrian::total_force without the goal term, branch-free): `veh` is 1 for a vehicle
/// target, `(nnx, nny, rect)` the repulsion direction of [`EdgeState`].
#[inline(always)]
fn edge_force(
    fc: &ForceConsts,
    psi: f64,
    u: f64,
    veh: f64,
    inv_dist: f64,
    (nnx, nny, rect): (f64, f64, f64),
    clearance: f64,
) -> (f64, f64, f64) {
    let veh = veh != 0.0;
    let strength = if veh { fc.a_veh } else { fc.a_ped };
    let neg_inv_range = if veh {
        fc.neg_inv_b_veh
    } else {
        fc.neg_inv_b_ped
    };
    let lambda = if veh { fc.lam_veh } else { fc.lam_ped };
    let weighted = psi * (1.0 + lambda * u);
    let w = if fc.unit_weight { 1.0 } else { weighted };
    // Exactly `inv_dist` (rect = 0) or 1 (rect = 1), without a select on loads.
    let scale = rect + (1.0 - rect) * inv_dist;
    let nx = nnx * scale;
    let ny = nny * scale;
    let rep = strength * fastmath::exp(clearance * neg_inv_range);
    (nx * rep * w, ny * rep * w, w)
}

/// Sum in four interleaved lanes, then the lanes and the tail in a fixed order (vectorisable,
/// deterministic).
#[inline(always)]
fn lane_sum(v: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let chunks = v.chunks_exact(4);
    let tail = chunks.remainder();
    for ch in chunks {
        for l in 0..4 {
            acc[l] += ch[l];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for &x in tail {
        s += x;
    }
    s
}

/// Largest of `v` and 0 (weights are non-negative), in four lanes.
#[inline(always)]
fn lane_max(v: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let chunks = v.chunks_exact(4);
    let tail = chunks.remainder();
    for ch in chunks {
        for l in 0..4 {
            if ch[l] > acc[l] {
                acc[l] = ch[l];
            }
        }
    }
    let mut m = acc[0].max(acc[1]).max(acc[2].max(acc[3]));
    for &x in tail {
        if x > m {
            m = x;
        }
    }
    m
}
