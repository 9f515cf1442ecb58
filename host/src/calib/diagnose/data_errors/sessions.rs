//! Data errors of instrument sessions: a re-mounted tool, a drift, single bad points. Each is
//! refitted and scored on the held-out sessions by its own rule (what `kincal calibrate` reports);
//! the diagnosis scores the calibration sessions' ones again by the held-out test.
//!
//! **Single bad points.** A beam broken and caught again on the wrong spot of the reflector, a
//! probe bumped: one point carries a gross error e_i, X_i = B_s · F(q_i) · t + e_i. A calibration
//! point whose error is beyond [`BAD_POINT_FACTOR`] times the median error (chi-3 errors almost
//! never are: 5× the median is 7.7 σ) is a candidate; all of them are left out together
//! (`--exclude-point SESSION:LINE`) and the refit is scored on the held-out sessions.
//!
//! **Tool moved between sessions.** A probe or reflector taken off and put back sits a little
//! elsewhere on the flange: in session S the measured point is B_S · F(q) · (t + Δ_S). With the
//! orientation varying inside S, Δ_S cannot be absorbed by S's base, and a calibration that
//! shares t across sessions bends the arm parameters to spread it (an arm error that is not
//! one). The candidate lets the tool float in S (its own Δ_S, `--float-tool S`): in a
//! calibration session it is scored by the held-out error of the refit; in a held-out session
//! whose orientation varies by that session's error with its base and Δ_S refitted. A
//! displacement beyond [`MAX_REMOUNT_MM`] is the session's model error, not a re-mount; a gain
//! below [`MIN_GAIN`] of the held-out error is none. Only the best candidate is called, when
//! |Δ_S| is beyond three of its standard deviations and the held-out error falls: the others
//! were scored against a model the best one still bends (apply it, and score again).
//!
//! **A 6-DoF probe turned on its mount.** A probe taken off and put back turned about the
//! flange (a T-Mac-type probe on a later day, a half turn): in session S the probe's rotation on
//! the flange is R_t,S = Q_S·R_t and its point Q_S·t, Q_S the turn in the flange frame. Its
//! positions show a re-mounted tool (Δ_S = (Q_S − I)·t, as large as twice the tool's distance
//! from the turn's axis), its orientations a constant rotation: in a held-out session S whose
//! orientation varies and whose points determine its base's rotation, R_t,S is the chordal mean
//! of R_Fᵀ·R_Sᵀ·R_meas (its base refitted with its tool floated), and Q_S = R_t,S·R_tᵀ. It is
//! called, in place of the re-mounted tool, when |Q_S| is beyond three of its standard deviations
//! (the orientation residual per axis over √n) and the held-out orientation error falls by
//! [`MIN_GAIN`]; the action is the re-mounted tool's (`--float-tool S`), which in a held-out 6-DoF
//! session refits the probe's rotation with its point. In a calibration session S the shared
//! probe rotation would spread Q_S over the arm parameters (and a half turn breaks the fit): the
//! candidate refits with S's tool floating, which leaves S's orientations out of the fit (they
//! are its own probe's, [`Observations::without_orientations_of`]), and Q_S is found, as in a
//! held-out session, from S's orientations at the refit and its shared probe rotation; it is
//! called by the same rule, S's own orientation error falling with it.
//!
//! **Drift within a session.** The instrument, its stand, its length scale or the arm creeps
//! while a session is measured, against time (`time_s`) or temperature (`temp_C`): a base shift
//! X_i = B_s · F(q_i) · t + v_S · (τ_i − τ̄) or a length scale X_i = B_s · (1 + k_S · (τ_i − τ̄)) ·
//! F(q_i) · t (the four kinds, their formulas and physical causes in
//! [`crate::calib::nuisance::drift`]). A calibration that holds S still spreads the creep over the
//! arm parameters. Each calibration session is refitted drifting each way its columns allow
//! (`--drift-session S:KIND`, three unknowns for a shift, one for a scale) and scored, like the
//! others, by the held-out error of the refit; a drift is called when its rate is beyond three of
//! its standard deviations and the held-out error falls by [`MIN_GAIN`]. It claims no arm
//! effect: the arm parameters are refitted, not changed by it.

