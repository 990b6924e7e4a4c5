//! Shared helpers of the server integration tests: an in-process server on a random free
//! loopback port (multicast scouting off) and clients in their own zenoh sessions. Every await
//! goes through [`t`] (a tokio timeout).
#![allow(dead_code)]

use std::future::IntoFuture;
use std::time::Duration;

use protocol::{CreateEnv, KeySpace, StepResult};
use serde_json::json;
use sim_server::server::client::Client;
use sim_server::server::{run, ServerConfig, ServerError};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;

/// Upper bound of any single await in the tests.
pub const T: Duration = Duration::from_secs(20);

/// Awaits `f` under [`T`].
pub async fn t<F: IntoFuture>(f: F) -> F::Output {
    tokio::time::timeout(T, f.into_future())
        .await
        .expect("timed out")
}

/// Whether the step ended the episode of any of its agents (terminated or truncated).
pub fn episode_over(s: &StepResult) -> bool {
    s.terminated
        .iter()
        .chain(s.truncated.iter())
        .any(|v| v == 1)
}

/// The step's reward, terminated and truncated columns as their bytes: a bit-exact record of
/// its outcome.
pub fn outcome_bytes(s: &StepResult) -> Vec<u8> {
    let mut bytes = s.reward.as_le_bytes().to_vec();
    bytes.extend_from_slice(s.terminated.as_le_bytes());
    bytes.extend_from_slice(s.truncated.as_le_bytes());
    bytes
}

/// A free TCP port on 127.0.0.1.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A server config listening on `port` with `server_id`.
pub fn config(port: u16, server_id: &str) -> ServerConfig {
    ServerConfig {
        server_id: Some(server_id.to_string()),
        zenoh: json!({
            "mode": "peer",
            "listen": {"endpoints": [format!("tcp/127.0.0.1:{port}")]},
            "scouting": {"multicast": {"enabled": false}},
        }),
        ..ServerConfig::default()
    }
}

pub struct TestServer {
    pub port: u16,
    pub server_id: String,
    stop: Option<oneshot::Sender<()>>,
    handle: Option<JoinHandle<Result<(), ServerError>>>,
}

impl TestServer {
    /// Stops the server (graceful shutdown through `run`'s shutdown future).
    pub async fn stop(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(h) = self.handle.take() {
            t(h).await.expect("server task").expect("server ran");
        }
    }
}

/// Starts `sim_server::server::run` in a task.
pub async fn start(cfg: ServerConfig) -> TestServer {
    let port = cfg
        .zenoh
        .pointer("/listen/endpoints/0")
        .and_then(|v| v.as_str())
        .and_then(|s| s.rsplit(':').next())
        .and_then(|p| p.parse().ok())
        .expect("config listens on a port");
    let server_id = cfg.server_id.clone().expect("server id");
    let (tx, rx) = oneshot::channel::<()>();
    let handle = tokio::spawn(run(cfg, async move {
        let _ = rx.await;
    }));
    // Wait until the server listens.
    t(async {
        while tokio::net::TcpStream::connect(("127.0.0.1", port))
            .await
            .is_err()
        {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    TestServer {
        port,
        server_id,
        stop: Some(tx),
        handle: Some(handle),
    }
}

/// A zenoh session in client mode connected to the server's port.
pub async fn session(port: u16) -> zenoh::Session {
    let cfg = json!({
        "mode": "client",
        "connect": {"endpoints": [format!("tcp/127.0.0.1:{port}")]},
        "scouting": {"multicast": {"enabled": false}},
    });
    let cfg = zenoh::Config::from_json5(&cfg.to_string()).unwrap();
    t(zenoh::open(cfg)).await.unwrap()
}

/// Creates one default env for trainer `c` and returns its id.
pub async fn one_env(c: &Client) -> String {
    let created = t(c.create(CreateEnv::new(c.client_id()))).await.unwrap();
    created.env_ids.into_iter().next().expect("one env created")
}

/// A client with its own session; waits until the server answers `info`.
pub async fn client(server: &TestServer, client_id: &str) -> Client {
    let s = session(server.port).await;
    let c = t(Client::new(
        s,
        KeySpace::default(),
        &server.server_id,
        client_id,
    ))
    .await
    .unwrap();
    t(async {
        loop {
            if c.info().await.is_ok() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    c
}
