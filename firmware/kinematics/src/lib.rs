//! The calibrated tool pose on the controller, in f32, with every effect the host model holds.
//!
//! Same definitions as the host (`kincal::model::kinematics`, `kincal::effects`):
//! θ_j = φ_j + δθ_j + a·sin φ + b·cos φ + a₂·sin 2φ + b₂·cos 2φ + c·λ_j, link Rz(θ)·Tz(d)·Tx(a)·Rx(α)·Ry(β)
//! (classic) or Rx(α)·Ry(β)·Tx(a)·Rz(θ)·Tz(d) (modified), tool point, length scale. λ_j is the
//! unit-weight gravity lever on the undeflected, unscaled arm.
//!
//! Its own crate so that the firmware can build it at `opt-level = 3` and everything else for
//! size (see `firmware/Cargo.toml`).
//!
//! Cost on a Cortex-M4F (single-precision FPU only): everything that depends only on the
//! parameters — sines and cosines of α and β, lengths, tool point — is computed once in
//! [`Kinematics::new`]. Per pose, joint angles are wrapping `u32` fixed-point (one turn = 2³²
//! units, 2¹⁰ units per encoder count), reduced to their quadrant exactly, and sine and cosine
//! come from f32 polynomials; the chain is f32. No f64 or 64-bit integer arithmetic runs per pose
//! (both are library calls on this core). Gravity compliance needs the undeflected chain for its
//! levers, so it walks the chain twice; the levers come from running sums in one pass.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

use kincal_protocol::joints::JOINTS;
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

/// Fixed-point angle units per turn: one turn is 2³² units, so wrapping `u32` arithmetic is
/// arithmetic modulo 360° and every conversion to and from f32 is a single FPU instruction.
const UNITS_PER_TURN: f64 = 4_294_967_296.0;
/// Fixed-point units per encoder count (22-bit encoders).
const UNITS_PER_COUNT_SHIFT: u32 = 32 - 22;
/// Radians per fixed-point unit.
const RAD_PER_UNIT: f32 = core::f32::consts::TAU / 4_294_967_296.0;

/// An angle in degrees as fixed-point units (modulo one turn).
fn units_from_deg(deg: f64) -> u32 {
    libm::round(deg * (UNITS_PER_TURN / 360.0)) as i64 as u32
}

/// A small signed angle in fixed-point units, from f32 (saturating; the envelope keeps every
/// correction far below half a turn).
fn units_from_small(units: f32) -> u32 {
    units as i32 as u32
}

