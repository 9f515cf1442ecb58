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

const STEP_PIVOT: &str = "pivot calibration (gimbal/)";
const STEP_DELAY: &str = "time delay (delay/)";
const STEP_JOINTS: &str = "joint calibration (joints/)";
const STEP_REFERENCE: &str = "orientation reference (reference/)";
const STEP_GIMBALS: &str = "gimbal calibration (gimbal/, reference/)";
const STEP_VERIFY: &str = "verification (verify/)";

fn fail(step: &'static str) -> impl Fn(HapticError) -> HapticFailure {
    move |error| HapticFailure { step, error, partial: None, maps: None }
}

fn step<'a>(rec: &'a Recording, name: &'static str) -> Result<&'a Step, HapticError> {
    rec.steps.get(name).ok_or(HapticError::Missing(name))
}

fn target<'a>(step: &'a Step, name: &'static str) -> Result<&'a TargetStream, HapticError> {
    step.targets.get(name).ok_or(HapticError::Missing(name))
}

fn poses(s: &TargetStream) -> Vec<Pose> {
    s.rotation.iter().zip(&s.position_mm).map(|(q, p)| (q.to_rotation_matrix().into_inner(), *p)).collect()
}

/// Raw device readings at time `t` (linear interpolation, clamped to the stream).
fn raw_at(d: &DeviceStream, t: f64) -> [f64; 6] {
    let i = d.t_s.partition_point(|&x| x <= t).clamp(1, d.t_s.len().max(2) - 1);
    let (t0, t1) = (d.t_s[i - 1], d.t_s[i]);
    let w = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
    std::array::from_fn(|j| d.raw[i - 1][j] * (1.0 - w) + d.raw[i][j] * w)
}

fn angles(sensors: &[SensorModel; 6], raw: &[f64; 6]) -> [f64; 6] {
    std::array::from_fn(|j| sensors[j].angle(raw[j]))
}

fn with_joints(joints: &[SensorModel; 3]) -> [SensorModel; 6] {
    [joints[0], joints[1], joints[2], SensorModel::IDENTITY, SensorModel::IDENTITY, SensorModel::IDENTITY]
}

/// k-means clusters selecting the joint-calibration samples of each iteration (paper: 200).
pub const CLUSTERS: usize = 200;

/// Minimum spacing of the samples used to fit, mm (the paper's dd).
pub const SAMPLE_SPACING_MM: f64 = 5.0;

/// Length of the blocks of `joints/` of which every fourth is held out to choose the start, s.
pub const HOLD_OUT_BLOCK_S: f64 = 2.0;

/// Indices of samples at least `spacing_mm` apart (greedy, in time order): an even spread over
/// the workspace instead of every tracker sample.
fn spread_out(points: &[Vector3<f64>], spacing_mm: f64) -> Vec<usize> {
    let mut kept: Vec<usize> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if kept.iter().rev().take(400).all(|&k| (points[k] - p).norm() >= spacing_mm) {
            kept.push(i);
        }
    }
    kept
}

/// Stylus-axis error (degrees) of a sensor set against the reference axis in the target frame.
fn axis_errors_deg(
    device: &Device,
    sensors: &[SensorModel; 6],
    eh: &Pose,
    samples: &[([f64; 6], Matrix3<f64>)],
    axis_in_target: &Vector3<f64>,
) -> Vec<f64> {
    samples
        .iter()
        .map(|(raw, r_target)| {
            let model_axis = eh.0 * device.rotation(&angles(sensors, raw)).column(2);
            model_axis.dot(&(r_target * axis_in_target)).clamp(-1.0, 1.0).acos().to_degrees()
        })
        .collect()
}

/// One aligned sample: the device readings at the tracker's time − delay, the target pose, the
/// tracker time.
#[derive(Clone, Copy)]
struct Aligned {
    raw: [f64; 6],
    pose: Pose,
    t_s: f64,
}

/// The recording with wild samples removed; counts of rejections and gaps.
fn cleaned(rec: &Recording) -> (Recording, usize, usize) {
    let (mut rejected, mut gaps) = (0, 0);
    let mut out = rec.clone();
    for step in out.steps.values_mut() {
        for stream in step.targets.values_mut() {
            let (clean, removed) = reject_wild(stream);
            rejected += removed;
            gaps += clean.segments().len() - 1;
            *stream = clean;
        }
    }
    (out, rejected, gaps)
}

