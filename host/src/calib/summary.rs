//! `summary.json` of a RUN (`kincal-run/2`): one shape for every kind of data, its `kind` field
//! saying which sections it holds — the distance validation of artefact placements, the
//! per-session validation of tracker sessions, or both (mixed data). Read back, every figure is
//! checked for plausibility ([`Summary::check_figures`]) and every recorded option against the
//! command line's limits ([`SummaryOptions::check`]): diagnose refits with them.

use crate::calib::diagnose::data_errors::DataError;
use crate::calib::error_stats::{AngleStats, ErrorStats};
use crate::calib::fit::{Estimate, IdentifiabilityReport, StartOutcome};
use crate::calib::floor::{Gap, NoiseFloor, PointFloor};
use crate::calib::identify::Identifiability;
use crate::calib::nuisance::drift::{DriftSpec, SessionDrift};
use crate::calib::nuisance::tool::{FloatedTool, ToolRotation};
use crate::calib::outliers::Outlier;
use crate::calib::setup::{
    Change, Objective, Setup, SolveOptions, HUBER_DELTA_RANGE_MM, LEVER_RANGE_MM, MAX_RESTARTS,
};
use crate::calib::study::StudyRow;
use crate::calib::validate::{GroupStats, Repeatability, SessionValidation};
use crate::data::{DataKind, Joints, MAX_ARTEFACT_SPAN_MM};
use crate::model::effects::Effect;
use crate::model::plausible::MAX_REACH_MM;
use crate::trace::{ArmIdentity, FileHash};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Format tag of `summary.json`.
pub const RUN_FORMAT: &str = "kincal-run/2";
/// Format tag of `residuals.json`.
pub const RESIDUALS_FORMAT: &str = "kincal-residuals/1";

/// The input files of a run and the setup that changes the data or the model (absolute paths
/// once the run has loaded them).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct RunInputs {
    /// Arm model file.
    pub model: PathBuf,
    /// Artefact file (for artefact sessions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub artefact: Option<PathBuf>,
    /// Folder of calibration sessions.
    pub calibration: PathBuf,
    /// Folder of validation sessions.
    pub validation: PathBuf,
    /// Effects of the library added to the model (`--add`).
    #[serde(default)]
    pub add: Vec<String>,
    /// Landmarks whose touches are left out of both folders (a wrong certificate).
    #[serde(default)]
    pub exclude_landmarks: Vec<String>,
    /// Calibration blocks left out: `PLACEMENT/REPEAT` (the artefact moved) or a session.
    #[serde(default)]
    pub exclude_blocks: Vec<String>,
    /// Calibration observations left out: `SESSION:LINE` or `PLACEMENT/REPEAT/LANDMARK`.
    #[serde(default)]
    pub exclude_points: Vec<String>,
    /// Groups (placements or sessions, calibration or held out) whose tool floats.
    #[serde(default)]
    pub float_tool: Vec<String>,
    /// Calibration sessions whose points drift, and how.
    #[serde(default)]
    pub drift_sessions: Vec<DriftSpec>,
    /// Held-out sessions measured from a calibration session's placement, `HELD_OUT=CALIBRATION`.
    #[serde(default)]
    pub same_base: Vec<String>,
    /// The instrument's stated σ per axis, mm, for rows that carry none.
    #[serde(default)]
    pub stated_sigma_mm: Option<f64>,
    /// The 6-DoF probe's stated orientation σ per axis, degrees.
    #[serde(default)]
    pub orientation_sigma_deg: Option<f64>,
}

impl RunInputs {
    /// The setup of a run of these inputs with `options`: its options, floated tools, σ and the
    /// options it was given.
    pub fn setup(&self, options: &SolveOptions) -> Setup {
        let mut given: Vec<String> = self.add.iter().map(|e| format!("--add {e}")).collect();
        given.extend(self.exclude_landmarks.iter().map(|l| format!("--exclude-landmark {l}")));
        given.extend(self.exclude_blocks.iter().map(|b| format!("--exclude-block {b}")));
        given.extend(self.exclude_points.iter().map(|p| format!("--exclude-point {p}")));
        given.extend(self.float_tool.iter().map(|g| format!("--float-tool {g}")));
        given.extend(self.drift_sessions.iter().map(|d| format!("--drift-session {d}")));
        Setup {
            options: SolveOptions {
                orientation_sigma_deg: self.orientation_sigma_deg,
                drift_sessions: self.drift_sessions.clone(),
                ..options.clone()
            },
            float_tool: self.float_tool.clone(),
            stated_sigma_mm: self.stated_sigma_mm,
            changes: Vec::new(),
            given,
        }
    }

