//! sharedspace server crate: the zenoh simulation server and the command-line tools built on the
//! pure `sim-core` pipeline.

pub mod params_file;
pub mod pedeval_cmd;
pub mod rollout;
pub mod router;
pub mod server;
pub mod step_timing;
