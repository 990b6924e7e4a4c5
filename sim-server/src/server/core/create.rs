//! `CreateEnv`: the request's pool (a served one, or synthetic scenes), its parameter
//! overrides, and the new envs in the registry.

use super::*;

/// The names accepted in `CreateEnv.pedestrian_params` (model.md names) besides the social-force
/// ones (`SocialForceParams::NAMES`, which apply to the parameter sets of `sfm`, `ra_sfm` and
/// `cr_sfm` alike), each with the field it sets.
type ParamField = fn(&mut WorldParams) -> &mut f64;
const OTHER_PEDESTRIAN_PARAMS: [(&str, ParamField); 9] = [
    ("gamma1", |p| &mut p.risk.gamma1),
    ("gamma2", |p| &mut p.risk.gamma2),
    ("lambda", |p| &mut p.risk.lambda),
    ("s0", |p| &mut p.cognition.s0),
    ("q", |p| &mut p.cognition.q),
    ("s_o", |p| &mut p.cognition.s_o),
    ("v_ped_max", |p| &mut p.ped_speed_max),
    ("ped_radius", |p| &mut p.ped_radius),
    ("ped_goal_radius", |p| &mut p.ped_goal_radius),
];

fn apply_pedestrian_params(
    base: WorldParams,
    overrides: &BTreeMap<String, f64>,
) -> Result<WorldParams, ErrorReply> {
    let mut p = base;
    for (name, &v) in overrides {
        if SocialForceParams::NAMES.contains(&name.as_str()) {
            for set in p.pedestrians.social_force_sets_mut() {
                *set.get_mut(name).expect("one of NAMES") = v;
            }
        } else if let Some((_, field)) = OTHER_PEDESTRIAN_PARAMS.iter().find(|(n, _)| n == name) {
            *field(&mut p) = v;
        } else {
            let known: Vec<&str> = SocialForceParams::NAMES
                .iter()
                .copied()
                .chain(OTHER_PEDESTRIAN_PARAMS.iter().map(|(n, _)| *n))
                .collect();
            return Err(ErrorReply::new(
                ErrorCode::BadRequest,
                format!(
                    "unknown pedestrian parameter {name:?}; known: {}",
                    known.join(", ")
                ),
            ));
        }
    }
    p.validate()
        .map_err(|e| ErrorReply::new(ErrorCode::BadRequest, format!("pedestrian_params: {e}")))?;
    Ok(p)
}

fn apply_reward_weights(
    mut p: WorldParams,
    weights: &BTreeMap<String, f64>,
) -> Result<WorldParams, ErrorReply> {
    for (name, &v) in weights {
        let w = &mut p.reward;
        match name.as_str() {
            "progress" => w.progress = v,
            "success" => w.success = v,
            "collision" => w.collision = v,
            "danger" => w.danger = v,
            "danger_clearance" => w.danger_clearance = v,
            "comfort_jerk" => w.jerk_penalty = v,
            "comfort_omega" => w.yaw_rate_penalty = v,
            _ => {
                return Err(ErrorReply::new(
                    ErrorCode::BadRequest,
                    format!("unknown reward weight {name:?}"),
                ))
            }
        }
    }
    Ok(p)
}

fn split_of(s: WireSplit) -> Split {
    match s {
        WireSplit::Train => Split::Train,
        WireSplit::Test => Split::Test,
    }
}

fn parse_vehicle(name: &str) -> Option<usize> {
    let k = name.strip_prefix("vehicle_")?;
    if k.is_empty() || (k.len() > 1 && k.starts_with('0')) || !k.bytes().all(|b| b.is_ascii_digit())
    {
        return None;
    }
    k.parse().ok()
}

/// Most pedestrians of a requested synthetic scene (a world of this size steps in milliseconds).
pub const MAX_SYNTHETIC_PEDESTRIANS: u32 = 2_000;
/// Most scenes of one synthetic request.
pub const MAX_SYNTHETIC_SCENES: u32 = 256;

