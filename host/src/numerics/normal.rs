//! Normal equations JᵀWJ and JᵀWr (W the rows' IRLS weights) summed as outer products of the
//! Jacobian's rows, as Ceres' dense normal Cholesky forms them: the inner loop over contiguous
//! columns, one multiply and add per entry of the upper triangle (which the compiler
//! vectorises), and nothing allocated per row.
//!
//! [`NormalSums`] sums terms that each touch a few of n columns (a point reads the arm's columns
//! and its own session's frame): a batch of terms is laid out as dense rows over the union of
//! their columns, its Gram matrix formed there and added into the n × n sums once per batch. The
//! order of every sum depends on the terms' order only.

/// Add Σ_i w_i·a_i·a_iᵀ into the upper triangle of `h` (k × k, row-major) and Σ_i w_i·r_i·a_i
/// into `g`, for the rows a_i of `rows` (row-major, k columns), `weights` and `r` one per row.
/// Row after row, each entry gains (w_i·a_ip)·a_iq (nothing for w_i·a_ip = 0): the same
/// arithmetic in the same order as the plain triple loop, so the same sums to the last bit.
pub fn add_gram(h: &mut [f64], g: &mut [f64], k: usize, rows: &[f64], weights: &[f64], r: &[f64]) {
    gram::<1>(h, g, k, rows, weights, r);
}

/// As [`add_gram`], four rows at a time: each entry of the triangle is read and written once per
/// four rows (about three times faster; the sums in another order, so equal to rounding).
pub fn add_gram_by_four(h: &mut [f64], g: &mut [f64], k: usize, rows: &[f64], weights: &[f64], r: &[f64]) {
    gram::<4>(h, g, k, rows, weights, r);
}

/// As [`add_gram`], `B` rows at a time.
fn gram<const B: usize>(h: &mut [f64], g: &mut [f64], k: usize, rows: &[f64], weights: &[f64], r: &[f64]) {
    debug_assert!(rows.len() == weights.len() * k && r.len() == weights.len());
    debug_assert!(h.len() == k * k && g.len() == k);
    let whole = weights.len() / B * B;
    for i in (0..whole).step_by(B) {
        let a: [&[f64]; B] = std::array::from_fn(|b| &rows[(i + b) * k..(i + b + 1) * k]);
        for p in 0..k {
            let u: [f64; B] = std::array::from_fn(|b| weights[i + b] * a[b][p]);
            if u.iter().all(|&v| v == 0.0) {
                continue;
            }
            let mut gp = u[0] * r[i];
            for b in 1..B {
                gp += u[b] * r[i + b];
            }
            g[p] += gp;
            let row = &mut h[p * k + p..(p + 1) * k];
            let len = row.len();
            let columns: [&[f64]; B] = std::array::from_fn(|b| &a[b][p..p + len]);
            for q in 0..len {
                let mut s = u[0] * columns[0][q];
                for b in 1..B {
                    s += u[b] * columns[b][q];
                }
                row[q] += s;
            }
        }
    }
    if whole < weights.len() && B > 1 {
        gram::<1>(h, g, k, &rows[whole * k..], &weights[whole..], &r[whole..]);
    }
}

/// Rows a batch holds before its Gram matrix is formed.
const BATCH_ROWS: usize = 256;
/// Columns a batch may span before its Gram matrix is formed.
const BATCH_COLUMNS: usize = 96;
/// No column's local index.
const NONE: usize = usize::MAX;

/// JᵀWJ (upper triangle, n × n row-major) and JᵀWr summed term by term.
pub struct NormalSums {
    n: usize,
    h: Vec<f64>,
    g: Vec<f64>,
    /// Per column, its index in the batch (or [`NONE`]).
    local: Vec<usize>,
    /// The batch's columns, by local index.
    globals: Vec<usize>,
    /// The batch's terms: (first row, rows, first column entry, columns).
    terms: Vec<(usize, usize, usize, usize)>,
    columns: Vec<usize>,
    values: Vec<f64>,
    r: Vec<f64>,
    w: Vec<f64>,
    dense: Vec<f64>,
    h_local: Vec<f64>,
    g_local: Vec<f64>,
}

impl NormalSums {
    /// Empty sums over `n` columns.
    pub fn new(n: usize) -> NormalSums {
        NormalSums {
            n,
            h: vec![0.0; n * n],
            g: vec![0.0; n],
            local: vec![NONE; n],
            globals: Vec::new(),
            terms: Vec::new(),
            columns: Vec::new(),
            values: Vec::new(),
            r: Vec::new(),
            w: Vec::new(),
            dense: Vec::new(),
            h_local: Vec::new(),
            g_local: Vec::new(),
        }
    }

    /// Add one term: its rows' residuals `r` and weights `w`, its non-zero columns `columns`
    /// with their derivatives `values` (one per row, column after column).
    pub fn add(&mut self, columns: &[usize], values: &[f64], r: &[f64], w: &[f64]) {
        let new = columns.iter().filter(|&&c| self.local[c] == NONE).count();
        if self.r.len() + r.len() > BATCH_ROWS || self.globals.len() + new > BATCH_COLUMNS {
            self.flush();
        }
        for &c in columns {
            if self.local[c] == NONE {
                self.local[c] = self.globals.len();
                self.globals.push(c);
            }
        }
        self.terms.push((self.r.len(), r.len(), self.columns.len(), columns.len()));
        self.columns.extend_from_slice(columns);
        self.values.extend_from_slice(values);
        self.r.extend_from_slice(r);
        self.w.extend_from_slice(w);
    }

