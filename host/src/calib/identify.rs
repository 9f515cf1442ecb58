//! Identifiability: which parameters (and combinations) the data can determine.
//!
//! Each Jacobian column is first scaled by its parameter's plausible range (the width of its
//! bounds), so a column measures how much the residuals move over that range and units do not
//! decide. The singular values σ₁ ≥ … ≥ σ_n give the condition number σ₁/σ_n; a right singular
//! vector whose σ is negligible against σ₁ names an unidentifiable combination, spelled in
//! parameter names and physical units. A column-pivoted Gram–Schmidt (rank-revealing QR) picks a base set of identifiable
//! parameters; the rest are fixed at their current values rather than left to drift.

use crate::model::ParamId;
use nalgebra::{DMatrix, DVector};

/// Column norm, relative to the largest, below which a parameter is taken to move nothing.
pub const ZERO_COLUMN_BELOW: f64 = 1e-9;
/// σ/σ₁ below which a direction is reported unidentifiable and fixed.
pub const UNIDENTIFIABLE_BELOW: f64 = 1e-4;
/// Residual norm of a range-scaled column after projecting out the kept ones, relative to the
/// largest column, below which a parameter is left out of the base set.
pub const BASE_SET_TOLERANCE: f64 = UNIDENTIFIABLE_BELOW;
/// σ/σ₁ below which a direction is at rounding level: two or more such span a null space whose
/// singular vectors rounding chooses, reported in its reduced echelon basis instead.
pub const EXACT_NULL_BELOW: f64 = 1e-10;
/// Entry of an orthonormal null-space basis below which a column is not an echelon pivot.
const ECHELON_PIVOT_BELOW: f64 = 1e-6;
/// σ/σ₁ below which a direction is reported poorly identified.
pub const POORLY_IDENTIFIED_BELOW: f64 = 1e-2;

/// A direction in parameter space the data hardly sees.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Combination {
    /// σ/σ₁ of this direction; `None` below [`EXACT_NULL_BELOW`], where it is zero at rounding
    /// level and its digits are noise (they change with the order of the arithmetic), not a figure.
    pub relative_singular_value: Option<f64>,
    /// Parameters and their share of the direction, in physical units, largest first,
    /// scaled so the largest is ±1.
    pub terms: Vec<(String, f64)>,
    /// Human-readable form, e.g. `length:6 −1.000 mm ↔ tcp.z +1.000 mm`.
    pub text: String,
}

/// Identifiability of a parameter set at one point.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Identifiability {
    /// Parameter names, in column order.
    pub params: Vec<String>,
    /// Singular values of the column-scaled Jacobian, largest first; 0 where below
    /// [`EXACT_NULL_BELOW`] × σ₁ (zero at rounding level).
    pub singular_values: Vec<f64>,
    /// σ₁/σ_n (infinite when rank-deficient, at rounding level included).
    #[serde(deserialize_with = "crate::files::null_as_infinity")]
    pub condition_number: f64,
    /// Directions the data cannot determine at all.
    pub unidentifiable: Vec<Combination>,
    /// Directions the data determines only weakly.
    pub poorly_identified: Vec<Combination>,
}

/// Norms of the range-scaled columns, with columns negligible against the largest set to
/// exactly zero.
fn column_norms(jac: &[f64], n: usize, ranges: &[f64]) -> Vec<f64> {
    if n == 0 {
        // No parameter: no column (and no row to chunk).
        return Vec::new();
    }
    let mut norms = vec![0.0; n];
    for row in jac.chunks_exact(n) {
        for (c, v) in row.iter().enumerate() {
            norms[c] += (v * ranges[c]).powi(2);
        }
    }
    let norms: Vec<f64> = norms.iter().map(|s| s.sqrt()).collect();
    let largest = norms.iter().cloned().fold(0.0, f64::max);
    norms.into_iter().map(|v| if v <= ZERO_COLUMN_BELOW * largest { 0.0 } else { v }).collect()
}

/// The Jacobian restricted to `cols`, each column scaled by its range.
fn scaled(jac: &[f64], n: usize, ranges: &[f64], cols: &[usize]) -> DMatrix<f64> {
    let m = jac.len() / n.max(1);
    DMatrix::from_fn(m, cols.len(), |i, k| jac[i * n + cols[k]] * ranges[cols[k]])
}

