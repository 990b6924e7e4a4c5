//! One simulation env: a seeded scenario sequence, the current episode's [`World`], its steps
//! and resets as protocol messages (the translations of sim-core's results: `wire.rs`). Pure and
//! synchronous.

use std::sync::{Arc, OnceLock};

use protocol::{
    encode, EnvTopic, EpisodeMetrics, ErrorCode, ErrorReply, Event, EventKind, EventsMsg, F32Array,
    F64Array, KeySpace, Mode, ObsBatch, Reset, ResetResult, RewardTerms as WireTerms, RiskGraphMsg,
    StateRewards, StatesMsg, StepInfo, StepResult, U32Array, U8Array, UncertaintyMsg, N_FEATURES,
    PAD_NODE_ID,
};
use sim_core::geometry::Shape;
use sim_core::params::VehicleModel;
use sim_core::params::{PedestrianModel, WorldParams};
use sim_core::scenario::Split;
use sim_core::support::rng::{derive_seed, SplitMix64};
use sim_core::variation::{Variation, VariationSpec};
use sim_core::world::{
    AgentId, Control, EpisodeConfig, StepError, StepOutcome, StepScratch, World,
};

use protocol::wire::{BatchArrays, BatchColumns, BatchReset, ObsRef};

use super::pools::{
    AgentsNeeded, Composed, EpisodeDraw, ExternalAgent, ScenarioSequence, ServedPool,
    ServedScenario,
};

mod buffers;
mod publish;
mod wire;

pub use buffers::{BufMut, Buffers, Slots};
pub use publish::{Gates, Publication, Watch};
use wire::{agent_descs, event, outcome_of, sim_event, to_wire_kind, write_obs};

/// The stream of an env's variation seeds, apart from its scenario sequence (an arbitrary
/// constant: "variation" in ASCII).
const VARIATION_STREAM: u64 = 0x7661_7269_6174_696f;
/// The stream of an env's composed-scene draws (an arbitrary constant: "composed" in ASCII).
const COMPOSED_STREAM: u64 = 0x636f_6d70_6f73_6564;

/// The configuration shared by the envs of one `CreateEnv`.
#[derive(Debug)]
pub struct EnvSpec {
    pub client_id: String,
    pub pool: Arc<ServedPool>,
    pub split: Split,
    /// Scenario indices an episode may be drawn from.
    pub candidates: Arc<Vec<usize>>,
    pub pinned: Option<usize>,
    /// Scenes composed from the recorded parts of a pool's train scenes, drawn beside the
    /// candidates or instead of them (`CreateEnv.composed`).
    pub composed: Option<Arc<Composed>>,
    pub model: PedestrianModel,
    pub params: WorldParams,
    /// External agent names (`vehicle_{k}`, `pedestrian_{k}`) in action order.
    pub external_names: Vec<String>,
    /// Each of them parsed.
    pub externals: Vec<ExternalAgent>,
    pub mode: Mode,
    pub max_agents: u32,
    pub autoreset: bool,
    pub realtime_factor: f64,
    /// Scene variations drawn per episode (`CreateEnv.variations` or the pool entry's).
    pub variations: Option<VariationSpec>,
    /// How the vehicles nobody controls move (`CreateEnv.vehicle_model` or the pool's).
    pub vehicle_model: VehicleModel,
    pub keys: KeySpace,
    /// The fresh world of each scenario of the pool for this configuration, built on first
    /// use (`World::new` is deterministic, so a reset clones it instead of building it again).
    pub fresh_worlds: Vec<OnceLock<World>>,
}

impl EnvSpec {
    pub fn n_ext(&self) -> usize {
        self.external_names.len()
    }

    /// One empty cache slot per scenario of `pool`, for [`EnvSpec::fresh_worlds`].
    pub fn world_cache(pool: &ServedPool) -> Vec<OnceLock<World>> {
        (0..pool.scenarios.len()).map(|_| OnceLock::new()).collect()
    }
}

