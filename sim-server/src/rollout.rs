//! The `rollout` command: one scenario, one pedestrian model and one vehicle model, every step
//! written as a JSON line.
//!
//! Format (one JSON object per line; `docs/ROLLOUT.md` documents every field):
//! - `{"type":"header", ...}`: scenario, model, parameters, agents (id, record id, kind, control);
//! - `{"type":"step", ...}` for step 0 and every step after: agents' positions, velocities,
//!   headings; the risk graph's edges `[observer, target, psi, u, A]`; reward terms of the
//!   external agents for the transition into this step; events;
//! - `{"type":"end", ...}`: why the rollout stopped and the external agents' episode metrics.

use std::io::Write;
use std::sync::Arc;

use serde_json::{json, Value};
use sim_core::params::{PedestrianModel, VehicleModel, WorldParams};
use sim_core::scenario::{AgentKind, AgentRecord, Scenario};
use sim_core::variation::Variation;
use sim_core::world::{AgentOutcome, Control, EpisodeConfig, Event, World, WorldError};

/// How the scenario's ego vehicle moves during a rollout.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum EgoDrive {
    /// Replays its record (the run ends with the record).
    Replay,
    /// Is external and holds this normalised action `[acc, yaw rate]` every step.
    Constant([f64; 2]),
}

/// What moves the agents nobody controls during a rollout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RolloutModels {
    /// Every pedestrian that is not non-reactive.
    pub pedestrians: PedestrianModel,
    /// Every vehicle that is not the external ego.
    pub vehicles: VehicleModel,
}

