//! `kincal haptic calibrate`: the whole procedure over a recording folder.
//!
//! 0. wild tracker samples rejected in every stream ([`super::clean`]); occlusions split the
//!    streams into segments and nothing is interpolated across them;
//! 1. pivot calibration of the stylus target on `gimbal/` (HIP held in its stand); its RMS is
//!    the tracker noise the later guards compare with;
//! 2. time delay on `delay/` with the transform the paper uses for this step (pivot + Horn on the
//!    uncalibrated device), both streams as distance from the device origin;
//! 3. the joints step must cover the workspace: each of θ1–θ3 through [`MIN_JOINT_RANGE_DEG`];
//! 4. two starts for the joint calibration: the landmark-based transform (p1 from T1 pivoting
//!    about the central joint, ây from how T2 turns against θ1, p3 the HIP where the device reads
//!    θ1 ≈ 0) and the pose-based one (Horn); each is calibrated and the one with the lower error
//!    on held-out blocks of `joints/` is kept;
//! 5. a joint residual far above the tracker noise is refused, naming the joint convention that
//!    would explain the data if one does;
//! 6. the delay is estimated again with the calibrated joints and the joints calibrated again
//!    with the new alignment, until the delay changes by less than [`DELAY_SETTLED_MS`];
//! 7. orientation reference on `reference/`; gimbal calibration on `gimbal/` + `joints/` (axis)
//!    and `reference/` (roll), linear vs quadratic on held-out error;
//! 8. position and orientation errors on `verify/` (held-out), before and after; a calibration
//!    worse than the uncalibrated device is refused.
//!
//! Every refusal is a [`HapticFailure`] naming the step, the cause and what to do, and carries
//! what was computed up to that point.

use super::clean::reject_wild;
use super::gimbal::{calibrate_gimbals, linear_held_out_deg, GimbalModel, GimbalSample};
use super::kinematics::{Device, SensorModel};
use super::landmarks::{initial_transform, turret_axis, LandmarkError};
use super::pivot::{pivot_calibration, PivotError};
use super::position::{
    calibrate_position, pose_based_transform, position_errors, Correspondence, PositionCalibration, Transform,
};
use super::recording::{DeviceStream, JointConvention, Recording, Step, TargetStream, Theta3};
use super::reference::{orientation_reference, Pose, ReferenceError};
use super::report_data::{error_maps, ErrorMaps, HeldOutSample};
use crate::numerics::delay::{estimate_delay_ms, DelayError, DelayEstimate, Signal};
use crate::numerics::stats::rms;
use nalgebra::{Matrix3, Vector3};

/// Smallest range each of θ1–θ3 must move through in `joints/`, degrees.
pub const MIN_JOINT_RANGE_DEG: f64 = 20.0;
/// The signal the delay is estimated on, with what to do when it hardly varies.
const STYLUS_DISTANCE: &str =
    "the stylus's distance from the device origin (move the stylus towards and away from the device)";

/// The delay is settled when it changes by less than this between rounds, ms.
pub const DELAY_SETTLED_MS: f64 = 0.05;
/// Iterations (Horn + LM) of the joint calibration from each start when choosing between them.
pub const START_ITERATIONS: usize = 6;
/// Iterations of each joint calibration after a delay estimate.
pub const ITERATIONS: usize = 20;
/// Most gimbal samples fitted (evenly strided; the paper uses 200 per optimisation).
pub const MAX_GIMBAL_SAMPLES: usize = 1500;
/// Most gimbal samples when scoring an alternative convention.
pub const MAX_ALTERNATIVE_SAMPLES: usize = 400;
/// Most delay/joint rounds.
pub const MAX_DELAY_ROUNDS: usize = 8;
/// A joint residual above `IMPLAUSIBLE_MM + IMPLAUSIBLE_FACTOR × tracker noise` is refused.
pub const IMPLAUSIBLE_MM: f64 = 2.0;
/// See [`IMPLAUSIBLE_MM`].
pub const IMPLAUSIBLE_FACTOR: f64 = 5.0;
/// Fewest aligned samples the joint calibration needs.
pub const MIN_JOINT_SAMPLES: usize = 100;