/// The parts of a step result that are not arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct StepMeta {
    pub episode: u64,
    /// The name of the stepped episode's scenario.
    pub scenario: Arc<str>,
    pub step: u32,
    pub t: f64,
    /// With [`Env::action_clipped`], the step's [`StepInfo`].
    pub events: Vec<Event>,
    pub metrics: Vec<EpisodeMetrics>,
    /// Whether the step ended the episode and autoreset started the next: its `ResetResult`
    /// is then [`Env::reset_result`] (or [`Env::push_reset_columns`]) until the next step.
    pub reset: bool,
}

/// One env.
#[derive(Debug)]
pub struct Env {
    pub id: String,
    pub spec: Arc<EnvSpec>,
    seq: ScenarioSequence,
    /// The seeds of the env's variations, one per episode (seeded with the env's seed like
    /// `seq`, on a stream of its own).
    variation_seeds: SplitMix64,
    /// The current episode's variation, if the env has variations.
    variation: Option<Variation>,
    /// The draws of the env's composed scenes (seeded with the env's seed on a stream of its
    /// own).
    composed_draws: SplitMix64,
    episode: u64,
    world: Option<World>,
    /// The current episode's scenario (a pool's, or a composed one).
    served: Arc<ServedScenario>,
    /// Agent ids of the external agents in the current episode, in action order.
    ext_ids: Vec<AgentId>,
    returns: Vec<f64>,
    /// Realtime: held action and last applied sequence number per external agent.
    held: Vec<[f64; 2]>,
    held_seq: Vec<Option<u64>>,
    /// Scratch for the actions of the active external agents of a step (kept to avoid an
    /// allocation per step).
    active: Vec<(AgentId, [f64; 2])>,
    /// Scratch for the first observation of an episode (autoreset makes that frequent).
    reset_obs: Buffers,
    /// Per external agent: whether its action in the last step was clipped (kept here rather
    /// than allocated per step).
    clipped: Vec<bool>,
    pub closed: bool,
}

impl Env {
    pub fn new(id: String, spec: Arc<EnvSpec>, seed: u64) -> Self {
        let n = spec.n_ext();
        Self {
            id,
            seq: ScenarioSequence::new(spec.candidates.clone(), seed),
            variation_seeds: SplitMix64::new(derive_seed(seed, VARIATION_STREAM)),
            variation: None,
            composed_draws: SplitMix64::new(derive_seed(seed, COMPOSED_STREAM)),
            served: spec.pool.scenarios[spec.candidates.first().copied().unwrap_or(0)].clone(),
            spec,
            episode: 0,
            world: None,
            ext_ids: Vec::new(),
            returns: vec![0.0; n],
            held: vec![[0.0; 2]; n],
            held_seq: vec![None; n],
            active: Vec::with_capacity(n),
            reset_obs: Buffers::default(),
            clipped: vec![false; n],
            closed: false,
        }
    }

    /// Re-seeds the scenario sequence and the variation seeds (`Reset.seed`).
    fn reseed(&mut self, seed: u64) {
        self.seq.reseed(seed);
        self.variation_seeds = SplitMix64::new(derive_seed(seed, VARIATION_STREAM));
        self.composed_draws = SplitMix64::new(derive_seed(seed, COMPOSED_STREAM));
    }

    pub fn episode(&self) -> u64 {
        self.episode
    }

    pub fn world(&self) -> Option<&World> {
        self.world.as_ref()
    }

    /// Per external agent, whether its action in the last step was clipped.
    pub fn action_clipped(&self) -> &[bool] {
        &self.clipped
    }

    /// The name of the current episode's scenario.
    pub fn scenario_name(&self) -> &Arc<str> {
        &self.served.name
    }

    /// Starts a new episode (`Reset`). Publications of the first state go to `pubs`.
    pub fn reset(
        &mut self,
        req: &Reset,
        gates: Gates,
        pubs: &mut Vec<Publication>,
    ) -> Result<ResetResult, ErrorReply> {
        self.start_episode(req.seed, req.scenario.as_deref(), req.variation)?;
        let result = self.reset_result()?;
        self.publish_episode_start(gates, pubs);
        Ok(result)
    }

