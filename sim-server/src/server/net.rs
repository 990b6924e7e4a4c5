//! The thin zenoh/tokio layer: declares the queryables, liveliness token and subscribers, moves
//! payload bytes to [`ServerCore`] and its replies and publications back onto the network.

use std::future::Future;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use protocol::{ErrorCode, ErrorReply, KeySpace};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use zenoh::bytes::Encoding;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::query::{Query, Queryable};
use zenoh::sample::SampleKind;
use zenoh::{Session, Wait};

use super::config::{ConfigError, ServerConfig};
use super::core::{reply_bytes, Response, ServerCore};
use super::env::{Gates, Publication, Watch};
use super::pools::load_pools;
use super::watch::{sync_env_watch, EnvWatch, NetWatch, TOPICS};

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("scenario pool: {0}")]
    Pool(String),
    #[error("world parameters: {0}")]
    Params(String),
    #[error("zenoh: {0}")]
    Zenoh(String),
}

fn zerr(e: impl std::fmt::Display) -> ServerError {
    ServerError::Zenoh(e.to_string())
}

/// The MessagePack encoding set on every reply and publication.
pub fn msgpack() -> Encoding {
    Encoding::from("application/msgpack")
}

#[derive(Debug, Clone, Copy)]
enum Kind {
    Info,
    Create,
    EnvOp,
    Batch,
}

struct Ctx {
    core: Arc<ServerCore>,
    session: Session,
    keys: KeySpace,
    /// One flag per topic of [`TOPICS`]: does any subscriber match `{p}/env/*/{topic}`?
    gates: [Arc<AtomicBool>; 5],
    /// Per env, narrower flags (see [`EnvWatch`]).
    env_watch: Arc<EnvWatch>,
    stop: watch::Receiver<bool>,
    /// Single-env steps are answered on the zenoh thread (see [`Ctx::answers_inline`]).
    inline_steps: bool,
}

/// Single-env steps are answered on the zenoh thread only while every served scenario has at
/// most this many agents: a world step costs about 2 us at 4 agents and 0.2 ms at 100, and
/// the thread it would hold up carries every other trainer's traffic.
const INLINE_STEP_MAX_AGENTS: usize = 64;

impl Ctx {
    fn gates(&self) -> Gates {
        let g = |i: usize| self.gates[i].load(Ordering::Relaxed);
        Gates {
            states: g(0),
            uncertainty: g(1),
            risk_graph: g(2),
            events: g(3),
            result: g(4),
        }
    }

