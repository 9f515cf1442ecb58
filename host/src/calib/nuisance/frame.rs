//! The frame of a block: a rigid motion (R, t) between the robot's base and another frame, the
//! instrument's of a session, or an artefact placement's.
//!
//! Its closed form is Horn's absolute orientation: the rotation and shift that best map one set
//! of points onto another ([`Frame::fit`]). In a calibration a session's frame is an unknown of
//! its own, started at the closed form for the nominal arm and moved by a small rotation ω (mrad,
//! left of the start R⁰) and a shift t (mm): R = exp(ω)·R⁰ (the manifold of a rotation). A change
//! δω turns R by J_l(ω)·δω ([`left_jacobian`]), so the Jacobian is exact at any ω, not only at the
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

/// The left Jacobian of SO(3) at the rotation vector φ (rad): exp(φ + δ) = exp(J_l(φ)·δ)·exp(φ)
/// to first order in δ, J_l(φ) = I + (1 − cos θ)/θ²·\[φ\]× + (θ − sin θ)/θ³·\[φ\]×², θ = ‖φ‖ (the
/// identity at φ = 0). The right Jacobian, exp(φ + δ) = exp(φ)·exp(J_r(φ)·δ), is its transpose.
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta = phi.norm();
    let k = phi.cross_matrix();
    let (a, b) = if theta < 1e-4 {
        // The series, exact to rounding below 1e-4 rad.
        let t2 = theta * theta;
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        ((1.0 - theta.cos()) / (theta * theta), (theta - theta.sin()) / (theta * theta * theta))
    };
    Matrix3::identity() + k * a + k * k * b
}

/// Axis · angle (rad) of a rotation matrix.
pub fn rotation_vector(m: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix(m).scaled_axis()
}
