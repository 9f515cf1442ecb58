//! Joint compliance under the gravity torque of the masses beyond the joint: `sag:j`.
//!
//! Formula: θ_j = φ_j + δθ_j + s_j · τ_j / 1000 (degrees), with s_j in deg/(kN·m) and
//! τ_j = a_j · M_j (N·m) the torque about joint j's axis a_j of M_j = Σ_b (c_b − o_j) × m_b·g, the
//! moment about the joint's origin o_j of the weight of every body b beyond the joint (every
//! link of every branch it carries, from the model's mass table, see [`crate::model::tree`]),
//! g = (0, 0, −9.81) m/s². The moments are those of the deflected robot (the fixed point of
//! [`crate::model::tree::loads`]); the Jacobian leaves out their own change with the
//! parameters (first order: ∂θ_j/∂s_j = τ_j / 1000).
//!
//! Physical cause: the weight of the links beyond a joint — an arm's own links, the other arm
//! and the head on a humanoid's torso — twists the joint's gear train and shaft in proportion to
//! the torque it carries, so the link sits further down than its encoder says. Unlike
//! `compliance:j` (a unit mass at the tool point), the torque is the real one of the robot's
//! mass distribution at every pose, which a tool-point lever cannot follow.

/// ∂θ_j/∂s_j, degrees per deg/(kN·m), under a gravity torque of `torque_nm` N·m.
pub fn partial(torque_nm: f64) -> f64 {
    torque_nm / 1000.0
}
