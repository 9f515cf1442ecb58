//! Pivot (tooltip) calibration, Tuceryan et al.: a tool with a tracked target pivots about a
//! fixed point. For every pose (R_i, t_i) of the target, R_i·p_tip + t_i = p_pivot, linear in the
//! tip offset p_tip (target frame) and the pivot point p_pivot (tracker frame):
//! [R_i  −I]·[p_tip; p_pivot] = −t_i, solved in the least-squares sense over all poses.

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// Smallest spread of orientations (largest angle between two poses) accepted, degrees.
pub const MIN_ROTATION_DEG: f64 = 15.0;

/// Why a pivot calibration failed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum PivotError {
    /// Too few poses.
    #[error("pivot calibration needs at least 10 poses, got {0}")]
    TooFewPoses(usize),
    /// The tool hardly rotated: the tip offset is not determined.
    #[error("the tool rotated by at most {spread_deg:.1}° during pivoting; tilt it through at least {MIN_ROTATION_DEG}° in two directions")]
    TooLittleRotation {
        /// Largest angle between two poses, degrees.
        spread_deg: f64,
    },
}

/// Result of a pivot calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pivot {
    /// Tip offset in the target frame, mm.
    pub tip_mm: Vector3<f64>,
    /// Pivot point in the tracker frame, mm.
    pub pivot_mm: Vector3<f64>,
    /// RMS of |R_i·p_tip + t_i − p_pivot|, mm.
    pub rms_mm: f64,
}

fn angle_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let c = (((a.transpose() * b).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    c.acos().to_degrees()
}

/// Calibrate from target poses (rotation, translation in mm).
pub fn pivot_calibration(poses: &[(Matrix3<f64>, Vector3<f64>)]) -> Result<Pivot, PivotError> {
    if poses.len() < 10 {
        return Err(PivotError::TooFewPoses(poses.len()));
    }
    // Spread: the largest angle from the first pose, then from that pose (two passes suffice).
    let far = poses
        .iter()
        .max_by(|a, b| angle_deg(&poses[0].0, &a.0).total_cmp(&angle_deg(&poses[0].0, &b.0)))
        .map_or(poses[0].0, |p| p.0);
    let spread_deg = poses.iter().map(|p| angle_deg(&far, &p.0)).fold(0.0, f64::max);
    if spread_deg < MIN_ROTATION_DEG {
        return Err(PivotError::TooLittleRotation { spread_deg });
    }
    let n = poses.len();
    let mut a = DMatrix::zeros(3 * n, 6);
    let mut b = DVector::zeros(3 * n);
    for (i, (r, t)) in poses.iter().enumerate() {
        for row in 0..3 {
            for col in 0..3 {
                a[(3 * i + row, col)] = r[(row, col)];
            }
            a[(3 * i + row, 3 + row)] = -1.0;
            b[3 * i + row] = -t[row];
        }
    }
    let x = a.clone().svd(true, true).solve(&b, 1e-12).unwrap_or_else(|_| DVector::zeros(6));
    let tip_mm = Vector3::new(x[0], x[1], x[2]);
    let pivot_mm = Vector3::new(x[3], x[4], x[5]);
    let rms_mm = (poses.iter().map(|(r, t)| (r * tip_mm + t - pivot_mm).norm_squared()).sum::<f64>()
        / n as f64)
        .sqrt();
    Ok(Pivot { tip_mm, pivot_mm, rms_mm })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn poses(tilt_deg: f64, noise_mm: f64) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
        let tip = Vector3::new(3.0, -120.0, 8.0);
        let pivot = Vector3::new(250.0, 40.0, 900.0);
        (0..60)
            .map(|k| {
                let a = k as f64 * 0.37;
                let r = Rotation3::from_euler_angles(
                    tilt_deg.to_radians() * a.sin(),
                    tilt_deg.to_radians() * (1.7 * a).cos(),
                    0.8 * a,
                )
                .into_inner();
                let wobble = Vector3::new(
                    (k * 13 % 7) as f64 - 3.0,
                    (k * 5 % 11) as f64 - 5.0,
                    (k * 3 % 5) as f64 - 2.0,
                ) * (noise_mm / 5.0);
                (r, pivot - r * tip + wobble)
            })
            .collect()
    }

    #[test]
    fn recovers_tip_and_pivot() {
        let p = pivot_calibration(&poses(30.0, 0.0)).unwrap();
        assert!((p.tip_mm - Vector3::new(3.0, -120.0, 8.0)).norm() < 1e-6, "{:?}", p.tip_mm);
        assert!((p.pivot_mm - Vector3::new(250.0, 40.0, 900.0)).norm() < 1e-6);
        assert!(p.rms_mm < 1e-6);
        let noisy = pivot_calibration(&poses(30.0, 0.3)).unwrap();
        assert!((noisy.tip_mm - Vector3::new(3.0, -120.0, 8.0)).norm() < 1.0 && noisy.rms_mm > 0.05);
    }

    #[test]
    fn too_little_rotation_is_refused() {
        let little: Vec<_> = poses(30.0, 0.0).into_iter().map(|(_, t)| (Matrix3::identity(), t)).collect();
        assert!(matches!(pivot_calibration(&little), Err(PivotError::TooLittleRotation { .. })));
        assert!(matches!(pivot_calibration(&poses(30.0, 0.0)[..5]), Err(PivotError::TooFewPoses(5))));
    }
}
