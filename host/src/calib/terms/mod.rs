//! Residual terms, one kind per file (Ceres' cost functions): each knows one measurement's
//! geometry and reads the tool poses of its observations (computed once per observation, with
//! their derivatives over the arm's columns, and shared by every term that reads them) and the
//! unknowns of its own block (frame, floated tool, drift, the probe's rotation), never the arm.
//!
//! | term | rows | reads | residual |
//! | --- | --- | --- | --- |
//! | [`distance::Distance`] | 1 | two touches of one block | ‖p_a − p_b‖ − D_ab, mm |
//! | [`relative_orientation::RelativeOrientation`] | 4 | the same pair | tool axes and yaw against the pillars', mm via a lever |
//! | [`point::Point`] | 3 | one point, its session's frame, tool, drift | B_s·p − X, mm |
//! | [`orientation::Orientation`] | 3 | one oriented point, its frame, the probe rotation | rotation vector of R_predᵀ·R_meas, mm via σ ratio |
//! | [`point_distance`] | 1 | two frame-free points of one session | ‖p_a − p_b‖ − ‖X_a − X_b‖, mm |
//!
//! A new observation kind is one more file here: a struct implementing [`Term`] and the function
//! that makes its terms from the observations ([`build`] calls it).

pub mod distance;
pub mod orientation;
pub mod point;
pub mod point_distance;
pub mod relative_orientation;

use crate::calib::layout::{Layout, State};
use crate::data::Observations;
use crate::model::kinematics::{PoseDerivative, ToolPose};
use crate::numerics::normal::{RowTarget, TermRows};
use nalgebra::{Matrix3, Vector3};
use wide::f64x2;

/// The tool poses of some observations (those from `first` on) at one evaluation, with their
/// derivatives over the arm's columns when a Jacobian is asked for.
pub struct Poses {
    /// The first observation held.
    pub first: usize,
    /// Per observation from `first`, its pose (`None` for one not asked for).
    pub pose: Vec<Option<ToolPose>>,
    /// Per observation, `arm` derivatives (empty without a Jacobian).
    pub chain: Vec<PoseDerivative>,
    /// Arm columns.
    pub arm: usize,
    /// Whether the derivatives were computed.
    pub jacobian: bool,
}

impl Poses {
    /// Observation `k`'s pose.
    pub fn of(&self, k: usize) -> &ToolPose {
        self.pose[k - self.first].as_ref().expect("the poses of every observation a term reads are computed")
    }

    /// Observation `k`'s derivatives over the arm's columns (`None` without a Jacobian).
    pub fn chain(&self, k: usize) -> Option<&[PoseDerivative]> {
        let at = k - self.first;
        self.jacobian.then(|| &self.chain[at * self.arm..(at + 1) * self.arm])
    }
}

/// The position part of the arm derivatives of some [`Poses`], laid out for rows over the arm's
/// columns: per observation, per pair of consecutive columns c, c + 1, the six values
/// [x_c, x_c+1, y_c, y_c+1, z_c, z_c+1] (an odd last column paired with zeros). A row reads two
/// columns' values per axis from consecutive places, one load each, instead of gathering 3 of
/// every 9 values of each column's [`PoseDerivative`]; laid out once per evaluation, read by
/// every term of the observation (a touch is in a dozen distances).
pub struct ArmPositions {
    first: usize,
    arm: usize,
    pairs: Vec<[f64; 6]>,
}

impl ArmPositions {
    /// The layout of the derivatives of `poses` (`None` without them or without arm columns).
    pub fn of(poses: &Poses) -> Option<ArmPositions> {
        let arm = poses.arm;
        if !poses.jacobian || arm == 0 {
            return None;
        }
        let mut pairs = Vec::with_capacity(poses.pose.len() * arm.div_ceil(2));
        for derivatives in poses.chain.chunks_exact(arm).take(poses.pose.len()) {
            let (whole, last) = derivatives.as_chunks::<2>();
            pairs.extend(whole.iter().map(|[c, d]| [c[0], d[0], c[1], d[1], c[2], d[2]]));
            if let [c] = last {
                pairs.push([c[0], 0.0, c[1], 0.0, c[2], 0.0]);
            }
        }
        Some(ArmPositions { first: poses.first, arm, pairs })
    }

    /// Arm columns.
    pub fn arm(&self) -> usize {
        self.arm
    }

    /// Observation `k`'s pairs of columns.
    pub fn of_observation(&self, k: usize) -> &[[f64; 6]] {
        let count = self.arm.div_ceil(2);
        &self.pairs[(k - self.first) * count..][..count]
    }
}

