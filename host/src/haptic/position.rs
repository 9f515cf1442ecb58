//! Position calibration of the joint-angle sensors (Harders' iterative method, with the
//! paper's filters): alternate
//! 1. the device → tracker transform EH by absolute orientation (Horn) between the device's
//!    positions (current sensor model) and the reference HIP positions from the tracker, using
//!    samples within [`EH_RADIUS_MM`] of the device origin and at least `dd` apart (5 mm, relaxed
//!    by 0.9 every iteration), and
//! 2. Levenberg–Marquardt on linear corrections θ_j = k_j·raw_j + m_j of joints 1–3, the residual
//!    of each sample being the distance ‖FK(θ) − EH⁻¹·ref‖ (not its square), over the samples of
//!    a [`Clustering`] selection.
//!
//! The loop stops when the mean error changes by less than 10⁻⁴ mm; a step that makes the error
//! worse is retried from the previous result, and it stops after three failures to improve.

use super::kinematics::{Device, SensorModel};
use crate::numerics::geometry::absolute_orientation;
use crate::numerics::solver::{self, Residuals, SolverOptions, Termination};
use nalgebra::{Matrix3, Vector3};

/// Samples farther than this from the device origin are not used for EH, mm.
pub const EH_RADIUS_MM: f64 = 100.0;
/// Kept samples the spacing of a new one is checked against.
const SPACING_WINDOW: usize = 400;
/// Initial minimum spacing of the samples used for EH, mm.
pub const EH_SPACING_MM: f64 = 5.0;

/// One time-aligned sample: raw joint readings and the HIP reference in tracker coordinates.
#[derive(Clone, Copy, Debug)]
pub struct Correspondence {
    /// Raw readings of joints 1–3, radians.
    pub raw: [f64; 3],
    /// Reference HIP position in tracker coordinates, mm.
    pub reference_mm: Vector3<f64>,
}

/// Device → tracker transform: p_tracker = R·p_device + t.
pub type Transform = (Matrix3<f64>, Vector3<f64>);

/// Result of the position calibration.
#[derive(Clone, Debug)]
pub struct PositionCalibration {
    /// Sensor models of joints 1–3.
    pub joints: [SensorModel; 3],
    /// Device → tracker transform.
    pub transform: Transform,
    /// Mean position error on the calibration samples after each iteration, mm.
    pub mean_error_mm: Vec<f64>,
}

fn angles(joints: &[SensorModel; 3], raw: &[f64; 3]) -> [f64; 6] {
    [joints[0].angle(raw[0]), joints[1].angle(raw[1]), joints[2].angle(raw[2]), 0.0, 0.0, 0.0]
}

/// Device positions of `samples` under `joints`.
fn device_points(
    device: &Device,
    joints: &[SensorModel; 3],
    samples: &[Correspondence],
) -> Vec<Vector3<f64>> {
    samples.iter().map(|s| device.position_mm(&angles(joints, &s.raw))).collect()
}

/// Position errors ‖R·FK + t − ref‖ of `samples`, mm.
pub fn position_errors(
    device: &Device,
    joints: &[SensorModel; 3],
    transform: &Transform,
    samples: &[Correspondence],
) -> Vec<f64> {
    let (r, t) = transform;
    device_points(device, joints, samples)
        .iter()
        .zip(samples)
        .map(|(p, s)| (r * p + t - s.reference_mm).norm())
        .collect()
}

/// EH from the filtered samples (falls back to all samples if too few pass the filters).
fn estimate_transform(
    device: &Device,
    joints: &[SensorModel; 3],
    samples: &[Correspondence],
    spacing_mm: f64,
) -> Transform {
    let points = device_points(device, joints, samples);
    let origin = Vector3::from(device.origin_mm);
    let mut chosen: Vec<usize> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        // Spacing checked against the last samples kept (the samples come in time order).
        if (p - origin).norm() <= EH_RADIUS_MM
            && chosen.iter().rev().take(SPACING_WINDOW).all(|&c| (points[c] - p).norm() >= spacing_mm)
        {
            chosen.push(i);
        }
    }
    if chosen.len() < 10 {
        chosen = (0..samples.len()).collect();
    }
    let a: Vec<Vector3<f64>> = chosen.iter().map(|&i| points[i]).collect();
    let b: Vec<Vector3<f64>> = chosen.iter().map(|&i| samples[i].reference_mm).collect();
    absolute_orientation(&a, &b)
}

/// Distances to the references in device coordinates, as a function of (k1..k3, m1..m3).
struct JointProblem<'a> {
    device: &'a Device,
    samples: &'a [Correspondence],
    references: Vec<Vector3<f64>>,
}

impl JointProblem<'_> {
    fn joints(x: &[f64]) -> [SensorModel; 3] {
        std::array::from_fn(|j| SensorModel { j: 0.0, k: x[j], m: x[3 + j] })
    }
}