/// Why a recording could not be calibrated.
#[derive(Debug, thiserror::Error)]
pub enum HapticError {
    /// A step or target is missing from the recording.
    #[error("the recording has no {0}")]
    Missing(&'static str),
    /// Pivot calibration failed.
    #[error("pivot calibration on {0}: {1}")]
    Pivot(&'static str, PivotError),
    /// No delay could be estimated.
    #[error("{0}")]
    Delay(#[from] DelayError),
    /// No delay, and a different joint convention would give one.
    #[error(
        "no delay with the declared joint convention ({error}); the joint convention looks wrong — {hint}"
    )]
    DelayConvention {
        /// The delay error with the declared convention.
        error: DelayError,
        /// The convention that gives a clear delay.
        hint: String,
    },
    /// The delay kept changing between rounds.
    #[error("the delay did not settle within {MAX_DELAY_ROUNDS} rounds (ms: {0:?}); the tracker's timestamps may not be on the host clock")]
    DelayUnsettled(Vec<f64>),
    /// No orientation reference could be derived.
    #[error("{0}")]
    Reference(#[from] ReferenceError),
    /// A joint hardly moved.
    #[error("too little motion: θ{joint} moved through {range_deg:.1}° only, at least {MIN_JOINT_RANGE_DEG}° per joint are needed; move the stylus through the whole workspace{hint}")]
    TooLittleMotion {
        /// Joint, 1-based.
        joint: usize,
        /// Range covered, degrees.
        range_deg: f64,
        /// A further hint.
        hint: &'static str,
    },
    /// Too few tracker samples are left.
    #[error("{found} usable tracker samples in joints/ after occlusions and wild samples, {held} of them in the held-out blocks (every fourth {HOLD_OUT_BLOCK_S} s); at least {needed} are needed, a quarter of them held out; record longer")]
    TooFewSamples {
        /// Samples found.
        found: usize,
        /// Of which held out.
        held: usize,
        /// Samples needed.
        needed: usize,
    },
    /// The residual is far above the tracker noise.
    #[error("the residual after calibrating the joints is {residual_mm:.2} mm RMS on held-out samples, far above the tracker noise ({noise_mm:.2} mm): {hint}")]
    Implausible {
        /// Held-out residual, mm.
        residual_mm: f64,
        /// Tracker noise, mm.
        noise_mm: f64,
        /// The likely cause.
        hint: String,
    },
    /// Another gimbal convention explains the data far better.
    #[error("the held-out stylus-axis error is {declared_deg:.3}° with the declared joint convention; the joint convention looks wrong — {hint}")]
    GimbalConvention {
        /// Held-out axis error with the declared convention, degrees.
        declared_deg: f64,
        /// The convention that explains the data.
        hint: String,
    },
    /// The calibration made the device worse.
    #[error("the {quantity} error on held-out samples is worse after calibration ({before:.3} → {after:.3} {unit}); likely cause: {hint}")]
    Worse {
        /// Position or orientation.
        quantity: &'static str,
        /// Unit of the errors.
        unit: &'static str,
        /// Before, in `unit`.
        before: f64,
        /// After, in `unit`.
        after: f64,
        /// The likely cause.
        hint: String,
    },
}

/// A refused calibration: the step, the cause and what had been computed.
#[derive(Debug, thiserror::Error)]
#[error("{step} failed: {error}")]
pub struct HapticFailure {
    /// The step that failed, with its folder.
    pub step: &'static str,
    /// Why.
    pub error: HapticError,
    /// The calibration as far as it got, when it got to the end.
    pub partial: Option<Box<HapticCalibration>>,
    /// Where the joint residuals are, when the joint calibration was refused (held-out blocks of
    /// `joints/`; axis errors not computed, 0).
    pub maps: Option<Box<ErrorMaps>>,
}

/// Errors before and after, as summary.json reports them.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct BeforeAfter {
    /// Before calibration.
    pub before: f64,
    /// After calibration.
    pub after: f64,
}

/// How the joint calibration was started.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StartChoice {
    /// Held-out joint residual from the landmark-based start, mm (`None` when the landmarks gave
    /// no transform, see `landmark_note`).
    pub landmark_mm: Option<f64>,
    /// Held-out joint residual from the pose-based (Horn) start, mm.
    pub pose_mm: f64,
    /// The start kept: `landmark` or `pose`.
    pub chosen: &'static str,
    /// Why the landmarks gave no transform.
    pub landmark_note: Option<String>,
}