fn describe(
    params: &[ParamId],
    names: &[String],
    direction: &[f64],
    relative: f64,
    unidentifiable: bool,
) -> Combination {
    let biggest = direction.iter().fold(0.0_f64, |a, v| a.max(v.abs())).max(1e-300);
    let mut terms: Vec<(&str, ParamId, f64)> = params
        .iter()
        .zip(names)
        .zip(direction)
        .map(|((p, name), v)| (name.as_str(), *p, v / biggest))
        .filter(|(_, _, v)| v.abs() > 0.05)
        .collect();
    // Largest share first as printed (three decimals), ties in the parameters' order: the same
    // text whatever the rounding below the printed digits.
    let printed = |v: f64| (v.abs() * 1000.0).round();
    terms.sort_by(|a, b| printed(b.2).total_cmp(&printed(a.2)));
    if terms.first().is_some_and(|t| t.2 < 0.0) {
        terms.iter_mut().for_each(|t| t.2 = -t.2);
    }
    let text = if terms.len() == 1 {
        let effect = if unidentifiable { "changes no residual" } else { "barely changes the residuals" };
        format!("{} ({effect})", terms[0].0)
    } else {
        terms
            .iter()
            .map(|(name, p, v)| format!("{name} {v:+.3} {}", p.unit()))
            .collect::<Vec<_>>()
            .join(" ↔ ")
    };
    Combination {
        relative_singular_value: (relative >= EXACT_NULL_BELOW).then_some(relative),
        terms: terms.into_iter().map(|(name, _, v)| (name.to_string(), v)).collect(),
        text,
    }
}

/// Analyse a row-major Jacobian (m × `params.len()`); `ranges` are the parameters' plausible
/// ranges (bound widths) in their units.
pub fn analyse(jac: &[f64], params: &[ParamId], ranges: &[f64]) -> Identifiability {
    let names: Vec<String> = params.iter().map(|p| p.to_string()).collect();
    analyse_named(jac, params, &names, ranges)
}

/// [`analyse`] with the parameters written as `names` (a model's names, e.g. `mass:payload`).
pub fn analyse_named(jac: &[f64], params: &[ParamId], names: &[String], ranges: &[f64]) -> Identifiability {
    let n = params.len();
    let mut out = Identifiability {
        params: names.to_vec(),
        singular_values: vec![],
        condition_number: f64::INFINITY,
        unidentifiable: vec![],
        poorly_identified: vec![],
    };
    if n == 0 || jac.is_empty() {
        return out;
    }
    let norms = column_norms(jac, n, ranges);
    // A parameter that moves no residual is unidentifiable on its own.
    for c in (0..n).filter(|&c| norms[c] == 0.0) {
        let mut dir = vec![0.0; n];
        dir[c] = 1.0;
        out.unidentifiable.push(describe(params, names, &dir, 0.0, true));
    }
    let live: Vec<usize> = (0..n).filter(|&c| norms[c] > 0.0).collect();
    if live.is_empty() {
        return out;
    }
    // With fewer rows than columns the thin decomposition lacks the null directions beyond the
    // rows: zero rows make it square (they change no singular value and add those directions).
    let a = scaled(jac, n, ranges, &live);
    let rows = a.nrows().max(live.len());
    let svd = a.resize_vertically(rows, 0.0).svd(false, true);
    let Some(v_t) = svd.v_t else { return out };
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    let sv: Vec<f64> = order.iter().map(|&i| svd.singular_values[i]).collect();
    let top = sv.first().copied().unwrap_or(0.0).max(1e-300);
    // Two or more directions at rounding level span a null space whose singular vectors are any
    // basis of it (rounding picks one): it is reported in its one reduced echelon basis instead.
    let null: Vec<usize> =
        order.iter().zip(&sv).filter(|(_, &s)| s / top < EXACT_NULL_BELOW).map(|(&i, _)| i).collect();
    if null.len() > 1 {
        let basis = DMatrix::from_fn(null.len(), live.len(), |r, k| v_t[(null[r], k)]);
        let a = scaled(jac, n, ranges, &live);
        for w in echelon_rows(basis) {
            let relative = (&a * DVector::from_row_slice(w.as_slice())).norm() / (w.norm() * top);
            let mut dir = vec![0.0; n];
            for (k, &c) in live.iter().enumerate() {
                dir[c] = w[k] * ranges[c];
            }
            out.unidentifiable.push(describe(params, names, &dir, relative, true));
        }
    }
    for (&i, &s) in order.iter().zip(&sv) {
        let relative = s / top;
        if relative >= POORLY_IDENTIFIED_BELOW || (null.len() > 1 && relative < EXACT_NULL_BELOW) {
            continue;
        }
        // Direction in physical units: δq_c = v_c · range_c.
        let mut dir = vec![0.0; n];
        for (k, &c) in live.iter().enumerate() {
            dir[c] = v_t[(i, k)] * ranges[c];
        }
        let combo = describe(params, names, &dir, relative, relative < UNIDENTIFIABLE_BELOW);
        if relative < UNIDENTIFIABLE_BELOW {
            out.unidentifiable.push(combo);
        } else {
            out.poorly_identified.push(combo);
        }
    }
    // A singular value at rounding level is zero: its digits are the arithmetic's order, not the
    // data's, so neither it nor the condition number it would give is a figure.
    let sv: Vec<f64> = sv.into_iter().map(|s| if s / top < EXACT_NULL_BELOW { 0.0 } else { s }).collect();
    let smallest = if live.len() < n || sv.len() < n { 0.0 } else { sv[n - 1] };
    out.condition_number = if smallest > 0.0 { top / smallest } else { f64::INFINITY };
    out.singular_values = sv;
    out
}

