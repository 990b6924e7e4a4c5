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
//! 5. events (collisions and whose fault they are, arrivals) and every reward term of the
//!    transition.
//!
//! Where each stage lives (the equations themselves are in [`crate::model`]):
//! - `agents.rs`, `store.rs`: the state (agents by slot, the edge store of beliefs and graph);
//! - `config.rs`: what moves each agent ([`Control`]) and the episode's configuration;
//! - `lifecycle.rs`: stages 1 and 3 (entering, arriving, leaving);
//! - `motion.rs`: stage 2 (every agent's move), `reactive_vehicles.rs` its last part (the cars
//!   nobody controls, one after the other);
//! - `observe/`: stage 4 (the observe pass: `mod.rs` its threads and compiled variants,
//!   `kernel.rs` one observer's edges, which call the equation modules);
//! - `outcome.rs`: stage 5 (events and rewards);
//! - `observation.rs`: the learner's view of the state (ego-frame node features, padded
//!   adjacency and mask), read after a step.

use std::ops::Range;
use std::sync::Arc;

use crate::geometry::{Shape, Vec2};
use crate::metrics::EpisodeMetrics;
use crate::model::cognition::VarianceSchedule;
use crate::model::risk;
use crate::model::traffic::RecordedPath;
use crate::params::{ParamError, WorldParams};
use crate::scenario::{AgentKind, Scenario};
use crate::support::grid::Grid;
use crate::support::threads::Helpers;

mod agents;
mod config;
mod lifecycle;
mod motion;
pub mod observation;
mod observe;
mod outcome;
mod reactive_vehicles;
mod store;

use agents::{Agents, ExternalTrack};
pub use config::{Control, EpisodeConfig};
pub use observe::{Kernels, KernelsUnavailable, PARALLEL_MIN_AGENTS};
use observe::{ObserveWorker, TargetInfo};
pub(crate) use store::Edge;
use store::EdgeStore;

/// An agent's identity: its index in the scenario's agent list. Stable for the whole episode.
pub type AgentId = u32;

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

/// The names of the reward terms, in the order of [`RewardTerms`]' fields (and of every list
/// of terms: the wire's `reward_terms`, `names.json` for the Python side).
pub const REWARD_TERM_NAMES: [&str; 5] = ["progress", "success", "collision", "danger", "comfort"];

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
    /// The terms in [`REWARD_TERM_NAMES`] order.
    pub fn values(&self) -> [f64; 5] {
        [
            self.progress,
            self.success,
            self.collision,
            self.danger,
            self.comfort,
        ]
    }

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
    /// The collision of an external `vehicle` and a `pedestrian` this step is the vehicle's
    /// fault (model.md 2c); follows their [`Event::Collision`].
    AtFault {
        vehicle: AgentId,
        pedestrian: AgentId,
    },
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
    /// Reactive vehicles due to enter whose entry was occupied by another vehicle: they enter,
    /// in id order, as soon as it is free.
    deferred: Vec<AgentId>,
    /// Per agent of the scenario, the recorded path of a reactive vehicle (shared by clones).
    paths: Arc<[Option<RecordedPath>]>,
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

/// A scenario a world can be built from: its `dt` the parameters', fewer agents than the slot
/// sentinel, and every track non-empty and finite.
fn check_scenario(scenario: &Scenario, params: &WorldParams) -> Result<(), WorldError> {
    let name = || scenario.name.clone();
    if (scenario.dt - params.dt).abs() > 1e-9 {
        return Err(WorldError::DtMismatch {
            scenario: name(),
            got: scenario.dt,
            want: params.dt,
        });
    }
    if scenario.agents.len() >= NO_SLOT as usize {
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
    Ok(())
}

/// The externally controlled agents' tracks (each agent once, known to the scenario); their
/// control set to [`Control::External`] in `control_of`.
fn external_tracks(
    scenario: &Scenario,
    config: &EpisodeConfig,
    control_of: &mut [Control],
) -> Result<Vec<ExternalTrack>, WorldError> {
    let mut externals: Vec<ExternalTrack> = Vec::new();
    for &id in &config.external {
        if id as usize >= scenario.agents.len() {
            return Err(WorldError::UnknownAgent {
                scenario: scenario.name.clone(),
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
            in_path: Vec::new(),
            in_path_before: Vec::new(),
        });
    }
    Ok(externals)
}

/// Steps of an episode (model.md section 7): the last recorded step of the controlled vehicles
/// (the latest one ends last; the ego's when no vehicle is controlled) plus `horizon_extra`.
/// With several controlled cars, each must have its own recorded time and the margin: a horizon
/// from the ego alone would cut a car that enters later or drives longer before it could arrive.
fn episode_horizon(scenario: &Scenario, params: &WorldParams, externals: &[ExternalTrack]) -> u32 {
    let end_of = |id: usize| scenario.agents.get(id).map(|a| a.end_step());
    let controlled_end = externals
        .iter()
        .filter(|e| scenario.agents[e.id as usize].kind == AgentKind::Vehicle)
        .filter_map(|e| end_of(e.id as usize))
        .max();
    let last = controlled_end
        .or_else(|| end_of(scenario.ego))
        .unwrap_or_else(|| scenario.recorded_steps().saturating_sub(1));
    ((last as f64 * params.dt + params.horizon_extra) / params.dt).round() as u32
}

impl World {
    /// Starts an episode of `scenario` at its first step.
    pub fn new(
        scenario: Arc<Scenario>,
        params: WorldParams,
        config: EpisodeConfig,
    ) -> Result<Self, WorldError> {
        params.validate()?;
        check_scenario(&scenario, &params)?;
        let mut control_of = config.controls(&scenario);
        let externals = external_tracks(&scenario, &config, &mut control_of)?;
        let paths: Arc<[Option<RecordedPath>]> = scenario
            .agents
            .iter()
            .zip(&control_of)
            .map(|(rec, c)| matches!(c, Control::Vehicle(_)).then(|| RecordedPath::new(rec)))
            .collect();
        let horizon = episode_horizon(&scenario, &params, &externals);
        let n_total = scenario.agents.len();
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
            deferred: Vec::new(),
            paths,
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
}

impl World {
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
        self.check_actions(actions)?;
        let mut events = Vec::new();
        self.departed.clear();
        // 1. External agents whose episode ended last step leave now.
        self.remove_leaving(scratch, &mut events);
        // 2. Every agent moves from t to t + 1.
        self.move_agents(scratch, actions);
        self.step += 1;
        // 3. Pedestrians at their goal leave; agents recorded from t + 1 enter.
        self.mark_arrivals(&mut events);
        self.remove_leaving(scratch, &mut events);
        self.enter_pending(&mut events);
        // 4. Beliefs, risk and graph at t + 1.
        self.observe(scratch);
        // 5. Events and rewards.
        Ok(self.outcome(events))
    }

    /// Refuses (changing nothing) a step whose actions are not exactly one finite action per
    /// active external agent.
    fn check_actions(&self, actions: &[(AgentId, [f64; 2])]) -> Result<(), StepError> {
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

        Ok(())
    }
}
