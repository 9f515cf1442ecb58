//! The R factor of a tall matrix by Householder reflections (what LAPACK's `dgeqrf` computes,
//! unblocked): column-major, each reflection applied to a later column as one dot product (in four
//! partial sums) and one update over contiguous memory, which the compiler vectorises. Q is not
//! formed.

use nalgebra::DMatrix;

/// The R factor of `a` (m × w): min(m, w) × w, upper triangular, with RᵀR = aᵀa (the row signs
/// of R are those of the reflections; any sign makes the same column geometry).
pub fn r_factor(mut a: DMatrix<f64>) -> DMatrix<f64> {
    let (m, w) = a.shape();
    let k = m.min(w);
    let data = a.as_mut_slice();
    for j in 0..k {
        let (done, rest) = data.split_at_mut((j + 1) * m);
        let v = &mut done[j * m + j..];
        let norm = dot(v, v).sqrt();
        if norm == 0.0 {
            continue;
        }
        // v = x − α·e₁ with α of the sign opposite to x₀ (no cancellation); H = I − 2vvᵀ/vᵀv.
        let alpha = if v[0] > 0.0 { -norm } else { norm };
        v[0] -= alpha;
        let scale = 2.0 / dot(v, v);
        for column in rest.chunks_exact_mut(m) {
            let c = &mut column[j..];
            let d = scale * dot(v, c);
            for (ci, vi) in c.iter_mut().zip(v.iter()) {
                *ci -= d * vi;
            }
        }
        v[0] = alpha;
    }
    DMatrix::from_fn(k, w, |i, j| if i <= j { data[j * m + i] } else { 0.0 })
}

/// Σ a_i·b_i in four interleaved partial sums (independent additions the processor overlaps).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut s = [0.0; 4];
    let (a4, b4) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = a4.remainder().iter().zip(b4.remainder()).map(|(x, y)| x * y).sum();
    for (x, y) in a4.zip(b4) {
        for k in 0..4 {
            s[k] += x[k] * y[k];
        }
    }
    (s[0] + s[1]) + (s[2] + s[3]) + tail
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_factor_has_the_columns_geometry_and_is_upper_triangular() {
        for (m, w) in [(40, 7), (7, 7), (4, 9), (1, 3)] {
            let a =
                DMatrix::from_fn(m, w, |i, j| ((i * 7 + j * 13) as f64 * 0.61).sin() + (i == j) as u8 as f64);
            let r = r_factor(a.clone());
            assert_eq!(r.shape(), (m.min(w), w));
            let (rtr, ata) = (r.transpose() * &r, a.transpose() * &a);
            assert!((&rtr - &ata).norm() <= 1e-12 * ata.norm(), "{m} × {w}");
            for i in 0..r.nrows() {
                for j in 0..i {
                    assert_eq!(r[(i, j)], 0.0);
                }
            }
            // The same as nalgebra's factor, row by row up to the sign.
            let reference = a.qr().r();
            for i in 0..r.nrows() {
                let sign = if r[(i, i)] * reference[(i, i)] < 0.0 { -1.0 } else { 1.0 };
                assert!((r.row(i) * sign - reference.row(i)).norm() <= 1e-12 * (1.0 + reference.norm()));
            }
        }
    }
}