/// Everything the stages share.
struct Context<'a> {
    rec: &'a Recording,
    device: Device,
    tip: Vector3<f64>,
}

impl Context<'_> {
    fn hip(&self, pose: &Pose) -> Vector3<f64> {
        pose.0 * self.tip + pose.1
    }

    /// Samples of a step's `hip` target with the device read at tracker time − `lag_ms`.
    fn aligned(&self, s: &Step, lag_ms: f64) -> Result<Vec<Aligned>, HapticError> {
        let hip = target(s, "hip")?;
        let lag = lag_ms / 1000.0;
        let (first, last) = (s.device.t_s[0], *s.device.t_s.last().unwrap_or(&0.0));
        Ok(hip
            .t_s
            .iter()
            .zip(poses(hip))
            .filter(|(t, _)| **t - lag >= first && **t - lag <= last)
            .map(|(t, pose)| Aligned { raw: raw_at(&s.device, t - lag), pose, t_s: *t })
            .collect())
    }

    fn correspondences(&self, samples: &[Aligned]) -> Vec<Correspondence> {
        samples
            .iter()
            .map(|a| Correspondence { raw: [a.raw[0], a.raw[1], a.raw[2]], reference_mm: self.hip(&a.pose) })
            .collect()
    }

    /// The samples used to fit: spread over the workspace.
    fn spread(&self, samples: &[Aligned]) -> Vec<Aligned> {
        let points: Vec<Vector3<f64>> = samples.iter().map(|a| self.hip(&a.pose)).collect();
        spread_out(&points, SAMPLE_SPACING_MM).into_iter().map(|i| samples[i]).collect()
    }

    /// Delay on `delay/` with the joints `joints` and the transform `eh`.
    fn delay(&self, joints: &[SensorModel; 3], eh: &Transform) -> Result<DelayEstimate, HapticError> {
        let delay_step = step(self.rec, "delay")?;
        let hip = target(delay_step, "hip")?;
        let origin = Vector3::from(self.device.origin_mm);
        let sensors = with_joints(joints);
        let dev_signal: Vec<f64> = delay_step
            .device
            .raw
            .iter()
            .map(|r| (self.device.position_mm(&angles(&sensors, r)) - origin).norm())
            .collect();
        let trk_signal: Vec<f64> =
            poses(hip).iter().map(|p| (eh.0.transpose() * (self.hip(p) - eh.1) - origin).norm()).collect();
        Ok(estimate_delay_ms(
            &Signal {
                name: "delay/device.csv",
                what: STYLUS_DISTANCE,
                t_s: &delay_step.device.t_s,
                value: &dev_signal,
            },
            &Signal { name: "delay/hip.csv", what: STYLUS_DISTANCE, t_s: &hip.t_s, value: &trk_signal },
        )?)
    }

    /// The landmark-based start at delay `lag_ms`.
    fn landmark_transform(&self, lag_ms: f64) -> Result<Transform, String> {
        let landmarks = step(self.rec, "landmarks").map_err(|e| e.to_string())?;
        let t1 = target(landmarks, "t1").map_err(|e| e.to_string())?;
        let t2 = target(landmarks, "t2").map_err(|e| e.to_string())?;
        let p1 = pivot_calibration(&poses(t1)).map_err(|e| format!("landmarks/t1.csv: {e}"))?.pivot_mm;
        let lag = lag_ms / 1000.0;
        let theta1: Vec<f64> = t2.t_s.iter().map(|t| raw_at(&landmarks.device, t - lag)[0]).collect();
        let rotations: Vec<Matrix3<f64>> = poses(t2).iter().map(|p| p.0).collect();
        let ay = turret_axis(&rotations, &theta1).map_err(|e| format!("landmarks/t2.csv: {e}"))?;
        let hip = self.aligned(landmarks, lag_ms).map_err(|e| e.to_string())?;
        let p3 = hip
            .iter()
            .min_by(|a, b| a.raw[0].abs().total_cmp(&b.raw[0].abs()))
            .map(|a| self.hip(&a.pose))
            .ok_or_else(|| "landmarks/hip.csv has no samples".to_string())?;
        initial_transform(&self.device, p1, ay, p3).map_err(|e: LandmarkError| format!("landmarks: {e}"))
    }
}