    /// These inputs with the changes of `setup` applied, as `kincal calibrate` would be given
    /// them.
    pub fn with_changes(&self, setup: &Setup) -> RunInputs {
        setup.changes.iter().fold(self.clone(), |inputs, change| inputs.with_change(change))
    }

    /// These inputs with `change` applied, as `kincal calibrate` would be given them.
    pub fn with_change(&self, change: &Change) -> RunInputs {
        let mut out = self.clone();
        match change {
            Change::Effect(e) => out.add.push(e.to_string()),
            Change::FloatTool(group) => out.float_tool.push(group.clone()),
            Change::Drift(spec) => out.drift_sessions.push(spec.clone()),
            Change::ExcludePoints(points) => out.exclude_points.extend(points.iter().cloned()),
            Change::ExcludeBlock(block) => out.exclude_blocks.push(block.clone()),
            Change::FreeLandmark(id) => out.exclude_landmarks.push(id.clone()),
        }
        out
    }

    /// The whole `kincal calibrate` command of these inputs, writing the RUN folder `out`: every
    /// input, option and stated σ (the solver's options stay at the defaults for the data).
    pub fn calibrate_command(&self, out: &str) -> String {
        let path = |p: &std::path::Path| crate::files::shell_word(p);
        let word = |t: &str| crate::files::shell_word(std::path::Path::new(t));
        let mut words = vec!["kincal calibrate".to_string(), format!("--model {}", path(&self.model))];
        words.extend(self.artefact.as_ref().map(|a| format!("--artefact {}", path(a))));
        words.push(format!("--data {}", path(&self.calibration)));
        words.push(format!("--validate {}", path(&self.validation)));
        words.push(format!("--out {}", word(out)));
        let repeated: [(&str, Vec<String>); 7] = [
            ("--add", self.add.clone()),
            ("--exclude-landmark", self.exclude_landmarks.clone()),
            ("--exclude-block", self.exclude_blocks.clone()),
            ("--exclude-point", self.exclude_points.clone()),
            ("--float-tool", self.float_tool.clone()),
            ("--drift-session", self.drift_sessions.iter().map(ToString::to_string).collect()),
            ("--same-base", self.same_base.clone()),
        ];
        for (option, values) in repeated {
            words.extend(values.iter().map(|v| format!("{option} {}", word(v))));
        }
        words.extend(self.stated_sigma_mm.map(|s| format!("--sigma-mm {s}")));
        words.extend(self.orientation_sigma_deg.map(|s| format!("--orientation-sigma-deg {s}")));
        words.join(" ")
    }

    /// Inputs from the model, artefact (if any) and the two folders, nothing else set.
    pub fn new(
        model: PathBuf,
        artefact: Option<PathBuf>,
        calibration: PathBuf,
        validation: PathBuf,
    ) -> RunInputs {
        RunInputs { model, artefact, calibration, validation, ..RunInputs::default() }
    }
}

/// The solver options as they applied (every default resolved).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SummaryOptions {
    /// Huber threshold δ, mm; left out for plain least squares (a `null` is refused: a number
    /// that was lost, not a choice).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "present_number")]
    pub huber_delta_mm: Option<f64>,
    /// Random restarts.
    pub restarts: usize,
    /// Seed.
    pub seed: u64,
    /// Objective minimised.
    pub objective: Objective,
    /// Weight of tracker rows against artefact distances, mixed data only (σ_distance/σ_point).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point_weight: Option<f64>,
}

/// A number that, when present, must be one (`null` refused).
fn present_number<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
    let value: f64 = serde::Deserialize::deserialize(d)?;
    Ok(Some(value))
}

