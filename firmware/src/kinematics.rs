//! The calibrated tool pose on the controller, in f32, with every effect the host model holds.
//!
//! Same definitions as the host (`kincal::model::kinematics`, `kincal::effects`):
//! θ_j = φ_j + δθ_j + a·sin φ + b·cos φ + a₂·sin 2φ + b₂·cos 2φ + c·λ_j, link Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)
//! (classic) or Rx(α)·Ry(β)·Tx(a)·Rz(θ)·Tz(d) (modified), tool point, length scale. λ_j is the
//! unit-weight gravity lever on the undeflected, unscaled arm.
//!
//! Cost on a Cortex-M4F (single-precision FPU only): everything that depends only on the
//! parameters — the constant rotations Rx(α)·Ry(β), lengths, tool point — is computed once in
//! [`Kinematics::new`]. Per pose, joint angles are fixed-point integers (one turn = 2³² units,
//! 2¹⁰ units per encoder count), reduced to their quadrant exactly, and sine and cosine come
//! from f32 polynomials; the chain is f32. No f64 arithmetic runs per pose.

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

/// Fixed-point angle units per turn.
const UNITS_PER_TURN: f64 = 4_294_967_296.0;
/// Fixed-point units per encoder count.
const UNITS_PER_COUNT_SHIFT: u32 = 32 - 22;

/// An angle in degrees as fixed-point units.
fn units_from_deg(deg: f64) -> i64 {
    libm::round(deg * (UNITS_PER_TURN / 360.0)) as i64
}

/// sin and cos of a fixed-point angle: exact reduction to |r| ≤ 45° in integers, then f32
/// polynomials (Taylor to r¹¹ / r¹⁰, error below 2·10⁻⁹ before f32 rounding).
pub fn sincos_units(angle: i64) -> (f32, f32) {
    let q = (angle + (1 << 29)) >> 30; // nearest quarter turn
    let r = (angle - (q << 30)) as f32 * (core::f32::consts::TAU / 4_294_967_296.0);
    let r2 = r * r;
    let s =
        r * (1.0 + r2 * (-1.0 / 6.0 + r2 * (1.0 / 120.0 + r2 * (-1.0 / 5040.0 + r2 * (1.0 / 362_880.0)))));
    let c = 1.0
        + r2 * (-0.5
            + r2 * (1.0 / 24.0 + r2 * (-1.0 / 720.0 + r2 * (1.0 / 40_320.0 + r2 * (-1.0 / 3_628_800.0)))));
    match q & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

fn mul(a: &M3, b: &M3) -> M3 {
    core::array::from_fn(|i| {
        core::array::from_fn(|j| a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j])
    })
}

/// A rigid frame: rotation and origin.
#[derive(Clone, Copy)]
struct Frame {
    r: M3,
    p: V3,
}

impl Frame {
    fn translate(&mut self, local: V3) {
        for i in 0..3 {
            self.p[i] += self.r[i][0] * local[0] + self.r[i][1] * local[1] + self.r[i][2] * local[2];
        }
    }

    /// self ← self · Rz(θ), from sin and cos.
    fn rotate_z(&mut self, (s, c): (f32, f32)) {
        for row in self.r.iter_mut() {
            let (x, y) = (row[0], row[1]);
            row[0] = c * x + s * y;
            row[1] = -s * x + c * y;
        }
    }
}

/// Precomputed device kinematics of one parameter set.
#[derive(Clone, Debug)]
pub struct Kinematics {
    modified: bool,
    offset_units: [i64; JOINTS],
    /// Harmonic amplitudes in fixed-point units (sin φ, cos φ, sin 2φ, cos 2φ).
    harmonics: [[f32; 4]; JOINTS],
    /// Compliance in fixed-point units per mm of lever.
    compliance_units_per_mm: [f32; JOINTS],
    fixed: [M3; JOINTS],
    d_mm: [f32; JOINTS],
    a_mm: [f32; JOINTS],
    tcp_mm: V3,
    scale: f32,
}

fn rotation_x_then_y(alpha_deg: f64, beta_deg: f64) -> M3 {
    let (sa, ca) = (libm::sin(alpha_deg.to_radians()), libm::cos(alpha_deg.to_radians()));
    let (sb, cb) = (libm::sin(beta_deg.to_radians()), libm::cos(beta_deg.to_radians()));
    let rx = [[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]];
    let ry = [[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]];
    let m: [[f64; 3]; 3] = core::array::from_fn(|i| {
        core::array::from_fn(|j| rx[i][0] * ry[0][j] + rx[i][1] * ry[1][j] + rx[i][2] * ry[2][j])
    });
    m.map(|row| row.map(|v| v as f32))
}

