//! The calibration engine: observations of every kind as residual terms over one parameter
//! vector (the arm's free parameters and each block's own unknowns), the problem the solver
//! minimises, the fit (identifiability, passes, restarts, covariance), validation on held-out
//! blocks, the noise floor, and what is built on them: outlier metrics, the dataset-size study,
//! whether figures are a result (trust), the plan of what to measure next, the diagnosis of
//! missing effects and data errors, and the whole run from input files to results.

pub mod bench_problem;
pub mod diagnose;
pub mod error;
pub mod error_stats;
pub mod fit;
pub mod floor;
pub mod identify;
pub mod layout;
pub mod monte_carlo;
pub mod nuisance;
pub mod outliers;
pub mod peer;
pub mod plan;
pub mod problem;
pub mod repeats;
pub mod run;
pub mod setup;
pub mod study;
pub mod summary;
pub mod terms;
pub mod trust;
pub mod validate;
