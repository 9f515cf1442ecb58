//! The RUN summaries of earlier versions, read and turned into today's [`Summary`]: an artefact
//! run (`kincal-run/1`: distances only, one validation block at the top) and a tracker run
//! (`kincal-tracker-run/1`: held-out sessions, the floor, the data errors). Nothing writes them any
//! more; a RUN folder of either kind stays readable by `diagnose`, `compare` and `plan`.

use crate::calib::diagnose::data_errors::DataError;
use crate::calib::error_stats::{AngleStats, ErrorStats};
use crate::calib::fit::{Estimate, IdentifiabilityReport, StartOutcome};
use crate::calib::floor::PointFloor;
use crate::calib::identify::Identifiability;
use crate::calib::nuisance::drift::{DriftSpec, SessionDrift};
use crate::calib::nuisance::tool::{FloatedTool, ToolRotation};
use crate::calib::outliers::Outlier;
use crate::calib::setup::Objective;
use crate::calib::study::StudyRow;
use crate::calib::summary::*;
use crate::data::DataKind;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Format tag of an artefact run's summary before [`RUN_FORMAT`].
pub const ARTEFACT_RUN_V1: &str = "kincal-run/1";
/// Format tag of a tracker run's summary before [`RUN_FORMAT`].
pub const TRACKER_RUN_V1: &str = "kincal-tracker-run/1";

/// `kincal-run/1` inputs.
#[derive(serde::Deserialize)]
struct ArtefactInputsV1 {
    model: PathBuf,
    artefact: PathBuf,
    calibration: PathBuf,
    validation: PathBuf,
    #[serde(default)]
    exclude_landmarks: Vec<String>,
    #[serde(default)]
    exclude_blocks: Vec<String>,
}

/// `kincal-run/1` options (the Huber δ always set).
#[derive(serde::Deserialize)]
struct ArtefactOptionsV1 {
    huber_delta_mm: f64,
    restarts: usize,
    seed: u64,
    objective: Objective,
    #[serde(default)]
    added_effects: Vec<String>,
}

/// `kincal-run/1` calibration figures.
#[derive(serde::Deserialize)]
struct ArtefactCalibrationV1 {
    rms_mm: f64,
    cost: f64,
    pairs: usize,
    touches: usize,
    estimates: Vec<Estimate>,
    #[serde(default)]
    fixed_unidentifiable: Vec<String>,
    correlations: Vec<(String, String, f64)>,
    starts: Vec<StartOutcome>,
}

/// `kincal-run/1` identifiability.
#[derive(serde::Deserialize)]
struct IdentifiabilityV1 {
    before: Identifiability,
    after: Identifiability,
}

/// `summary.json` of an artefact run, `kincal-run/1`.
#[derive(serde::Deserialize)]
pub struct ArtefactRunV1 {
    kincal_version: String,
    inputs: ArtefactInputsV1,
    options: ArtefactOptionsV1,
    calibration: ArtefactCalibrationV1,
    identifiability: IdentifiabilityV1,
    validation: ErrorStats,
    nominal_validation: ErrorStats,
    validation_detail: ValidationDetail,
    outliers: Vec<Outlier>,
    #[serde(default)]
    outliers_skipped: bool,
    objective_comparison: ObjectiveComparison,
    #[serde(default)]
    study: Option<Vec<StudyRow>>,
    #[serde(default)]
    not_trustworthy: Vec<String>,
}

/// `kincal-tracker-run/1` inputs.
#[derive(serde::Deserialize)]
struct TrackerInputsV1 {
    model: PathBuf,
    calibration: PathBuf,
    validation: PathBuf,
    #[serde(default)]
    float_tool: Vec<String>,
    #[serde(default)]
    stated_sigma_mm: Option<f64>,
    #[serde(default)]
    exclude_points: Vec<String>,
    #[serde(default)]
    orientation_sigma_deg: Option<f64>,
    #[serde(default)]
    drift_sessions: Vec<DriftSpec>,
    #[serde(default)]
    same_base: Vec<String>,
    #[serde(default)]
    add: Vec<String>,
}

/// `kincal-tracker-run/1` held-out figures.
#[derive(serde::Deserialize)]
struct TrackerValidationV1 {
    sessions: Vec<SessionFigures>,
    overall: ErrorStats,
    nominal_overall: ErrorStats,
    #[serde(default)]
    orientation_overall: Option<AngleStats>,
}

/// `summary.json` of a tracker run, `kincal-tracker-run/1`.
#[derive(serde::Deserialize)]
pub struct TrackerRunV1 {
    kincal_version: String,
    inputs: TrackerInputsV1,
    joints: usize,
    calibration_sessions: BTreeMap<String, usize>,
    fit: ErrorStats,
    #[serde(default)]
    orientation_fit: Option<AngleStats>,
    #[serde(default)]
    tool_rotation: Option<ToolRotation>,
    estimates: Vec<Estimate>,
    #[serde(default)]
    tool_offsets: Vec<FloatedTool>,
    #[serde(default)]
    drifts: Vec<SessionDrift>,
    identifiability: IdentifiabilityReport,
    validation: TrackerValidationV1,
    floor: PointFloor,
    #[serde(default)]
    data_errors: Vec<DataError>,
    #[serde(default)]
    verdict: Vec<String>,
    #[serde(default)]
    warnings: Vec<String>,
}

