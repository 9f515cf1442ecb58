//! The landmark-based initial device → tracker transform (paper eqs. 1–6), which does not depend
//! on a good device initialisation.
//!
//! p1 (central joint, pivot point of target T1), ây (the device's y axis, the θ1 axis) and p3
//! (the HIP, in tracker coordinates, at a sample where the device reports θ1 ≈ 0):
//! p3′ = p3 − ((p3 − p1)·ây)·ây; âz = (p3′ − p1)/‖p3′ − p1‖; âx = ây × âz; R = [âx ây âz];
//! T = p1 + l1·âz − l2·ây. A device point p maps to R·p + T.
//!
//! The paper takes ây = (p2 − p1)/‖p2 − p1‖ with p2 the centre of T2's circle, which is right
//! only when T2 sits above the central joint: below it the frame turns by 180°, beside it p2 ≈ p1.
//! Here ây comes from how T2 turns against the θ1 reading ([`turret_axis`]): the turret turns by
//! −θ1 about +y (R = R_y(−θ1)…), so the rotation of T2 between two samples, as a rotation
//! vector, is −Δθ1·ây — whatever T2's position on the turret.

use super::kinematics::Device;
use nalgebra::{Matrix3, Vector3};

/// Why the landmarks do not define a frame.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LandmarkError {
    /// T2 hardly turned.
    #[error("T2 turned with θ1 through {range_deg:.1}° over {samples} samples; swing the turret through at least {MIN_TURRET_DEG}°")]
    TurretStill {
        /// θ1 range, degrees.
        range_deg: f64,
        /// Samples.
        samples: usize,
    },
    /// T2 turned by a different amount than θ1 reports.
    #[error("T2 turned {0:.2} times as far as the θ1 reading says: T2 is not fixed to the turret, or θ1 is not in radians")]
    TurretScale(f64),
    /// p3 lies (nearly) on the y axis.
    #[error("landmark p3 is {0:.2} mm from the device's y axis; take it with the stylus out in front of the device")]
    NoZAxis(f64),
}

/// Smallest θ1 range T2 must turn through, degrees.
pub const MIN_TURRET_DEG: f64 = 20.0;

/// The device's y axis in tracker coordinates from T2's orientations `rotations` (T2 → tracker)
/// and the θ1 readings at the same times (radians, the model's sign): least squares of
/// ω_i = −(θ1_i − θ1_ref)·ây over the samples, ω_i the rotation vector of R_i·R_refᵀ, the
/// reference being the sample with the median reading. The fitted vector's length is the
/// ratio of T2's turn to the reading's: far from 1 means the θ1 reading is not in radians or T2
/// is not on the turret.
pub fn turret_axis(rotations: &[Matrix3<f64>], theta1: &[f64]) -> Result<Vector3<f64>, LandmarkError> {
    let n = rotations.len().min(theta1.len());
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| theta1[a].total_cmp(&theta1[b]));
    let range = if n > 0 { theta1[order[n - 1]] - theta1[order[0]] } else { 0.0 };
    if n < 10 || range.to_degrees() < MIN_TURRET_DEG {
        return Err(LandmarkError::TurretStill { range_deg: range.to_degrees(), samples: n });
    }
    let reference = order[n / 2];
    let (mut sum, mut weight) = (Vector3::zeros(), 0.0);
    for i in 0..n {
        let d = theta1[i] - theta1[reference];
        let w = nalgebra::Rotation3::from_matrix_unchecked(rotations[i] * rotations[reference].transpose())
            .scaled_axis();
        sum -= w * d;
        weight += d * d;
    }
    let axis = sum / weight;
    if !(0.8..1.25).contains(&axis.norm()) {
        return Err(LandmarkError::TurretScale(axis.norm()));
    }
    Ok(axis.normalize())
}

/// Device → tracker transform from the landmarks: p1, the unit y axis `ay` and p3 (tracker
/// coordinates, mm).
pub fn initial_transform(
    device: &Device,
    p1: Vector3<f64>,
    ay: Vector3<f64>,
    p3: Vector3<f64>,
) -> Result<(Matrix3<f64>, Vector3<f64>), LandmarkError> {
    let p3p = p3 - ay * (p3 - p1).dot(&ay);
    let z = p3p - p1;
    if z.norm() < 1.0 {
        return Err(LandmarkError::NoZAxis(z.norm()));
    }
    let az = z.normalize();
    let ax = ay.cross(&az);
    let r = Matrix3::from_columns(&[ax, ay, az]);
    Ok((r, p1 + az * device.l1_mm - ay * device.l2_mm))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    #[test]
    fn recovers_the_transform_from_exact_landmarks() {
        let device = Device::omni();
        let r = Rotation3::from_euler_angles(0.2, -0.4, 1.1).into_inner();
        let t = Vector3::new(300.0, -50.0, 800.0);
        let to_tracker = |p: Vector3<f64>| r * p + t;
        // Central joint at (0, l2, −l1) in device coordinates; a point further up the y axis;
        // the HIP at θ1 = 0 (x = 0) out in front.
        let p1 = to_tracker(Vector3::new(0.0, device.l2_mm, -device.l1_mm));
        let p3 = to_tracker(device.position_mm(&[0.0, 0.3, 0.5, 0.0, 0.0, 0.0]));
        // T2 turns with the turret: R_y(−θ1) in device coordinates, wherever it is mounted.
        let theta1: Vec<f64> = (0..40).map(|k| 0.6 * (k as f64 * 0.3).sin()).collect();
        let mount = Rotation3::from_euler_angles(0.3, 1.1, -0.4).into_inner();
        let turret: Vec<Matrix3<f64>> = theta1
            .iter()
            .map(|a| r * Rotation3::from_axis_angle(&Vector3::y_axis(), -a).into_inner() * mount)
            .collect();
        let ay = turret_axis(&turret, &theta1).unwrap();
        assert!((ay - r * Vector3::y()).norm() < 1e-9, "{ay}");
        let (rf, tf) = initial_transform(&device, p1, ay, p3).unwrap();
        assert!((rf - r).norm() < 1e-9 && (tf - t).norm() < 1e-9, "{rf} {tf}");
        let doubled: Vec<f64> = theta1.iter().map(|a| a * 0.5).collect();
        assert!(matches!(turret_axis(&turret, &doubled), Err(LandmarkError::TurretScale(_))));
        assert!(matches!(turret_axis(&turret[..5], &theta1[..5]), Err(LandmarkError::TurretStill { .. })));
        assert!(matches!(initial_transform(&device, p1, ay, p1 + ay * 30.0), Err(LandmarkError::NoZAxis(_))));
    }
}