/// What a term reads at one evaluation.
pub struct TermInput<'a> {
    /// The unknowns turned into values (model, frames, tools, probe rotation, drifts).
    pub state: &'a State,
    /// Where each unknown's columns are.
    pub layout: &'a Layout,
    /// The observations.
    pub data: &'a Observations,
    /// Their tool poses.
    pub poses: &'a Poses,
}

/// The non-zero Jacobian columns of one term's rows: column `columns[k]` holds
/// `values[k * rows .. (k + 1) * rows]`. Reused from term to term.
#[derive(Clone, Default)]
pub struct TermJacobian {
    /// Rows of the term.
    pub rows: usize,
    /// Columns, in the order pushed.
    pub columns: Vec<usize>,
    /// Their derivatives, `rows` per column.
    pub values: Vec<f64>,
}

impl TermJacobian {
    /// Empty, for a term of `rows` rows.
    pub fn reset(&mut self, rows: usize) {
        self.rows = rows;
        self.columns.clear();
        self.values.clear();
    }

    /// Column `column` has the derivatives `values` (one per row).
    pub fn push(&mut self, column: usize, values: &[f64]) {
        self.columns.push(column);
        self.values.extend_from_slice(values);
    }

    /// As [`TermJacobian::push`] for a three-row term (three values written in place: no copy
    /// of a slice per column).
    #[inline]
    pub fn push3(&mut self, column: usize, v: Vector3<f64>) {
        self.columns.push(column);
        self.values.extend([v.x, v.y, v.z]);
    }

    /// As [`TermJacobian::push3`] for the columns `first..`, one per value of `values`.
    #[inline]
    pub fn push3_from(&mut self, first: usize, values: impl ExactSizeIterator<Item = Vector3<f64>>) {
        let (at, count) = (self.values.len(), values.len());
        self.columns.extend(first..first + count);
        self.values.resize(at + 3 * count, 0.0);
        for (out, v) in self.values[at..].chunks_exact_mut(3).zip(values) {
            out.copy_from_slice(v.as_slice());
        }
    }

    /// The derivatives of the k-th column pushed.
    pub fn column(&self, k: usize) -> &[f64] {
        &self.values[k * self.rows..(k + 1) * self.rows]
    }
}

/// Where a three-row term writes its derivatives column by column: its [`TermJacobian`] or its
/// rows in a batch ([`Term::evaluate_into_rows`]); one computation serves both.
pub trait Derivatives3 {
    /// Column `column`'s derivatives (rows 0, 1, 2).
    fn put(&mut self, column: usize, v: Vector3<f64>);
    /// The columns `first..`, one per value of `values`.
    fn put_from(&mut self, first: usize, values: impl ExactSizeIterator<Item = Vector3<f64>>) {
        for (c, v) in (first..).zip(values) {
            self.put(c, v);
        }
    }
    /// The arm's columns `0..chain.len()`: each pose derivative's position part turned by
    /// `rotation`, times `growth`.
    fn put_arm(&mut self, chain: &[PoseDerivative], rotation: &Matrix3<f64>, growth: f64) {
        // Without a drift's growth, no product by 1 per column (the same values).
        if growth == 1.0 {
            self.put_from(0, chain.iter().map(|d| turned(rotation, d)));
        } else {
            self.put_from(0, chain.iter().map(|d| turned(rotation, d) * growth));
        }
    }
}

/// R·dp, dp the position part of `d`, written out (R·v's sums in nalgebra's order) for the
/// loops over columns to compile to plain arithmetic.
#[inline(always)]
fn turned(r: &Matrix3<f64>, d: &PoseDerivative) -> Vector3<f64> {
    Vector3::from_fn(|i, _| r[(i, 0)] * d[0] + r[(i, 1)] * d[1] + r[(i, 2)] * d[2])
}

impl Derivatives3 for TermJacobian {
    #[inline]
    fn put(&mut self, column: usize, v: Vector3<f64>) {
        self.push3(column, v);
    }

    fn put_from(&mut self, first: usize, values: impl ExactSizeIterator<Item = Vector3<f64>>) {
        self.push3_from(first, values);
    }
}