impl Kinematics {
    /// Precompute what depends only on `params` (runs once per parameter upload).
    pub fn new(params: &ArmParams) -> Kinematics {
        let j = &params.joints;
        Kinematics {
            modified: params.modified_dh,
            offset_units: j.map(|r| units_from_deg(r.offset_deg)),
            harmonics: j.map(|r| {
                [r.eccentricity_deg[0], r.eccentricity_deg[1], r.eccentricity2_deg[0], r.eccentricity2_deg[1]]
                    .map(|a| (a * UNITS_PER_TURN / 360.0) as f32)
            }),
            compliance_units_per_mm: j
                .map(|r| (r.compliance_deg_per_m / 1000.0 * UNITS_PER_TURN / 360.0) as f32),
            fixed: j.map(|r| rotation_x_then_y(r.alpha_deg, r.axis_deg)),
            d_mm: j.map(|r| r.d_mm as f32),
            a_mm: j.map(|r| r.a_mm as f32),
            tcp_mm: params.tcp_mm.map(|v| v as f32),
            scale: (1.0 + params.scale_ppm * 1e-6) as f32,
        }
    }

    /// Joint angles (fixed-point units) before compliance; the harmonics are small terms
    /// evaluated in f32.
    fn rigid_angles(&self, counts: &[u32; JOINTS]) -> [i64; JOINTS] {
        core::array::from_fn(|j| {
            let phi = (counts[j] as i64) << UNITS_PER_COUNT_SHIFT;
            let h = &self.harmonics[j];
            let ecc = if *h == [0.0; 4] {
                0
            } else {
                let (s1, c1) = sincos_units(phi);
                let (s2, c2) = (2.0 * s1 * c1, c1 * c1 - s1 * s1);
                (h[0] * s1 + h[1] * c1 + h[2] * s2 + h[3] * c2) as i64
            };
            phi + self.offset_units[j] + ecc
        })
    }

    /// Walk the chain; returns the tool frame, each joint's axis frame and each row's end frame.
    fn chain(&self, theta: &[i64; JOINTS]) -> (Frame, [Frame; JOINTS], [Frame; JOINTS]) {
        let mut f = Frame { r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], p: [0.0; 3] };
        let mut axes = [f; JOINTS];
        let mut rows = [f; JOINTS];
        for j in 0..JOINTS {
            let sc = sincos_units(theta[j]);
            if self.modified {
                f.r = mul(&f.r, &self.fixed[j]);
                f.translate([self.a_mm[j], 0.0, 0.0]);
                axes[j] = f;
                f.rotate_z(sc);
                f.translate([0.0, 0.0, self.d_mm[j]]);
            } else {
                axes[j] = f;
                f.rotate_z(sc);
                f.translate([self.a_mm[j], 0.0, self.d_mm[j]]);
                f.r = mul(&f.r, &self.fixed[j]);
            }
            rows[j] = f;
        }
        f.translate(self.tcp_mm);
        (f, axes, rows)
    }

    /// Tool pose for raw encoder positions `counts`.
    pub fn tool_pose(&self, counts: &[u32; JOINTS]) -> Pose {
        let mut theta = self.rigid_angles(counts);
        if self.compliance_units_per_mm.iter().any(|c| *c != 0.0) {
            let (tool, axes, rows) = self.chain(&theta);
            for j in 0..JOINTS {
                let (o, z) = (axes[j].p, [axes[j].r[0][2], axes[j].r[1][2], axes[j].r[2][2]]);
                // Σ ((m − o) × ĝ)·z with ĝ = −z_base: (m − o) × (0,0,−1) = (−dy, dx, 0).
                let lever_mm: f32 = rows[j..]
                    .iter()
                    .map(|f| f.p)
                    .chain([tool.p])
                    .map(|m| -(m[1] - o[1]) * z[0] + (m[0] - o[0]) * z[1])
                    .sum();
                theta[j] += (self.compliance_units_per_mm[j] * lever_mm) as i64;
            }
        }
        let (tool, _, _) = self.chain(&theta);
        Pose {
            position_mm: tool.p.map(|v| v * self.scale),
            x_axis: [tool.r[0][0], tool.r[1][0], tool.r[2][0]],
            z_axis: [tool.r[0][2], tool.r[1][2], tool.r[2][2]],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sincos_matches_the_library_everywhere() {
        let mut worst: f64 = 0.0;
        for k in -200_000..=200_000 {
            let deg = k as f64 * 0.0037 + 0.001;
            let (s, c) = sincos_units(units_from_deg(deg));
            let r = deg.to_radians();
            worst = worst.max((s as f64 - r.sin()).abs()).max((c as f64 - r.cos()).abs());
        }
        assert!(worst < 2e-7, "{worst}");
    }
}