    /// Form the batch's Gram matrix over its columns and add it into the sums.
    fn flush(&mut self) {
        let (k, m) = (self.globals.len(), self.r.len());
        if m == 0 {
            return;
        }
        self.dense.clear();
        self.dense.resize(m * k, 0.0);
        let mut at = 0;
        for &(row, rows, first, count) in &self.terms {
            for &c in &self.columns[first..first + count] {
                let l = self.local[c];
                for (j, v) in self.values[at..at + rows].iter().enumerate() {
                    self.dense[(row + j) * k + l] += v;
                }
                at += rows;
            }
        }
        self.h_local.clear();
        self.h_local.resize(k * k, 0.0);
        self.g_local.clear();
        self.g_local.resize(k, 0.0);
        add_gram_by_four(&mut self.h_local, &mut self.g_local, k, &self.dense, &self.w, &self.r);
        let n = self.n;
        for (p, &a) in self.globals.iter().enumerate() {
            self.g[a] += self.g_local[p];
            for (q, &b) in self.globals.iter().enumerate().skip(p) {
                self.h[a.min(b) * n + a.max(b)] += self.h_local[p * k + q];
            }
        }
        for &c in &self.globals {
            self.local[c] = NONE;
        }
        self.globals.clear();
        self.terms.clear();
        self.columns.clear();
        self.values.clear();
        self.r.clear();
        self.w.clear();
    }

    /// The sums: the upper triangle of JᵀWJ (n × n, row-major) and JᵀWr.
    pub fn finish(mut self) -> (Vec<f64>, Vec<f64>) {
        self.flush();
        (self.h, self.g)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// JᵀWJ and JᵀWr entry by entry, the plain way.
    fn plain(jac: &[f64], w: &[f64], r: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
        let (mut h, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        for (i, row) in jac.chunks_exact(n).enumerate() {
            for a in 0..n {
                g[a] += w[i] * row[a] * r[i];
                for b in 0..n {
                    h[a * n + b] += w[i] * row[a] * row[b];
                }
            }
        }
        (h, g)
    }

    #[test]
    fn terms_on_few_columns_sum_to_the_dense_normal_equations() {
        // 300 terms of 3 rows over 40 columns: each reads columns 0..5, a "session" block of 6
        // (one of five) and sometimes a column seen by no other term.
        let n = 40;
        let value = |t: usize, j: usize, c: usize| ((t * 31 + j * 7 + c * 13) as f64 * 0.37).sin();
        let mut jac = Vec::new();
        let (mut r, mut w) = (Vec::new(), Vec::new());
        let mut sums = NormalSums::new(n);
        for t in 0..300 {
            let mut columns: Vec<usize> = (0..5).chain(5 + 6 * (t % 5)..11 + 6 * (t % 5)).collect();
            if t % 7 == 0 {
                columns.push(35 + t % 5);
            }
            let rows = 3;
            let values: Vec<f64> =
                columns.iter().flat_map(|&c| (0..rows).map(move |j| value(t, j, c))).collect();
            let tr: Vec<f64> = (0..rows).map(|j| value(t, j, 99)).collect();
            let tw: Vec<f64> = (0..rows).map(|j| 0.5 + value(t, j, 98).abs()).collect();
            for j in 0..rows {
                let mut row = vec![0.0; n];
                for &c in &columns {
                    row[c] = value(t, j, c);
                }
                jac.extend(row);
            }
            r.extend(&tr);
            w.extend(&tw);
            sums.add(&columns, &values, &tr, &tw);
        }
        let (h, g) = sums.finish();
        let (hd, gd) = plain(&jac, &w, &r, n);
        for a in 0..n {
            assert!((g[a] - gd[a]).abs() < 1e-12 * (1.0 + gd[a].abs()), "g[{a}]");
            for b in 0..n {
                let ours = if a <= b { h[a * n + b] } else { h[b * n + a] };
                assert!((ours - hd[a * n + b]).abs() < 1e-12 * (1.0 + hd[a * n + b].abs()), "h[{a},{b}]");
            }
        }
        // And the dense kernels on the whole Jacobian, with a row count not a multiple of four:
        // the plain order to the last bit, four rows at a time to rounding.
        let m = r.len() - 1;
        let (hd, gd) = plain(&jac[..m * n], &w[..m], &r[..m], n);
        let (mut h, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        add_gram(&mut h, &mut g, n, &jac[..m * n], &w[..m], &r[..m]);
        for a in 0..n {
            assert_eq!(g[a], gd[a]);
            for b in a..n {
                assert_eq!(h[a * n + b], hd[a * n + b]);
            }
        }
        let (mut h, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        add_gram_by_four(&mut h, &mut g, n, &jac[..m * n], &w[..m], &r[..m]);
        for a in 0..n {
            assert!((g[a] - gd[a]).abs() < 1e-12 * (1.0 + gd[a].abs()));
            for b in a..n {
                assert!((h[a * n + b] - hd[a * n + b]).abs() < 1e-12 * (1.0 + hd[a * n + b].abs()));
            }
        }
    }
}
