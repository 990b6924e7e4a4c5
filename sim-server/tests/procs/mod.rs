//! Shared helpers of the multi-process deployment tests: `sim-server router` and
//! `sim-server serve` as child processes (the binary under test, on 127.0.0.1 random free ports,
//! multicast scouting off, with the shipped `deploy/` configurations plus `--cfg` overrides),
//! killed on drop; a scratch directory removed on drop; zenoh client sessions with or without
//! credentials. Every wait is bounded by [`crate::common::T`].
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use serde_json::json;

pub use crate::common::{free_port, t};

/// Credentials written to the router's dictionary by [`Scratch::new`].
pub const SERVER_USER: (&str, &str) = ("server", "server-test-pw");
pub const TRAINER_USER: (&str, &str) = ("trainer", "trainer-test-pw");

/// The repository's `deploy/` directory.
pub fn deploy_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy")
}

/// A scratch directory (credentials, process logs), removed on drop.
pub struct Scratch {
    pub dir: PathBuf,
}

impl Scratch {
    /// A fresh directory holding `credentials.txt` with [`SERVER_USER`] and [`TRAINER_USER`].
    pub fn new(name: &str) -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos();
        let dir =
            std::env::temp_dir().join(format!("sharedspace-{name}-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("credentials.txt"),
            format!(
                "{}:{}\n{}:{}\n",
                SERVER_USER.0, SERVER_USER.1, TRAINER_USER.0, TRAINER_USER.1
            ),
        )
        .unwrap();
        Self { dir }
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A child process, SIGKILLed and reaped on drop; its stderr goes to a log file.
pub struct Proc {
    pub name: String,
    child: Child,
    log: PathBuf,
}

impl Proc {
    fn spawn(name: &str, log_dir: &Path, args: &[String]) -> Self {
        let log = log_dir.join(format!("{name}.log"));
        let child = Command::new(env!("CARGO_BIN_EXE_sim-server"))
            .args(args)
            .env(
                "RUST_LOG",
                std::env::var("SHAREDSPACE_TEST_LOG").unwrap_or_else(|_| "info,zenoh=warn".into()),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap_or_else(|e| panic!("spawning {name}: {e}"));
        Self {
            name: name.to_string(),
            child,
            log,
        }
    }

    /// What the process wrote to stderr so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// SIGKILL (no clean shutdown: the process vanishes as in a crash) and reap.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Panics (with the log) if the process has exited.
    pub fn assert_running(&mut self) {
        if let Ok(Some(status)) = self.child.try_wait() {
            panic!("{} exited ({status}):\n{}", self.name, self.log());
        }
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

/// Waits until 127.0.0.1:`port` accepts TCP connections (the process keeps running).
pub async fn wait_listening(p: &mut Proc, port: u16) {
    t(async {
        while tokio::net::TcpStream::connect(("127.0.0.1", port))
            .await
            .is_err()
        {
            p.assert_running();
            tokio::time::sleep(Duration::from_millis(25)).await;
        }
    })
    .await;
}

/// `sim-server router --config deploy/router.json5` (its auth and access control as shipped)
/// listening on 127.0.0.1:`port` with the scratch credentials; returns once it listens.
pub async fn router(scratch: &Scratch, port: u16) -> Proc {
    let cred = scratch.dir.join("credentials.txt");
    let args = vec![
        "router".to_string(),
        "--config".into(),
        deploy_dir().join("router.json5").display().to_string(),
        "--cfg".into(),
        format!("listen/endpoints:[\"tcp/127.0.0.1:{port}\"]"),
        "--cfg".into(),
        format!("transport/auth/usrpwd/dictionary_file:{}", json!(cred)),
    ];
    let mut p = Proc::spawn("router", &scratch.dir, &args);
    wait_listening(&mut p, port).await;
    p
}

/// `sim-server serve --config deploy/server-routed.json5` (zenoh client mode) joining the router
/// on `router_port` as `user`; does not wait (see [`wait_server`]).
pub fn serve(scratch: &Scratch, router_port: u16, server_id: &str, user: (&str, &str)) -> Proc {
    let args = vec![
        "serve".to_string(),
        "--config".into(),
        deploy_dir()
            .join("server-routed.json5")
            .display()
            .to_string(),
        "--cfg".into(),
        format!("server_id:{server_id}"),
        "--cfg".into(),
        format!("zenoh/connect/endpoints:[\"tcp/127.0.0.1:{router_port}\"]"),
        "--cfg".into(),
        format!("zenoh/transport/auth/usrpwd/user:{}", json!(user.0)),
        "--cfg".into(),
        format!("zenoh/transport/auth/usrpwd/password:{}", json!(user.1)),
    ];
    Proc::spawn(&format!("serve-{server_id}"), &scratch.dir, &args)
}

/// The zenoh configuration of a client-mode session to the router on `port`, with `user`
/// credentials (none when `None`).
pub fn client_config(port: u16, user: Option<(&str, &str)>) -> zenoh::Config {
    let mut cfg = json!({
        "mode": "client",
        "connect": {"endpoints": [format!("tcp/127.0.0.1:{port}")]},
        "scouting": {"multicast": {"enabled": false}},
    });
    if let Some((u, p)) = user {
        cfg["transport"] = json!({"auth": {"usrpwd": {"user": u, "password": p}}});
    }
    zenoh::Config::from_json5(&cfg.to_string()).unwrap()
}

/// A client-mode session to the router on `port` (panics if it cannot open).
pub async fn session(port: u16, user: Option<(&str, &str)>) -> zenoh::Session {
    t(zenoh::open(client_config(port, user)))
        .await
        .expect("opening a zenoh session")
}

/// Waits until `server_id` answers `info` through `c`'s session (the server process running).
pub async fn wait_server(c: &sim_server::server::client::Client, p: &mut Proc) {
    t(async {
        loop {
            if c.info().await.is_ok() {
                break;
            }
            p.assert_running();
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
}
