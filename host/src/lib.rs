//! kincal host library: calibrate tracker arms from artefact touches.
//!
//! The model (parameters, kinematics, effects) is kept apart from the solver and from the
//! reports: [`model`] knows geometry, [`solver`] knows residual vectors and bounds,
//! [`calibrate`] joins them, [`report`] reads results and never recomputes them.

pub mod bench;
pub mod calibrate;
pub mod data;
pub mod device;
pub mod diagnose;
pub mod effects;
pub mod emulator;
pub mod fsutil;
pub mod geometry;
pub mod haptic;
pub mod identify;
pub mod link;
pub mod model;
pub mod objective;
pub mod outliers;
pub mod record;
pub mod report;
pub mod run;
pub mod simulate;
pub mod solver;
pub mod study;
pub mod svg;
pub mod validate;
pub mod workflow;
