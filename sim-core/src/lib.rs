//! `sim-core`: the pure simulation pipeline of sharedspace.
//!
//! Everything here is deterministic and free of I/O, async, wall clocks and global random state:
//! the world advances only when [`world::World::step`] is called with the actions for that step.
//! The equations and every decision the paper leaves open are in `shared/spec/model.md`; each
//! module names the section it implements.

#![deny(unsafe_op_in_unsafe_fn)]

pub mod cognition;
pub mod fastmath;
pub mod geometry;
pub mod grid;
pub mod helpers;
pub mod metrics;
pub mod observation;
pub mod params;
pub mod pedestrian;
pub mod pedeval;
pub mod risk;
pub mod rng;
pub mod scenario;
pub mod traffic;
pub mod variation;
pub mod vehicle;
pub mod world;

pub use geometry::{Shape, Vec2};
pub use params::{PedestrianModel, VehicleModel, WorldParams};
pub use scenario::{AgentKind, Scenario, ScenarioPool, Split};
pub use world::{AgentId, EpisodeConfig, StepError, StepOutcome, StepScratch, World, WorldError};
