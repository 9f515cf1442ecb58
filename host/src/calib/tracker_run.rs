//! The whole tracker run: read the sessions, calibrate, validate on held-out sessions (each
//! base refitted) against the nominal model, the noise floor, the data-error candidates and the
//! verdict, as `summary.json` (`kincal-tracker-run/1`) holds them.
//!
//! The nominal figures are the nominal arm with only the tool point (and the bases) fitted on the
//! calibration sessions, as an instrument user would use the vendor's model. The floor is the
//! pooled scatter of repeated poses (rows sharing a `pose` id) in the held-out sessions, else the
//! stated instrument uncertainty (σ per axis, σ = U95/2, so a point's 3-D RMS is σ·√3; from the
//! rows, or `--sigma-mm` for rows that carry none), each
//! scaled by √(1 − 2/n) for the six values of a refitted base; otherwise unknown, and then the
//! model is never said to explain the data.

use crate::calib::fit::{calibrate, CalibError, Estimate, Fit, IdentifiabilityReport};
use crate::calib::nuisance::drift::{DriftSpec, SessionDrift};
use crate::calib::nuisance::tool::{FloatedTool, ToolRotation};
use crate::calib::setup::SolveOptions;
use crate::calib::tracker_errors::{data_error_candidates, sessions, DataError};
use crate::calib::validate::{
    calibration_residuals_mm, errors_in_calibration_session, fit_session_with_tool, orientation_errors_deg,
    session_residuals_mm, validate_orientations, validate_session, AngleStats, ErrorStats, SessionValidation,
};
use crate::data::Observations;
use crate::files::FileError;
use crate::model::effects::Effect;
use crate::model::{ArmModel, ParamId};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Format tag of a tracker run's `summary.json`.
pub const TRACKER_RUN_FORMAT: &str = "kincal-tracker-run/1";
/// Held-out RMS within this factor of the floor: the model explains the data.
pub const EXPLAINS_WITHIN: f64 = 1.10;

/// Why a tracker run failed.
#[derive(Debug, thiserror::Error)]
pub enum TrackerRunError {
    /// An input file was unusable.
    #[error(transparent)]
    Data(#[from] FileError),
    /// The calibration could not run.
    #[error(transparent)]
    Calibration(#[from] CalibError),
    /// `--exclude-point` names no calibration point.
    #[error("--exclude-point {0}: no calibration session and line of that name (expected SESSION:LINE)")]
    UnknownPoint(String),
    /// `--same-base` does not pair a held-out session with a calibration session.
    #[error(
        "--same-base {0}: expected HELD_OUT=CALIBRATION, a held-out session and the calibration session whose \
         instrument placement it shares"
    )]
    SameBase(String),
    /// `--add` names no effect of the library.
    #[error("--add {0}: not an effect of the library (e.g. compliance:2, harmonic:3:2, twist:4, scale)")]
    UnknownEffect(String),
    /// A validation session has the name of a calibration session.
    #[error(
        "session \"{0}\" is in both the calibration and the validation folder: validation must be held out"
    )]
    SameSession(String),
}

/// The inputs of a tracker run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerInputs {
    /// Arm model file.
    pub model: PathBuf,
    /// Folder of calibration sessions.
    pub calibration: PathBuf,
    /// Folder of held-out sessions.
    pub validation: PathBuf,
    /// Sessions whose tool floats.
    pub float_tool: Vec<String>,
    /// The instrument's stated σ per axis, mm, for rows that carry none.
    pub stated_sigma_mm: Option<f64>,
    /// Calibration points left out, `SESSION:LINE` (single bad points).
    #[serde(default)]
    pub exclude_points: Vec<String>,
    /// The 6-DoF probe's stated orientation σ per axis, degrees (`None`: the default).
    #[serde(default)]
    pub orientation_sigma_deg: Option<f64>,
    /// Calibration sessions whose points drift, and how (`--drift-session SESSION[:KIND]`).
    #[serde(default)]
    pub drift_sessions: Vec<DriftSpec>,
    /// Held-out sessions measured from a calibration session's instrument placement,
    /// `HELD_OUT=CALIBRATION` (`--same-base`): validated with that base too (protocol S).
    #[serde(default)]
    pub same_base: Vec<String>,
    /// Effects of the library added to the model (`--add`, e.g. `compliance:2`).
    #[serde(default)]
    pub add: Vec<String>,
}