/// Fit and held-out halves of aligned `joints/` samples: every fourth block of
/// [`HOLD_OUT_BLOCK_S`] is held out.
fn split(samples: &[Aligned]) -> (Vec<Aligned>, Vec<Aligned>) {
    let t0 = samples.first().map_or(0.0, |a| a.t_s);
    let held = |a: &Aligned| ((a.t_s - t0) / HOLD_OUT_BLOCK_S) as usize % 4 == 3;
    (
        samples.iter().filter(|a| !held(a)).copied().collect(),
        samples.iter().filter(|a| held(a)).copied().collect(),
    )
}

/// Joint calibration from `start` and its held-out residual RMS, mm.
fn calibrate_from(
    ctx: &Context,
    fit: &[Aligned],
    held: &[Aligned],
    start: Transform,
    joints: [SensorModel; 3],
    seed: u64,
    iterations: usize,
) -> (PositionCalibration, f64) {
    let spread = ctx.correspondences(&ctx.spread(fit));
    let result = calibrate_position(&ctx.device, &spread, start, joints, iterations, Some((CLUSTERS, seed)));
    let residual =
        rms(&position_errors(&ctx.device, &result.joints, &result.transform, &ctx.correspondences(held)));
    (result, residual)
}

/// The joint conventions to try when the residual is implausible: each single change of the
/// declared one (a sign of θ1–θ3, θ3 absolute/relative, two of the first three columns swapped).
fn alternatives(declared: &JointConvention) -> Vec<(String, JointConvention)> {
    let mut out = Vec::new();
    for j in 0..3 {
        let mut c = *declared;
        c.sign[j] = -c.sign[j];
        out.push((format!("θ{} has the opposite sign", j + 1), c));
    }
    let mut c = *declared;
    c.theta3 = match c.theta3 {
        Theta3::Absolute => Theta3::Relative,
        Theta3::Relative => Theta3::Absolute,
    };
    out.push((
        format!(
            "θ3 is reported {} θ2",
            if c.theta3 == Theta3::Relative { "relative to" } else { "absolute, not relative to" }
        ),
        c,
    ));
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let mut c = *declared;
        c.columns.swap(a, b);
        out.push((format!("the columns of θ{} and θ{} are swapped", a + 1, b + 1), c));
    }
    out
}

/// `rec` read with the joint convention `c` instead of the declared one.
fn reconverted(rec: &Recording, c: &JointConvention) -> Recording {
    let mut out = rec.clone();
    for step in out.steps.values_mut() {
        for r in step.device.raw.iter_mut() {
            *r = c.apply(&rec.convention.invert(r));
        }
    }
    out.convention = *c;
    out
}

/// The first delay estimate: pose-based transform (Horn) on the delay step, uncalibrated joints.
fn first_delay(ctx: &Context) -> Result<DelayEstimate, HapticError> {
    let delay_step = step(ctx.rec, "delay")?;
    let horn = pose_based_transform(&ctx.device, &ctx.correspondences(&ctx.aligned(delay_step, 0.0)?));
    ctx.delay(&[SensorModel::IDENTITY; 3], &horn)
}

/// Which single convention change gives the clearest delay where the declared one gives none.
fn delay_convention(ctx: &Context) -> Option<String> {
    alternatives(&ctx.rec.convention)
        .into_iter()
        .filter_map(|(what, c)| {
            let alt = reconverted(ctx.rec, &c);
            first_delay(&Context { rec: &alt, ..*ctx }).ok().map(|e| (what, c, e))
        })
        .max_by(|a, b| a.2.correlation.total_cmp(&b.2.correlation))
        .map(|(what, c, estimate)| {
            format!(
                "{what}: with \"joint_convention\": {} in recording.json the streams correlate ({:.3}) at {:.1} ms",
                c.json(),
                estimate.correlation,
                estimate.delay_ms
            )
        })
}

