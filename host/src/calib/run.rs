//! `kincal calibrate`: the whole job from input files to results, for every kind of data — read
//! the folders (artefact placements, tracker sessions, or both), calibrate, validate on the held-out
//! folder (distances of artefact touches; points of tracker sessions, each frame refitted) against
//! the nominal model, the floor, the data-error candidates, whether the figures are a result, and
//! the verdict, as [`Summary`] holds them. Writing the RUN folder is [`crate::store`]'s job.
//!
//! The nominal figures of tracker sessions are the nominal arm with only the tool point (and the
//! frames) fitted on the calibration data, as an instrument user would use the vendor's model.

use crate::calib::diagnose::data_errors::sessions::{data_error_candidates_with, TakenOfFit};
use crate::calib::diagnose::Measure;
use crate::calib::error::CalibError;
use crate::calib::error_stats::{AngleStats, ErrorStats};
use crate::calib::fit::{
    calibrate_with_reference_on, check_data_sharing, dense_jacobian, Fit, SessionSums, SharedTerms,
    ToolFirstFit,
};
use crate::calib::floor::{gap, noise_floor, point_floor};
use crate::calib::identify;
use crate::calib::nuisance::frame::Frame;
use crate::calib::nuisance::tool::ModelPoses;
use crate::calib::outliers::outliers_with as outlier_metrics;
use crate::calib::setup::{SolveOptions, DEFAULT_LEVER_MM};
use crate::calib::study::{check_study_size, study, study_problems, StudyError, StudyOptions};
use crate::calib::summary::*;
use crate::calib::trust::{result_problems, TrustScales};
use crate::calib::validate::{
    angle_stats, calibration_residuals_mm, errors_in_calibration_session, orientation_errors_in_frame_deg,
    session_probe_rotation, undetermined_rotation, validate, SessionFits, SessionValidation, Validation,
};
use crate::data::{load_folder, Artefact, Observations, Purpose};
use crate::files::FileError;
use crate::model::effects::Effect;
use crate::model::{ArmModel, ParamId};
use nalgebra::Vector3;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use crate::calib::floor::EXPLAINS_WITHIN;

/// Most calibration sessions (instrument placements) one calibration takes: each adds a base of
/// 6 unknowns to one dense problem (256 sessions: 1 536 unknowns, about 19 MB per matrix).
pub const MAX_CALIBRATION_SESSIONS: usize = 256;

