//! Normal equations JᵀWJ and JᵀWr (W the rows' IRLS weights), as Ceres' dense normal Cholesky
//! forms them, of a Jacobian given in dense blocks of rows.
//!
//! The dense product takes one column-major block D (m × k): U = W·D (its rows times their
//! weights, copied row by row, so that Uᵀ is column-major), JᵀWr = Uᵀr, and UᵀD by nalgebra's
//! dense product, which hands blocks of this size to the `matrixmultiply` crate: register-tiled
//! micro-kernels over packed panels, chosen at run time for the CPU (AVX2 and FMA where the
//! processor has them, SSE2 otherwise). That is why these sums are not written here: a portable
//! build cannot use those instructions without `unsafe`, which the library forbids, and the
//! product computes the upper block triangle (up to 4/3 of the triangle's work) at up to four
//! times the rate of the best portable loop. Its order of summation depends on the CPU's kernel,
//! so two CPUs agree to rounding, not to the bit; one machine gives the same sums on any thread
//! count.
//! [`add_rows_gram`] does the same for a batch of rows held row-major (a dense Jacobian of few
//! columns, the artefact's, a batch at a time: U is D itself while every row's weight is 1).
//! [`add_gram`] keeps the plain order (for small problems that want it to the bit).
//!
//! [`NormalSums`] sums terms that each touch a few of n columns (a point reads the arm's columns
//! and its own session's frame): each term's derivatives are written straight into a batch D
//! held row-major over the union of the batch's columns (by the term itself, into the rows
//! [`RowTarget::rows`] gives it at the batch's places of its columns, or scattered from its
//! column list by [`NormalSums::add`]), and the batch's Gram matrix UᵀD is formed by
//! [`add_rows_gram`] and added into the n × n sums once per batch. The order of every sum
//! depends on the terms' order only.

use nalgebra::{DMatrixView, DMatrixViewMut, Dyn};
use std::ops::Range;

/// Add Σ_i w_i·a_i·a_iᵀ into the upper triangle of `h` (k × k, row-major) and Σ_i w_i·r_i·a_i
/// into `g`, for the rows a_i of `rows` (row-major, k columns), `weights` and `r` one per row.
/// Row after row, each entry gains (w_i·a_ip)·a_iq (nothing for w_i·a_ip = 0): the same
/// arithmetic in the same order as the plain triple loop, so the same sums to the last bit.
pub fn add_gram(h: &mut [f64], g: &mut [f64], k: usize, rows: &[f64], weights: &[f64], r: &[f64]) {
    debug_assert!(rows.len() == weights.len() * k && r.len() == weights.len());
    debug_assert!(h.len() == k * k && g.len() == k);
    if k == 0 {
        return;
    }
    for ((a, w), r) in rows.chunks_exact(k).zip(weights).zip(r) {
        for (p, h_row) in h.chunks_exact_mut(k).enumerate() {
            let u = w * a[p];
            if u == 0.0 {
                continue;
            }
            g[p] += u * r;
            add_scaled_row(&mut h_row[p..], u, &a[p..]);
        }
    }
}

/// `out[q] += u·c[q]` for every q, two q at a time: the compiler keeps each pair in one vector
/// register, which it does not for a loop over q of a row this short (a dozen columns).
#[inline(always)]
fn add_scaled_row(out: &mut [f64], u: f64, c: &[f64]) {
    let n = out.len();
    let c = &c[..n];
    let mut pairs = out.chunks_exact_mut(2);
    for (pair, q) in (&mut pairs).zip((0..n).step_by(2)) {
        let s = [u * c[q], u * c[q + 1]];
        pair[0] += s[0];
        pair[1] += s[1];
    }
    if let [last] = pairs.into_remainder() {
        *last += u * c[n - 1];
    }
}

/// The Gram matrix of the m rows of a column-major block (column l's rows at
/// `columns[l * stride ..]`, k columns) by the dense product, returned (k × k row-major, its
/// upper triangle, in `buffers`, which holds the weighted copy too), Uᵀr added into `g`; m and
/// k not zero.
fn columns_product<'b>(
    g: &mut [f64],
    (columns, stride, k): (&[f64], usize, usize),
    weights: &[f64],
    r: &[f64],
    buffers: &'b mut GramBuffers,
) -> &'b [f64] {
    let m = weights.len();
    // U = W·D row-major, so that Uᵀ (the product's left factor) is column-major.
    let u = &mut buffers.weighted;
    u.clear();
    u.resize(m * k, 0.0);
    for (l, column) in columns.chunks(stride).take(k).enumerate() {
        for ((ui, v), w) in u[l..].iter_mut().step_by(k).zip(&column[..m]).zip(weights) {
            *ui = w * v;
        }
    }
    let d = DMatrixView::from_slice_with_strides(&columns[..(k - 1) * stride + m], m, k, 1, stride);
    product_into(g, (u, k, k), &d, r, &mut buffers.product);
    &buffers.product
}

/// As [`add_gram`] for the rows of a batch held row-major, `(rows, width, k)`: row i's k
/// columns at `rows[i * width ..]` (k ≤ `width`), one weight and one residual per row; by the
/// dense product (see the module doc; the plain sums to rounding). U = W·D is copied into
/// `buffers` (which also holds the product) unless every weight is 1: U is then D itself.
pub fn add_rows_gram(
    h: &mut [f64],
    g: &mut [f64],
    (rows, width, k): (&[f64], usize, usize),
    weights: &[f64],
    r: &[f64],
    buffers: &mut GramBuffers,
) {
    let m = weights.len();
    debug_assert!(r.len() == m && h.len() == k * k && g.len() == k && k <= width);
    if m == 0 || k == 0 {
        return;
    }
    add_upper(h, rows_product(g, (rows, width, k), weights, r, buffers), k);
}