/// Why a rollout failed.
#[derive(Debug, thiserror::Error)]
pub enum RolloutError {
    #[error(transparent)]
    World(#[from] WorldError),
    #[error(transparent)]
    Step(#[from] sim_core::StepError),
    #[error("writing the rollout: {0}")]
    Io(#[from] std::io::Error),
    #[error("--pedestrian {index}: the scenario has {count} pedestrian(s) (pedestrian_0 .. pedestrian_{last})", last = .count.saturating_sub(1))]
    NoPedestrian { index: usize, count: usize },
}

/// A pedestrian driven like an external agent during a rollout (model.md 2b): `pedestrian_{index}`
/// (the scenario's pedestrians in agent order, as a server names them) holding `action`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrivenPedestrian {
    pub index: usize,
    /// Normalised `[forward, left]` acceleration, held every step.
    pub action: [f64; 2],
}

fn control_name(c: Control) -> String {
    match c {
        Control::External => "external".into(),
        Control::Replay => "replay".into(),
        Control::Model(m) => m.name().into(),
        Control::Vehicle(m) => m.name().into(),
    }
}

/// Agent `id` of a scenario as the rollout and trajectory files list it: its index, record id,
/// kind (`pedestrian` or `vehicle`) and first step, plus the caller's `fields`.
pub(crate) fn agent_json<const N: usize>(
    id: usize,
    a: &AgentRecord,
    fields: [(&str, Value); N],
) -> Value {
    let mut object = json!({
        "id": id,
        "record_id": a.record_id,
        "kind": a.kind,
        "start_step": a.start_step,
    });
    for (key, value) in fields {
        object[key] = value;
    }
    object
}

fn event_json(e: &Event) -> Value {
    match *e {
        Event::Collision { a, b } => json!({"event": "collision", "a": a, "b": b}),
        Event::AtFault {
            vehicle,
            pedestrian,
        } => json!({"event": "at_fault", "vehicle": vehicle, "pedestrian": pedestrian}),
        Event::GoalReached { agent } => json!({"event": "goal_reached", "agent": agent}),
        Event::Entered { agent } => json!({"event": "entered", "agent": agent}),
        Event::Left { agent } => json!({"event": "left", "agent": agent}),
    }
}

fn step_json(world: &World, outcomes: &[AgentOutcome], events: &[Event]) -> Value {
    let agents: Vec<Value> = world
        .agents()
        .map(|a| {
            json!({
                "id": a.id,
                "x": a.position.x, "y": a.position.y,
                "vx": a.velocity.x, "vy": a.velocity.y,
                "heading": a.heading,
            })
        })
        .collect();
    let edges: Vec<Value> = world
        .graph_edges()
        .map(|e| json!([e.observer, e.target, e.psi, e.u, e.a]))
        .collect();
    let rewards: Vec<Value> = outcomes
        .iter()
        .map(|o| {
            json!({
                "agent": o.agent,
                "total": o.reward.total(),
                "progress": o.reward.progress,
                "success": o.reward.success,
                "collision": o.reward.collision,
                "danger": o.reward.danger,
                "comfort": o.reward.comfort,
                "terminated": o.terminated,
                "truncated": o.truncated,
                "action_clipped": o.action_clipped,
            })
        })
        .collect();
    json!({
        "type": "step",
        "step": world.step_index(),
        "time": world.time(),
        "agents": agents,
        "edges": edges,
        "rewards": rewards,
        "events": events.iter().map(event_json).collect::<Vec<_>>(),
    })
}

/// Runs `scenario` (in `variation`, if given: the same scene and parameters a server env with
/// that variation plays) and writes the JSON lines to `out`, stepping on `threads` threads
/// (scenes of at least [`sim_core::world::PARALLEL_MIN_AGENTS`] agents are split; the lines are
/// the same for every count). Returns the number of steps taken.
pub fn rollout(
    scenario: Arc<Scenario>,
    params: WorldParams,
    models: RolloutModels,
    ego: EgoDrive,
    variation: Option<&Variation>,
    threads: usize,
    out: &mut impl Write,
) -> Result<u32, RolloutError> {
    rollout_driving(scenario, params, models, ego, &[], variation, threads, out)
}

/// [`rollout`] with `walkers` driven like external agents (their rewards and episode metrics
/// are written as the car's).
#[allow(clippy::too_many_arguments)] // the rollout's inputs, each plainly named
pub fn rollout_driving(
    scenario: Arc<Scenario>,
    params: WorldParams,
    models: RolloutModels,
    ego: EgoDrive,
    walkers: &[DrivenPedestrian],
    variation: Option<&Variation>,
    threads: usize,
    out: &mut impl Write,
) -> Result<u32, RolloutError> {
    let (scenario, params) = match variation {
        Some(v) => (Arc::new(v.apply(&scenario)), v.apply_params(&params)),
        None => (scenario, params),
    };
    let model = models.pedestrians;
    let mut config = match ego {
        EgoDrive::Replay => EpisodeConfig::replay_vehicles(model),
        EgoDrive::Constant(_) => EpisodeConfig::ego_external(&scenario, model),
    };
    config.vehicle_model = models.vehicles;
    let walker_actions = driven_ids(&scenario, walkers)?;
    config
        .external
        .extend(walker_actions.iter().map(|&(id, _)| id));
    let mut world = World::new(scenario.clone(), params, config)?;
    world.set_threads(threads);
    let mut header = header_json(&world, &scenario, &params, models, ego, variation);
    header["pedestrians_driven"] = walkers
        .iter()
        .zip(&walker_actions)
        .map(|(w, (id, a))| json!({"name": format!("pedestrian_{}", w.index), "agent": id, "action": a}))
        .collect();
    writeln!(out, "{header}")?;
    writeln!(out, "{}", step_json(&world, &[], &[]))?;
    let last_recorded = scenario.recorded_steps().saturating_sub(1);
    let mut metrics = Vec::new();
    let reason = loop {
        if world.is_over() {
            break "episode_over";
        }
        if ego == EgoDrive::Replay && world.step_index() >= last_recorded {
            break "record_ended";
        }
        let actions: Vec<_> = world
            .active_externals()
            .filter_map(|id| match walker_actions.iter().find(|(w, _)| *w == id) {
                Some(&(_, a)) => Some((id, a)),
                None => match ego {
                    EgoDrive::Constant(a) => Some((id, a)),
                    EgoDrive::Replay => None,
                },
            })
            .collect();
        let outcome = world.step(&actions)?;
        metrics.extend(
            outcome
                .agents
                .iter()
                .filter_map(|o| o.metrics.map(|m| (o.agent, m))),
        );
        writeln!(
            out,
            "{}",
            step_json(&world, &outcome.agents, &outcome.events)
        )?;
    };
    let metrics: Vec<Value> = metrics
        .iter()
        .map(|(agent, m)| json!({"agent": agent, "metrics": serde_json::to_value(m).expect("metrics serialise")}))
        .collect();
    writeln!(
        out,
        "{}",
        json!({"type": "end", "reason": reason, "steps": world.step_index(), "metrics": metrics})
    )?;
    Ok(world.step_index())
}

/// The agent id and action of each driven pedestrian (`pedestrian_{index}` is the scene's
/// pedestrian number `index` in agent order, as a server names them).
fn driven_ids(
    scenario: &Scenario,
    walkers: &[DrivenPedestrian],
) -> Result<Vec<(u32, [f64; 2])>, RolloutError> {
    let pedestrians: Vec<u32> = (0..scenario.agents.len() as u32)
        .filter(|&id| scenario.agents[id as usize].kind == AgentKind::Pedestrian)
        .collect();
    walkers
        .iter()
        .map(|w| {
            let id = *pedestrians.get(w.index).ok_or(RolloutError::NoPedestrian {
                index: w.index,
                count: pedestrians.len(),
            })?;
            Ok((id, w.action))
        })
        .collect()
}

/// The rollout's first line: the scenario, the models, the parameters, the variation and every
/// agent with its control.
fn header_json(
    world: &World,
    scenario: &Scenario,
    params: &WorldParams,
    models: RolloutModels,
    ego: EgoDrive,
    variation: Option<&Variation>,
) -> Value {
    let model = models.pedestrians;
    let agents: Vec<Value> = scenario
        .agents
        .iter()
        .enumerate()
        .map(|(id, a)| {
            let control = control_name(world.control(id as u32).expect("id in range"));
            let fields = [
                ("control", json!(control)),
                ("end_step", json!(a.end_step())),
            ];
            agent_json(id, a, fields)
        })
        .collect();
    json!({
        "type": "header",
        "format": "sharedspace-rollout/1",
        "scenario": scenario.name,
        "split": scenario.split,
        "model": model.name(),
        "vehicle_model": models.vehicles.name(),
        "dt": params.dt,
        "horizon": world.horizon(),
        "ego": scenario.ego,
        "ego_drive": match ego { EgoDrive::Replay => json!("replay"), EgoDrive::Constant(a) => json!(a) },
        "params": serde_json::to_value(params).expect("params serialise"),
        "variation": serde_json::to_value(variation).expect("variation serialises"),
        "agents": agents,
    })
}