    fn watch(&self) -> NetWatch<'_> {
        NetWatch {
            topics: self.gates(),
            flags: self
                .env_watch
                .flags
                .read()
                .unwrap_or_else(|p| p.into_inner()),
        }
    }

    async fn publish(&self, pubs: Vec<Publication>) {
        for p in pubs {
            if let Err(e) = self
                .session
                .put(p.key.as_str(), p.payload)
                .encoding(msgpack())
                .await
            {
                tracing::debug!(key = %p.key, error = %e, "publication failed");
            }
        }
    }

    /// Whether `query` is answered on the network thread that delivered it (see
    /// [`serve_query`]): an info query, or a single-env step when no served scenario has more
    /// than [`INLINE_STEP_MAX_AGENTS`] agents (each some microseconds of work).
    fn answers_inline(&self, kind: Kind, query: &Query) -> bool {
        match kind {
            Kind::Info => true,
            Kind::EnvOp => {
                self.inline_steps
                    && matches!(
                        self.keys
                            .parse_env_op(self.core.server_id(), query.key_expr().as_str()),
                        Some((_, protocol::EnvOp::Step))
                    )
            }
            Kind::Create | Kind::Batch => false,
        }
    }

    /// Answers `query` on this thread: the reply and any publications are handed to zenoh
    /// without waiting on the async runtime. Realtime clocks only start from `Create`, which is
    /// never answered here.
    fn handle_inline(&self, kind: Kind, query: Query) {
        let (resp, reply_key) = self.respond(kind, &query);
        debug_assert!(resp.realtime_envs.is_empty());
        for p in resp.pubs {
            if let Err(e) = self
                .session
                .put(p.key.as_str(), p.payload)
                .encoding(msgpack())
                .wait()
            {
                tracing::debug!(key = %p.key, error = %e, "publication failed");
            }
        }
        if let Err(e) = query
            .reply(reply_key.as_str(), resp.reply)
            .encoding(msgpack())
            .wait()
        {
            tracing::warn!(key = %reply_key, error = %e, "reply failed");
        }
    }

    async fn handle(self: Arc<Self>, kind: Kind, query: Query) {
        let (resp, reply_key) = self.respond(kind, &query);
        self.publish(resp.pubs).await;
        for (env_id, period) in resp.realtime_envs {
            let ctx = self.clone();
            tokio::spawn(ctx.realtime_clock(env_id, period));
        }
        if let Err(e) = query
            .reply(reply_key.as_str(), resp.reply)
            .encoding(msgpack())
            .await
        {
            tracing::warn!(key = %reply_key, error = %e, "reply failed");
        }
    }

    /// The core's response to `query` and the key to reply on.
    fn respond(&self, kind: Kind, query: &Query) -> (Response, String) {
        let key = query.key_expr().as_str().to_string();
        let core = &self.core;
        let len = query.payload().map_or(0, |p| p.len());
        if let Some(refused) = core.refuse_oversized(len) {
            tracing::debug!(key = %key, len, "request refused: too large");
            return (refused, key);
        }
        let payload: Vec<u8> = query
            .payload()
            .map(|p| p.to_bytes().into_owned())
            .unwrap_or_default();
        let watch = self.watch();
        let resp: Response = match kind {
            Kind::Info => core.handle_info(&payload, &self.env_watch.sizes()),
            Kind::Create => core.handle_create(&payload, Instant::now()),
            Kind::Batch => core.handle_batch(&payload, &watch),
            Kind::EnvOp => match self.keys.parse_env_op(core.server_id(), &key) {
                Some((env_id, protocol::EnvOp::Reset)) => {
                    core.handle_reset(env_id, &payload, watch.gates(env_id))
                }
                Some((env_id, protocol::EnvOp::Step)) => {
                    core.handle_step(env_id, &payload, watch.gates(env_id))
                }
                Some((env_id, protocol::EnvOp::Close)) => core.handle_close(env_id, &payload),
                None => Response {
                    reply: reply_bytes::<()>(Err(ErrorReply::new(
                        ErrorCode::BadRequest,
                        format!(
                            "key {key:?} is not {}/server/{}/env/{{env_id}}/{{reset|step|close}} with a valid env id",
                            self.keys.prefix(),
                            core.server_id()
                        ),
                    ))),
                    ..Response::default()
                },
            },
        };
        let reply_key = match kind {
            Kind::Info => self.keys.server_info(core.server_id()).ok(),
            Kind::Create => self.keys.env_create(core.server_id()).ok(),
            Kind::Batch => self.keys.batch_step(core.server_id()).ok(),
            Kind::EnvOp => None,
        }
        .unwrap_or(key);
        (resp, reply_key)
    }

    /// Steps a realtime env every `period` until it is closed or the server stops.
    async fn realtime_clock(self: Arc<Self>, env_id: String, period: Duration) {
        let mut stop = self.stop.clone();
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        tick.tick().await;
        loop {
            tokio::select! {
                _ = tick.tick() => {
                    let gates = self.watch().gates(&env_id);
                    match self.core.realtime_tick(&env_id, gates) {
                        None => break,
                        Some(pubs) => self.publish(pubs).await,
                    }
                }
                _ = stop.changed() => break,
            }
        }
        tracing::debug!(env = %env_id, "realtime clock stopped");
    }
}

