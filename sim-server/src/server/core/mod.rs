//! The server's pure request handling: env registry, trainers and reaping, limits, and every
//! request from payload bytes to reply bytes. Synchronous and free of zenoh, so it is unit-tested
//! directly; the network layer (`net.rs`) only moves bytes and publications.
//!
//! Here: the registry, limits, info, lookups, and the single-env requests (reset, step,
//! close). Beside it, one request or job per file: `create` (`CreateEnv`, its pools and
//! parameter overrides), `batch` (`BatchStep` and its reusable buffers), `reaping` (trainers'
//! liveliness), `memory` (the allocator's figures and trimming).
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
use sim_core::params::{PedestrianModel, WorldParams};

use crate::params_file::ModelParams;
use sim_core::scenario::Split;
use sim_core::world::StepScratch;

use super::env::{BufMut, Buffers, Env, EnvSpec, Gates, Publication, Watch};
use super::fair::FairTurns;
use super::pools::ServedPool;
use scenarios::composed::Parts;
use sim_core::support::threads::Helpers;

mod batch;
mod create;
mod memory;
mod reaping;
/// A `non_finite_action` error of a `Step` with the name of the external agent whose row holds
/// the first non-finite number, as the client named it (`pedestrian_1: actions: ...`).
fn named_agent(e: ErrorReply, req: &Step, names: &[String]) -> ErrorReply {
    if e.code != ErrorCode::NonFiniteAction {
        return e;
    }
    let values = req.actions.to_f64_vec();
    match values
        .iter()
        .position(|v| !v.is_finite())
        .and_then(|i| names.get(i / 2))
    {
        Some(name) => ErrorReply::new(e.code, format!("{name}: {}", e.message)),
        None => e,
    }
}

#[cfg(test)]
mod tests;

pub use create::{MAX_SYNTHETIC_PEDESTRIANS, MAX_SYNTHETIC_SCENES};
pub use memory::{allocator_figures, limit_allocator_arenas, trim_allocator};

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
    /// The parts of composed scenes by source pool and held-out scenes, taken apart once for
    /// every request that asks for the same (a crowd pool's take a tenth of a second).
    composed_parts: Mutex<HashMap<PartsKey, Arc<Parts>>>,
}
/// The parts of composed scenes are keyed by source pool and sorted held-out scene names.
type PartsKey = (String, Vec<String>);

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
            composed_parts: Mutex::new(HashMap::new()),
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

    /// The names of the pools it serves, the default first.
    pub fn pool_names(&self) -> Vec<&str> {
        self.pools.iter().map(|p| p.name.as_str()).collect()
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
                .map_err(|e| named_agent(e, &req, &env.spec.external_names))
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
}
