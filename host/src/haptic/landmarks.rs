//! The landmark-based initial device → tracker transform (paper eqs. 1–6), which does not depend
//! on a good device initialisation.
//!
//! p1 (central joint, pivot point of target T1), p2 (a point on the device's y axis through p1,
//! centre of T2 circling that axis) and p3 (the HIP, in tracker coordinates, at a sample where the
//! device reports θ1 ≈ 0):
//! ây = (p2 − p1)/‖p2 − p1‖; p3′ = p3 − ((p3 − p1)·ây)·ây; âz = (p3′ − p1)/‖p3′ − p1‖;
//! âx = ây × âz; R = [âx ây âz]; T = p1 + l1·âz − l2·ây. A device point p maps to R·p + T.

use super::kinematics::Device;
use nalgebra::{Matrix3, Vector3};

/// Why the landmarks do not define a frame.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LandmarkError {
    /// p1 and p2 (nearly) coincide.
    #[error("landmarks p1 and p2 are {0:.2} mm apart; they must lie apart along the device's y axis")]
    NoYAxis(f64),
    /// p3 lies (nearly) on the y axis.
    #[error("landmark p3 is {0:.2} mm from the device's y axis; take it with the stylus out in front of the device")]
    NoZAxis(f64),
}

/// Device → tracker transform from the three landmarks (tracker coordinates, mm).
pub fn initial_transform(
    device: &Device,
    p1: Vector3<f64>,
    p2: Vector3<f64>,
    p3: Vector3<f64>,
) -> Result<(Matrix3<f64>, Vector3<f64>), LandmarkError> {
    let y = p2 - p1;
    if y.norm() < 1.0 {
        return Err(LandmarkError::NoYAxis(y.norm()));
    }
    let ay = y.normalize();
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
        let p2 = to_tracker(Vector3::new(0.0, device.l2_mm + 60.0, -device.l1_mm));
        let p3 = to_tracker(device.position_mm(&[0.0, 0.3, 0.5, 0.0, 0.0, 0.0]));
        let (rf, tf) = initial_transform(&device, p1, p2, p3).unwrap();
        assert!((rf - r).norm() < 1e-9 && (tf - t).norm() < 1e-9, "{rf} {tf}");
        assert!(matches!(initial_transform(&device, p1, p1, p3), Err(LandmarkError::NoYAxis(_))));
        assert!(matches!(initial_transform(&device, p1, p2, p2), Err(LandmarkError::NoZAxis(_))));
    }
}
