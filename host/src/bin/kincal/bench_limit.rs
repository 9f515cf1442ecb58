//! The limit estimate of `kincal bench --peers`: the floating-point work one Gauss–Newton
//! iteration of a benchmark problem cannot avoid, at this core's measured rates.
//!
//! Work of one iteration, in flops, for a touch of J joints and n free parameters:
//! * the touch's frames, from the base out: per joint its rotation about z from the encoder
//!   angle's sine and cosine (data, computed once per solve) and the offset's by angle
//!   addition (6), that rotation applied to the frame so far (18), the joint's fixed rotation
//!   (a 3 × 3 product, 45) and its shift (9); the tool point (15); one Jacobian column per
//!   parameter, a cross product and a difference (12);
//! * the touch's point alone at the trial step, carried from the tool back to the base: per
//!   joint the angle addition, the fixed rotation, the shift and the rotation about z
//!   (6 + 15 + 2 + 6);
//! * residual rows: an artefact pair (difference, length, direction: 13, again at the trial
//!   point; its Jacobian row, 8n); a tracker point (its base's rotation and shift: 18, again at
//!   the trial point; the arm's columns rotated, 15n; the base's three rotation columns, 45);
//! * normal equations JᵀJ (upper triangle) and Jᵀr over each row's k nonzero columns:
//!   k(k + 1) + 2k per row;
//! * the Cholesky factor of the N × N normal matrix, N³/3, and its two triangular solves, 2N².
//!
//! Rates, one core: the kinematics at the measured rate of a kernel doing the frames' work
//! (angle additions, 3 × 3 products and shifts, independent across touches), the linear algebra
//! at the measured rate of a dense 256 × 256 matrix product (nalgebra). The estimate is that
//! sum; the bound runs all the work at the product's rate. Not counted: memory traffic, the
//! solver's bookkeeping, rejected steps' extra trial points, sines and cosines (none remain).

use nalgebra::{DMatrix, Matrix3, Vector3};
use std::time::{Duration, Instant};

/// Measured rates of this core, flops per second of CPU time.
#[derive(Clone, Copy, Debug)]
pub struct Rates {
    /// A dense 256 × 256 matrix product.
    pub product: f64,
    /// The kinematics kernel.
    pub kinematics: f64,
}

/// The work of one Gauss–Newton iteration, flops.
#[derive(Clone, Copy, Debug)]
pub struct Work {
    /// Kinematics and residual rows with their Jacobians.
    pub kinematics: f64,
    /// Normal equations and the Cholesky solve.
    pub linear_algebra: f64,
}

impl Work {
    /// Both parts, flops.
    pub fn total(&self) -> f64 {
        self.kinematics + self.linear_algebra
    }

    /// Time of `iterations` iterations, ms: (bound, estimate).
    pub fn ms(&self, rates: &Rates, iterations: usize) -> (f64, f64) {
        let it = iterations as f64 * 1e3;
        let bound = self.total() / rates.product * it;
        let estimate = (self.kinematics / rates.kinematics + self.linear_algebra / rates.product) * it;
        (bound, estimate)
    }
}

/// Flops of one touch's frames, tool point and Jacobian columns, and of its point alone at the
/// trial step.
fn touch(joints: usize, params: usize) -> f64 {
    let j = joints as f64;
    j * (6.0 + 18.0 + 45.0 + 9.0) + 15.0 + 12.0 * params as f64 + j * (6.0 + 15.0 + 2.0 + 6.0)
}

/// Normal equations over `rows` rows of `k` nonzero columns each, and the Cholesky solve of
/// `unknowns`.
fn linear_algebra(rows: f64, k: usize, unknowns: usize) -> f64 {
    let (k, n) = (k as f64, unknowns as f64);
    rows * (k * (k + 1.0) + 2.0 * k) + n * n * n / 3.0 + 2.0 * n * n
}

/// One iteration of the artefact problem: `touches` touches, `rows` pair distances.
pub fn artefact(touches: usize, joints: usize, params: usize, rows: usize) -> Work {
    let n = params as f64;
    Work {
        kinematics: touches as f64 * touch(joints, params) + rows as f64 * (13.0 + 8.0 * n + 13.0),
        linear_algebra: linear_algebra(rows as f64, params, params),
    }
}

/// One iteration of the tracker problem: `points` points in `sessions` sessions, each row
/// reading the arm's `params` and its session's six base unknowns.
pub fn tracker(points: usize, joints: usize, params: usize, sessions: usize) -> Work {
    let n = params as f64;
    Work {
        kinematics: points as f64 * (touch(joints, params) + 18.0 + 15.0 * n + 45.0 + 18.0),
        linear_algebra: linear_algebra(3.0 * points as f64, params + 6, params + 6 * sessions),
    }
}

/// Repeat `kernel` (doing `flops` each) for at least `at_least`; flops per second of CPU time.
fn rate(flops: f64, at_least: Duration, mut kernel: impl FnMut()) -> f64 {
    kernel();
    let (start, cpu) = (Instant::now(), crate::cpu_time::process_cpu_ms());
    let mut runs = 0;
    while start.elapsed() < at_least {
        kernel();
        runs += 1;
    }
    flops * runs as f64 / ((crate::cpu_time::process_cpu_ms() - cpu) * 1e-3)
}

/// Measure this core's rates (about half a second, on this thread; the process's other threads
/// must be idle, as its CPU time is read).
pub fn measure() -> Rates {
    const N: usize = 256;
    let a = DMatrix::<f64>::from_fn(N, N, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
    let b = DMatrix::<f64>::from_fn(N, N, |i, j| ((i * 5 + j) % 13) as f64 - 6.0);
    let product = rate(2.0 * (N * N * N) as f64, Duration::from_millis(250), || {
        std::hint::black_box(&a * &b);
    });
    // The frames of 1024 touches of 6 joints: angle addition, the rotation about z applied to
    // the frame, the fixed rotation, the shift (6 + 45 + 45 + 18 flops as written here).
    const TOUCHES: usize = 1024;
    const JOINTS: usize = 6;
    const KERNEL_PER_JOINT: f64 = 6.0 + 45.0 + 45.0 + 18.0;
    let fixed: Vec<Matrix3<f64>> = (0..JOINTS)
        .map(|j| nalgebra::Rotation3::from_euler_angles(0.3 * j as f64, -0.2, 0.1).into_inner())
        .collect();
    let shifts: Vec<Vector3<f64>> = (0..JOINTS).map(|j| Vector3::new(10.0 * j as f64, 0.0, 50.0)).collect();
    let offsets: Vec<(f64, f64)> = (0..JOINTS).map(|j| (0.01 * j as f64).sin_cos()).collect();
    let encoders: Vec<(f64, f64)> =
        (0..TOUCHES * JOINTS).map(|k| ((k % 360) as f64 * 0.0174).sin_cos()).collect();
    let mut points = vec![Vector3::zeros(); TOUCHES];
    let kinematics = rate((TOUCHES * JOINTS) as f64 * KERNEL_PER_JOINT, Duration::from_millis(250), || {
        for (p, angles) in points.iter_mut().zip(encoders.chunks_exact(JOINTS)) {
            let (mut r, mut o) = (Matrix3::identity(), Vector3::zeros());
            for j in 0..JOINTS {
                let ((s0, c0), (sd, cd)) = (std::hint::black_box(angles[j]), offsets[j]);
                let (s, c) = (s0 * cd + c0 * sd, c0 * cd - s0 * sd);
                r *= Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
                o += r * shifts[j];
                r *= fixed[j];
            }
            *p = o;
        }
        std::hint::black_box(&points);
    });
    Rates { product, kinematics }
}
