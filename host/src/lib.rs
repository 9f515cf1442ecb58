//! kincal host library: calibrate serial arms from artefact touches and tracker measurements (one
//! engine for every kind), and PHANToM haptic devices.
//!
//! Layers, lowest first; a module may use only modules of its own or a lower layer (checked by
//! `host/tests/layers.rs`):
//!
//! | layer | modules | what it knows |
//! | --- | --- | --- |
//! | 0 | [`files`], [`numerics`], [`igtl`] | the user's files and their errors; solvers, geometry, statistics, stream delays, no arms; the OpenIGTLink wire format |
//! | 1 | [`trace`] | arm identities and the hashes of the files a result came from |
//! | 2 | [`model`] (with its [`model::effects`]) | the arm's geometry and effects |
//! | 3 | [`data`] | observations of every kind, in blocks, and their readers |
//! | 4 | [`simulate`] | an independent forward path that makes data with known truth |
//! | 5 | [`calib`], [`haptic`], [`motion`] | the engine (terms, block unknowns, problem, fit, validation, floor), then what is built on it (the diagnosis, outliers, study, plan), then the run (three floors inside `calib`, checked too); the haptic pipeline; the arm in motion and its dynamic validation |
//! | 6 | [`report`] | HTML pages and plots that read results, never recompute them |
//! | 7 | [`store`] | the folders kincal writes and reads back (RUN/ of every version, diagnosis, study, simulated data, haptic, dynamic validation) |
//! | 8 | [`api`] | the facade the CLI and tests call: load, calibrate, validate, diagnose, auto, plan, compare |
//! | 9 | [`controller`] | the link to the arm's controller, recording, upload, the emulated demo |
//!
//! The CLI (`src/bin/kincal/`) parses arguments, calls [`api`] (and these) and prints.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod api;
pub mod calib;
pub mod controller;
pub mod data;
pub mod files;
pub mod haptic;
pub mod igtl;
pub mod model;
pub mod motion;
pub mod numerics;
pub mod store;

pub mod report;
pub mod simulate;
pub mod trace;