/// As [`add_rows_gram`], the Gram matrix returned (k × k row-major, its upper triangle, in
/// `buffers`) instead of added into sums, for a caller that adds it where its columns belong;
/// m and k not zero.
fn rows_product<'b>(
    g: &mut [f64],
    (rows, width, k): (&[f64], usize, usize),
    weights: &[f64],
    r: &[f64],
    buffers: &'b mut GramBuffers,
) -> &'b [f64] {
    let m = weights.len();
    let span = (m - 1) * width + k;
    if m <= NALGEBRA_SMALL || k <= NALGEBRA_SMALL {
        // Too small for the crate's product, which reads a row-major D only above that size:
        // packed column-major.
        let packed: Vec<f64> = (0..k).flat_map(|l| rows[l..span].iter().step_by(width).copied()).collect();
        return columns_product(g, (&packed, m, k), weights, r, buffers);
    }
    let d = DMatrixView::from_slice_with_strides(&rows[..span], m, k, width, 1);
    if weights.iter().all(|&w| w == 1.0) {
        product_into(g, (rows, width, k), &d, r, &mut buffers.product);
        return &buffers.product;
    }
    let u = &mut buffers.weighted;
    // Only its first m·k entries are written and read: kept at the largest size asked for, never
    // shrunk or zeroed again.
    u.resize(u.len().max(m * k), 0.0);
    for ((ui, row), w) in u.chunks_exact_mut(k).zip(rows.chunks(width)).zip(weights) {
        ui.iter_mut().zip(&row[..k]).for_each(|(u, v)| *u = w * v);
    }
    product_into(g, (&u[..m * k], k, k), &d, r, &mut buffers.product);
    &buffers.product
}

/// Add the upper triangle of `product` (k × k, row-major) into `h`'s.
fn add_upper(h: &mut [f64], product: &[f64], k: usize) {
    for p in 0..k {
        let row = p * k + p..(p + 1) * k;
        h[row.clone()].iter_mut().zip(&product[row]).for_each(|(hq, v)| *hq += v);
    }
}

/// Add Uᵀr into `g` and set the upper triangle of UᵀD into `product` (k × k, row-major; the
/// lower triangle is left partly unset): U (m × k) row-major with row stride `u_stride` (so
/// that Uᵀ is a column-major view: nalgebra's product for small sizes reads past the end of
/// views with another row stride); D may have any strides when every dimension is above
/// nalgebra's small size (5), which hands the product to the `matrixmultiply` crate (any
/// strides, the same sums as packed).
///
/// Only the upper block triangle is formed: the columns in up to three blocks, each block's
/// columns against the rows up to its last (a third fewer products than the square). Each
/// entry's sum runs over the m rows in the crate's order whatever block holds it, so the sums
/// are the square's to the bit.
fn product_into(
    g: &mut [f64],
    (u, u_stride, k): (&[f64], usize, usize),
    d: &DMatrixView<f64, Dyn, Dyn>,
    r: &[f64],
    product: &mut Vec<f64>,
) {
    let m = r.len();
    debug_assert!(d.strides().0 == 1 || m.min(k) > NALGEBRA_SMALL);
    add_transposed(g, (u, u_stride, k), r);
    let ut = DMatrixView::from_slice_with_strides(&u[..(m - 1) * u_stride + k], k, m, 1, u_stride);
    product.resize(k * k, 0.0);
    let (edges, blocks) = column_blocks(k);
    let edges = &edges[..=blocks];
    for (&first, &end) in edges.iter().zip(&edges[1..]) {
        // Row-major k × k: the rows 0..end of the columns first..end.
        let mut block = DMatrixViewMut::from_slice_with_strides_mut(
            &mut product[first..(end - 1) * k + end],
            end,
            end - first,
            k,
            1,
        );
        block.gemm(1.0, &ut.rows(0, end), &d.columns(first, end - first), 0.0);
    }
}

/// Add Uᵀr into `g` (U as in [`product_into`]), each entry's sum row after row as by one row
/// at a time, but four rows per pass over `g`: a quarter of its loads and stores.
fn add_transposed(g: &mut [f64], (u, u_stride, k): (&[f64], usize, usize), r: &[f64]) {
    let g = &mut g[..k];
    let row = |i: usize| &u[i * u_stride..i * u_stride + k];
    let fours = r.chunks_exact(4);
    let last = fours.remainder();
    for (i, [r0, r1, r2, r3]) in fours.map(|f| [f[0], f[1], f[2], f[3]]).enumerate() {
        let rows = row(4 * i).iter().zip(row(4 * i + 1)).zip(row(4 * i + 2)).zip(row(4 * i + 3));
        for (gl, (((a, b), c), d)) in g.iter_mut().zip(rows) {
            *gl = *gl + a * r0 + b * r1 + c * r2 + d * r3;
        }
    }
    for (i, ri) in (r.len() - last.len()..).zip(last) {
        g.iter_mut().zip(row(i)).for_each(|(gl, v)| *gl += v * ri);
    }
}

/// nalgebra's largest dimension for which its product does not call `matrixmultiply`.
const NALGEBRA_SMALL: usize = 5;

/// The column blocks of [`product_into`] for k columns: their edges `[0, .., k]` (the first
/// count + 1 entries: no allocation per batch) and their count. Three blocks from 48 columns,
/// two from 24, else one; inner edges on multiples of 8 (the crate's tiles: no partial tiles
/// inside), which leaves every block of a split wider than [`NALGEBRA_SMALL`].
fn column_blocks(k: usize) -> ([usize; 4], usize) {
    let blocks = match k {
        48.. => 3,
        24.. => 2,
        _ => 1,
    };
    let mut edges = [k; 4];
    for (j, edge) in edges.iter_mut().take(blocks).enumerate() {
        *edge = (k * j / blocks).next_multiple_of(8);
    }
    debug_assert!(blocks == 1 || edges[..=blocks].windows(2).all(|e| e[1] - e[0] > NALGEBRA_SMALL));
    (edges, blocks)
}