use super::{DataError, DataErrorKind, DataSet};
use crate::calib::diagnose::units::Measure;
use crate::calib::fit::{recalibrate, recalibrate_with, Fit, SessionSums};
use crate::calib::nuisance::drift::{DriftKind, DriftSpec};
use crate::calib::nuisance::frame::rotation_vector;
use crate::calib::nuisance::frame::Frame;
use crate::calib::nuisance::tool::CONSTANT_ORIENTATION_DEG;
use crate::calib::nuisance::tool::{orientation_spread_with, ModelPoses};
use crate::calib::setup::{Change, SolveOptions};
use crate::calib::validate::{
    angle_stats, block_frame, calibration_errors, orientation_errors_in_frame_deg, session_probe_rotation,
    session_tool, undetermined_rotation, SessionFit, SessionFits,
};
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::stats::rms;
use nalgebra::{Matrix3, Vector3};

/// Largest tool displacement taken for a re-mount, mm: a probe put back sits within millimetres;
/// more is the session's model error, not a tool.
pub const MAX_REMOUNT_MM: f64 = 10.0;

/// Least share of the held-out error a data error must remove to be called.
pub const MIN_GAIN: f64 = 0.05;

/// Held-out RMS of `model` over `val`'s sessions, the sessions in `floating` with their tool
/// refitted too.
pub fn held_out_rms(model: &ArmModel, val: &Observations, floating: &[String]) -> f64 {
    rms(&Measure::Points.errors(model, val, floating))
}

/// RMS of `errors`, those of session `b` replaced by `own`: [`held_out_rms`] with one session's
/// tool placed at `own`'s.
fn rms_with(errors: &[(usize, Vec<f64>)], b: usize, own: &[f64]) -> f64 {
    let all: Vec<f64> =
        errors.iter().flat_map(|(s, e)| if *s == b { own } else { e.as_slice() }).copied().collect();
    rms(&all)
}

/// A calibration point beyond this many times the median error is a bad-point candidate.
pub const BAD_POINT_FACTOR: f64 = 5.0;

/// The held-out sessions a candidate's refit is scored on: the sessions, the tools that float
/// in them, and the fit's own held-out RMS (mm).
struct HeldOut<'a> {
    val: &'a Observations,
    floating: &'a [String],
    before: f64,
}

impl HeldOut<'_> {
    /// The held-out RMS (mm) of `model`.
    fn rms(&self, model: &ArmModel) -> f64 {
        held_out_rms(model, self.val, self.floating)
    }
}

/// The bad-points candidate: calibration points far beyond the others, left out and refitted.
fn bad_points_candidate(
    nominal: &ArmModel,
    cal: &Observations,
    fit: &Fit,
    options: &SolveOptions,
    held_out: &HeldOut,
    poses: Option<&ModelPoses>,
) -> Option<DataError> {
    let before = held_out.before;
    let errors = calibration_errors(fit, cal, poses);
    let median = crate::numerics::stats::median(errors.iter().flatten().copied().collect());
    let mut bad = Vec::new();
    let mut dropped = vec![false; cal.obs.len()];
    for (b, e) in cal.sessions().into_iter().zip(&errors) {
        for (&k, &err) in cal.blocks[b].members.iter().zip(e) {
            if err > BAD_POINT_FACTOR * median {
                bad.push((cal.point_name(k), err, cal.block_name(b)));
                dropped[k] = true;
            }
        }
    }
    if bad.is_empty() {
        return None;
    }
    let kept = cal.without(|k| dropped[k]);
    let refit = recalibrate(nominal, &kept, options, fit).ok()?;
    let after = held_out.rms(&refit.model);
    let largest = bad.iter().map(|b| b.1).fold(0.0, f64::max);
    let names: Vec<&str> = bad.iter().map(|b| b.0.as_str()).collect();
    let mut sessions: Vec<&str> = bad.iter().map(|b| b.2.as_str()).collect();
    sessions.dedup();
    let change = Change::ExcludePoints(names.iter().map(|n| n.to_string()).collect());
    Some(DataError {
        kind: DataErrorKind::BadPoints,
        session: sessions.join(", "),
        set: DataSet::Calibration,
        size_mm: largest,
        size_std_mm: median / 1.538,
        held_out_before_mm: before,
        held_out_after_mm: after,
        significant: after < (1.0 - MIN_GAIN) * before,
        text: format!(
            "{} single bad point{} ({}; up to {largest:.3} mm, the median point {median:.4} mm); held-out RMS \
             {before:.4} → {after:.4} mm without {}",
            bad.len(),
            if bad.len() == 1 { "" } else { "s" },
            names.join(", "),
            if bad.len() == 1 { "it" } else { "them" }
        ),
        action: change.action(),
        change: Some(change),
    })
}