/// The single changes of the gimbals' convention tried: a sign of θ4 or θ5, their columns
/// swapped.
fn gimbal_alternatives(declared: &JointConvention) -> Vec<(String, JointConvention)> {
    let mut out = Vec::new();
    for j in 3..5 {
        let mut c = *declared;
        c.sign[j] = -c.sign[j];
        out.push((format!("θ{} has the opposite sign", j + 1), c));
    }
    let mut c = *declared;
    c.columns.swap(3, 4);
    out.push(("the columns of θ4 and θ5 are swapped".to_string(), c));
    out
}

/// A declared gimbal convention is refused when another explains the data with less than this
/// fraction of its held-out axis error.
pub const GIMBAL_CONVENTION_RATIO: f64 = 0.33;

/// The orientation reference and the gimbal samples it gives, fitted and held out.
struct GimbalData {
    reference: super::reference::OrientationReference,
    fit: Vec<GimbalSample>,
    held: Vec<GimbalSample>,
}

/// The orientation reference and gimbal samples with calibrated joints and transform.
struct GimbalStage<'a> {
    device: &'a Device,
    joints: &'a [SensorModel; 3],
    eh: &'a Transform,
}

impl GimbalStage<'_> {
    /// Reference and gimbal samples (fit, held out) with the readings taken as convention `c`
    /// instead of `declared`.
    fn run(
        &self,
        roll: &[Aligned],
        gimbal: &[Aligned],
        joints: &[Aligned],
        declared: &JointConvention,
        c: &JointConvention,
        max_samples: usize,
    ) -> Result<GimbalData, ReferenceError> {
        let (device, eh) = (self.device, self.eh);
        let sensors = with_joints(self.joints);
        let convert = |raw: &[f64; 6]| if c == declared { *raw } else { c.apply(&declared.invert(raw)) };
        let frames: Vec<Pose> = roll
            .iter()
            .map(|a| {
                let r = convert(&a.raw);
                let th = angles(&sensors, &[r[0], r[1], r[2], r[3], r[4], 0.0]);
                (device.rotation(&th), device.position_mm(&th))
            })
            .collect();
        let targets: Vec<Pose> = roll.iter().map(|a| a.pose).collect();
        let reference = orientation_reference(&targets, &frames, eh)?;
        let sample = |a: &Aligned, roll: Option<f64>| {
            let r = convert(&a.raw);
            let th = angles(&sensors, &r);
            GimbalSample {
                theta123: [th[0], th[1], th[2]],
                raw: [r[3], r[4], r[5]],
                axis: eh.0.transpose() * (a.pose.0 * reference.axis_in_target),
                roll,
            }
        };
        let samples: Vec<GimbalSample> = gimbal
            .iter()
            .chain(joints.iter())
            .map(|a| sample(a, None))
            .chain(roll.iter().zip(&reference.roll).map(|(a, r)| sample(a, Some(*r))))
            .collect();
        let stride = samples.len().div_ceil(max_samples).max(1);
        let samples: Vec<GimbalSample> = samples.into_iter().step_by(stride).collect();
        // Every fourth sample is held out to choose the gimbal model.
        let held: Vec<GimbalSample> = samples.iter().step_by(4).copied().collect();
        let fit: Vec<GimbalSample> =
            samples.iter().enumerate().filter(|(i, _)| i % 4 != 0).map(|(_, s)| *s).collect();
        Ok(GimbalData { reference, fit, held })
    }
}

/// Which single convention change explains the joints data, if any: its description, the
/// convention and its held-out residual.
fn diagnose_convention(
    ctx: &Context,
    fit: &[Aligned],
    held: &[Aligned],
    limit_mm: f64,
) -> Option<(String, JointConvention, f64)> {
    let declared = ctx.rec.convention;
    let convert = |samples: &[Aligned], c: &JointConvention| -> Vec<Aligned> {
        samples.iter().map(|a| Aligned { raw: c.apply(&declared.invert(&a.raw)), ..*a }).collect()
    };
    alternatives(&declared)
        .into_iter()
        .map(|(what, c)| {
            let (f, h) = (convert(fit, &c), convert(held, &c));
            let start = pose_based_transform(&ctx.device, &ctx.correspondences(&f));
            let (_, residual) =
                calibrate_from(ctx, &f, &h, start, [SensorModel::IDENTITY; 3], 7, START_ITERATIONS);
            (what, c, residual)
        })
        .filter(|(_, _, r)| *r < limit_mm)
        .min_by(|a, b| a.2.total_cmp(&b.2))
}

