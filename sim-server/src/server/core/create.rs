//! `CreateEnv`: the request's pool (a served one, or synthetic scenes), its parameter
//! overrides, and the new envs in the registry.

use super::*;

/// The names accepted in `CreateEnv.pedestrian_params` (model.md names) besides the social-force
/// ones (`SocialForceParams::NAMES`, which set that field of every model with social forces),
/// each with the parameter-file field it sets.
const OTHER_PEDESTRIAN_PARAMS: [(&str, &str); 9] = [
    ("gamma1", "risk.gamma1"),
    ("gamma2", "risk.gamma2"),
    ("lambda", "risk.lambda"),
    ("s0", "cognition.s0"),
    ("q", "cognition.q"),
    ("s_o", "cognition.s_o"),
    ("v_ped_max", "ped_speed_max"),
    ("ped_radius", "ped_radius"),
    ("ped_goal_radius", "ped_goal_radius"),
];

/// The names accepted in `CreateEnv.reward_weights` (`protocol::REWARD_WEIGHT_DEFAULTS`), each
/// with the parameter-file field it sets.
const REWARD_WEIGHTS: [(&str, &str); 7] = [
    ("progress", "reward.progress"),
    ("success", "reward.success"),
    ("collision", "reward.collision"),
    ("danger", "reward.danger"),
    ("danger_clearance", "reward.danger_clearance"),
    ("comfort_jerk", "reward.jerk_penalty"),
    ("comfort_omega", "reward.yaw_rate_penalty"),
];

/// The parameter-file fields a `pedestrian_params` name sets, or None for an unknown name.
fn pedestrian_param_fields(name: &str) -> Option<Vec<String>> {
    if SocialForceParams::NAMES.contains(&name) {
        let defaults = WorldParams::default().pedestrians;
        let sets = PedestrianModel::ALL
            .into_iter()
            .filter(|&m| defaults.for_model(m).is_some());
        return Some(
            sets.map(|m| format!("pedestrians.{}.{name}", m.name()))
                .collect(),
        );
    }
    let (_, field) = OTHER_PEDESTRIAN_PARAMS.iter().find(|(n, _)| *n == name)?;
    Some(vec![field.to_string()])
}

/// `base` with a request's `pedestrian_params` and `reward_weights`, set through the parameter
/// file's overlay (`params_file::with_values`), so that they are checked as a file's fields are.
fn apply_overrides(
    base: &WorldParams,
    pedestrian_params: &BTreeMap<String, f64>,
    reward_weights: &BTreeMap<String, f64>,
) -> Result<WorldParams, ErrorReply> {
    let bad = |m: String| ErrorReply::new(ErrorCode::BadRequest, m);
    let mut values = Vec::new();
    for (name, &v) in pedestrian_params {
        let fields = pedestrian_param_fields(name).ok_or_else(|| {
            let known: Vec<&str> = SocialForceParams::NAMES
                .iter()
                .copied()
                .chain(OTHER_PEDESTRIAN_PARAMS.iter().map(|(n, _)| *n))
                .collect();
            bad(format!(
                "unknown pedestrian parameter {name:?}; known: {}",
                known.join(", ")
            ))
        })?;
        values.extend(fields.into_iter().map(|f| (f, v)));
    }
    for (name, &v) in reward_weights {
        let (_, field) = REWARD_WEIGHTS
            .iter()
            .find(|(n, _)| n == name)
            .ok_or_else(|| bad(format!("unknown reward weight {name:?}")))?;
        values.push((field.to_string(), v));
    }
    if values.is_empty() {
        return Ok(*base);
    }
    crate::params_file::with_values(base, &values, "CreateEnv").map_err(|e| match e {
        crate::params_file::ParamsFileError::Parse { message, .. } => {
            bad(format!("pedestrian_params/reward_weights: {message}"))
        }
        crate::params_file::ParamsFileError::Invalid { source, .. } => {
            bad(format!("pedestrian_params/reward_weights: {source}"))
        }
        e => bad(e.to_string()),
    })
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
        let params = apply_overrides(
            self.params.for_model(req.pedestrian_model),
            &req.pedestrian_params,
            &req.reward_weights,
        )?;
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
    fn every_override_name_sets_its_field_and_nothing_else() {
        let base = WorldParams::default();
        let none = BTreeMap::new();
        let pedestrian = SocialForceParams::NAMES
            .iter()
            .copied()
            .chain(OTHER_PEDESTRIAN_PARAMS.iter().map(|(n, _)| *n))
            .map(|n| (n, true));
        let reward = REWARD_WEIGHTS.iter().map(|(n, _)| (*n, false));
        for (name, is_pedestrian) in pedestrian.chain(reward) {
            let one = BTreeMap::from([(name.to_string(), 0.123)]);
            let (p, r) = if is_pedestrian {
                (&one, &none)
            } else {
                (&none, &one)
            };
            let set = apply_overrides(&base, p, r).unwrap_or_else(|e| panic!("{name}: {e:?}"));
            // Every field that changed is one the name stands for, and now holds 0.123.
            let (before, after) = (
                serde_json::to_value(base).unwrap(),
                serde_json::to_value(set).unwrap(),
            );
            let mut changed = changed_leaves(&before, &after, "");
            let mut expected: Vec<String> = if is_pedestrian {
                pedestrian_param_fields(name).unwrap()
            } else {
                let field = REWARD_WEIGHTS.iter().find(|(n, _)| *n == name).unwrap().1;
                vec![field.to_string()]
            };
            changed.sort();
            expected.sort();
            assert_eq!(changed, expected, "{name}");
            for field in &expected {
                let leaf = field.split('.').fold(&after, |v, k| &v[k]);
                assert_eq!(leaf.as_f64(), Some(0.123), "{field}");
            }
        }
        let social = pedestrian_param_fields("tau").unwrap();
        assert_eq!(social.len(), 3, "sfm, ra_sfm and cr_sfm: {social:?}");
        let e = apply_overrides(&base, &[("nope".to_string(), 1.0)].into(), &none).unwrap_err();
        assert!(e.message.contains("ped_goal_radius") && e.message.contains("lambda3"));
        let e = apply_overrides(&base, &none, &[("nope".to_string(), 1.0)].into()).unwrap_err();
        assert!(e.message.contains("unknown reward weight"), "{}", e.message);
        let e = apply_overrides(&base, &[("tau".to_string(), -1.0)].into(), &none).unwrap_err();
        assert!(e.message.contains("tau"), "{}", e.message);
    }

    /// The dotted paths of the leaves that differ between two JSON values.
    fn changed_leaves(a: &serde_json::Value, b: &serde_json::Value, path: &str) -> Vec<String> {
        match (a, b) {
            (serde_json::Value::Object(x), serde_json::Value::Object(y)) => x
                .iter()
                .flat_map(|(k, v)| {
                    let at = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    changed_leaves(v, &y[k], &at)
                })
                .collect(),
            _ if a != b => vec![path.to_string()],
            _ => vec![],
        }
    }
}