/// The pool `synthetic` of a `CreateEnv.synthetic` request: its scenes, seeds `seed`,
/// `seed + 1`, ..., all in `split`.
fn synthetic_pool(req: &SyntheticScenes, split: Split) -> Result<ServedPool, ErrorReply> {
    use scenarios::synthetic::{generate_pool, Layout, SyntheticConfig};
    let layout: Layout = req.layout.parse().map_err(|_| {
        bad(format!(
            "synthetic.layout {:?}: expected one of crossing, counter_flow, random",
            req.layout
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
        let pool = match (&req.synthetic, &req.pool) {
            (Some(_), Some(name)) => {
                return Err(bad(format!(
                    "synthetic scenes and pool {name:?} exclude each other: send one"
                )))
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
        })?;
        let params = apply_pedestrian_params(
            *self.params.for_model(req.pedestrian_model),
            &req.pedestrian_params,
        )?;
        let params = apply_reward_weights(params, &req.reward_weights)?;
        let mut vehicles = Vec::with_capacity(req.external_agents.len());
        for name in &req.external_agents {
            let k = parse_vehicle(name).ok_or_else(|| {
                bad(format!(
                    "external agent {name:?}: expected a vehicle name vehicle_{{k}} (vehicle_0 is the scenario's ego)"
                ))
            })?;
            vehicles.push(k);
        }
        let need = vehicles.iter().max().map_or(0, |k| k + 1);
        let split = split_of(req.split);
        let candidates = pool.candidates(split, need);
        let pinned = match &req.scenario {
            None => None,
            Some(name) => {
                let i = pool
                    .find(name)
                    .ok_or_else(|| bad(format!("no scenario {name:?} in pool {:?}", pool.name)))?;
                if !candidates.contains(&i) {
                    return Err(bad(format!(
                        "scenario {name:?} is not in split {:?} of pool {:?} or has fewer than {need} vehicles",
                        split, pool.name
                    )));
                }
                Some(i)
            }
        };
        if candidates.is_empty() {
            return Err(bad(format!(
                "split {split:?} of pool {:?} has no scenario with {need} vehicle(s)",
                pool.name
            )));
        }
        let spec = Arc::new(EnvSpec {
            client_id: req.client_id.clone(),
            pool: pool.clone(),
            split,
            candidates: Arc::new(candidates),
            pinned,
            model: req.pedestrian_model,
            params,
            external_names: req.external_agents.clone(),
            external_vehicles: vehicles,
            mode: req.mode,
            max_agents: req.max_agents,
            autoreset: req.autoreset,
            realtime_factor: req.realtime_factor,
            variations: req.variations.clone().or_else(|| pool.variations.clone()),
            vehicle_model: req.vehicle_model.unwrap_or(pool.vehicle_model),
            keys: self.keys.clone(),
            fresh_worlds: EnvSpec::world_cache(&pool),
        });
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
        let grace = self.limits.trainer_grace;
        let client = reg.clients.entry(req.client_id.clone()).or_default();
        client.envs.extend(ids.iter().cloned());
        if !client.alive && client.deadline.is_none() {
            client.deadline = Some(now + grace);
        }
        drop(reg);
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
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_pedestrian_param_name_sets_its_field_and_nothing_else() {
        let base = WorldParams::default();
        let names = SocialForceParams::NAMES
            .iter()
            .copied()
            .chain(OTHER_PEDESTRIAN_PARAMS.iter().map(|(n, _)| *n));
        for name in names {
            let set = apply_pedestrian_params(base, &[(name.to_string(), 0.123)].into())
                .unwrap_or_else(|e| panic!("{name}: {e:?}"));
            assert_ne!(set, base, "{name} changed nothing");
            let mut back = set;
            if SocialForceParams::NAMES.contains(&name) {
                for (s, b) in back.pedestrians.social_force_sets_mut().into_iter().zip([
                    base.pedestrians.sfm,
                    base.pedestrians.ra_sfm,
                    base.pedestrians.cr_sfm,
                ]) {
                    assert_eq!(*s.get_mut(name).unwrap(), 0.123, "{name}");
                    *s.get_mut(name).unwrap() = *b.clone().get_mut(name).unwrap();
                }
            } else {
                let field = OTHER_PEDESTRIAN_PARAMS
                    .iter()
                    .find(|(n, _)| *n == name)
                    .unwrap()
                    .1;
                assert_eq!(*field(&mut back), 0.123, "{name}");
                *field(&mut back) = *field(&mut base.clone());
            }
            assert_eq!(back, base, "{name} changed another field too");
        }
        let e = apply_pedestrian_params(base, &[("nope".to_string(), 1.0)].into()).unwrap_err();
        assert!(e.message.contains("ped_goal_radius") && e.message.contains("lambda3"));
    }
}
