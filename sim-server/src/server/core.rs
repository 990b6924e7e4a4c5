//! The server's pure request handling: env registry, trainers and reaping, limits, and every
//! request from payload bytes to reply bytes. Synchronous and free of zenoh, so it is unit-tested
//! directly; the network layer (`net.rs`) only moves bytes and publications.
//!
//! Locking: the registry mutex is never held while an env mutex is being acquired by a request
//! that already holds another env (batches lock their envs in id order), and no env lock is held
//! while taking the registry lock, so there is no lock-order cycle.

use rustc_hash::FxBuildHasher;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use protocol::keys::{make_env_id, validate_env_id};
use protocol::wire::{decode_batch_step, write_batch_step_ok, BatchColumns, BatchEnvRef};
use protocol::{
    decode, decode_or_default, encode, ActionMsg, ActionSpace, BatchStep, BatchStepResult, Close,
    Closed, CreateEnv, EnvCreated, ErrorCode, ErrorReply, InfoRequest, KeySpace, Mode, ObsLayout,
    OpenEnv, Reply, Reset, ServerInfo, Split as WireSplit, Step, SyntheticScenes, PROTOCOL_VERSION,
};
use serde::Serialize;
use sim_core::params::{PedestrianModel, SocialForceParams, WorldParams};

use crate::params_file::ModelParams;
use sim_core::scenario::Split;
use sim_core::world::StepScratch;

use super::env::{BufMut, Buffers, Env, EnvSpec, Gates, Publication, Watch};
use super::fair::FairTurns;
use super::pools::ServedPool;
use sim_core::helpers::Helpers;

/// Batches of at least this many envs may be stepped on several threads (see
/// [`ServerCore::set_batch_threads`]).
pub const PARALLEL_MIN_BATCH: usize = 64;

/// Server limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Maximum simultaneously open envs.
    pub capacity: u32,
    /// Maximum simultaneously open envs of one trainer (client id). Default: `capacity`.
    pub max_envs_per_trainer: u32,
    /// Maximum `CreateEnv.count` and `BatchStep` K.
    pub max_batch: u32,
    /// Maximum `CreateEnv.max_agents`.
    pub max_agents: u32,
    /// Largest request payload, bytes: a larger one is refused before it is decoded.
    /// Default 1 MiB (a `BatchStep` of 1 024 envs is about 10 kB).
    pub max_request_bytes: usize,
    /// How long envs of a client without liveliness token survive.
    pub trainer_grace: Duration,
    /// How long envs of a trainer whose liveliness token disappeared survive, waiting for it
    /// to reconnect (its token reappearing keeps them). Zero (default): reaped at once.
    pub reconnect_grace: Duration,
    /// Most batches stepped at once; more wait for a fair turn ([`FairTurns`]).
    /// 0 (default): one per batch thread.
    pub batch_slots: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            capacity: 4096,
            max_envs_per_trainer: 4096,
            max_batch: 1024,
            max_agents: 64,
            max_request_bytes: 1 << 20,
            trainer_grace: Duration::from_secs(10),
            reconnect_grace: Duration::ZERO,
            batch_slots: 0,
        }
    }
}

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

/// Encodes a reply envelope.
pub fn reply_bytes<T: Serialize>(r: Result<T, ErrorReply>) -> Vec<u8> {
    encode(&Reply::from(r))
}

fn bad(e: impl std::fmt::Display) -> ErrorReply {
    ErrorReply::new(ErrorCode::BadRequest, e.to_string())
}

/// What a handler produced: the reply payload and the publications to send before it.
#[derive(Debug, Default)]
pub struct Response {
    pub reply: Vec<u8>,
    pub pubs: Vec<Publication>,
    /// Realtime envs created by this request (the network layer starts their clocks).
    pub realtime_envs: Vec<(String, Duration)>,
}

impl Response {
    fn of<T: Serialize>(r: Result<T, ErrorReply>, pubs: Vec<Publication>) -> Self {
        Self {
            reply: reply_bytes(r),
            pubs,
            realtime_envs: Vec::new(),
        }
    }

    /// An error reply and nothing else.
    pub fn error(e: ErrorReply) -> Self {
        Self::of(Err::<(), _>(e), Vec::new())
    }
}

#[derive(Debug, Default)]
struct Client {
    alive: bool,
    envs: BTreeSet<String>,
    /// Without a live token, the envs are reaped at this instant.
    deadline: Option<Instant>,
}

#[derive(Debug, Default)]
struct Registry {
    // FxHash: the registry is looked up once per env of every batch, and SipHash of the ids showed
    // in profiles. The keys are ids this server issued, so clients cannot choose colliding keys.
    envs: HashMap<String, Arc<Mutex<Env>>, FxBuildHasher>,
    /// Client id of every open env.
    owner: HashMap<String, String>,
    counter: u64,
    clients: HashMap<String, Client>,
}

/// The server state and request handlers.
#[derive(Debug)]
pub struct ServerCore {
    server_id: String,
    keys: KeySpace,
    limits: Limits,
    pools: Vec<Arc<ServedPool>>,
    params: ModelParams,
    reg: Mutex<Registry>,
    /// Most threads a large batch is stepped on.
    batch_threads: usize,
    /// `batch_threads - 1` threads that step a large batch's chunks beside the request's own.
    helpers: Helpers,
    /// Turns of the batches: at most `batch_slots` step at once, the rest wait in fair order.
    turns: FairTurns,
    /// Step buffers of finished batches, for reuse (a K=256 batch's are ~200 KB).
    scratch: Mutex<Vec<Buffers>>,
    /// The worlds' step scratch of finished batches, one per batch thread: every world a
    /// thread steps works in the same warm buffers instead of its own (sim-core `StepScratch`).
    steppers: Mutex<Vec<StepScratch>>,
}

