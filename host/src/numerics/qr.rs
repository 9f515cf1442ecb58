//! The R factor of a tall matrix by Householder reflections, blocked as LAPACK's `dgeqrf` is: a
//! panel of 8 columns is reflected column by column, its reflections gathered as
//! I − V·T·Vᵀ (the compact WY form, LAPACK's `dlarft`), and the columns right of the panel are
//! updated by two matrix products (`dlarfb`), which matrixmultiply runs with the vector
//! instructions it finds on the processor at run time. Q is not formed. The same reflections as
//! the unblocked algorithm, so the same backward stability; only the summation order differs.

use nalgebra::{DMatrix, DMatrixView};

/// Columns reflected one by one before the columns right of them are updated by one product
/// (on the tracker's groups of about 30 columns, 6 and 10 took 25 % more instructions than 8,
/// the height of matrixmultiply's kernel).
const PANEL: usize = 8;

/// The R factor of `a` (m × w): min(m, w) × w, upper triangular, with RᵀR = aᵀa (the row signs
/// of R are those of the reflections; any sign makes the same column geometry).
pub fn r_factor(mut a: DMatrix<f64>) -> DMatrix<f64> {
    let (m, w) = a.shape();
    let k = m.min(w);
    let mut panel = Panel::default();
    for start in (0..k).step_by(PANEL) {
        let width = PANEL.min(k - start);
        panel.reflect(&mut a, start, width);
        if start + width < w {
            panel.update(&mut a, start, width);
        }
    }
    DMatrix::from_fn(k, w, |i, j| if i <= j { a[(i, j)] } else { 0.0 })
}

/// The R factor of two R factors stacked, `top` over `bottom` (both upper trapezoidal, w
/// columns). When `top` is square (w × w), the same reflections as [`r_factor`] of the stacked
/// rows, each over the entries that are not zero (row j of `top` and the first j + 1 rows of
/// `bottom`): ≈ ⅔·w³ operations instead of ≈ 3·w³; otherwise [`r_factor`] of the stacked rows.
pub fn r_factor_of_stacked(mut top: DMatrix<f64>, mut bottom: DMatrix<f64>) -> DMatrix<f64> {
    let (w, q) = (top.ncols(), bottom.nrows());
    debug_assert_eq!(bottom.ncols(), w);
    // The fold reads only the upper trapezoids: anything below them would be silently ignored.
    let upper = |m: &DMatrix<f64>| (0..m.ncols()).all(|j| (j + 1..m.nrows()).all(|i| m[(i, j)] == 0.0));
    debug_assert!(upper(&top) && upper(&bottom), "r_factor_of_stacked takes two R factors");
    if top.nrows() != w {
        let mut stacked = DMatrix::zeros(top.nrows() + q, w);
        stacked.rows_mut(0, top.nrows()).copy_from(&top);
        stacked.rows_mut(top.nrows(), q).copy_from(&bottom);
        return r_factor(stacked);
    }
    if q == 0 {
        return top;
    }
    for j in 0..w {
        let len = q.min(j + 1);
        let x0 = top[(j, j)];
        let (done, rest) = bottom.as_mut_slice().split_at_mut((j + 1) * q);
        let v = &mut done[j * q..j * q + len];
        let below = dot(v, v);
        let norm = (x0 * x0 + below).sqrt();
        if norm == 0.0 {
            continue;
        }
        let alpha = if x0 > 0.0 { -norm } else { norm };
        let v0 = x0 - alpha;
        let scale = 2.0 / (v0 * v0 + below);
        for (c, column) in (j + 1..w).zip(rest.chunks_exact_mut(q)) {
            let d = scale * (v0 * top[(j, c)] + dot(v, &column[..len]));
            top[(j, c)] -= d * v0;
            for (ci, vi) in column[..len].iter_mut().zip(v.iter()) {
                *ci -= d * vi;
            }
        }
        top[(j, j)] = alpha;
        v.fill(0.0);
    }
    top
}

/// One panel's reflections: V (their vectors, column-major, from the panel's first row down,
/// zero above each one's start), Vᵀ row by row, T, and the buffers of the update.
#[derive(Default)]
struct Panel {
    v: DMatrix<f64>,
    vt: DMatrix<f64>,
    tau: Vec<f64>,
    t: DMatrix<f64>,
    w: DMatrix<f64>,
}

impl Panel {
    /// Reflect columns `start..start + width` of `a` (rows from `start` down), leaving R's part
    /// in place and the reflections' vectors and factors 2/vᵀv in `self`.
    fn reflect(&mut self, a: &mut DMatrix<f64>, start: usize, width: usize) {
        let m = a.nrows();
        let rows = m - start;
        self.v = DMatrix::zeros(rows, width);
        self.tau.clear();
        let data = a.as_mut_slice();
        for i in 0..width {
            let j = start + i;
            let (done, rest) = data.split_at_mut((j + 1) * m);
            let v = &mut done[j * m + j..];
            let norm = dot(v, v).sqrt();
            if norm == 0.0 {
                self.tau.push(0.0);
                continue;
            }
            // v = x − α·e₁ with α of the sign opposite to x₀ (no cancellation); H = I − 2vvᵀ/vᵀv.
            let alpha = if v[0] > 0.0 { -norm } else { norm };
            v[0] -= alpha;
            let scale = 2.0 / dot(v, v);
            for column in rest.chunks_exact_mut(m).take(width - i - 1) {
                let c = &mut column[j..];
                let d = scale * dot(v, c);
                for (ci, vi) in c.iter_mut().zip(v.iter()) {
                    *ci -= d * vi;
                }
            }
            self.v.column_mut(i).as_mut_slice()[i..].copy_from_slice(v);
            self.tau.push(scale);
            v[0] = alpha;
        }
    }

