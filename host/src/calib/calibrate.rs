//! Calibration: identifiability, base parameters, seeded restarts, covariance.

use crate::calib::identify::{self, Identifiability};
use crate::calib::objective::{CalibrationProblem, Objective};
use crate::data::{Artefact, Observations};
use crate::model::{ArmModel, ParamId};
use crate::numerics::solver::{self, Loss, Residuals, SolverOptions, StopReason};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Settings of one calibration.
#[derive(Clone, Copy, Debug)]
pub struct CalibrationOptions {
    /// Huber threshold δ, mm (thesis: 1.35 mm).
    pub huber_delta_mm: f64,
    /// Random starts inside the bounds, in addition to the start at the nominal values.
    pub restarts: usize,
    /// Seed of the random starts.
    pub seed: u64,
    /// Residual blocks minimised.
    pub objective: Objective,
    /// Solver settings other than the loss.
    pub solver: SolverOptions,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            huber_delta_mm: 1.35,
            restarts: 8,
            seed: 1,
            objective: Objective::Distance,
            solver: SolverOptions::default(),
        }
    }
}

/// Why a calibration could not run.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// Too few distances for the free parameters.
    #[error("{pairs} landmark pairs cannot determine {params} parameters: touch more landmarks per placement and repeat")]
    TooFewPairs {
        /// Distance residuals available.
        pairs: usize,
        /// Parameters to determine.
        params: usize,
    },
    /// The model has no free parameter.
    #[error("the model has no free parameter: give bounds in its [free] table")]
    NothingFree,
    /// No free parameter changes any distance on these touches.
    #[error(
        "none of the free parameters changes any measured distance: the touches carry no information \
         (all at one pose, or the same joint angles copied into every measurement?)"
    )]
    NothingIdentifiable,
    /// The sessions' joint count differs from the model's.
    #[error("the artefact sessions record {data} encoder angles, the model has {model} joints")]
    JointCount {
        /// Joints in the data.
        data: usize,
        /// Joints of the model.
        model: usize,
    },
    /// The model gives positions that are not finite numbers on these touches.
    #[error("the model gives non-finite tool positions on these touches: check the model's numbers")]
    NonFinite,
}

/// The outcome of one start of the solver.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StartOutcome {
    /// 0 for the nominal start, then 1.. for random starts.
    pub start: usize,
    /// Cost at the start.
    pub initial_cost: f64,
    /// Cost reached.
    pub final_cost: f64,
    /// Jacobian evaluations.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: StopReason,
}

/// How one parameter came out.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Estimate {
    /// Parameter name.
    pub param: String,
    /// Unit of the values.
    pub unit: String,
    /// Nominal value.
    pub nominal: f64,
    /// Calibrated value.
    pub value: f64,
    /// One standard deviation from the covariance, when estimated.
    pub std: Option<f64>,
    /// `estimated`, or `fixed: unidentifiable` when the data cannot determine it.
    pub status: String,
}

/// The result of a calibration.
#[derive(Clone, Debug)]
pub struct Calibration {
    /// The calibrated model (same free set and bounds as the nominal one).
    pub model: ArmModel,
    /// Robust cost at the solution.
    pub cost: f64,
    /// RMS of the distance residuals on the calibration data, mm.
    pub rms_mm: f64,
    /// Identifiability of all free parameters at the nominal values.
    pub before: Identifiability,
    /// Identifiability of all free parameters at the solution.
    pub after: Identifiability,
    /// Parameters fixed because the data cannot determine them.
    pub fixed: Vec<ParamId>,
    /// Parameters estimated.
    pub estimated: Vec<ParamId>,
    /// Estimates with standard deviations.
    pub estimates: Vec<Estimate>,
    /// Parameter pairs correlated beyond ±0.9.
    pub correlations: Vec<(String, String, f64)>,
    /// Every start, in order.
    pub starts: Vec<StartOutcome>,
}

