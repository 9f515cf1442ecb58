//! Lateral compliance (bending) under the gravity moment across the joint's axis: `bend:j`.
//!
//! Formula: after its rotation θ_j, joint j's frame turns by the rotation vector
//! β_j = b_j · M⊥_j / 1000 (degrees), with b_j in deg/(kN·m) and M⊥_j = M_j − τ_j·a_j (N·m, in
//! the joint's frame) the part of the gravity moment M_j of the masses beyond the joint (see
//! [`super::sag`]) perpendicular to the axis a_j. The turn is about M⊥_j's own direction, so
//! ∂(turn)/∂b_j is a rotation about that direction of |M⊥_j| / 1000 degrees per unit (first
//! order in the moments, as for `sag:j`).
//!
//! Physical cause: the moment a joint does not transmit as torque loads its bearings and the
//! link structure across the axis; the bearing's play and stiffness and the link's bending let
//! the frame tilt about the moment's direction (not about the axis, which the joint's own spring,
//! `sag:j`, covers). On a humanoid's torso it is the whole upper body leaning on the lower joints.

/// The bend turn's axis (a unit vector in the joint's frame) and ∂|turn|/∂b_j (degrees per
/// deg/(kN·m)) under a lateral moment `lateral_nm` (N·m); `None` when there is none.
pub fn direction_and_partial(lateral_nm: &nalgebra::Vector3<f64>) -> Option<(nalgebra::Vector3<f64>, f64)> {
    let size = lateral_nm.norm();
    (size > 0.0).then(|| (lateral_nm / size, size / 1000.0))
}
