//! `kincal calibrate`: the whole job from input files to results, and the typed files of a RUN
//! folder read back.
//!
//! RUN/ holds `model.toml` (the calibrated model, loadable again), `nominal.toml` (the model it
//! started from, with any added effects), `summary.json` ([`Summary`], format [`RUN_FORMAT`]),
//! `residuals.json` ([`StoredResiduals`], every validation distance error, for `kincal compare`)
//! and `report.html`. Writing the folder is [`crate::output`]'s job.

use crate::calib::fit::{calibrate, check_data, dense_jacobian, CalibError, Estimate, Fit, StartOutcome};
use crate::calib::identify::{self, Identifiability};
use crate::calib::outliers::{landmark_outliers, LandmarkOutlier};
use crate::calib::setup::{Objective, SolveOptions, HUBER_DELTA_RANGE_MM, LEVER_RANGE_MM, MAX_RESTARTS};
use crate::calib::study::{check_study_size, study, study_problems, StudyError, StudyOptions, StudyRow};
use crate::calib::trust::{result_problems, TrustScales};
use crate::calib::validate::{self, validate, ErrorStats, GroupStats, Repeatability, Validation};
use crate::data::{Artefact, Joints, Observations, Purpose, MAX_ARTEFACT_SPAN_MM};
use crate::files::FileError;
use crate::files::{field_error, read_tagged};
use crate::model::effects::Effect;
use crate::model::file::MAX_REACH_MM;
use crate::model::ArmModel;
use std::path::{Path, PathBuf};

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// An input file was unusable.
    #[error(transparent)]
    Data(#[from] FileError),
    /// The calibration could not run.
    #[error(transparent)]
    Calibration(#[from] CalibError),
    /// `--exclude-landmark` or `--exclude-block` names nothing in the data.
    #[error("{0}")]
    Exclusion(String),
    /// The artefact is larger than the arm can span.
    #[error(
        "the artefact's landmarks span {span:.0} mm but the model's arm reaches at most {reach:.0} mm \
         from its base: it cannot touch them all (model or artefact of another device, or other units?)"
    )]
    OutOfReach {
        /// Largest distance between two landmarks, mm.
        span: f64,
        /// The arm's reach (Σ|d| + |a| + |tool|), mm.
        reach: f64,
    },
    /// The study asked for is too large.
    #[error(transparent)]
    Study(#[from] StudyError),
    /// The validation sessions hold no distance to validate on.
    #[error(
        "{path}: no two different landmarks touched in the same placement and repeat: no distance to \
         validate on"
    )]
    NoValidationPairs {
        /// The validation folder.
        path: PathBuf,
    },
    /// A validation placement repeats a calibration placement touch for touch.
    #[error(
        "validation placement \"{validation}\" holds the same touches as calibration placement \
         \"{calibration}\": validation must be held out (copied files?)"
    )]
    SameData {
        /// The validation placement.
        validation: String,
        /// The calibration placement it copies.
        calibration: String,
    },
    /// The model's figures on the data are beyond the model-independent scales (see
    /// [`crate::calib::trust`]): nothing computed from the model is a result.
    #[error(
        "the model does not describe these touches; nothing computed from it is a result:\n  - {}",
        .0.join("\n  - ")
    )]
    NotACalibration(Vec<String>),
    /// An effect added on the command line names a joint the model does not have.
    #[error("--add {effect}: the model has {joints} joints, there is no such joint")]
    NoSuchJoint {
        /// The effect.
        effect: String,
        /// The model's joints.
        joints: usize,
    },
    /// An input path could not be resolved.
    #[error("{path}: {source}")]
    Input {
        /// The file or folder.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
}

/// Input files of a run (absolute once the run has loaded them).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct RunInputs {
    /// Arm model file.
    pub model: PathBuf,
    /// Artefact file.
    pub artefact: PathBuf,
    /// Folder of calibration sessions.
    pub calibration: PathBuf,
    /// Folder of validation sessions.
    pub validation: PathBuf,
    /// Landmark ids whose touches are left out of both datasets (a wrong certificate).
    #[serde(default)]
    pub exclude_landmarks: Vec<String>,
    /// Calibration blocks `PLACEMENT/REPEAT` left out (the artefact moved during the repeat).
    #[serde(default)]
    pub exclude_blocks: Vec<String>,
}

