//! Server configuration: a JSON5 file (see `deploy/server.json5`) plus `--cfg KEY:VALUE`
//! overrides in the style of the zenoh examples. `KEY` is a `/`-separated path into the
//! configuration (`capacity`, `zenoh/mode`, `zenoh/connect/endpoints`), `VALUE` is JSON5
//! (`64`, `"client"`, `["tcp/10.0.0.1:7447"]`); a value that is not valid JSON5 is taken as a
//! string (`--cfg prefix:lab/run3`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::Deserialize;
use serde_json::{json, Map, Value};

use super::core::Limits;
use super::pools::PoolEntry;

/// Default zenoh listen endpoint of a peer or router server.
pub const DEFAULT_LISTEN: &str = "tcp/127.0.0.1:7447";

/// Sets zenoh's `scouting/multicast/enabled` to false where a configuration leaves it out:
/// every sharedspace process (server, router) finds its peers by configured endpoints, not by
/// multicast, unless asked to.
pub fn multicast_scouting_off_unless_set(zenoh: &mut Map<String, Value>) {
    let scouting = zenoh
        .entry("scouting")
        .or_insert_with(|| Value::Object(Map::new()));
    if let Some(s) = scouting.as_object_mut() {
        let multicast = s
            .entry("multicast")
            .or_insert_with(|| Value::Object(Map::new()));
        if let Some(m) = multicast.as_object_mut() {
            m.entry("enabled").or_insert(json!(false));
        }
    }
}

/// Everything the server needs to start.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ServerConfig {
    /// Key-expression prefix (default `sharedspace`).
    pub prefix: String,
    /// Server id (a key segment); default `{hostname}-{pid}-{random}`.
    pub server_id: Option<String>,
    /// Maximum simultaneously open envs.
    pub capacity: u32,
    /// Maximum simultaneously open envs of one trainer (client id); absent = `capacity`.
    pub max_envs_per_trainer: Option<u32>,
    /// Maximum `CreateEnv.count` and `BatchStep` K.
    pub max_batch: u32,
    /// Maximum `CreateEnv.max_agents` (observation nodes).
    pub max_agents: u32,
    /// Largest request payload in bytes; larger ones are refused before decoding.
    pub max_request_bytes: u64,
    /// Seconds the envs of a trainer without a liveliness token survive.
    pub trainer_grace_s: f64,
    /// Seconds the envs of a trainer whose token disappeared wait for it to reconnect
    /// (0 = reaped at once). A silent link is noticed after zenoh's lease
    /// (`zenoh/transport/link/tx/lease`, ms, default 10 000).
    pub reconnect_grace_s: f64,
    /// Scenario pools: files (scenarios/FORMAT.md) or `embedded:hbs-paper` /
    /// `embedded:hbs-general`, each as its path or as `{path, variations, vehicle_model}` (the
    /// scene variations and the vehicle model, `replay` | `idm`, of every env on that pool that
    /// sends none of its own); empty = both embedded pools. The first pool is the default.
    pub pools: Vec<PoolEntry>,
    /// World-parameter file (JSON5, docs/PARAMETERS.md); absent = defaults.
    pub params: Option<PathBuf>,
    /// Most threads one `BatchStep` of at least 64 envs is stepped on; 0 (default) = one per
    /// available core.
    pub batch_threads: u32,
    /// Most `BatchStep`s stepped at once; when more wait, the next turn goes to the trainer
    /// served the fewest env-steps (fair share). 0 (default) = one per batch thread.
    pub batch_slots: u32,
    /// Seconds between returns of the allocator's free memory to the system (glibc
    /// `malloc_trim`); 0 = never. Without it, memory freed by the many threads' arenas stays
    /// in the process (docs/BENCHMARKS.md, soak). Default 10. A no-op with jemalloc (the
    /// default build), which returns free pages by itself; used by `--features glibc`.
    pub memory_trim_s: f64,
    /// Most glibc malloc arenas the process keeps (`M_ARENA_MAX`, set by `sim-server serve`
    /// before its threads start); 0 = glibc's own limit (8 per core). Every thread that
    /// allocates, the batch threads included, otherwise gets its own arena, and memory freed
    /// in one stays fragmented there (docs/BENCHMARKS.md section 6, the soak). Default 2.
    /// Only a `--features glibc` build has these arenas.
    pub malloc_arenas: u32,
    /// Passed to `zenoh::Config::from_json5` after filling defaults: mode `peer`, listening on
    /// `tcp/127.0.0.1:7447` (peer and router), multicast scouting off.
    pub zenoh: Value,
}

