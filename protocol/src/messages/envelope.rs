//! The reply envelope: `{ok: true, result}` or `{ok: false, error}` ([`Reply`], [`ErrorReply`]).

use std::fmt;

use serde::de::{self, DeserializeOwned, Deserializer, MapAccess, Visitor};
use serde::ser::{SerializeMap, Serializer};
use serde::{Deserialize, Serialize};

use super::ErrorCode;

/// An error reply: `{"code": ErrorCode, "message": str, "env_id": str | nil}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorReply {
    /// Machine-readable code.
    pub code: ErrorCode,
    /// Human-readable explanation (names the offending field / env / value).
    pub message: String,
    /// The env concerned, when there is one (always set for batch errors about one env).
    #[serde(default)]
    pub env_id: Option<String>,
}

impl ErrorReply {
    /// An error without env.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Self {
            code,
            message: message.into(),
            env_id: None,
        }
    }

    /// Sets the env concerned.
    pub fn with_env(mut self, env_id: impl Into<String>) -> Self {
        self.env_id = Some(env_id.into());
        self
    }
}

impl fmt::Display for ErrorReply {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.env_id {
            Some(env) => write!(f, "{} (env {env}): {}", self.code, self.message),
            None => write!(f, "{}: {}", self.code, self.message),
        }
    }
}

impl std::error::Error for ErrorReply {}

impl From<crate::ProtocolError> for ErrorReply {
    fn from(e: crate::ProtocolError) -> Self {
        let code = match &e {
            crate::ProtocolError::VersionMismatch { .. } => ErrorCode::VersionMismatch,
            crate::ProtocolError::Array(_) => ErrorCode::WrongShape,
            crate::ProtocolError::Encode { .. } => ErrorCode::Internal,
            _ => ErrorCode::BadRequest,
        };
        ErrorReply::new(code, e.to_string())
    }
}

/// The reply to every query: a map with exactly one key, `"ok"` (the result) or `"error"`
/// (an [`ErrorReply`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Reply<T> {
    /// `{"ok": T}`
    Ok(T),
    /// `{"error": ErrorReply}`
    Err(ErrorReply),
}

impl<T> Reply<T> {
    /// Converts into a `Result`.
    pub fn into_result(self) -> Result<T, ErrorReply> {
        match self {
            Reply::Ok(v) => Ok(v),
            Reply::Err(e) => Err(e),
        }
    }

    /// An error reply.
    pub fn error(code: ErrorCode, message: impl Into<String>) -> Self {
        Reply::Err(ErrorReply::new(code, message))
    }
}

impl<T> From<Result<T, ErrorReply>> for Reply<T> {
    fn from(r: Result<T, ErrorReply>) -> Self {
        match r {
            Ok(v) => Reply::Ok(v),
            Err(e) => Reply::Err(e),
        }
    }
}

impl<T: Serialize> Serialize for Reply<T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut m = serializer.serialize_map(Some(1))?;
        match self {
            Reply::Ok(v) => m.serialize_entry("ok", v)?,
            Reply::Err(e) => m.serialize_entry("error", e)?,
        }
        m.end()
    }
}

impl<'de, T: DeserializeOwned> Deserialize<'de> for Reply<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct V<T>(std::marker::PhantomData<T>);
        impl<'de, T: DeserializeOwned> Visitor<'de> for V<T> {
            type Value = Reply<T>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a reply map with exactly one of the keys \"ok\" or \"error\"")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Reply<T>, A::Error> {
                let mut out: Option<Reply<T>> = None;
                while let Some(key) = map.next_key::<String>()? {
                    let value = match key.as_str() {
                        "ok" => Reply::Ok(map.next_value::<T>()?),
                        "error" => Reply::Err(map.next_value::<ErrorReply>()?),
                        _ => {
                            map.next_value::<de::IgnoredAny>()?;
                            continue;
                        }
                    };
                    if out.is_some() {
                        return Err(de::Error::custom(
                            "reply has both/duplicate \"ok\" and \"error\" keys",
                        ));
                    }
                    out = Some(value);
                }
                out.ok_or_else(|| de::Error::custom("reply has neither \"ok\" nor \"error\" key"))
            }
        }
        deserializer.deserialize_map(V(std::marker::PhantomData))
    }
}