    /// The state change of [`Env::reset`].
    fn start_episode(
        &mut self,
        seed: Option<u64>,
        scenario: Option<&str>,
        variation: Option<u64>,
    ) -> Result<(), ErrorReply> {
        if variation.is_some() && self.spec.variations.is_none() {
            return Err(ErrorReply::new(
                ErrorCode::BadRequest,
                "variation: this env has no variations (CreateEnv.variations)",
            )
            .with_env(self.id.clone()));
        }
        let draw = self.next_scenario(seed, scenario)?;
        let spec = self.spec.clone();
        let served = match draw {
            EpisodeDraw::Recorded(i) => spec.pool.scenarios[i].clone(),
            EpisodeDraw::Composed(i) => Arc::new(ServedScenario::new(
                spec.composed
                    .as_ref()
                    .expect("drawn only with composed scenes")
                    .scene(i),
            )),
        };
        let cache_slot = match draw {
            EpisodeDraw::Recorded(i) => Some(i),
            EpisodeDraw::Composed(_) => None,
        };
        let ext_ids: Vec<AgentId> = spec
            .externals
            .iter()
            .map(|&e| {
                served
                    .agent_id(e)
                    .expect("a candidate scenario has every external agent")
            })
            .collect();
        let config = EpisodeConfig {
            pedestrian_model: spec.model,
            model_overrides: Vec::new(),
            external: ext_ids.clone(),
            vehicle_model: spec.vehicle_model,
            vehicle_overrides: Vec::new(),
        };
        let variation = spec.variations.as_ref().map(|v| {
            let seed = variation.unwrap_or_else(|| self.variation_seeds.next_u64());
            v.draw(&served.scenario, &spec.params, seed)
        });
        let world = self.episode_world(&served, cache_slot, variation.as_ref(), config)?;
        self.world = Some(world);
        self.variation = variation;
        self.served = served;
        self.ext_ids = ext_ids;
        self.episode += 1;
        self.returns.iter_mut().for_each(|r| *r = 0.0);
        self.held.iter_mut().for_each(|h| *h = [0.0; 2]);
        self.held_seq.iter_mut().for_each(|h| *h = None);
        Ok(())
    }

    /// The next episode's scenario: the one named (among the env's candidates, or a composed
    /// scene of its generator), else the pinned one, else the next draw of the env's sequence
    /// (re-seeded first when a `seed` is given).
    fn next_scenario(
        &mut self,
        seed: Option<u64>,
        scenario: Option<&str>,
    ) -> Result<EpisodeDraw, ErrorReply> {
        let spec = self.spec.clone();
        let Some(name) = scenario else {
            if let Some(seed) = seed {
                self.reseed(seed);
            }
            return Ok(match (spec.pinned, &spec.composed) {
                (Some(i), _) => EpisodeDraw::Recorded(i),
                (None, Some(c)) => c.draw(&spec.candidates, &mut self.composed_draws),
                (None, None) => EpisodeDraw::Recorded(self.seq.next_scenario()),
            });
        };
        let named = spec.composed.as_ref().and_then(|c| c.index_of(name));
        let draw = match named {
            Some(i) => EpisodeDraw::Composed(i),
            None => EpisodeDraw::Recorded(self.candidate_named(name)?),
        };
        if let Some(seed) = seed {
            self.reseed(seed);
        }
        Ok(draw)
    }

    /// The pool index of candidate scenario `name`.
    fn candidate_named(&self, name: &str) -> Result<usize, ErrorReply> {
        let spec = &self.spec;
        let pool = &spec.pool;
        let Some(i) = pool.find(name) else {
            return Err(ErrorReply::new(
                ErrorCode::BadRequest,
                format!("no scenario {name:?} in pool {:?}", pool.name),
            )
            .with_env(self.id.clone()));
        };
        if !spec.candidates.contains(&i) {
            return Err(ErrorReply::new(
                ErrorCode::BadRequest,
                format!(
                    "scenario {name:?} is not in this env's candidates (split {:?} of pool {:?} with at least {})",
                    spec.split,
                    pool.name,
                    AgentsNeeded::of(&spec.externals)
                ),
            )
            .with_env(self.id.clone()));
        }
        Ok(i)
    }

