//! Data errors: faults of the measurement rather than of the arm, each found by a detector of its
//! kind of block and remedied by a typed [`Change`] — a wrong certificate, an artefact moved
//! within a repeat, a mis-seated touch ([`touches`]); a re-mounted tool, a probe turned on its
//! mount, a drifting session, single bad points ([`sessions`]). The diagnosis scores their remedies on the held-out data
//! beside the arm effects, by the same test.

pub mod sessions;
pub mod touches;

use crate::calib::setup::Change;

/// What kind of data error an instrument session shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum DataErrorKind {
    /// The tool sits elsewhere in one session (re-mounted).
    #[serde(rename = "tool moved")]
    ToolMoved,
    /// The session's base or length scale creeps against time or temperature.
    #[serde(rename = "drift")]
    Drift,
    /// Single points far beyond the others.
    #[serde(rename = "bad points")]
    BadPoints,
    /// A 6-DoF probe turned on its mount in one session (its rotation and its point with it).
    #[serde(rename = "probe turned")]
    ProbeTurned,
}

impl DataErrorKind {
    /// The words in messages and in summary.json.
    pub fn word(self) -> &'static str {
        match self {
            DataErrorKind::ToolMoved => "tool moved",
            DataErrorKind::Drift => "drift",
            DataErrorKind::BadPoints => "bad points",
            DataErrorKind::ProbeTurned => "probe turned",
        }
    }
}

/// Which folder a data error sits in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum DataSet {
    /// A calibration session.
    #[serde(rename = "calibration")]
    Calibration,
    /// A held-out session.
    #[serde(rename = "validation")]
    HeldOut,
}

impl DataSet {
    /// The word in messages and in summary.json.
    pub fn word(self) -> &'static str {
        match self {
            DataSet::Calibration => "calibration",
            DataSet::HeldOut => "validation",
        }
    }
}

/// A data error of instrument sessions, scored by its own rule: a session whose tool point sits
/// elsewhere, a session that drifts, or single bad points (as `kincal calibrate` reports them).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DataError {
    /// What it is.
    pub kind: DataErrorKind,
    /// The session (for bad points, the sessions holding them).
    pub session: String,
    /// Where the session is.
    pub set: DataSet,
    /// The tool point's displacement (flange frame), the largest bad point's error (mm), the
    /// length of a drift's rate (mm/h, mm/K, ppm/h or ppm/K, as its text says), or a turned
    /// probe's angle (degrees).
    pub size_mm: f64,
    /// Standard deviation of the displacement's length, the points' robust σ (mm), of the
    /// drift rate's length (its unit), or of the probe's angle (degrees).
    pub size_std_mm: f64,
    /// Held-out RMS without the candidate, mm.
    pub held_out_before_mm: f64,
    /// Held-out RMS with it, mm.
    pub held_out_after_mm: f64,
    /// Beyond 3 σ and the held-out error falls.
    pub significant: bool,
    /// The sentence a user reads.
    pub text: String,
    /// The command-line option that applies it.
    pub action: String,
    /// The remedy, typed (absent in files written before kincal stored it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub change: Option<Change>,
}

impl std::fmt::Display for DataErrorKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.word())
    }
}

impl std::fmt::Display for DataSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.word())
    }
}
