//! Calibration without block unknowns (artefact distances): identifiability at the nominal
//! values and again at the solution, the passes, the seeded restarts and the covariance.
//!
//! Identifiability reads the column geometry of the Jacobian alone (the norms of its columns and
//! the angles between them), which an R factor of its rows holds: at the nominal values the
//! factor of the dense Jacobian the checks formed, at a solution the groups' factors folded as
//! their rows are evaluated ([`Problem::group_factors`], no m × n matrix). Every check (the base
//! set, the singular values before and after, the base set again at the solution) reads those
//! few rows instead of the m rows. The covariance takes JᵀWJ at the solution from the solve's
//! last evaluation when it was there.

use super::*;
use crate::numerics::qr::r_factor;
use nalgebra::DMatrix;

pub(super) fn calibrate_dense(
    nominal: &ArmModel,
    pieces: &Pieces,
    options: &SolveOptions,
) -> Result<Fit, CalibError> {
    let all: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
    let (full, jac) = check_dense(pieces, &all)?;
    let nominal_model = &pieces.model;
    let all_ranges: Vec<f64> = all.iter().map(|&id| pieces.range(id)).collect();
    let geometry = column_geometry(&jac, all.len());
    let before = identify::analyse(&geometry, &all, &all_ranges);
    let (kept, _) = identify::base_columns(&geometry, all.len(), &all_ranges);
    let mut estimated: Vec<ParamId> = kept.iter().map(|&c| all[c]).collect();
    let solver_options = dense_solver(pieces, options);
    let seed = pieces.resolved.seed;
    let frames = vec![Frame::identity(); pieces.data.blocks.len()];
    let mut pass = 0;
    let (problem, mut best, starts, at_best) = loop {
        if estimated.is_empty() {
            return Err(CalibError::NothingIdentifiable);
        }
        pass += 1;
        let problem = pieces.problem(estimated.clone(), nominal_model, &frames, None);
        let n = problem.layout.unknowns();
        let (lower, upper) = pieces.bounds(&estimated, n);
        let ranges: Vec<f64> = estimated.iter().map(|&id| pieces.range(id)).collect();
        let mut x_nominal: Vec<f64> = estimated.iter().map(|&id| nominal_model.get(id)).collect();
        x_nominal.resize(n, 0.0);
        let (_, nominal_start, mut starts) =
            solve_from_starts(&problem, &x_nominal, (&lower, &upper), &solver_options, seed, 0..=0, None);
        let at_start = geometry_at(&full, &problem, &nominal_start.x)?;
        let columns = positions(&all, &estimated);
        let (kept, dropped) =
            identify::base_columns(&select(&at_start, all.len(), &columns), estimated.len(), &ranges);
        if dropped.is_empty() || pass >= MAX_IDENTIFIABILITY_PASSES {
            let (mut best, mut at_best) = (nominal_start, at_start);
            let restarts = pieces.resolved.restarts;
            if restarts > 0 {
                // One scan in start order from the nominal start: a tie is not transitive, so
                // the restarts' own best compared with it could keep the nominal where a later
                // start is lower than it by more than the tolerance.
                let (kept, solution, more) = solve_from_starts(
                    &problem,
                    &x_nominal,
                    (&lower, &upper),
                    &solver_options,
                    seed,
                    1..=restarts,
                    Some((0, best)),
                );
                starts.extend(more);
                if kept != 0 {
                    at_best = geometry_at(&full, &problem, &solution.x)?;
                }
                best = solution;
            }
            break (problem, best, starts, at_best);
        }
        estimated = kept.iter().map(|&c| estimated[c]).collect();
    };
    let fixed: Vec<ParamId> = all.iter().filter(|id| !estimated.contains(id)).copied().collect();
    let state = problem.state(&best.x);
    let model = state.model;
    let after = identify::analyse(&at_best, &all, &all_ranges);
    let loss = pieces.resolved.loss;
    let n = problem.layout.unknowns();
    let r = &best.residuals;
    let dof = (r.len() as f64 - n as f64).max(1.0);
    let variance = r.iter().map(|&v| loss.weight(v) * v * v).sum::<f64>() / dof;
    // JᵀWJ at the solution: the solve's last, when it was evaluated there.
    let normal = best.normal_at_x.take().unwrap_or_else(|| {
        let mut r = vec![0.0; problem.len()];
        problem.normal_equations(&best.x, &mut r, loss).0
    });
    let cov = identify::covariance_of_normal(normal, variance);
    let stats = residual_stats(&problem, &best.residuals);
    let rms_mm = stats.distances.or(stats.points).map_or(0.0, |s| s.rms_mm);
    let iterations = starts.iter().map(|s| s.iterations).sum();
    Ok(Fit {
        estimates: estimates(nominal, &model, &all, &estimated, cov.as_ref()),
        correlations: correlations(nominal, &estimated, cov.as_ref()),
        model,
        options: pieces.resolved,
        cost: best.cost,
        rms_mm,
        stats,
        before,
        after: Some(after),
        statements: Vec::new(),
        orientation_spread_deg: Vec::new(),
        estimated,
        fixed,
        starts,
        iterations,
        frames: Vec::new(),
        tool_offsets: floated_tools(&problem, pieces.data, &state.tools, cov.as_ref()),
        drifts: Vec::new(),
        tool_rotation: None,
        encoders: pieces.encoders.clone(),
    })
}