    /// The world of an episode of `served`: built from the variation's scene, or a copy of
    /// the cached fresh world of pool scenario `cache_slot` (built and cached on its first
    /// episode), or built afresh (a composed scene).
    fn episode_world(
        &mut self,
        served: &ServedScenario,
        cache_slot: Option<usize>,
        variation: Option<&Variation>,
        config: EpisodeConfig,
    ) -> Result<World, ErrorReply> {
        let spec = self.spec.clone();
        let slot = cache_slot.and_then(|i| spec.fresh_worlds.get(i));
        Ok(match (variation, slot.and_then(OnceLock::get)) {
            (Some(v), _) => World::new(
                Arc::new(v.apply(&served.scenario)),
                v.apply_params(&spec.params),
                config,
            )
            .map_err(|e| {
                ErrorReply::new(
                    ErrorCode::Internal,
                    format!("cannot start episode (variation {}): {e}", v.seed),
                )
                .with_env(self.id.clone())
            })?,
            // Into the finished episode's world, so that a `World::clone_from` reusing its
            // allocations pays off here (sim-core's derived one still clones and drops).
            (None, Some(w)) => match self.world.take() {
                Some(mut old) => {
                    old.clone_from(w);
                    old
                }
                None => w.clone(),
            },
            (None, None) => {
                let w = World::new(served.scenario.clone(), spec.params, config).map_err(|e| {
                    ErrorReply::new(ErrorCode::Internal, format!("cannot start episode: {e}"))
                        .with_env(self.id.clone())
                })?;
                if let Some(cell) = slot {
                    let _ = cell.set(w.clone());
                }
                w
            }
        })
    }

    /// Writes the current episode's first observation into `reset_obs` (right after a reset
    /// or an autoreset).
    fn fill_reset_obs(&mut self) {
        let world = self
            .world
            .as_ref()
            .expect("a first observation after a reset");
        let m = self.spec.max_agents as usize;
        self.reset_obs.resize(1, self.spec.n_ext(), m);
        write_obs(world, &self.ext_ids, m, &mut self.reset_obs.slots(0));
    }

    /// The `ResetResult` of the current episode's first state (right after a reset or an
    /// autoreset).
    pub fn reset_result(&mut self) -> Result<ResetResult, ErrorReply> {
        self.fill_reset_obs();
        let world = self.world.as_ref().expect("reset_result after a reset");
        let served = &self.served;
        let agents = agent_descs(world, served, &self.ext_ids);
        let obs = self.reset_obs.obs();
        Ok(ResetResult {
            env_id: self.id.clone(),
            episode: self.episode,
            scenario: served.scenario.name.clone(),
            step: 0,
            t: 0.0,
            horizon_steps: world.horizon(),
            agents,
            obs: obs?,
            variation: self.variation.clone(),
        })
    }

    /// Adds [`Env::reset_result`] to a batch reply's columns as the reset of the env pushed
    /// last (this one), without building the owned result.
    pub fn push_reset_columns(&mut self, cols: &mut BatchColumns) {
        self.fill_reset_obs();
        let world = self
            .world
            .as_ref()
            .expect("push_reset_columns after a reset");
        let served = &self.served;
        cols.push_reset(BatchReset {
            episode: self.episode,
            scenario: &served.scenario.name,
            horizon_steps: world.horizon(),
            agents: agent_descs(world, served, &self.ext_ids),
            obs: self.reset_obs.obs_ref(),
            variation: self.variation.as_ref().map(|v| v.seed),
        });
    }

    /// Checks the env can be stepped in lockstep now.
    pub fn check_steppable(&self, lockstep: bool) -> Result<(), ErrorReply> {
        let err = |code, m: &str| Err(ErrorReply::new(code, m).with_env(self.id.clone()));
        if self.closed {
            return err(ErrorCode::EnvClosed, "env is closed");
        }
        if lockstep && self.spec.mode != Mode::Lockstep {
            return err(
                ErrorCode::WrongMode,
                "env is in realtime mode: publish actions on its action keys instead of stepping",
            );
        }
        match &self.world {
            None => err(
                ErrorCode::NeedsReset,
                "env was never reset; send Reset first",
            ),
            Some(w) if w.is_over() => err(
                ErrorCode::NeedsReset,
                "the episode is over (autoreset off); send Reset",
            ),
            Some(_) => Ok(()),
        }
    }

