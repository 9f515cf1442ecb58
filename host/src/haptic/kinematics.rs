//! PHANToM forward kinematics (as in Ubitrack's haptic calibration, checked in shared/notes):
//!
//! x = c_x − (l1·cos θ2 + l2·sin θ3)·sin θ1
//! y = c_y + l1·sin θ2 − l2·cos θ3 + l2
//! z = c_z − l1 + (l1·cos θ2 + l2·sin θ3)·cos θ1
//! R = R_y(−θ1)·R_x(−θ3)·R_y(θ4)·R_x(−θ5)·R_z(−θ6) (θ2 does not appear); stylus axis = 3rd column.
//!
//! Joint angles come from the sensor readings through a per-joint model: linear θ = k·raw + m,
//! or quadratic θ = j·raw² + k·raw + m. Both link lengths are used as given (the reference
//! implementation silently set l2 = l1).

use nalgebra::{Matrix3, Rotation3, Vector3};

/// Link lengths and origin offset of a device, mm.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Device {
    /// First link, mm.
    pub l1_mm: f64,
    /// Second link, mm.
    pub l2_mm: f64,
    /// Origin offset c, mm.
    pub origin_mm: [f64; 3],
}

impl Device {
    /// PHANToM Omni: l1 = l2 = 133.35 mm.
    pub fn omni() -> Device {
        Device { l1_mm: 133.35, l2_mm: 133.35, origin_mm: [0.0; 3] }
    }

    /// PHANToM Premium 1.5: l1 = l2 ≈ 209.55 mm.
    pub fn premium15() -> Device {
        Device { l1_mm: 209.55, l2_mm: 209.55, origin_mm: [0.0; 3] }
    }

    /// Haptic interaction point for joint angles θ1…θ3 (radians), mm.
    pub fn position_mm(&self, theta: &[f64; 6]) -> Vector3<f64> {
        let (l1, l2, c) = (self.l1_mm, self.l2_mm, self.origin_mm);
        let reach = l1 * theta[1].cos() + l2 * theta[2].sin();
        Vector3::new(
            c[0] - reach * theta[0].sin(),
            c[1] + l1 * theta[1].sin() - l2 * theta[2].cos() + l2,
            c[2] - l1 + reach * theta[0].cos(),
        )
    }

    /// Stylus orientation for joint angles θ1…θ6 (radians).
    pub fn rotation(&self, theta: &[f64; 6]) -> Matrix3<f64> {
        let ry = |a: f64| Rotation3::from_axis_angle(&Vector3::y_axis(), a);
        let rx = |a: f64| Rotation3::from_axis_angle(&Vector3::x_axis(), a);
        let rz = |a: f64| Rotation3::from_axis_angle(&Vector3::z_axis(), a);
        (ry(-theta[0]) * rx(-theta[2]) * ry(theta[3]) * rx(-theta[4]) * rz(-theta[5])).into_inner()
    }
}

/// Sensor model of one joint: θ = j·raw² + k·raw + m (radians; j = 0 for the linear model).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SensorModel {
    /// Quadratic term.
    pub j: f64,
    /// Gain.
    pub k: f64,
    /// Offset, radians.
    pub m: f64,
}

impl SensorModel {
    /// θ = raw.
    pub const IDENTITY: SensorModel = SensorModel { j: 0.0, k: 1.0, m: 0.0 };

    /// Joint angle for a raw reading.
    pub fn angle(&self, raw: f64) -> f64 {
        (self.j * raw + self.k) * raw + self.m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reset_pose_and_axes() {
        let d = Device { l1_mm: 133.35, l2_mm: 140.0, origin_mm: [1.0, 2.0, 3.0] };
        // θ = 0: the arm folded to its reset pose at the origin offset.
        assert!((d.position_mm(&[0.0; 6]) - Vector3::new(1.0, 2.0, 3.0)).norm() < 1e-12);
        // θ2 lifts the first link: y grows by l1·sin θ2.
        let p = d.position_mm(&[0.0, 0.3, 0.0, 0.0, 0.0, 0.0]);
        assert!((p.y - (2.0 + 133.35 * 0.3f64.sin())).abs() < 1e-12);
        // θ1 turns the arm about y: the distance from the vertical axis through c is kept.
        let a = d.position_mm(&[0.0, 0.2, 0.4, 0.0, 0.0, 0.0]);
        let b = d.position_mm(&[0.7, 0.2, 0.4, 0.0, 0.0, 0.0]);
        let r = |p: Vector3<f64>| ((p.x - 1.0).powi(2) + (p.z - 3.0 + 133.35).powi(2)).sqrt();
        assert!((r(a) - r(b)).abs() < 1e-9);
        assert!((d.rotation(&[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]).determinant() - 1.0).abs() < 1e-12);
        assert_eq!(SensorModel { j: 0.1, k: 2.0, m: -0.5 }.angle(2.0), 0.1 * 4.0 + 4.0 - 0.5);
    }
}