/// The drift candidates: each calibration session, with each drift kind whose column it carries
/// over the least span ([`DriftKind::applies_to`]), refitted drifting that way (from `fit`).
fn drift_candidates(
    nominal: &ArmModel,
    cal: &Observations,
    fit: &Fit,
    options: &SolveOptions,
    held_out: &HeldOut,
) -> Vec<DataError> {
    let before = held_out.before;
    let mut out = Vec::new();
    for b in cal.sessions() {
        let name = cal.block_name(b);
        if options.drift_sessions.iter().any(|d| d.session == name) {
            continue;
        }
        for kind in DriftKind::ALL.into_iter().filter(|k| k.applies_to(cal, b)) {
            let mut drift_sessions = options.drift_sessions.clone();
            drift_sessions.push(DriftSpec { session: name.clone(), kind });
            let drifting = SolveOptions { drift_sessions, ..options.clone() };
            let Ok(refit) = recalibrate(nominal, cal, &drifting, fit) else {
                continue;
            };
            let Some(drift) = refit.drifts.iter().find(|d| d.session == name) else { continue };
            let after = held_out.rms(&refit.model);
            let (size, std) = (drift.size(), drift.rate_std);
            // A shift reads in µm (per hour or per kelvin), a scale in ppm.
            let (scale, unit) = if kind.is_scale() {
                (1.0, kind.unit().to_string())
            } else {
                (1e3, kind.unit().replacen("mm", "µm", 1))
            };
            let what = if kind.is_scale() {
                format!(
                    "its length scale changes by {:.2} ± {:.2} {unit}",
                    scale * drift.rate[0],
                    scale * std
                )
            } else {
                let along =
                    drift.rate.iter().map(|x| format!("{:.3}", x / size.max(1e-300))).collect::<Vec<_>>();
                format!(
                    "its base moves {:.1} ± {:.1} {unit} along ({}) (instrument frame)",
                    scale * size,
                    scale * std,
                    along.join(", ")
                )
            };
            let change = Change::Drift(DriftSpec { session: name.clone(), kind });
            out.push(DataError {
                kind: DataErrorKind::Drift,
                session: name.clone(),
                set: DataSet::Calibration,
                size_mm: size,
                size_std_mm: std,
                held_out_before_mm: before,
                held_out_after_mm: after,
                significant: size > 3.0 * std && after < (1.0 - MIN_GAIN) * before,
                text: format!(
                    "session {} drifts ({}, against {}): {what}; held-out RMS {before:.4} → {after:.4} mm with it drifting",
                    name,
                    kind.name(),
                    kind.column(),
                ),
                action: change.action(),
                change: Some(change),
            });
        }
    }
    out
}

/// A 6-DoF probe's turn on its mount in one held-out session (see the module doc).
struct ProbeTurn {
    /// Q_S, the turn in the flange frame.
    turn: Matrix3<f64>,
    /// |Q_S|, degrees.
    angle_deg: f64,
    /// Its standard deviation, degrees.
    std_deg: f64,
    /// The session's held-out orientation RMS with the shared probe rotation, degrees.
    before_deg: f64,
    /// With its own, degrees.
    after_deg: f64,
}

/// Half-angle of the cone about the flange's z axis within which a turn's axis is named "the
/// flange z axis", degrees.
const FLANGE_Z_WITHIN_DEG: f64 = 10.0;

/// The probe's turn in session `b` of `data` (its tool offset `offset_mm` refitted, its frame
/// refitted with it given by `frame`, asked only when there is a turn to score), against the
/// shared probe rotation of `fit` (for a calibration session, the refit with its tool floating,
/// which leaves its orientations out): `None` without
/// a fitted probe rotation, without orientations, or when the session's points leave its base's
/// rotation free.
fn probe_turn(
    fit: &Fit,
    data: &Observations,
    b: usize,
    offset_mm: [f64; 3],
    frame: impl FnOnce() -> Frame,
) -> Option<ProbeTurn> {
    let shared = fit.tool_rotation.as_ref()?.rotation();
    if undetermined_rotation(data, b).is_some() {
        return None;
    }
    let own = session_probe_rotation(&fit.model, data, b, offset_mm)?;
    let frame = frame();
    let stats = |probe: &Matrix3<f64>| {
        angle_stats(&orientation_errors_in_frame_deg(&fit.model, data, b, &frame, probe))
    };
    let before = stats(&shared)?;
    let after = stats(&own)?;
    let turn = own * shared.transpose();
    // The residual angle's RMS spreads over three axes; the turn's angle is a mean of n of them.
    let std_deg = after.rms_deg / (3.0 * after.orientations as f64).sqrt();
    Some(ProbeTurn {
        turn,
        angle_deg: rotation_vector(&turn).norm().to_degrees(),
        std_deg,
        before_deg: before.rms_deg,
        after_deg: after.rms_deg,
    })
}

