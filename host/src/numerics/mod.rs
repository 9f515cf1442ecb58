//! Numerics that know residual vectors and points, not arms: the bounded robust least-squares
//! solver, rigid-body geometry and small statistics.

pub mod geometry;
pub mod normal;
pub mod qr;
pub mod solver;
pub mod stats;
