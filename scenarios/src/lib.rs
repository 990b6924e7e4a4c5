//! Scenario pools for the shared-space simulator (model.md sections 1, 7 and 8).
//!
//! - [`hbs`]: parse the HBS shared-space CSV and extract the paper-like pool (`hbs-paper`: one
//!   car and three interacting pedestrians) and the general pool (`hbs-general`: every
//!   pedestrian and car in the car's window), deterministically.
//! - [`pool`]: the versioned scenario file format (a [`sim_core::scenario::ScenarioPool`] as
//!   JSON, see `FORMAT.md`) with a validating loader whose errors name file, scenario, agent and
//!   field.
//! - [`synthetic`]: seeded synthetic scenarios (`crossing`, `counter_flow`, `random`) of any size.
//! - [`composed`]: seeded scenes composed from the recorded parts of a pool's train scenes.
//! - [`embedded`]: the paper-like pool compiled into the binary.
//! - [`footprint`]: the agents' footprints and the overlap checks shared by all of the above.

pub mod composed;
pub mod embedded;
pub mod footprint;
pub mod hbs;
pub mod pool;
pub mod synthetic;

pub use embedded::default_pool;
pub use pool::{load_pool, load_pool_file, save_pool, validate_pool, OverlapCheck, PoolError};