/// Where a query is answered. Small requests (a single-env step, info) are answered on the zenoh
/// thread that delivered them, as a bare queryable would: handing them to the async runtime
/// first costs a thread wake-up or two, tens of microseconds on a loaded machine, several times
/// the work itself. Everything else (create, reset, close, batches of up to `max_batch` envs)
/// runs as a task, so that the network threads keep moving other trainers' traffic. Once the
/// server stops, queries are no longer answered (they time out at the client).
/// The pure core of a server: its pools and world parameters loaded from the configuration.
fn build_core(
    cfg: &ServerConfig,
    server_id: &str,
    keys: &KeySpace,
) -> Result<ServerCore, ServerError> {
    let params = crate::params_file::ParamsDoc::from_arg(cfg.params.as_deref())
        .and_then(|doc| crate::params_file::ModelParams::from_doc(&doc))
        .map_err(|e| ServerError::Params(e.to_string()))?;
    let pools = load_pools(&cfg.pools, params.base()).map_err(ServerError::Pool)?;
    let mut core = ServerCore::new(
        server_id.to_string(),
        keys.clone(),
        cfg.limits(),
        pools,
        params,
    );
    core.set_batch_threads(cfg.batch_threads());
    Ok(core)
}

/// Publication gates: one wildcard publisher per topic of [`TOPICS`], whose zenoh matching
/// status is kept in that topic's flag.
async fn declare_gates(
    session: &Session,
    keys: &KeySpace,
) -> Result<(Vec<Publisher<'static>>, [Arc<AtomicBool>; 5]), ServerError> {
    let mut publishers = Vec::new();
    let gates: [Arc<AtomicBool>; 5] = std::array::from_fn(|_| Arc::new(AtomicBool::new(false)));
    for (topic, flag) in TOPICS.iter().zip(&gates) {
        let publisher = session
            .declare_publisher(keys.env_topic_all(*topic))
            .await
            .map_err(zerr)?;
        let f = flag.clone();
        publisher
            .matching_listener()
            .callback(move |s| f.store(s.matching(), Ordering::Relaxed))
            .background()
            .await
            .map_err(zerr)?;
        if publisher.matching_status().await.map_err(zerr)?.matching() {
            flag.store(true, Ordering::Relaxed);
        }
        publishers.push(publisher);
    }
    Ok((publishers, gates))
}

/// One queryable per request kind (SPEC section 3), each answered by [`serve_query`].
async fn declare_queryables(
    ctx: &Arc<Ctx>,
    server_id: &str,
) -> Result<Vec<Queryable<()>>, ServerError> {
    let keys = &ctx.keys;
    let queryables = [
        (keys.server_info(server_id), Kind::Info),
        (keys.env_create(server_id), Kind::Create),
        (
            keys.env_op_wildcard(server_id, protocol::EnvOp::Reset),
            Kind::EnvOp,
        ),
        (
            keys.env_op_wildcard(server_id, protocol::EnvOp::Step),
            Kind::EnvOp,
        ),
        (
            keys.env_op_wildcard(server_id, protocol::EnvOp::Close),
            Kind::EnvOp,
        ),
        (keys.batch_step(server_id), Kind::Batch),
    ];
    let rt = tokio::runtime::Handle::current();
    let mut served = Vec::with_capacity(queryables.len());
    for (key, kind) in queryables {
        let key = key.map_err(|e| ConfigError::Invalid(e.to_string()))?;
        let (served_ctx, rt) = (ctx.clone(), rt.clone());
        let q = ctx
            .session
            .declare_queryable(key)
            .complete(true)
            .callback(move |query| serve_query(&served_ctx, &rt, kind, query))
            .await
            .map_err(zerr)?;
        served.push(q);
    }
    Ok(served)
}

/// Realtime actions: `{p}/env/*/action/*`, handed to the core as they arrive.
async fn declare_action_subscriber(
    session: &Session,
    core: &Arc<ServerCore>,
    keys: &KeySpace,
) -> Result<Subscriber<()>, ServerError> {
    let (core, keys_a) = (core.clone(), keys.clone());
    session
        .declare_subscriber(format!("{}/env/*/action/*", keys.prefix()))
        .callback(move |sample| {
            let key = sample.key_expr().as_str();
            let Some((env_id, agent)) = keys_a.parse_env_action(key) else {
                return;
            };
            let bytes = sample.payload().to_bytes();
            if let Err(e) = core.handle_action(env_id, agent, &bytes) {
                tracing::debug!(key, error = %e, "action dropped");
            }
        })
        .await
        .map_err(zerr)
}

