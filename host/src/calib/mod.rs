//! Arm calibration from artefact touches: the objective (residual blocks), identifiability, the
//! calibration itself, validation on held-out placements, outlier metrics, diagnosis of missing
//! effects, the dataset-size study, whether figures are a result (trust), and the whole run from input files to results.

pub mod auto;
pub mod calibrate;
pub mod data_errors;
pub mod diagnose;
pub mod floor;
pub mod identify;
pub mod monte_carlo;
pub mod objective;
pub mod outliers;
pub mod peer;
pub mod plan;
pub mod run;
pub mod study;
pub mod tracker;
pub mod tracker_diagnose;
pub mod tracker_drift;
pub mod tracker_errors;
pub mod tracker_run;
pub mod trust;
pub mod validate;
