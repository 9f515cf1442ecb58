//! Geometry helpers shared by the arm and the haptic calibration.

use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};

/// Absolute orientation, Horn's closed form (unit quaternions, 1987): the rotation R and
/// translation t minimising Σ‖R·a_i + t − b_i‖². The optimal rotation is the eigenvector of the
/// largest eigenvalue of a symmetric 4×4 matrix built from the cross-covariance of the centred
/// point sets.
pub fn absolute_orientation(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> (Matrix3<f64>, Vector3<f64>) {
    let n = a.len().min(b.len()).max(1) as f64;
    let (ca, cb) = (a.iter().sum::<Vector3<f64>>() / n, b.iter().sum::<Vector3<f64>>() / n);
    let s: Matrix3<f64> = a.iter().zip(b).map(|(p, q)| (p - ca) * (q - cb).transpose()).sum();
    let (sxx, sxy, sxz, syx, syy, syz, szx, szy, szz) =
        (s[(0, 0)], s[(0, 1)], s[(0, 2)], s[(1, 0)], s[(1, 1)], s[(1, 2)], s[(2, 0)], s[(2, 1)], s[(2, 2)]);
    #[rustfmt::skip]
    let k = Matrix4::new(
        sxx + syy + szz, syz - szy,        szx - sxz,        sxy - syx,
        syz - szy,       sxx - syy - szz,  sxy + syx,        szx + sxz,
        szx - sxz,       sxy + syx,        -sxx + syy - szz, syz + szy,
        sxy - syx,       szx + sxz,        syz + szy,        -sxx - syy + szz,
    );
    let eig = k.symmetric_eigen();
    let best = eig.eigenvalues.iter().enumerate().max_by(|x, y| x.1.total_cmp(y.1)).map_or(0, |m| m.0);
    let v = eig.eigenvectors.column(best);
    let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(v[0], v[1], v[2], v[3]));
    let r: Rotation3<f64> = q.into();
    let r = r.into_inner();
    (r, cb - r * ca)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_rotation_and_shift() {
        let a: Vec<Vector3<f64>> = vec![
            Vector3::new(0., 0., 0.),
            Vector3::new(10., 0., 0.),
            Vector3::new(0., 20., 0.),
            Vector3::new(0., 0., 5.),
            Vector3::new(3., -4., 7.),
        ];
        for (roll, pitch, yaw) in [(0.1, -0.2, 0.3), (3.0, 0.1, -2.5), (0.0, 0.0, 0.0)] {
            let r = Rotation3::from_euler_angles(roll, pitch, yaw).into_inner();
            let t = Vector3::new(500.0, 10.0, -3.0);
            let b: Vec<Vector3<f64>> = a.iter().map(|v| r * v + t).collect();
            let (rf, tf) = absolute_orientation(&a, &b);
            assert!((rf - r).norm() < 1e-9 && (tf - t).norm() < 1e-9, "{rf} {tf}");
        }
    }
}
