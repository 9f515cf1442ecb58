//! Numerics that know residual vectors and points, not arms: the bounded robust least-squares
//! solver and rigid-body geometry.

pub mod geometry;
pub mod solver;
