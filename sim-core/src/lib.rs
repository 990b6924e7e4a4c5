//! `sim-core`: the pure simulation pipeline of sharedspace.
//!
//! Everything here is deterministic and free of I/O, async, wall clocks and global random state:
//! the world advances only when [`world::World::step`] is called with the actions for that step.
//! The equations and every decision the paper leaves open are in `shared/spec/model.md`; each
//! module names the section it implements.

pub mod geometry;
pub mod scenario;
