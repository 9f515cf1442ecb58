//! The calibrated tool pose on the controller, in f32, with every effect the host model holds.
//!
//! Same definitions as the host (`kincal::model::kinematics`, `kincal::effects`): θ_j = φ_j + δθ_j
//! + a·sin φ + b·cos φ + a₂·sin 2φ + b₂·cos 2φ + c·λ_j, link Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)
//! (classic) or Rx(α)·Ry(β)·Tx(a)·Rz(θ)·Tz(d) (modified), tool point, length scale. λ_j is the
//! unit-weight gravity lever on the undeflected, unscaled arm. The joint angle is formed and
//! reduced to ±180° in f64 (a handful of operations) so the f32 trigonometry starts from a
//! small, exact argument; the chain is f32.

use kincal_protocol::biss::COUNTS_PER_TURN;
use kincal_protocol::messages::JOINTS;
use kincal_protocol::params::ArmParams;

type V3 = [f32; 3];
type M3 = [[f32; 3]; 3];

/// Tool pose: position (mm) and the tool's x and z axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Tool point, mm.
    pub position_mm: V3,
    /// Tool x axis.
    pub x_axis: V3,
    /// Tool z axis.
    pub z_axis: V3,
}

fn mul(a: &M3, b: &M3) -> M3 {
    core::array::from_fn(|i| core::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j]))
}

fn apply(a: &M3, v: &V3) -> V3 {
    core::array::from_fn(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

fn rot(axis: usize, angle_rad: f32) -> M3 {
    let (s, c) = (libm::sinf(angle_rad), libm::cosf(angle_rad));
    match axis {
        0 => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
        1 => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
        _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
    }
}

/// Angle in degrees (f64) reduced to (−180°, 180°] and converted to f32 radians.
fn reduced_rad(deg: f64) -> f32 {
    let r = deg - 360.0 * libm::round(deg / 360.0);
    (r * core::f64::consts::PI / 180.0) as f32
}

/// A rigid frame: rotation and origin.
#[derive(Clone, Copy)]
struct Frame {
    r: M3,
    p: V3,
}

impl Frame {
    fn translate(&mut self, local: V3) {
        let d = apply(&self.r, &local);
        for k in 0..3 {
            self.p[k] += d[k];
        }
    }
    fn rotate(&mut self, axis: usize, angle_rad: f32) {
        self.r = mul(&self.r, &rot(axis, angle_rad));
    }
}

/// Walk the chain for joint angles `theta_deg`; returns the tool frame, each joint's axis frame
/// (before its rotation) and the frame after each joint row.
fn chain(params: &ArmParams, theta_deg: &[f64; JOINTS]) -> (Frame, [Frame; JOINTS], [Frame; JOINTS]) {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut f = Frame { r: identity, p: [0.0; 3] };
    let mut axes = [f; JOINTS];
    let mut rows = [f; JOINTS];
    for (j, row) in params.joints.iter().enumerate() {
        let theta = reduced_rad(theta_deg[j]);
        let (alpha, beta) = (reduced_rad(row.alpha_deg), reduced_rad(row.axis_deg));
        if params.modified_dh {
            f.rotate(0, alpha);
            f.rotate(1, beta);
            f.translate([row.a_mm as f32, 0.0, 0.0]);
            axes[j] = f;
            f.rotate(2, theta);
            f.translate([0.0, 0.0, row.d_mm as f32]);
        } else {
            axes[j] = f;
            f.rotate(2, theta);
            f.translate([0.0, 0.0, row.d_mm as f32]);
            f.translate([row.a_mm as f32, 0.0, 0.0]);
            f.rotate(0, alpha);
            f.rotate(1, beta);
        }
        rows[j] = f;
    }
    f.translate([params.tcp_mm[0] as f32, params.tcp_mm[1] as f32, params.tcp_mm[2] as f32]);
    (f, axes, rows)
}

/// Joint angles (degrees, f64) before compliance.
fn rigid_angles(params: &ArmParams, counts: &[u32; JOINTS]) -> [f64; JOINTS] {
    core::array::from_fn(|j| {
        let row = &params.joints[j];
        let phi = counts[j] as f64 * (360.0 / COUNTS_PER_TURN as f64);
        let p = phi.to_radians();
        let ecc = row.eccentricity_deg[0] * libm::sin(p) + row.eccentricity_deg[1] * libm::cos(p) + row.eccentricity2_deg[0] * libm::sin(2.0 * p) + row.eccentricity2_deg[1] * libm::cos(2.0 * p);
        phi + row.offset_deg + ecc
    })
}

/// Tool pose for raw encoder positions `counts`.
pub fn tool_pose(params: &ArmParams, counts: &[u32; JOINTS]) -> Pose {
    let mut theta = rigid_angles(params, counts);
    if params.joints.iter().any(|j| j.compliance_deg_per_m != 0.0) {
        let (tool, axes, rows) = chain(params, &theta);
        for j in 0..JOINTS {
            let (o, z) = (axes[j].p, [axes[j].r[0][2], axes[j].r[1][2], axes[j].r[2][2]]);
            // Σ ((m − o) × ĝ)·z with ĝ = −z_base: (m − o) × (0,0,−1) = (−dy, dx, 0).
            let lever_mm: f32 = rows[j..].iter().map(|f| f.p).chain([tool.p]).map(|m| -(m[1] - o[1]) * z[0] + (m[0] - o[0]) * z[1]).sum();
            theta[j] += params.joints[j].compliance_deg_per_m * lever_mm as f64 / 1000.0;
        }
    }
    let (tool, _, _) = chain(params, &theta);
    let s = (1.0 + params.scale_ppm * 1e-6) as f32;
    Pose {
        position_mm: tool.p.map(|v| v * s),
        x_axis: [tool.r[0][0], tool.r[1][0], tool.r[2][0]],
        z_axis: [tool.r[0][2], tool.r[1][2], tool.r[2][2]],
    }
}
