//! Zenoh key expressions, all under a configurable prefix (default [`DEFAULT_PREFIX`]).
//!
//! | key | kind | payload |
//! | --- | --- | --- |
//! | `{p}/server/{server_id}/info` | queryable | `InfoRequest` → `Reply<ServerInfo>` |
//! | `{p}/server/{server_id}/env/create` | queryable | `CreateEnv` → `Reply<EnvCreated>` |
//! | `{p}/server/{server_id}/env/{env_id}/reset` | queryable | `Reset` → `Reply<ResetResult>` |
//! | `{p}/server/{server_id}/env/{env_id}/step` | queryable | `Step` → `Reply<StepResult>` |
//! | `{p}/server/{server_id}/env/{env_id}/close` | queryable | `Close` → `Reply<Closed>` |
//! | `{p}/server/{server_id}/batch/step` | queryable | `BatchStep` → `Reply<BatchStepResult>` |
//! | `{p}/server/{server_id}/alive` | liveliness token | — |
//! | `{p}/env/{env_id}/states` | publication | `StatesMsg` |
//! | `{p}/env/{env_id}/uncertainty` | publication | `UncertaintyMsg` |
//! | `{p}/env/{env_id}/risk_graph` | publication | `RiskGraphMsg` |
//! | `{p}/env/{env_id}/events` | publication | `EventsMsg` |
//! | `{p}/env/{env_id}/result` | publication (realtime mode) | `StepResult` |
//! | `{p}/env/{env_id}/action/{agent_name}` | subscription (realtime mode) | `ActionMsg` |
//! | `{p}/trainer/{client_id}` | liveliness token | — |
//!
//! "create" is a reserved word: it can never be an env id (see [`validate_env_id`]).

use crate::error::ProtocolError;

/// The default key prefix.
pub const DEFAULT_PREFIX: &str = "sharedspace";

/// Characters that may not appear in a key segment.
pub const FORBIDDEN_SEGMENT_CHARS: &[char] = &['/', '*', '$', '?', '#'];

/// Env-id values that would collide with other keys under `server/{id}/env/`.
pub const RESERVED_ENV_IDS: &[&str] = &["create"];

/// Checks one key segment: non-empty, no `/ * $ ? #`, no ASCII control characters or spaces
/// at the ends, not `.`/`..`.
pub fn validate_segment(what: &'static str, segment: &str) -> Result<(), ProtocolError> {
    let err = |reason| {
        Err(ProtocolError::InvalidKeySegment {
            what,
            segment: segment.to_string(),
            reason,
        })
    };
    if segment.is_empty() {
        return err("empty");
    }
    if segment.contains(FORBIDDEN_SEGMENT_CHARS) {
        return err("contains one of / * $ ? #");
    }
    if segment.chars().any(char::is_control) {
        return err("contains a control character");
    }
    if segment.trim() != segment {
        return err("leading or trailing whitespace");
    }
    Ok(())
}

/// Checks a server id (one key segment).
pub fn validate_server_id(id: &str) -> Result<(), ProtocolError> {
    validate_segment("server id", id)
}

/// Checks an env id (one key segment, not a reserved word such as `create`).
pub fn validate_env_id(id: &str) -> Result<(), ProtocolError> {
    validate_segment("env id", id)?;
    if RESERVED_ENV_IDS.contains(&id) {
        return Err(ProtocolError::InvalidKeySegment {
            what: "env id",
            segment: id.to_string(),
            reason: "reserved word",
        });
    }
    Ok(())
}

/// Checks an agent name (one key segment).
pub fn validate_agent_name(name: &str) -> Result<(), ProtocolError> {
    validate_segment("agent name", name)
}

/// Checks a trainer client id (one key segment).
pub fn validate_client_id(id: &str) -> Result<(), ProtocolError> {
    validate_segment("client id", id)
}

/// The env id the server gives its `counter`-th env: `{server_id}-{counter}`.
pub fn make_env_id(server_id: &str, counter: u64) -> String {
    format!("{server_id}-{counter}")
}

/// A per-env operation under `{p}/server/{server_id}/env/{env_id}/{op}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EnvOp {
    /// `reset`
    Reset,
    /// `step`
    Step,
    /// `close`
    Close,
}

impl EnvOp {
    /// All operations.
    pub const ALL: [EnvOp; 3] = [EnvOp::Reset, EnvOp::Step, EnvOp::Close];

    /// The key segment.
    pub fn as_str(self) -> &'static str {
        match self {
            EnvOp::Reset => "reset",
            EnvOp::Step => "step",
            EnvOp::Close => "close",
        }
    }

    /// Parses a key segment.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|op| op.as_str() == s)
    }
}