impl Residuals for JointProblem<'_> {
    fn len(&self) -> usize {
        self.samples.len()
    }

    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
        let joints = Self::joints(x);
        let (l1, l2) = (self.device.l1_mm, self.device.l2_mm);
        let mut jac = jacobian;
        for (i, s) in self.samples.iter().enumerate() {
            let th = angles(&joints, &s.raw);
            let e = self.device.position_mm(&th) - self.references[i];
            let d = e.norm();
            r[i] = d;
            let Some(j) = jac.as_deref_mut() else { continue };
            let (s1, c1, s2, c2, s3, c3) =
                (th[0].sin(), th[0].cos(), th[1].sin(), th[1].cos(), th[2].sin(), th[2].cos());
            let reach = l1 * c2 + l2 * s3;
            let dp = [
                Vector3::new(-reach * c1, 0.0, -reach * s1),
                Vector3::new(l1 * s2 * s1, l1 * c2, -l1 * s2 * c1),
                Vector3::new(-l2 * c3 * s1, l2 * s3, l2 * c3 * c1),
            ];
            let u = if d > 1e-12 { e / d } else { Vector3::zeros() };
            for k in 0..3 {
                let g = u.dot(&dp[k]);
                j[i * 6 + k] = g * s.raw[k];
                j[i * 6 + 3 + k] = g;
            }
        }
    }
}

/// Samples the LM step of each iteration uses: `Some((n, seed))` re-clusters the samples into `n`
/// k-means centroids every iteration (seed + iteration) and uses the nearest real samples
/// (paper §2.2); `None` uses every sample.
pub type Clustering = Option<(usize, u64)>;

/// Calibrate joints 1–3 starting from `transform` (pose- or landmark-based) and `start` models.
pub fn calibrate_position(
    device: &Device,
    samples: &[Correspondence],
    transform: Transform,
    start: [SensorModel; 3],
    max_iterations: usize,
    clustering: Clustering,
) -> PositionCalibration {
    let mut joints = start;
    let mut eh = transform;
    let mut history = Vec::new();
    let mut best = f64::INFINITY;
    let mut failures = 0;
    let mut spacing = EH_SPACING_MM;
    let reference_points: Vec<Vector3<f64>> = samples.iter().map(|s| s.reference_mm).collect();
    for iteration in 0..max_iterations {
        let (r, t) = eh;
        let chosen: Vec<Correspondence> = match clustering {
            Some((n, seed)) => super::select::kmeans_select(&reference_points, n, seed + iteration as u64)
                .into_iter()
                .map(|i| samples[i])
                .collect(),
            None => samples.to_vec(),
        };
        let references: Vec<Vector3<f64>> =
            chosen.iter().map(|s| r.transpose() * (s.reference_mm - t)).collect();
        let problem = JointProblem { device, samples: &chosen, references };
        let x0: Vec<f64> = (0..6).map(|i| if i < 3 { joints[i].k } else { joints[i - 3].m }).collect();
        let lower = [0.5, 0.5, 0.5, -1.0, -1.0, -1.0];
        let upper = [1.5, 1.5, 1.5, 1.0, 1.0, 1.0];
        let solved = solver::solve(
            &problem,
            &x0,
            &lower,
            &upper,
            &SolverOptions {
                max_iterations: 50,
                termination: Termination::AcceptedSteps,
                ..SolverOptions::default()
            },
        );
        let candidate = JointProblem::joints(&solved.x);
        let candidate_eh = estimate_transform(device, &candidate, samples, spacing);
        spacing *= 0.9;
        let errors = position_errors(device, &candidate, &candidate_eh, samples);
        let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
        history.push(mean);
        if mean < best {
            let change = best - mean;
            best = mean;
            joints = candidate;
            eh = candidate_eh;
            failures = 0;
            if change < 1e-4 {
                break;
            }
        } else {
            failures += 1;
            if failures >= 3 {
                break;
            }
        }
    }
    PositionCalibration { joints, transform: eh, mean_error_mm: history }
}

