//! A solve's first normal equations from the group factors its base set was chosen on.
//!
//! A calibration from the nominal values factors the Jacobian of every free parameter at its
//! start, group by group ([`Problem::group_factors`]), to decide what the data determine; the
//! solve then starts at that same point over the parameters kept. The factors hold what its first
//! evaluation would compute: R_gᵀR_g is J_gᵀJ_g over group g's columns (the same inner product of
//! any two columns, to rounding), and each factor carries its rows' Jᵀr and Σ ½r². So the solve
//! takes its first normal equations from them instead of evaluating the Jacobian again.

use super::shared::keys;
use crate::calib::layout::{Layout, State};
use crate::calib::problem::{GroupFactor, Problem};
use crate::data::Observations;
use crate::numerics::solver::{KnownStart, Loss};
use nalgebra::{DMatrix, DVector};

/// The group factors of the Jacobian of every free parameter at a point, with what they need to
/// serve a solve over some of those parameters there.
pub(super) struct Factored<'d> {
    /// The layout of the factors' problem.
    layout: Layout,
    /// Its values at the point.
    state: State,
    /// Its observations.
    data: &'d Observations,
    factors: Vec<GroupFactor>,
}

impl<'d> Factored<'d> {
    /// `factors` of `full` (a problem of `data`) at `x`.
    pub(super) fn new(full: &Problem, x: &[f64], factors: Vec<GroupFactor>, data: &'d Observations) -> Self {
        debug_assert!(std::ptr::eq(full.data(), data));
        Factored { layout: full.layout.clone(), state: full.state(x), data, factors }
    }

    /// The factors.
    pub(super) fn factors(&self) -> &[GroupFactor] {
        &self.factors
    }

    /// The normal matrix, gradient and cost of `problem` at `x0` from the factors, each over the
    /// columns `problem` shares with theirs. `None` unless the two are the same point (every value
    /// the terms read equal), of the same observations, every column of `problem` is one of the
    /// factors' problem's, and every residual has weight 1 under `loss` there (the factors' rows
    /// are unweighted).
    pub(super) fn normal_at(&self, problem: &Problem, x0: &[f64], loss: Loss) -> Option<KnownStart> {
        let unweighted = self.factors.iter().all(|f| loss.weight(f.largest_residual) == 1.0);
        if !unweighted
            || !std::ptr::eq(self.data, problem.data())
            || !same_point(&self.state, &problem.state(x0))
        {
            return None;
        }
        let into = self.column_map(problem)?;
        let n = problem.layout.unknowns();
        let (mut h, mut g, mut cost) = (DMatrix::zeros(n, n), DVector::zeros(n), 0.0);
        for f in &self.factors {
            let gram = f.r.tr_mul(&f.r);
            let at: Vec<(usize, usize)> =
                f.columns.iter().enumerate().filter_map(|(i, &c)| into[c].map(|c| (i, c))).collect();
            for &(i, ci) in &at {
                g[ci] += f.gradient[i];
                for &(j, cj) in &at {
                    h[(ci, cj)] += gram[(i, j)];
                }
            }
            cost += f.half_squares;
        }
        Some(KnownStart { normal: h, gradient: g, cost })
    }

    /// Per column of the factors' problem, the column of `problem` that is the same unknown
    /// (none: a parameter `problem` holds); `None` when a column of `problem` is none of theirs.
    fn column_map(&self, problem: &Problem) -> Option<Vec<Option<usize>>> {
        let mut into = vec![None; self.layout.unknowns()];
        let mut covered = vec![false; problem.layout.unknowns()];
        for (b, block) in self.data.blocks.iter().enumerate() {
            let theirs = keys(&problem.layout, b, block.group);
            for (key, c) in keys(&self.layout, b, block.group) {
                if let Some(&(_, mine)) = theirs.iter().find(|(k, _)| *k == key) {
                    into[c] = Some(mine);
                    covered[mine] = true;
                }
            }
        }
        covered.iter().all(|&c| c).then_some(into)
    }
}

/// Whether two states give the terms the same values: the arm's, every frame, tool, drift and
/// the probe's rotation (with the rotations' turns).
fn same_point(a: &State, b: &State) -> bool {
    a.model.free_values() == b.model.free_values()
        && a.frames == b.frames
        && a.frame_turns == b.frame_turns
        && a.tools == b.tools
        && a.probe == b.probe
        && a.probe_turn == b.probe_turn
        && a.drifts == b.drifts
}