impl ArtefactRunV1 {
    /// The same run as today's summary (the model's joints from its `model.toml`; version-1
    /// tracker arms had six).
    pub fn into_summary(self, joints: usize) -> Summary {
        let i = self.inputs;
        let c = self.calibration;
        let status = |e: &Estimate| e.status.starts_with("estimated");
        let report = IdentifiabilityReport {
            estimated: c.estimates.iter().filter(|e| status(e)).map(|e| e.param.clone()).collect(),
            fixed: c.fixed_unidentifiable.clone(),
            statements: Vec::new(),
            unidentifiable: self.identifiability.after.unidentifiable.clone(),
            poorly_identified: self.identifiability.after.poorly_identified.clone(),
            orientation_spread_deg: Vec::new(),
        };
        Summary {
            format: RUN_FORMAT.into(),
            kincal_version: self.kincal_version,
            provenance: Provenance::default(),
            kind: DataKind::Artefact,
            joints,
            inputs: RunInputs {
                exclude_landmarks: i.exclude_landmarks,
                exclude_blocks: i.exclude_blocks,
                add: self.options.added_effects,
                ..RunInputs::new(i.model, Some(i.artefact), i.calibration, i.validation)
            },
            options: SummaryOptions {
                huber_delta_mm: Some(self.options.huber_delta_mm),
                restarts: self.options.restarts,
                seed: self.options.seed,
                objective: self.options.objective,
                point_weight: None,
            },
            calibration: CalibrationSummary {
                rms_mm: c.rms_mm,
                cost: Some(c.cost),
                distances: None,
                points: None,
                orientations: None,
                pairs: c.pairs,
                observations: c.touches,
                groups: BTreeMap::new(),
                estimates: c.estimates,
                correlations: c.correlations,
                starts: c.starts,
                tool_offsets: Vec::new(),
                drifts: Vec::new(),
                tool_rotation: None,
            },
            identifiability: IdentifiabilitySummary {
                before: Some(self.identifiability.before),
                after: Some(self.identifiability.after),
                report,
            },
            validation: ValidationSummary {
                distances: Some(DistanceValidation {
                    calibrated: self.validation,
                    nominal: self.nominal_validation,
                    detail: self.validation_detail,
                }),
                sessions: None,
            },
            floor: FloorSummary::default(),
            outliers: self.outliers,
            outliers_skipped: self.outliers_skipped,
            objective_comparison: Some(self.objective_comparison),
            study: self.study,
            data_errors: Vec::new(),
            verdict: Vec::new(),
            not_trustworthy: self.not_trustworthy,
            warnings: Vec::new(),
        }
    }
}

impl TrackerRunV1 {
    /// The same run as today's summary. Version 1 recorded no solver options: a tracker run was
    /// always plain least squares from the nominal start with the default seed.
    pub fn into_summary(self) -> Summary {
        let i = self.inputs;
        let v = self.validation;
        Summary {
            format: RUN_FORMAT.into(),
            kincal_version: self.kincal_version,
            provenance: Provenance::default(),
            kind: DataKind::Tracker,
            joints: self.joints,
            inputs: RunInputs {
                add: i.add,
                exclude_points: i.exclude_points,
                float_tool: i.float_tool,
                drift_sessions: i.drift_sessions,
                same_base: i.same_base,
                stated_sigma_mm: i.stated_sigma_mm,
                orientation_sigma_deg: i.orientation_sigma_deg,
                ..RunInputs::new(i.model, None, i.calibration, i.validation)
            },
            options: SummaryOptions {
                huber_delta_mm: None,
                restarts: 0,
                seed: 1,
                objective: Objective::Distance,
                point_weight: None,
            },
            calibration: CalibrationSummary {
                rms_mm: self.fit.rms_mm,
                cost: None,
                distances: None,
                points: Some(self.fit),
                orientations: self.orientation_fit,
                pairs: 0,
                observations: self.calibration_sessions.values().sum(),
                groups: self.calibration_sessions,
                estimates: self.estimates,
                correlations: Vec::new(),
                starts: Vec::new(),
                tool_offsets: self.tool_offsets,
                drifts: self.drifts,
                tool_rotation: self.tool_rotation,
            },
            identifiability: IdentifiabilitySummary {
                before: None,
                after: None,
                report: self.identifiability,
            },
            validation: ValidationSummary {
                distances: None,
                sessions: Some(SessionsValidation {
                    sessions: v.sessions,
                    overall: v.overall,
                    nominal_overall: v.nominal_overall,
                    orientation_overall: v.orientation_overall,
                }),
            },
            floor: FloorSummary { points: Some(self.floor), ..FloorSummary::default() },
            outliers: Vec::new(),
            outliers_skipped: true,
            objective_comparison: None,
            study: None,
            data_errors: self.data_errors,
            verdict: self.verdict,
            not_trustworthy: Vec::new(),
            warnings: self.warnings,
        }
    }
}
