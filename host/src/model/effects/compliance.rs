//! Joint compliance under gravity: `compliance:j`.
//!
//! Formula: Δθ_j = c_j · λ_j with the unit-weight gravity lever
//! λ_j = Σ_k ((m_k − o_j) × ĝ) · z_j / 1000 (metres), summed over the mass points m_k beyond
//! joint j (the frame origins after joints j…6 and the tool point), o_j and z_j the point and
//! direction of joint j's axis, ĝ = (0, 0, −1). c_j (deg/m) lumps the joint's torsional
//! compliance and the masses of the links beyond it. λ is evaluated on the arm without the
//! deflections themselves and before the length scale (a first-order model: deflections are
//! small).
//!
//! Physical cause: the weight of the links beyond a joint twists its bearing, shaft and
//! transmission in proportion to the gravity torque, so the joint sits slightly further down
//! than its encoder says, by an amount that depends on the pose (zero for a vertical axis).

use nalgebra::Vector3;

/// Direction of gravity in the base frame (the base plate is level).
pub fn gravity() -> Vector3<f64> {
    -Vector3::z()
}

/// Unit-weight gravity lever λ (m) of a joint whose axis passes through `axis_point_mm` along
/// `axis`, carrying unit masses at `masses_mm`.
pub fn gravity_lever_m(axis_point_mm: &Vector3<f64>, axis: &Vector3<f64>, masses_mm: &[Vector3<f64>]) -> f64 {
    masses_mm.iter().map(|m| (m - axis_point_mm).cross(&gravity()).dot(axis)).sum::<f64>() / 1000.0
}