/// A held-out session validated with a calibration session's base (protocol S: the same
/// instrument placement, no base refitted).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SameBaseFigures {
    /// The calibration session whose base the held-out session shares.
    pub calibration_session: String,
    /// The calibrated model with that session's calibrated base.
    pub calibrated: ErrorStats,
    /// The nominal model (tool fitted) with that session's base from the nominal fit.
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
    /// The calibrated model's orientation figures (`rms_deg, mean_deg, max_deg`), 6-DoF probes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation: Option<AngleStats>,
    /// The nominal model's orientation figures on the same session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub nominal_orientation: Option<AngleStats>,
    /// With a calibration session's base (`--same-base`, protocol S).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub same_base: Option<SameBaseFigures>,
}

/// Held-out figures.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerValidation {
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

/// The noise floor of the held-out sessions.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerFloor {
    /// `repeated poses`, `stated uncertainty` or `unknown`.
    pub source: String,
    /// Expected held-out RMS of a perfect model, mm.
    pub rms_mm: Option<f64>,
}

/// `summary.json` of a tracker run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerSummary {
    /// Always [`TRACKER_RUN_FORMAT`].
    pub format: String,
    /// kincal's version.
    pub kincal_version: String,
    /// Inputs.
    pub inputs: TrackerInputs,
    /// Joints of the arm.
    pub joints: usize,
    /// Calibration sessions and their points.
    pub calibration_sessions: BTreeMap<String, usize>,
    /// Position error on the calibration sessions.
    pub fit: ErrorStats,
    /// Orientation error on the calibration sessions (6-DoF probes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation_fit: Option<AngleStats>,
    /// The probe's orientation on the flange (6-DoF probes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool_rotation: Option<ToolRotation>,
    /// Parameter estimates.
    pub estimates: Vec<Estimate>,
    /// Floated tools.
    pub tool_offsets: Vec<FloatedTool>,
    /// Drifting sessions' rates.
    #[serde(default)]
    pub drifts: Vec<SessionDrift>,
    /// What the data cannot separate.
    pub identifiability: IdentifiabilityReport,
    /// Held-out figures.
    pub validation: TrackerValidation,
    /// The floor.
    pub floor: TrackerFloor,
    /// Data-error candidates, best first.
    pub data_errors: Vec<DataError>,
    /// The verdict, in words.
    pub verdict: Vec<String>,
    /// Warnings of the readers.
    pub warnings: Vec<String>,
}

/// One point as the calibrated model leaves it.
#[derive(Clone, Debug)]
pub struct PointResidual {
    /// Line in the session's file.
    pub line: usize,
    /// Pose id, when the file has a `pose` column.
    pub pose: Option<String>,
    /// Time of the measurement, s, when the file has a `time_s` column.
    pub time_s: Option<f64>,
    /// Joint angles, degrees.
    pub q_deg: Vec<f64>,
    /// Measured − predicted, in the robot's base frame, mm.
    pub residual_mm: [f64; 3],
    /// Orientation error, degrees (6-DoF probes).
    pub orientation_error_deg: Option<f64>,
}

/// The residuals of one session's points, in file order.
#[derive(Clone, Debug)]
pub struct SessionResiduals {
    /// Session name.
    pub name: String,
    /// Its points.
    pub points: Vec<PointResidual>,
}

/// A finished tracker run.
#[derive(Clone, Debug)]
pub struct TrackerRun {
    /// The nominal model as loaded.
    pub nominal: ArmModel,
    /// The calibration.
    pub calibration: Fit,
    /// The summary.
    pub summary: TrackerSummary,
    /// Every held-out point's residual (its session's base refitted), per session, as
    /// `validation.sessions[]` summarises them.
    pub held_out: Vec<SessionResiduals>,
    /// Every calibration point's residual at the solution, per session, as `fit` summarises them.
    pub calibration_residuals: Vec<SessionResiduals>,
}

