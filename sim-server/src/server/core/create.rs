//! `CreateEnv`: the request's pool (a served one, or synthetic scenes), its parameter
//! overrides, and the new envs in the registry.

use protocol::ComposedScenes;
use scenarios::composed::{ComposeConfig, Parts, Role, RoleShares};
use sim_core::params::OverlayError;

use crate::server::pools::{AgentsNeeded, Composed, ExternalAgent};

use super::{
    bad, decode, lock, make_env_id, validate_env_id, ActionSpace, Arc, BTreeMap, CreateEnv,
    Duration, Env, EnvCreated, EnvSpec, ErrorCode, ErrorReply, Instant, Mode, Mutex, ObsLayout,
    Response, ServedPool, ServerCore, Split, SyntheticScenes, WireSplit, WorldParams,
};

/// `base` with a request's `pedestrian_params` and `reward_weights` (sim-core's
/// [`WorldParams::with_named`]: checked as a parameter file's fields are).
fn apply_overrides(
    base: &WorldParams,
    pedestrian_params: &BTreeMap<String, f64>,
    reward_weights: &BTreeMap<String, f64>,
) -> Result<WorldParams, ErrorReply> {
    base.with_named(pedestrian_params, reward_weights)
        .map_err(|e| match e {
            e @ OverlayError::UnknownName { .. } => bad(e.to_string()),
            e => bad(format!("pedestrian_params/reward_weights: {e}")),
        })
}

fn split_of(s: WireSplit) -> Split {
    match s {
        WireSplit::Train => Split::Train,
        WireSplit::Test => Split::Test,
    }
}

/// Most pedestrians of a requested synthetic scene (a world of this size steps in milliseconds).
pub const MAX_SYNTHETIC_PEDESTRIANS: u32 = 2_000;
/// Most scenes of one synthetic request.
pub const MAX_SYNTHETIC_SCENES: u32 = 256;

/// The pool `synthetic` of a `CreateEnv.synthetic` request: its scenes, seeds `seed`,
/// `seed + 1`, ..., all in `split`.
fn synthetic_pool(req: &SyntheticScenes, split: Split) -> Result<ServedPool, ErrorReply> {
    use scenarios::synthetic::{generate_pool, Layout, Routes, SyntheticConfig};
    let layout: Layout = req.layout.parse().map_err(|_| {
        bad(format!(
            "synthetic.layout {:?}: expected one of crossing, counter_flow, random",
            req.layout
        ))
    })?;
    let routes: Routes = req.routes.parse().map_err(|_| {
        bad(format!(
            "synthetic.routes {:?}: expected one of lanes, intersection",
            req.routes
        ))
    })?;
    if req.pedestrians > MAX_SYNTHETIC_PEDESTRIANS {
        return Err(ErrorReply::new(
            ErrorCode::LimitExceeded,
            format!(
                "synthetic.pedestrians {} exceeds {MAX_SYNTHETIC_PEDESTRIANS}",
                req.pedestrians
            ),
        ));
    }
    if req.scenes == 0 || req.scenes > MAX_SYNTHETIC_SCENES {
        return Err(bad(format!(
            "synthetic.scenes {} must be between 1 and {MAX_SYNTHETIC_SCENES}",
            req.scenes
        )));
    }
    let configs: Vec<SyntheticConfig> = (0..u64::from(req.scenes))
        .map(|i| SyntheticConfig {
            layout,
            pedestrians: req.pedestrians as usize,
            vehicles: req.vehicles as usize,
            routes,
            density: req.density,
            seed: req.seed.wrapping_add(i),
            split,
            ..SyntheticConfig::default()
        })
        .collect();
    let pool = generate_pool("synthetic", &configs).map_err(|e| bad(format!("synthetic: {e}")))?;
    Ok(ServedPool::new(pool))
}

impl ServerCore {
    /// `CreateEnv` → `Reply<EnvCreated>`.
    pub fn handle_create(&self, payload: &[u8], now: Instant) -> Response {
        match self.create(payload, now) {
            Ok((created, realtime)) => {
                let mut r = Response::of(Ok::<_, ErrorReply>(created), Vec::new());
                r.realtime_envs = realtime;
                r
            }
            Err(e) => Response::of(Err::<EnvCreated, _>(e), Vec::new()),
        }
    }

