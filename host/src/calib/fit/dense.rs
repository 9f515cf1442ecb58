//! Calibration without block unknowns (artefact distances): identifiability at the nominal
//! values and again at the solution, the passes, the seeded restarts and the covariance.

use super::*;

pub(super) fn calibrate_dense(
    nominal: &ArmModel,
    pieces: &Pieces,
    options: &SolveOptions,
) -> Result<Fit, CalibError> {
    let all: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
    let (full, jac) = check_dense(pieces, &all)?;
    let nominal_model = &pieces.model;
    let all_ranges: Vec<f64> = all.iter().map(|&id| pieces.range(id)).collect();
    let before = identify::analyse(&jac, &all, &all_ranges);
    let (kept, _) = identify::base_columns(&jac, all.len(), &all_ranges);
    let mut estimated: Vec<ParamId> = kept.iter().map(|&c| all[c]).collect();
    let solver_options = SolverOptions { loss: pieces.resolved.loss, ..options.solver };
    let seed = pieces.resolved.seed;
    let frames = vec![Frame::identity(); pieces.data.blocks.len()];
    let mut pass = 0;
    let (problem, best, starts) = loop {
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
        let (nominal_start, mut starts) =
            solve_from_starts(&problem, &x_nominal, &lower, &upper, &solver_options, seed, 0..=0);
        let (_, jac) = jacobian_at(&problem, &nominal_start.x);
        let (kept, dropped) =
            identify::base_columns(&arm_columns(&jac, n, estimated.len()), estimated.len(), &ranges);
        if dropped.is_empty() || pass >= MAX_IDENTIFIABILITY_PASSES {
            let mut best = nominal_start;
            let restarts = pieces.resolved.restarts;
            if restarts > 0 {
                let (restarted, more) = solve_from_starts(
                    &problem,
                    &x_nominal,
                    &lower,
                    &upper,
                    &solver_options,
                    seed,
                    1..=restarts,
                );
                starts.extend(more);
                if restarted.cost < best.cost {
                    best = restarted;
                }
            }
            break (problem, best, starts);
        }
        estimated = kept.iter().map(|&c| estimated[c]).collect();
    };
    let fixed: Vec<ParamId> = all.iter().filter(|id| !estimated.contains(id)).copied().collect();
    let state = problem.state(&best.x);
    let model = state.model;
    let (r, jac) = jacobian_at(&problem, &best.x);
    let mut x_full = model.free_values();
    x_full.resize(full.layout.unknowns(), 0.0);
    let (_, full_jac) = jacobian_at(&full, &x_full);
    let after =
        identify::analyse(&arm_columns(&full_jac, full.layout.unknowns(), all.len()), &all, &all_ranges);
    let loss = pieces.resolved.loss;
    let n = problem.layout.unknowns();
    let dof = (r.len() as f64 - n as f64).max(1.0);
    let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
    let variance = r.iter().zip(&weights).map(|(v, w)| w * v * v).sum::<f64>() / dof;
    let cov = identify::covariance(&jac, &weights, n, variance);
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
    })
}

/// The first `arm` columns of a row-major Jacobian of `n` columns.
pub(super) fn arm_columns(jac: &[f64], n: usize, arm: usize) -> std::borrow::Cow<'_, [f64]> {
    if n == arm {
        return std::borrow::Cow::Borrowed(jac);
    }
    std::borrow::Cow::Owned(jac.chunks_exact(n.max(1)).flat_map(|row| row[..arm].iter().copied()).collect())
}
