//! The R factor of a tall matrix by Householder reflections, blocked as LAPACK's `dgeqrf` is: a
//! panel of 8 columns is reflected column by column, its reflections gathered as
//! I − V·T·Vᵀ (the compact WY form, LAPACK's `dlarft`), and the columns right of the panel are
//! updated by two matrix products (`dlarfb`: [VᵀV | VᵀC] in one, then C − V·W), which
//! matrixmultiply runs with the vector instructions it finds on the processor at run time. Q is
//! not formed. The same reflections as the unblocked algorithm, so the same backward stability;
//! only the summation order differs.
//!
//! The reflections within a panel, and the updates too small for matrixmultiply, are loops
//! written here (nalgebra's own loops for small products index element by element): the
//! library forbids `unsafe`, so they are the portable build's two-lane vector instructions,
//! shaped so that the compiler emits them (a dot product in two partial sums over eight terms a
//! pass, two columns updated per pass over a reflection's vector).

use nalgebra::{DMatrix, DMatrixView};

/// Columns reflected one by one before the columns right of them are updated by products (on
/// the tracker's blocks of 384 × 35, 6, 10, 12 and 16 took 9 % to 16 % more instructions than
/// 8, the height of matrixmultiply's kernel).
const PANEL: usize = 8;

/// The R factor of `a` (m × w): min(m, w) × w, upper triangular, with RᵀR = aᵀa (the row signs
/// of R are those of the reflections; any sign makes the same column geometry).
pub fn r_factor(mut a: DMatrix<f64>) -> DMatrix<f64> {
    r_factor_overwriting(&mut a)
}

/// [`r_factor`] of `a`, whose entries it overwrites (with the reflections' vectors below R):
/// for a caller that keeps the matrix's storage for the next one.
pub fn r_factor_overwriting(a: &mut DMatrix<f64>) -> DMatrix<f64> {
    let (m, w) = a.shape();
    let k = m.min(w);
    let mut panel = Panel::default();
    for start in (0..k).step_by(PANEL) {
        let width = PANEL.min(k - start);
        panel.reflect(a, start, width);
        if start + width < w {
            panel.update(a, start, width);
        }
        for (i, &alpha) in panel.alpha.iter().enumerate() {
            a[(start + i, start + i)] = alpha;
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
            axpy(-d, v, &mut column[..len]);
        }
        top[(j, j)] = alpha;
        v.fill(0.0);
    }
    top
}

/// Sizes above which nalgebra hands a product to matrixmultiply (at or below it, its own loop,
/// which reads past the end of views whose row stride is not 1).
const NALGEBRA_SMALL: usize = 5;

/// One panel's reflections and the buffers of its update, kept for every panel of a factor.
/// The reflections' vectors v stay in the panel's columns of the matrix, from its diagonal down
/// (V, m × b below the entries of R above the diagonal), until the update is done.
#[derive(Default)]
struct Panel {
    /// R's diagonal entries, written over the vectors' first entries once they are applied.
    alpha: Vec<f64>,
    /// The reflections' factors 2/vᵀv.
    tau: Vec<f64>,
    /// R's entries above the panel's diagonal, while V's zeros stand in their place.
    above: Vec<f64>,
    /// [VᵀV | W]: V's Gram matrix, then Vᵀ·C, then Tᵀ·Vᵀ·C.
    products: DMatrix<f64>,
    /// T (upper triangular, column-major).
    t: Vec<f64>,
}

impl Panel {
    /// Reflect columns `start..start + width` of `a` (rows from `start` down), leaving R's part
    /// above the diagonal and the vectors from it down, the diagonal of R in `alpha`.
    fn reflect(&mut self, a: &mut DMatrix<f64>, start: usize, width: usize) {
        let m = a.nrows();
        self.alpha.clear();
        self.tau.clear();
        let data = a.as_mut_slice();
        for i in 0..width {
            let j = start + i;
            let (done, rest) = data.split_at_mut((j + 1) * m);
            let v = &mut done[j * m + j..];
            let below = dot(&v[1..], &v[1..]);
            let x0 = v[0];
            let norm = (x0 * x0 + below).sqrt();
            if norm == 0.0 {
                // A zero column: no reflection (v = 0).
                self.alpha.push(0.0);
                self.tau.push(0.0);
                continue;
            }
            // v = x − α·e₁ with α of the sign opposite to x₀ (no cancellation); H = I − 2vvᵀ/vᵀv.
            let alpha = if x0 > 0.0 { -norm } else { norm };
            v[0] = x0 - alpha;
            let scale = 2.0 / (v[0] * v[0] + below);
            reflect_columns(v, scale, &mut rest[..(width - i - 1) * m], j);
            self.alpha.push(alpha);
            self.tau.push(scale);
        }
    }

    /// Apply the panel's reflections to the columns right of it: by products when they are
    /// large enough for matrixmultiply, otherwise one by one.
    fn update(&mut self, a: &mut DMatrix<f64>, start: usize, width: usize) {
        if width <= NALGEBRA_SMALL || a.ncols() - start - width <= NALGEBRA_SMALL {
            self.update_one_by_one(a, start, width);
        } else {
            self.update_by_products(a, start, width);
        }
    }

    /// Apply the panel's reflections to the columns right of it one after the other.
    fn update_one_by_one(&self, a: &mut DMatrix<f64>, start: usize, width: usize) {
        let m = a.nrows();
        let (panel, c) = a.as_mut_slice().split_at_mut((start + width) * m);
        for (i, &scale) in self.tau.iter().enumerate() {
            let j = start + i;
            reflect_columns(&panel[j * m + j..(j + 1) * m], scale, c, j);
        }
    }