/// The buffers of [`add_rows_gram`]: a block's weighted copy and its k × k product
/// (row-major).
#[derive(Default)]
pub struct GramBuffers {
    weighted: Vec<f64>,
    product: Vec<f64>,
}

/// Where a term writes its rows itself: rows of a batch that sums them into normal equations.
pub trait RowTarget {
    /// Room for a term of `rows` rows (at most a batch's) reading the columns of `columns`:
    /// its rows, for it to write its derivatives into. A term asks once, over disjoint spans,
    /// and must write every column of `columns`, a zero derivative too: the rows are zero at the
    /// batch's other columns but hold any values at these (an earlier batch's; NaN in a build
    /// with debug assertions, so that a column left unwritten poisons the sums there).
    fn rows<'a>(&'a mut self, rows: usize, columns: &'a [Range<usize>]) -> TermRows<'a>;
}

/// A term's rows in a batch: row i's derivative by column c at `rows[i * stride + local[c]]`.
pub struct TermRows<'a> {
    rows: &'a mut [f64],
    stride: usize,
    local: &'a [usize],
    columns: &'a [Range<usize>],
    /// Bit i set: span i of `columns` is known to be at consecutive places in its order.
    in_order: u64,
}

impl<'a> TermRows<'a> {
    /// A term's rows at the start of `rows` (row i at `rows[i * stride ..]`), column c at place
    /// `local[c]` of each row, for a term reading the columns of `columns` (each of which must
    /// have a place).
    pub fn new(rows: &'a mut [f64], stride: usize, local: &'a [usize], columns: &'a [Range<usize>]) -> Self {
        debug_assert!(columns.iter().flat_map(Clone::clone).all(|c| local[c] < stride));
        TermRows { rows, stride, local, columns, in_order: 0 }
    }

    /// The derivatives of the first three rows by column `column`.
    #[inline]
    pub fn set3(&mut self, column: usize, values: [f64; 3]) {
        let (l, stride) = (self.local[column], self.stride);
        self.rows[l] = values[0];
        self.rows[stride + l] = values[1];
        self.rows[2 * stride + l] = values[2];
    }

    /// The derivatives of the first three rows by the columns `span`, one slice per row, when
    /// the batch holds those columns at consecutive places in their order (as it does for a
    /// span some term asked for first); `None` otherwise.
    #[inline]
    pub fn span3(&mut self, span: Range<usize>) -> Option<[&mut [f64]; 3]> {
        let known =
            self.columns.iter().zip(0..u64::BITS).any(|(c, i)| self.in_order >> i & 1 == 1 && *c == span);
        let locals = &self.local[span];
        let first = if known { locals[0] } else { first_in_order(locals)? };
        let (stride, count) = (self.stride, locals.len());
        let (row0, rest) = self.rows.split_at_mut(stride);
        let (row1, row2) = rest.split_at_mut(stride);
        let at = first..first + count;
        Some([&mut row0[at.clone()], &mut row1[at.clone()], &mut row2[at]])
    }

    /// Every derivative written times `factor`.
    pub fn scale(&mut self, factor: f64) {
        for row in self.rows.chunks_exact_mut(self.stride) {
            for span in self.columns {
                self.local[span.clone()].iter().for_each(|&l| row[l] *= factor);
            }
        }
    }
}

