//! Numerics that know residual vectors and points, not arms: the bounded robust least-squares
//! solver, rigid-body geometry, small statistics and the held-out test's significance.

pub mod geometry;
pub mod significance;
pub mod solver;
pub mod stats;