/// The reduced row echelon form of the rows of `basis` (k × n, orthonormal rows spanning a
/// subspace), its rows in order of their leading column: each leads with 1 in a column where
/// every other row has 0. It depends on the subspace only, not on the basis given.
fn echelon_rows(mut basis: DMatrix<f64>) -> Vec<nalgebra::RowDVector<f64>> {
    let (k, n) = basis.shape();
    let mut row = 0;
    for c in 0..n {
        if row == k {
            break;
        }
        // A column is a pivot when the rows left reach it: its norm over them (at the first
        // column, the subspace's projection of the axis, whatever the basis) is not below the
        // threshold. Its largest entry among them is the pivot.
        let reach = (row..k).map(|r| basis[(r, c)].powi(2)).sum::<f64>().sqrt();
        let Some(p) = (row..k).max_by(|&a, &b| basis[(a, c)].abs().total_cmp(&basis[(b, c)].abs())) else {
            break;
        };
        if reach < ECHELON_PIVOT_BELOW {
            continue;
        }
        basis.swap_rows(row, p);
        let pivot = basis[(row, c)];
        basis.row_mut(row).scale_mut(1.0 / pivot);
        let lead = basis.row(row).into_owned();
        for r in (0..k).filter(|&r| r != row) {
            let factor = basis[(r, c)];
            for (q, v) in lead.iter().enumerate() {
                basis[(r, q)] -= factor * v;
            }
        }
        row += 1;
    }
    (0..row).map(|r| basis.row(r).into_owned()).collect()
}

/// Split columns into an identifiable base set and the rest, by column-pivoted Gram–Schmidt
/// on the range-scaled Jacobian. Returns (kept, dropped) column indices, each ascending.
pub fn base_columns(jac: &[f64], n: usize, ranges: &[f64]) -> (Vec<usize>, Vec<usize>) {
    let norms = column_norms(jac, n, ranges);
    let live: Vec<usize> = (0..n).filter(|&c| norms[c] > 0.0).collect();
    let largest = norms.iter().cloned().fold(0.0, f64::max);
    let a = scaled(jac, n, ranges, &live);
    let mut residual: Vec<DVector<f64>> = (0..live.len()).map(|k| a.column(k).into_owned()).collect();
    let mut kept = Vec::new();
    let mut remaining: Vec<usize> = (0..live.len()).collect();
    while !remaining.is_empty() {
        // Largest remaining residual norm; ties go to the earlier parameter.
        let (pos, best) = remaining.iter().enumerate().fold((0, -1.0), |acc, (pos, &k)| {
            let v = residual[k].norm();
            if v > acc.1 * (1.0 + 1e-9) {
                (pos, v)
            } else {
                acc
            }
        });
        if best < BASE_SET_TOLERANCE * largest {
            break;
        }
        let k = remaining.remove(pos);
        let q = &residual[k] / best;
        for &o in &remaining {
            let proj = q.dot(&residual[o]);
            residual[o] -= &q * proj;
        }
        kept.push(live[k]);
    }
    kept.sort_unstable();
    let dropped = (0..n).filter(|c| !kept.contains(c)).collect();
    (kept, dropped)
}