impl ProbeTurn {
    /// Beyond three standard deviations, the orientation error falling by [`MIN_GAIN`], and the
    /// tool point's displacement `offset_mm` the turn's own within [`MAX_REMOUNT_MM`].
    fn called(&self, fit: &Fit, offset_mm: &[f64; 3]) -> bool {
        let t = Vector3::from(fit.model.tcp_mm);
        let unexplained = (Vector3::from(*offset_mm) - (self.turn - Matrix3::identity()) * t).norm();
        self.angle_deg > 3.0 * self.std_deg
            && self.after_deg < (1.0 - MIN_GAIN) * self.before_deg
            && unexplained <= MAX_REMOUNT_MM
    }

    /// The turn's axis in words: "the flange z axis" (its sign in the angle), or its direction.
    fn about(&self) -> (f64, String) {
        let w = rotation_vector(&self.turn);
        let axis = w / w.norm().max(1e-300);
        if axis.z.abs() >= FLANGE_Z_WITHIN_DEG.to_radians().cos() {
            (self.angle_deg * axis.z.signum(), "the flange z axis".into())
        } else {
            (self.angle_deg, format!("the flange axis ({:.3}, {:.3}, {:.3})", axis.x, axis.y, axis.z))
        }
    }

    /// The data error, in place of the re-mounted tool `moved` of the same session.
    fn data_error(&self, moved: DataError) -> DataError {
        let (angle, about) = self.about();
        // A held-out session's orientation is scored with the shared probe and with its own; a
        // calibration session's, at the refit that leaves it out, the same way.
        let whose = match moved.set {
            DataSet::HeldOut => "held-out orientation RMS",
            DataSet::Calibration => "its orientation RMS",
        };
        DataError {
            kind: DataErrorKind::ProbeTurned,
            size_mm: self.angle_deg,
            size_std_mm: self.std_deg,
            // Called: its angle is determined and the orientation error falls.
            significant: true,
            text: format!(
                "the probe is turned {angle:.3} ± {:.3}° about {about} in session {} (its point moved {:.3} mm with it); \
                 {whose} {:.3}° → {:.3}°, held-out position RMS {:.4} → {:.4} mm with its probe floating",
                self.std_deg,
                moved.session,
                moved.size_mm,
                self.before_deg,
                self.after_deg,
                moved.held_out_before_mm,
                moved.held_out_after_mm
            ),
            ..moved
        }
    }
}

/// Score the data errors, best first: "the tool moved in session S" for every session not
/// already floating, "session S drifts" for every drift kind a session's columns allow, and
/// single bad points.
pub fn data_error_candidates(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    fit: &Fit,
    options: &SolveOptions,
) -> Vec<DataError> {
    data_error_candidates_with(nominal, cal, val, fit, options, TakenOfFit::default())
}

/// What a run has already taken of its fit, read by the data-error scoring instead of taking it
/// again; each only where it is of that fit (else taken here).
#[derive(Clone, Copy, Default)]
pub struct TakenOfFit<'a> {
    /// The normal equations of the fit's solution, session by session ([`SessionSums`]): the
    /// first evaluation of the refits floating a session's tool.
    pub sums: Option<&'a SessionSums<'a>>,
    /// The fit's poses of the calibration observations ([`ModelPoses`]).
    pub poses: Option<&'a ModelPoses<'a>>,
    /// The fit's held-out sessions' closed-form fits ([`SessionFits`], its tools floated).
    pub held_out: Option<&'a SessionFits<'a>>,
}

