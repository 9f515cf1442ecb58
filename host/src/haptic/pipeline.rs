//! `kincal haptic calibrate`: the whole procedure over a recording folder.
//!
//! 1. pivot calibration of the stylus target on `gimbal/` (HIP held in its stand);
//! 2. landmark-based initial transform: p1 from T1 pivoting about the central joint, p2 the
//!    centre of T2's circle about the y axis, p3 the HIP where the device reads θ1 ≈ 0;
//! 3. time delay on `delay/`; the device is then read at tracker time − delay;
//! 4. iterative joint-angle calibration on `joints/`, then the delay estimated again with the
//!    calibrated joints and the joints refined with the new alignment;
//! 5. orientation reference on `reference/`;
//! 6. gimbal calibration on `gimbal/` + `joints/` (axis) and `reference/` (roll);
//! 7. position and orientation errors on `verify/` (held-out), before and after.

use super::delay::{estimate_delay_ms, DelayError, Signal};
use super::gimbal::{calibrate_gimbals, GimbalModel, GimbalSample};
use super::kinematics::{Device, SensorModel};
use super::landmarks::{initial_transform, LandmarkError};
use super::pivot::{pivot_calibration, PivotError};
use super::position::{calibrate_position, pose_based_transform, position_errors, Correspondence};
use super::recording::{DeviceStream, Recording, Step, TargetStream};
use super::reference::{fit_circle, orientation_reference, Pose, ReferenceError};
use nalgebra::{Matrix3, Vector2, Vector3};

