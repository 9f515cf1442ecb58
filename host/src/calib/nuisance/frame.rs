//! The frame of a block: a rigid motion (R, t) between the robot's base and another frame, the
//! instrument's of a session, or an artefact placement's.
//!
//! Its closed form is Horn's absolute orientation: the rotation and shift that best map one set
//! of points onto another ([`Frame::fit`]). In a calibration a session's frame is an unknown of
//! its own, started at the closed form for the nominal arm and moved by a small rotation ω (mrad,
//! left of the start R⁰) and a shift t (mm): R = exp(ω)·R⁰ (the manifold of a rotation). A change
//! δω turns R by J_l(ω)·δω ([`left_jacobian`](crate::numerics::geometry::left_jacobian)), so the Jacobian is exact at any ω, not only at the
//! start.

use crate::numerics::geometry::absolute_orientation;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// Unknowns of one frame: a rotation (mrad) and a shift (mm).
pub const FRAME_UNKNOWNS: usize = 6;

/// A rigid motion: x ↦ R·x + t.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// Rotation.
    pub rotation: Matrix3<f64>,
    /// Translation, mm.
    pub translation_mm: Vector3<f64>,
}

impl Frame {
    /// The identity.
    pub fn identity() -> Frame {
        Frame { rotation: Matrix3::identity(), translation_mm: Vector3::zeros() }
    }

    /// The frame that best maps `from` onto `to` in the least-squares sense (Horn's closed form).
    pub fn fit(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Frame {
        let (rotation, translation_mm) = absolute_orientation(from, to);
        Frame { rotation, translation_mm }
    }

    /// What is left of `to` once `from` is fitted onto it: to_i − frame(from_i), mm, with the
    /// frame of [`Frame::fit`].
    pub fn residuals(from: &[Vector3<f64>], to: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
        let frame = Frame::fit(from, to);
        from.iter().zip(to).map(|(f, t)| t - frame.apply(f)).collect()
    }

    /// R·p + t.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation_mm
    }

    /// The frame at the unknowns `x` (ω in mrad, t in mm) from the start rotation `start`.
    pub fn at(start: &Matrix3<f64>, x: &[f64]) -> Frame {
        let omega = Vector3::new(x[0], x[1], x[2]) * 1e-3;
        Frame {
            rotation: Rotation3::new(omega).into_inner() * start,
            translation_mm: Vector3::new(x[3], x[4], x[5]),
        }
    }
}

/// Axis · angle (rad) of a rotation matrix.
pub fn rotation_vector(m: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix(m).scaled_axis()
}