/// [`data_error_candidates`], reading what a run has already taken of `fit` from `taken`.
pub fn data_error_candidates_with(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    fit: &Fit,
    options: &SolveOptions,
    taken: TakenOfFit,
) -> Vec<DataError> {
    let TakenOfFit { sums, poses, held_out: held_out_fits } = taken;
    // The fit's errors on each of `val`'s sessions in order, from which [`held_out_rms`] is taken.
    let errors = SessionFits::errors(held_out_fits, &fit.model, val, &options.float_tool);
    let before = rms(&errors.iter().flat_map(|(_, e)| e.iter().copied()).collect::<Vec<_>>());
    let held_out = HeldOut { val, floating: &options.float_tool, before };
    // `options.float_tool` may name held-out sessions too (their tools float in the held-out
    // errors); the refits float only the calibration's own, or every refit would be refused.
    let refitting = &SolveOptions {
        float_tool: options.float_tool.iter().filter(|n| cal.find_group(n).is_some()).cloned().collect(),
        ..options.clone()
    };
    let mut out = Vec::new();
    let verdict = |session: &str, set: DataSet, offset: [f64; 3], std: f64, after: f64| {
        let size = offset.iter().map(|v| v * v).sum::<f64>().sqrt();
        let significant = size > 3.0 * std && size <= MAX_REMOUNT_MM && after < (1.0 - MIN_GAIN) * before;
        let change = Change::FloatTool(session.to_string());
        DataError {
            kind: DataErrorKind::ToolMoved,
            session: session.into(),
            set,
            size_mm: size,
            size_std_mm: std,
            held_out_before_mm: before,
            held_out_after_mm: after,
            significant,
            text: format!(
                "the tool sits {size:.3} ± {std:.3} mm elsewhere in session {session} (flange frame: {:.3}, {:.3}, {:.3} mm); \
                 held-out RMS {before:.4} → {after:.4} mm with it floating",
                offset[0], offset[1], offset[2]
            ),
            action: change.action(),
            change: Some(change),
        }
    };
    // A calibration session's own tool needs the shared one fixed by other sessions that turn it.
    let turning = |data: &Observations, poses: Option<&ModelPoses>| -> Vec<usize> {
        data.sessions()
            .into_iter()
            .filter(|&b| !options.float_tool.contains(&data.block_name(b)))
            .filter(|&b| orientation_spread_with(&fit.model, data, b, poses) >= CONSTANT_ORIENTATION_DEG)
            .collect()
    };
    let cal_turning = turning(cal, poses);
    // Each refit starts from the other sessions' normal equations at the fit's solution.
    let own;
    let sums = match sums.filter(|s| std::ptr::eq(s.fit(), fit)) {
        Some(sums) => Some(sums),
        None => {
            own = (cal_turning.len() >= 2).then(|| SessionSums::of(nominal, fit, cal, refitting)).flatten();
            own.as_ref()
        }
    };
    for &b in &cal_turning {
        if cal_turning.len() < 2 {
            break;
        }
        let name = cal.block_name(b);
        let mut float_tool = refitting.float_tool.clone();
        float_tool.push(name.clone());
        let floated = SolveOptions { float_tool, ..refitting.clone() };
        let refitted = match sums {
            Some(sums) => recalibrate_with(nominal, cal, &floated, sums),
            None => recalibrate(nominal, cal, &floated, fit),
        };
        let Ok(refit) = refitted else {
            continue;
        };
        let Some(tool) = refit.tool_offsets.iter().find(|t| t.session == name) else { continue };
        let after = held_out.rms(&refit.model);
        let moved = verdict(&name, DataSet::Calibration, tool.offset_mm, tool.size_std_mm, after);
        let frame = || block_frame(&refit.model, cal, b, &Vector3::from(tool.offset_mm));
        out.push(match probe_turn(&refit, cal, b, tool.offset_mm, frame) {
            Some(turn) if turn.called(&refit, &tool.offset_mm) => turn.data_error(moved),
            _ => moved,
        });
    }
    // A held-out session whose orientation is constant cannot tell its tool from its base.
    for b in turning(val, None) {
        let name = val.block_name(b);
        let tool = session_tool(&fit.model, val, b);
        let session = SessionFit::of(&fit.model, val, b, tool.offset_mm);
        let after = rms_with(&errors, b, &session.errors());
        let moved = verdict(&name, DataSet::HeldOut, tool.offset_mm, tool.size_std_mm, after);
        out.push(match probe_turn(fit, val, b, tool.offset_mm, || *session.frame()) {
            Some(turn) if turn.called(fit, &tool.offset_mm) => turn.data_error(moved),
            _ => moved,
        });
    }
    out.extend(drift_candidates(nominal, cal, fit, refitting, &held_out));
    out.extend(bad_points_candidate(nominal, cal, fit, refitting, &held_out, poses));
    out.sort_by(|a, b| a.held_out_after_mm.total_cmp(&b.held_out_after_mm));
    // One data error at a time: the others are scored against a model the best one still bends,
    // so only the best is called; apply it and score again.
    for c in out.iter_mut().skip(1) {
        c.significant = false;
    }
    out
}
