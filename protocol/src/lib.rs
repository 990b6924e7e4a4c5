//! The sharedspace wire protocol: Zenoh key expressions, message types and the MessagePack
//! codec shared by the simulation server and its clients.
//!
//! Pure crate: no networking. `SPEC.md` (next to this crate's `Cargo.toml`) is the normative
//! description for implementers in other languages.
//!
//! * [`keys`]: key-expression builders and parsers ([`KeySpace`]).
//! * [`messages`]: requests, replies ([`Reply`] envelope, [`ErrorCode`]), publications.
//! * [`mod@array`]: binary n-d arrays ([`F32Array`], [`F64Array`], [`U32Array`], [`U64Array`],
//!   [`U8Array`],
//!   [`FloatArray`]).
//! * [`codec`]: [`encode`] / [`decode`] (named-map MessagePack).
//! * `samples` (feature `samples`, on in this crate's tests): the fixed example values behind
//!   the golden files in `tests/golden/`.
//! * [`wire`]: the batch-step reply as borrowed views of [`BatchStepResult`] (its arrays are
//!   [`ArrayView`]s of the server's step buffers; same bytes as [`encode`] of the owned result).

pub mod array;
pub mod codec;
pub mod error;
pub mod keys;
pub mod messages;
#[cfg(any(test, feature = "samples"))]
pub mod samples;
pub mod wire;

/// The protocol version. Bumped on every incompatible change (see `SPEC.md`, "Versioning").
pub const PROTOCOL_VERSION: u32 = 2;

pub use array::{
    ArrayError, ArrayView, Element, F32Array, F64Array, FloatArray, NdArray, U32Array, U64Array,
    U8Array,
};
pub use codec::{decode, decode_or_default, encode, try_encode};
pub use error::ProtocolError;
pub use keys::{EnvOp, EnvTopic, KeySpace, DEFAULT_PREFIX};
pub use messages::*;