fn pooled(parts: &[SessionValidation]) -> ErrorStats {
    ErrorStats::pooled(&parts.iter().map(SessionValidation::stats).collect::<Vec<_>>())
}

/// The residuals of `fit` on held-out block `b` of `val`, its frame (and tool offset
/// `offset_mm`) refitted.
fn held_out_points(fit: &Fit, val: &Observations, b: usize, offset_mm: [f64; 3]) -> SessionResiduals {
    let residuals = session_residuals_mm(&fit.model, val, b, offset_mm);
    let angles = fit.tool_rotation.as_ref().map_or_else(
        || vec![None; val.blocks[b].members.len()],
        |t| orientation_errors_deg(&fit.model, val, b, [0.0; 3], &t.rotation()),
    );
    session_residuals(val, b, residuals, angles)
}

/// Block `b`'s points with their residuals and orientation errors.
fn session_residuals(
    data: &Observations,
    b: usize,
    residuals: Vec<Vector3<f64>>,
    angles: Vec<Option<f64>>,
) -> SessionResiduals {
    let points = data.blocks[b]
        .members
        .iter()
        .map(|&k| &data.obs[k])
        .zip(residuals)
        .zip(angles)
        .map(|((p, r), angle)| PointResidual {
            line: p.line,
            pose: p.pose.clone(),
            time_s: p.time_s,
            q_deg: p.q_deg.to_vec(),
            residual_mm: r.into(),
            orientation_error_deg: angle,
        })
        .collect();
    SessionResiduals { name: data.block_name(b), points }
}

/// The held-out floor (see the module's doc comment).
pub fn floor(val: &Observations, stated_sigma_mm: Option<f64>) -> TrackerFloor {
    let (mut sum, mut dof) = (0.0, 0usize);
    let mut fit_share = Vec::new();
    for b in sessions(val) {
        let members = &val.blocks[b].members;
        let mut groups: BTreeMap<&str, Vec<Vector3<f64>>> = BTreeMap::new();
        for p in members.iter().map(|&k| &val.obs[k]) {
            if let (Some(pose), Some(x)) = (&p.pose, p.point_mm()) {
                groups.entry(pose).or_default().push(x);
            }
        }
        for g in groups.values().filter(|g| g.len() > 1) {
            let mean = g.iter().sum::<Vector3<f64>>() / g.len() as f64;
            sum += g.iter().map(|v| (v - mean).norm_squared()).sum::<f64>();
            dof += g.len() - 1;
        }
        fit_share.push((1.0 - 2.0 / members.len().max(3) as f64, members.len()));
    }
    let points: usize = fit_share.iter().map(|f| f.1).sum();
    let shrink =
        (fit_share.iter().map(|f| f.0 * f.1 as f64).sum::<f64>() / points.max(1) as f64).max(0.0).sqrt();
    if dof > 0 {
        return TrackerFloor {
            source: "repeated poses".into(),
            rms_mm: Some((sum / dof as f64).sqrt() * shrink),
        };
    }
    let sigmas: Vec<f64> = sessions(val)
        .into_iter()
        .flat_map(|b| val.blocks[b].members.iter().map(|&k| &val.obs[k]))
        .filter_map(|p| p.sigma_mm.or(stated_sigma_mm))
        .collect();
    if !sigmas.is_empty() && sigmas.len() == points {
        let mean_square = sigmas.iter().map(|s| 3.0 * s * s).sum::<f64>() / sigmas.len() as f64;
        return TrackerFloor {
            source: "stated uncertainty".into(),
            rms_mm: Some(mean_square.sqrt() * shrink),
        };
    }
    TrackerFloor { source: "unknown".into(), rms_mm: None }
}

/// The nominal arm with only its tool point free.
fn tool_only(nominal: &ArmModel) -> ArmModel {
    let mut m = nominal.clone();
    m.free.retain(|f| matches!(f.id, ParamId::Tcp(_)));
    m
}

