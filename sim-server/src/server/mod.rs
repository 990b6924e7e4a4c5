//! The zenoh simulation server (`sim-server serve`).
//!
//! # Architecture
//!
//! The server speaks the wire protocol of `protocol/SPEC.md` over Zenoh 1.x. It is split into a
//! pure, synchronous core and a thin network layer:
//!
//! * [`pools`]: scenario pools as served (agent naming, split candidates) and the seeded
//!   per-env scenario sequence.
//! * [`env`]: one env — its scenario sequence, the current episode's `sim_core::World`, and the
//!   translation of sim-core results into protocol replies and publications (observations are
//!   written straight into the reply's arrays, batched or not).
//! * [`sim_core::support::threads`]: the persistent threads that step a large batch's chunks.
//! * [`core`]: [`ServerCore`], the env registry (env id → `Arc<Mutex<Env>>`), trainers and
//!   reaping, limits, and one handler per request taking payload bytes and returning reply bytes
//!   plus the publications to send. Unit-testable without zenoh.
//! * [`net`]: the tokio/zenoh layer — one queryable per request kind (an info query, and a
//!   single-env step while no served scenario has more than 64 agents, answered on the zenoh
//!   thread that delivered it; batches on tokio's blocking threads (`spawn_blocking`), where
//!   they may wait for a fair turn; every other query in its own tokio task, so steps of
//!   different envs run concurrently, serialised per env by the env's mutex), the server's liveliness token, the trainers' liveliness subscriber, the realtime
//!   action subscriber and one clock task per realtime env; [`run`] is the entry point.
//! * [`fair`]: [`fair::FairTurns`], the fair order of batches waiting to be stepped.
//! * [`config`]: the JSON5 configuration with `--cfg KEY:VALUE` overrides.
//! * [`client`]: a small Rust client used by the tests and the benchmark.
//!
//! # Behaviour decided here (also in `protocol/SPEC.md`)
//!
//! * **Scenario sequence.** Env k of a `CreateEnv` is seeded with `seed + k`. Its episodes are
//!   drawn from the candidate scenarios (pool split, enough vehicles) as consecutive random
//!   permutations (Fisher–Yates with SplitMix64 seeded by the env's seed); `Reset.seed` re-seeds
//!   and starts a new permutation. Trainers sharing a server never influence each other's
//!   sequences.
//! * **Agent names.** `vehicle_0` is the scenario's ego, other vehicles follow in agent order;
//!   `pedestrian_k` in agent order. Either may be external (`pools::ExternalAgent`).
//! * **Publications cost nothing unobserved.** For each topic (`states`, `uncertainty`,
//!   `risk_graph`, `events`, `result`) the server declares one publisher on `{p}/env/*/{topic}` and
//!   keeps its zenoh matching status in an atomic flag; a topic without any matching subscriber
//!   is neither encoded nor put. While somebody matches a topic, each open env gets a publisher
//!   of its own on it (`watch::EnvWatch`), whose matching status gates that env: a subscriber of
//!   one env's topic costs the other envs nothing.
//! * **Scene variations.** An env with variations (`CreateEnv.variations`, else its pool
//!   entry's) draws one variation seed per episode from a stream seeded by its seed
//!   (`Reset.seed` re-seeds it, `Reset.variation` plays a given seed) and builds that
//!   episode's world from `sim_core::variation`; the reset reports the seed and the values.
//! * **Reaping.** The trainers' liveliness tokens `{p}/trainer/{client_id}` are watched with
//!   history; when one disappears its envs are closed at once, or after `reconnect_grace_s`
//!   (default 0) unless the token comes back first (a trainer that reconnects keeps its envs).
//!   Envs of a client without a token are reaped after `trainer_grace_s` (default 10 s),
//!   checked every 250 ms. A trainer whose network link is lost or silent is detected by
//!   zenoh's transport lease (`zenoh/transport/link/tx/lease`, default 10 s).
//! * **Quotas.** `capacity` open envs in all, `max_envs_per_trainer` per client id (default:
//!   the capacity); a request payload over `max_request_bytes` (1 MiB) is refused before it is
//!   copied or decoded. At most `batch_slots` batches (default: one per batch thread) step at
//!   once; when more wait, the next turn goes to the trainer that has been served the fewest
//!   env-steps (start-time fair queueing, [`fair`]), so a trainer flooding the server with
//!   batches waits behind its own queue, not in front of everyone else's. Batches are answered
//!   on tokio's blocking threads, so waiting ones never hold up the runtime.
//! * **Realtime.** A realtime env's clock ticks every `dt / realtime_factor` seconds from its
//!   creation; after a `Reset` every tick steps with the latest action per agent (zero-order
//!   hold, `[0, 0]` until the first one), publishes the `StepResult` on `{p}/env/{id}/result` and
//!   the state publications. Missed ticks are delayed, not made up.
//! * **Batches.** A `BatchStep` of at least 64 envs is split into consecutive chunks stepped on
//!   up to `batch_threads` threads (default one per core), bit-identical to one thread; each
//!   thread steps its envs' worlds in one shared `sim_core::StepScratch`.
//! * **Errors.** Every query gets exactly one reply; decoding, validation, limits and state errors
//!   map to the error codes of SPEC section 4 and never change any env. Batches lock their envs
//!   in id order and check everything before stepping any.
//! * **Shutdown.** [`run`] serves until its shutdown future completes (the binary passes
//!   [`shutdown_signal`]: SIGINT or SIGTERM), then undeclares the liveliness token, stops the
//!   tasks, closes every env and the zenoh session.

pub mod client;
pub mod config;
pub mod core;
pub mod env;
pub mod fair;
pub mod net;
pub mod pools;
mod watch;

pub use self::config::ServerConfig;
pub use self::core::{limit_allocator_arenas, Limits, ServerCore};
pub use self::net::{run, shutdown_signal, Server, ServerError};
