//! Support code the equations and the world run on, with no model in it: neighbour search,
//! the random generator, fast math and helper threads.

pub mod fastmath;
pub mod grid;
pub mod rng;
pub mod threads;