    /// One step with `actions` (one row per external agent, finite; checked by the caller).
    /// Writes arrays into `slots`, publications into `pubs`. The world steps in `scratch` when
    /// given (a batch thread's, shared by the envs it steps), else in its own.
    pub fn step_into(
        &mut self,
        actions: &[[f64; 2]],
        slots: &mut Slots<'_>,
        gates: Gates,
        pubs: &mut Vec<Publication>,
        scratch: Option<&mut StepScratch>,
    ) -> Result<StepMeta, ErrorReply> {
        let out = self.step_world(actions, scratch)?;
        let step = out.step;
        let dt = self.world.as_ref().expect("stepped").params().dt;
        let t = step as f64 * dt;
        let mut events: Vec<Event> = out.events.iter().map(|e| sim_event(e, step, t)).collect();
        let metrics = self.write_outcomes(&out, slots, &mut events, t, dt);
        let world = self.world.as_ref().expect("present");
        write_obs(world, &self.ext_ids, self.spec.max_agents as usize, slots);
        let over = world.is_over();
        if gates.any() {
            self.publish_state(gates, &events, Some(slots), pubs);
        }
        let meta_episode = self.episode;
        let scenario = self.served.name.clone();
        let reset = over && self.spec.autoreset;
        if reset {
            self.start_episode(None, None, None)?;
            self.publish_episode_start(gates, pubs);
        }
        Ok(StepMeta {
            episode: meta_episode,
            scenario,
            step,
            t,
            events,
            metrics,
            reset,
        })
    }

    /// Steps the world with one action row per external agent (agents whose episode has
    /// ended are left out).
    fn step_world(
        &mut self,
        actions: &[[f64; 2]],
        scratch: Option<&mut StepScratch>,
    ) -> Result<StepOutcome, ErrorReply> {
        self.check_steppable(false)?;
        let n = self.spec.n_ext();
        if actions.len() != n {
            return Err(ErrorReply::new(
                ErrorCode::WrongShape,
                format!("expected {n} action rows, got {}", actions.len()),
            )
            .with_env(self.id.clone()));
        }
        let world = self.world.as_mut().expect("checked above");
        let ext_ids = &self.ext_ids;
        self.active.clear();
        self.active
            .extend(world.active_externals().filter_map(|id| {
                ext_ids
                    .iter()
                    .position(|&x| x == id)
                    .map(|k| (id, actions[k]))
            }));
        let out = match scratch {
            Some(s) => world.step_in(s, &self.active),
            None => world.step(&self.active),
        };
        out.map_err(|e| {
            let (code, message) = match e {
                StepError::EpisodeOver => (ErrorCode::NeedsReset, e.to_string()),
                // named as the client names the agent: its row in `external_agents`
                StepError::NonFiniteAction { agent, .. } => {
                    let name = ext_ids
                        .iter()
                        .position(|&x| x == agent)
                        .map_or("?", |k| self.spec.external_names[k].as_str());
                    (ErrorCode::NonFiniteAction, format!("{name}: {e}"))
                }
                _ => (ErrorCode::Internal, e.to_string()),
            };
            ErrorReply::new(code, message).with_env(self.id.clone())
        })
    }

