//! The model's equations (docs/MODEL.md), one implementation each, free of the world's state:
//! the world's stages ([`crate::world`]) gather their inputs and call them. They stand on
//! [`crate::geometry`] (footprints and clearance) and [`crate::params`].

pub mod cognition;
pub mod fault;
pub mod pedestrian;
pub mod risk;
pub mod traffic;
pub mod vehicle;
