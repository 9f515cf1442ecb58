//! Calibration with block unknowns (instrument sessions' frames, floated tools, drifts): the
//! frames at their closed form, identifiability with them projected out, the passes re-centring
//! them, and the covariance.

use super::*;
use crate::model::effects::mass;
use crate::model::FreeParam;
use std::cell::{RefCell, RefMut};

/// A solution with frames: the model, each block's frame, each group's tool, the probe and the
/// drifts, with its cost, iterations and how its last pass stopped.
#[derive(Clone)]
pub(super) struct Solved {
    pub(super) model: ArmModel,
    pub(super) frames: Vec<Frame>,
    pub(super) tools: Vec<Vector3<f64>>,
    pub(super) probe: Option<Matrix3<f64>>,
    pub(super) drifts: Vec<Vec<f64>>,
    pub(super) outcome: StartOutcome,
    /// The last pass' residuals at the solution and, when its last Jacobian evaluation was there,
    /// its normal matrix (see [`solver::Solution::normal_at_x`]).
    pub(super) at_solution: Option<(Vec<f64>, Option<nalgebra::DMatrix<f64>>)>,
}

impl Solved {
    /// Not solved yet: `model` with `frames` and the probe at `probe`, tools and drifts zero.
    pub(super) fn at(
        model: ArmModel,
        frames: Vec<Frame>,
        probe: Option<Matrix3<f64>>,
        data: &Observations,
    ) -> Solved {
        Solved {
            model,
            frames,
            tools: vec![Vector3::zeros(); data.groups.len()],
            probe,
            drifts: vec![Vec::new(); data.blocks.len()],
            outcome: unsolved(0),
            at_solution: None,
        }
    }
}

/// What calibrations from the nominal values of one arm on the same data share: each block's
/// frame at its closed form and each session's orientation spread (both of the arm's values
/// alone), and the tool point's first fit (see [`calibrate_framed`]) for the tool bounds it was
/// solved with, each taken once when first asked for. A run's check of its data takes the
/// frames, its calibration the rest; its tool-only reference (the same values, fewer other
/// parameters free) starts with all of them. Only the arm's values are checked: it is the
/// crate's, given only to calls on the same data with the same options (a run's).
#[derive(Default)]
pub(crate) struct ToolFirstFit(pub(super) RefCell<Option<KeptStart>>);

/// The start [`ToolFirstFit`] keeps for one arm's values.
pub(super) struct KeptStart {
    /// The arm's values (no free parameters) the start is of.
    values: ArmModel,
    /// Each block's frame at its closed form for these values, once asked for.
    frames: Option<Vec<Frame>>,
    /// Each framed session's orientation spread (name, degrees), once asked for.
    spreads: Option<Vec<(String, f64)>>,
    /// The tool point's fit with the tool bounds it had.
    pub(super) tool_fit: Option<(Vec<FreeParam>, Solved)>,
}

impl ToolFirstFit {
    /// The start kept for `pieces`' arm values: an empty one, in place of what was kept, when
    /// that was of other values.
    fn kept(&self, pieces: &Pieces) -> RefMut<'_, KeptStart> {
        let values = ArmModel { free: Vec::new(), ..pieces.model.clone() };
        let mut kept = self.0.borrow_mut();
        if kept.as_ref().is_some_and(|k| k.values != values) {
            *kept = None;
        }
        RefMut::map(kept, |k| {
            k.get_or_insert_with(|| KeptStart { values, frames: None, spreads: None, tool_fit: None })
        })
    }

    /// Each block's frame at its closed form for `pieces`' arm (kept).
    pub(super) fn closed_form_frames(&self, pieces: &Pieces) -> Vec<Frame> {
        let mut kept = self.kept(pieces);
        kept.frames.get_or_insert_with(|| pieces.closed_form_frames(&pieces.model)).clone()
    }

    /// The orientation spread of each framed block of `pieces` on its arm (kept).
    pub(super) fn spreads(&self, pieces: &Pieces) -> Vec<(String, f64)> {
        let (model, data) = (&pieces.model, pieces.data);
        let spreads_of = || {
            (0..data.blocks.len())
                .filter(|&b| pieces.framed[b])
                .map(|b| (data.block_name(b), orientation_spread_deg(model, data, b)))
                .collect()
        };
        self.kept(pieces).spreads.get_or_insert_with(spreads_of).clone()
    }

    /// The tool point's fit over `tool` from `start` on `pieces` (closed-form frames of its
    /// model): the kept one when its tool bounds are `pieces`', else solved (and kept).
    fn solve(&self, pieces: &Pieces, tool: &[ParamId], start: Solved) -> Solved {
        let bounds: Vec<FreeParam> =
            pieces.model.free.iter().filter(|f| tool.contains(&f.id)).copied().collect();
        if let Some((_, solved)) = self.kept(pieces).tool_fit.as_ref().filter(|f| f.0 == bounds) {
            // The same point, of this calibration's model (its own free set).
            let mut solved = solved.clone();
            solved.model.free.clone_from(&pieces.model.free);
            return solved;
        }
        let solved = solve_framed(pieces, tool, start, 0);
        self.kept(pieces).tool_fit = Some((bounds, solved.clone()));
        solved
    }
}

