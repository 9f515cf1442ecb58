//! Geometric effects: the terms of the DH chain itself.
//!
//! * `offset:j` — θ_j = φ_j + δθ_j. Cause: encoders mounted at an arbitrary zero.
//! * `length:j` — d_j, translation along z_{j−1}. Cause: machining and assembly of link lengths.
//! * `link_offset:j` — a_j, translation along x_j. Cause: consecutive axes that do not intersect.
//! * `twist:j` — α_j, rotation about x_j. Cause: consecutive axes not at their nominal angle.
//! * `axis:j` — β_j, rotation about y_j (Hayati). Cause: near-parallel consecutive axes, where a
//!   small tilt cannot be expressed by DH parameters without a huge d.
//! * `tcp` — (x, y, z) of the tool point in the last frame. Cause: stylus bent or seated off axis.
//! * `scale` — p ← (1 + s·10⁻⁶)·p. Cause: thermal expansion of the arm, or an artefact certified
//!   at another temperature (distances alone cannot tell the two apart).
//!
//! The link matrix is Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β) (classic) or Rx(α)·Ry(β)·Tx(a)·Rz(θ)·Tz(d)
//! (modified, Craig); see [`crate::model::kinematics`].