/// The first of `locals` when they are consecutive and in order (and not empty).
fn first_in_order(locals: &[usize]) -> Option<usize> {
    let first = *locals.first()?;
    // Every place compared, no early exit: a loop of a few instructions per two columns.
    let misplaced = locals.iter().zip(first..).fold(0, |any, (&l, expected)| any | (l ^ expected));
    (misplaced == 0).then_some(first)
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
    /// The local indices of the term being added by [`NormalSums::add`], one per column it
    /// reads.
    term_locals: Vec<usize>,
    /// The column spans of the last term given rows by [`RowTarget::rows`] while they are all
    /// in the batch (empty after a flush): the next term over the same spans (a point of the
    /// same session) has its columns' places already.
    placed: Vec<Range<usize>>,
    /// Bit i set: span i of `placed` is at consecutive places in its order (see
    /// [`TermRows::span3`]).
    placed_in_order: u64,
    /// Row stride of the batch: [`BATCH_COLUMNS`], or more after a term that reads more.
    width: usize,
    /// The batch's derivatives D, row-major: row i's local columns at `i * width ..` (zero
    /// where a term does not read the column). Only the batch's rows and columns are kept so;
    /// the rest holds what earlier batches left (a new column is zeroed over the rows before
    /// it, a term's rows where it writes less than every column), so that no row is zeroed
    /// after each batch.
    dense: Vec<f64>,
    r: Vec<f64>,
    w: Vec<f64>,
    g_local: Vec<f64>,
    /// Per local column, how many local columns from it on hold consecutive columns: the
    /// batch's Gram matrix is added into the sums a run at a time.
    runs: Vec<usize>,
    buffers: GramBuffers,
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
            term_locals: Vec::new(),
            placed: Vec::new(),
            placed_in_order: 0,
            width: BATCH_COLUMNS,
            dense: vec![0.0; BATCH_ROWS * BATCH_COLUMNS],
            r: Vec::with_capacity(BATCH_ROWS),
            w: Vec::with_capacity(BATCH_ROWS),
            g_local: Vec::new(),
            runs: Vec::new(),
            buffers: GramBuffers::default(),
        }
    }

    /// Add one term: its rows' residuals `r` and weights `w`, its non-zero columns `columns`
    /// with their derivatives `values` (one per row, column after column).
    pub fn add(&mut self, columns: &[usize], values: &[f64], r: &[f64], w: &[f64]) {
        let rows = r.len();
        debug_assert!(values.len() == columns.len() * rows);
        self.admit(rows, |sums| {
            for &c in columns {
                sums.assign(c..c + 1);
            }
        });
        self.term_locals.clear();
        self.term_locals.extend(columns.iter().map(|&c| self.local[c]));
        let (first, width, k) = (self.r.len(), self.width, self.globals.len());
        let block = &mut self.dense[first * width..(first + rows) * width];
        for (i, row) in block.chunks_exact_mut(width).enumerate() {
            row[..k].fill(0.0);
            // Row i of the term: its derivatives are `values[i]`, `values[i + rows]`, ...
            for (&l, &v) in self.term_locals.iter().zip(values[i..].iter().step_by(rows)) {
                row[l] += v;
            }
        }
        self.close(r, w);
    }

    /// Make room in the batch for a term of `rows` rows whose columns `assign` gives their
    /// local indices ([`NormalSums::assign`]): when the batch would hold too many rows or
    /// columns, its Gram matrix is formed first and the columns are assigned again in a new
    /// batch. (Assigned before the test: one pass over the term's columns, most of them in the
    /// batch already.)
    fn admit(&mut self, rows: usize, assign: impl Fn(&mut NormalSums)) {
        debug_assert!(rows <= BATCH_ROWS);
        let before = self.globals.len();
        assign(self);
        if self.r.len() + rows > BATCH_ROWS || self.globals.len() > BATCH_COLUMNS {
            for &c in &self.globals[before..] {
                self.local[c] = NONE;
            }
            self.globals.truncate(before);
            self.flush();
            assign(self);
        }
        if self.globals.len() > self.width {
            // One term reading more columns than a batch spans (the batch is empty): wider rows.
            self.width = self.globals.len();
            self.dense = vec![0.0; BATCH_ROWS * self.width];
        }
    }

    /// Give each column of `span` new to the batch the next free index in it, zero over the
    /// batch's rows so far.
    #[inline]
    fn assign(&mut self, span: Range<usize>) {
        let (m, width) = (self.r.len(), self.width);
        for (c, l) in span.clone().zip(&mut self.local[span]) {
            if *l == NONE {
                *l = self.globals.len();
                self.globals.push(c);
                // (A place past the rows' width is never written: the batch is full.)
                if *l < width {
                    self.dense[*l..].iter_mut().step_by(width).take(m).for_each(|v| *v = 0.0);
                }
            }
        }
    }

    /// The residuals `r` and weights `w` of the term whose rows were just written into the
    /// batch (by [`NormalSums::add`], or by the term itself into the rows of
    /// [`RowTarget::rows`]).
    pub fn close(&mut self, r: &[f64], w: &[f64]) {
        debug_assert!(w.len() == r.len() && self.r.len() + r.len() <= BATCH_ROWS);
        self.r.extend_from_slice(r);
        self.w.extend_from_slice(w);
    }

    /// Form the batch's Gram matrix over its columns, add it into the sums and empty the batch.
    fn flush(&mut self) {
        let (k, m, width) = (self.globals.len(), self.r.len(), self.width);
        if m > 0 && k > 0 {
            self.g_local.clear();
            self.g_local.resize(k, 0.0);
            // The product added where its columns belong, with no zeroed k × k sums between
            // (the same sums: each entry was added once onto zero there).
            let mut buffers = std::mem::take(&mut self.buffers);
            let rows = (&self.dense[..], width, k);
            let product = rows_product(&mut self.g_local, rows, &self.w, &self.r, &mut buffers);
            self.add_local(product);
            self.buffers = buffers;
        }
        for &c in &self.globals {
            self.local[c] = NONE;
        }
        self.globals.clear();
        self.placed.clear();
        self.r.clear();
        self.w.clear();
    }

    /// Add the batch's Gram matrix `h_local` (k × k row-major, its upper triangle) and
    /// `g_local` into the sums at the batch's columns: a run of consecutive columns at a time,
    /// into a run of a row of the sums (or of a column, for columns before the row's).
    fn add_local(&mut self, h_local: &[f64]) {
        let (k, n) = (self.globals.len(), self.n);
        self.runs.clear();
        self.runs.resize(k, 1);
        for q in (0..k.saturating_sub(1)).rev() {
            if self.globals[q + 1] == self.globals[q] + 1 {
                self.runs[q] = self.runs[q + 1] + 1;
            }
        }
        for (p, &a) in self.globals.iter().enumerate() {
            self.g[a] += self.g_local[p];
            let mut q = p;
            while q < k {
                let (b, run) = (self.globals[q], self.runs[q]);
                let values = &h_local[p * k + q..p * k + q + run];
                // A run holds columns b..b + run: from a on (the first run, from a itself) or all
                // before a (a is in no other run).
                if b >= a {
                    let sums = &mut self.h[a * n + b..a * n + b + run];
                    sums.iter_mut().zip(values).for_each(|(s, v)| *s += v);
                } else {
                    let sums = self.h[b * n + a..].iter_mut().step_by(n);
                    sums.zip(values).for_each(|(s, v)| *s += v);
                }
                q += run;
            }
        }
    }

    /// The sums: the upper triangle of JᵀWJ (n × n, row-major) and JᵀWr. The sums start again
    /// from zero; the batch's buffers are kept for them (no allocation or zeroing when they are
    /// used again over as many columns).
    pub fn finish(&mut self) -> (Vec<f64>, Vec<f64>) {
        self.finish_on(None)
    }

    /// [`NormalSums::finish`], the sums starting again on `zeroed` (n × n and n zeros, such as
    /// [`add_and_clear`] leaves a finished pair) when given, instead of on buffers allocated
    /// zeroed.
    pub fn finish_on(&mut self, zeroed: Option<(Vec<f64>, Vec<f64>)>) -> (Vec<f64>, Vec<f64>) {
        self.flush();
        let n = self.n;
        let (h, g) = zeroed
            .filter(|(h, g)| h.len() == n * n && g.len() == n)
            .unwrap_or_else(|| (vec![0.0; n * n], vec![0.0; n]));
        debug_assert!(h.iter().chain(&g).all(|v| *v == 0.0), "the sums start on zeros");
        (std::mem::replace(&mut self.h, h), std::mem::replace(&mut self.g, g))
    }

    /// Columns summed over.
    pub fn columns(&self) -> usize {
        self.n
    }
}