fn jacobian_at(problem: &CalibrationProblem, x: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let m = problem.len();
    let mut r = vec![0.0; m];
    let mut jac = vec![0.0; m * x.len()];
    problem.evaluate(x, &mut r, Some(&mut jac));
    (r, jac)
}

/// Most random restarts a calibration may ask for (the CLI and a RUN read back both check it).
pub const MAX_RESTARTS: usize = 1000;
/// Range of the Huber threshold δ, mm.
pub const HUBER_DELTA_RANGE_MM: (f64, f64) = (0.001, 1000.0);
/// Range of the six-dof objective's lever, mm per radian.
pub const LEVER_RANGE_MM: (f64, f64) = (0.001, 100_000.0);

/// Change of a residual, mm, over a parameter's whole range below which it counts as none.
const NEGLIGIBLE_MM: f64 = 1e-9;

/// Most times the base set is re-checked at a solution and the problem solved again.
const MAX_IDENTIFIABILITY_PASSES: usize = 3;

/// Solve from the nominal values (start 0) or from random points inside the bounds (starts 1..),
/// keeping the lowest cost (the earliest start on a tie). Random start k is the same point
/// whichever starts are run; the starts run in parallel on every core.
fn solve_from_starts(
    problem: &CalibrationProblem,
    x_nominal: &[f64],
    lower: &[f64],
    upper: &[f64],
    options: &CalibrationOptions,
    starts: std::ops::RangeInclusive<usize>,
) -> (solver::Solution, Vec<StartOutcome>) {
    let solver_options = SolverOptions { loss: Loss::Huber(options.huber_delta_mm), ..options.solver };
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let points: Vec<(usize, Vec<f64>)> = (0..=*starts.end())
        .map(|start| {
            let x0: Vec<f64> = if start == 0 {
                x_nominal.to_vec()
            } else {
                lower.iter().zip(upper).map(|(l, u)| l + (u - l) * rng.random::<f64>()).collect()
            };
            (start, x0)
        })
        .filter(|(start, _)| starts.contains(start))
        .collect();
    let solved: Vec<(StartOutcome, solver::Solution)> = points
        .par_iter()
        .map(|(start, x0)| {
            let mut r0 = vec![0.0; problem.len()];
            problem.evaluate(x0, &mut r0, None);
            let s = solver::solve(problem, x0, lower, upper, &solver_options);
            let outcome = StartOutcome {
                start: *start,
                initial_cost: solver_options.loss.cost(&r0),
                final_cost: s.cost,
                iterations: s.iterations,
                stop: s.stop,
            };
            (outcome, s)
        })
        .collect();
    let mut outcomes = Vec::new();
    let mut best: Option<solver::Solution> = None;
    for (outcome, s) in solved {
        outcomes.push(outcome);
        if best.as_ref().is_none_or(|b| s.cost < b.cost) {
            best = Some(s);
        }
    }
    let best = best.unwrap_or_else(|| solver::solve(problem, x_nominal, lower, upper, &solver_options));
    (best, outcomes)
}

/// Solve again for the parameters `fit` estimated, on other data (a landmark or block left out),
/// starting from `fit`'s solution: no identifiability analysis, no restarts, no uncertainty. The
/// leave-one-out refits of the outlier metrics use it; their data differ from `fit`'s by a few
/// touches, so the base set and the basin stay the same.
pub fn refit(
    fit: &Calibration,
    artefact: &Artefact,
    data: &Observations,
    options: &CalibrationOptions,
) -> Result<ArmModel, CalibrationError> {
    solve_warm(&fit.model, &fit.estimated, artefact, data, options)
}