/// Why a run failed.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// An input file was unusable.
    #[error(transparent)]
    Data(#[from] FileError),
    /// One pose id names two different arm poses in one session.
    #[error(
        "{path}:{line}: column `pose`: pose id {pose} was given at line {first_line} too, but joint {joint} differs \
         by {differs_deg:.3}° between them: rows with one pose id must be repeats of one arm pose (their joint angles \
         within {}°), else the floor from repeats is not a floor; give each pose its own id",
        crate::calib::trust::SAME_POSE_DEG
    )]
    RepeatedPose {
        /// The session file.
        path: PathBuf,
        /// The later row's line.
        line: usize,
        /// The first row's line.
        first_line: usize,
        /// The pose id.
        pose: String,
        /// The joint (1-based) that differs most.
        joint: usize,
        /// By how much, degrees.
        differs_deg: f64,
    },
    /// Every calibration session's tool floats: the shared tool point is determined by none.
    #[error(
        "--float-tool: every calibration session floats its tool ({0}), so no session determines the shared tool \
         point the held-out sessions are predicted with; float the tool in the sessions where it was re-mounted only"
    )]
    EveryToolFloated(String),
    /// More calibration sessions than one calibration takes.
    #[error(
        "{folder}: {count} calibration sessions (files), at most {MAX_CALIBRATION_SESSIONS} are taken: each \
         session is one placement of the instrument with its own unknown base (6 unknowns), so {count} sessions \
         of {median_points} point{} (median) leave little for the arm and make the problem too large to solve \
         here; if the files are the poses of fewer placements (one file per pose?), put each placement's \
         points into one file",
        if *median_points == 1 { "" } else { "s" }
    )]
    TooManySessions {
        /// The calibration folder.
        folder: PathBuf,
        /// Its sessions.
        count: usize,
        /// Their median number of points.
        median_points: usize,
    },
    /// A held-out session too small to fit its own base.
    #[error(
        "{path}: held-out session {session} has {points} point{}: its own base (6 unknowns) needs at least 3 points \
         to be fitted, so its error cannot be scored; measure more points there, move it to the calibration folder \
         if it shares no base, or name the calibration session it shares its base with (--same-base {session}=CAL)",
        if *points == 1 { "" } else { "s" }
    )]
    HeldOutTooSmall {
        /// The session file.
        path: PathBuf,
        /// The session.
        session: String,
        /// Its points.
        points: usize,
    },
    /// The calibration could not run.
    #[error(transparent)]
    Calibration(#[from] CalibError),
    /// The sessions name joints or tips the model does not have.
    #[error(transparent)]
    Names(#[from] crate::data::BindError),
    /// `--exclude-landmark`, `--exclude-block` or `--exclude-point` names nothing in the data.
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
    /// A validation session has the name of a calibration session.
    #[error(
        "session \"{0}\" is in both the calibration and the validation folder: validation must be held out"
    )]
    SameSession(String),
    /// `--same-base` does not pair a held-out session with a calibration session.
    #[error(
        "--same-base {0}: expected HELD_OUT=CALIBRATION, a held-out session and the calibration session whose \
         instrument placement it shares"
    )]
    SameBase(String),
    /// An option that has no meaning on the data given (named, with the kind of data).
    #[error("{option}: not for {kind} data: {why}")]
    NotForKind {
        /// The option, as the command line spells it.
        option: String,
        /// The kind of data it was given (`artefact`, `tracker`, `mixed`).
        kind: &'static str,
        /// What it needs.
        why: String,
    },
    /// An option that would change nothing on the data given (named, with why).
    #[error("{option}: it would change nothing: {why}")]
    NoEffect {
        /// The option, as the command line spells it.
        option: String,
        /// Why nothing would change.
        why: String,
    },
    /// `--add` names no effect of the library.
    #[error("--add {0}: not an effect of the library (e.g. compliance:2, harmonic:3:2, twist:4, scale)")]
    UnknownEffect(String),
    /// The model's figures on the data are beyond the model-independent scales (see
    /// [`crate::calib::trust`]): nothing computed from the model is a result.
    #[error(
        "the model does not describe these touches; nothing computed from it is a result:\n  - {}",
        .0.join("\n  - ")
    )]
    NotACalibration(Vec<String>),
    /// An effect added on the command line names a joint or a body the model does not have,
    /// or needs a mass table it has not.
    #[error("--add {effect}: {why} (model {})", model.display())]
    EffectNotInModel {
        /// The effect.
        effect: String,
        /// What the model lacks, and what it has.
        why: String,
        /// The model file.
        model: PathBuf,
    },
    /// The sessions were measured on two arms, or some name their arm and others do not.
    #[error(transparent)]
    MixedArms(#[from] crate::trace::MixedArms),
    /// The data are not those the RUN was made from.
    #[error("{path}: {what}; the data changed since the calibration (calibrate again)")]
    DataChanged {
        /// The file or folder.
        path: PathBuf,
        /// What differs.
        what: String,
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

impl RunInputs {
    /// The nominal model (the model file's arm with the added effects).
    pub fn nominal(&self) -> Result<ArmModel, RunError> {
        let mut nominal = ArmModel::load(&self.model)?;
        for name in &self.add {
            let effect = Effect::parse(name).ok_or_else(|| RunError::UnknownEffect(name.clone()))?;
            if let Some(why) = effect.check_in(&nominal) {
                return Err(RunError::EffectNotInModel {
                    effect: effect.to_string(),
                    why,
                    model: self.model.clone(),
                });
            }
            effect.add_to(&mut nominal);
        }
        Ok(nominal)
    }

    /// Both folders, as read: the calibration and validation observations (the artefact file
    /// read when given).
    pub fn read_folders(&self) -> Result<(Observations, Observations), RunError> {
        let artefact = self.artefact.as_deref().map(Artefact::load).transpose()?;
        let mut cal = load_folder(&self.calibration, artefact.as_ref(), Purpose::Calibration)?;
        let mut val = load_folder(&self.validation, artefact.as_ref(), Purpose::Validation)?;
        if cal.names.is_some() || val.names.is_some() {
            let model = ArmModel::load(&self.model)?;
            cal.bind(&model)?;
            val.bind(&model)?;
        }
        Ok((cal, val))
    }

    /// The observations with the exclusions applied: landmarks out of both folders, blocks and
    /// observations out of the calibration folder. Taken by value: without exclusions they are
    /// handed back as they came (a copy of a calibration folder is megabytes of fresh memory).
    pub fn exclude(
        &self,
        mut cal: Observations,
        mut val: Observations,
    ) -> Result<(Observations, Observations), RunError> {
        for id in &self.exclude_landmarks {
            let Some(l) = cal.landmark_index(id) else {
                let artefact = self.artefact.as_deref().unwrap_or(Path::new("the artefact"));
                return Err(RunError::Exclusion(format!(
                    "--exclude-landmark {id}: no landmark \"{id}\" in {}",
                    artefact.display()
                )));
            };
            cal = cal.without_landmark(l);
            val = val.without_landmark(l);
        }
        for block in &self.exclude_blocks {
            let Some(b) = cal.find_block(block) else {
                return Err(RunError::Exclusion(format!(
                    "--exclude-block {block}: expected PLACEMENT/REPEAT of a calibration block, or a calibration \
                     session, in {}",
                    self.calibration.display()
                )));
            };
            cal = cal.without(|k| cal.obs[k].block == b);
        }
        if self.exclude_points.is_empty() {
            return Ok((cal, val));
        }
        Ok((exclude_points(&cal, &self.exclude_points)?, val))
    }

    /// The solve options of `options` with this setup (the floated tools of the calibration
    /// groups, the drifts, the probe's σ).
    pub fn solve_options(&self, options: &SolveOptions, cal: &Observations) -> SolveOptions {
        SolveOptions {
            float_tool: self.float_tool.iter().filter(|n| cal.find_group(n).is_some()).cloned().collect(),
            drift_sessions: self.drift_sessions.clone(),
            orientation_sigma_deg: self.orientation_sigma_deg,
            ..options.clone()
        }
    }
}

/// `cal` without the observations named `SESSION:LINE` or `PLACEMENT/REPEAT/LANDMARK`
/// (`--exclude-point`).
pub fn exclude_points(cal: &Observations, names: &[String]) -> Result<Observations, RunError> {
    let mut dropped = vec![false; cal.obs.len()];
    for name in names {
        let found = cal.find_point(name);
        if found.is_empty() {
            return Err(RunError::Exclusion(format!(
                "--exclude-point {name}: no calibration observation of that name (expected SESSION:LINE, or \
                 PLACEMENT/REPEAT/LANDMARK for a touch)"
            )));
        }
        found.into_iter().for_each(|k| dropped[k] = true);
    }
    Ok(cal.without(|k| dropped[k]))
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

/// A finished run: results plus what the report draws.
pub struct Run {
    /// The model calibration started from (input model plus added effects).
    pub nominal: ArmModel,
    /// The summary written to `summary.json`.
    pub summary: Summary,
    /// The calibration itself.
    pub calibration: Fit,
    /// Calibrated and nominal model on the held-out distances (artefact placements).
    pub distances: Option<(Validation, Validation)>,
    /// Every held-out point's residual (its session's frame refitted), per session.
    pub held_out: Vec<SessionResiduals>,
    /// Every calibration point's residual at the solution, per session.
    pub calibration_residuals: Vec<SessionResiduals>,
    /// The held-out observations, for plots.
    pub validation_data: Observations,
    /// How long each step took.
    pub steps: StepTimes,
}

/// The first validation placement that copies a calibration placement touch for touch.
fn copied_placement(cal: &Observations, val: &Observations) -> Option<(String, String)> {
    let key = |data: &Observations, p: usize| -> Vec<(usize, u32, Vec<u64>)> {
        let mut v: Vec<_> = data
            .obs
            .iter()
            .filter(|t| t.group == p && t.landmark().is_some())
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

/// Every refusal of a run's data before anything is fitted, shared by `calibrate` (on the
/// nominal model) and `diagnose` (on the RUN's calibrated model) so both refuse the same data with
/// the same message: sessions of two arms, a held-out artefact folder without a distance, an artefact out of the arm's
/// reach, a validation placement copied from the calibration data, a session in both folders,
/// and whatever [`check_data`](crate::calib::fit::check_data) refuses.
pub fn check_run_data(
    model: &ArmModel,
    cal: &Observations,
    val: &Observations,
    inputs: &RunInputs,
    options: &SolveOptions,
) -> Result<(), RunError> {
    check_run_data_on(model, cal, val, inputs, options, &ToolFirstFit::default(), None)
}

/// [`check_run_data`], the nominal arm's closed-form frames taken from (and kept in) `start` and
/// the terms of `cal` from `terms` when given (built there by this check).
fn check_run_data_on<'a>(
    model: &ArmModel,
    cal: &'a Observations,
    val: &Observations,
    inputs: &RunInputs,
    options: &SolveOptions,
    start: &ToolFirstFit,
    terms: Option<&'a SharedTerms<'a>>,
) -> Result<(), RunError> {
    cal.one_arm(&[val])?;
    let touches = |d: &Observations| d.obs.iter().any(|o| o.landmark().is_some());
    if touches(val) && val.pair_count() == 0 {
        return Err(RunError::NoValidationPairs { path: inputs.validation.clone() });
    }
    let (span, reach) = (cal.landmark_span_mm(), model.reach_mm());
    if touches(cal) && span > 2.0 * reach {
        return Err(RunError::OutOfReach { span, reach });
    }
    if let Some((validation, calibration)) = copied_placement(cal, val) {
        return Err(RunError::SameData { validation, calibration });
    }
    if let Some(b) = val.sessions().into_iter().find(|&b| cal.find_block(&val.block_name(b)).is_some()) {
        return Err(RunError::SameSession(val.block_name(b)));
    }
    if !val.obs.is_empty() && val.joints != model.joints.len() {
        let tracker = val.point_count() > 0;
        return Err(CalibError::JointCount {
            kind: if tracker { "tracker" } else { "artefact" },
            record: if tracker { "have" } else { "record" },
            data: val.joints,
            what: if tracker { "joint columns (q1_deg …)" } else { "encoder angles" },
            model: model.joints.len(),
        }
        .into());
    }
    for data in [cal, val] {
        check_pose_ids(data)?;
    }
    let sessions: Vec<String> = cal
        .sessions()
        .into_iter()
        .filter(|&b| cal.blocks[b].members.iter().any(|&k| cal.obs[k].point_mm().is_some()))
        .map(|b| cal.block_name(b))
        .collect();
    if !sessions.is_empty() && sessions.iter().all(|s| options.float_tool.contains(s)) {
        return Err(RunError::EveryToolFloated(sessions.join(", ")));
    }
    if sessions.len() > MAX_CALIBRATION_SESSIONS {
        let mut points: Vec<usize> =
            cal.sessions().into_iter().map(|b| cal.blocks[b].members.len()).collect();
        points.sort_unstable();
        return Err(RunError::TooManySessions {
            folder: inputs.calibration.clone(),
            count: sessions.len(),
            median_points: points[points.len() / 2],
        });
    }
    for b in val.sessions() {
        let (name, members) = (val.block_name(b), &val.blocks[b].members);
        let points = members.iter().filter(|&&k| val.obs[k].point_mm().is_some()).count();
        let shares = inputs.same_base.iter().any(|pair| pair.split_once('=').is_some_and(|(v, _)| v == name));
        if points > 0 && points < 3 && !shares {
            let path = val.groups[val.blocks[b].group].source.clone();
            return Err(RunError::HeldOutTooSmall { path, session: name, points });
        }
    }
    check_data_sharing(model, cal, cal.encoders(), options, start, terms)?;
    Ok(())
}

/// Refuse a pose id given to two different arm poses in one group (a joint apart by more than
/// [`crate::calib::trust::SAME_POSE_DEG`]; a repeat reads the same angles to the encoders' noise) (see [`RunError::RepeatedPose`]).
fn check_pose_ids(data: &Observations) -> Result<(), RunError> {
    let mut first: BTreeMap<(usize, &str), usize> = BTreeMap::new();
    for (k, o) in data.obs.iter().enumerate() {
        let Some(pose) = o.pose.as_deref() else { continue };
        let Some(&j) = first.get(&(o.group, pose)) else {
            first.insert((o.group, pose), k);
            continue;
        };
        let earlier = &data.obs[j];
        let differs = o.q_deg.iter().zip(earlier.q_deg.iter()).map(|(a, b)| (a - b).abs()).enumerate();
        let Some((joint, differs_deg)) = differs.max_by(|a, b| a.1.total_cmp(&b.1)) else { continue };
        if differs_deg > crate::calib::trust::SAME_POSE_DEG {
            return Err(RunError::RepeatedPose {
                path: data.groups[o.group].source.clone(),
                line: o.line,
                first_line: earlier.line,
                pose: pose.to_string(),
                joint: joint + 1,
                differs_deg,
            });
        }
    }
    Ok(())
}

/// Every option the data given cannot use, refused naming the option and the kind of data
/// (nothing is silently ignored): `--objective six-dof` without an orientation (relative
/// orientation of artefact touches, or a 6-DoF probe's), `--orientation-sigma-deg` without a
/// probe orientation, `--sigma-mm` and `--same-base` without held-out tracker sessions,
/// `--drift-session` on an artefact placement, `--exclude-landmark` without artefact touches.
pub fn check_options(
    cal: &Observations,
    val: &Observations,
    inputs: &RunInputs,
    options: &SolveOptions,
) -> Result<(), RunError> {
    let kind = cal.kind().unwrap_or(crate::data::DataKind::Artefact).word();
    let refuse =
        |option: &str, why: &str| RunError::NotForKind { option: option.into(), kind, why: why.into() };
    let touches = |d: &Observations| d.obs.iter().any(|o| o.landmark().is_some());
    let oriented = cal.obs.iter().any(|o| o.orientation().is_some());
    let held_out_points = val.point_count() > 0;
    if matches!(options.objective, Some(crate::calib::setup::Objective::SixDof { .. }))
        && !touches(cal)
        && !oriented
    {
        return Err(refuse(
            "--objective six-dof",
            "it fits orientations: the relative orientation of artefact touches, or a 6-DoF probe's (qw,qx,qy,qz \
             columns), and these calibration sessions carry neither",
        ));
    }
    if inputs.orientation_sigma_deg.is_some() && !oriented {
        return Err(refuse(
            "--orientation-sigma-deg",
            "it states a 6-DoF probe's orientation σ, and the calibration data carry no probe orientation (qw,qx,qy,qz)",
        ));
    }
    if inputs.stated_sigma_mm.is_some() && !held_out_points {
        return Err(refuse(
            "--sigma-mm",
            "it states the instrument's σ of tracker points; the floor of artefact distances comes from repeated touches",
        ));
    }
    let all_stated = val.obs.iter().filter(|o| o.point_mm().is_some()).all(|o| o.sigma_mm.is_some());
    if inputs.stated_sigma_mm.is_some() && held_out_points && all_stated {
        return Err(RunError::NoEffect {
            option: "--sigma-mm".into(),
            why: "every held-out point states its own σ (a sigma_mm or u95_mm column), which the floor uses"
                .into(),
        });
    }
    if !inputs.same_base.is_empty() && !held_out_points {
        return Err(refuse(
            "--same-base",
            "it pairs a held-out tracker session with a calibration session's frame",
        ));
    }
    for spec in &inputs.drift_sessions {
        let touched =
            cal.find_group(&spec.session).is_some_and(|g| cal.groups[g].kind == crate::data::Kind::Artefact);
        if touched {
            return Err(refuse(
                &format!("--drift-session {spec}"),
                "a drift is fitted against a session's time_s or temp_C, which artefact placements do not carry",
            ));
        }
    }
    if !inputs.exclude_landmarks.is_empty() && !touches(cal) && !touches(val) {
        return Err(refuse("--exclude-landmark", "the data hold no artefact landmarks (tracker sessions)"));
    }
    Ok(())
}

/// Check that `cal` and `val` (read with the run's exclusions) are the data `summary` was made
/// from: the same groups with the same observation counts, the same held-out sessions, and, when
/// the setup was calibrated again on them, `calibration_rms_mm` equal to the stored one.
pub fn check_same_data(
    summary: &Summary,
    cal: &Observations,
    val: &Observations,
    calibration_rms_mm: Option<f64>,
) -> Result<(), RunError> {
    let changed = |path: &Path, what: String| RunError::DataChanged { path: path.into(), what };
    let source = |data: &Observations, b: usize| data.groups[data.blocks[b].group].source.clone();
    for (name, count) in &summary.calibration.groups {
        match cal.find_group(name) {
            None => {
                return Err(changed(
                    &summary.inputs.calibration,
                    format!("calibration group {name} is no longer there"),
                ))
            }
            Some(g) if cal.group_members(g).len() != *count => {
                let now = cal.group_members(g).len();
                return Err(changed(&cal.groups[g].source, format!("{count} observations used, {now} now")));
            }
            Some(_) => {}
        }
    }
    if !summary.calibration.groups.is_empty() {
        if let Some(g) =
            (0..cal.groups.len()).find(|&g| !summary.calibration.groups.contains_key(&cal.groups[g].name))
        {
            return Err(changed(&cal.groups[g].source, "a calibration group the run did not use".into()));
        }
    }
    for f in summary.held_out_sessions() {
        let name = &f.calibrated.name;
        let Some(b) = val.find_block(name) else {
            return Err(changed(
                &summary.inputs.validation,
                format!("held-out session {name} is no longer there"),
            ));
        };
        let now = val.blocks[b].members.len();
        if now != f.calibrated.points {
            return Err(changed(
                &source(val, b),
                format!("{} points held out, {now} now", f.calibrated.points),
            ));
        }
    }
    let stored = summary.calibration.rms_mm;
    if let Some(rms) = calibration_rms_mm.filter(|rms| (rms - stored).abs() > 1e-6 * stored.max(1e-3)) {
        return Err(changed(
            &summary.inputs.calibration,
            format!("calibration RMS {stored:.6} mm in summary.json, {rms:.6} mm on these files"),
        ));
    }
    Ok(())
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

/// Load the inputs, calibrate, validate and judge: see [`run_on`].
pub fn run(
    inputs: &RunInputs,
    options: &SolveOptions,
    study_subsets: usize,
    outliers: bool,
) -> Result<Run, RunError> {
    let absolute =
        |p: &Path| std::fs::canonicalize(p).map_err(|source| RunError::Input { path: p.to_owned(), source });
    let inputs = &RunInputs {
        model: absolute(&inputs.model)?,
        artefact: inputs.artefact.as_deref().map(absolute).transpose()?,
        calibration: absolute(&inputs.calibration)?,
        validation: absolute(&inputs.validation)?,
        ..inputs.clone()
    };
    let nominal = inputs.nominal()?;
    let (cal, val) = inputs.read_folders()?;
    run_on(nominal, cal, val, inputs, options, study_subsets, outliers)
}

/// [`run`] on folders already read: apply the exclusions, check, calibrate, validate on `val`
/// (artefact distances and tracker sessions, each against the nominal model), the floor, the
/// data-error candidates of tracker sessions, the outlier metrics (with `outliers`), the
/// dataset-size study (with `study_subsets` > 0 random subsets per group count), whether the
/// figures are a result, and the verdict.
pub fn run_on(
    nominal: ArmModel,
    cal: Observations,
    val: Observations,
    inputs: &RunInputs,
    options: &SolveOptions,
    study_subsets: usize,
    outliers: bool,
) -> Result<Run, RunError> {
    let mut steps = StepTimes::start();
    let arm = cal.one_arm(&[&val])?;
    check_options(&cal, &val, inputs, options)?;
    let (cal_kept, val_kept) = inputs.exclude(cal, val)?;
    let (cal, val) = (&cal_kept, &val_kept);
    steps.lap("load");
    let options = &inputs.solve_options(options, cal);
    for name in &inputs.float_tool {
        if cal.find_group(name).is_none() && val.find_group(name).is_none() {
            return Err(CalibError::UnknownSession(name.clone()).into());
        }
    }
    let mut same_base = BTreeMap::new();
    for pair in &inputs.same_base {
        let named =
            pair.split_once('=').filter(|(v, c)| val.find_block(v).is_some() && cal.find_block(c).is_some());
        let Some((held_out, calibration)) = named else { return Err(RunError::SameBase(pair.clone())) };
        same_base.insert(held_out.to_string(), calibration.to_string());
    }
    // The encoder angles' sines and cosines, once for every calibration and pose on `cal`.
    let encoders = cal.encoders();
    // The closed-form frames of the nominal arm, taken by the check and kept for the calibrations.
    let start = ToolFirstFit::default();
    // The terms of `cal`, built by the check and borrowed by the calibrations and session sums.
    let terms = SharedTerms::default();
    check_run_data_on(&nominal, cal, val, inputs, options, &start, Some(&terms))?;
    check_study_size(cal, study_subsets)?;
    steps.lap("input checks");
    // The nominal figures of held-out sessions are the nominal arm's with its tool point fitted:
    // that fit starts the calibration too.
    let tool_only = (!val.sessions().is_empty()).then(|| tool_only(&nominal));
    let (mut fit, reference) = calibrate_with_reference_on(
        &nominal,
        tool_only.as_ref(),
        cal,
        encoders,
        options,
        &start,
        Some(&terms),
    )?;
    let reference = reference.transpose()?;
    let on_bounds = mark_bounds(&mut fit);
    // The calibrated model is of the arm its sessions were measured on, whatever the model it
    // started from names.
    fit.model.arm = arm.clone();
    steps.lap("fit");
    let mut verdict = Vec::new();
    let mut not_trustworthy = Vec::new();
    let mut floor = FloorSummary::default();
    let touches = |d: &Observations| d.obs.iter().any(|o| o.landmark().is_some());
    // Artefact placements held out: distances, calibrated and nominal, against the floor.
    let distances = touches(val).then(|| (validate(&fit.model, val), validate(&nominal, val)));
    if let Some((v, n)) = &distances {
        let scales = TrustScales::of(&nominal, cal, val);
        not_trustworthy.extend(result_problems(&fit, v, &scales));
        floor.distances = noise_floor(&fit.model, cal, val, fit.estimated.len())
            .map(|f| f.with_estimate_noise(&fit.model, &fit.estimated, cal, val));
        floor.distance_gap = floor.distances.as_ref().map(|f| gap(f, v.overall.rms_mm, val));
        verdict.push(match &floor.distance_gap {
            Some(g) => format!("held-out distances: {}", g.sentence()),
            None => format!(
                "held-out distances: {:.3} mm RMS over {} pairs (nominal {:.3} mm); no landmark was touched twice in a \
                 placement, so the floor is unknown and the model cannot be called explained",
                v.overall.rms_mm, v.overall.count, n.overall.rms_mm
            ),
        });
    }
    steps.lap("validation");
    // The fit's pose of every calibration observation, read by the calibration sessions'
    // residuals, the outlier rows and the data-error scoring.
    let cal_poses = (!cal.sessions().is_empty()).then(|| ModelPoses::of(&fit.model, cal));
    // The normal equations of the fit's solution, session by session: the first evaluation of
    // the data-error scoring's refits and of the outlier metrics' leave-one-session-out refits.
    let setup = inputs.setup(options);
    let sums = (cal.sessions().len() >= 2 && (outliers || !val.sessions().is_empty()))
        .then(|| SessionSums::of_sharing(&fit.model, &fit, cal, &setup.solve_options(cal), Some(&terms)))
        .flatten();
    // Tracker sessions held out (each frame refitted, against the nominal arm with its tool
    // fitted) and the outlier metrics: independent given the fit, its poses and its sums, so
    // computed side by side (each refits five times; together they keep both threads busy).
    let outliers_skipped = !outliers;
    let (tracker, outliers) = rayon::join(
        || {
            reference.as_ref().map(|reference| {
                let run = RunContext { nominal: &nominal, cal, val, inputs, options };
                sessions_section(run, &fit, reference, &same_base, sums.as_ref(), cal_poses.as_ref())
            })
        },
        || match outliers {
            true => outlier_metrics(
                &fit,
                cal,
                Measure::of(val).map(|_| val),
                &setup,
                sums.as_ref(),
                cal_poses.as_ref(),
            ),
            false => Vec::new(),
        },
    );
    drop(sums);
    if let Some(t) = &tracker {
        not_trustworthy.extend(crate::calib::trust::point_problems(&fit, nominal.reach_mm()));
        verdict.extend(t.verdict.iter().cloned());
        floor.points = Some(t.floor.clone());
    }
    steps.lap("trust scales and outliers");
    let study_rows = (study_subsets > 0).then(|| {
        let setup = inputs.setup(&SolveOptions { restarts: Some(0), ..options.clone() });
        study(
            &nominal,
            cal,
            val,
            &StudyOptions { subsets: study_subsets, seed: options.seed, setup, progress: false },
        )
    });
    if let Some(rows) = &study_rows {
        not_trustworthy.extend(study_problems(rows).into_iter().map(|p| format!("study: {p}")));
        steps.lap("study");
    }
    let objective_comparison = touches(cal).then(|| objective_comparison(&fit, cal));
    steps.lap("6-DoF comparison");
    verdict.push(
        "next: kincal diagnose RUN names what the model misses (an effect of the library or a data error)"
            .into(),
    );
    let stats = &fit.stats;
    let summary = Summary {
        format: RUN_FORMAT.to_string(),
        kincal_version: env!("CARGO_PKG_VERSION").to_string(),
        provenance: provenance(arm, inputs, cal, val)?,
        kind: cal.kind().unwrap_or(crate::data::DataKind::Artefact),
        joints: nominal.joints.len(),
        inputs: inputs.clone(),
        options: SummaryOptions {
            huber_delta_mm: fit.options.huber_delta_mm(),
            restarts: fit.options.restarts,
            seed: fit.options.seed,
            objective: fit.options.objective,
            point_weight: (fit.options.point_weight != 1.0).then_some(fit.options.point_weight),
        },
        calibration: CalibrationSummary {
            rms_mm: fit.rms_mm,
            cost: Some(fit.cost),
            distances: stats.distances,
            points: stats.points,
            orientations: stats.orientations,
            pairs: cal.landmark_pairs().len(),
            observations: cal.obs.len(),
            groups: (0..cal.groups.len())
                .map(|g| (cal.groups[g].name.clone(), cal.group_members(g).len()))
                .collect(),
            estimates: fit.estimates.clone(),
            correlations: fit.correlations.clone(),
            starts: fit.starts.clone(),
            tool_offsets: fit.tool_offsets.clone(),
            drifts: fit.drifts.clone(),
            tool_rotation: fit.tool_rotation,
        },
        identifiability: IdentifiabilitySummary {
            before: Some(fit.before.clone()),
            after: fit.after.clone(),
            report: fit.identifiability(),
        },
        validation: ValidationSummary {
            distances: distances.as_ref().map(|(v, n)| DistanceValidation {
                calibrated: v.overall,
                nominal: n.overall,
                detail: ValidationDetail {
                    per_landmark: v.per_landmark.clone(),
                    nominal_per_landmark: n.per_landmark.clone(),
                    per_placement: v.per_placement.clone(),
                    nominal_per_placement: n.per_placement.clone(),
                    repeatability: v.repeatability.clone(),
                },
            }),
            sessions: tracker.as_ref().map(|t| t.validation.clone()),
        },
        floor,
        outliers,
        outliers_skipped,
        objective_comparison,
        study: study_rows,
        data_errors: tracker.as_ref().map_or_else(Vec::new, |t| t.data_errors.clone()),
        verdict,
        not_trustworthy,
        warnings: cal.warnings.iter().chain(&val.warnings).cloned().chain(on_bounds).collect(),
    };
    let calibration_residuals = cal
        .sessions()
        .into_iter()
        .zip(calibration_residuals_mm(&fit, cal, cal_poses.as_ref()))
        .map(|(b, residuals)| session_residuals(cal, b, residuals, vec![None; cal.blocks[b].members.len()]))
        .collect();
    Ok(Run {
        nominal,
        summary,
        calibration: fit,
        distances,
        held_out: tracker.map_or_else(Vec::new, |t| t.held_out),
        calibration_residuals,
        validation_data: val_kept,
        steps,
    })
}

/// Share of a parameter's bound width within which an estimate counts as on its bound.
pub const ON_BOUND_WITHIN: f64 = 1e-6;

/// Which bound of `bound` the value `value` sits on (within [`ON_BOUND_WITHIN`] of its width):
/// ("lower" or "upper", the bound), or `None`.
pub fn bound_side(bound: &crate::model::FreeParam, value: f64) -> Option<(&'static str, f64)> {
    let near = ON_BOUND_WITHIN * (bound.upper - bound.lower).abs().max(1e-12);
    if (value - bound.lower).abs() <= near {
        Some(("lower", bound.lower))
    } else if (bound.upper - value).abs() <= near {
        Some(("upper", bound.upper))
    } else {
        None
    }
}

/// The free parameters of `model` whose value sits on one of their bounds, each as "NAME on its
/// SIDE bound (VALUE)": a calibrated model holding one carries a value the data pushed there,
/// not a result (`kincal upload` refuses it unless told otherwise).
pub fn parameters_on_bounds(model: &ArmModel) -> Vec<String> {
    model
        .free
        .iter()
        .filter_map(|f| {
            let value = model.get(f.id);
            bound_side(f, value).map(|(side, at)| format!("{} on its {side} bound ({at})", f.id))
        })
        .collect()
}

/// Mark each estimated parameter of `fit` that ended on one of its bounds (its status says
/// which) and say, per parameter, that its value is not a result: the data pushed it there.
fn mark_bounds(fit: &mut Fit) -> Vec<String> {
    let mut sentences = Vec::new();
    for e in fit.estimates.iter_mut().filter(|e| e.status == "estimated") {
        let Some(bound) = fit.model.free.iter().find(|f| f.id.to_string() == e.param) else { continue };
        let Some(side) = bound_side(bound, e.value) else { continue };
        e.status = format!("estimated, on its {} bound", side.0);
        sentences.push(format!(
            "{} ended on its {} bound ({} {}, nominal {} {}): the data pushed it there, so its value is not a \
             result; an effect the model lacks may have leaked into it (kincal diagnose RUN names it), or its \
             bounds are too tight (widen them in the model's [free] table, or hold it by removing it there)",
            e.param, side.0, side.1, e.unit, e.nominal, e.unit
        ));
    }
    sentences
}

/// The run's [`Provenance`]: `arm`, now as the validation date, the artefact's certificate
/// number, and the SHA-256 of the model, the artefact and every session file read (`cal` and
/// `val`'s groups; data made in memory have no file).
fn provenance(
    arm: Option<crate::trace::ArmIdentity>,
    inputs: &RunInputs,
    cal: &Observations,
    val: &Observations,
) -> Result<Provenance, RunError> {
    let artefact_certificate = match &inputs.artefact {
        Some(path) => Artefact::load(path)?.certificate,
        None => None,
    };
    let sessions = cal.groups.iter().chain(&val.groups).map(|g| g.source.as_path());
    let files: Vec<&Path> = std::iter::once(inputs.model.as_path())
        .chain(inputs.artefact.as_deref())
        .chain(sessions)
        .filter(|p| !p.as_os_str().is_empty())
        .collect();
    let validated_at = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH);
    Ok(Provenance {
        arm,
        validated_at_unix_s: validated_at.ok().map(|d| d.as_secs()),
        artefact_certificate,
        input_files: crate::trace::hash_inputs(&files)?,
    })
}

/// What one objective can determine at the calibrated model: distances alone, and with the
/// relative orientation of the asymmetric pillars.
fn objective_comparison(fit: &Fit, cal: &Observations) -> ObjectiveComparison {
    let all: Vec<_> = fit.model.free.iter().map(|f| f.id).collect();
    let ranges: Vec<f64> = fit.model.free.iter().map(|f| (f.upper - f.lower).max(1e-9)).collect();
    let jacobian = |lever_mm| dense_jacobian(&fit.model, &all, cal, lever_mm).1;
    let (distance, six_dof) = (jacobian(None), jacobian(Some(DEFAULT_LEVER_MM)));
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

/// The held-out tracker sessions' section of a run.
struct SessionsSection {
    validation: SessionsValidation,
    floor: crate::calib::floor::PointFloor,
    data_errors: Vec<crate::calib::diagnose::data_errors::DataError>,
    verdict: Vec<String>,
    held_out: Vec<SessionResiduals>,
}

/// The nominal arm with only its tool point free.
fn tool_only(nominal: &ArmModel) -> ArmModel {
    let mut m = nominal.clone();
    m.free.retain(|f| matches!(f.id, ParamId::Tcp(_)));
    m
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

/// What a run's steps read besides the fit: the nominal arm, the calibration and held-out data
/// (exclusions applied), the run's inputs and its resolved solver options.
#[derive(Clone, Copy)]
struct RunContext<'a> {
    nominal: &'a ArmModel,
    cal: &'a Observations,
    val: &'a Observations,
    inputs: &'a RunInputs,
    options: &'a SolveOptions,
}

/// Validate `fit` on the held-out sessions of `run.val` (each frame refitted, and each tool that
/// floats) against `reference`, the nominal arm with its tool fitted on `run.cal`; the floor, the
/// data errors and the verdict (its refits' first normal equations from `sums`, the fit's poses
/// of the calibration observations from `cal_poses`, when given).
/// `same_base` names each held-out session measured in a calibration session's base frame.
fn sessions_section(
    run: RunContext,
    fit: &Fit,
    reference: &Fit,
    same_base: &BTreeMap<String, String>,
    sums: Option<&SessionSums>,
    cal_poses: Option<&ModelPoses>,
) -> SessionsSection {
    let RunContext { nominal, cal, val, inputs, options } = run;
    let floated = |b: usize| inputs.float_tool.contains(&val.groups[val.blocks[b].group].name);
    // Each session's tool offset (its own when floated) and its closed-form fit with it, from
    // which every figure of the session for that model is read (for the fit, the data-error
    // scoring's too).
    let calibrated_fits = SessionFits::of(&fit.model, val, &inputs.float_tool);
    let nominal_fits = SessionFits::of(&reference.model, val, &inputs.float_tool);
    // The probe's rotation on the flange in session b: the shared one, or, where the tool floats
    // (the probe re-mounted, perhaps turned on its mount), the session's own. A session whose
    // points leave its base's rotation free has none: no orientation figure.
    let probe = |fit: &Fit, b: usize, offset_mm: [f64; 3]| {
        let shared = fit.tool_rotation.as_ref().filter(|_| undetermined_rotation(val, b).is_none())?;
        if floated(b) {
            session_probe_rotation(&fit.model, val, b, offset_mm)
        } else {
            Some(shared.rotation())
        }
    };
    // The orientation error of every point of session b (its frame `frame`, refitted with the
    // tool offset), when it has a probe rotation.
    let angles = |fit: &Fit, b: usize, offset_mm: [f64; 3], frame: &Frame| {
        probe(fit, b, offset_mm).map(|p| orientation_errors_in_frame_deg(&fit.model, val, b, frame, &p))
    };
    let mut verdict = Vec::new();
    let (mut session_figures, mut held_out) = (Vec::new(), Vec::new());
    let (mut calibrated_parts, mut nominal_parts, mut angle_parts) = (Vec::new(), Vec::new(), Vec::new());
    for ((b, offset_mm, calibrated), (_, nominal_offset_mm, nominal_fit)) in
        calibrated_fits.fits().iter().zip(nominal_fits.fits())
    {
        let (b, offset_mm, nominal_offset_mm) = (*b, *offset_mm, *nominal_offset_mm);
        let name = val.block_name(b);
        let (c, n) = (calibrated.validation(), nominal_fit.validation());
        let orientation_withheld = fit.tool_rotation.as_ref().and_then(|_| undetermined_rotation(val, b));
        let point_angles = angles(fit, b, offset_mm, calibrated.frame());
        let orientation = point_angles.as_deref().and_then(angle_stats);
        let point_angles = point_angles.unwrap_or_else(|| vec![None; val.blocks[b].members.len()]);
        held_out.push(session_residuals(val, b, calibrated.residuals_mm(), point_angles));
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
                calibrated: stats(fit)?,
                nominal: stats(reference)?,
            })
        });
        calibrated_parts.push(c.clone());
        nominal_parts.push(n.clone());
        session_figures.push(SessionFigures {
            calibrated: c,
            nominal: n,
            transfers,
            orientation,
            nominal_orientation: angles(reference, b, nominal_offset_mm, nominal_fit.frame())
                .as_deref()
                .and_then(angle_stats),
            orientation_withheld,
            same_base,
        });
    }
    let pooled = |parts: &[SessionValidation]| {
        ErrorStats::pooled(&parts.iter().map(SessionValidation::stats).collect::<Vec<_>>())
    };
    let overall = pooled(&calibrated_parts);
    let floor = point_floor(val, inputs.stated_sigma_mm);
    let data_errors = if cal.sessions().is_empty() {
        Vec::new()
    } else {
        let all_floating = SolveOptions { float_tool: inputs.float_tool.clone(), ..options.clone() };
        let taken = TakenOfFit { sums, poses: cal_poses, held_out: Some(&calibrated_fits) };
        data_error_candidates_with(nominal, cal, val, fit, &all_floating, taken)
    };
    if let Some(best) = data_errors.iter().find(|d| d.significant) {
        verdict.push(format!("data error: {}; apply it with {}", best.text, best.action));
    }
    verdict.push(match floor.rms_mm {
        Some(f) if overall.rms_mm <= EXPLAINS_WITHIN * f => format!(
            "the model explains the held-out data: {:.4} mm against a floor of {f:.4} mm ({})",
            overall.rms_mm, floor.source
        ),
        Some(f) => format!(
            "the model is incomplete: {:.4} mm held out against a floor of {f:.4} mm ({}): something is missing (in the model or the data)",
            overall.rms_mm, floor.source
        ),
        None => format!(
            "the floor is unknown (no repeated poses, no stated uncertainty): {:.4} mm held out cannot be called explained",
            overall.rms_mm
        ),
    });
    SessionsSection {
        validation: SessionsValidation {
            sessions: session_figures,
            overall,
            nominal_overall: pooled(&nominal_parts),
            orientation_overall: AngleStats::pooled(&angle_parts),
        },
        floor,
        data_errors,
        verdict,
        held_out,
    }
}

impl Run {
    /// Every validation distance error, named, as `residuals.json` stores it.
    pub fn stored_residuals(&self) -> StoredResiduals {
        let val = &self.validation_data;
        let pairs = self
            .distances
            .iter()
            .flat_map(|(v, _)| &v.errors)
            .map(|e| StoredPairError {
                placement: val.groups[e.placement].name.clone(),
                landmarks: (val.landmarks[e.landmarks.0].id.clone(), val.landmarks[e.landmarks.1].id.clone()),
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
    use crate::calib::fit::calibrate;
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
