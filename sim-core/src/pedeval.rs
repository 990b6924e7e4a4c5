//! Pedestrian-model evaluation (model.md 9, paper Table I): the vehicles replay their record, the
//! pedestrians are simulated by the model under test from their recorded initial state, and the
//! simulated tracks are compared with the recorded ones.

use std::sync::Arc;

use crate::geometry::Vec2;
use crate::metrics::{displacement_errors, DisplacementErrors, PedestrianEvalSummary};
use crate::params::{PedestrianModel, WorldParams};
use crate::scenario::Scenario;
use crate::world::{AgentId, Control, EpisodeConfig, Event, World, WorldError};

/// One scenario's evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct PedestrianEpisode {
    pub errors: DisplacementErrors,
    /// A simulated pedestrian collided with someone at a step after the start.
    pub collided: bool,
    /// Simulated positions per simulated pedestrian, from its entry to the step it left or the
    /// last recorded step (for plots).
    pub simulated: Vec<(AgentId, Vec<Vec2>)>,
}

/// Runs `scenario` over its recorded window with the pedestrians driven by `model`.
///
/// A simulated pedestrian that reaches its goal early leaves the scene; its last simulated
/// position (the one at which it arrived) stands for it at the remaining steps. Errors are taken at every step at which the
/// pedestrian is recorded, from the step after its entry.
pub fn evaluate_scenario(
    scenario: Arc<Scenario>,
    params: &WorldParams,
    model: PedestrianModel,
) -> Result<PedestrianEpisode, WorldError> {
    let end = scenario.recorded_steps().saturating_sub(1);
    // The whole recorded window is evaluated: the horizon (the ego's recorded duration plus
    // `horizon_extra`) must not cut it short when other agents are recorded for longer.
    let mut params = *params;
    params.horizon_extra = params.horizon_extra.max(f64::from(end) * params.dt);
    let mut world = World::new(
        scenario.clone(),
        params,
        EpisodeConfig::replay_vehicles(model),
    )?;
    let simulated_ids: Vec<AgentId> = (0..scenario.agents.len() as AgentId)
        .filter(|&id| matches!(world.control(id), Some(Control::Model(_))))
        .collect();
    let mut last: Vec<Option<Vec2>> = simulated_ids
        .iter()
        .map(|&id| world.agent(id).map(|a| a.position))
        .collect();
    let mut simulated: Vec<Vec<Vec2>> = last.iter().map(|p| p.iter().copied().collect()).collect();
    let mut sim_err: Vec<Vec<Vec2>> = vec![Vec::new(); simulated_ids.len()];
    let mut rec_err: Vec<Vec<Vec2>> = vec![Vec::new(); simulated_ids.len()];
    let mut collided = false;
    for _ in 0..end {
        let out = world
            .step(&[])
            .expect("no external agents: a step cannot be refused");
        for ev in &out.events {
            if let Event::Collision { a, b } = ev {
                collided |= simulated_ids.contains(a) || simulated_ids.contains(b);
            }
        }
        let t = out.step;
        for (k, &id) in simulated_ids.iter().enumerate() {
            // Present, or removed during this step (at its goal) at the position it reached.
            let now = world.agent(id).map(|a| a.position).or_else(|| {
                world
                    .departed()
                    .iter()
                    .find(|(d, _)| *d == id)
                    .map(|(_, p)| *p)
            });
            if let Some(p) = now {
                last[k] = Some(p);
                simulated[k].push(p);
            }
            let rec = &scenario.agents[id as usize];
            if let (Some(p), Some(r)) = (last[k], rec.position_at(t)) {
                if t > rec.start_step {
                    sim_err[k].push(p);
                    rec_err[k].push(Vec2::new(r[0], r[1]));
                }
            }
        }
    }
    Ok(PedestrianEpisode {
        errors: displacement_errors(&sim_err, &rec_err),
        collided,
        simulated: simulated_ids.into_iter().zip(simulated).collect(),
    })
}

/// Evaluates `model` on every scenario and averages (the Table I row).
pub fn evaluate<'a>(
    scenarios: impl IntoIterator<Item = &'a Arc<Scenario>>,
    params: &WorldParams,
    model: PedestrianModel,
) -> Result<PedestrianEvalSummary, WorldError> {
    let mut episodes = Vec::new();
    for s in scenarios {
        let e = evaluate_scenario(s.clone(), params, model)?;
        episodes.push((e.errors, e.collided));
    }
    Ok(PedestrianEvalSummary::of(&episodes))
}