/// Why a recording could not be calibrated.
#[derive(Debug, thiserror::Error)]
pub enum HapticError {
    /// A step or target is missing from the recording.
    #[error("the recording has no {0}")]
    Missing(&'static str),
    /// Pivot calibration failed.
    #[error("pivot calibration on {0}: {1}")]
    Pivot(&'static str, PivotError),
    /// The landmarks do not define a frame.
    #[error("landmarks: {0}")]
    Landmarks(#[from] LandmarkError),
    /// No delay could be estimated.
    #[error("time delay on delay/: {0}")]
    Delay(#[from] DelayError),
    /// No orientation reference could be derived.
    #[error("orientation reference on reference/: {0}")]
    Reference(#[from] ReferenceError),
}

/// Errors before and after, as summary.json reports them.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct BeforeAfter {
    /// Before calibration.
    pub before: f64,
    /// After calibration.
    pub after: f64,
}

/// The result of a haptic calibration.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HapticCalibration {
    /// Tracker delay behind the device, ms.
    pub delay_ms: f64,
    /// Position error RMS on held-out samples, mm.
    pub position_mm: BeforeAfter,
    /// Stylus-axis error RMS on held-out samples, degrees.
    pub orientation_deg: BeforeAfter,
    /// Gimbal sensor model chosen.
    pub gimbal_model: GimbalModel,
    /// Sensor models of joints 1–3 and gimbals 4–6 (θ = j·raw² + k·raw + m).
    pub sensors: [SensorModel; 6],
    /// HIP position in the stylus target frame, mm, and the pivot RMS, mm.
    pub tip_mm: ([f64; 3], f64),
    /// Device → tracker rotation (row-major) and translation, mm.
    pub device_to_tracker: ([f64; 9], [f64; 3]),
    /// Held-out samples the errors were measured on.
    pub held_out: usize,
    /// Per held-out sample: see [`HeldOut`].
    #[serde(skip)]
    pub samples: Vec<HeldOut>,
}

/// One held-out sample: stylus direction in device coordinates (unit), axis error after
/// calibration (degrees), position error after calibration (mm).
pub type HeldOut = (Vector3<f64>, f64, f64);

/// `summary.json` of a haptic run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HapticSummary {
    /// Tracker delay behind the device, ms.
    pub delay_ms: f64,
    /// Position error RMS before and after, mm.
    pub position: PositionSummary,
    /// Stylus-axis error RMS before and after, degrees.
    pub orientation: OrientationSummary,
    /// Gimbal sensor model chosen on held-out error.
    pub gimbal_model: GimbalModel,
    /// The full result.
    pub calibration: HapticCalibration,
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

impl HapticCalibration {
    /// The summary written to `summary.json`.
    pub fn summary(&self) -> HapticSummary {
        HapticSummary {
            delay_ms: self.delay_ms,
            position: PositionSummary {
                before_mm: self.position_mm.before,
                after_mm: self.position_mm.after,
            },
            orientation: OrientationSummary {
                before_deg: self.orientation_deg.before,
                after_deg: self.orientation_deg.after,
            },
            gimbal_model: self.gimbal_model,
            calibration: self.clone(),
        }
    }
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

/// Centre of the circle a point moves on in 3-D (plane by SVD, circle by ODR).
fn circle_centre(points: &[Vector3<f64>]) -> Vector3<f64> {
    let n = points.len().max(1) as f64;
    let mean = points.iter().sum::<Vector3<f64>>() / n;
    let m = nalgebra::DMatrix::from_fn(points.len(), 3, |i, k| points[i][k] - mean[k]);
    let v = m.svd(false, true).v_t.unwrap_or_else(|| nalgebra::DMatrix::identity(3, 3));
    let (u, w) =
        (Vector3::new(v[(0, 0)], v[(0, 1)], v[(0, 2)]), Vector3::new(v[(1, 0)], v[(1, 1)], v[(1, 2)]));
    let flat: Vec<Vector2<f64>> =
        points.iter().map(|p| Vector2::new((p - mean).dot(&u), (p - mean).dot(&w))).collect();
    let (c, _, _) = fit_circle(&flat);
    mean + u * c.x + w * c.y
}

/// k-means clusters selecting the joint-calibration samples of each iteration (paper: 200).
pub const CLUSTERS: usize = 200;

/// Minimum spacing of the samples used to fit, mm (the paper's dd).
pub const SAMPLE_SPACING_MM: f64 = 5.0;

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

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|e| e * e).sum::<f64>() / v.len().max(1) as f64).sqrt()
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

/// Calibrate a recording.
pub fn calibrate_recording(rec: &Recording) -> Result<HapticCalibration, HapticError> {
    let device = rec.device;
    // 1. The HIP in the stylus target frame.
    let gimbal_step = step(rec, "gimbal")?;
    let pivot = pivot_calibration(&poses(target(gimbal_step, "hip")?))
        .map_err(|e| HapticError::Pivot("gimbal/hip.csv", e))?;
    let tip = pivot.tip_mm;
    let hip_of = |s: &TargetStream| -> Vec<Vector3<f64>> {
        s.rotation.iter().zip(&s.position_mm).map(|(q, p)| q * tip + p).collect()
    };
    // 2. Landmark-based initial transform.
    let landmarks = step(rec, "landmarks")?;
    let p1 = pivot_calibration(&poses(target(landmarks, "t1")?))
        .map_err(|e| HapticError::Pivot("landmarks/t1.csv", e))?
        .pivot_mm;
    let p2 = circle_centre(&target(landmarks, "t2")?.position_mm);
    let hip_l = target(landmarks, "hip")?;
    let hip_l_points = hip_of(hip_l);
    let p3_index = (0..hip_l.t_s.len())
        .min_by(|&a, &b| {
            raw_at(&landmarks.device, hip_l.t_s[a])[0]
                .abs()
                .total_cmp(&raw_at(&landmarks.device, hip_l.t_s[b])[0].abs())
        })
        .ok_or(HapticError::Missing("landmarks/hip.csv samples"))?;
    let eh_init = initial_transform(&device, p1, p2, hip_l_points[p3_index])?;
    // 3. Delay: distance from the device origin in both streams.
    let delay_step = step(rec, "delay")?;
    let hip_d = target(delay_step, "hip")?;
    let hip_d_points = hip_of(hip_d);
    let origin = Vector3::from(device.origin_mm);
    let estimate_delay = |joints: &[SensorModel; 3], eh: &Pose| -> Result<f64, HapticError> {
        let sensors = [
            joints[0],
            joints[1],
            joints[2],
            SensorModel::IDENTITY,
            SensorModel::IDENTITY,
            SensorModel::IDENTITY,
        ];
        let dev_signal: Vec<f64> = delay_step
            .device
            .raw
            .iter()
            .map(|r| (device.position_mm(&angles(&sensors, r)) - origin).norm())
            .collect();
        let trk_signal: Vec<f64> =
            hip_d_points.iter().map(|p| (eh.0.transpose() * (p - eh.1) - origin).norm()).collect();
        Ok(estimate_delay_ms(
            &Signal { name: "delay/device.csv", t_s: &delay_step.device.t_s, value: &dev_signal },
            &Signal { name: "delay/hip.csv", t_s: &hip_d.t_s, value: &trk_signal },
        )?)
    };
    // Aligned samples of a step: raw device readings at the tracker's times, the target pose.
    let aligned = |s: &Step, lag: f64| -> Result<Vec<([f64; 6], Pose)>, HapticError> {
        let hip = target(s, "hip")?;
        Ok(hip
            .t_s
            .iter()
            .zip(poses(hip))
            .filter(|(t, _)| {
                **t - lag >= s.device.t_s[0] && **t - lag <= *s.device.t_s.last().unwrap_or(&0.0)
            })
            .map(|(t, pose)| (raw_at(&s.device, t - lag), pose))
            .collect())
    };
    let correspondences_of = |samples: &[([f64; 6], Pose)]| -> Vec<Correspondence> {
        samples
            .iter()
            .map(|(raw, (r, p))| Correspondence { raw: [raw[0], raw[1], raw[2]], reference_mm: r * tip + p })
            .collect()
    };
    // The samples used to fit: spread over the workspace.
    let spread = |samples: Vec<([f64; 6], Pose)>| -> Vec<([f64; 6], Pose)> {
        let points: Vec<Vector3<f64>> = samples.iter().map(|(_, (r, p))| r * tip + p).collect();
        spread_out(&points, SAMPLE_SPACING_MM).into_iter().map(|i| samples[i]).collect()
    };
    // 4. Joint angles, then the delay again with the calibrated joints (the uncalibrated model
    //    distorts the distance signal and biases the first estimate), and the joints again.
    let joints_step = step(rec, "joints")?;
    let first_delay = estimate_delay(&[SensorModel::IDENTITY; 3], &eh_init)?;
    let first = calibrate_position(
        &device,
        &correspondences_of(&spread(aligned(joints_step, first_delay / 1000.0)?)),
        eh_init,
        [SensorModel::IDENTITY; 3],
        20,
        Some((CLUSTERS, 1)),
    );
    let delay_ms = estimate_delay(&first.joints, &first.transform)?;
    let lag = delay_ms / 1000.0;
    let all_joints = aligned(joints_step, lag)?;
    let joints = spread(all_joints.clone());
    let correspondences = correspondences_of(&joints);
    let position = calibrate_position(
        &device,
        &correspondences,
        first.transform,
        first.joints,
        20,
        Some((CLUSTERS, 101)),
    );
    let eh = position.transform;
    let mut sensors = [SensorModel::IDENTITY; 6];
    sensors[..3].copy_from_slice(&position.joints);
    // 5. Orientation reference from the roll.
    let roll_samples = aligned(step(rec, "reference")?, lag)?;
    let frames: Vec<Pose> = roll_samples
        .iter()
        .map(|(raw, _)| {
            let th = angles(&sensors, &[raw[0], raw[1], raw[2], raw[3], raw[4], 0.0]);
            (device.rotation(&th), device.position_mm(&th))
        })
        .collect();
    let targets: Vec<Pose> = roll_samples.iter().map(|(_, pose)| *pose).collect();
    let reference = orientation_reference(&targets, &frames, &eh)?;
    // 6. Gimbals: axis samples from gimbal/ and joints/, roll samples from reference/.
    let mut gimbal_samples: Vec<GimbalSample> = Vec::new();
    for (raw, (r_target, _)) in spread(aligned(gimbal_step, lag)?).iter().chain(joints.iter()) {
        let th = angles(&sensors, raw);
        gimbal_samples.push(GimbalSample {
            theta123: [th[0], th[1], th[2]],
            raw: [raw[3], raw[4], raw[5]],
            axis: eh.0.transpose() * (r_target * reference.axis_in_target),
            roll: None,
        });
    }
    for ((raw, (r_target, _)), roll) in roll_samples.iter().zip(&reference.roll) {
        let th = angles(&sensors, raw);
        gimbal_samples.push(GimbalSample {
            theta123: [th[0], th[1], th[2]],
            raw: [raw[3], raw[4], raw[5]],
            axis: eh.0.transpose() * (r_target * reference.axis_in_target),
            roll: Some(*roll),
        });
    }
    // Every fourth sample is held out to choose the gimbal model.
    let held: Vec<GimbalSample> = gimbal_samples.iter().step_by(4).copied().collect();
    let fit: Vec<GimbalSample> =
        gimbal_samples.iter().enumerate().filter(|(i, _)| i % 4 != 0).map(|(_, s)| *s).collect();
    let gimbals = calibrate_gimbals(&device, &fit, &held);
    sensors[3..].copy_from_slice(&gimbals.sensors);
    // 7. Held-out errors: verify/ if recorded, else the held-out quarter of joints/.
    let verify = match rec.steps.get("verify") {
        Some(s) => aligned(s, lag)?,
        None => all_joints.iter().enumerate().filter(|(i, _)| i % 4 == 0).map(|(_, s)| *s).collect(),
    };
    let verify_corr = correspondences_of(&verify);
    let before_eh = pose_based_transform(&device, &correspondences);
    let verify_axes: Vec<([f64; 6], Matrix3<f64>)> = verify.iter().map(|(raw, (r, _))| (*raw, *r)).collect();
    let position_mm = BeforeAfter {
        before: rms(&position_errors(&device, &[SensorModel::IDENTITY; 3], &before_eh, &verify_corr)),
        after: rms(&position_errors(&device, &position.joints, &eh, &verify_corr)),
    };
    let orientation_deg = BeforeAfter {
        before: rms(&axis_errors_deg(
            &device,
            &[SensorModel::IDENTITY; 6],
            &before_eh,
            &verify_axes,
            &reference.axis_in_target,
        )),
        after: rms(&axis_errors_deg(&device, &sensors, &eh, &verify_axes, &reference.axis_in_target)),
    };
    let after_axes = axis_errors_deg(&device, &sensors, &eh, &verify_axes, &reference.axis_in_target);
    let after_positions = position_errors(&device, &position.joints, &eh, &verify_corr);
    let samples = verify_axes
        .iter()
        .zip(after_axes.iter().zip(&after_positions))
        .map(|((raw, _), (a, p))| (device.rotation(&angles(&sensors, raw)).column(2).into_owned(), *a, *p))
        .collect();
    let r = eh.0;
    Ok(HapticCalibration {
        samples,
        delay_ms,
        position_mm,
        orientation_deg,
        gimbal_model: gimbals.model,
        sensors,
        tip_mm: ([tip.x, tip.y, tip.z], pivot.rms_mm),
        device_to_tracker: (std::array::from_fn(|k| r[(k / 3, k % 3)]), [eh.1.x, eh.1.y, eh.1.z]),
        held_out: verify.len(),
    })
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
