//! Why a calibration could not run.

use crate::calib::nuisance::drift::DriftError;

/// Why a calibration could not run.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// The sessions' joint count differs from the model's.
    #[error("the {kind} sessions {record} {data} {what}, the model has {model} joints")]
    JointCount {
        /// `artefact` or `tracker`.
        kind: &'static str,
        /// How the sessions hold the joints.
        record: &'static str,
        /// Joints in the data.
        data: usize,
        /// What they are.
        what: &'static str,
        /// Joints of the model.
        model: usize,
    },
    /// Too few distances for the free parameters.
    #[error("{pairs} landmark pairs cannot determine {params} parameters: touch more landmarks per placement and repeat")]
    TooFewPairs {
        /// Distance residuals available.
        pairs: usize,
        /// Parameters to determine.
        params: usize,
    },
    /// More unknowns than residuals.
    #[error("{residuals} measured coordinates cannot determine {unknowns} unknowns: measure more points")]
    TooFewResiduals {
        /// Residual rows.
        residuals: usize,
        /// Unknowns (arm, tool, frames).
        unknowns: usize,
    },
    /// A session has too few points to place its frame.
    #[error(
        "{path}: session \"{session}\" has {points} points: at least 3 not on one line are needed to place its base"
    )]
    TooFewPoints {
        /// The session's file.
        path: String,
        /// The session.
        session: String,
        /// Its points.
        points: usize,
    },
    /// A change names an observation, block or landmark the data do not hold.
    #[error("{0}: not in these data")]
    NotInData(String),
    /// A group named by `--float-tool` is not in the data.
    #[error("--float-tool / --drift-session {0}: no calibration session of that name")]
    UnknownSession(String),
    /// A drift asked for cannot be fitted.
    #[error(transparent)]
    Drift(#[from] DriftError),
    /// The model has no free parameter.
    #[error("the model has no free parameter: give bounds in its [free] table")]
    NothingFree,
    /// No free parameter changes any residual on these observations.
    #[error(
        "none of the free parameters changes any measured distance: the touches carry no information \
         (all at one pose, or the same joint angles copied into every measurement?)"
    )]
    NothingIdentifiable,
    /// The model gives positions that are not finite numbers.
    #[error("the model gives non-finite tool positions on these touches: check the model's numbers")]
    NonFinite,
}