impl Default for ServerConfig {
    fn default() -> Self {
        let l = Limits::default();
        Self {
            prefix: protocol::DEFAULT_PREFIX.to_string(),
            server_id: None,
            capacity: l.capacity,
            max_envs_per_trainer: None,
            max_batch: l.max_batch,
            max_agents: l.max_agents,
            max_request_bytes: l.max_request_bytes as u64,
            trainer_grace_s: l.trainer_grace.as_secs_f64(),
            reconnect_grace_s: l.reconnect_grace.as_secs_f64(),
            pools: Vec::new(),
            params: None,
            batch_threads: 0,
            batch_slots: 0,
            memory_trim_s: 10.0,
            malloc_arenas: 2,
            zenoh: Value::Object(Map::new()),
        }
    }
}

/// A configuration problem.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("reading config {path}: {source}")]
    Read {
        path: String,
        source: std::io::Error,
    },
    #[error("config {origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("--cfg {arg:?}: {message}")]
    Override { arg: String, message: String },
    #[error("config: {0}")]
    Invalid(String),
}

/// The first top-level key of `root` whose value alone does not deserialize (serde_json's
/// type errors, such as a negative count, do not say which field they are about).
fn offending_key(root: &Value) -> Option<&str> {
    root.as_object()?.iter().find_map(|(key, value)| {
        let alone = Value::Object(Map::from_iter([(key.clone(), value.clone())]));
        serde_json::from_value::<ServerConfig>(alone)
            .is_err()
            .then_some(key.as_str())
    })
}

fn set_path(root: &mut Value, path: &str, value: Value) -> Result<(), String> {
    let parts: Vec<&str> = path.split('/').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err("empty key segment".into());
    }
    let mut cur = root;
    for (i, p) in parts.iter().enumerate() {
        if !cur.is_object() {
            *cur = Value::Object(Map::new());
        }
        let obj = cur.as_object_mut().expect("object");
        if i + 1 == parts.len() {
            obj.insert((*p).to_string(), value);
            return Ok(());
        }
        cur = obj
            .entry((*p).to_string())
            .or_insert_with(|| Value::Object(Map::new()));
    }
    Ok(())
}

/// Parses JSON5 text (empty text = `{}`) into a JSON object and applies `KEY:VALUE` overrides
/// (`KEY` a `/`-separated path, `VALUE` JSON5 or else a string). Shared by `serve` and `router`.
pub fn json5_with_overrides(
    text: &str,
    origin: &str,
    overrides: &[String],
) -> Result<Value, ConfigError> {
    let mut root: Value = if text.trim().is_empty() {
        Value::Object(Map::new())
    } else {
        json5::from_str(text).map_err(|e| ConfigError::Parse {
            origin: origin.to_string(),
            message: e.to_string(),
        })?
    };
    if !root.is_object() {
        return Err(ConfigError::Parse {
            origin: origin.to_string(),
            message: "the top level must be an object".into(),
        });
    }
    for arg in overrides {
        let (key, raw) = arg.split_once(':').ok_or_else(|| ConfigError::Override {
            arg: arg.clone(),
            message: "expected KEY:VALUE".into(),
        })?;
        let value: Value = json5::from_str(raw).unwrap_or_else(|_| Value::String(raw.to_string()));
        set_path(&mut root, key.trim(), value).map_err(|message| ConfigError::Override {
            arg: arg.clone(),
            message,
        })?;
    }
    Ok(root)
}

/// Reads a JSON5 file (or `{}` when `path` is `None`) and applies `KEY:VALUE` overrides.
pub fn load_json5_with_overrides(
    path: Option<&Path>,
    overrides: &[String],
) -> Result<Value, ConfigError> {
    match path {
        None => json5_with_overrides("", "(defaults)", overrides),
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                path: p.display().to_string(),
                source,
            })?;
            json5_with_overrides(&text, &p.display().to_string(), overrides)
        }
    }
}