    #[allow(clippy::type_complexity)]
    fn create(
        &self,
        payload: &[u8],
        now: Instant,
    ) -> Result<(EnvCreated, Vec<(String, Duration)>), ErrorReply> {
        let req: CreateEnv = decode(payload).map_err(bad)?;
        req.validate()?;
        self.check_create_limits(&req)?;
        let pool = self.pool_of(&req)?;
        let params = apply_overrides(
            self.params.for_model(req.pedestrian_model),
            &req.pedestrian_params,
            &req.reward_weights,
        )?;
        let externals = external_agents(&req.external_agents)?;
        let split = split_of(req.split);
        let composed = self.composed_of(req.composed.as_ref(), &pool, split, &externals)?;
        let (candidates, pinned) =
            episode_candidates(&pool, split, &externals, &req.scenario, &req.exclude)?;
        let spec = Arc::new(EnvSpec {
            client_id: req.client_id.clone(),
            pool: pool.clone(),
            split,
            candidates: Arc::new(candidates),
            pinned,
            composed,
            model: req.pedestrian_model,
            params,
            external_names: req.external_agents.clone(),
            externals,
            mode: req.mode,
            max_agents: req.max_agents,
            autoreset: req.autoreset,
            realtime_factor: req.realtime_factor,
            variations: req.variations.clone().or_else(|| pool.variations.clone()),
            vehicle_model: req.vehicle_model.unwrap_or(pool.vehicle_model),
            keys: self.keys.clone(),
            fresh_worlds: EnvSpec::world_cache(&pool),
        });
        let ids = self.register_envs(&req, &spec, now)?;
        let realtime = if req.mode == Mode::Realtime {
            let period =
                Duration::from_secs_f64((params.dt / req.realtime_factor).clamp(1e-3, 3600.0));
            ids.iter().map(|id| (id.clone(), period)).collect()
        } else {
            Vec::new()
        };
        let created = EnvCreated {
            env_ids: ids,
            external_agents: req.external_agents,
            observation: ObsLayout::standard(req.max_agents),
            action: ActionSpace::normalised(params.vehicle.acc_max, params.vehicle.omega_max),
            dt: params.dt,
            mode: req.mode,
            split: req.split,
            pedestrian_model: req.pedestrian_model,
            autoreset: req.autoreset,
        };
        Ok((created, realtime))
    }

    /// The composed scenes of a request (`CreateEnv.composed`), checked: train envs driving
    /// `vehicle_0` alone, a served source pool, held-out scenes it has, shares by known names.
    fn composed_of(
        &self,
        req: Option<&ComposedScenes>,
        pool: &ServedPool,
        split: Split,
        externals: &[ExternalAgent],
    ) -> Result<Option<Arc<Composed>>, ErrorReply> {
        let Some(c) = req else {
            return Ok(None);
        };
        if split != Split::Train {
            return Err(bad(
                "composed scenes are train scenes: send split train with them",
            ));
        }
        let need = AgentsNeeded::of(externals);
        if need.vehicles > 1 || need.pedestrians > 0 {
            return Err(bad(format!(
                "composed scenes have one car a client drives, vehicle_0; external_agents needs {need}"
            )));
        }
        if c.scenes == Some(0) {
            return Err(bad(
                "composed.scenes must be at least 1 (nil: a fresh scene every episode)",
            ));
        }
        let mut shares = RoleShares::default();
        for (name, &weight) in &c.shares {
            let role: Role = name
                .parse()
                .map_err(|e| bad(format!("composed.shares: {e}")))?;
            match role {
                Role::Crossing => shares.crossing = weight,
                Role::Along => shares.along = weight,
                Role::Oncoming => shares.oncoming = weight,
                Role::Background => shares.background = weight,
            }
        }
        let config = ComposeConfig {
            seed: c.seed,
            pedestrians: c.pedestrians,
            shares,
            other_cars: c.other_cars,
        };
        config
            .validate()
            .map_err(|e| bad(format!("composed: {e}")))?;
        let source_name = c.source.as_deref().unwrap_or(&pool.name);
        let source = self.pool_named(Some(source_name)).ok_or_else(|| {
            let names: Vec<&str> = self.pools.iter().map(|p| p.name.as_str()).collect();
            bad(format!(
                "composed.source {source_name:?}: this server has no such pool; it has: {}",
                names.join(", ")
            ))
        })?;
        let parts = self.composed_parts(&source, &c.hold_out)?;
        Ok(Some(Arc::new(Composed {
            parts,
            config,
            scenes: c.scenes,
        })))
    }

    /// The parts of `source`'s train scenes less `hold_out`, taken apart on the first request
    /// that asks for them.
    fn composed_parts(
        &self,
        source: &ServedPool,
        hold_out: &[String],
    ) -> Result<Arc<Parts>, ErrorReply> {
        let mut held = hold_out.to_vec();
        held.sort();
        held.dedup();
        let key = (source.name.clone(), held);
        if let Some(parts) = lock(&self.composed_parts).get(&key) {
            return Ok(parts.clone());
        }
        let scenes: Vec<&sim_core::scenario::Scenario> =
            source.scenarios.iter().map(|s| &*s.scenario).collect();
        let parts = Parts::of_scenes(&source.name, &scenes, &key.1)
            .map_err(|e| bad(format!("composed: {e}")))?;
        let parts = Arc::new(parts);
        lock(&self.composed_parts).insert(key, parts.clone());
        Ok(parts)
    }