impl RunInputs {
    /// Inputs from the four paths, nothing excluded.
    pub fn new(model: PathBuf, artefact: PathBuf, calibration: PathBuf, validation: PathBuf) -> RunInputs {
        RunInputs {
            model,
            artefact,
            calibration,
            validation,
            exclude_landmarks: Vec::new(),
            exclude_blocks: Vec::new(),
        }
    }

    /// Load the calibration and validation sessions with the exclusions applied.
    pub fn load_data(&self, artefact: &Artefact) -> Result<(Observations, Observations), RunError> {
        let mut cal = Observations::load_artefact_dir(&self.calibration, artefact, Purpose::Calibration)?;
        let mut val = Observations::load_artefact_dir(&self.validation, artefact, Purpose::Validation)?;
        for id in &self.exclude_landmarks {
            let l = artefact.index_of(id).ok_or_else(|| {
                RunError::Exclusion(format!(
                    "--exclude-landmark {id}: no landmark \"{id}\" in {}",
                    self.artefact.display()
                ))
            })?;
            cal = cal.without_landmark(l);
            val = val.without_landmark(l);
        }
        for block in &self.exclude_blocks {
            let Some(b) = cal.find_block(block) else {
                return Err(RunError::Exclusion(format!(
                    "--exclude-block {block}: expected PLACEMENT/REPEAT of a calibration block in {}",
                    self.calibration.display()
                )));
            };
            cal = cal.without(|k| cal.obs[k].block == b);
        }
        Ok((cal, val))
    }
}

/// What one objective can determine at the calibrated model.
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

/// Everything `summary.json` holds.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Summary {
    /// Always [`RUN_FORMAT`].
    pub format: String,
    /// Tool version.
    pub kincal_version: String,
    /// Input files.
    pub inputs: RunInputs,
    /// Options used.
    pub options: SummaryOptions,
    /// Calibration figures.
    pub calibration: CalibrationSummary,
    /// Identifiability before and after solving.
    pub identifiability: IdentifiabilitySummary,
    /// Calibrated model on the validation sessions.
    pub validation: ErrorStats,
    /// Nominal model on the validation sessions.
    pub nominal_validation: ErrorStats,
    /// Per landmark and per placement, nominal vs calibrated.
    pub validation_detail: ValidationDetail,
    /// Appendix-F outlier metrics per landmark (calibration data).
    pub outliers: Vec<LandmarkOutlier>,
    /// The outlier metrics were not computed (`--no-outliers`): `outliers` is empty because
    /// nothing was looked at, not because nothing was found.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub outliers_skipped: bool,
    /// What relative orientation adds to distances.
    pub objective_comparison: ObjectiveComparison,
    /// Observations-size study, when asked for (`--study-subsets`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub study: Option<Vec<StudyRow>>,
    /// Why the figures are not a result, with the likely cause ([`result_problems`]); empty when
    /// they are. A RUN with problems is written for inspection and the command exits non-zero.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_trustworthy: Vec<String>,
}

/// The first validation placement that copies a calibration placement touch for touch.
fn copied_placement(cal: &Observations, val: &Observations) -> Option<(String, String)> {
    let key = |data: &Observations, p: usize| -> Vec<(usize, u32, Vec<u64>)> {
        let mut v: Vec<_> = data
            .obs
            .iter()
            .filter(|t| t.group == p)
            .map(|t| (t.touched(), t.repeat, t.q_deg.iter().map(|v| v.to_bits()).collect::<Vec<u64>>()))
            .collect();
        v.sort_unstable();
        v
    };
    let cal_keys: std::collections::HashMap<_, usize> =
        (0..cal.groups.len()).map(|p| (key(cal, p), p)).collect();
    (0..val.groups.len()).find_map(|p| {
        let k = key(val, p);
        (!k.is_empty())
            .then(|| cal_keys.get(&k))
            .flatten()
            .map(|&c| (val.groups[p].name.clone(), cal.groups[c].name.clone()))
    })
}

/// Options recorded in the summary.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SummaryOptions {
    /// Huber threshold, mm.
    pub huber_delta_mm: f64,
    /// Random restarts.
    pub restarts: usize,
    /// Seed.
    pub seed: u64,
    /// Objective minimised.
    pub objective: Objective,
    /// Effects added to the input model with `--add`.
    #[serde(default)]
    pub added_effects: Vec<String>,
}