impl SummaryOptions {
    /// Whether the recorded options are within the limits the command line accepts:
    /// `Err((field, what was expected))` otherwise.
    pub fn check(&self) -> Result<(), (String, String)> {
        let within = |v: f64, (lo, hi): (f64, f64)| v.is_finite() && (lo..=hi).contains(&v);
        if let Some(delta) = self.huber_delta_mm.filter(|d| !within(*d, HUBER_DELTA_RANGE_MM)) {
            let (lo, hi) = HUBER_DELTA_RANGE_MM;
            return Err((
                "options.huber_delta_mm".into(),
                format!("expected {lo} to {hi} mm, found {delta}"),
            ));
        }
        if self.restarts > MAX_RESTARTS {
            return Err((
                "options.restarts".into(),
                format!("expected at most {MAX_RESTARTS}, found {}", self.restarts),
            ));
        }
        if let Objective::SixDof { lever_mm: Some(lever_mm) } = self.objective {
            if !within(lever_mm, LEVER_RANGE_MM) {
                let (lo, hi) = LEVER_RANGE_MM;
                return Err((
                    "options.objective.lever_mm".into(),
                    format!("expected {lo} to {hi}, found {lever_mm}"),
                ));
            }
        }
        Ok(())
    }

    /// The solve options these record, with the setup of `inputs` (floated tools of `groups`,
    /// drifts, the probe's σ).
    pub fn solve_options(&self, inputs: &RunInputs, groups: &[String]) -> SolveOptions {
        SolveOptions {
            huber_delta_mm: self.huber_delta_mm,
            restarts: Some(self.restarts),
            seed: self.seed,
            objective: Some(self.objective),
            orientation_sigma_deg: inputs.orientation_sigma_deg,
            float_tool: inputs.float_tool.iter().filter(|n| groups.contains(n)).cloned().collect(),
            drift_sessions: inputs.drift_sessions.clone(),
            ..SolveOptions::default()
        }
    }
}

/// What one objective can determine at the calibrated model (artefact touches).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ObjectiveComparison {
    /// Free parameters identifiable from distances alone.
    pub identifiable_by_distance: Vec<String>,
    /// Free parameters identifiable with distances plus relative orientation.
    pub identifiable_by_six_dof: Vec<String>,
    /// Identifiable with orientation but not with distances.
    pub gained_by_orientation: Vec<String>,
    /// Standard deviations of each estimated parameter under both objectives (same residual
    /// variance), `[param, distance, six_dof]`.
    pub std: Vec<(String, Option<f64>, Option<f64>)>,
}

/// Calibration figures.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CalibrationSummary {
    /// Calibration RMS, mm: of the distances with touches, else of the point errors.
    pub rms_mm: f64,
    /// Cost Σρ at the solution (not recorded by version-1 tracker runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cost: Option<f64>,
    /// Distance errors between touches (artefact).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distances: Option<ErrorStats>,
    /// Point errors (tracker).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<ErrorStats>,
    /// Orientation errors (6-DoF probes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientations: Option<AngleStats>,
    /// Distance pairs used.
    pub pairs: usize,
    /// Observations used.
    pub observations: usize,
    /// Calibration groups (placements, sessions) and their observations.
    pub groups: BTreeMap<String, usize>,
    /// Each parameter: nominal, calibrated, std, status.
    pub estimates: Vec<Estimate>,
    /// Strongly correlated estimated pairs.
    pub correlations: Vec<(String, String, f64)>,
    /// Every solver start.
    pub starts: Vec<StartOutcome>,
    /// Floated tools.
    #[serde(default)]
    pub tool_offsets: Vec<FloatedTool>,
    /// Drifting sessions' rates.
    #[serde(default)]
    pub drifts: Vec<SessionDrift>,
    /// The probe's orientation on the flange (6-DoF probes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_rotation: Option<ToolRotation>,
}

/// Identifiability in the summary.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct IdentifiabilitySummary {
    /// At the nominal values (frames projected out; not recorded by version-1 tracker runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub before: Option<Identifiability>,
    /// At the solution (without block unknowns).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub after: Option<Identifiability>,
    /// What was estimated, what was held and why, in words.
    pub report: IdentifiabilityReport,
}

/// Validation detail of artefact placements.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ValidationDetail {
    /// Calibrated model, per landmark.
    pub per_landmark: Vec<GroupStats>,
    /// Nominal model, per landmark.
    pub nominal_per_landmark: Vec<GroupStats>,
    /// Calibrated model, per placement.
    pub per_placement: Vec<GroupStats>,
    /// Nominal model, per placement.
    pub nominal_per_placement: Vec<GroupStats>,
    /// Repeatability per landmark (calibrated model, validation data).
    pub repeatability: Vec<Repeatability>,
}