/// The result of a haptic calibration.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HapticCalibration {
    /// Tracker delay behind the device, ms.
    pub delay_ms: f64,
    /// The delay after each round (first: uncalibrated joints), ms.
    pub delay_rounds_ms: Vec<f64>,
    /// Peak correlation of the final delay estimate.
    pub delay_correlation: f64,
    /// Position error RMS on held-out samples, mm.
    pub position_mm: BeforeAfter,
    /// Stylus-axis error RMS on held-out samples, degrees.
    pub orientation_deg: BeforeAfter,
    /// Gimbal sensor model chosen.
    pub gimbal_model: GimbalModel,
    /// Held-out axis error of the linear and the quadratic gimbal model, degrees.
    pub gimbal_held_out_deg: (f64, f64),
    /// Sensor models of joints 1–3 and gimbals 4–6 (θ = j·raw² + k·raw + m).
    pub sensors: [SensorModel; 6],
    /// HIP position in the stylus target frame, mm, and the pivot RMS, mm (the tracker noise the
    /// guards compare with).
    pub tip_mm: ([f64; 3], f64),
    /// Device → tracker rotation (row-major) and translation, mm.
    pub device_to_tracker: ([f64; 9], [f64; 3]),
    /// The start of the joint calibration.
    pub start: StartChoice,
    /// The joint convention the readings were read with.
    pub convention: JointConvention,
    /// Wild tracker samples rejected, all streams.
    pub rejected_samples: usize,
    /// Occlusion gaps in the tracker streams, all streams.
    pub tracker_gaps: usize,
    /// Held-out samples the errors were measured on.
    pub held_out: usize,
    /// Where the held-out errors are: per stylus direction, per workspace region, per joint.
    pub maps: ErrorMaps,
    /// Per held-out sample.
    #[serde(skip)]
    pub samples: Vec<HeldOutSample>,
}

/// Outcome of a run in `summary.json`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Calibrated and checked.
    Ok,
    /// Refused: see `failure`.
    Failed,
}

/// Which step failed and why, in `summary.json`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FailureSummary {
    /// The step, with its folder.
    pub step: &'static str,
    /// The message.
    pub message: String,
    /// Where the joint residuals are, when the joint calibration was refused.
    pub maps: Option<ErrorMaps>,
}

/// `summary.json` of a haptic run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HapticSummary {
    /// `ok` or `failed`.
    pub status: Status,
    /// Set when failed.
    pub failure: Option<FailureSummary>,
    /// Tracker delay behind the device, ms.
    pub delay_ms: Option<f64>,
    /// Position error RMS before and after, mm.
    pub position: Option<PositionSummary>,
    /// Stylus-axis error RMS before and after, degrees.
    pub orientation: Option<OrientationSummary>,
    /// Gimbal sensor model chosen on held-out error.
    pub gimbal_model: Option<GimbalModel>,
    /// The full result (on failure: as far as it got, if it got to the end).
    pub calibration: Option<HapticCalibration>,
}

/// Position errors in `summary.json`.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct PositionSummary {
    /// Before calibration, mm.
    pub before_mm: f64,
    /// After calibration, mm.
    pub after_mm: f64,
}

/// Orientation errors in `summary.json`.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct OrientationSummary {
    /// Before calibration, degrees.
    pub before_deg: f64,
    /// After calibration, degrees.
    pub after_deg: f64,
}

impl HapticSummary {
    fn of(status: Status, failure: Option<FailureSummary>, c: Option<&HapticCalibration>) -> HapticSummary {
        HapticSummary {
            status,
            failure,
            delay_ms: c.map(|c| c.delay_ms),
            position: c
                .map(|c| PositionSummary { before_mm: c.position_mm.before, after_mm: c.position_mm.after }),
            orientation: c.map(|c| OrientationSummary {
                before_deg: c.orientation_deg.before,
                after_deg: c.orientation_deg.after,
            }),
            gimbal_model: c.map(|c| c.gimbal_model),
            calibration: c.cloned(),
        }
    }
}

impl HapticCalibration {
    /// The summary written to `summary.json`.
    pub fn summary(&self) -> HapticSummary {
        HapticSummary::of(Status::Ok, None, Some(self))
    }
}