impl Derivatives3 for TermRows<'_> {
    #[inline]
    fn put(&mut self, column: usize, v: Vector3<f64>) {
        self.set3(column, [v.x, v.y, v.z]);
    }

    /// Straight into the three rows' runs when the batch holds the arm's columns in order (no
    /// place looked up per column, two columns at a time: `turned_rows`), else column by
    /// column.
    fn put_arm(&mut self, chain: &[PoseDerivative], rotation: &Matrix3<f64>, growth: f64) {
        let Some(rows) = self.span3(0..chain.len()) else {
            for (c, d) in chain.iter().enumerate() {
                self.put(c, turned(rotation, d) * growth);
            }
            return;
        };
        // Without a drift's growth, no product by 1 per column (the same values).
        if growth == 1.0 {
            turned_rows(rows, chain, rotation, |v| v);
        } else {
            let growth = f64x2::splat(growth);
            turned_rows(rows, chain, rotation, |v| v * growth);
        }
    }
}

/// Rows x, y, z of the columns of `chain` (a value per column in each) from [`turned`] of each
/// pose derivative, its three values then passed through `then`: two columns per `f64x2`, one
/// packed multiply or add serving both (no fused multiply-add: each lane's values are those of
/// its column alone, to the bit); an odd last column is its pair's first lane (the pair made of
/// it twice).
#[inline(always)]
fn turned_rows(
    [x, y, z]: [&mut [f64]; 3],
    chain: &[PoseDerivative],
    rotation: &Matrix3<f64>,
    then: impl Fn(f64x2) -> f64x2,
) {
    let r: [[f64x2; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|k| f64x2::splat(rotation[(i, k)])));
    let pair = |a: &PoseDerivative, b: &PoseDerivative| {
        let [d0, d1, d2] = std::array::from_fn(|k| f64x2::new([a[k], b[k]]));
        r.map(|[r0, r1, r2]| then(r0 * d0 + r1 * d1 + r2 * d2))
    };
    let (pairs, last) = chain.as_chunks::<2>();
    let ((xs, x_last), (ys, y_last), (zs, z_last)) =
        (x.as_chunks_mut(), y.as_chunks_mut(), z.as_chunks_mut());
    let rows = xs.iter_mut().zip(ys.iter_mut()).zip(zs.iter_mut());
    for (((x, y), z), [a, b]) in rows.zip(pairs) {
        [*x, *y, *z] = pair(a, b).map(f64x2::to_array);
    }
    if let ([d], [x], [y], [z]) = (last, x_last, y_last, z_last) {
        [*x, *y, *z] = pair(d, d).map(|v| v.as_array()[0]);
    }
}

/// One residual kind over the observations of one block.
pub trait Term: Send + Sync {
    /// Residual rows.
    fn rows(&self) -> usize;
    /// The block whose unknowns it reads.
    fn block(&self) -> usize;
    /// The observations whose tool poses it reads.
    fn observations(&self) -> &[usize];
    /// Its residuals into `r` (`rows` values); with `jac`, its non-zero Jacobian columns.
    fn evaluate(&self, at: &TermInput<'_>, r: &mut [f64], jac: Option<&mut TermJacobian>);
    /// A one-row term's residual into `r` and its derivatives straight into `row` (one value per
    /// column of a problem whose columns are the arm's alone, every one written: `row` holds
    /// anything before), read from `positions` (the layout of `at`'s pose derivatives) instead
    /// of through a [`TermJacobian`] copied into the row afterwards; `false` when the term reads
    /// other columns or has no such path (the default): the caller then evaluates it.
    fn evaluate_into_row(
        &self,
        _at: &TermInput<'_>,
        _positions: &ArmPositions,
        _r: &mut f64,
        _row: &mut [f64],
    ) -> bool {
        false
    }
    /// As [`Term::evaluate_into_row`] for a problem with block unknowns: its residuals into `r`
    /// and its derivatives straight into rows of `target` (asked for once, over the columns it
    /// reads), instead of through a [`TermJacobian`] scattered into the rows afterwards; `false`,
    /// without asking for rows, when it has no such path (the default).
    fn evaluate_into_rows(&self, _at: &TermInput<'_>, _r: &mut [f64], _target: &mut dyn RowTarget) -> bool {
        false
    }
    /// Whether its rows are positions (mm) rather than orientations weighed into mm.
    fn is_position(&self) -> bool {
        true
    }
    /// The factor its rows carry (1 for a distance; a point's weight against touches in mixed
    /// data; an orientation's mm per radian): a row divided by it is the measurement's error.
    fn weight(&self) -> f64 {
        1.0
    }
}

/// Which terms the calibration minimises.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TermChoice {
    /// Relative orientation of touches (the asymmetric pillars), mm per radian.
    pub relative_orientation_lever_mm: Option<f64>,
    /// A 6-DoF probe's orientations, mm per radian.
    pub orientation_weight_mm_per_rad: Option<f64>,
    /// Weight of an instrument's rows (points, orientations) against distances between touches:
    /// 1 unless both kinds are fitted together (see [`crate::calib::setup::Resolved::point_weight`]).
    pub point_weight: f64,
}