    /// Each external agent's reward, terms and flags into `slots`, its clipped action and
    /// episode end into `events`; the metrics of the episodes that ended.
    fn write_outcomes(
        &mut self,
        out: &StepOutcome,
        slots: &mut Slots<'_>,
        events: &mut Vec<Event>,
        t: f64,
        dt: f64,
    ) -> Vec<EpisodeMetrics> {
        let (n, step) = (self.spec.n_ext(), out.step);
        slots.reward.fill(0.0);
        for term in slots.terms.iter_mut() {
            term.fill(0.0);
        }
        slots.terminated.fill(0);
        slots.truncated.fill(0);
        self.clipped.clear();
        self.clipped.resize(n, false);
        let mut metrics = Vec::new();
        for o in &out.agents {
            let Some(k) = self.ext_ids.iter().position(|&x| x == o.agent) else {
                continue;
            };
            let r = &o.reward;
            let total = r.total();
            slots.reward[k] = total as f32;
            for (column, value) in slots.terms.iter_mut().zip(r.values()) {
                column[k] = value as f32;
            }
            slots.terminated[k] = u8::from(o.terminated);
            slots.truncated[k] = u8::from(o.truncated);
            self.returns[k] += total;
            if o.action_clipped {
                self.clipped[k] = true;
                events.push(event(EventKind::ActionClipped, step, t, vec![o.agent]));
            }
            if let Some(mm) = &o.metrics {
                let outcome = outcome_of(mm.status);
                events.push(Event {
                    outcome: Some(outcome),
                    ..event(EventKind::EpisodeEnd, step, t, vec![o.agent])
                });
                metrics.push(EpisodeMetrics {
                    agent: self.spec.external_names[k].clone(),
                    outcome,
                    steps: mm.steps,
                    duration: mm.steps as f64 * dt,
                    episode_return: self.returns[k],
                    avg_speed: mm.avg_speed,
                    avg_abs_jerk: mm.avg_abs_jerk,
                    max_abs_acc: mm.max_abs_acc,
                });
            }
        }
        metrics
    }

    /// A single (unbatched) step result; the world steps in `scratch` (see [`Env::step_into`]).
    pub fn step_single(
        &mut self,
        actions: &[[f64; 2]],
        gates: Gates,
        pubs: &mut Vec<Publication>,
        scratch: Option<&mut StepScratch>,
    ) -> Result<StepResult, ErrorReply> {
        let mut buf = Buffers::new(1, self.spec.n_ext(), self.spec.max_agents as usize);
        let meta = self.step_into(actions, &mut buf.slots(0), gates, pubs, scratch)?;
        let (reward, reward_terms, terminated, truncated) = buf.rewards()?;
        Ok(StepResult {
            env_id: self.id.clone(),
            episode: meta.episode,
            scenario: meta.scenario.to_string(),
            step: meta.step,
            t: meta.t,
            obs: buf.obs()?,
            reward,
            reward_terms,
            terminated,
            truncated,
            info: StepInfo {
                action_clipped: self.clipped.clone(),
                events: meta.events,
                metrics: meta.metrics,
            },
            reset: if meta.reset {
                Some(self.reset_result()?)
            } else {
                None
            },
        })
    }

    /// Realtime: records an action for external agent `agent` unless `seq` is older than the last
    /// one applied. Returns whether it was taken.
    pub fn hold_action(&mut self, agent: &str, action: [f64; 2], seq: u64) -> Result<bool, String> {
        let Some(k) = self.spec.external_names.iter().position(|a| a == agent) else {
            return Err(format!(
                "{agent:?} is not an external agent of env {}",
                self.id
            ));
        };
        if self.held_seq[k].is_some_and(|last| seq < last) {
            return Ok(false);
        }
        self.held_seq[k] = Some(seq);
        self.held[k] = action;
        Ok(true)
    }

    /// Realtime: one tick with the held actions. `None` when the env waits for a reset.
    pub fn realtime_tick(
        &mut self,
        gates: Gates,
        pubs: &mut Vec<Publication>,
    ) -> Option<Result<StepResult, ErrorReply>> {
        let waiting = match &self.world {
            None => true,
            Some(w) => w.is_over(),
        };
        if self.closed || waiting {
            return None;
        }
        let held = self.held.clone();
        let r = self.step_single(&held, gates, pubs, None);
        if gates.result {
            if let Ok(res) = &r {
                if let Ok(key) = self.spec.keys.env_result(&self.id) {
                    pubs.push(Publication {
                        key,
                        topic: EnvTopic::Result,
                        payload: encode(res),
                    });
                }
            }
        }
        Some(r)
    }
}