/// A per-env publication under `{p}/env/{env_id}/{topic}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum EnvTopic {
    /// `states` (`StatesMsg`)
    States,
    /// `uncertainty` (`UncertaintyMsg`)
    Uncertainty,
    /// `risk_graph` (`RiskGraphMsg`)
    RiskGraph,
    /// `events` (`EventsMsg`)
    Events,
    /// `result` (`StepResult`, realtime mode only)
    Result,
}

impl EnvTopic {
    /// All topics.
    pub const ALL: [EnvTopic; 5] = [
        EnvTopic::States,
        EnvTopic::Uncertainty,
        EnvTopic::RiskGraph,
        EnvTopic::Events,
        EnvTopic::Result,
    ];

    /// The key segment.
    pub fn as_str(self) -> &'static str {
        match self {
            EnvTopic::States => "states",
            EnvTopic::Uncertainty => "uncertainty",
            EnvTopic::RiskGraph => "risk_graph",
            EnvTopic::Events => "events",
            EnvTopic::Result => "result",
        }
    }

    /// Parses a key segment.
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.as_str() == s)
    }
}

/// Builds and parses key expressions under one prefix.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct KeySpace {
    prefix: String,
}

impl Default for KeySpace {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.to_string(),
        }
    }
}

impl KeySpace {
    /// A key space under `prefix`, which may have several `/`-separated segments
    /// (each validated like any other segment; no leading/trailing `/`).
    pub fn new(prefix: impl Into<String>) -> Result<Self, ProtocolError> {
        let prefix = prefix.into();
        if prefix.is_empty() {
            return Err(ProtocolError::InvalidKeySegment {
                what: "key prefix",
                segment: prefix,
                reason: "empty",
            });
        }
        for seg in prefix.split('/') {
            validate_segment("key prefix segment", seg)?;
        }
        Ok(Self { prefix })
    }

