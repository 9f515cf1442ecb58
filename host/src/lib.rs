//! kincal host library: calibrate tracker arms from artefact touches, and PHANToM haptic devices.
//!
//! Layers, lowest first; a module may use only modules of its own or a lower layer (checked by
//! `host/tests/layers.rs`):
//!
//! | layer | modules | what it knows |
//! | --- | --- | --- |
//! | 0 | [`files`], [`numerics`], [`trace`] | the user's files and their errors; solvers, geometry, statistics, no arms; arm identities and file hashes |
//! | 1 | [`model`] (with its [`model::effects`]) | the arm's geometry and effects |
//! | 2 | [`data`] | artefact and sessions |
//! | 3 | [`simulate`] | an independent forward path that makes data with known truth |
//! | 4 | [`calib`], [`haptic`] | calibration, validation, diagnosis, study; the haptic pipeline |
//! | 5 | [`report`] | HTML pages and plots that read results, never recompute them |
//! | 6 | [`output`] | the folders kincal writes (RUN/, diagnosis, study, simulated data, haptic) |
//! | 7 | [`controller`] | the link to the arm's controller, recording, upload, the emulated demo |
//!
//! The CLI (`src/bin/kincal/`) parses arguments, calls these and prints.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod calib;
pub mod controller;
pub mod data;
pub mod files;
pub mod haptic;
pub mod model;
pub mod numerics;
pub mod output;

pub mod report;
pub mod simulate;
pub mod trace;