/// Solve for `params` (free in `start`, with its bounds) on `data` from `start`'s values: one
/// warm start, no identifiability analysis, no restarts, no uncertainty. For refits whose base
/// set is already known (leave-one-out refits, the diagnosis' candidate refits).
pub fn solve_warm(
    start: &ArmModel,
    params: &[ParamId],
    artefact: &Artefact,
    data: &Observations,
    options: &CalibrationOptions,
) -> Result<ArmModel, CalibrationError> {
    if !data.obs.is_empty() && start.joints.len() != data.joints {
        return Err(CalibrationError::JointCount { data: data.joints, model: start.joints.len() });
    }
    let problem = CalibrationProblem::new(start, params.to_vec(), artefact, data, options.objective);
    if problem.distance_rows() < params.len() {
        return Err(CalibrationError::TooFewPairs { pairs: problem.distance_rows(), params: params.len() });
    }
    let bounds: Vec<_> = params.iter().filter_map(|id| start.free.iter().find(|f| f.id == *id)).collect();
    let lower: Vec<f64> = bounds.iter().map(|b| b.lower).collect();
    let upper: Vec<f64> = bounds.iter().map(|b| b.upper).collect();
    let x0: Vec<f64> = params.iter().map(|&id| start.get(id)).collect();
    let (solution, _) = solve_from_starts(&problem, &x0, &lower, &upper, options, 0..=0);
    Ok(problem.model_at(&solution.x))
}

/// What [`check_calibration_data`] found usable: the free parameters, their bound widths and the
/// Jacobian at the model's values.
struct Checked<'a> {
    full: CalibrationProblem<'a>,
    all: Vec<ParamId>,
    all_ranges: Vec<f64>,
    jac: Vec<f64>,
}

/// Everything that makes `data` unusable for calibrating `model` before any solving: no free
/// parameter, fewer distances than parameters, non-finite positions, or touches that carry no
/// information. `calibrate` refuses with these errors, and so does `diagnose` on a RUN's data
/// (through [`crate::calib::run::check_run_data`]), with the same messages.
pub fn check_data(
    model: &ArmModel,
    artefact: &Artefact,
    data: &Observations,
    objective: Objective,
) -> Result<(), CalibrationError> {
    check_calibration_data(model, artefact, data, objective).map(|_| ())
}

fn check_calibration_data<'a>(
    nominal: &'a ArmModel,
    artefact: &'a Artefact,
    data: &'a Observations,
    objective: Objective,
) -> Result<Checked<'a>, CalibrationError> {
    if !data.obs.is_empty() && nominal.joints.len() != data.joints {
        return Err(CalibrationError::JointCount { data: data.joints, model: nominal.joints.len() });
    }
    let all: Vec<ParamId> = nominal.free.iter().map(|f| f.id).collect();
    if all.is_empty() {
        return Err(CalibrationError::NothingFree);
    }
    let range_of =
        |id: ParamId| nominal.free.iter().find(|f| f.id == id).map_or(1.0, |f| (f.upper - f.lower).max(1e-9));
    let full = CalibrationProblem::new(nominal, all.clone(), artefact, data, objective);
    if full.distance_rows() < all.len() {
        return Err(CalibrationError::TooFewPairs { pairs: full.distance_rows(), params: all.len() });
    }
    let all_ranges: Vec<f64> = all.iter().map(|&id| range_of(id)).collect();
    let (r0, jac) = jacobian_at(&full, &nominal.free_values());
    if !r0.iter().chain(&jac).all(|v| v.is_finite()) {
        return Err(CalibrationError::NonFinite);
    }
    // Over its whole range, no free parameter moves any residual by a measurable amount.
    let n = all.len();
    if jac.iter().enumerate().all(|(k, v)| (v * all_ranges[k % n]).abs() < NEGLIGIBLE_MM) {
        return Err(CalibrationError::NothingIdentifiable);
    }
    Ok(Checked { full, all, all_ranges, jac })
}