impl HapticFailure {
    /// A recording that could not be read.
    pub fn unreadable(error: &super::recording::RecordingError) -> HapticSummary {
        HapticSummary::of(
            Status::Failed,
            Some(FailureSummary { step: "reading the recording", message: error.to_string(), maps: None }),
            None,
        )
    }

    /// The summary written to `summary.json`, marked failed.
    pub fn summary(&self) -> HapticSummary {
        HapticSummary::of(
            Status::Failed,
            Some(FailureSummary {
                step: self.step,
                message: self.error.to_string(),
                maps: self.maps.as_deref().cloned(),
            }),
            self.partial.as_deref(),
        )
    }
}

mod stages;
#[cfg(test)]
mod tests;

use stages::*;

/// Calibrate a recording; a refusal names the step and the cause.
pub fn calibrate_recording(raw_rec: &Recording) -> Result<HapticCalibration, HapticFailure> {
    let (rec, rejected_samples, tracker_gaps) = cleaned(raw_rec);
    let rec = &rec;
    let device = rec.device;
    // 1. The HIP in the stylus target frame; its RMS is the tracker noise at the HIP.
    let gimbal_step = step(rec, "gimbal").map_err(fail(STEP_PIVOT))?;
    let pivot = pivot_calibration(&poses(target(gimbal_step, "hip").map_err(fail(STEP_PIVOT))?))
        .map_err(|e| fail(STEP_PIVOT)(HapticError::Pivot("gimbal/hip.csv", e)))?;
    let ctx = Context { rec, device, tip: pivot.tip_mm };
    let noise_mm = pivot.rms_mm.max(0.01);
    // 2. Delay with the pose-based transform on the delay step itself.
    let first = first_delay(&ctx).map_err(|e| match e {
        HapticError::Delay(error @ (DelayError::AtWindowEdge { .. } | DelayError::NoClearPeak { .. })) => {
            match delay_convention(&ctx) {
                Some(hint) => fail(STEP_DELAY)(HapticError::DelayConvention { error, hint }),
                None => fail(STEP_DELAY)(HapticError::Delay(error)),
            }
        }
        other => fail(STEP_DELAY)(other),
    })?;
    let mut delay_ms = first.delay_ms;
    let mut delay_rounds_ms = vec![delay_ms];
    // 3. Enough motion and samples in joints/.
    let joints_step = step(rec, "joints").map_err(fail(STEP_JOINTS))?;
    for j in 0..3 {
        let (lo, hi) = joints_step
            .device
            .raw
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| (lo.min(r[j]), hi.max(r[j])));
        let range_deg = (hi - lo).to_degrees();
        if range_deg.is_nan() || range_deg < MIN_JOINT_RANGE_DEG {
            let hint = if rec.convention.unit == super::recording::AngleUnit::Deg {
                " (or the readings are radians while recording.json says \"unit\": \"deg\")"
            } else {
                ""
            };
            return Err(fail(STEP_JOINTS)(HapticError::TooLittleMotion { joint: j + 1, range_deg, hint }));
        }
    }
    let all = ctx.aligned(joints_step, delay_ms).map_err(fail(STEP_JOINTS))?;
    let (fit, held) = split(&all);
    if all.len() < MIN_JOINT_SAMPLES || held.len() < MIN_JOINT_SAMPLES / 4 {
        return Err(fail(STEP_JOINTS)(HapticError::TooFewSamples {
            found: all.len(),
            held: held.len(),
            needed: MIN_JOINT_SAMPLES,
        }));
    }
    let pose_start = pose_based_transform(&device, &ctx.correspondences(&fit));
    let (from_pose, pose_mm) =
        calibrate_from(&ctx, &fit, &held, pose_start, [SensorModel::IDENTITY; 3], 1, START_ITERATIONS);
    let landmark = ctx.landmark_transform(delay_ms);
    let (mut position, residual, start) = match &landmark {
        Ok(eh) => {
            let (from_landmarks, landmark_mm) =
                calibrate_from(&ctx, &fit, &held, *eh, [SensorModel::IDENTITY; 3], 1, START_ITERATIONS);
            let landmark_wins = landmark_mm <= pose_mm;
            let start = StartChoice {
                landmark_mm: Some(landmark_mm),
                pose_mm,
                chosen: if landmark_wins { "landmark" } else { "pose" },
                landmark_note: None,
            };
            if landmark_wins {
                (from_landmarks, landmark_mm, start)
            } else {
                (from_pose, pose_mm, start)
            }
        }
        Err(note) => (
            from_pose,
            pose_mm,
            StartChoice { landmark_mm: None, pose_mm, chosen: "pose", landmark_note: Some(note.clone()) },
        ),
    };
    // 5. A residual far above the tracker noise: name the convention that explains it, if any.
    let limit_mm = IMPLAUSIBLE_MM + IMPLAUSIBLE_FACTOR * noise_mm;
    if residual > limit_mm {
        let hint = match diagnose_convention(&ctx, &fit, &held, limit_mm) {
            Some((what, c, r)) => format!(
                "the joint convention looks wrong — {what}: with \"joint_convention\": {} in recording.json the residual would be {r:.2} mm",
                c.json()
            ),
            None => format!(
                "no single change of the joint convention explains it; check l1_mm/l2_mm in recording.json, that the stylus target is rigid, and that the tracker and the device record the same motion (landmark start: {})",
                start.landmark_note.as_deref().unwrap_or("used")
            ),
        };
        let maps = error_maps(&joint_residuals(&ctx, &position, &held));
        return Err(HapticFailure {
            step: STEP_JOINTS,
            error: HapticError::Implausible { residual_mm: residual, noise_mm, hint },
            partial: None,
            maps: Some(Box::new(maps)),
        });
    }
    // 6. Delay and joints in turn until the delay settles.
    let mut settled = false;
    let mut delay_correlation = first.correlation;
    for round in 0..MAX_DELAY_ROUNDS {
        let estimate = ctx.delay(&position.joints, &position.transform).map_err(fail(STEP_DELAY))?;
        delay_rounds_ms.push(estimate.delay_ms);
        delay_correlation = estimate.correlation;
        let change = (estimate.delay_ms - delay_ms).abs();
        delay_ms = estimate.delay_ms;
        // At least one full calibration at the re-estimated delay.
        if change < DELAY_SETTLED_MS && round > 0 {
            settled = true;
            break;
        }
        let all = ctx.aligned(joints_step, delay_ms).map_err(fail(STEP_JOINTS))?;
        let (fit, held) = split(&all);
        position = calibrate_from(
            &ctx,
            &fit,
            &held,
            position.transform,
            position.joints,
            101 + round as u64,
            ITERATIONS,
        )
        .0;
    }
    if !settled {
        return Err(fail(STEP_DELAY)(HapticError::DelayUnsettled(delay_rounds_ms)));
    }
    let all_joints = ctx.aligned(joints_step, delay_ms).map_err(fail(STEP_JOINTS))?;
    let joints = ctx.spread(&all_joints);
    let eh = position.transform;
    let mut sensors = with_joints(&position.joints);
    // 7. Orientation reference from the roll, then the gimbals — with the declared convention,
    //    and with each single change of the gimbals' convention: one that explains the data far
    //    better means the declared one is wrong.
    let roll_samples = ctx
        .aligned(step(rec, "reference").map_err(fail(STEP_REFERENCE))?, delay_ms)
        .map_err(fail(STEP_REFERENCE))?;
    let gimbal_aligned = ctx.spread(&ctx.aligned(gimbal_step, delay_ms).map_err(fail(STEP_GIMBALS))?);
    let stage = GimbalStage { device: &device, joints: &position.joints, eh: &eh };
    let declared = rec.convention;
    let data = stage
        .run(&roll_samples, &gimbal_aligned, &joints, &declared, &declared, MAX_GIMBAL_SAMPLES)
        .map_err(|e| fail(STEP_REFERENCE)(e.into()))?;
    let gimbals = calibrate_gimbals(&device, &data.fit, &data.held);
    let reference = data.reference;
    let declared_deg = gimbals.held_out_deg.0.min(gimbals.held_out_deg.1);
    let better = gimbal_alternatives(&declared)
        .into_iter()
        .filter_map(|(what, c)| {
            let data = stage
                .run(&roll_samples, &gimbal_aligned, &joints, &declared, &c, MAX_ALTERNATIVE_SAMPLES)
                .ok()?;
            Some((what, c, linear_held_out_deg(&device, &data.fit, &data.held)))
        })
        .min_by(|a, b| a.2.total_cmp(&b.2));
    if let Some((what, c, deg)) = better.filter(|b| b.2 < GIMBAL_CONVENTION_RATIO * declared_deg) {
        return Err(fail(STEP_GIMBALS)(HapticError::GimbalConvention {
            declared_deg,
            hint: format!(
                "{what}: with \"joint_convention\": {} in recording.json the held-out axis error would be {deg:.3}°",
                c.json()
            ),
        }));
    }
    sensors[3..].copy_from_slice(&gimbals.sensors);
    // 8. Held-out errors: verify/ if recorded, else the held-out blocks of joints/.
    let verify = match rec.steps.get("verify") {
        Some(s) => ctx.aligned(s, delay_ms).map_err(fail(STEP_VERIFY))?,
        None => split(&all_joints).1,
    };
    let verify_corr = ctx.correspondences(&verify);
    let before_eh = pose_based_transform(&device, &ctx.correspondences(&joints));
    let verify_axes: Vec<([f64; 6], Matrix3<f64>)> = verify.iter().map(|a| (a.raw, a.pose.0)).collect();
    let after_axes = axis_errors_deg(&device, &sensors, &eh, &verify_axes, &reference.axis_in_target);
    let after_positions = position_errors(&device, &position.joints, &eh, &verify_corr);
    let position_mm = BeforeAfter {
        before: rms(&position_errors(&device, &[SensorModel::IDENTITY; 3], &before_eh, &verify_corr)),
        after: rms(&after_positions),
    };
    let orientation_deg = BeforeAfter {
        before: rms(&axis_errors_deg(
            &device,
            &[SensorModel::IDENTITY; 6],
            &before_eh,
            &verify_axes,
            &reference.axis_in_target,
        )),
        after: rms(&after_axes),
    };
    let samples: Vec<HeldOutSample> = verify
        .iter()
        .zip(after_axes.iter().zip(&verify_corr))
        .map(|(a, (axis_error_deg, c))| {
            let th = angles(&sensors, &a.raw);
            let model = device.position_mm(&th);
            HeldOutSample {
                direction: device.rotation(&th).column(2).into_owned(),
                position_mm: model,
                error_mm: eh.0.transpose() * (c.reference_mm - eh.1) - model,
                axis_error_deg: *axis_error_deg,
                theta_deg: [th[0].to_degrees(), th[1].to_degrees(), th[2].to_degrees()],
            }
        })
        .collect();
    let r = eh.0;
    let calibration = HapticCalibration {
        maps: error_maps(&samples),
        samples,
        delay_ms,
        delay_rounds_ms,
        delay_correlation,
        position_mm,
        orientation_deg,
        gimbal_model: gimbals.model,
        gimbal_held_out_deg: gimbals.held_out_deg,
        sensors,
        tip_mm: ([ctx.tip.x, ctx.tip.y, ctx.tip.z], pivot.rms_mm),
        device_to_tracker: (std::array::from_fn(|k| r[(k / 3, k % 3)]), [eh.1.x, eh.1.y, eh.1.z]),
        start,
        convention: rec.convention,
        rejected_samples,
        tracker_gaps,
        held_out: verify.len(),
    };
    // Never a calibration worse than the uncalibrated device.
    let worse = if position_mm.after >= position_mm.before {
        Some((STEP_JOINTS, HapticError::Worse {
            quantity: "position",
            unit: "mm",
            before: position_mm.before,
            after: position_mm.after,
            hint: worse_hint(
                position_mm.before,
                noise_mm,
                "a flipped axis in the start transform, a wrong joint convention or too little motion in joints/",
            ),
        }))
    } else if orientation_deg.after >= orientation_deg.before {
        Some((
            STEP_GIMBALS,
            HapticError::Worse {
                quantity: "orientation",
                unit: "°",
                before: orientation_deg.before,
                after: orientation_deg.after,
                hint: worse_hint(
                    position_mm.before,
                    noise_mm,
                    "a gimbal reading with the wrong sign or column, or too little stylus rotation in gimbal/",
                ),
            },
        ))
    } else {
        None
    };
    match worse {
        Some((step, error)) => {
            Err(HapticFailure { step, error, partial: Some(Box::new(calibration)), maps: None })
        }
        None => Ok(calibration),
    }
}