/// Start `number`'s outcome before its solve.
fn unsolved(number: usize) -> StartOutcome {
    StartOutcome {
        start: number,
        initial_cost: f64::NAN,
        final_cost: f64::INFINITY,
        iterations: 0,
        stop: StopReason::NoProgress,
    }
}

/// Solve for `estimated` from `start` (its arm, frames, tools, probe and drifts); again from its
/// solution with the frames' rotations (and the probe's) re-centred, while a solve stops without
/// converging (up to [`PASSES`] passes).
pub(super) fn solve_framed(pieces: &Pieces, estimated: &[ParamId], start: Solved, number: usize) -> Solved {
    solve_framed_from(pieces, estimated, start, number, |_: &Problem, _: &[f64]| None)
}

/// [`solve_framed`], the first pass' normal equations and cost at `start` given by `first` (from
/// the session sums of the solution it starts at) when it can give them.
pub(super) fn solve_framed_from(
    pieces: &Pieces,
    estimated: &[ParamId],
    start: Solved,
    number: usize,
    first: impl FnOnce(&Problem, &[f64]) -> Option<KnownStart>,
) -> Solved {
    let options = SolverOptions { loss: pieces.resolved.loss, ..FRAMED_SOLVER };
    let mut s = Solved { outcome: unsolved(number), ..start };
    let mut last_cost = f64::INFINITY;
    let mut first = Some(first);
    for pass in 0..PASSES {
        let problem = pieces.problem(estimated.to_vec(), &s.model, &s.frames, s.probe);
        let n = problem.layout.unknowns();
        let x0 = pieces.x_of(&problem, &s.model, &s.frames, &s.tools, &s.drifts);
        let (lower, upper) = pieces.bounds(estimated, n);
        let given = first.take().and_then(|known| known(&problem, &x0));
        let solution = solver::solve_from(&problem, &x0, &lower, &upper, &options, given);
        if pass == 0 {
            s.outcome.initial_cost = initial_cost(&problem, &x0, &lower, &upper, &solution, options.loss);
        }
        s.outcome.iterations += solution.iterations;
        s.outcome.stop = solution.stop;
        s.outcome.final_cost = solution.cost;
        let state = problem.state(&solution.x);
        s.tools = state.tools;
        s.frames = state.frames;
        s.probe = s.probe.map(|_| state.probe);
        s.drifts = state.drifts;
        s.model = state.model;
        s.at_solution = Some((solution.residuals, solution.normal_at_x));
        // The rotations' Jacobians are exact at any ω (J_l): a solve that stopped on a tolerance
        // is at the minimum; another pass re-centres one that hit its limit or lost progress.
        let settled = matches!(
            solution.stop,
            StopReason::CostConverged | StopReason::GradientConverged | StopReason::StepConverged
        );
        let converged = (last_cost - solution.cost).abs() <= 1e-9 * solution.cost.max(1e-12);
        last_cost = solution.cost;
        if settled || converged {
            break;
        }
    }
    s
}