/// A column [`base_columns_last`] held: it adds no rank to the base set.
#[derive(Clone, Debug, PartialEq)]
pub struct Held {
    /// The column.
    pub column: usize,
    /// The kept columns it trades against (a share of at least a twentieth of the largest),
    /// largest share first; empty when it moves no residual.
    pub with: Vec<usize>,
}

/// The base set with the columns `last` taken after every other (a mass after the compliances
/// it multiplies, so a scale neither the masses nor the compliances fix is held on the mass):
/// [`base_columns`] of the other columns, then each of `last` in turn, kept when it adds rank to
/// the columns kept so far ([`added_rank`]). Returns the kept columns (ascending) and the held
/// ones of `last`.
pub fn base_columns_last(jac: &[f64], n: usize, ranges: &[f64], last: &[usize]) -> (Vec<usize>, Vec<Held>) {
    let first: Vec<f64> = (0..n).map(|c| if last.contains(&c) { 0.0 } else { ranges[c] }).collect();
    let (kept, _) = base_columns(jac, n, &first);
    add_last(jac, n, ranges, kept, last)
}

/// The columns `last` added in turn to the base set `kept` (see [`base_columns_last`]): the
/// base set with those that add rank (ascending), and the held ones.
pub fn add_last(
    jac: &[f64],
    n: usize,
    ranges: &[f64],
    mut kept: Vec<usize>,
    last: &[usize],
) -> (Vec<usize>, Vec<Held>) {
    let mut held = Vec::new();
    for &c in last {
        let Some(rank) = added_rank(jac, n, ranges, &kept, &[c]).pop() else { continue };
        if rank.adds {
            kept.push(c);
            continue;
        }
        let largest = rank.share.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
        let mut with: Vec<(usize, f64)> = kept
            .iter()
            .zip(&rank.share)
            .filter(|(_, s)| !rank.moves_nothing && largest > 0.0 && s.abs() >= 0.05 * largest)
            .map(|(&k, s)| (k, s.abs()))
            .collect();
        with.sort_by(|a, b| b.1.total_cmp(&a.1));
        held.push(Held { column: c, with: with.into_iter().map(|w| w.0).collect() });
    }
    kept.sort_unstable();
    (kept, held)
}

/// Parameter covariance σ²·(JᵀWJ)⁻¹ from a row-major Jacobian, IRLS weights and the residual
/// variance σ²; `None` when JᵀWJ is singular.
pub fn covariance(jac: &[f64], weights: &[f64], n: usize, variance: f64) -> Option<DMatrix<f64>> {
    let zeros = vec![0.0; weights.len()];
    let (h, _) = crate::numerics::solver::normal_equations(jac, &zeros, weights, n);
    covariance_of_normal(h, variance)
}

/// Parameter covariance σ²·H⁻¹ from the normal matrix H = JᵀWJ; `None` when H is singular.
pub fn covariance_of_normal(h: DMatrix<f64>, variance: f64) -> Option<DMatrix<f64>> {
    h.cholesky().map(|c| c.inverse() * variance)
}