    /// `count` and `max_agents` within the server's limits.
    fn check_create_limits(&self, req: &CreateEnv) -> Result<(), ErrorReply> {
        let lim = self.limits;
        if req.count > lim.max_batch {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!("count {} exceeds max_batch {}", req.count, lim.max_batch),
            ));
        }
        if req.max_agents > lim.max_agents {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "max_agents {} exceeds the server's maximum {}",
                    req.max_agents, lim.max_agents
                ),
            ));
        }
        Ok(())
    }

    /// The pool the envs play: the generated scenes the request asks for, or a served pool.
    fn pool_of(&self, req: &CreateEnv) -> Result<Arc<ServedPool>, ErrorReply> {
        match (&req.synthetic, &req.pool) {
            (Some(_), Some(name)) => {
                return Err(bad(format!(
                    "synthetic scenes and pool {name:?} exclude each other: send one"
                )))
            }
            (Some(_), None) if req.composed.is_some() => {
                return Err(bad(
                    "synthetic and composed scenes exclude each other: send one",
                ))
            }
            (Some(syn), None) => Some(Arc::new(synthetic_pool(syn, split_of(req.split))?)),
            (None, _) => self.pool_named(req.pool.as_deref()),
        }
        .ok_or_else(|| {
            let names: Vec<&str> = self.pools.iter().map(|p| p.name.as_str()).collect();
            bad(format!(
                "unknown pool {:?}; this server has: {}",
                req.pool.as_deref().unwrap_or("(default)"),
                names.join(", ")
            ))
        })
    }

    /// Registers `count` envs of `spec` for the request's client, within the quotas (per
    /// trainer, then the server's capacity); their ids.
    fn register_envs(
        &self,
        req: &CreateEnv,
        spec: &Arc<EnvSpec>,
        now: Instant,
    ) -> Result<Vec<String>, ErrorReply> {
        let lim = self.limits;
        let mut reg = lock(&self.reg);
        let load = reg.envs.len() as u64;
        let own = reg.clients.get(&req.client_id).map_or(0, |c| c.envs.len()) as u64;
        if own + u64::from(req.count) > u64::from(lim.max_envs_per_trainer) {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "max_envs_per_trainer: trainer {:?} has {own} of {} envs open, {} more requested",
                    req.client_id, lim.max_envs_per_trainer, req.count
                ),
            ));
        }
        if load + u64::from(req.count) > u64::from(lim.capacity) {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "capacity: {load} of {} envs open, {} more requested",
                    lim.capacity, req.count
                ),
            ));
        }
        let mut ids = Vec::with_capacity(req.count as usize);
        for k in 0..u64::from(req.count) {
            let id = make_env_id(&self.server_id, reg.counter);
            validate_env_id(&id)
                .map_err(|e| ErrorReply::new(ErrorCode::Internal, e.to_string()))?;
            reg.counter += 1;
            let env = Env::new(id.clone(), spec.clone(), req.seed.wrapping_add(k));
            reg.envs.insert(id.clone(), Arc::new(Mutex::new(env)));
            reg.owner.insert(id.clone(), req.client_id.clone());
            ids.push(id);
        }
        let client = reg.clients.entry(req.client_id.clone()).or_default();
        client.envs.extend(ids.iter().cloned());
        if !client.alive && client.deadline.is_none() {
            client.deadline = Some(now + lim.trainer_grace);
        }
        Ok(ids)
    }
}

/// Each external agent's name parsed: `vehicle_{k}` or `pedestrian_{k}`.
fn external_agents(names: &[String]) -> Result<Vec<ExternalAgent>, ErrorReply> {
    names
        .iter()
        .map(|name| {
            ExternalAgent::parse(name).ok_or_else(|| {
                bad(format!(
                    "external agent {name:?}: expected vehicle_{{k}} (vehicle_0 is the scenario's ego) or pedestrian_{{k}}"
                ))
            })
        })
        .collect()
}

/// The scenarios of `split` with every external agent, and the pinned `scenario`'s index
/// among them (if one is named).
fn episode_candidates(
    pool: &ServedPool,
    split: Split,
    externals: &[ExternalAgent],
    scenario: &Option<String>,
    exclude: &[String],
) -> Result<(Vec<usize>, Option<usize>), ErrorReply> {
    let need = AgentsNeeded::of(externals);
    let mut excluded = Vec::with_capacity(exclude.len());
    for name in exclude {
        let i = pool.find(name).ok_or_else(|| {
            bad(format!(
                "exclude: no scenario {name:?} in pool {:?}",
                pool.name
            ))
        })?;
        excluded.push(i);
    }
    let candidates: Vec<usize> = pool
        .candidates(split, need)
        .into_iter()
        .filter(|i| !excluded.contains(i))
        .collect();
    let pinned = match scenario {
        None => None,
        Some(name) => {
            let i = pool
                .find(name)
                .ok_or_else(|| bad(format!("no scenario {name:?} in pool {:?}", pool.name)))?;
            if !candidates.contains(&i) {
                return Err(bad(format!(
                    "scenario {name:?} is not in split {:?} of pool {:?}, has fewer than {need} \
                     or is excluded",
                    split, pool.name
                )));
            }
            Some(i)
        }
    };
    if candidates.is_empty() {
        return Err(bad(format!(
            "split {split:?} of pool {:?} has no scenario with {need} (less {} excluded)",
            pool.name,
            excluded.len()
        )));
    }
    Ok((candidates, pinned))
}