/// The start of a refit from `warm`'s solution: its values of the free parameters, each framed
/// block's frame (by name; the closed form for that arm where `warm` has none), each floated
/// group's tool offset and each drift (zero where `warm` has none), and its probe rotation (or
/// the probe's start for that arm).
pub(super) fn warm_start(pieces: &Pieces, warm: &Fit) -> Solved {
    let data = pieces.data;
    let mut model = pieces.model.clone();
    for f in &pieces.model.free {
        model.set(f.id, warm.model.get(f.id));
    }
    let names: Vec<String> = (0..data.blocks.len()).map(|b| data.block_name(b)).collect();
    let known: Vec<Option<Frame>> = (0..data.blocks.len())
        .map(|b| if pieces.framed[b] { warm.frame(&names[b]) } else { Some(Frame::identity()) })
        .collect();
    let frames: Vec<Frame> = if known.iter().all(Option::is_some) {
        known.into_iter().flatten().collect()
    } else {
        let closed = pieces.closed_form_frames(&model);
        known.into_iter().zip(closed).map(|(k, c)| k.unwrap_or(c)).collect()
    };
    let probe = match warm.tool_rotation {
        Some(t) => Some(t.rotation()),
        None => start_probe_rotation(&model, data, &frames),
    }
    .filter(|_| pieces.resolved.orientation_weight_mm_per_rad.is_some());
    let mut start = Solved::at(model, frames, probe, data);
    start.tools = data.groups.iter().map(|g| warm.tool_offset(&g.name)).collect();
    for (b, slot) in pieces.drift.iter().enumerate() {
        let same = |d: &&SessionDrift| Some(d.kind) == slot.map(|s| s.kind) && d.session == names[b];
        if let Some(d) = warm.drifts.iter().find(same) {
            start.drifts[b] = d.rate.clone();
        }
    }
    start
}