/// Held-out distances of artefact placements.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct DistanceValidation {
    /// Calibrated model.
    pub calibrated: ErrorStats,
    /// Nominal model.
    pub nominal: ErrorStats,
    /// Per landmark, per placement, repeatability.
    pub detail: ValidationDetail,
}

/// A held-out session validated with a calibration session's frame (protocol S).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SameBaseFigures {
    /// The calibration session whose frame the held-out session shares.
    pub calibration_session: String,
    /// The calibrated model with that session's calibrated frame.
    pub calibrated: ErrorStats,
    /// The nominal model (tool fitted) with that session's frame from the nominal fit.
    pub nominal: ErrorStats,
}

/// One held-out session's figures, calibrated and nominal.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SessionFigures {
    /// The calibrated model's figures (`name, points, rms_mm, mean_mm, max_mm, pairwise_rms_mm`).
    #[serde(flatten)]
    pub calibrated: SessionValidation,
    /// The nominal model on the same session.
    pub nominal: SessionValidation,
    /// False when the calibration does worse than nominal here.
    pub transfers: bool,
    /// The calibrated model's orientation figures, 6-DoF probes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation: Option<AngleStats>,
    /// The nominal model's orientation figures on the same session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_orientation: Option<AngleStats>,
    /// Why a 6-DoF session has no orientation figures (its points leave its base's rotation free).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation_withheld: Option<String>,
    /// With a calibration session's frame (`--same-base`, protocol S).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub same_base: Option<SameBaseFigures>,
}

/// Held-out points of tracker sessions, each session's frame refitted.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SessionsValidation {
    /// Per session.
    pub sessions: Vec<SessionFigures>,
    /// Pooled over every held-out point, calibrated.
    pub overall: ErrorStats,
    /// Pooled, nominal.
    pub nominal_overall: ErrorStats,
    /// Orientation error pooled over every held-out orientation, calibrated (6-DoF probes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation_overall: Option<AngleStats>,
}

/// Held-out figures: the sections of the kinds the validation folder holds.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct ValidationSummary {
    /// Distances between touches of artefact placements.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distances: Option<DistanceValidation>,
    /// Points of tracker sessions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sessions: Option<SessionsValidation>,
}

/// The noise floor of the held-out data and how far the model is from it.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct FloorSummary {
    /// Of the held-out distances, from repeated touches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distances: Option<NoiseFloor>,
    /// The held-out distances against it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distance_gap: Option<Gap>,
    /// Of the held-out points, from repeated poses or the stated σ.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<PointFloor>,
}

/// What ties a RUN to its arm and its inputs: the arm the sessions were measured on, when the
/// run validated the model, and the SHA-256 of every file it read. RUNs written before kincal
/// recorded these read back without them.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Provenance {
    /// The arm every session names (`None`: none names one; a calibration of sessions of two
    /// arms is refused).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub arm: Option<ArmIdentity>,
    /// When the run validated the calibrated model on the held-out data, Unix seconds (the
    /// date a signed set carries: [`crate::trace::VALIDATED_AT_FIELD`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validated_at_unix_s: Option<u64>,
    /// The artefact's certificate number, when its file states one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub artefact_certificate: Option<String>,
    /// SHA-256 of every file read: the model, the artefact, each session.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub input_files: Vec<FileHash>,
}

