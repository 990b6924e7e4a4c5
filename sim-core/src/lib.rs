//! `sim-core`: the pure simulation pipeline of sharedspace.
//!
//! Everything here is deterministic and free of I/O, async, wall clocks and global random state:
//! the world advances only when [`world::World::step`] is called with the actions for that step.
//! The equations and every decision the paper leaves open are in docs/MODEL.md; each module names
//! the section it implements.
//!
//! - [`geometry`]: footprints (discs, oriented rectangles) and clearance, what everything stands
//!   on;
//! - [`model`]: the equations, one implementation each (cognition, risk, pedestrian forces,
//!   vehicle kinematics, traffic);
//! - [`world`]: the world's state and its step, stage by stage, calling the equations, and the
//!   learner's observation of it;
//! - [`params`], [`scenario`], [`variation`]: what a world is built from;
//! - [`metrics`], [`pedeval`]: episode metrics and the pedestrian-model evaluation;
//! - [`support`]: neighbour grid, random generator, fast math, helper threads.

#![deny(unsafe_op_in_unsafe_fn)]

pub mod geometry;
pub mod metrics;
pub mod model;
pub mod params;
pub mod pedeval;
pub mod scenario;
pub mod support;
pub mod variation;
pub mod world;

pub use geometry::{Shape, Vec2};
pub use params::{PedestrianModel, VehicleModel, WorldParams};
pub use scenario::{AgentKind, Scenario, ScenarioPool, Split};
pub use world::{AgentId, EpisodeConfig, StepError, StepOutcome, StepScratch, World, WorldError};
