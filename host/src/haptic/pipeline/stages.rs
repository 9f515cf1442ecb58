//! The stages of the haptic calibration and what they share: the aligned samples, the context,
//! the starts, the conventions tried when the data refuse the declared one, the gimbal stage.

use super::*;

pub(super) const STEP_PIVOT: &str = "pivot calibration (gimbal/)";
pub(super) const STEP_DELAY: &str = "time delay (delay/)";
pub(super) const STEP_JOINTS: &str = "joint calibration (joints/)";
pub(super) const STEP_REFERENCE: &str = "orientation reference (reference/)";
pub(super) const STEP_GIMBALS: &str = "gimbal calibration (gimbal/, reference/)";
pub(super) const STEP_VERIFY: &str = "verification (verify/)";

pub(super) fn fail(step: &'static str) -> impl Fn(HapticError) -> HapticFailure {
    move |error| HapticFailure { step, error, partial: None, maps: None }
}

pub(super) fn step<'a>(rec: &'a Recording, name: &'static str) -> Result<&'a Step, HapticError> {
    rec.steps.get(name).ok_or(HapticError::Missing(name))
}

pub(super) fn target<'a>(step: &'a Step, name: &'static str) -> Result<&'a TargetStream, HapticError> {
    step.targets.get(name).ok_or(HapticError::Missing(name))
}

pub(super) fn poses(s: &TargetStream) -> Vec<Pose> {
    s.rotation.iter().zip(&s.position_mm).map(|(q, p)| (q.to_rotation_matrix().into_inner(), *p)).collect()
}

/// Raw device readings at time `t` (linear interpolation, clamped to the stream).
pub(super) fn raw_at(d: &DeviceStream, t: f64) -> [f64; 6] {
    let i = d.t_s.partition_point(|&x| x <= t).clamp(1, d.t_s.len().max(2) - 1);
    let (t0, t1) = (d.t_s[i - 1], d.t_s[i]);
    let w = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
    std::array::from_fn(|j| d.raw[i - 1][j] * (1.0 - w) + d.raw[i][j] * w)
}

pub(super) fn angles(sensors: &[SensorModel; 6], raw: &[f64; 6]) -> [f64; 6] {
    std::array::from_fn(|j| sensors[j].angle(raw[j]))
}

pub(super) fn with_joints(joints: &[SensorModel; 3]) -> [SensorModel; 6] {
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
pub(super) fn spread_out(points: &[Vector3<f64>], spacing_mm: f64) -> Vec<usize> {
    let mut kept: Vec<usize> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if kept.iter().rev().take(400).all(|&k| (points[k] - p).norm() >= spacing_mm) {
            kept.push(i);
        }
    }
    kept
}

/// Stylus-axis error (degrees) of a sensor set against the reference axis in the target frame.
pub(super) fn axis_errors_deg(
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
pub(super) struct Aligned {
    pub(super) raw: [f64; 6],
    pub(super) pose: Pose,
    pub(super) t_s: f64,
}

/// The recording with wild samples removed; counts of rejections and gaps.
pub(super) fn cleaned(rec: &Recording) -> (Recording, usize, usize) {
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
pub(super) struct Context<'a> {
    pub(super) rec: &'a Recording,
    pub(super) device: Device,
    pub(super) tip: Vector3<f64>,
}

impl Context<'_> {
    pub(super) fn hip(&self, pose: &Pose) -> Vector3<f64> {
        pose.0 * self.tip + pose.1
    }

    /// Samples of a step's `hip` target with the device read at tracker time − `lag_ms`.
    pub(super) fn aligned(&self, s: &Step, lag_ms: f64) -> Result<Vec<Aligned>, HapticError> {
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

    pub(super) fn correspondences(&self, samples: &[Aligned]) -> Vec<Correspondence> {
        samples
            .iter()
            .map(|a| Correspondence { raw: [a.raw[0], a.raw[1], a.raw[2]], reference_mm: self.hip(&a.pose) })
            .collect()
    }

    /// The samples used to fit: spread over the workspace.
    pub(super) fn spread(&self, samples: &[Aligned]) -> Vec<Aligned> {
        let points: Vec<Vector3<f64>> = samples.iter().map(|a| self.hip(&a.pose)).collect();
        spread_out(&points, SAMPLE_SPACING_MM).into_iter().map(|i| samples[i]).collect()
    }

    /// Delay on `delay/` with the joints `joints` and the transform `eh`.
    pub(super) fn delay(
        &self,
        joints: &[SensorModel; 3],
        eh: &Transform,
    ) -> Result<DelayEstimate, HapticError> {
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
    pub(super) fn landmark_transform(&self, lag_ms: f64) -> Result<Transform, String> {
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
pub(super) fn split(samples: &[Aligned]) -> (Vec<Aligned>, Vec<Aligned>) {
    let t0 = samples.first().map_or(0.0, |a| a.t_s);
    let held = |a: &Aligned| ((a.t_s - t0) / HOLD_OUT_BLOCK_S) as usize % 4 == 3;
    (
        samples.iter().filter(|a| !held(a)).copied().collect(),
        samples.iter().filter(|a| held(a)).copied().collect(),
    )
}

/// Joint calibration from `start` and its held-out residual RMS, mm.
pub(super) fn calibrate_from(
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
pub(super) fn alternatives(declared: &JointConvention) -> Vec<(String, JointConvention)> {
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
pub(super) fn reconverted(rec: &Recording, c: &JointConvention) -> Recording {
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
pub(super) fn first_delay(ctx: &Context) -> Result<DelayEstimate, HapticError> {
    let delay_step = step(ctx.rec, "delay")?;
    let horn = pose_based_transform(&ctx.device, &ctx.correspondences(&ctx.aligned(delay_step, 0.0)?));
    ctx.delay(&[SensorModel::IDENTITY; 3], &horn)
}

/// Which single convention change gives the clearest delay where the declared one gives none.
pub(super) fn delay_convention(ctx: &Context) -> Option<String> {
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
pub(super) fn gimbal_alternatives(declared: &JointConvention) -> Vec<(String, JointConvention)> {
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
pub(super) struct GimbalData {
    pub(super) reference: crate::haptic::reference::OrientationReference,
    pub(super) fit: Vec<GimbalSample>,
    pub(super) held: Vec<GimbalSample>,
}

/// The orientation reference and gimbal samples with calibrated joints and transform.
pub(super) struct GimbalStage<'a> {
    pub(super) device: &'a Device,
    pub(super) joints: &'a [SensorModel; 3],
    pub(super) eh: &'a Transform,
}

impl GimbalStage<'_> {
    /// Reference and gimbal samples (fit, held out) with the readings taken as convention `c`
    /// instead of `declared`.
    pub(super) fn run(
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
pub(super) fn diagnose_convention(
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
pub(super) fn joint_residuals(
    ctx: &Context,
    position: &PositionCalibration,
    held: &[Aligned],
) -> Vec<HeldOutSample> {
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
pub(super) fn worse_hint(position_before_mm: f64, noise_mm: f64, cause: &str) -> String {
    if position_before_mm <= 2.0 * noise_mm {
        format!("the uncalibrated device is already at the tracker noise ({position_before_mm:.3} mm against {noise_mm:.3} mm): it needs no calibration; otherwise {cause}")
    } else {
        cause.to_string()
    }
}