/// The trainers' liveliness tokens, with history: a trainer that appears is alive, one that
/// disappears has its envs reaped (or kept for `reconnect_grace_s`).
async fn watch_trainers(
    session: &Session,
    core: &Arc<ServerCore>,
    keys: &KeySpace,
    mut stop: watch::Receiver<bool>,
) -> Result<JoinHandle<()>, ServerError> {
    let trainers = session
        .liveliness()
        .declare_subscriber(keys.trainer_all())
        .history(true)
        .await
        .map_err(zerr)?;
    let (core, keys) = (core.clone(), keys.clone());
    Ok(tokio::spawn(async move {
        loop {
            tokio::select! {
                s = trainers.recv_async() => {
                    let Ok(sample) = s else { break };
                    let Some(client) = keys.parse_trainer(sample.key_expr().as_str()) else {
                        continue;
                    };
                    match sample.kind() {
                        SampleKind::Put => {
                            tracing::debug!(client, "trainer alive");
                            core.trainer_alive(client);
                        }
                        SampleKind::Delete => {
                            let reaped = core.trainer_lost(client, Instant::now());
                            tracing::info!(client, envs = reaped.len(), "trainer gone, envs reaped (or kept for reconnect_grace_s)");
                        }
                    }
                }
                _ = stop.changed() => break,
            }
        }
    }))
}

/// Gives the allocator's free memory back to the system every `period`.
fn spawn_memory_trim(period: Duration, mut stop: watch::Receiver<bool>) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                _ = tick.tick() => {
                    // Walks every arena under its lock: milliseconds, off the runtime.
                    let _ = tokio::task::spawn_blocking(super::core::trim_allocator).await;
                }
                _ = stop.changed() => break,
            }
        }
    })
}

/// Reaps, every 250 ms, the envs of clients without a liveliness token (`trainer_grace_s`).
fn spawn_sweep(core: Arc<ServerCore>, mut stop: watch::Receiver<bool>) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(250));
        loop {
            tokio::select! {
                _ = tick.tick() => {
                    let reaped = core.sweep(Instant::now());
                    if !reaped.is_empty() {
                        tracing::info!(envs = reaped.len(), "reaped envs of trainers without liveliness token");
                    }
                }
                _ = stop.changed() => break,
            }
        }
    })
}

/// The server's liveliness token `{p}/server/{id}/alive`: what clients find it by.
async fn declare_alive_token(
    session: &Session,
    keys: &KeySpace,
    server_id: &str,
) -> Result<LivelinessToken, ServerError> {
    let key = keys
        .server_alive(server_id)
        .map_err(|e| ConfigError::Invalid(e.to_string()))?;
    session.liveliness().declare_token(key).await.map_err(zerr)
}

fn serve_query(ctx: &Arc<Ctx>, rt: &tokio::runtime::Handle, kind: Kind, query: Query) {
    if *ctx.stop.borrow() {
        return;
    }
    if ctx.answers_inline(kind, &query) {
        ctx.handle_inline(kind, query);
    } else if matches!(kind, Kind::Batch) {
        // A batch may wait for its fair turn (`fair`) and then steps for milliseconds: on a
        // blocking thread, neither holds up the runtime's other tasks.
        let ctx = ctx.clone();
        rt.spawn_blocking(move || ctx.handle_inline(kind, query));
    } else {
        rt.spawn(ctx.clone().handle(kind, query));
    }
}

/// A running server (see [`run`]).
pub struct Server {
    core: Arc<ServerCore>,
    session: Session,
    stop_tx: watch::Sender<bool>,
    tasks: Vec<JoinHandle<()>>,
    token: Option<LivelinessToken>,
    queryables: Vec<Queryable<()>>,
    _gate_publishers: Vec<Publisher<'static>>,
    _actions: Option<Subscriber<()>>,
}