    /// The prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    fn server(&self, server_id: &str) -> Result<String, ProtocolError> {
        validate_server_id(server_id)?;
        Ok(format!("{}/server/{server_id}", self.prefix))
    }

    /// `{p}/server/{server_id}/info` (queryable: `InfoRequest` → `Reply<ServerInfo>`).
    pub fn server_info(&self, server_id: &str) -> Result<String, ProtocolError> {
        Ok(format!("{}/info", self.server(server_id)?))
    }

    /// `{p}/server/*/info`: query it to discover every server.
    pub fn server_info_all(&self) -> String {
        format!("{}/server/*/info", self.prefix)
    }

    /// `{p}/server/{server_id}/env/create` (queryable: `CreateEnv` → `Reply<EnvCreated>`).
    pub fn env_create(&self, server_id: &str) -> Result<String, ProtocolError> {
        Ok(format!("{}/env/create", self.server(server_id)?))
    }

    /// `{p}/server/{server_id}/env/{env_id}/{op}`.
    pub fn env_op(
        &self,
        server_id: &str,
        env_id: &str,
        op: EnvOp,
    ) -> Result<String, ProtocolError> {
        validate_env_id(env_id)?;
        Ok(format!(
            "{}/env/{env_id}/{}",
            self.server(server_id)?,
            op.as_str()
        ))
    }

    /// `{p}/server/{server_id}/env/{env_id}/reset` (queryable: `Reset` → `Reply<ResetResult>`).
    pub fn env_reset(&self, server_id: &str, env_id: &str) -> Result<String, ProtocolError> {
        self.env_op(server_id, env_id, EnvOp::Reset)
    }

    /// `{p}/server/{server_id}/env/{env_id}/step` (queryable: `Step` → `Reply<StepResult>`).
    pub fn env_step(&self, server_id: &str, env_id: &str) -> Result<String, ProtocolError> {
        self.env_op(server_id, env_id, EnvOp::Step)
    }

    /// `{p}/server/{server_id}/env/{env_id}/close` (queryable: `Close` → `Reply<Closed>`).
    pub fn env_close(&self, server_id: &str, env_id: &str) -> Result<String, ProtocolError> {
        self.env_op(server_id, env_id, EnvOp::Close)
    }

    /// `{p}/server/{server_id}/env/*/{op}`: what the server declares its queryable on.
    pub fn env_op_wildcard(&self, server_id: &str, op: EnvOp) -> Result<String, ProtocolError> {
        Ok(format!("{}/env/*/{}", self.server(server_id)?, op.as_str()))
    }

    /// The rest of `key` after `{p}{section}`; `None` when it does not start so.
    fn section<'k>(&self, key: &'k str, section: &str) -> Option<&'k str> {
        key.strip_prefix(self.prefix.as_str())?
            .strip_prefix(section)
    }

    /// Parses `{p}/server/{server_id}/env/{env_id}/{op}` into `(env_id, op)`;
    /// `None` for any other key (including another server's).
    pub fn parse_env_op<'k>(&self, server_id: &str, key: &'k str) -> Option<(&'k str, EnvOp)> {
        let rest = self
            .section(key, "/server/")?
            .strip_prefix(server_id)?
            .strip_prefix("/env/")?;
        let (env_id, op) = rest.split_once('/')?;
        let op = EnvOp::parse(op)?;
        validate_env_id(env_id).ok()?;
        Some((env_id, op))
    }

    /// `{p}/server/{server_id}/batch/step` (queryable: `BatchStep` → `Reply<BatchStepResult>`).
    pub fn batch_step(&self, server_id: &str) -> Result<String, ProtocolError> {
        Ok(format!("{}/batch/step", self.server(server_id)?))
    }

    /// `{p}/server/{server_id}/alive` (the server's liveliness token).
    pub fn server_alive(&self, server_id: &str) -> Result<String, ProtocolError> {
        Ok(format!("{}/alive", self.server(server_id)?))
    }

    /// `{p}/server/*/alive`: liveliness subscription/query for every server.
    pub fn server_alive_all(&self) -> String {
        format!("{}/server/*/alive", self.prefix)
    }

    /// Parses `{p}/server/{server_id}/alive` into the server id.
    pub fn parse_server_alive<'k>(&self, key: &'k str) -> Option<&'k str> {
        let rest = self.section(key, "/server/")?;
        let id = rest.strip_suffix("/alive")?;
        validate_server_id(id).ok()?;
        Some(id)
    }

    /// `{p}/env/{env_id}/{topic}`.
    pub fn env_topic(&self, env_id: &str, topic: EnvTopic) -> Result<String, ProtocolError> {
        validate_env_id(env_id)?;
        Ok(format!("{}/env/{env_id}/{}", self.prefix, topic.as_str()))
    }

    /// `{p}/env/*/{topic}`: subscribe to one topic of every env.
    pub fn env_topic_all(&self, topic: EnvTopic) -> String {
        format!("{}/env/*/{}", self.prefix, topic.as_str())
    }

    /// Parses `{p}/env/{env_id}/{topic}` into `(env_id, topic)`.
    pub fn parse_env_topic<'k>(&self, key: &'k str) -> Option<(&'k str, EnvTopic)> {
        let rest = self.section(key, "/env/")?;
        let (env_id, topic) = rest.split_once('/')?;
        let topic = EnvTopic::parse(topic)?;
        validate_env_id(env_id).ok()?;
        Some((env_id, topic))
    }

    /// `{p}/env/{env_id}/states` (`StatesMsg`).
    pub fn env_states(&self, env_id: &str) -> Result<String, ProtocolError> {
        self.env_topic(env_id, EnvTopic::States)
    }

    /// `{p}/env/{env_id}/uncertainty` (`UncertaintyMsg`).
    pub fn env_uncertainty(&self, env_id: &str) -> Result<String, ProtocolError> {
        self.env_topic(env_id, EnvTopic::Uncertainty)
    }

    /// `{p}/env/{env_id}/risk_graph` (`RiskGraphMsg`).
    pub fn env_risk_graph(&self, env_id: &str) -> Result<String, ProtocolError> {
        self.env_topic(env_id, EnvTopic::RiskGraph)
    }

    /// `{p}/env/{env_id}/events` (`EventsMsg`).
    pub fn env_events(&self, env_id: &str) -> Result<String, ProtocolError> {
        self.env_topic(env_id, EnvTopic::Events)
    }

    /// `{p}/env/{env_id}/result` (`StepResult`, realtime mode).
    pub fn env_result(&self, env_id: &str) -> Result<String, ProtocolError> {
        self.env_topic(env_id, EnvTopic::Result)
    }

    /// `{p}/env/{env_id}/action/{agent_name}` (`ActionMsg`, realtime mode).
    pub fn env_action(&self, env_id: &str, agent_name: &str) -> Result<String, ProtocolError> {
        validate_env_id(env_id)?;
        validate_agent_name(agent_name)?;
        Ok(format!("{}/env/{env_id}/action/{agent_name}", self.prefix))
    }

    /// `{p}/env/{env_id}/action/*`: what a realtime env subscribes to.
    pub fn env_action_wildcard(&self, env_id: &str) -> Result<String, ProtocolError> {
        validate_env_id(env_id)?;
        Ok(format!("{}/env/{env_id}/action/*", self.prefix))
    }

    /// Parses `{p}/env/{env_id}/action/{agent_name}` into `(env_id, agent_name)`.
    pub fn parse_env_action<'k>(&self, key: &'k str) -> Option<(&'k str, &'k str)> {
        let rest = self.section(key, "/env/")?;
        let (env_id, rest) = rest.split_once('/')?;
        let agent = rest.strip_prefix("action/")?;
        validate_env_id(env_id).ok()?;
        validate_agent_name(agent).ok()?;
        Some((env_id, agent))
    }

    /// `{p}/trainer/{client_id}` (a trainer's liveliness token).
    pub fn trainer(&self, client_id: &str) -> Result<String, ProtocolError> {
        validate_client_id(client_id)?;
        Ok(format!("{}/trainer/{client_id}", self.prefix))
    }

    /// `{p}/trainer/*`: what the server's liveliness subscriber watches.
    pub fn trainer_all(&self) -> String {
        format!("{}/trainer/*", self.prefix)
    }

    /// Parses `{p}/trainer/{client_id}` into the client id.
    pub fn parse_trainer<'k>(&self, key: &'k str) -> Option<&'k str> {
        let id = self.section(key, "/trainer/")?;
        validate_client_id(id).ok()?;
        Some(id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builders() {
        let k = KeySpace::default();
        let (s, e) = ("s1", "s1-0");
        let built = [
            (k.server_info(s), "sharedspace/server/s1/info"),
            (k.env_create(s), "sharedspace/server/s1/env/create"),
            (k.env_reset(s, e), "sharedspace/server/s1/env/s1-0/reset"),
            (k.env_step(s, e), "sharedspace/server/s1/env/s1-0/step"),
            (k.env_close(s, e), "sharedspace/server/s1/env/s1-0/close"),
            (
                k.env_op_wildcard(s, EnvOp::Step),
                "sharedspace/server/s1/env/*/step",
            ),
            (k.batch_step(s), "sharedspace/server/s1/batch/step"),
            (k.server_alive(s), "sharedspace/server/s1/alive"),
            (k.env_states(e), "sharedspace/env/s1-0/states"),
            (k.env_uncertainty(e), "sharedspace/env/s1-0/uncertainty"),
            (k.env_risk_graph(e), "sharedspace/env/s1-0/risk_graph"),
            (k.env_events(e), "sharedspace/env/s1-0/events"),
            (k.env_result(e), "sharedspace/env/s1-0/result"),
            (
                k.env_action(e, "vehicle_0"),
                "sharedspace/env/s1-0/action/vehicle_0",
            ),
            (k.trainer("t-42"), "sharedspace/trainer/t-42"),
        ];
        for (got, want) in built {
            assert_eq!(got.unwrap(), want);
        }
        assert_eq!(k.trainer_all(), "sharedspace/trainer/*");
        assert_eq!(make_env_id("s1", 7), "s1-7");
    }

    #[test]
    fn custom_prefix() {
        let k = KeySpace::new("lab/a").unwrap();
        assert_eq!(k.server_info("x").unwrap(), "lab/a/server/x/info");
        for bad in ["", "/a", "a/", "a//b", "a/*", "a/$x", "**"] {
            assert!(KeySpace::new(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn segment_validation() {
        let k = KeySpace::default();
        for bad in ["", "a/b", "*", "a*", "$x", "a?b", "a#b", " a", "a\n"] {
            assert!(k.env_states(bad).is_err(), "{bad:?}");
            assert!(k.server_info(bad).is_err(), "{bad:?}");
            assert!(k.trainer(bad).is_err(), "{bad:?}");
            assert!(k.env_action("e", bad).is_err(), "{bad:?}");
        }
        assert!(k.env_step("s", "create").is_err());
        let e = k.env_states("a/b").unwrap_err().to_string();
        assert!(e.contains("env id") && e.contains("a/b"), "{e}");
    }

    #[test]
    fn parsing() {
        let k = KeySpace::default();
        assert_eq!(
            k.parse_env_op("s1", "sharedspace/server/s1/env/s1-3/step"),
            Some(("s1-3", EnvOp::Step))
        );
        assert_eq!(
            k.parse_env_op("s2", "sharedspace/server/s1/env/s1-3/step"),
            None
        );
        assert_eq!(
            k.parse_env_op("s1", "sharedspace/server/s1/env/create"),
            None
        );
        assert_eq!(
            k.parse_env_op("s1", "sharedspace/server/s1/env/a/b/step"),
            None
        );
        assert_eq!(
            k.parse_env_topic("sharedspace/env/s1-3/risk_graph"),
            Some(("s1-3", EnvTopic::RiskGraph))
        );
        assert_eq!(
            k.parse_env_action("sharedspace/env/s1-3/action/vehicle_0"),
            Some(("s1-3", "vehicle_0"))
        );
        assert_eq!(k.parse_env_action("sharedspace/env/s1-3/action/"), None);
        assert_eq!(k.parse_trainer("sharedspace/trainer/abc"), Some("abc"));
        assert_eq!(k.parse_trainer("sharedspace/trainer/a/b"), None);
        assert_eq!(
            k.parse_server_alive("sharedspace/server/s1/alive"),
            Some("s1")
        );
        assert_eq!(k.parse_server_alive("other/server/s1/alive"), None);
    }
}