/// The solver's settings for a problem without block unknowns: `options.solver` with the
/// problem's loss, each trial point's normal equations evaluated with its residuals
/// ([`SolverOptions::trial_normal`]). Nearly every step of a distance fit is accepted, from a
/// random start too (and each solve stops on a lowered cost), so a trial's residuals would be
/// followed by its normal equations at the same point: one evaluation instead of two, and the
/// normal matrix at the solution for the covariance. The same steps and results.
pub(super) fn dense_solver(pieces: &Pieces, options: &SolveOptions) -> SolverOptions {
    SolverOptions { loss: pieces.resolved.loss, trial_normal: true, ..options.solver }
}

/// The column geometry (row-major, one column per free parameter) of the Jacobian over every
/// free parameter at a solution `x` of `problem` (over some of them, the others at their nominal
/// values): the R factors of its rows folded group by group ([`Problem::group_factors`]) and
/// stacked, without an m × n matrix.
fn geometry_at(full: &Problem, problem: &Problem, x: &[f64]) -> Result<Vec<f64>, CalibError> {
    let mut x_full = problem.state(x).model.free_values();
    x_full.resize(full.layout.unknowns(), 0.0);
    let factors = full.group_factors(&x_full).ok_or(CalibError::NonFinite)?;
    Ok(projected_arm_columns(&full.layout, &factors).0)
}

/// The column of each of `some` among `all`.
fn positions(all: &[ParamId], some: &[ParamId]) -> Vec<usize> {
    some.iter().filter_map(|id| all.iter().position(|a| a == id)).collect()
}

/// The columns `columns` of a row-major matrix of `width` columns, row-major.
fn select(rows: &[f64], width: usize, columns: &[usize]) -> Vec<f64> {
    rows.chunks_exact(width.max(1)).flat_map(|row| columns.iter().map(|&c| row[c])).collect()
}

/// The R factor (row-major, at most `n` × `n`) of a row-major Jacobian of `n` columns: the same
/// inner product of any two columns, so the same column norms, singular values, right singular
/// vectors and base set, from a matrix of n rows instead of m.
fn column_geometry(jac: &[f64], n: usize) -> Vec<f64> {
    if n == 0 || jac.is_empty() {
        return Vec::new();
    }
    let r = r_factor(DMatrix::from_row_slice(jac.len() / n, n, jac));
    r.transpose().as_slice().to_vec()
}