impl Server {
    /// Opens the zenoh session and declares everything. Returns once the server serves.
    pub async fn start(cfg: ServerConfig) -> Result<Self, ServerError> {
        let keys =
            KeySpace::new(cfg.prefix.clone()).map_err(|e| ConfigError::Invalid(e.to_string()))?;
        let server_id = cfg.server_id_or_random();
        let core = Arc::new(build_core(&cfg, &server_id, &keys)?);
        let zcfg = zenoh::Config::from_json5(&cfg.zenoh_json()).map_err(zerr)?;
        let session = zenoh::open(zcfg).await.map_err(zerr)?;
        let (stop_tx, stop_rx) = watch::channel(false);

        let (gate_publishers, gates) = declare_gates(&session, &keys).await?;
        let env_watch = Arc::new(EnvWatch::default());
        let ctx = Arc::new(Ctx {
            core: core.clone(),
            session: session.clone(),
            keys: keys.clone(),
            gates: gates.clone(),
            env_watch: env_watch.clone(),
            stop: stop_rx.clone(),
            inline_steps: core.max_scene_agents() <= INLINE_STEP_MAX_AGENTS,
        });
        let queryables = declare_queryables(&ctx, &server_id).await?;
        let actions = declare_action_subscriber(&session, &core, &keys).await?;
        let mut tasks = vec![tokio::spawn(sync_env_watch(
            session.clone(),
            core.clone(),
            keys.clone(),
            gates,
            env_watch,
            stop_rx.clone(),
        ))];
        tasks.push(watch_trainers(&session, &core, &keys, stop_rx.clone()).await?);
        if cfg.memory_trim_s > 0.0 {
            let period = Duration::from_secs_f64(cfg.memory_trim_s);
            tasks.push(spawn_memory_trim(period, stop_rx.clone()));
        }
        tasks.push(spawn_sweep(core.clone(), stop_rx));
        // Last: clients find the server by this token, once it answers everything.
        let token = declare_alive_token(&session, &keys, &server_id).await?;
        // The one line a person starting a server waits for (stderr, at info by default).
        tracing::info!(
            server_id = %server_id,
            prefix = keys.prefix(),
            endpoints = %cfg.endpoints_line(),
            pools = %core.pool_names().join(","),
            "sharedspace server serving"
        );
        Ok(Self {
            core,
            session,
            stop_tx,
            tasks,
            token: Some(token),
            queryables,
            _gate_publishers: gate_publishers,
            _actions: Some(actions),
        })
    }

    pub fn core(&self) -> &Arc<ServerCore> {
        &self.core
    }

    pub fn server_id(&self) -> &str {
        self.core.server_id()
    }

    /// Stops serving: undeclares everything, closes every env and the session.
    pub async fn stop(mut self) {
        let _ = self.stop_tx.send(true);
        if let Some(t) = self.token.take() {
            let _ = t.undeclare().await;
        }
        for q in self.queryables.drain(..) {
            let _ = q.undeclare().await;
        }
        for t in self.tasks.drain(..) {
            let _ = tokio::time::timeout(Duration::from_secs(5), t).await;
        }
        if let Some(a) = self._actions.take() {
            let _ = a.undeclare().await;
        }
        let closed = self.core.close_all();
        if let Err(e) = self.session.close().await {
            tracing::warn!(error = %e, "closing the zenoh session");
        }
        tracing::info!(envs_closed = closed.len(), "server stopped");
    }
}

/// Runs a server until `shutdown` completes, then stops it gracefully.
pub async fn run(cfg: ServerConfig, shutdown: impl Future<Output = ()>) -> Result<(), ServerError> {
    let server = Server::start(cfg).await?;
    shutdown.await;
    tracing::info!("shutting down");
    server.stop().await;
    Ok(())
}

/// Completes on SIGINT (Ctrl-C) or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
}