/// Everything `summary.json` holds.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    /// Always [`RUN_FORMAT`].
    pub format: String,
    /// Tool version.
    pub kincal_version: String,
    /// The arm, the validation date and the inputs' hashes.
    #[serde(flatten)]
    pub provenance: Provenance,
    /// What the calibration data hold: `artefact`, `tracker` or `mixed`.
    pub kind: DataKind,
    /// Joints of the arm.
    pub joints: usize,
    /// Input files and setup.
    pub inputs: RunInputs,
    /// Options used.
    pub options: SummaryOptions,
    /// Calibration figures.
    pub calibration: CalibrationSummary,
    /// Identifiability.
    pub identifiability: IdentifiabilitySummary,
    /// Held-out figures.
    pub validation: ValidationSummary,
    /// The floor.
    #[serde(default)]
    pub floor: FloorSummary,
    /// Appendix-F outlier metrics per landmark or session (calibration data).
    #[serde(default)]
    pub outliers: Vec<Outlier>,
    /// The outlier metrics were not computed (`--no-outliers`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub outliers_skipped: bool,
    /// What relative orientation adds to distances (artefact touches).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub objective_comparison: Option<ObjectiveComparison>,
    /// Dataset-size study, when asked for (`--study-subsets`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub study: Option<Vec<StudyRow>>,
    /// Data-error candidates of tracker sessions, best first.
    #[serde(default)]
    pub data_errors: Vec<DataError>,
    /// The verdict, in words: where the model stands and the next step.
    #[serde(default)]
    pub verdict: Vec<String>,
    /// Why the figures are not a result; empty when they are. A RUN with problems is written for
    /// inspection and the command exits non-zero.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_trustworthy: Vec<String>,
    /// Warnings of the readers.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// One validation distance error as stored in `residuals.json`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StoredPairError {
    /// Placement name.
    pub placement: String,
    /// Landmark ids.
    pub landmarks: (String, String),
    /// Repeat.
    pub repeat: u32,
    /// Measured minus certified distance, mm.
    pub error_mm: f64,
    /// Raw encoder angles of the two touches, degrees.
    pub enc_deg: (Joints, Joints),
}

/// `residuals.json`: every validation distance error of the calibrated model.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StoredResiduals {
    /// Always [`RESIDUALS_FORMAT`].
    pub format: String,
    /// One entry per validation pair.
    pub pairs: Vec<StoredPairError>,
}

/// Largest distance figure (an error, an RMS, a bias), mm, a RUN can hold: two tool positions of
/// the longest arm a model may describe plus the largest artefact. Read back, a larger figure (or
/// a non-finite one) is a damaged or edited file, refused like an implausible input.
pub const MAX_STORED_MM: f64 = 2.0 * MAX_REACH_MM + MAX_ARTEFACT_SPAN_MM;

/// `Err((field, what was expected))` when a stored distance figure is not finite or beyond
/// [`MAX_STORED_MM`] (or negative where it cannot be).
fn check_mm(field: &str, value: f64, signed: bool) -> Result<(), (String, String)> {
    let ok = value.is_finite() && value.abs() <= MAX_STORED_MM && (signed || value >= 0.0);
    if ok {
        return Ok(());
    }
    let range = if signed { format!("±{MAX_STORED_MM}") } else { format!("0 to {MAX_STORED_MM}") };
    let found = if value.abs() < 1e6 { format!("{value}") } else { format!("{value:e}") };
    Err((field.to_string(), format!("expected a finite distance figure of {range} mm, found {found}")))
}

impl ErrorStats {
    /// Whether every figure is plausible (see [`MAX_STORED_MM`]).
    fn check(&self, field: &str) -> Result<(), (String, String)> {
        check_mm(&format!("{field}.rms_mm"), self.rms_mm, false)?;
        check_mm(&format!("{field}.mean_mm"), self.mean_mm, true)?;
        check_mm(&format!("{field}.std_mm"), self.std_mm, false)?;
        check_mm(&format!("{field}.max_mm"), self.max_mm, false)
    }
}

