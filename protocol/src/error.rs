//! Errors of this crate.

use crate::array::ArrayError;

/// Everything that can go wrong encoding, decoding or building protocol values.
#[derive(Debug, thiserror::Error)]
pub enum ProtocolError {
    /// The bytes are not a valid MessagePack encoding of the expected message type.
    #[error("cannot decode {expected}: {}{source}", if path.is_empty() || path == "." { String::new() } else { format!("{path}: ") })]
    Decode {
        /// The message type that was expected (short Rust type name).
        expected: String,
        /// Where in the message the error is (`variations.start_offset_steps`; `.` at the top).
        path: String,
        /// The MessagePack / serde error text.
        #[source]
        source: rmp_serde::decode::Error,
    },
    /// A valid message was followed by extra bytes.
    #[error("cannot decode {expected}: {count} trailing bytes after the message")]
    TrailingBytes {
        /// The message type that was expected.
        expected: String,
        /// How many bytes were left over.
        count: usize,
    },
    /// Encoding failed (should not happen for this crate's types).
    #[error("cannot encode {what}: {source}")]
    Encode {
        /// The message type being encoded.
        what: String,
        /// The MessagePack / serde error.
        #[source]
        source: rmp_serde::encode::Error,
    },
    /// A key-expression segment (prefix part, server id, env id, agent name, client id) is invalid.
    #[error("invalid {what} {segment:?}: {reason}")]
    InvalidKeySegment {
        /// What the segment is (e.g. "env id").
        what: &'static str,
        /// The offending value.
        segment: String,
        /// Why it is invalid.
        reason: &'static str,
    },
    /// An array did not have the length, shape or dtype required.
    #[error(transparent)]
    Array(#[from] ArrayError),
    /// The peer speaks another protocol version.
    #[error("protocol version mismatch: expected {expected}, got {got}")]
    VersionMismatch {
        /// This crate's [`crate::PROTOCOL_VERSION`].
        expected: u32,
        /// The version the peer sent.
        got: u32,
    },
}