/// `cal` without the points named `SESSION:LINE` (`--exclude-point`).
pub fn without_points(cal: &Observations, names: &[String]) -> Result<Observations, TrackerRunError> {
    let mut dropped = vec![false; cal.obs.len()];
    for name in names {
        let found = cal.find_point(name);
        if found.is_empty() {
            return Err(TrackerRunError::UnknownPoint(name.clone()));
        }
        for k in found {
            dropped[k] = true;
        }
    }
    Ok(cal.without(|k| dropped[k]))
}

/// Load, calibrate, validate, score the data errors and say what it means.
pub fn run_tracker(
    inputs: &TrackerInputs,
    huber_delta_mm: Option<f64>,
) -> Result<TrackerRun, TrackerRunError> {
    let mut nominal = ArmModel::load(&inputs.model)?;
    for name in &inputs.add {
        Effect::parse(name).ok_or_else(|| TrackerRunError::UnknownEffect(name.clone()))?.add_to(&mut nominal);
    }
    let cal = crate::data::tracker::load_dir(&inputs.calibration)?;
    let val = crate::data::tracker::load_dir(&inputs.validation)?;
    run_on(nominal, &cal, &val, inputs, huber_delta_mm)
}

/// [`run_tracker`] on sessions already read.
pub fn run_on(
    nominal: ArmModel,
    cal: &Observations,
    val: &Observations,
    inputs: &TrackerInputs,
    huber_delta_mm: Option<f64>,
) -> Result<TrackerRun, TrackerRunError> {
    let kept = without_points(cal, &inputs.exclude_points)?;
    let cal = &kept;
    if let Some(g) = val.groups.iter().find(|v| cal.find_group(&v.name).is_some()) {
        return Err(TrackerRunError::SameSession(g.name.clone()));
    }
    if val.joints != nominal.joints.len() {
        return Err(CalibError::JointCount {
            kind: "tracker",
            record: "have",
            data: val.joints,
            what: "joint columns (q1_deg …)",
            model: nominal.joints.len(),
        }
        .into());
    }
    let mut same_base = BTreeMap::new();
    for pair in &inputs.same_base {
        let named =
            pair.split_once('=').filter(|(v, c)| val.find_block(v).is_some() && cal.find_block(c).is_some());
        let Some((held_out, calibration)) = named else {
            return Err(TrackerRunError::SameBase(pair.clone()));
        };
        same_base.insert(held_out.to_string(), calibration.to_string());
    }
    let cal_float: Vec<String> =
        inputs.float_tool.iter().filter(|n| cal.find_group(n).is_some()).cloned().collect();
    let val_float: Vec<String> =
        inputs.float_tool.iter().filter(|n| val.find_group(n).is_some()).cloned().collect();
    if let Some(n) = inputs.float_tool.iter().find(|n| !cal_float.contains(n) && !val_float.contains(n)) {
        return Err(CalibError::UnknownSession(n.clone()).into());
    }
    let options = SolveOptions {
        huber_delta_mm,
        float_tool: cal_float,
        orientation_sigma_deg: inputs.orientation_sigma_deg,
        drift_sessions: inputs.drift_sessions.clone(),
        ..SolveOptions::default()
    };
    let fit = calibrate(&nominal, cal, &options)?;
    let reference = calibrate(&tool_only(&nominal), cal, &options)?;
    // The session's tool offset (its own when floated) and its figures.
    let validate = |model: &ArmModel, b: usize| {
        if val_float.contains(&val.block_name(b)) {
            let (tool, figures) = fit_session_with_tool(model, val, b);
            (tool.offset_mm, figures)
        } else {
            ([0.0; 3], validate_session(model, val, b, [0.0; 3]))
        }
    };
    let orientations = |fit: &Fit, b: usize, offset_mm: [f64; 3]| {
        fit.tool_rotation
            .as_ref()
            .and_then(|t| validate_orientations(&fit.model, val, b, offset_mm, &t.rotation()))
    };
    let mut verdict = Vec::new();
    let mut session_figures = Vec::new();
    let mut held_out = Vec::new();
    let (mut calibrated_parts, mut nominal_parts, mut angle_parts) = (Vec::new(), Vec::new(), Vec::new());
    for b in sessions(val) {
        let name = val.block_name(b);
        let (offset_mm, c) = validate(&fit.model, b);
        let n = validate(&reference.model, b).1;
        held_out.push(held_out_points(&fit, val, b, offset_mm));
        let orientation = orientations(&fit, b, [0.0; 3]);
        let nominal_orientation = orientations(&reference, b, [0.0; 3]);
        angle_parts.extend(orientation);
        let transfers = c.rms_mm <= n.rms_mm;
        if !transfers {
            verdict.push(format!(
                "the calibration does not transfer to session {}: {:.4} mm calibrated vs {:.4} mm nominal (base refitted)",
                name, c.rms_mm, n.rms_mm
            ));
        }
        let same_base = same_base.get(&name).and_then(|calibration| {
            let stats = |fit: &Fit| {
                errors_in_calibration_session(fit, cal, calibration, val, b).map(|e| ErrorStats::of(&e))
            };
            Some(SameBaseFigures {
                calibration_session: calibration.clone(),
                calibrated: stats(&fit)?,
                nominal: stats(&reference)?,
            })
        });
        calibrated_parts.push(c.clone());
        nominal_parts.push(n.clone());
        session_figures.push(SessionFigures {
            calibrated: c,
            nominal: n,
            transfers,
            orientation,
            nominal_orientation,
            same_base,
        });
    }
    let overall = pooled(&calibrated_parts);
    let floor = floor(val, inputs.stated_sigma_mm);
    let data_errors = data_error_candidates(
        &nominal,
        cal,
        val,
        &fit,
        &SolveOptions { float_tool: inputs.float_tool.clone(), ..options.clone() },
    );
    if let Some(best) = data_errors.iter().find(|d| d.significant) {
        verdict.push(format!("data error: {}; apply it with {}", best.text, best.action));
    }
    match floor.rms_mm {
        Some(f) if overall.rms_mm <= EXPLAINS_WITHIN * f => verdict.push(format!(
            "the model explains the held-out data: {:.4} mm against a floor of {f:.4} mm ({})",
            overall.rms_mm, floor.source
        )),
        Some(f) => verdict.push(format!(
            "the model is incomplete: {:.4} mm held out against a floor of {f:.4} mm ({}); the cause is not in the model",
            overall.rms_mm, floor.source
        )),
        None => verdict.push(format!(
            "the floor is unknown (no repeated poses, no stated uncertainty): {:.4} mm held out cannot be called explained",
            overall.rms_mm
        )),
    }
    let fit_points = fit.stats.points.unwrap_or_default();
    let summary = TrackerSummary {
        format: TRACKER_RUN_FORMAT.into(),
        kincal_version: env!("CARGO_PKG_VERSION").into(),
        inputs: inputs.clone(),
        joints: nominal.joints.len(),
        calibration_sessions: sessions(cal)
            .into_iter()
            .map(|b| (cal.block_name(b), cal.blocks[b].members.len()))
            .collect(),
        fit: fit_points,
        orientation_fit: fit.stats.orientations,
        tool_rotation: fit.tool_rotation,
        estimates: fit.estimates.clone(),
        tool_offsets: fit.tool_offsets.clone(),
        drifts: fit.drifts.clone(),
        identifiability: fit.identifiability(),
        validation: TrackerValidation {
            sessions: session_figures,
            overall,
            nominal_overall: pooled(&nominal_parts),
            orientation_overall: AngleStats::pooled(&angle_parts),
        },
        floor,
        data_errors,
        verdict,
        warnings: cal.warnings.iter().chain(&val.warnings).cloned().collect(),
    };
    let calibration_residuals = sessions(cal)
        .into_iter()
        .zip(calibration_residuals_mm(&fit, cal))
        .map(|(b, residuals)| session_residuals(cal, b, residuals, vec![None; cal.blocks[b].members.len()]))
        .collect();
    Ok(TrackerRun { nominal, calibration: fit, summary, held_out, calibration_residuals })
}
