//! Numerics that know residual vectors and points, not arms: the bounded robust least-squares
//! solver, rigid-body geometry, small statistics, the held-out test's significance and the time
//! delay between two streams.

pub mod delay;
pub mod geometry;
pub mod normal;
pub mod qr;
pub mod significance;
pub mod solver;
pub mod stats;