impl Summary {
    /// Whether every figure read back is plausible (finite, within [`MAX_STORED_MM`] for
    /// distances) and every added effect known: `Err((field, what was expected))` otherwise.
    pub fn check_figures(&self) -> Result<(), (String, String)> {
        check_mm("calibration.rms_mm", self.calibration.rms_mm, false)?;
        if let Some(cost) = self.calibration.cost.filter(|c| !(c.is_finite() && *c >= 0.0)) {
            return Err((
                "calibration.cost".into(),
                format!("expected a finite non-negative cost, found {cost}"),
            ));
        }
        if let Some(bad) = self.inputs.add.iter().find(|e| Effect::parse(e).is_none()) {
            return Err(("inputs.add".into(), format!("unknown effect `{bad}`")));
        }
        for (name, stats) in [
            ("calibration.distances", &self.calibration.distances),
            ("calibration.points", &self.calibration.points),
        ] {
            if let Some(s) = stats {
                s.check(name)?;
            }
        }
        if let Some(v) = &self.validation.distances {
            v.calibrated.check("validation.distances.calibrated")?;
            v.nominal.check("validation.distances.nominal")?;
            let d = &v.detail;
            for (name, groups) in [
                ("per_landmark", &d.per_landmark),
                ("nominal_per_landmark", &d.nominal_per_landmark),
                ("per_placement", &d.per_placement),
                ("nominal_per_placement", &d.nominal_per_placement),
            ] {
                for (i, g) in groups.iter().enumerate() {
                    g.stats.check(&format!("validation.distances.detail.{name}[{i}].stats"))?;
                }
            }
            for (i, r) in d.repeatability.iter().enumerate() {
                check_mm(&format!("validation.distances.detail.repeatability[{i}].rms_mm"), r.rms_mm, false)?;
                check_mm(&format!("validation.distances.detail.repeatability[{i}].rp_mm"), r.rp_mm, false)?;
            }
        }
        if let Some(v) = &self.validation.sessions {
            v.overall.check("validation.sessions.overall")?;
            v.nominal_overall.check("validation.sessions.nominal_overall")?;
            for (i, s) in v.sessions.iter().enumerate() {
                s.calibrated.stats().check(&format!("validation.sessions.sessions[{i}]"))?;
            }
        }
        for (i, o) in self.outliers.iter().enumerate() {
            check_mm(&format!("outliers[{i}].bias_mm"), o.bias_mm, true)?;
        }
        for (i, e) in self.calibration.estimates.iter().enumerate() {
            let figures = [e.nominal, e.value].into_iter().chain(e.std);
            if figures.into_iter().any(|v| !v.is_finite()) {
                return Err((
                    format!("calibration.estimates[{i}]"),
                    format!("{}: expected finite nominal, value and std", e.param),
                ));
            }
        }
        for (i, row) in self.study.iter().flatten().enumerate() {
            let figures = [row.mean_mm, row.std_mm, row.min_mm, row.max_mm];
            for v in figures.into_iter().chain(row.rms_mm.iter().copied()) {
                check_mm(&format!("study[{i}]"), v, false)?;
            }
        }
        Ok(())
    }

    /// The held-out sessions' figures (none without tracker sessions held out).
    pub fn held_out_sessions(&self) -> &[SessionFigures] {
        self.validation.sessions.as_ref().map_or(&[], |v| &v.sessions)
    }

    /// The floor of the held-out points (`unknown` without tracker sessions held out).
    pub fn point_floor(&self) -> PointFloor {
        self.floor.points.clone().unwrap_or(PointFloor { source: "unknown".into(), rms_mm: None })
    }

    /// The held-out RMS the run is judged by, mm: of the distances with artefact placements held
    /// out, else of the points.
    pub fn held_out_rms_mm(&self) -> f64 {
        match (&self.validation.distances, &self.validation.sessions) {
            (Some(d), _) => d.calibrated.rms_mm,
            (None, Some(s)) => s.overall.rms_mm,
            (None, None) => f64::NAN,
        }
    }

    /// The nominal model's figure on the same held-out data as [`Summary::held_out_rms_mm`], mm.
    pub fn nominal_held_out_rms_mm(&self) -> f64 {
        match (&self.validation.distances, &self.validation.sessions) {
            (Some(d), _) => d.nominal.rms_mm,
            (None, Some(s)) => s.nominal_overall.rms_mm,
            (None, None) => f64::NAN,
        }
    }
}

impl StoredResiduals {
    /// Whether every stored pair is plausible: a finite error within [`MAX_STORED_MM`] and
    /// `joints` raw encoder angles in [0, 360) degrees, as the sessions they came from had to hold.
    pub fn check(&self, joints: usize) -> Result<(), (String, String)> {
        for (i, p) in self.pairs.iter().enumerate() {
            check_mm(&format!("pairs[{i}].error_mm"), p.error_mm, true)?;
            for (side, angles) in [p.enc_deg.0, p.enc_deg.1].iter().enumerate() {
                if angles.len() != joints {
                    return Err((
                        format!("pairs[{i}].enc_deg[{side}]"),
                        format!(
                            "expected {joints} encoder angles (the model's joints), found {}",
                            angles.len()
                        ),
                    ));
                }
                if let Some(k) = angles.iter().position(|v| !(v.is_finite() && (0.0..360.0).contains(v))) {
                    return Err((
                        format!("pairs[{i}].enc_deg[{side}][{k}]"),
                        format!("expected a raw encoder angle in [0, 360) degrees, found {}", angles[k]),
                    ));
                }
            }
        }
        Ok(())
    }
}