/// Calibrate with block unknowns from the nominal values, or, given `warm`, from a previous
/// solution of close data or options (the tool point's first fit skipped: `warm` has it). From
/// the nominal values, the closed-form frames, the orientation spreads and the tool point's first
/// fit are `first_fit`'s when it has them for these values, and kept there.
pub(super) fn calibrate_framed(
    nominal: &ArmModel,
    pieces: &Pieces,
    warm: Option<&Fit>,
    sums: Option<&SessionSums>,
    first_fit: &ToolFirstFit,
) -> Result<Fit, CalibError> {
    let data = pieces.data;
    let model = &pieces.model;
    let all: Vec<ParamId> = model.free.iter().map(|f| f.id).collect();
    let (mut start, spreads) = match warm {
        Some(warm) => (warm_start(pieces, warm), warm.orientation_spread_deg.clone()),
        None => {
            let (frames, spreads) = (first_fit.closed_form_frames(pieces), first_fit.spreads(pieces));
            let probe = start_probe_rotation(model, data, &frames)
                .filter(|_| pieces.resolved.orientation_weight_mm_per_rad.is_some());
            (Solved::at(model.clone(), frames, probe, data), spreads)
        }
    };
    // Over every free parameter (their values from `x0`, the rest from the model).
    let full = pieces.problem(all.clone(), model, &start.frames, start.probe);
    let x0 = pieces.x_of(&full, &start.model, &start.frames, &start.tools, &start.drifts);
    // No session turns the tool and no touch pins it: its point is the frames' translation,
    // whatever a small model error makes the Jacobian say; it stays at its nominal value.
    let pinned = data.obs.iter().any(|o| o.landmark().is_some());
    let tool_turns = pinned || spreads.iter().any(|s| s.1 >= CONSTANT_ORIENTATION_DEG);
    // Identifiability at the nominal arm with the tool point (and the probe's rotation, the
    // frames) first fitted to the data: a model's tool point often lies on the last joint's axis
    // (a URDF's tool0 or flange), where that axis' tilt moves no point, while the probe measured
    // is off the axis. Decided at the nominal tool point, the tilt would be held because of a
    // coincidence of the CAD values; decided at the fitted one, only what the data cannot
    // determine is held.
    let tool: Vec<ParamId> = all.iter().copied().filter(|p| matches!(p, ParamId::Tcp(_))).collect();
    // `start` is already the nominal start's solution (see below).
    let mut solved_already = false;
    // The factors identifiability was decided on, with their problem and point.
    let mut factored = None;
    let (before, estimated, fixed, statements) = match warm {
        // A refit keeps the base set of the solution it starts from.
        Some(warm) => {
            // The residuals' finiteness at the start is checked on the solve's own first
            // evaluation there (below): the same point, evaluated once.
            check_rows(&full)?;
            let (estimated, fixed): (Vec<ParamId>, Vec<ParamId>) =
                all.iter().partition(|id| warm.estimated.contains(id));
            (warm.before.clone(), estimated, fixed, warm.statements.clone())
        }
        None => {
            let (full, x) = if tool_turns && !tool.is_empty() {
                // The factors are taken after the tool's fit: at the start only the checks, the
                // residuals' finiteness on that fit's own first evaluation (the same point).
                check_rows(&full)?;
                start = first_fit.solve(pieces, &tool, start);
                if !start.outcome.initial_cost.is_finite() {
                    return Err(CalibError::NonFinite);
                }
                let full = pieces.problem(all.clone(), &start.model, &start.frames, start.probe);
                let x = pieces.x_of(&full, &start.model, &start.frames, &start.tools, &start.drifts);
                (full, x)
            } else {
                (full, x0)
            };
            let factors = Factored::new(&full, &x, check_framed(&full, &x)?, data);
            let (raw, projected) = projected_arm_columns(&full.layout, factors.factors());
            let ranges: Vec<f64> = all.iter().map(|&id| pieces.range(id)).collect();
            // A mass moves a point only through the compliances it loads: every other parameter
            // is decided here, each mass after them where the compliances the data determine
            // are of a typical size (see `effects::mass`).
            let masses: Vec<usize> = (0..all.len()).filter(|&c| matches!(all[c], ParamId::Mass(_))).collect();
            let (kept, _) = identify::base_columns_last(&projected, all.len(), &ranges, &masses);
            let (kept, held, projected) = match masses.is_empty() {
                true => (kept, Vec::new(), projected),
                false => {
                    let probe = mass::probe_model(&start.model, |id| kept.iter().any(|&c| all[c] == id));
                    let full = pieces.problem(all.clone(), &probe, &start.frames, start.probe);
                    let x = pieces.x_of(&full, &probe, &start.frames, &start.tools, &start.drifts);
                    let (_, at_probe) = projected_arm_columns(&full.layout, &check_framed(&full, &x)?);
                    let (kept, held) = identify::add_last(&at_probe, all.len(), &ranges, kept, &masses);
                    (kept, held, at_probe)
                }
            };
            let names: Vec<String> = all.iter().map(|&id| model.param_name(id)).collect();
            let before = identify::analyse_named(&projected, &all, &names, &ranges);
            let is_tool = |c: &usize| matches!(all[*c], ParamId::Tcp(_));
            let estimated: Vec<ParamId> =
                kept.iter().filter(|c| tool_turns || !is_tool(c)).map(|&c| all[c]).collect();
            let fixed: Vec<ParamId> =
                (0..all.len()).filter(|c| !estimated.contains(&all[*c])).map(|c| all[c]).collect();
            let probe_turns = full.layout.rotation_column().is_some();
            let others: Vec<ParamId> =
                fixed.iter().copied().filter(|p| !matches!(p, ParamId::Mass(_))).collect();
            let mut statements =
                identify::explain(&all, &raw, &projected, probe_turns, &others, &spreads, &ranges);
            statements.extend(held.iter().map(|h| {
                let with: Vec<ParamId> = h.with.iter().map(|&k| all[k]).collect();
                mass::held_statement(model, all[h.column], &with)
            }));
            // With the tool point all there is to estimate (no floated tool, no drift) and its
            // first fit stopped at its last evaluation (a negligible step or a vanished
            // gradient), that fit is the nominal start's solve: solving again from its solution
            // would evaluate the same point and stop there.
            let at_minimum =
                matches!(start.outcome.stop, StopReason::StepConverged | StopReason::GradientConverged);
            let nothing_else = !pieces.floated.iter().any(|f| *f) && pieces.drift.iter().all(Option::is_none);
            solved_already =
                tool_turns && !tool.is_empty() && estimated == tool && nothing_else && at_minimum;
            if !solved_already {
                // The tool's first fit only placed the tool point: tools and drifts start at zero.
                start = Solved::at(start.model, start.frames, start.probe, data);
            }
            factored = Some(factors);
            (before, estimated, fixed, statements)
        }
    };
    // Solve from the nominal values (the tool point as first fitted, held parameters at their
    // nominal values), then from the random starts.
    for id in &fixed {
        start.model.set(*id, model.get(*id));
    }
    // The first normal equations from the warm fit's session sums, or from the factors when the
    // solve starts where they were taken.
    let sums = sums.filter(|_| warm.is_some());
    let loss = pieces.resolved.loss;
    let given = |problem: &Problem, x0: &[f64]| match &factored {
        Some(factored) => factored.normal_at(problem, x0, loss),
        None => sums.and_then(|s| s.normal_at_start(pieces, problem)),
    };
    let mut solved =
        if solved_already { start } else { solve_framed_from(pieces, &estimated, start, 0, given) };
    if warm.is_some() && !solved.outcome.initial_cost.is_finite() {
        return Err(CalibError::NonFinite);
    }
    let restarts = pieces.resolved.restarts;
    let mut starts = vec![solved.outcome.clone()];
    if restarts > 0 {
        let x_nominal: Vec<f64> = estimated.iter().map(|&id| model.get(id)).collect();
        let (lower, upper) = pieces.bounds(&estimated, estimated.len());
        let points = start_points(&x_nominal, &lower, &upper, pieces.resolved.seed, 1..=restarts);
        let others: Vec<Solved> = points
            .par_iter()
            .map(|(k, x)| {
                let mut start = model.clone();
                for (id, v) in estimated.iter().zip(x) {
                    start.set(*id, *v);
                }
                let frames = pieces.closed_form_frames(&start);
                let probe = start_probe_rotation(&start, data, &frames)
                    .filter(|_| pieces.resolved.orientation_weight_mm_per_rad.is_some());
                solve_framed(pieces, &estimated, Solved::at(start, frames, probe, data), *k)
            })
            .collect();
        for other in others {
            starts.push(other.outcome.clone());
            if beats(other.outcome.final_cost, solved.outcome.final_cost, TIE_FTOL) {
                solved = other;
            }
        }
    }
    // Uncertainty at the solution (frames, floated tools and drifts marginalised).
    let problem = pieces.problem(estimated.clone(), &solved.model, &solved.frames, solved.probe);
    let loss = pieces.resolved.loss;
    // The solve's last normal matrix when it was taken at the solution. Its frames' rotation
    // columns are those of the pass' own centring, T·(these), T invertible block by block; the
    // inverse's blocks of every other unknown (arm, tools, drifts) do not depend on T, so they
    // equal those of an evaluation centred at the solution. The probe's rotation block would, so
    // with a probe rotation the normal matrix is evaluated again.
    let reused = match solved.at_solution.take() {
        Some((r, Some(normal))) if problem.layout.rotation_column().is_none() => Some((r, normal)),
        _ => None,
    };
    let (r, normal) = reused.unwrap_or_else(|| {
        let x = pieces.x_of(&problem, &solved.model, &solved.frames, &solved.tools, &solved.drifts);
        let mut r = vec![0.0; problem.len()];
        let (normal, _) = problem.normal_equations(&x, &mut r, loss);
        (r, normal)
    });
    let n = problem.layout.unknowns();
    let dof = (r.len() as f64 - n as f64).max(1.0);
    let variance = r.iter().map(|&v| loss.weight(v) * v * v).sum::<f64>() / dof;
    let cov = identify::covariance_of_normal(normal, variance);
    let stats = residual_stats(&problem, &r);
    let tool_rotation =
        problem.layout.rotation_column().zip(solved.probe).map(|(c, rotation)| ToolRotation {
            rotation_vector_deg: rotation_vector(&rotation).map(f64::to_degrees).into(),
            std_deg: cov
                .as_ref()
                .map(|m| [0, 1, 2].map(|k| (m[(c + k, c + k)].max(0.0).sqrt() * 1e-3).to_degrees())),
        });
    let drifts = (0..data.blocks.len())
        .filter_map(|b| {
            let (c, d) = problem.layout.drift(b)?;
            let rate = solved.drifts[b].clone();
            let rate_std = if d.kind.is_scale() {
                cov.as_ref().map_or(0.0, |m| m[(c, c)].max(0.0).sqrt())
            } else {
                length_std(&Vector3::from_column_slice(&rate), &covariance_block(cov.as_ref(), c))
            };
            Some(SessionDrift {
                session: data.block_name(b),
                kind: d.kind,
                rate,
                rate_std,
                unit: d.kind.unit().into(),
                centre: d.centre,
            })
        })
        .collect();
    Ok(Fit {
        estimates: estimates(nominal, &solved.model, &all, &estimated, cov.as_ref()),
        correlations: correlations(nominal, &estimated, cov.as_ref()),
        tool_offsets: floated_tools(&problem, data, &solved.tools, cov.as_ref()),
        rms_mm: stats.distances.or(stats.points).map_or(0.0, |s| s.rms_mm),
        stats,
        options: pieces.resolved,
        cost: solved.outcome.final_cost,
        before,
        after: None,
        statements,
        orientation_spread_deg: spreads,
        estimated,
        fixed,
        iterations: solved.outcome.iterations,
        starts,
        frames: (0..data.blocks.len())
            .filter(|&b| pieces.framed[b])
            .map(|b| (data.block_name(b), solved.frames[b]))
            .collect(),
        drifts,
        tool_rotation,
        model: solved.model,
        encoders: pieces.encoders.clone(),
    })
}