/// The pose-based initial transform: absolute orientation between the uncalibrated device
/// positions and the references (what Harders' method starts from).
pub fn pose_based_transform(device: &Device, samples: &[Correspondence]) -> Transform {
    estimate_transform(device, &[SensorModel::IDENTITY; 3], samples, EH_SPACING_MM)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::haptic::landmarks::initial_transform;
    use nalgebra::Rotation3;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    /// A device whose joint sensors were initialised badly (offsets of several degrees) and a
    /// tracker with 0.15 mm noise.
    struct Bench {
        device: Device,
        truth: [SensorModel; 3],
        calibration: Vec<Correspondence>,
        verify: Vec<Correspondence>,
        landmarks: [Vector3<f64>; 3],
        noise_floor_mm: f64,
    }

    fn bench(seed: u64) -> Bench {
        let device = Device::omni();
        let truth = [
            SensorModel { j: 0.0, k: 1.02, m: 0.05 },
            SensorModel { j: 0.0, k: 0.97, m: -0.09 },
            SensorModel { j: 0.0, k: 1.03, m: 0.11 },
        ];
        let r = Rotation3::from_euler_angles(0.1, 0.6, -0.2).into_inner();
        let t = Vector3::new(220.0, -80.0, 950.0);
        let sigma = 0.15;
        let noise = Normal::new(0.0, sigma).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut sample = |k: usize| {
            // Smooth, irregular motion through the workspace (true joint angles), raw readings
            // from the inverse of the true sensor model.
            let s = k as f64 * 0.013;
            let theta = [
                0.5 * (0.7 * s).sin() + 0.2 * (1.9 * s).sin(),
                0.45 + 0.35 * (0.5 * s + 1.0).sin(),
                0.3 + 0.4 * (0.83 * s).cos(),
            ];
            let raw: [f64; 3] = std::array::from_fn(|j| (theta[j] - truth[j].m) / truth[j].k);
            let p = device.position_mm(&[theta[0], theta[1], theta[2], 0.0, 0.0, 0.0]);
            let reference_mm = r * p
                + t
                + Vector3::new(noise.sample(&mut rng), noise.sample(&mut rng), noise.sample(&mut rng));
            Correspondence { raw, reference_mm }
        };
        let calibration: Vec<Correspondence> = (0..400).map(|k| sample(k * 7)).collect();
        let verify: Vec<Correspondence> = (0..200).map(|k| sample(k * 11 + 3)).collect();
        let to_tracker = |p: Vector3<f64>| r * p + t;
        // p3: where the device *reports* θ1 = 0 (raw 0): true θ1 is the sensor offset.
        let p3_theta = [truth[0].m, 0.4, 0.5, 0.0, 0.0, 0.0];
        let landmarks = [
            to_tracker(Vector3::new(0.0, device.l2_mm, -device.l1_mm)),
            to_tracker(Vector3::new(0.0, device.l2_mm + 60.0, -device.l1_mm)),
            to_tracker(device.position_mm(&p3_theta)),
        ];
        Bench { device, truth, calibration, verify, landmarks, noise_floor_mm: sigma * 3f64.sqrt() }
    }

    use crate::numerics::stats::rms;

    #[test]
    fn landmark_initialisation_reaches_the_noise_floor_and_beats_the_pose_based_one() {
        for seed in [1, 2] {
            let b = bench(seed);
            let before = rms(&position_errors(
                &b.device,
                &[SensorModel::IDENTITY; 3],
                &pose_based_transform(&b.device, &b.calibration),
                &b.verify,
            ));
            let [p1, p2, p3] = b.landmarks;
            let landmark_eh = initial_transform(&b.device, p1, (p2 - p1).normalize(), p3).unwrap();
            let iterations = 4;
            let with_landmarks = calibrate_position(
                &b.device,
                &b.calibration,
                landmark_eh,
                [SensorModel::IDENTITY; 3],
                iterations,
                None,
            );
            let with_poses = calibrate_position(
                &b.device,
                &b.calibration,
                pose_based_transform(&b.device, &b.calibration),
                [SensorModel::IDENTITY; 3],
                iterations,
                None,
            );
            let after_landmarks = rms(&position_errors(
                &b.device,
                &with_landmarks.joints,
                &with_landmarks.transform,
                &b.verify,
            ));
            let after_poses =
                rms(&position_errors(&b.device, &with_poses.joints, &with_poses.transform, &b.verify));
            eprintln!("seed {seed}: before {before:.3} mm, after (landmarks) {after_landmarks:.3} mm, after (poses) {after_poses:.3} mm, floor {:.3} mm, iterations {:?}", b.noise_floor_mm, with_landmarks.mean_error_mm);
            assert!(before > 5.0 * b.noise_floor_mm, "the bad initialisation must show: {before}");
            assert!(
                after_landmarks <= 1.10 * b.noise_floor_mm,
                "landmark-initialised calibration {after_landmarks} vs floor {}",
                b.noise_floor_mm
            );
            assert!(after_landmarks < after_poses, "landmark-based {after_landmarks} should beat pose-based {after_poses} after {iterations} iterations");
            for j in 0..3 {
                assert!(
                    (with_landmarks.joints[j].m - b.truth[j].m).abs() < 0.01 || j == 0,
                    "joint {} offset {} vs {}",
                    j + 1,
                    with_landmarks.joints[j].m,
                    b.truth[j].m
                );
            }
        }
    }
}