    /// Apply the panel's reflections to the columns right of it: C − V·(Tᵀ·(Vᵀ·C)), with
    /// H₁⋯H_b = I − V·T·Vᵀ.
    fn update(&mut self, a: &mut DMatrix<f64>, start: usize, width: usize) {
        let (m, w) = a.shape();
        let (rows, right) = (m - start, w - start - width);
        self.vt = self.v.transpose();
        // T (upper triangular) column by column: T[..i, i] = −τᵢ·T[..i, ..i]·(V[:, ..i]ᵀ·vᵢ).
        let mut gram = DMatrix::zeros(width, width);
        gram.gemm(1.0, &self.vt, &self.v, 0.0);
        self.t = DMatrix::zeros(width, width);
        for i in 0..width {
            self.t[(i, i)] = self.tau[i];
            for l in 0..i {
                let s: f64 = (l..i).map(|p| self.t[(l, p)] * gram[(p, i)]).sum();
                self.t[(l, i)] = -self.tau[i] * s;
            }
        }
        // Unit row strides in every view (nalgebra's product for small sizes reads past the end
        // of views with another row stride).
        let c: DMatrixView<f64> = a.view((start, start + width), (rows, right));
        if self.w.shape() != (width, right) {
            self.w = DMatrix::zeros(width, right);
        }
        self.w.gemm(1.0, &self.vt, &c, 0.0);
        // W ← Tᵀ·W, from the last row up (row i reads rows l ≤ i).
        for col in 0..right {
            for i in (0..width).rev() {
                self.w[(i, col)] = (0..=i).map(|l| self.t[(l, i)] * self.w[(l, col)]).sum();
            }
        }
        a.view_mut((start, start + width), (rows, right)).gemm(-1.0, &self.v, &self.w, 1.0);
    }
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

    fn sample(m: usize, w: usize, seed: usize) -> DMatrix<f64> {
        DMatrix::from_fn(m, w, |i, j| {
            ((i * 7 + j * 13 + seed * 5) as f64 * 0.61).sin() + (i == j) as u8 as f64
        })
    }

    /// `r` is an upper triangular factor of `a`'s columns (RᵀR = AᵀA).
    fn assert_geometry_of(r: &DMatrix<f64>, a: &DMatrix<f64>) {
        let (m, w) = a.shape();
        assert_eq!(r.shape(), (m.min(w), w));
        let (rtr, ata) = (r.transpose() * r, a.transpose() * a);
        assert!((&rtr - &ata).norm() <= 1e-12 * ata.norm(), "{m} × {w}");
        for i in 0..r.nrows() {
            for j in 0..i {
                assert_eq!(r[(i, j)], 0.0);
            }
        }
    }

    /// `r` is an upper triangular factor of `a`'s columns, equal to nalgebra's up to row signs
    /// (`a` of full rank: its factor is unique up to them).
    fn assert_factor_of(r: &DMatrix<f64>, a: &DMatrix<f64>) {
        assert_geometry_of(r, a);
        let reference = a.clone().qr().r();
        for i in 0..r.nrows() {
            let sign = if r[(i, i)] * reference[(i, i)] < 0.0 { -1.0 } else { 1.0 };
            assert!(
                (r.row(i) * sign - reference.row(i)).norm() <= 1e-12 * (1.0 + reference.norm()),
                "{:?}, row {i}",
                a.shape()
            );
        }
    }

    #[test]
    fn the_factor_has_the_columns_geometry_and_is_upper_triangular() {
        // Narrower than a panel, whole panels and a partial last one, wider than tall, and
        // columns that are zero or repeated (reflections that do nothing).
        for (m, w) in [(40, 7), (7, 7), (4, 9), (1, 3), (300, 34), (34, 34), (20, 34), (9, 17)] {
            let a = sample(m, w, 0);
            assert_factor_of(&r_factor(a.clone()), &a);
        }
        let mut a = sample(60, 20, 1);
        a.column_mut(3).fill(0.0);
        let repeated = a.column(5).into_owned();
        a.column_mut(11).copy_from(&repeated);
        let r = r_factor(a.clone());
        assert_geometry_of(&r, &a);
        assert!(r[(11, 11)].abs() <= 1e-12 * r.norm());
    }

    #[test]
    fn two_stacked_factors_fold_into_the_factor_of_their_rows() {
        // Square tops (the folded form) and a top with fewer rows than columns (stacked whole).
        for (m1, m2, w) in [(50, 40, 12), (34, 300, 34), (40, 5, 9), (9, 9, 9), (5, 20, 9), (3, 2, 9)] {
            let (a, b) = (sample(m1, w, 2), sample(m2, w, 3));
            let folded = r_factor_of_stacked(r_factor(a.clone()), r_factor(b.clone()));
            let mut stacked = DMatrix::zeros(m1 + m2, w);
            stacked.rows_mut(0, m1).copy_from(&a);
            stacked.rows_mut(m1, m2).copy_from(&b);
            assert_factor_of(&folded, &stacked);
        }
    }
}