/// sin and cos of a fixed-point angle: exact reduction to |r| ≤ 45° in integers, then the
/// Cephes single-precision minimax polynomials (sin to r⁷, cos to r⁸; about one f32 ulp).
pub fn sincos_units(angle: u32) -> (f32, f32) {
    let quarter = angle.wrapping_add(1 << 29) >> 30; // nearest quarter turn, 0…3
    let r = angle.wrapping_sub(quarter << 30) as i32 as f32 * RAD_PER_UNIT;
    let r2 = r * r;
    let s = r + r * r2 * (-1.666_665_5e-1 + r2 * (8.332_161e-3 + r2 * -1.951_529_6e-4));
    let c = 1.0 - 0.5 * r2 + r2 * r2 * (4.166_664_6e-2 + r2 * (-1.388_731_6e-3 + r2 * 2.443_315_7e-5));
    match quarter {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// A rigid frame: rotation and origin.
#[derive(Clone, Copy)]
struct Frame {
    r: M3,
    p: V3,
}

impl Frame {
    const IDENTITY: Frame = Frame { r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], p: [0.0; 3] };

    // Written out element by element: the firmware is built for size, and the compiler then
    // leaves loops and `array::from_fn` rolled (about three times the instructions here).

    /// self.p ← self.p + self.r · local.
    #[inline(always)]
    fn translate(&mut self, [x, y, z]: V3) {
        let r = &self.r;
        self.p[0] += r[0][0] * x + r[0][1] * y + r[0][2] * z;
        self.p[1] += r[1][0] * x + r[1][1] * y + r[1][2] * z;
        self.p[2] += r[2][0] * x + r[2][1] * y + r[2][2] * z;
    }

    /// self ← self · Rz(θ), from sin and cos.
    #[inline(always)]
    fn rotate_z(&mut self, (s, c): (f32, f32)) {
        let r = &mut self.r;
        let [x0, x1, x2] = [r[0][0], r[1][0], r[2][0]];
        let [y0, y1, y2] = [r[0][1], r[1][1], r[2][1]];
        r[0][0] = c * x0 + s * y0;
        r[1][0] = c * x1 + s * y1;
        r[2][0] = c * x2 + s * y2;
        r[0][1] = c * y0 - s * x0;
        r[1][1] = c * y1 - s * x1;
        r[2][1] = c * y2 - s * x2;
    }

    /// self ← self · Rx(α), from sin and cos.
    #[inline(always)]
    fn rotate_x(&mut self, (s, c): (f32, f32)) {
        let r = &mut self.r;
        let [y0, y1, y2] = [r[0][1], r[1][1], r[2][1]];
        let [z0, z1, z2] = [r[0][2], r[1][2], r[2][2]];
        r[0][1] = c * y0 + s * z0;
        r[1][1] = c * y1 + s * z1;
        r[2][1] = c * y2 + s * z2;
        r[0][2] = c * z0 - s * y0;
        r[1][2] = c * z1 - s * y1;
        r[2][2] = c * z2 - s * y2;
    }

    /// self ← self · Ry(β), from sin and cos.
    #[inline(always)]
    fn rotate_y(&mut self, (s, c): (f32, f32)) {
        let r = &mut self.r;
        let [x0, x1, x2] = [r[0][0], r[1][0], r[2][0]];
        let [z0, z1, z2] = [r[0][2], r[1][2], r[2][2]];
        r[0][0] = c * x0 - s * z0;
        r[1][0] = c * x1 - s * z1;
        r[2][0] = c * x2 - s * z2;
        r[0][2] = c * z0 + s * x0;
        r[1][2] = c * z1 + s * x1;
        r[2][2] = c * z2 + s * x2;
    }

    /// self ← self · Rx(α) · Ry(β) of joint row `j`; Ry only where β ≠ 0.
    #[inline(always)]
    fn rotate_twist_and_tilt(&mut self, k: &Kinematics, j: usize) {
        self.rotate_x(k.twist[j]);
        if let Some(tilt) = k.tilt[j] {
            self.rotate_y(tilt);
        }
    }

    fn z_axis(&self) -> V3 {
        [self.r[0][2], self.r[1][2], self.r[2][2]]
    }
}

/// What the gravity lever needs of one joint on the undeflected arm: where its axis passes,
/// which way it points, and the origin of the frame at the end of its row.
#[derive(Clone, Copy, Default)]
struct JointPlace {
    axis_origin_mm: V3,
    axis: V3,
    row_end_mm: V3,
}

/// Precomputed device kinematics of one parameter set.
#[derive(Clone, Debug)]
pub struct Kinematics {
    modified: bool,
    offset_units: [u32; JOINTS],
    /// Harmonic amplitudes in fixed-point units (sin φ, cos φ, sin 2φ, cos 2φ).
    harmonics: [[f32; 4]; JOINTS],
    /// Compliance in fixed-point units per mm of lever.
    compliance_units_per_mm: [f32; JOINTS],
    /// sin and cos of each row's twist α.
    twist: [(f32, f32); JOINTS],
    /// sin and cos of each row's Hayati tilt β, where not zero.
    tilt: [Option<(f32, f32)>; JOINTS],
    d_mm: [f32; JOINTS],
    a_mm: [f32; JOINTS],
    tcp_mm: V3,
    scale: f32,
}

/// sin and cos of an angle in degrees, in f64: exact reduction to |r| ≤ 45° in degrees, then
/// Taylor series to r¹⁷ / r¹⁸ (error below 10⁻¹⁸). Runs once per parameter upload; libm's
/// general sin/cos would bring 5 KiB of argument reduction the controller never needs.
fn sincos_deg(deg: f64) -> (f64, f64) {
    let quarter = libm::round(deg / 90.0);
    let r = (deg - quarter * 90.0).to_radians();
    let r2 = r * r;
    let (mut s, mut c, mut term_s, mut term_c) = (r, 1.0, r, 1.0);
    for k in 1..=9 {
        let k = k as f64;
        term_s *= -r2 / ((2.0 * k) * (2.0 * k + 1.0));
        term_c *= -r2 / ((2.0 * k - 1.0) * (2.0 * k));
        s += term_s;
        c += term_c;
    }
    match (quarter as i64).rem_euclid(4) {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// sin and cos of an angle in degrees, in f32.
fn sincos_f32(deg: f64) -> (f32, f32) {
    let (s, c) = sincos_deg(deg);
    (s as f32, c as f32)
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
            twist: j.map(|r| sincos_f32(r.alpha_deg)),
            tilt: j.map(|r| (r.axis_deg != 0.0).then(|| sincos_f32(r.axis_deg))),
            d_mm: j.map(|r| r.d_mm as f32),
            a_mm: j.map(|r| r.a_mm as f32),
            tcp_mm: params.tcp_mm.map(|v| v as f32),
            scale: (1.0 + params.scale_ppm * 1e-6) as f32,
        }
    }

    /// Joint angles (fixed-point units) before compliance; the harmonics are small terms
    /// evaluated in f32.
    fn rigid_angles(&self, counts: &[u32; JOINTS]) -> [u32; JOINTS] {
        core::array::from_fn(|j| {
            let phi = counts[j] << UNITS_PER_COUNT_SHIFT;
            let h = &self.harmonics[j];
            let ecc = if *h == [0.0; 4] {
                0
            } else {
                let (s1, c1) = sincos_units(phi);
                let (s2, c2) = (2.0 * s1 * c1, c1 * c1 - s1 * s1);
                units_from_small(h[0] * s1 + h[1] * c1 + h[2] * s2 + h[3] * c2)
            };
            phi.wrapping_add(self.offset_units[j]).wrapping_add(ecc)
        })
    }

    /// Walk the chain to the tool frame; `visit(j, axis frame, row end frame)` sees each joint.
    #[inline(always)]
    fn chain(&self, theta: &[u32; JOINTS], mut visit: impl FnMut(usize, &Frame, &Frame)) -> Frame {
        let mut f = Frame::IDENTITY;
        for (j, &angle) in theta.iter().enumerate() {
            let sc = sincos_units(angle);
            let axis;
            if self.modified {
                f.rotate_twist_and_tilt(self, j);
                f.translate([self.a_mm[j], 0.0, 0.0]);
                axis = f;
                f.rotate_z(sc);
                f.translate([0.0, 0.0, self.d_mm[j]]);
            } else {
                axis = f;
                f.rotate_z(sc);
                f.translate([self.a_mm[j], 0.0, self.d_mm[j]]);
                f.rotate_twist_and_tilt(self, j);
            }
            visit(j, &axis, &f);
        }
        f.translate(self.tcp_mm);
        f
    }

    /// Gravity deflection of each joint, fixed-point units: c_j·λ_j with the unit-weight lever
    /// λ_j = Σ_m ((m − o_j) × ĝ)·z_j over the row ends m after joint j and the tool point, ĝ = −z_base.
    /// With ĝ = (0, 0, −1) the sum is z_y·Σ(m_x − o_x) − z_x·Σ(m_y − o_y), so one pass from the
    /// tool back keeps running sums.
    fn deflections(&self, places: &[JointPlace; JOINTS], tool_mm: V3) -> [u32; JOINTS] {
        let mut deflection = [0u32; JOINTS];
        let (mut sum_x, mut sum_y, mut count) = (tool_mm[0], tool_mm[1], 1.0f32);
        for j in (0..JOINTS).rev() {
            let place = &places[j];
            sum_x += place.row_end_mm[0];
            sum_y += place.row_end_mm[1];
            count += 1.0;
            let [ox, oy, _] = place.axis_origin_mm;
            let lever_mm = place.axis[1] * (sum_x - count * ox) - place.axis[0] * (sum_y - count * oy);
            deflection[j] = units_from_small(self.compliance_units_per_mm[j] * lever_mm);
        }
        deflection
    }

    /// Tool pose for raw encoder positions `counts`.
    pub fn tool_pose(&self, counts: &[u32; JOINTS]) -> Pose {
        let mut theta = self.rigid_angles(counts);
        if self.compliance_units_per_mm.iter().any(|c| *c != 0.0) {
            let mut places = [JointPlace::default(); JOINTS];
            let rigid_tool = self.chain(&theta, |j, axis, row_end| {
                places[j] = JointPlace { axis_origin_mm: axis.p, axis: axis.z_axis(), row_end_mm: row_end.p };
            });
            for (angle, deflection) in theta.iter_mut().zip(self.deflections(&places, rigid_tool.p)) {
                *angle = angle.wrapping_add(deflection);
            }
        }
        let tool = self.chain(&theta, |_, _, _| {});
        Pose {
            position_mm: tool.p.map(|v| v * self.scale),
            x_axis: [tool.r[0][0], tool.r[1][0], tool.r[2][0]],
            z_axis: tool.z_axis(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degree_sincos_matches_the_library() {
        for k in -20_000..=20_000 {
            let deg = k as f64 * 0.0371 + 0.0005;
            let (s, c) = sincos_deg(deg);
            let r = deg.to_radians();
            // The reference rounds the angle to radians first: a few ulps of 13 rad.
            assert!((s - r.sin()).abs() < 5e-15 && (c - r.cos()).abs() < 5e-15, "{deg}°");
        }
    }

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