/// Most step buffers kept for reuse between batches (as many as batches ever ran at once; a
/// few is plenty).
const MAX_POOLED_BUFFERS: usize = 8;

/// `ServerInfo::allocator`: glibc malloc's own figures (`mallinfo2`, summed over its arenas):
/// bytes in use by live allocations, free bytes it keeps in its arenas, and bytes in mmapped
/// chunks. What RSS holds beyond `in_use` is the allocator's retention, not live data.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn allocator_figures() -> BTreeMap<String, u64> {
    // SAFETY: mallinfo2 only reads the allocator's statistics (it takes each arena's lock);
    // glibc >= 2.33 has it, and Debian 12 ships 2.36.
    let m = unsafe { libc::mallinfo2() };
    [
        ("in_use", m.uordblks + m.hblkhd),
        ("free_retained", m.fordblks),
        ("mmapped", m.hblkhd),
        ("arena", m.arena),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v as u64))
    .collect()
}

/// `ServerInfo::allocator` where the allocator reports nothing: empty.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn allocator_figures() -> BTreeMap<String, u64> {
    BTreeMap::new()
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

/// One thread per available core. A lockstep trainer's request has fully arrived before its
/// batch is stepped and its reply is not sent until the batch is done, so the network threads
/// are idle meanwhile: on two cores, two batch threads took a K = 256 batch from 1.10–1.35 ms
/// to 0.72–0.81 ms in `core_batch` (measured in docs/BENCHMARKS.md section 2, in its git history).
pub fn default_batch_threads() -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .max(1)
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a lock cannot leave an env half-stepped in a way later requests
    // could observe inconsistently more than the panic itself; keep serving.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl ServerCore {
    /// A server with `pools` (the first is the default) and base world parameters.
    pub fn new(
        server_id: String,
        keys: KeySpace,
        limits: Limits,
        pools: Vec<ServedPool>,
        params: impl Into<ModelParams>,
    ) -> Self {
        let mut core = Self {
            server_id,
            keys,
            limits,
            pools: pools.into_iter().map(Arc::new).collect(),
            params: params.into(),
            reg: Mutex::new(Registry::default()),
            batch_threads: 1,
            helpers: Helpers::new(0, "batch"),
            turns: FairTurns::new(1),
            scratch: Mutex::new(Vec::new()),
            steppers: Mutex::new(Vec::new()),
        };
        core.set_batch_threads(default_batch_threads());
        core
    }

    /// Sets the most threads a batch of at least [`PARALLEL_MIN_BATCH`] envs is stepped on
    /// (default: [`default_batch_threads`]).
    pub fn set_batch_threads(&mut self, threads: usize) {
        self.batch_threads = threads.max(1);
        self.helpers = Helpers::new(self.batch_threads - 1, "batch");
        self.turns = FairTurns::new(match self.limits.batch_slots {
            0 => self.batch_threads,
            n => n as usize,
        });
        if self.helpers.len() < self.batch_threads - 1 {
            tracing::warn!(
                wanted = self.batch_threads - 1,
                started = self.helpers.len(),
                "not every batch helper thread started; the rest of a batch runs on its own thread"
            );
        }
    }

    pub fn server_id(&self) -> &str {
        &self.server_id
    }

    /// The served pool `name`, or the default pool (the first) for None.
    fn pool_named(&self, name: Option<&str>) -> Option<Arc<ServedPool>> {
        match name {
            None => self.pools.first().cloned(),
            Some(name) => self.pools.iter().find(|p| p.name == name).cloned(),
        }
    }

    /// The most agents any scenario of the served pools has (an upper bound on a world's size).
    pub fn max_scene_agents(&self) -> usize {
        self.pools
            .iter()
            .flat_map(|p| p.scenarios.iter())
            .map(|s| s.scenario.agents.len())
            .max()
            .unwrap_or(0)
    }

    pub fn keys(&self) -> &KeySpace {
        &self.keys
    }

    pub fn limits(&self) -> Limits {
        self.limits
    }

    /// Number of open envs.
    pub fn load(&self) -> usize {
        lock(&self.reg).envs.len()
    }

    /// Ids of the open envs (sorted).
    pub fn open_envs(&self) -> Vec<String> {
        let mut v: Vec<String> = lock(&self.reg).envs.keys().cloned().collect();
        v.sort();
        v
    }

    pub fn info(&self) -> ServerInfo {
        ServerInfo {
            protocol_version: PROTOCOL_VERSION,
            server_id: self.server_id.clone(),
            version: env!("CARGO_PKG_VERSION").to_string(),
            capacity: self.limits.capacity,
            load: self.load() as u32,
            max_batch: self.limits.max_batch,
            max_agents: self.limits.max_agents,
            dt: self.params.base().dt,
            pedestrian_models: PedestrianModel::ALL.to_vec(),
            pools: self.pools.iter().map(|p| p.summary()).collect(),
            envs: self.open_env_owners(),
            tables: self.tables(),
            allocator: allocator_figures(),
        }
    }

    /// `ServerInfo::tables`: the entries of each of the core's tables. Every one of them is back
    /// to its idle size once the trainers are gone (the pools of step buffers are bounded, not
    /// emptied: at most `MAX_POOLED_BUFFERS` and `4 * batch_threads`).
    pub fn tables(&self) -> BTreeMap<String, u64> {
        let reg = lock(&self.reg);
        let sizes = [
            ("envs", reg.envs.len()),
            ("env_owners", reg.owner.len()),
            ("trainers", reg.clients.len()),
            (
                "trainer_envs",
                reg.clients.values().map(|c| c.envs.len()).sum(),
            ),
            ("fair_trainers", self.turns.trainers()),
            ("fair_waiting", self.turns.waiting()),
            ("pooled_step_buffers", lock(&self.scratch).len()),
            ("pooled_step_scratch", lock(&self.steppers).len()),
        ];
        sizes
            .into_iter()
            .map(|(name, n)| (name.to_string(), n as u64))
            .collect()
    }

    /// `ServerInfo::envs`: the open envs in creation order (ids end in the server's counter).
    fn open_env_owners(&self) -> Vec<OpenEnv> {
        let reg = lock(&self.reg);
        let mut envs: Vec<OpenEnv> = reg
            .owner
            .iter()
            .map(|(env_id, client_id)| OpenEnv {
                env_id: env_id.clone(),
                client_id: client_id.clone(),
            })
            .collect();
        let counter = |id: &str| {
            id.rsplit('-')
                .next()
                .and_then(|n| n.parse::<u64>().ok())
                .unwrap_or(u64::MAX)
        };
        envs.sort_by(|a, b| (counter(&a.env_id), &a.env_id).cmp(&(counter(&b.env_id), &b.env_id)));
        envs
    }

    /// The refusal of a request payload of `len` bytes above `max_request_bytes`, decided
    /// before the payload is copied or decoded; `None` when it may be handled.
    pub fn refuse_oversized(&self, len: usize) -> Option<Response> {
        let max = self.limits.max_request_bytes;
        (len > max).then(|| {
            Response::error(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!("request of {len} bytes exceeds max_request_bytes {max}: not decoded"),
            ))
        })
    }

    /// `InfoRequest` → `Reply<ServerInfo>`; `net_tables`: the network layer's tables, reported
    /// beside the core's.
    pub fn handle_info(&self, payload: &[u8], net_tables: &[(&str, usize)]) -> Response {
        let r = decode_or_default::<InfoRequest>(payload)
            .map_err(bad)
            .map(|_| {
                let mut info = self.info();
                for (name, n) in net_tables {
                    info.tables.insert(name.to_string(), *n as u64);
                }
                info
            });
        Response::of(r, Vec::new())
    }

    fn lookup(&self, env_id: &str) -> Result<Arc<Mutex<Env>>, ErrorReply> {
        let reg = lock(&self.reg);
        if let Some(e) = reg.envs.get(env_id) {
            return Ok(e.clone());
        }
        let issued = env_id
            .strip_prefix(self.server_id.as_str())
            .and_then(|r| r.strip_prefix('-'))
            .filter(|n| {
                n.bytes().all(|b| b.is_ascii_digit()) && (n.len() == 1 || !n.starts_with('0'))
            })
            .and_then(|n| n.parse::<u64>().ok())
            .is_some_and(|n| n < reg.counter);
        Err(if issued {
            ErrorReply::new(ErrorCode::EnvClosed, format!("env {env_id} is closed"))
        } else {
            ErrorReply::new(
                ErrorCode::UnknownEnv,
                format!(
                    "env {env_id:?} was never issued by server {}",
                    self.server_id
                ),
            )
        }
        .with_env(env_id.to_string()))
    }

    /// [`ServerCore::lookup`] of every id under one lock of the registry.
    fn lookup_all(&self, env_ids: &[String]) -> Result<Vec<Arc<Mutex<Env>>>, ErrorReply> {
        {
            let reg = lock(&self.reg);
            let found: Option<Vec<_>> =
                env_ids.iter().map(|id| reg.envs.get(id).cloned()).collect();
            if let Some(found) = found {
                return Ok(found);
            }
        }
        // Some id is unknown or closed: the first such gets its error as from a single lookup.
        env_ids.iter().map(|id| self.lookup(id)).collect()
    }

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

    /// `Reset` on `env_id`.
    pub fn handle_reset(&self, env_id: &str, payload: &[u8], gates: Gates) -> Response {
        let mut pubs = Vec::new();
        let r = (|| {
            let req: Reset = decode_or_default(payload).map_err(bad)?;
            let env = self.lookup(env_id)?;
            let mut env = lock(&env);
            if env.closed {
                return Err(ErrorReply::new(ErrorCode::EnvClosed, "env is closed")
                    .with_env(env_id.to_string()));
            }
            env.reset(&req, gates, &mut pubs)
        })();
        Response::of(r, pubs)
    }

    /// `Step` on `env_id`.
    pub fn handle_step(&self, env_id: &str, payload: &[u8], gates: Gates) -> Response {
        let mut pubs = Vec::new();
        let r = (|| {
            let req: Step = decode(payload).map_err(bad)?;
            let env = self.lookup(env_id)?;
            let mut env = lock(&env);
            env.check_steppable(true)?;
            let actions = req
                .checked_actions(env.spec.n_ext() as u32)
                .map_err(|e| e.with_env(env_id.to_string()))?;
            // A pooled scratch: an autoreset world starts every episode with an empty one.
            let mut scratch = self.take_stepper();
            let r = env.step_single(&actions, gates, &mut pubs, Some(&mut scratch));
            self.return_steppers(std::iter::once(scratch));
            r
        })();
        Response::of(r, pubs)
    }

    /// `Close` on `env_id`.
    pub fn handle_close(&self, env_id: &str, payload: &[u8]) -> Response {
        let r = (|| {
            decode_or_default::<Close>(payload).map_err(bad)?;
            // Lookup first so that unknown/closed envs get their codes.
            self.lookup(env_id)?;
            let closed = self.close_envs(&[env_id.to_string()]);
            if closed.is_empty() {
                // Closed concurrently.
                return Err(ErrorReply::new(ErrorCode::EnvClosed, "env is closed")
                    .with_env(env_id.to_string()));
            }
            Ok(Closed { env_ids: closed })
        })();
        Response::of(r, Vec::new())
    }

    /// Removes the given envs; returns those that were open.
    fn close_envs(&self, ids: &[String]) -> Vec<String> {
        let mut removed = Vec::new();
        let mut gone_clients = Vec::new();
        {
            let mut reg = lock(&self.reg);
            for id in ids {
                if let Some(env) = reg.envs.remove(id) {
                    removed.push((id.clone(), env));
                }
            }
            for (id, _) in &removed {
                let Some(client) = reg.owner.remove(id) else {
                    continue;
                };
                if let Some(c) = reg.clients.get_mut(&client) {
                    c.envs.remove(id);
                    if c.envs.is_empty() && !c.alive {
                        reg.clients.remove(&client);
                        gone_clients.push(client);
                    }
                }
            }
        }
        // A client without a token that closed its last env is gone: its fair-queue tag too
        // (it grew by one entry per such client before, for the server's lifetime).
        for client in &gone_clients {
            self.turns.forget(client);
        }
        for (_, env) in &removed {
            lock(env).closed = true;
        }
        removed.into_iter().map(|(id, _)| id).collect()
    }

    /// `BatchStep`.
    pub fn handle_batch(&self, payload: &[u8], watch: &dyn Watch) -> Response {
        let mut pubs = Vec::new();
        let reply = self
            .batch(payload, watch, &mut pubs)
            .unwrap_or_else(|e| reply_bytes::<BatchStepResult>(Err(e)));
        Response {
            reply,
            pubs,
            realtime_envs: Vec::new(),
        }
    }

    /// Steps a batch and writes its `Reply::Ok(BatchStepResult)` straight from the step
    /// buffers (see [`protocol::wire`]): no owned arrays or per-env infos are built, which
    /// halved the allocations and copies of a large batch.
    fn batch(
        &self,
        payload: &[u8],
        watch: &dyn Watch,
        pubs: &mut Vec<Publication>,
    ) -> Result<Vec<u8>, ErrorReply> {
        let req: BatchStep = decode_batch_step(payload).map_err(bad)?;
        let k = req.env_ids.len();
        if k == 0 {
            return Err(bad("env_ids is empty"));
        }
        if k > self.limits.max_batch as usize {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "batch of {k} envs exceeds max_batch {}",
                    self.limits.max_batch
                ),
            ));
        }
        // Duplicates first (they would otherwise deadlock the locking below).
        let mut order: Vec<usize> = (0..k).collect();
        order.sort_by(|&a, &b| req.env_ids[a].cmp(&req.env_ids[b]));
        for w in order.windows(2) {
            if req.env_ids[w[0]] == req.env_ids[w[1]] {
                let id = &req.env_ids[w[0]];
                return Err(
                    bad(format!("env id {id:?} listed twice in batch")).with_env(id.clone())
                );
            }
        }
        let handles = self.lookup_all(&req.env_ids)?;
        // A fair turn among the trainers' batches (module `fair`), charged to the trainer that
        // created the first env; held until the reply is written. Taken before any env is
        // locked, so that waiting never holds an env.
        let trainer = lock(&handles[0]).spec.client_id.clone();
        let _turn = self.turns.acquire(&trainer, k as u64);
        // Lock in id order.
        let mut guards: Vec<Option<MutexGuard<'_, Env>>> = (0..k).map(|_| None).collect();
        for &i in &order {
            guards[i] = Some(lock(&handles[i]));
        }
        let mut envs: Vec<MutexGuard<'_, Env>> =
            guards.into_iter().map(|g| g.expect("locked")).collect();
        let (n_ext, m) = (envs[0].spec.n_ext(), envs[0].spec.max_agents);
        for env in &envs {
            if env.closed {
                return Err(
                    ErrorReply::new(ErrorCode::EnvClosed, "env is closed").with_env(env.id.clone())
                );
            }
            if env.spec.mode != Mode::Lockstep {
                return Err(ErrorReply::new(
                    ErrorCode::WrongMode,
                    "env is in realtime mode; batch step needs lockstep envs",
                )
                .with_env(env.id.clone()));
            }
            if env.spec.n_ext() != n_ext || env.spec.max_agents != m {
                return Err(ErrorReply::new(
                    ErrorCode::WrongShape,
                    format!(
                        "batch mixes envs: {} has n_ext {} and max_agents {}, {} has {} and {}",
                        envs[0].id,
                        n_ext,
                        m,
                        env.id,
                        env.spec.n_ext(),
                        env.spec.max_agents
                    ),
                )
                .with_env(env.id.clone()));
            }
        }
        let actions = req.checked_action_rows(n_ext as u32)?;
        for env in &envs {
            env.check_steppable(true)?;
        }
        // Large batches are stepped on several threads (consecutive chunks of envs, each
        // writing its own range of the one output buffer), the first chunk on this thread.
        let threads = if k >= PARALLEL_MIN_BATCH {
            self.batch_threads.min(k / (PARALLEL_MIN_BATCH / 2)).max(1)
        } else {
            1
        };
        let chunk = k.div_ceil(threads);
        let mut buf = self.take_buffers(k, n_ext, m as usize);
        let mut refs: Vec<&mut Env> = envs.iter_mut().map(|g| &mut **g).collect();
        // Per chunk: its envs' columns of the reply, and its publications.
        type Part = (BatchColumns, Vec<Publication>, Result<(), ErrorReply>);
        let mut steppers = self.take_steppers(threads);
        let run = |base: usize,
                   envs: &mut [&mut Env],
                   actions: &[[f64; 2]],
                   mut out: BufMut<'_>,
                   scratch: &mut StepScratch|
         -> Part {
            let mut cols = BatchColumns::with_capacity(base as u32, envs.len(), n_ext);
            let mut pubs = Vec::new();
            for (i, env) in envs.iter_mut().enumerate() {
                let rows = &actions[i * n_ext..(i + 1) * n_ext];
                let slots = &mut out.slots(i);
                let gates = watch.gates(&env.id);
                let meta = match env.step_into(rows, slots, gates, &mut pubs, Some(scratch)) {
                    Ok(meta) => meta,
                    Err(e) => return (cols, pubs, Err(e)),
                };
                cols.push_env(&BatchEnvRef {
                    episode: meta.episode,
                    scenario: env.scenario_name(meta.scenario),
                    step: meta.step,
                    t: meta.t,
                    action_clipped: env.action_clipped(),
                    events: &meta.events,
                    metrics: &meta.metrics,
                });
                if meta.reset {
                    env.push_reset_columns(&mut cols);
                }
            }
            (cols, pubs, Ok(()))
        };
        let parts: Vec<Part> = if threads <= 1 {
            vec![run(0, &mut refs, &actions, buf.view(), &mut steppers[0])]
        } else {
            // The first chunk on this thread, the others on the helper threads, each into its
            // own slot (in chunk order).
            let mut slots: Vec<Option<Part>> = (0..threads).map(|_| None).collect();
            let actions = &actions[..];
            let mut work = refs
                .chunks_mut(chunk)
                .zip((0..k).step_by(chunk))
                .zip(buf.view().chunks(k, chunk))
                .zip(steppers.iter_mut())
                .zip(slots.iter_mut());
            let ((((e0, b0), o0), s0), p0) = work.next().expect("k >= 1");
            let jobs: Vec<Box<dyn FnOnce() + Send + '_>> = work
                .map(|((((e, b), o), s), p)| {
                    Box::new(move || *p = Some(run(b, e, &actions[b * n_ext..], o, s)))
                        as Box<dyn FnOnce() + Send + '_>
                })
                .collect();
            self.helpers.run(jobs, || {
                *p0 = Some(run(b0, e0, &actions[b0 * n_ext..], o0, s0));
            });
            slots
                .into_iter()
                .map(|p| {
                    p.unwrap_or_else(|| {
                        (
                            BatchColumns::default(),
                            Vec::new(),
                            Err(ErrorReply::new(
                                ErrorCode::Internal,
                                "batch worker panicked",
                            )),
                        )
                    })
                })
                .collect()
        };
        drop(refs);
        drop(envs);
        self.return_steppers(steppers);
        let mut cols = BatchColumns::default();
        for (i, (part, p, r)) in parts.into_iter().enumerate() {
            r?;
            if i == 0 {
                cols = part;
            } else {
                cols.append(&part);
            }
            pubs.extend(p);
        }
        let arrays = buf.arrays();
        let mut reply = Vec::with_capacity(
            arrays.data_bytes()
                + 8 * k
                + req.env_ids.iter().map(String::len).sum::<usize>()
                + cols.encoded_bytes(),
        );
        let written = write_batch_step_ok(&mut reply, &req.env_ids, &arrays, &cols);
        self.return_buffers(buf);
        written.map_err(Buffers::err)?;
        Ok(reply)
    }

    /// Step buffers for a batch, reusing those of an earlier batch when there are any.
    fn take_buffers(&self, k: usize, n_ext: usize, m: usize) -> Buffers {
        let mut buf = lock(&self.scratch).pop().unwrap_or_default();
        buf.resize(k, n_ext, m);
        buf
    }

    /// A step scratch of an earlier request, or a new one.
    fn take_stepper(&self) -> StepScratch {
        lock(&self.steppers).pop().unwrap_or_default()
    }

    /// `n` step scratches for a batch's threads.
    fn take_steppers(&self, n: usize) -> Vec<StepScratch> {
        let mut pool = lock(&self.steppers);
        (0..n).map(|_| pool.pop().unwrap_or_default()).collect()
    }

    fn return_steppers(&self, steppers: impl IntoIterator<Item = StepScratch>) {
        let mut pool = lock(&self.steppers);
        // Enough for a few batches at once on every thread.
        let room = (4 * self.batch_threads).saturating_sub(pool.len());
        pool.extend(steppers.into_iter().take(room));
    }

    fn return_buffers(&self, buf: Buffers) {
        let mut pool = lock(&self.scratch);
        // As many as batches ever ran at once; a few is plenty.
        if pool.len() < MAX_POOLED_BUFFERS {
            pool.push(buf);
        }
    }

    /// Realtime action published on `{p}/env/{env_id}/action/{agent}`. Errors are for logging.
    pub fn handle_action(&self, env_id: &str, agent: &str, payload: &[u8]) -> Result<bool, String> {
        let msg: ActionMsg = decode(payload).map_err(|e| e.to_string())?;
        let action = msg.checked_action().map_err(|e| e.to_string())?;
        let env = self.lookup(env_id).map_err(|e| e.to_string())?;
        let mut env = lock(&env);
        if env.spec.mode != Mode::Realtime {
            return Err(format!("env {env_id} is not a realtime env"));
        }
        env.hold_action(agent, action, msg.seq)
    }

    /// One realtime tick of `env_id`: `None` once the env is gone (stop its clock), else the
    /// publications to send.
    pub fn realtime_tick(&self, env_id: &str, gates: Gates) -> Option<Vec<Publication>> {
        let env = self.lookup(env_id).ok()?;
        let mut env = lock(&env);
        if env.closed {
            return None;
        }
        let mut pubs = Vec::new();
        if let Some(Err(e)) = env.realtime_tick(gates, &mut pubs) {
            tracing::warn!(env = env_id, error = %e, "realtime step failed");
        }
        Some(pubs)
    }

    /// The liveliness token of `client_id` is present.
    pub fn trainer_alive(&self, client_id: &str) {
        let mut reg = lock(&self.reg);
        let c = reg.clients.entry(client_id.to_string()).or_default();
        c.alive = true;
        c.deadline = None;
    }

    /// The liveliness token of `client_id` disappeared at `now` (closed session, or a link
    /// silent for zenoh's lease): its envs are reaped at once without a `reconnect_grace`,
    /// else when it ends, unless the token reappears first ([`Self::trainer_alive`]).
    /// Returns the envs reaped now.
    pub fn trainer_lost(&self, client_id: &str, now: Instant) -> Vec<String> {
        let grace = self.limits.reconnect_grace;
        if grace.is_zero() {
            return self.trainer_gone(client_id);
        }
        let mut reg = lock(&self.reg);
        if let Some(c) = reg.clients.get_mut(client_id) {
            c.alive = false;
            c.deadline = Some(now + grace);
        }
        Vec::new()
    }

    /// The envs of `client_id` are reaped now. Returns them.
    pub fn trainer_gone(&self, client_id: &str) -> Vec<String> {
        let ids: Vec<String> = {
            let mut reg = lock(&self.reg);
            match reg.clients.remove(client_id) {
                Some(c) => c.envs.into_iter().collect(),
                None => Vec::new(),
            }
        };
        self.turns.forget(client_id);
        self.close_envs(&ids)
    }

    /// Reaps the envs of clients whose grace period ran out without a token. Returns them.
    pub fn sweep(&self, now: Instant) -> Vec<String> {
        let expired: Vec<String> = {
            let reg = lock(&self.reg);
            reg.clients
                .iter()
                .filter(|(_, c)| !c.alive && c.deadline.is_some_and(|d| d <= now))
                .map(|(id, _)| id.clone())
                .collect()
        };
        let mut reaped = Vec::new();
        for c in expired {
            reaped.extend(self.trainer_gone(&c));
        }
        reaped
    }

    /// Closes everything (shutdown).
    pub fn close_all(&self) -> Vec<String> {
        let ids = self.open_envs();
        self.close_envs(&ids)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{decode, F64Array, Reply, ResetResult, StepResult};

    fn core(limits: Limits) -> ServerCore {
        ServerCore::new(
            "s".into(),
            KeySpace::default(),
            limits,
            vec![ServedPool::new(scenarios::embedded::default_pool())],
            WorldParams::default(),
        )
    }

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

    fn err_of(bytes: &[u8]) -> ErrorReply {
        match decode::<Reply<serde::de::IgnoredAny>>(bytes).unwrap() {
            Reply::Err(e) => e,
            Reply::Ok(_) => panic!("expected an error reply"),
        }
    }

    fn create(c: &ServerCore, req: &CreateEnv) -> EnvCreated {
        let r = c.handle_create(&encode(req), Instant::now());
        decode::<Reply<EnvCreated>>(&r.reply)
            .unwrap()
            .into_result()
            .unwrap()
    }

    #[test]
    fn lifecycle_and_errors_without_zenoh() {
        let c = core(Limits::default());
        let mut req = CreateEnv::new("t");
        req.count = 2;
        let created = create(&c, &req);
        assert_eq!(created.env_ids, vec!["s-0", "s-1"]);
        let id = &created.env_ids[0];
        let step = encode(&Step::from_rows(&[[0.5, 0.0]]));
        assert_eq!(
            err_of(&c.handle_step(id, &step, Gates::NONE).reply).code,
            ErrorCode::NeedsReset
        );
        let r = c.handle_reset(id, &[], Gates::NONE);
        assert!(r.pubs.is_empty());
        let reset: ResetResult = decode::<Reply<ResetResult>>(&r.reply)
            .unwrap()
            .into_result()
            .unwrap();
        assert_eq!(reset.episode, 1);
        assert_eq!(
            reset.obs.node_ids.get(&[0, 0]),
            Some(reset.agents.iter().find(|a| a.external).unwrap().id)
        );
        // NaN leaves the env untouched.
        let nan = encode(&Step {
            actions: F64Array::new(vec![1, 2], &[f64::NAN, 0.0]).unwrap().into(),
        });
        let e = err_of(&c.handle_step(id, &nan, Gates::NONE).reply);
        assert_eq!(e.code, ErrorCode::NonFiniteAction);
        assert_eq!(e.env_id.as_deref(), Some(id.as_str()));
        let r = c.handle_step(id, &step, Gates::ALL);
        let s: StepResult = decode::<Reply<StepResult>>(&r.reply)
            .unwrap()
            .into_result()
            .unwrap();
        assert_eq!(s.step, 1);
        // With every gate open the three state topics are published.
        let topics: Vec<_> = r.pubs.iter().map(|p| p.topic).collect();
        assert!(topics.contains(&protocol::EnvTopic::States));
        assert!(topics.contains(&protocol::EnvTopic::RiskGraph));
        assert!(topics.contains(&protocol::EnvTopic::Uncertainty));
        // Codes for unknown / closed envs.
        assert_eq!(
            err_of(&c.handle_step("s-9", &step, Gates::NONE).reply).code,
            ErrorCode::UnknownEnv
        );
        assert_eq!(
            err_of(&c.handle_step("other-0", &step, Gates::NONE).reply).code,
            ErrorCode::UnknownEnv
        );
        assert!(decode::<Reply<Closed>>(&c.handle_close(id, &[]).reply)
            .unwrap()
            .into_result()
            .is_ok());
        assert_eq!(
            err_of(&c.handle_close(id, &[]).reply).code,
            ErrorCode::EnvClosed
        );
        assert_eq!(c.load(), 1);
    }

    #[test]
    fn reaping_by_token_and_grace() {
        let c = core(Limits {
            trainer_grace: Duration::from_secs(10),
            ..Limits::default()
        });
        let t0 = Instant::now();
        c.trainer_alive("a");
        create(&c, &CreateEnv::new("a"));
        create(&c, &CreateEnv::new("b"));
        assert_eq!(c.load(), 2);
        assert!(c.sweep(t0 + Duration::from_secs(5)).is_empty());
        assert_eq!(
            c.sweep(t0 + Duration::from_secs(11)),
            vec!["s-1".to_string()]
        );
        assert_eq!(c.trainer_gone("a"), vec!["s-0".to_string()]);
        assert_eq!(c.load(), 0);
    }

    #[test]
    fn limits() {
        let c = core(Limits {
            capacity: 3,
            max_batch: 2,
            max_agents: 8,
            ..Limits::default()
        });
        let mut req = CreateEnv::new("a");
        req.count = 3;
        let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
        assert_eq!(e.code, ErrorCode::LimitExceeded);
        req.count = 2;
        create(&c, &req);
        let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
        assert_eq!(e.code, ErrorCode::LimitExceeded, "{e}");
        assert!(e.message.contains("capacity"), "{e}");
        req.count = 1;
        req.max_agents = 9;
        let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
        assert_eq!(e.code, ErrorCode::LimitExceeded);
    }

    #[test]
    fn a_lost_trainer_that_reconnects_within_the_grace_keeps_its_envs() {
        let c = core(Limits {
            reconnect_grace: Duration::from_secs(5),
            ..Limits::default()
        });
        let t0 = Instant::now();
        c.trainer_alive("a");
        c.trainer_alive("b");
        create(&c, &CreateEnv::new("a"));
        create(&c, &CreateEnv::new("b"));
        assert!(c.trainer_lost("a", t0).is_empty());
        assert!(c.trainer_lost("b", t0).is_empty());
        c.trainer_alive("a"); // a's token is back within the grace
        assert!(c.sweep(t0 + Duration::from_secs(4)).is_empty());
        assert_eq!(
            c.sweep(t0 + Duration::from_secs(6)),
            vec!["s-1".to_string()]
        );
        assert_eq!(c.load(), 1);
        // without a reconnect grace a lost trainer is reaped at once
        let now = core(Limits::default());
        create(&now, &CreateEnv::new("a"));
        assert_eq!(now.trainer_lost("a", t0), vec!["s-0".to_string()]);
    }

    #[test]
    fn a_trainer_at_its_quota_leaves_room_for_another() {
        let c = core(Limits {
            capacity: 8,
            max_envs_per_trainer: 3,
            ..Limits::default()
        });
        let mut req = CreateEnv::new("greedy");
        req.count = 3;
        create(&c, &req);
        req.count = 1;
        let e = err_of(&c.handle_create(&encode(&req), Instant::now()).reply);
        assert_eq!(e.code, ErrorCode::LimitExceeded);
        assert!(e.message.contains("max_envs_per_trainer"), "{e}");
        assert!(e.message.contains("greedy"), "{e}");
        let mut other = CreateEnv::new("modest");
        other.count = 2;
        let created = create(&c, &other);
        let id = &created.env_ids[0];
        assert!(c.handle_reset(id, &[], Gates::NONE).reply.len() > 16);
        let step = encode(&Step::from_rows(&[[0.5, 0.0]]));
        let r = c.handle_step(id, &step, Gates::NONE);
        assert!(decode::<Reply<StepResult>>(&r.reply)
            .unwrap()
            .into_result()
            .is_ok());
        // closing frees the quota
        decode::<Reply<Closed>>(&c.handle_close(&created.env_ids[1], &[]).reply)
            .unwrap()
            .into_result()
            .unwrap();
        assert_eq!(c.load(), 4);
    }

    #[test]
    fn synthetic_scenes_with_two_controlled_vehicles_are_created_and_stepped() {
        let c = core(Limits::default());
        let mut req = CreateEnv::new("syn");
        req.external_agents = vec!["vehicle_0".into(), "vehicle_1".into()];
        req.max_agents = 16;
        req.synthetic = Some(SyntheticScenes {
            layout: "counter_flow".into(),
            pedestrians: 60,
            vehicles: 2,
            seed: 7,
            scenes: 3,
            ..SyntheticScenes::default()
        });
        let created = create(&c, &req);
        let id = &created.env_ids[0];
        let reset: ResetResult =
            decode::<Reply<ResetResult>>(&c.handle_reset(id, &[], Gates::NONE).reply)
                .unwrap()
                .into_result()
                .unwrap();
        assert!(reset
            .scenario
            .starts_with("synthetic-counter_flow-n60-v2-seed"));
        assert_eq!(reset.agents.len(), 62);
        let step = encode(&Step::from_rows(&[[0.5, 0.0], [0.0, 0.1]]));
        let r: StepResult =
            decode::<Reply<StepResult>>(&c.handle_step(id, &step, Gates::NONE).reply)
                .unwrap()
                .into_result()
                .unwrap();
        assert_eq!(r.reward.len(), 2);
        // Refused with a message that names the problem, and nothing is created.
        let load = c.load();
        for (change, needle) in [
            (
                Box::new(|r: &mut CreateEnv| r.pool = Some("hbs-paper".into()))
                    as Box<dyn Fn(&mut CreateEnv)>,
                "exclude each other",
            ),
            (
                Box::new(|r: &mut CreateEnv| {
                    r.synthetic.as_mut().unwrap().layout = "spiral".into()
                }),
                "synthetic.layout",
            ),
            (
                Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().pedestrians = 5_000),
                "synthetic.pedestrians",
            ),
            (
                Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().vehicles = 1),
                "2 vehicle",
            ),
            (
                Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().scenes = 0),
                "synthetic.scenes",
            ),
            (
                Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().density = -1.0),
                "density",
            ),
            (
                Box::new(|r: &mut CreateEnv| r.synthetic.as_mut().unwrap().vehicles = 0),
                "vehicles",
            ),
        ] {
            let mut bad_req = req.clone();
            change(&mut bad_req);
            let e = err_of(&c.handle_create(&encode(&bad_req), Instant::now()).reply);
            assert!(e.message.contains(needle), "{needle}: {e}");
        }
        assert_eq!(c.load(), load);
    }

    #[test]
    fn an_oversized_request_is_refused_before_decoding() {
        let c = core(Limits {
            max_request_bytes: 64,
            ..Limits::default()
        });
        assert!(c.refuse_oversized(64).is_none());
        let refused = c.refuse_oversized(65).expect("refused");
        let e = err_of(&refused.reply);
        assert_eq!(e.code, ErrorCode::LimitExceeded);
        assert!(
            e.message.contains("65 bytes") && e.message.contains("not decoded"),
            "{e}"
        );
        assert!(refused.pubs.is_empty() && refused.realtime_envs.is_empty());
        assert_eq!(c.load(), 0);
    }

    #[test]
    fn threaded_batch_equals_single_steps() {
        let mut c = core(Limits::default());
        c.set_batch_threads(3);
        let k = 2 * PARALLEL_MIN_BATCH + 3;
        let mut req = CreateEnv::new("a");
        req.count = k as u32;
        req.autoreset = true;
        let a = create(&c, &req).env_ids;
        let b = create(&c, &req).env_ids;
        for id in a.iter().chain(&b) {
            c.handle_reset(id, &[], Gates::NONE);
        }
        let (mut resets, mut events) = (0, 0);
        // Enough rounds for episodes to end (collisions, arrivals) and restart.
        for round in 0..40 {
            let vals: Vec<f32> = (0..k)
                .flat_map(|i| [((i + round) as f32 * 0.1).sin(), 0.05])
                .collect();
            let batch = encode(&BatchStep {
                env_ids: a.clone(),
                actions: protocol::F32Array::new(vec![k as u32, 1, 2], &vals)
                    .unwrap()
                    .into(),
            });
            let r: BatchStepResult =
                decode::<Reply<BatchStepResult>>(&c.handle_batch(&batch, &Gates::NONE).reply)
                    .unwrap()
                    .into_result()
                    .unwrap();
            let singles: Vec<StepResult> = b
                .iter()
                .enumerate()
                .map(|(i, id)| {
                    let step = encode(&Step::from_rows(&[[vals[2 * i], vals[2 * i + 1]]]));
                    decode::<Reply<StepResult>>(&c.handle_step(id, &step, Gates::NONE).reply)
                        .unwrap()
                        .into_result()
                        .unwrap()
                })
                .collect();
            // The same transitions stacked (the reply names envs by position, so only the
            // ids differ).
            let mut want = BatchStepResult::from_results(singles).unwrap();
            want.env_ids = a.clone();
            assert_eq!(r, want, "round {round}");
            resets += r.resets.index.len();
            events += r.events.len();
        }
        assert!(resets > 0 && events > 0, "{resets} resets, {events} events");
    }
}