/// Every term of `data`, kind after kind (the order of the rows): distances between touches,
/// their relative orientations, measured points, frame-free distances between points, measured
/// orientations.
pub fn build(data: &Observations, choice: &TermChoice) -> Vec<Box<dyn Term>> {
    // Each kind's terms appended to the kinds before them; the first kind that has terms is
    // kept as made (one kind alone, a tracker's points, is not copied).
    let append = |mut terms: Vec<Box<dyn Term>>, mut more: Vec<Box<dyn Term>>| {
        if terms.is_empty() {
            return more;
        }
        terms.append(&mut more);
        terms
    };
    let pairs = data.landmark_pairs();
    let mut terms = distance::terms(data, &pairs);
    if let Some(lever) = choice.relative_orientation_lever_mm {
        terms = append(terms, relative_orientation::terms(data, &pairs, lever));
    }
    terms = append(terms, point::terms(data, choice.point_weight));
    terms = append(terms, point_distance::terms(data));
    if let Some(weight) = choice.orientation_weight_mm_per_rad {
        terms = append(terms, orientation::terms(data, weight * choice.point_weight));
    }
    terms
}

/// Column `k` (0: position, 1: x axis, 2: z axis) of a pose derivative.
pub fn column(d: &PoseDerivative, k: usize) -> Vector3<f64> {
    Vector3::new(d[3 * k], d[3 * k + 1], d[3 * k + 2])
}

/// Values uniform in [−1, 1) from a xorshift generator started at `state` (not zero): the
/// tests' reproducible randomness.
#[cfg(test)]
pub(crate) fn uniform_signed(mut state: u64) -> impl FnMut() -> f64 {
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The arm's columns turned in the loop written out are nalgebra's matrix-vector products to
    /// the bit (its sums in the same order): the direct rows equal the Jacobian path's.
    #[test]
    fn a_turned_column_is_the_matrix_product() {
        let mut next = uniform_signed(0x2545_f491_4f6c_dd1d_u64);
        for _ in 0..20_000 {
            let r = Matrix3::from_fn(|_, _| next());
            let d: PoseDerivative = std::array::from_fn(|_| next() * 1e3);
            let (turned, product) = (turned(&r, &d), r * Vector3::new(d[0], d[1], d[2]));
            assert!(
                turned.iter().zip(&product).all(|(a, b)| a.to_bits() == b.to_bits()),
                "{turned} {product}"
            );
        }
    }

    /// The arm's columns written into a batch's rows two at a time are those written one column
    /// at a time (each [`turned`] times the growth, through [`Derivatives3::put`]) to the bit, for
    /// odd and even column counts, with and without a growth, with derivatives that are not
    /// finite (a NaN, an infinity) among them.
    #[test]
    fn the_arm_rows_two_columns_at_a_time_are_those_column_by_column() {
        let mut next = uniform_signed(0x9e37_79b9_7f4a_7c15_u64);
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for arm in [0, 1, 2, 3, 13, 14, 25] {
            // The arm's columns at places 2.. of rows of `stride` values (the batch's order).
            let stride = arm + 4;
            let local: Vec<usize> = (2..arm + 2).collect();
            let span = 0..arm;
            let columns = std::slice::from_ref(&span);
            for k in 0..80 {
                let growth = if k % 2 == 0 { 1.0 } else { 1.0 + 1e-4 * next() };
                let r = Matrix3::from_fn(|_, _| next());
                let mut chain: Vec<PoseDerivative> =
                    (0..arm).map(|_| std::array::from_fn(|_| next() * 1e3)).collect();
                if arm > 2 {
                    chain[1][0] = f64::NAN;
                    chain[arm - 1][2] = f64::INFINITY;
                }
                let (mut pairs, mut single) = (vec![0.5; 3 * stride], vec![0.5; 3 * stride]);
                TermRows::new(&mut pairs, stride, &local, columns).put_arm(&chain, &r, growth);
                let mut rows = TermRows::new(&mut single, stride, &local, columns);
                for (c, d) in chain.iter().enumerate() {
                    rows.put(c, turned(&r, d) * growth);
                }
                for (p, (a, b)) in pairs.iter().zip(&single).enumerate() {
                    assert!(same(*a, *b), "{arm} columns, growth {growth}, place {p}: {a} {b}");
                }
            }
        }
    }
}