impl ServerConfig {
    /// Parses JSON5 text and applies `KEY:VALUE` overrides.
    pub fn from_json5_with(
        text: &str,
        origin: &str,
        overrides: &[String],
    ) -> Result<Self, ConfigError> {
        let root = json5_with_overrides(text, origin, overrides)?;
        let cfg: ServerConfig =
            serde_json::from_value(root.clone()).map_err(|e| ConfigError::Parse {
                origin: origin.to_string(),
                message: match offending_key(&root) {
                    Some(key) => format!("{key}: {e}"),
                    None => e.to_string(),
                },
            })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Reads a config file (or the defaults when `path` is `None`) and applies overrides.
    pub fn load(path: Option<&Path>, overrides: &[String]) -> Result<Self, ConfigError> {
        match path {
            None => Self::from_json5_with("", "(defaults)", overrides),
            Some(p) => {
                let text = std::fs::read_to_string(p).map_err(|source| ConfigError::Read {
                    path: p.display().to_string(),
                    source,
                })?;
                Self::from_json5_with(&text, &p.display().to_string(), overrides)
            }
        }
    }

    fn validate(&self) -> Result<(), ConfigError> {
        protocol::KeySpace::new(self.prefix.clone())
            .map_err(|e| ConfigError::Invalid(format!("prefix: {e}")))?;
        if let Some(id) = &self.server_id {
            protocol::keys::validate_server_id(id)
                .map_err(|e| ConfigError::Invalid(e.to_string()))?;
        }
        if self.capacity == 0 || self.max_batch == 0 || self.max_agents == 0 {
            return Err(ConfigError::Invalid(
                "capacity, max_batch and max_agents must be >= 1".into(),
            ));
        }
        if self.max_envs_per_trainer == Some(0) || self.max_request_bytes == 0 {
            return Err(ConfigError::Invalid(
                "max_envs_per_trainer and max_request_bytes must be >= 1".into(),
            ));
        }
        if !(self.trainer_grace_s.is_finite() && self.trainer_grace_s >= 0.0) {
            return Err(ConfigError::Invalid(
                "trainer_grace_s must be finite and >= 0".into(),
            ));
        }
        if !(self.reconnect_grace_s.is_finite() && self.reconnect_grace_s >= 0.0) {
            return Err(ConfigError::Invalid(
                "reconnect_grace_s must be finite and >= 0".into(),
            ));
        }
        if !(self.memory_trim_s.is_finite() && self.memory_trim_s >= 0.0) {
            return Err(ConfigError::Invalid(
                "memory_trim_s must be finite and >= 0".into(),
            ));
        }
        if !self.zenoh.is_object() {
            return Err(ConfigError::Invalid("zenoh must be an object".into()));
        }
        Ok(())
    }

    /// The server limits.
    pub fn limits(&self) -> Limits {
        Limits {
            capacity: self.capacity,
            max_envs_per_trainer: self.max_envs_per_trainer.unwrap_or(self.capacity),
            max_batch: self.max_batch,
            max_agents: self.max_agents,
            max_request_bytes: usize::try_from(self.max_request_bytes).unwrap_or(usize::MAX),
            trainer_grace: Duration::from_secs_f64(self.trainer_grace_s),
            reconnect_grace: Duration::from_secs_f64(self.reconnect_grace_s),
            batch_slots: self.batch_slots,
        }
    }

    /// Threads a large batch is stepped on: `batch_threads`, or one per core when it is 0.
    pub fn batch_threads(&self) -> usize {
        match self.batch_threads {
            0 => super::core::default_batch_threads(),
            n => n as usize,
        }
    }

    /// The zenoh section with defaults filled in, as JSON text for `zenoh::Config::from_json5`.
    pub fn zenoh_json(&self) -> String {
        let mut z = self.zenoh.clone();
        let obj = z.as_object_mut().expect("validated object");
        let mode = obj
            .entry("mode")
            .or_insert_with(|| json!("peer"))
            .as_str()
            .unwrap_or("peer")
            .to_string();
        if mode != "client" && !obj.contains_key("listen") {
            obj.insert("listen".into(), json!({"endpoints": [DEFAULT_LISTEN]}));
        }
        multicast_scouting_off_unless_set(obj);
        z.to_string()
    }

    /// Where the server's session is reached, for a person reading its log: `listen ...` (the
    /// endpoints it listens on) and `connect ...` (a router or peers it joins), as configured.
    pub fn endpoints_line(&self) -> String {
        let z: Value = serde_json::from_str(&self.zenoh_json()).unwrap_or_default();
        let list = |side: &str| -> Vec<String> {
            z[side]["endpoints"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|e| e.as_str().map(String::from))
                        .collect()
                })
                .unwrap_or_default()
        };
        let mut parts = Vec::new();
        for side in ["listen", "connect"] {
            let endpoints = list(side);
            if !endpoints.is_empty() {
                parts.push(format!("{side} {}", endpoints.join(",")));
            }
        }
        parts.join("; ")
    }

    /// The configured server id or a fresh `{host}-{pid}-{random}` one.
    pub fn server_id_or_random(&self) -> String {
        if let Some(id) = &self.server_id {
            return id.clone();
        }
        let host = std::env::var("HOSTNAME").unwrap_or_else(|_| "sim".into());
        let host: String = host
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
            .take(32)
            .collect();
        let host = if host.is_empty() { "sim".into() } else { host };
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        let mut rng = scenarios::synthetic::SplitMix64::new(nanos ^ u64::from(std::process::id()));
        format!(
            "{host}-{}-{:06x}",
            std::process::id(),
            rng.next_u64() & 0xff_ffff
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_and_overrides() {
        let c = ServerConfig::load(None, &[]).unwrap();
        assert_eq!(c, ServerConfig::default());
        let z: Value = serde_json::from_str(&c.zenoh_json()).unwrap();
        assert_eq!(z["mode"], "peer");
        assert_eq!(z["listen"]["endpoints"][0], DEFAULT_LISTEN);
        assert_eq!(z["scouting"]["multicast"]["enabled"], false);

        let c = ServerConfig::from_json5_with(
            "{capacity: 8, // comment\n zenoh: {mode: 'client'}}",
            "t",
            &[
                "max_batch:4".into(),
                "zenoh/connect/endpoints:[\"tcp/127.0.0.1:7000\"]".into(),
                "prefix:lab/run3".into(),
                "batch_threads:3".into(),
            ],
        )
        .unwrap();
        assert_eq!(c.batch_threads(), 3);
        assert_eq!(c.capacity, 8);
        assert_eq!(c.max_batch, 4);
        assert_eq!(c.prefix, "lab/run3");
        let z: Value = serde_json::from_str(&c.zenoh_json()).unwrap();
        assert_eq!(z["mode"], "client");
        assert!(z.get("listen").is_none());
        assert_eq!(z["connect"]["endpoints"][0], "tcp/127.0.0.1:7000");
        zenoh::Config::from_json5(&c.zenoh_json()).unwrap();
    }

    #[test]
    fn deploy_file_is_the_defaults() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/server.json5");
        let c = ServerConfig::load(Some(&path), &[]).unwrap();
        let d = ServerConfig::default();
        assert_eq!(
            (c.capacity, c.max_batch, c.max_agents, c.batch_threads),
            (d.capacity, d.max_batch, d.max_agents, d.batch_threads)
        );
        assert_eq!(c.zenoh_json(), d.zenoh_json());
        assert_eq!(c.memory_trim_s, d.memory_trim_s);
        assert_eq!(c.malloc_arenas, d.malloc_arenas);
    }

    #[test]
    fn errors_are_named() {
        let e = ServerConfig::from_json5_with("{capcity: 3}", "f.json5", &[]).unwrap_err();
        assert!(e.to_string().contains("capcity"), "{e}");
        for (setting, named) in [
            ("capacity", "KEY:VALUE"),
            ("capacity:0", "capacity"),
            ("capacity:-1", "capacity"),
            ("batch_threads:-1", "batch_threads"),
            ("memory_trim_s:-1", "memory_trim_s"),
            ("malloc_arenas:-2", "malloc_arenas"),
            ("prefix:a//b", "prefix"),
        ] {
            let e = ServerConfig::load(None, &[setting.into()]).unwrap_err();
            assert!(e.to_string().contains(named), "--cfg {setting}: {e}");
        }
    }
}