/// Held-out joint residuals of a joint calibration (stylus directions with uncalibrated
/// gimbals, axis errors 0: not computed).
fn joint_residuals(ctx: &Context, position: &PositionCalibration, held: &[Aligned]) -> Vec<HeldOutSample> {
    let sensors = with_joints(&position.joints);
    let (r, t) = position.transform;
    held.iter()
        .map(|a| {
            let th = angles(&sensors, &a.raw);
            let model = ctx.device.position_mm(&th);
            HeldOutSample {
                direction: ctx.device.rotation(&th).column(2).into_owned(),
                position_mm: model,
                error_mm: r.transpose() * (ctx.hip(&a.pose) - t) - model,
                axis_error_deg: 0.0,
                theta_deg: [th[0].to_degrees(), th[1].to_degrees(), th[2].to_degrees()],
            }
        })
        .collect()
}

/// The likely cause of a calibration worse than the uncalibrated device.
fn worse_hint(position_before_mm: f64, noise_mm: f64, cause: &str) -> String {
    if position_before_mm <= 2.0 * noise_mm {
        format!("the uncalibrated device is already at the tracker noise ({position_before_mm:.3} mm against {noise_mm:.3} mm): it needs no calibration; otherwise {cause}")
    } else {
        cause.to_string()
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::haptic::simulate::{simulate_recording, HapticSimOptions};

    /// Noise floors of the simulated tracker on verify/: RMS distance of the measured HIP from
    /// the true one, and RMS angle of the measured stylus axis from the true one.
    fn floors(rec: &Recording, truth: &crate::haptic::simulate::HapticTruth) -> (f64, f64) {
        let verify = &rec.steps["verify"];
        let hip = &verify.targets["hip"];
        let tip_true = -(truth.mount.0.transpose() * truth.mount.1);
        let axis_true = truth.mount.0.transpose() * Vector3::z();
        let (mut dp, mut da) = (Vec::new(), Vec::new());
        for ((t, q), p) in hip.t_s.iter().zip(&hip.rotation).zip(&hip.position_mm) {
            let theta: [f64; 6] = {
                let raw = raw_at(&verify.device, t - truth.delay_ms / 1000.0);
                angles(&truth.sensors, &raw)
            };
            let (r_true, _) = truth.stylus_target(&theta);
            dp.push((q * tip_true + p - truth.hip(&theta)).norm());
            da.push((q * axis_true).dot(&(r_true * axis_true)).clamp(-1.0, 1.0).acos().to_degrees());
        }
        (rms(&dp), rms(&da))
    }

    #[test]
    fn a_simulated_recording_calibrates_to_the_tracker_noise_floor() {
        for quadratic in [true, false] {
            let options = HapticSimOptions {
                seed: 5,
                delay_ms: 13.3,
                quadratic_gimbals: quadratic,
                joints_seconds: 40.0,
                ..HapticSimOptions::default()
            };
            let (rec, truth) = simulate_recording(&options);
            let result = calibrate_recording(&rec).expect("calibrates");
            let (floor_mm, floor_deg) = floors(&rec, &truth);
            eprintln!("quadratic {quadratic}: delay {:.3} ms, position {:.3} → {:.3} mm (floor {floor_mm:.3}), orientation {:.3} → {:.3}° (floor {floor_deg:.3}), gimbals {:?}", result.delay_ms, result.position_mm.before, result.position_mm.after, result.orientation_deg.before, result.orientation_deg.after, result.gimbal_model);
            assert!(
                (result.delay_ms - options.delay_ms).abs() < 0.25,
                "delay {} vs {}",
                result.delay_ms,
                options.delay_ms
            );
            assert!(result.position_mm.before > 3.0 * result.position_mm.after);
            assert!(
                result.position_mm.after <= 1.10 * floor_mm,
                "position {} vs floor {floor_mm}",
                result.position_mm.after
            );
            assert!(
                result.orientation_deg.after <= 1.10 * floor_deg,
                "orientation {} vs floor {floor_deg}",
                result.orientation_deg.after
            );
            assert_eq!(
                result.gimbal_model,
                if quadratic { GimbalModel::Quadratic } else { GimbalModel::Linear }
            );
        }
    }
}