/// Calibrate the free parameters of `nominal` on `data`.
///
/// The identifiable base set is chosen at the nominal values; after solving from the nominal
/// start it is checked again at the solution (a parameter can lose its lever once the model
/// fits, e.g. the tool length when every touch holds the tool vertical) and the problem is
/// solved again without the parameters that became unidentifiable, which stay at their nominal
/// values. The random restarts then run once, on the final base set.
pub fn calibrate(
    nominal: &ArmModel,
    artefact: &Artefact,
    data: &Observations,
    options: &CalibrationOptions,
) -> Result<Calibration, CalibrationError> {
    let Checked { full, all, all_ranges, jac } =
        check_calibration_data(nominal, artefact, data, options.objective)?;
    let range_of =
        |id: ParamId| nominal.free.iter().find(|f| f.id == id).map_or(1.0, |f| (f.upper - f.lower).max(1e-9));
    let before = identify::analyse(&jac, &all, &all_ranges);
    let (kept, _) = identify::base_columns(&jac, all.len(), &all_ranges);
    let mut estimated: Vec<ParamId> = kept.iter().map(|&c| all[c]).collect();
    let mut pass = 0;
    let (problem, best, starts) = loop {
        if estimated.is_empty() {
            return Err(CalibrationError::NothingIdentifiable);
        }
        pass += 1;
        let bounds: Vec<_> =
            estimated.iter().filter_map(|id| nominal.free.iter().find(|f| f.id == *id)).collect();
        let lower: Vec<f64> = bounds.iter().map(|b| b.lower).collect();
        let upper: Vec<f64> = bounds.iter().map(|b| b.upper).collect();
        let ranges: Vec<f64> = estimated.iter().map(|&id| range_of(id)).collect();
        let problem = CalibrationProblem::new(nominal, estimated.clone(), artefact, data, options.objective);
        let x_nominal: Vec<f64> = estimated.iter().map(|&id| nominal.get(id)).collect();
        let (nominal_start, mut starts) =
            solve_from_starts(&problem, &x_nominal, &lower, &upper, options, 0..=0);
        let (_, jac) = jacobian_at(&problem, &nominal_start.x);
        let (kept, dropped) = identify::base_columns(&jac, estimated.len(), &ranges);
        if dropped.is_empty() || pass >= MAX_IDENTIFIABILITY_PASSES {
            let mut best = nominal_start;
            if options.restarts > 0 {
                let (restarted, more) =
                    solve_from_starts(&problem, &x_nominal, &lower, &upper, options, 1..=options.restarts);
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
    let model = problem.model_at(&best.x);
    let (r, jac) = jacobian_at(&problem, &best.x);
    let (_, full_jac) = jacobian_at(&full, &model.free_values());
    let after = identify::analyse(&full_jac, &all, &all_ranges);
    let loss = Loss::Huber(options.huber_delta_mm);
    let n = estimated.len();
    let dof = (r.len() as f64 - n as f64).max(1.0);
    let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
    let variance = r.iter().zip(&weights).map(|(v, w)| w * v * v).sum::<f64>() / dof;
    let cov = identify::covariance(&jac, &weights, n, variance);
    let std_of = |k: usize| cov.as_ref().map(|c| c[(k, k)].max(0.0).sqrt());
    let mut correlations = Vec::new();
    if let Some(c) = &cov {
        for a in 0..n {
            for b in a + 1..n {
                let rho = c[(a, b)] / (c[(a, a)] * c[(b, b)]).sqrt();
                if rho.abs() > 0.9 {
                    correlations.push((estimated[a].to_string(), estimated[b].to_string(), rho));
                }
            }
        }
    }
    let estimates = all
        .iter()
        .map(|&id| {
            let k = estimated.iter().position(|e| *e == id);
            Estimate {
                param: id.to_string(),
                unit: id.unit().to_string(),
                nominal: nominal.get(id),
                value: model.get(id),
                std: k.and_then(std_of),
                status: if k.is_some() { "estimated".into() } else { "fixed: unidentifiable".into() },
            }
        })
        .collect();
    let d = problem.distance_rows();
    let rms_mm = (best.residuals[..d].iter().map(|v| v * v).sum::<f64>() / d as f64).sqrt();
    Ok(Calibration {
        model,
        cost: best.cost,
        rms_mm,
        before,
        after,
        fixed,
        estimated,
        estimates,
        correlations,
        starts,
    })
}