/// Sentences on what the data cannot separate when frames are fitted; `raw` and `projected` are
/// the arm columns before and after the frames (and floated tools, drifts, the probe rotation)
/// are projected out (row-major, `all.len()` columns); `spreads` the orientation spread of each
/// session, degrees; `probe_turns` when a probe's rotation is fitted.
pub fn explain(
    all: &[ParamId],
    raw: &[f64],
    projected: &[f64],
    probe_turns: bool,
    fixed: &[ParamId],
    spreads: &[(String, f64)],
    ranges: &[f64],
) -> Vec<String> {
    use crate::calib::nuisance::tool::CONSTANT_ORIENTATION_DEG;
    let a = all.len();
    let norm = |m: &[f64], stride: usize, c: usize| {
        m.chunks_exact(stride).map(|row| row[c] * row[c]).sum::<f64>().sqrt()
    };
    let mut out = Vec::new();
    let constant: Vec<&str> =
        spreads.iter().filter(|s| s.1 < CONSTANT_ORIENTATION_DEG).map(|s| s.0.as_str()).collect();
    let tool_fixed: Vec<String> =
        fixed.iter().filter(|p| matches!(p, ParamId::Tcp(_))).map(|p| p.to_string()).collect();
    if !constant.is_empty() {
        out.push(format!(
            "the tool orientation is constant (within {CONSTANT_ORIENTATION_DEG}°) in session{} {}: there, the \
             tool point and the base translation are one thing{}",
            if constant.len() == 1 { "" } else { "s" },
            constant.join(", "),
            if probe_turns {
                " (the probe's orientations do not separate them: R_s·R_F·t is one constant vector there)"
            } else {
                ""
            }
        ));
    }
    if !tool_fixed.is_empty() {
        out.push(format!(
            "{} cannot be separated from the session bases' translations (no session turns the tool): held at \
             the nominal value; no figure depends on this split, each session's base absorbs it",
            tool_fixed.join(", ")
        ));
    }
    let largest = (0..a).map(|c| norm(raw, a, c) * ranges[c]).fold(0.0, f64::max).max(1e-300);
    for p in fixed.iter().filter(|p| !matches!(p, ParamId::Tcp(_))) {
        let Some(c) = all.iter().position(|q| q == p) else { continue };
        let (raw, rest) = (norm(raw, a, c) * ranges[c], norm(projected, a, c) * ranges[c]);
        out.push(if raw < ZERO_COLUMN_BELOW * largest {
            format!("{p} moves no measured point: held at its nominal value")
        } else if rest < UNIDENTIFIABLE_BELOW * largest && probe_turns {
            format!(
                "{p} is absorbed by the session bases and the probe's orientation on the flange (a base rotation or \
                 shift, or a turn of the probe with the tool point, reproduces it): held at its nominal value"
            )
        } else if rest < UNIDENTIFIABLE_BELOW * largest {
            format!("{p} is absorbed by the session bases (a base rotation or shift reproduces it): held at its nominal value")
        } else {
            format!("{p} cannot be separated from the other free parameters on this data: held at its nominal value")
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_a_zero_column_and_a_collinear_pair() {
        // Columns: a, b = 2a (collinear), c independent, d zero.
        let rows: Vec<[f64; 4]> = (0..10)
            .map(|i| {
                let t = i as f64;
                [t, 2.0 * t, (t * 0.7).sin(), 0.0]
            })
            .collect();
        let jac: Vec<f64> = rows.iter().flatten().copied().collect();
        let params = [ParamId::Length(0), ParamId::Tcp(2), ParamId::Offset(1), ParamId::Offset(0)];
        let id = analyse(&jac, &params, &[1.0; 4]);
        let texts: Vec<&str> = id.unidentifiable.iter().map(|c| c.text.as_str()).collect();
        assert!(
            texts.iter().any(|t| t.contains("offset:1") && t.contains("changes no residual")),
            "{texts:?}"
        );
        let pair = id.unidentifiable.iter().find(|c| c.terms.len() == 2).expect("collinear pair");
        // δ(length:1) = −2·δ(tcp.z) leaves the residuals unchanged.
        assert!(
            (pair.terms[0].1.abs() - 1.0).abs() < 1e-9 && (pair.terms[1].1.abs() - 0.5).abs() < 1e-6,
            "{:?}",
            pair.terms
        );
        let (kept, dropped) = base_columns(&jac, 4, &[1.0; 4]);
        // The larger of two collinear columns stays in the base set.
        assert_eq!(kept, vec![1, 2]);
        assert_eq!(dropped, vec![0, 3]);
    }

    /// A direction at rounding level (a column that is another's combination, computed with
    /// rounding, so its singular value comes out ~1e-17, not 0) is zero: no singular value and no
    /// condition number of rounding noise is reported as a figure.
    #[test]
    fn a_direction_at_rounding_level_gives_no_figure() {
        let jac: Vec<f64> = (0..12)
            .flat_map(|i| {
                let (a, b) = ((i as f64 * 0.37).sin(), (i as f64 * 1.3).cos() * 3.1);
                [a, b, 0.3 * a + 0.7 * b, (i as f64).sqrt()]
            })
            .collect();
        let params = [ParamId::Length(0), ParamId::Length(1), ParamId::Tcp(0), ParamId::Tcp(1)];
        let id = analyse(&jac, &params, &[1.0; 4]);
        assert_eq!(id.singular_values.len(), 4);
        assert_eq!(id.singular_values[3], 0.0, "{:?}", id.singular_values);
        assert!(id.singular_values[..3].iter().all(|&s| s > EXACT_NULL_BELOW * id.singular_values[0]));
        assert!(id.condition_number.is_infinite(), "{}", id.condition_number);
        assert_eq!(id.unidentifiable.len(), 1);
        assert_eq!(id.unidentifiable[0].relative_singular_value, None);
    }

    /// Fewer residual rows than parameters (one point of a tracker session, say): the directions
    /// beyond the rows are named too, not only the condition number made unbounded.
    #[test]
    fn fewer_rows_than_parameters_name_every_missing_direction() {
        let jac = [1.0, 0.5, 0.0, 2.0, 0.0, 1.0, 3.0, -1.0];
        let params = [ParamId::Length(0), ParamId::Length(1), ParamId::Tcp(0), ParamId::Tcp(1)];
        let id = analyse(&jac, &params, &[1.0; 4]);
        assert!(id.condition_number.is_infinite());
        assert_eq!(id.unidentifiable.len(), 2, "{:?}", id.unidentifiable);
        // Each named direction changes no residual.
        for c in &id.unidentifiable {
            let dir: Vec<f64> = id
                .params
                .iter()
                .map(|name| c.terms.iter().find(|(n, _)| n == name).map_or(0.0, |t| t.1))
                .collect();
            for row in jac.chunks(4) {
                let moved: f64 = row.iter().zip(&dir).map(|(j, d)| j * d).sum();
                assert!(moved.abs() < 1e-9, "{} moves a residual by {moved}", c.text);
            }
        }
    }

    /// A null space of two directions is reported in its one reduced echelon basis, the same
    /// whatever basis the singular value decomposition picks: for columns a, b, a + b and a − b,
    /// δa = (δ(a+b) + δ(a−b))/2 and δb = (δ(a+b) − δ(a−b))/2, whether the rows come as they are,
    /// scaled or mixed by a rotation.
    #[test]
    fn a_null_space_of_two_directions_is_named_in_one_basis() {
        let params = [ParamId::Length(0), ParamId::Length(1), ParamId::Tcp(0), ParamId::Tcp(1)];
        let rows = |turn: f64, scale: f64| -> Vec<f64> {
            let plain: Vec<[f64; 2]> = (0..9).map(|i| [(i as f64).sin(), (0.4 * i as f64).cos()]).collect();
            let (c, s) = (turn.cos(), turn.sin());
            (0..9)
                .flat_map(|i| {
                    let j = (i + 1) % 9;
                    // Rows i and j mixed by a rotation, so the Jacobian's rows differ but not its columns' geometry.
                    let [a, b] = [0, 1].map(|k| scale * (c * plain[i][k] + s * plain[j][k]));
                    [a, b, a + b, a - b]
                })
                .collect()
        };
        let texts = |jac: Vec<f64>| -> Vec<String> {
            let id = analyse(&jac, &params, &[1.0; 4]);
            assert!(
                id.unidentifiable.iter().all(|c| c.relative_singular_value.is_none()),
                "{:?}",
                id.unidentifiable
            );
            id.unidentifiable.into_iter().map(|c| c.text).collect()
        };
        let expected = [
            "length:1 +1.000 mm ↔ tcp.x -0.500 mm ↔ tcp.y -0.500 mm",
            "length:2 +1.000 mm ↔ tcp.x -0.500 mm ↔ tcp.y +0.500 mm",
        ];
        for (turn, scale) in [(0.0, 1.0), (0.3, 1.0), (1.1, 7.0), (2.9, 0.01)] {
            assert_eq!(texts(rows(turn, scale)), expected, "turn {turn}, scale {scale}");
        }
    }

    /// Columns a, b and c = a + b (a scale the "mass" c trades against), d zero: c is held
    /// with a and b named, d held as moving nothing, a and b kept.
    #[test]
    fn a_column_taken_last_is_held_with_what_it_trades_against() {
        let jac: Vec<f64> = (0..12)
            .flat_map(|i| {
                let t = i as f64;
                let (a, b) = (t.sin(), (0.3 * t).cos());
                [a, b, a + b, 0.0]
            })
            .collect();
        let (kept, held) = base_columns_last(&jac, 4, &[1.0; 4], &[2, 3]);
        assert_eq!(kept, vec![0, 1]);
        assert_eq!(held, vec![Held { column: 2, with: vec![0, 1] }, Held { column: 3, with: vec![] }]);
        // Without a, c adds rank and is kept.
        let (kept, held) = base_columns_last(&jac, 4, &[0.0, 1.0, 1.0, 1.0], &[2]);
        assert_eq!((kept, held.len()), (vec![1, 2], 0));
    }

    #[test]
    fn no_parameter_means_no_column_and_no_panic() {
        // A model that frees nothing: residual rows exist but have no column.
        assert_eq!(base_columns(&[], 0, &[]), (vec![], vec![]));
        assert!(analyse(&[], &[], &[]).params.is_empty());
        let jac = [1.0, 2.0];
        assert!(added_rank(&jac, 1, &[1.0], &[], &[0])[0].adds);
    }
}

/// How candidate columns `extra` relate to the identifiable columns `base` (both indices into a
/// row-major m × n Jacobian, ranges as in [`analyse`]). Each extra column is projected on the
/// base columns and on the extras before it: it adds rank when the part left is at least
/// [`BASE_SET_TOLERANCE`] of the largest base column.
pub fn added_rank(jac: &[f64], n: usize, ranges: &[f64], base: &[usize], extra: &[usize]) -> Vec<AddedRank> {
    let m = jac.len() / n.max(1);
    let col = |c: usize| DVector::from_fn(m, |i, _| jac[i * n + c] * ranges[c]);
    let largest = base.iter().chain(extra).map(|&c| col(c).norm()).fold(0.0, f64::max);
    let b = DMatrix::from_fn(m, base.len(), |i, k| jac[i * n + base[k]] * ranges[base[k]]);
    let btb = b.transpose() * &b;
    let mut basis: Vec<DVector<f64>> = Vec::new();
    // Orthonormal basis of the base columns.
    for k in 0..base.len() {
        let mut v = b.column(k).into_owned();
        for q in &basis {
            v -= q * q.dot(&v);
        }
        let norm = v.norm();
        if norm > 1e-12 * largest.max(1e-300) {
            basis.push(v / norm);
        }
    }
    extra
        .iter()
        .map(|&c| {
            let original = col(c);
            let mut v = original.clone();
            for q in &basis {
                v -= q * q.dot(&v);
            }
            let norm = v.norm();
            let adds = norm >= BASE_SET_TOLERANCE * largest;
            if adds {
                basis.push(v / norm);
            }
            let scaled = btb
                .clone()
                .cholesky()
                .map(|ch| ch.solve(&(b.transpose() * &original)))
                .map(|x| x.iter().copied().collect())
                .unwrap_or_else(|| vec![0.0; base.len()]);
            let like = scaled.iter().enumerate().map(|(k, v)| v * ranges[base[k]] / ranges[c]).collect();
            AddedRank {
                adds,
                moves_nothing: original.norm() <= ZERO_COLUMN_BELOW * largest,
                like,
                share: scaled,
            }
        })
        .collect()
}

/// How one candidate column relates to the base columns (see [`added_rank`]).
#[derive(Clone, Debug)]
pub struct AddedRank {
    /// The column adds rank: the parameter is identifiable next to the base set.
    pub adds: bool,
    /// The column is negligible: the parameter changes no residual at all.
    pub moves_nothing: bool,
    /// Least-squares coefficients on the base columns in physical units: one unit of the
    /// candidate moves the residuals like `like[k]` units of base parameter k.
    pub like: Vec<f64>,
    /// The same coefficients on range-scaled columns (share of each base parameter's range
    /// per range of the candidate), for judging which matter.
    pub share: Vec<f64>,
}