/// Add `sums` into `total` entry by entry and zero them: a chunk's finished sums (see
/// [`NormalSums::finish_on`]) added into the totals, left zeroed for the next chunk to start on.
pub fn add_and_clear(total: &mut [f64], sums: &mut [f64]) {
    debug_assert_eq!(total.len(), sums.len());
    for (t, s) in total.iter_mut().zip(sums.iter_mut()) {
        *t += *s;
        *s = 0.0;
    }
}

impl RowTarget for NormalSums {
    fn rows<'a>(&'a mut self, rows: usize, columns: &'a [Range<usize>]) -> TermRows<'a> {
        if self.placed != columns || self.r.len() + rows > BATCH_ROWS {
            self.admit(rows, |sums| {
                for span in columns {
                    sums.assign(span.clone());
                }
            });
            self.placed.clear();
            self.placed.extend_from_slice(columns);
            let local = &self.local;
            self.placed_in_order = (columns.iter().zip(0..u64::BITS))
                .filter(|(span, _)| first_in_order(&local[(*span).clone()]).is_some())
                .fold(0, |bits, (_, i)| bits | 1 << i);
        }
        let (first, width, k) = (self.r.len(), self.width, self.globals.len());
        let block = &mut self.dense[first * width..(first + rows) * width];
        // The term writes its own columns; any other of the batch's must be zero.
        debug_assert!(columns.iter().flat_map(Clone::clone).all(|c| self.local[c] != NONE));
        debug_assert!(
            columns
                .iter()
                .enumerate()
                .all(|(i, a)| columns[..i].iter().all(|b| a.end <= b.start || b.end <= a.start)),
            "the spans of a term overlap: {columns:?}"
        );
        if columns.iter().map(ExactSizeIterator::len).sum::<usize>() < k {
            block.chunks_exact_mut(width).for_each(|row| row[..k].fill(0.0));
        } else if cfg!(debug_assertions) {
            block.chunks_exact_mut(width).for_each(|row| row[..k].fill(f64::NAN));
        }
        TermRows { in_order: self.placed_in_order, ..TermRows::new(block, width, &self.local, columns) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// JᵀWJ and JᵀWr entry by entry, the plain way.
    fn plain(jac: &[f64], w: &[f64], r: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
        let (mut h, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        for (i, row) in jac.chunks_exact(n).enumerate() {
            add_row(&mut h, &mut g, row, w[i], r[i]);
        }
        (h, g)
    }

    /// Add w·row·rowᵀ into `h` (n × n) and w·r·row into `g`, entry by entry.
    fn add_row(h: &mut [f64], g: &mut [f64], row: &[f64], w: f64, r: f64) {
        let n = row.len();
        for a in 0..n {
            g[a] += w * row[a] * r;
            for b in 0..n {
                h[a * n + b] += w * row[a] * row[b];
            }
        }
    }

    /// A term's rows give their columns as one run per row only where the batch holds them in
    /// order: after a term that placed them backwards, or another column between, none.
    #[test]
    fn a_span_of_rows_is_given_only_where_its_columns_are_in_order() {
        let mut sums = NormalSums::new(8);
        let three = [1.0, 2.0, 3.0];
        sums.add(&[6, 5, 4], &[0.0; 9], &three, &three);
        sums.add(&[1], &[0.0; 3], &three, &three);
        let spans = [0..4, 4..8];
        let mut rows = sums.rows(3, &spans);
        assert!(rows.span3(4..7).is_none(), "placed backwards");
        assert!(rows.span3(0..3).is_none(), "column 1 placed before 0 and 2");
        assert!(rows.span3(6..7).is_some() && rows.span3(2..4).is_some(), "placed in order");
        let [x, y, z] = rows.span3(2..4).expect("in order");
        (x[1], y[1], z[0]) = (7.0, 8.0, 9.0);
        // Columns 0, 2 and 3 came after the terms' 6, 5, 4 and 1: places 4, 5 and 6; rows 6 to 8.
        let width = sums.width;
        let written = [sums.dense[6 * width + 6], sums.dense[7 * width + 6], sums.dense[8 * width + 5]];
        assert_eq!(written, [7.0, 8.0, 9.0]);
        // Whole spans the batch knows in order (2..4 at places 5 and 6) or not (4..7): the same.
        sums.close(&three, &three);
        let spans = [2..4, 4..7];
        let mut rows = sums.rows(3, &spans);
        assert_eq!(rows.in_order, 0b01, "only the first span in order");
        assert!(rows.span3(4..7).is_none(), "placed backwards");
        let [x, _, z] = rows.span3(2..4).expect("in order");
        (x[0], z[1]) = (5.0, 6.0);
        assert_eq!([sums.dense[9 * width + 5], sums.dense[11 * width + 6]], [5.0, 6.0]);
    }

    #[test]
    fn terms_on_few_columns_sum_to_the_dense_normal_equations() {
        // 256 terms of 3 rows over 40 columns: each reads columns 0..5, a "session" block of 6
        // (one of five) and sometimes a column seen by no other term; the last batch of 3 rows
        // (too few for the crate's product).
        let n = 40;
        let value = |t: usize, j: usize, c: usize| ((t * 31 + j * 7 + c * 13) as f64 * 0.37).sin();
        let mut jac = Vec::new();
        let (mut r, mut w) = (Vec::new(), Vec::new());
        let mut sums = NormalSums::new(n);
        for t in 0..256 {
            let mut columns: Vec<usize> = (0..5).chain(5 + 6 * (t % 5)..11 + 6 * (t % 5)).collect();
            if t % 7 == 0 {
                columns.push(35 + t % 5);
            }
            let rows = 3;
            let values: Vec<f64> =
                columns.iter().flat_map(|&c| (0..rows).map(move |j| value(t, j, c))).collect();
            let tr: Vec<f64> = (0..rows).map(|j| value(t, j, 99)).collect();
            // Weight 1 for the first terms (a batch that is its own weighted copy), others after
            // (a batch whose weighted copy starts mid-way).
            let tw: Vec<f64> =
                (0..rows).map(|j| if t < 100 { 1.0 } else { 0.5 + value(t, j, 98).abs() }).collect();
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
        // And the plain kernel on the whole Jacobian: the plain order to the last bit.
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
    }

    /// Batches of rows held row-major, one to three of them summed one after the other into the
    /// same sums (as the dense terms' batches are), give the plain sums to 1e-12 relative: 13
    /// columns (not a multiple of the crate's tiles), batches of every weight 1 (no weighted
    /// copy), of weights far from 1 and zero, of zero rows, of fewer rows than the crate's
    /// product takes, rows with a stride past their columns, and column counts of the small
    /// product and of one above.
    #[test]
    fn batches_of_rows_give_the_plain_sums() {
        let value = |i: usize, l: usize| ((i * 19 + l * 23) as f64 * 0.47).sin() * (1.0 + l as f64);
        let mut buffers = GramBuffers::default();
        let batches: [&[usize]; 4] = [&[256], &[256, 256, 63], &[3, 200], &[100, 1, 7]];
        for k in [13, 5, 6, 31] {
            for sizes in batches {
                for width in [k, k + 3] {
                    let (mut h, mut g) = (vec![0.0; k * k], vec![0.0; k]);
                    let (mut jac, mut w, mut r) = (Vec::new(), Vec::new(), Vec::new());
                    for (b, &m) in sizes.iter().enumerate() {
                        let first = w.len();
                        let weight = |i: usize| match (b, i % 4) {
                            (0, _) => 1.0,
                            (_, 0) => 0.0,
                            (_, 1) => 0.05 + value(i, 99).abs(),
                            _ => 1.0,
                        };
                        // Every fifth row of a later batch is zero.
                        let row = |i: usize, l: usize| if b > 0 && i % 5 == 2 { 0.0 } else { value(i, l) };
                        let mut rows = vec![f64::NAN; m * width];
                        for i in first..first + m {
                            for l in 0..k {
                                rows[(i - first) * width + l] = row(i, l);
                                jac.push(row(i, l));
                            }
                            w.push(weight(i));
                            r.push(value(i, 98));
                        }
                        let (wb, rb) = (&w[first..], &r[first..]);
                        add_rows_gram(&mut h, &mut g, (&rows, width, k), wb, rb, &mut buffers);
                    }
                    let (hd, gd) = plain(&jac, &w, &r, k);
                    let scale = hd.iter().chain(&gd).fold(0.0f64, |a, v| a.max(v.abs()));
                    let label = format!("{k} columns, batches {sizes:?}, width {width}");
                    for a in 0..k {
                        assert!(
                            (g[a] - gd[a]).abs() <= 1e-12 * scale,
                            "{label}: g[{a}] {} vs {}",
                            g[a],
                            gd[a]
                        );
                        for c in 0..k {
                            let (ours, theirs) = (h[a * k + c], if c >= a { hd[a * k + c] } else { 0.0 });
                            assert!(
                                (ours - theirs).abs() <= 1e-12 * scale,
                                "{label}: h[{a},{c}] {ours} vs {theirs}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// Terms writing their rows through [`RowTarget::rows`] give the sums of the same terms
    /// given to [`NormalSums::add`] to the bit: batches closed by their rows and by their
    /// columns (terms over spans of 10 of 200 columns beside 8 every term reads, whose new
    /// columns overflow a batch and are assigned again in the next), with weights 1 and others.
    #[test]
    fn rows_written_in_place_give_the_sums_of_added_terms() {
        let n = 200;
        let value = |t: usize, j: usize, c: usize| ((t * 29 + j * 11 + c * 7) as f64 * 0.53).sin();
        let (mut direct, mut added) = (NormalSums::new(n), NormalSums::new(n));
        for t in 0..300 {
            let spans = [0..8, 8 + (t * 13) % 180..18 + (t * 13) % 180];
            let columns: Vec<usize> = spans.iter().flat_map(|s| s.clone()).collect();
            let r: Vec<f64> = (0..3).map(|j| value(t, j, 999)).collect();
            let w: Vec<f64> =
                (0..3).map(|j| if t < 120 { 1.0 } else { 0.3 + value(t, j, 998).abs() }).collect();
            let mut rows = direct.rows(3, &spans);
            for &c in &columns {
                rows.set3(c, [value(t, 0, c), value(t, 1, c), value(t, 2, c)]);
            }
            direct.close(&r, &w);
            let values: Vec<f64> =
                columns.iter().flat_map(|&c| (0..3).map(move |j| value(t, j, c))).collect();
            added.add(&columns, &values, &r, &w);
        }
        let ((h, g), (ha, ga)) = (direct.finish(), added.finish());
        assert!(h.iter().zip(&ha).all(|(a, b)| a.to_bits() == b.to_bits()), "JᵀWJ");
        assert!(g.iter().zip(&ga).all(|(a, b)| a.to_bits() == b.to_bits()), "JᵀWr");
        assert!(h[n + 1] != 0.0 && h[196 * n + 196] != 0.0, "sums over the first and last columns");
    }

    /// Runs of terms over the same spans (the points of one session, their columns placed
    /// once), sessions changing within a batch (new columns zeroed over the rows before them,
    /// the rows of a term that reads less than every column of the batch zeroed), batches over
    /// rows other batches left values in, a drifting session's extra span, and a term of
    /// another kind added between: the sums of the same terms added column by column to the
    /// bit, and the plain sums to 1e-12.
    #[test]
    fn runs_of_terms_over_the_same_spans_give_the_sums_of_added_terms() {
        let n = 60;
        let value = |t: usize, j: usize, c: usize| ((t * 37 + j * 13 + c * 5) as f64 * 0.29).sin();
        let (mut direct, mut added) = (NormalSums::new(n), NormalSums::new(n));
        let (mut jac, mut r_all, mut w_all) = (Vec::new(), Vec::new(), Vec::new());
        let mut plain_row = |columns: &[usize], values: &dyn Fn(usize) -> f64| {
            let mut row = vec![0.0; n];
            columns.iter().for_each(|&c| row[c] = values(c));
            jac.extend(row);
        };
        for t in 0..700 {
            // Sessions of 37 points: 8 arm columns, the session's 6 frame columns, 3 tool
            // columns at the end (places after the frame's: columns before them in a batch's
            // next session), 2 drift columns for one session.
            let s = t / 37 % 6;
            let drift = if s == 3 { 50..52 } else { 0..0 };
            let spans = [0..8, 8 + 6 * s..14 + 6 * s, 57..60, drift];
            let columns: Vec<usize> = spans.iter().flat_map(Clone::clone).collect();
            let r: Vec<f64> = (0..3).map(|j| value(t, j, 999)).collect();
            let w: Vec<f64> =
                (0..3).map(|j| if t % 200 < 90 { 1.0 } else { 0.2 + value(t, j, 998).abs() }).collect();
            let mut rows = direct.rows(3, &spans);
            for &c in &columns {
                rows.set3(c, [value(t, 0, c), value(t, 1, c), value(t, 2, c)]);
            }
            direct.close(&r, &w);
            let values: Vec<f64> =
                columns.iter().flat_map(|&c| (0..3).map(move |j| value(t, j, c))).collect();
            added.add(&columns, &values, &r, &w);
            for j in 0..3 {
                plain_row(&columns, &|c| value(t, j, c));
            }
            r_all.extend(&r);
            w_all.extend(&w);
            if t % 50 == 25 {
                let (columns, r, w) = ([2, 45, 46], [value(t, 5, 997)], [1.0]);
                let values = columns.map(|c| value(t, 5, c));
                direct.add(&columns, &values, &r, &w);
                added.add(&columns, &values, &r, &w);
                plain_row(&columns, &|c| value(t, 5, c));
                r_all.extend(r);
                w_all.extend(w);
            }
        }
        let ((h, g), (ha, ga)) = (direct.finish(), added.finish());
        assert!(h.iter().zip(&ha).all(|(a, b)| a.to_bits() == b.to_bits()), "JᵀWJ");
        assert!(g.iter().zip(&ga).all(|(a, b)| a.to_bits() == b.to_bits()), "JᵀWr");
        let (hd, gd) = plain(&jac, &w_all, &r_all, n);
        for a in 0..n {
            assert!((g[a] - gd[a]).abs() < 1e-12 * (1.0 + gd[a].abs()), "g[{a}]");
            for b in a..n {
                let (ours, theirs) = (h[a * n + b], hd[a * n + b]);
                assert!(
                    (ours - theirs).abs() < 1e-12 * (1.0 + theirs.abs()),
                    "h[{a},{b}] {ours} vs {theirs}"
                );
            }
        }
        assert!(h[50 * n + 51] != 0.0 && h[8 * n + 59] != 0.0, "the drift's and the frames' sums");
    }

    /// A term reading more columns than a batch spans gets a batch of wider rows (after terms
    /// of fewer columns, and before them again).
    #[test]
    fn a_term_wider_than_a_batch_is_summed() {
        let n = 130;
        let value = |t: usize, j: usize, c: usize| ((t * 31 + j * 7 + c * 13) as f64 * 0.41).cos();
        let mut sums = NormalSums::new(n);
        let (mut jac, mut r, mut w) = (Vec::new(), Vec::new(), Vec::new());
        for t in 0..40 {
            let columns: Vec<usize> =
                if t % 10 == 5 { (0..120).collect() } else { (t % 7..t % 7 + 9).collect() };
            let values: Vec<f64> =
                columns.iter().flat_map(|&c| (0..3).map(move |j| value(t, j, c))).collect();
            let tr: Vec<f64> = (0..3).map(|j| value(t, j, 200)).collect();
            let tw = [1.0, if t > 20 { 0.7 } else { 1.0 }, 1.0];
            for j in 0..3 {
                let mut row = vec![0.0; n];
                for &c in &columns {
                    row[c] = value(t, j, c);
                }
                jac.extend(row);
            }
            r.extend(&tr);
            w.extend(tw);
            sums.add(&columns, &values, &tr, &tw);
        }
        let (h, g) = sums.finish();
        let (hd, gd) = plain(&jac, &w, &r, n);
        for a in 0..n {
            assert!((g[a] - gd[a]).abs() < 1e-12 * (1.0 + gd[a].abs()), "g[{a}]");
            for b in a..n {
                assert!(
                    (h[a * n + b] - hd[a * n + b]).abs() < 1e-12 * (1.0 + hd[a * n + b].abs()),
                    "h[{a},{b}]"
                );
            }
        }
    }

    /// Uᵀr four rows at a time is the sums of one row at a time to the bit, for row counts with
    /// every remainder, onto sums already there, with a row stride past the columns.
    #[test]
    fn the_transposed_product_four_rows_at_a_time_is_the_plain_one() {
        let value = |i: usize, l: usize| ((i * 11 + l * 17) as f64 * 0.71).sin() * (1.0 + l as f64);
        for (m, k, stride) in
            [(1, 3, 3), (2, 7, 9), (3, 7, 7), (4, 5, 8), (7, 13, 13), (9, 1, 2), (256, 35, 96)]
        {
            let u: Vec<f64> = (0..(m - 1) * stride + k).map(|e| value(e / stride, e % stride)).collect();
            let r: Vec<f64> = (0..m).map(|i| value(i, 99)).collect();
            let mut plain: Vec<f64> = (0..k).map(|l| value(1000, l)).collect();
            let mut ours = plain.clone();
            for (ui, ri) in u.chunks(stride).zip(&r) {
                plain.iter_mut().zip(&ui[..k]).for_each(|(gl, v)| *gl += v * ri);
            }
            add_transposed(&mut ours, (&u, stride, k), &r);
            assert!(ours.iter().zip(&plain).all(|(a, b)| a.to_bits() == b.to_bits()), "{m} × {k}");
        }
    }

    /// The product by column blocks gives the whole square's sums to the bit (the same sums in
    /// the same order), for column counts of one, two and three blocks, a row-strided D (as a
    /// batch holds it) and weights.
    #[test]
    fn the_block_triangle_is_the_square_to_the_bit() {
        let value = |i: usize, l: usize| ((i * 13 + l * 31) as f64 * 0.43).cos() * (1.0 + l as f64);
        let mut product = Vec::new();
        for (m, k) in [(40, 12), (256, 24), (97, 47), (256, 48), (200, 61), (256, 96)] {
            let width = k + 5;
            let d: Vec<f64> = (0..m * width).map(|e| value(e / width, e % width)).collect();
            let u: Vec<f64> = d.iter().enumerate().map(|(e, v)| v * (0.5 + (e / width % 3) as f64)).collect();
            let r: Vec<f64> = (0..m).map(|i| value(i, 97)).collect();
            let dv = DMatrixView::from_slice_with_strides(&d[..(m - 1) * width + k], m, k, width, 1);
            let (mut h, mut g) = (vec![0.0; k * k], vec![0.0; k]);
            product_into(&mut g, (&u, width, k), &dv, &r, &mut product);
            add_upper(&mut h, &product, k);
            let ut = DMatrixView::from_slice_with_strides(&u[..(m - 1) * width + k], k, m, 1, width);
            let mut square = nalgebra::DMatrix::zeros(k, k);
            square.gemm(1.0, &ut, &dv, 0.0);
            for p in 0..k {
                for q in p..k {
                    assert_eq!(h[p * k + q].to_bits(), square[(p, q)].to_bits(), "{m} × {k}: h[{p},{q}]");
                }
            }
        }
    }

    /// The dense product's sums are the plain triple loop's to 1e-12 relative, on blocks whose
    /// sizes are not multiples of any kernel's tile (one row, one column, odd counts, fewer than
    /// nalgebra's threshold for the product and more), with zero weights and zero columns, given
    /// column-major packed and with a stride, added onto sums already there.
    #[test]
    fn the_dense_product_gives_the_plain_sums() {
        let value = |i: usize, l: usize| ((i * 17 + l * 29) as f64 * 0.61).sin() * (1.0 + l as f64);
        let mut buffers = GramBuffers::default();
        for (m, k) in
            [(1, 1), (7, 1), (1, 9), (5, 5), (6, 6), (13, 3), (255, 31), (257, 37), (1575, 10), (100, 64)]
        {
            let rows: Vec<f64> =
                (0..m * k).map(|e| if e % k == k / 2 && k > 2 { 0.0 } else { value(e / k, e % k) }).collect();
            let w: Vec<f64> =
                (0..m).map(|i| if i % 5 == 3 { 0.0 } else { 0.5 + value(i, 99).abs() }).collect();
            let r: Vec<f64> = (0..m).map(|i| value(i, 98)).collect();
            let (mut hd, mut gd) = plain(&rows, &w, &r, k);
            let start = |e: usize| (e as f64 * 0.1).cos();
            hd.iter_mut().enumerate().for_each(|(e, v)| *v += start(e));
            gd.iter_mut().enumerate().for_each(|(e, v)| *v += start(e));
            let scale = hd.iter().chain(&gd).fold(0.0f64, |a, v| a.max(v.abs()));
            // Column-major with a stride longer than the column, as a batch holds it.
            let stride = m + 3;
            let mut columns = vec![f64::NAN; stride * k];
            for i in 0..m {
                for l in 0..k {
                    columns[l * stride + i] = rows[i * k + l];
                }
            }
            let packed: Vec<f64> =
                (0..k).flat_map(|l| columns[l * stride..l * stride + m].to_vec()).collect();
            for (data, stride) in [(&columns, stride), (&packed, m)] {
                let (mut h, mut g): (Vec<f64>, Vec<f64>) =
                    ((0..k * k).map(start).collect(), (0..k).map(start).collect());
                add_upper(&mut h, columns_product(&mut g, (data, stride, k), &w, &r, &mut buffers), k);
                for a in 0..k {
                    assert!((g[a] - gd[a]).abs() <= 1e-12 * scale, "{m} × {k}: g[{a}] {} vs {}", g[a], gd[a]);
                    for b in a..k {
                        let (ours, theirs) = (h[a * k + b], hd[a * k + b]);
                        assert!(
                            (ours - theirs).abs() <= 1e-12 * scale,
                            "{m} × {k}: h[{a},{b}] {ours} vs {theirs}"
                        );
                    }
                    for b in 0..a {
                        assert_eq!(h[a * k + b], start(a * k + b), "the lower triangle is left alone");
                    }
                }
            }
        }
    }
}