impl SummaryOptions {
    /// Whether the recorded options are within the limits the command line accepts:
    /// `Err((field, what was expected))` otherwise.
    pub fn check(&self) -> Result<(), (String, String)> {
        let within = |v: f64, (lo, hi): (f64, f64)| v.is_finite() && (lo..=hi).contains(&v);
        if !within(self.huber_delta_mm, HUBER_DELTA_RANGE_MM) {
            let (lo, hi) = HUBER_DELTA_RANGE_MM;
            return Err((
                "options.huber_delta_mm".into(),
                format!("expected {lo} to {hi} mm, found {}", self.huber_delta_mm),
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
        if let Some(bad) = self.added_effects.iter().find(|e| Effect::parse(e).is_none()) {
            return Err(("options.added_effects".into(), format!("unknown effect `{bad}`")));
        }
        Ok(())
    }

    /// The calibration options these record.
    pub fn calibration_options(&self) -> SolveOptions {
        SolveOptions {
            huber_delta_mm: Some(self.huber_delta_mm),
            restarts: Some(self.restarts),
            seed: self.seed,
            objective: Some(self.objective),
            ..SolveOptions::default()
        }
    }
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

/// Format tag of `summary.json`.
pub const RUN_FORMAT: &str = "kincal-run/1";
/// Format tag of `residuals.json`.
pub const RESIDUALS_FORMAT: &str = "kincal-residuals/1";

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
    fn check(&self, field: &str) -> Result<(), (String, String)> {
        check_mm(&format!("{field}.rms_mm"), self.rms_mm, false)?;
        check_mm(&format!("{field}.mean_mm"), self.mean_mm, true)?;
        check_mm(&format!("{field}.std_mm"), self.std_mm, false)?;
        check_mm(&format!("{field}.max_mm"), self.max_mm, false)
    }
}

impl Summary {
    /// Whether every figure read back is plausible (finite, within [`MAX_STORED_MM`] for
    /// distances): `Err((field, what was expected))` otherwise.
    pub fn check_figures(&self) -> Result<(), (String, String)> {
        check_mm("calibration.rms_mm", self.calibration.rms_mm, false)?;
        if !(self.calibration.cost.is_finite() && self.calibration.cost >= 0.0) {
            return Err((
                "calibration.cost".into(),
                format!("expected a finite non-negative cost, found {}", self.calibration.cost),
            ));
        }
        self.validation.check("validation")?;
        self.nominal_validation.check("nominal_validation")?;
        let d = &self.validation_detail;
        for (name, groups) in [
            ("per_landmark", &d.per_landmark),
            ("nominal_per_landmark", &d.nominal_per_landmark),
            ("per_placement", &d.per_placement),
            ("nominal_per_placement", &d.nominal_per_placement),
        ] {
            for (i, g) in groups.iter().enumerate() {
                g.stats.check(&format!("validation_detail.{name}[{i}].stats"))?;
            }
        }
        for (i, r) in d.repeatability.iter().enumerate() {
            check_mm(&format!("validation_detail.repeatability[{i}].rms_mm"), r.rms_mm, false)?;
            check_mm(&format!("validation_detail.repeatability[{i}].rp_mm"), r.rp_mm, false)?;
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

/// A RUN folder read back as types.
pub struct RunFolder {
    /// The folder.
    pub dir: PathBuf,
    /// The calibrated model (`model.toml`).
    pub model: ArmModel,
    /// `summary.json`.
    pub summary: Summary,
}

impl RunFolder {
    /// Read `model.toml` and `summary.json` of a RUN folder; the recorded options are checked
    /// against the same limits as the command line's, since diagnose refits with them, and every
    /// figure for plausibility ([`Summary::check_figures`]).
    pub fn load(dir: &Path) -> Result<RunFolder, FileError> {
        let model = ArmModel::load(&dir.join("model.toml"))?;
        let path = dir.join("summary.json");
        let summary: Summary = read_tagged(&path, RUN_FORMAT)?;
        summary.options.check().map_err(|(field, message)| field_error(&path, field, message))?;
        summary.check_figures().map_err(|(field, message)| field_error(&path, field, message))?;
        Ok(RunFolder { dir: dir.to_owned(), model, summary })
    }

    /// Read `residuals.json`, its figures checked as [`StoredResiduals::check`] says.
    pub fn residuals(&self) -> Result<Vec<StoredPairError>, FileError> {
        let path = self.dir.join("residuals.json");
        let stored: StoredResiduals = read_tagged(&path, RESIDUALS_FORMAT)?;
        stored
            .check(self.model.joints.len())
            .map_err(|(field, message)| field_error(&path, field, message))?;
        Ok(stored.pairs)
    }

    /// Load the artefact and both datasets the run used, refused as `calibrate` refuses them
    /// ([`check_run_data`]), and refused when the RUN's model is beyond the model-independent
    /// scales on them ([`TrustScales`], with `nominal.toml` as the nominal model): a diagnosis of
    /// an absurd model would blame landmarks and effects for what the model gets wrong.
    pub fn data(&self) -> Result<(Artefact, Observations, Observations), RunError> {
        let inputs = &self.summary.inputs;
        let artefact = Artefact::load(&inputs.artefact)?;
        let (cal, val) = inputs.load_data(&artefact)?;
        check_run_data(&self.model, &cal, &val, inputs, &self.summary.options.calibration_options())?;
        let nominal = ArmModel::load(&self.dir.join("nominal.toml"))?;
        let scales = TrustScales::of(&nominal, &cal, &val);
        let rms = |data: &Observations| validate::validate(&self.model, data).overall.rms_mm;
        let beyond = scales.beyond(rms(&cal), rms(&val));
        if !beyond.is_empty() {
            return Err(RunError::NotACalibration(beyond));
        }
        Ok((artefact, cal, val))
    }
}

/// Calibration figures in the summary.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct CalibrationSummary {
    /// RMS distance residual on the calibration data, mm.
    pub rms_mm: f64,
    /// Robust cost Σρ at the solution.
    pub cost: f64,
    /// Distance pairs used.
    pub pairs: usize,
    /// Touches used.
    pub touches: usize,
    /// Each parameter: nominal, calibrated, std, status.
    pub estimates: Vec<Estimate>,
    /// Parameters fixed at nominal because the data cannot determine them.
    pub fixed_unidentifiable: Vec<String>,
    /// Strongly correlated estimated pairs.
    pub correlations: Vec<(String, String, f64)>,
    /// Every solver start.
    pub starts: Vec<StartOutcome>,
}

/// Identifiability in the summary.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct IdentifiabilitySummary {
    /// At the nominal values.
    pub before: Identifiability,
    /// At the solution.
    pub after: Identifiability,
}

/// Validation detail in the summary.
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

/// A finished run: results plus what the report draws.
pub struct Run {
    /// The model calibration started from (input model plus added effects).
    pub nominal: ArmModel,
    /// The summary written to `summary.json`.
    pub summary: Summary,
    /// The calibration itself.
    pub calibration: Fit,
    /// Calibrated model on the validation data.
    pub validation: Validation,
    /// Nominal model on the validation data.
    pub nominal_validation: Validation,
    /// The data, for plots.
    pub artefact: Artefact,
    /// Validation touches, for plots.
    pub validation_data: Observations,
    /// How long each step took.
    pub steps: StepTimes,
}

fn objective_comparison(fit: &Fit, cal: &Observations) -> ObjectiveComparison {
    let all: Vec<_> = fit.model.free.iter().map(|f| f.id).collect();
    let ranges: Vec<f64> = fit.model.free.iter().map(|f| (f.upper - f.lower).max(1e-9)).collect();
    let jacobian = |lever_mm| dense_jacobian(&fit.model, &all, cal, lever_mm).1;
    let (distance, six_dof) = (jacobian(None), jacobian(Some(crate::calib::setup::DEFAULT_LEVER_MM)));
    let names = |jac: &[f64]| -> Vec<String> {
        identify::base_columns(jac, all.len(), &ranges).0.into_iter().map(|c| all[c].to_string()).collect()
    };
    let (by_distance, by_six_dof) = (names(&distance), names(&six_dof));
    let gained = by_six_dof.iter().filter(|p| !by_distance.contains(p)).cloned().collect();
    let variance = fit.rms_mm.powi(2);
    let stds = |jac: &[f64]| -> Vec<Option<f64>> {
        let n = all.len();
        let cols: Vec<usize> =
            fit.estimated.iter().filter_map(|id| all.iter().position(|a| a == id)).collect();
        let rows = jac.len() / n;
        let sub: Vec<f64> = (0..rows).flat_map(|i| cols.iter().map(move |&c| jac[i * n + c])).collect();
        match identify::covariance(&sub, &vec![1.0; rows], cols.len(), variance) {
            Some(c) => (0..cols.len()).map(|k| Some(c[(k, k)].max(0.0).sqrt())).collect(),
            None => vec![None; cols.len()],
        }
    };
    let (sd, s6) = (stds(&distance), stds(&six_dof));
    let std = fit.estimated.iter().enumerate().map(|(k, id)| (id.to_string(), sd[k], s6[k])).collect();
    ObjectiveComparison {
        identifiable_by_distance: by_distance,
        identifiable_by_six_dof: by_six_dof,
        gained_by_orientation: gained,
        std,
    }
}

/// Every refusal of a RUN's inputs before anything is fitted, shared by `calibrate` (on the
/// nominal model) and `diagnose` (on the RUN's calibrated model) so both refuse the same data with
/// the same message: no validation pair, an artefact out of the arm's reach, a validation placement
/// copied from the calibration data, and whatever [`check_data`] refuses (no free parameter, too
/// few distance pairs, non-finite positions, touches without information).
pub fn check_run_data(
    model: &ArmModel,
    cal: &Observations,
    val: &Observations,
    inputs: &RunInputs,
    options: &SolveOptions,
) -> Result<(), RunError> {
    if val.pair_count() == 0 {
        return Err(RunError::NoValidationPairs { path: inputs.validation.clone() });
    }
    let (span, reach) = (cal.landmark_span_mm(), model.reach_mm());
    if span > 2.0 * reach {
        return Err(RunError::OutOfReach { span, reach });
    }
    if let Some((validation, calibration)) = copied_placement(cal, val) {
        return Err(RunError::SameData { validation, calibration });
    }
    check_data(model, cal, options)?;
    Ok(())
}

/// Load the inputs, add `effects` to the model, calibrate, validate and (with `outliers`) compute
/// the per-landmark outlier metrics, whose leave-one-out refits are about a third of the work;
/// with `study_subsets` > 0 also run the dataset-size study with that many random subsets per
/// placement count.
pub fn run(
    inputs: &RunInputs,
    options: &SolveOptions,
    effects: &[Effect],
    study_subsets: usize,
    outliers: bool,
) -> Result<Run, RunError> {
    let absolute =
        |p: &Path| std::fs::canonicalize(p).map_err(|source| RunError::Input { path: p.to_owned(), source });
    let inputs = &RunInputs {
        model: absolute(&inputs.model)?,
        artefact: absolute(&inputs.artefact)?,
        calibration: absolute(&inputs.calibration)?,
        validation: absolute(&inputs.validation)?,
        ..inputs.clone()
    };
    let mut steps = StepTimes::start();
    let mut nominal = ArmModel::load(&inputs.model)?;
    for effect in effects {
        if effect.joint.is_some_and(|j| j >= nominal.joints.len()) {
            return Err(RunError::NoSuchJoint { effect: effect.to_string(), joints: nominal.joints.len() });
        }
        effect.add_to(&mut nominal);
    }
    let artefact = Artefact::load(&inputs.artefact)?;
    let (cal, val) = inputs.load_data(&artefact)?;
    steps.lap("load");
    check_run_data(&nominal, &cal, &val, inputs, options)?;
    check_study_size(&cal, study_subsets)?;
    steps.lap("input checks");
    let fit = calibrate(&nominal, &cal, options)?;
    steps.lap("fit");
    let validation = validate(&fit.model, &val);
    let nominal_validation = validate(&nominal, &val);
    steps.lap("validation");
    let scales = TrustScales::of(&nominal, &cal, &val);
    let mut not_trustworthy = result_problems(&fit, &validation, &scales);
    steps.lap("trust scales");
    let study_rows = (study_subsets > 0).then(|| {
        let calibration = SolveOptions { restarts: Some(0), ..options.clone() };
        study(
            &nominal,
            &cal,
            &val,
            &StudyOptions { subsets: study_subsets, seed: options.seed, calibration, progress: false },
        )
    });
    if let Some(rows) = &study_rows {
        not_trustworthy.extend(study_problems(rows).into_iter().map(|p| format!("study: {p}")));
        steps.lap("study");
    }
    let outliers_skipped = !outliers;
    let outliers = if outliers { landmark_outliers(&fit, &cal, Some(&val), options) } else { Vec::new() };
    steps.lap("outliers");
    let objective_comparison = objective_comparison(&fit, &cal);
    steps.lap("6-DoF comparison");
    let summary = Summary {
        format: RUN_FORMAT.to_string(),
        kincal_version: env!("CARGO_PKG_VERSION").to_string(),
        inputs: inputs.clone(),
        options: SummaryOptions {
            huber_delta_mm: fit.options.huber_delta_mm().unwrap_or_default(),
            restarts: fit.options.restarts,
            seed: options.seed,
            objective: fit.options.objective,
            added_effects: effects.iter().map(|e| e.to_string()).collect(),
        },
        calibration: CalibrationSummary {
            rms_mm: fit.rms_mm,
            cost: fit.cost,
            pairs: cal.landmark_pairs().len(),
            touches: cal.obs.len(),
            estimates: fit.estimates.clone(),
            fixed_unidentifiable: fit.fixed.iter().map(|p| p.to_string()).collect(),
            correlations: fit.correlations.clone(),
            starts: fit.starts.clone(),
        },
        identifiability: IdentifiabilitySummary {
            before: fit.before.clone(),
            after: fit.after.clone().unwrap_or_else(|| fit.before.clone()),
        },
        validation: validation.overall,
        nominal_validation: nominal_validation.overall,
        validation_detail: ValidationDetail {
            per_landmark: validation.per_landmark.clone(),
            nominal_per_landmark: nominal_validation.per_landmark.clone(),
            per_placement: validation.per_placement.clone(),
            nominal_per_placement: nominal_validation.per_placement.clone(),
            repeatability: validation.repeatability.clone(),
        },
        outliers_skipped,
        outliers,
        objective_comparison,
        study: study_rows,
        not_trustworthy,
    };
    Ok(Run {
        nominal,
        summary,
        calibration: fit,
        validation,
        nominal_validation,
        artefact,
        validation_data: val,
        steps,
    })
}

/// Wall time of each step of a run, in order, for `kincal bench`'s breakdown.
#[derive(Clone, Debug)]
pub struct StepTimes {
    last: std::time::Instant,
    /// (step, milliseconds).
    pub ms: Vec<(&'static str, f64)>,
}

impl StepTimes {
    /// Start timing.
    pub fn start() -> StepTimes {
        StepTimes { last: std::time::Instant::now(), ms: Vec::new() }
    }

    /// The step `name` ended now.
    pub fn lap(&mut self, name: &'static str) {
        let now = std::time::Instant::now();
        self.ms.push((name, (now - self.last).as_secs_f64() * 1e3));
        self.last = now;
    }
}

impl Run {
    /// Every validation distance error, named, as `residuals.json` stores it.
    pub fn stored_residuals(&self) -> StoredResiduals {
        let val = &self.validation_data;
        let pairs = self
            .validation
            .errors
            .iter()
            .map(|e| StoredPairError {
                placement: val.groups[e.placement].name.clone(),
                landmarks: (
                    self.artefact.landmarks[e.landmarks.0].id.clone(),
                    self.artefact.landmarks[e.landmarks.1].id.clone(),
                ),
                repeat: val.obs[e.touches.0].repeat,
                error_mm: e.error_mm,
                enc_deg: (val.obs[e.touches.0].q_deg, val.obs[e.touches.1].q_deg),
            })
            .collect();
        StoredResiduals { format: RESIDUALS_FORMAT.to_string(), pairs }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{simulate, SimulationOptions};

    #[test]
    fn validation_from_another_arm_is_not_a_result() {
        let nominal = ArmModel::suta_nominal();
        let ours = simulate(&nominal, &SimulationOptions::default());
        let other = simulate(&nominal, &SimulationOptions { seed: 2, ..SimulationOptions::default() });
        let cal = Observations::from_sessions(&ours.calibration, &ours.artefact);
        let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
        let fit = calibrate(&nominal, &cal, &options).unwrap();
        let val = Observations::from_sessions(&ours.validation, &ours.artefact);
        let scales = TrustScales::of(&nominal, &cal, &val);
        assert!(result_problems(&fit, &validate(&fit.model, &val), &scales).is_empty());
        let foreign = Observations::from_sessions(&other.validation, &ours.artefact);
        let problems = result_problems(&fit, &validate(&fit.model, &foreign), &scales);
        assert!(problems.iter().any(|p| p.contains("another arm")), "{problems:?}");
        assert_eq!(copied_placement(&cal, &val), None);
        assert_eq!(copied_placement(&cal, &cal), Some(("A_O".into(), "A_O".into())));
    }
}