    /// Apply the panel's reflections to the columns right of it (more than [`NALGEBRA_SMALL`]
    /// of them, the panel as wide) by three products: C − V·(Tᵀ·(Vᵀ·C)), with
    /// H₁⋯H_b = I − V·T·Vᵀ.
    fn update_by_products(&mut self, a: &mut DMatrix<f64>, start: usize, width: usize) {
        let (m, w) = a.shape();
        let (rows, right) = (m - start, w - start - width);
        // V: zeros above the diagonal (R's entries kept aside meanwhile).
        let places = (1..width).flat_map(|i| (0..i).map(move |l| (start + l, start + i)));
        self.above.clear();
        self.above.extend(places.clone().map(|place| std::mem::take(&mut a[place])));
        // [VᵀV | VᵀC] in one product, Vᵀ read from V's columns row by row (every size above
        // NALGEBRA_SMALL: no view with another row stride reaches nalgebra's own loop).
        let vt = DMatrixView::from_slice_with_strides(&a.as_slice()[start * m + start..], width, rows, m, 1);
        let vc = a.view((start, start), (rows, width + right));
        self.products.resize_mut(width, width + right, 0.0);
        self.products.gemm(1.0, &vt, &vc, 0.0);
        let (gram, wc) = self.products.as_mut_slice().split_at_mut(width * width);
        // T column by column: T[..i, i] = −τᵢ·T[..i, ..i]·(V[:, ..i]ᵀ·vᵢ).
        let t = &mut self.t;
        t.clear();
        t.resize(width * width, 0.0);
        for i in 0..width {
            let g = &gram[i * width..i * width + i];
            t[i * width + i] = self.tau[i];
            for l in 0..i {
                let s: f64 = (l..i).map(|p| t[p * width + l] * g[p]).sum();
                t[i * width + l] = -self.tau[i] * s;
            }
        }
        // W ← Tᵀ·W column by column, from the last row up (row i reads rows l ≤ i).
        for column in wc.chunks_exact_mut(width) {
            for i in (0..width).rev() {
                column[i] = t[i * width..=i * width + i].iter().zip(&column[..=i]).map(|(t, w)| t * w).sum();
            }
        }
        let w_view = self.products.columns(width, right);
        let (v, mut c) = a.columns_range_pair_mut(start..start + width, start + width..);
        c.rows_mut(start, rows).gemm(-1.0, &v.rows(start, rows), &w_view, 1.0);
        let places = (1..width).flat_map(|i| (0..i).map(move |l| (start + l, start + i)));
        for (place, &entry) in places.zip(&self.above) {
            a[place] = entry;
        }
    }
}

/// Apply H = I − scale·vvᵀ to the rows `first..` of each column of `columns` (column-major,
/// each as long as the rows of `v` from `first` on plus `first`), two columns per pass over `v`.
fn reflect_columns(v: &[f64], scale: f64, columns: &mut [f64], first: usize) {
    let m = first + v.len();
    let mut pairs = columns.chunks_exact_mut(2 * m);
    for pair in &mut pairs {
        let (c1, c2) = pair.split_at_mut(m);
        let (c1, c2) = (&mut c1[first..], &mut c2[first..]);
        let (d1, d2) = (scale * dot(v, c1), scale * dot(v, c2));
        axpy2(-d1, -d2, v, c1, c2);
    }
    if let Some(last) = pairs.into_remainder().get_mut(first..).filter(|c| !c.is_empty()) {
        let d = scale * dot(v, last);
        axpy(-d, v, last);
    }
}

/// Σ a_i·b_i in two partial sums (the two lanes of one vector instruction), eight terms a pass.
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let (a8, at) = a.as_chunks::<8>();
    let (b8, bt) = b[..a.len()].as_chunks::<8>();
    let mut s = [0.0; 2];
    for (x, y) in a8.iter().zip(b8) {
        for k in (0..8).step_by(2) {
            s[0] += x[k] * y[k];
            s[1] += x[k + 1] * y[k + 1];
        }
    }
    let tail: f64 = at.iter().zip(bt).map(|(x, y)| x * y).sum();
    s[0] + s[1] + tail
}

/// y ← y + α·x.
fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// y ← y + α·x and z ← z + β·x in one pass over `x`.
fn axpy2(alpha: f64, beta: f64, x: &[f64], y: &mut [f64], z: &mut [f64]) {
    for ((yi, zi), xi) in y.iter_mut().zip(z.iter_mut()).zip(x) {
        *yi += alpha * xi;
        *zi += beta * xi;
    }
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
    fn a_panel_updates_the_same_by_products_as_one_by_one() {
        // Panels at the top and lower down, narrower than the others, as tall as wide.
        for (m, w, start, width) in [(60, 30, 0, 8), (60, 30, 8, 8), (40, 30, 16, 7), (14, 24, 8, 6)] {
            let mut a = sample(m, w, 4);
            let mut panel = Panel::default();
            for before in (0..start).step_by(PANEL) {
                panel.reflect(&mut a, before, PANEL);
                panel.update_one_by_one(&mut a, before, PANEL);
            }
            panel.reflect(&mut a, start, width);
            let (mut by_products, mut one_by_one) = (a.clone(), a.clone());
            panel.update_by_products(&mut by_products, start, width);
            panel.update_one_by_one(&mut one_by_one, start, width);
            assert!((&by_products - &one_by_one).norm() <= 1e-13 * a.norm(), "{m} × {w} from {start}");
            // The panel's columns (R's part and the vectors) are left as they were, the others
            // are reflected.
            let (done, right) = (start + width, w - start - width);
            assert_eq!(by_products.columns(0, done), a.columns(0, done));
            assert!((by_products.columns(done, right) - a.columns(done, right)).norm() > 1e-3 * a.norm());
        }
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
