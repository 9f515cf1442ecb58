//! Calibration: the checks, identifiability, the solve (passes and seeded restarts) and the
//! covariance, for every kind of observation (Ceres' Solve and Covariance over the problem).
//!
//! Without block unknowns (artefact distances) the identifiable base set is chosen on the dense
//! Jacobian at the nominal values; after solving from the nominal start it is checked again at
//! the solution (a parameter can lose its lever once the model fits, e.g. the tool length when
//! every touch holds the tool vertical) and the problem is solved again without the parameters
//! that became unidentifiable, which stay at their nominal values. The random restarts then run
//! once, on the final base set, and the lowest cost wins (the earliest start on a tie).
//!
//! With block unknowns (instrument sessions), each session's frame starts at its closed form for
//! the nominal arm ([`Frame::fit`]); the tool point (with the probe's rotation and the frames) is
//! first fitted on the nominal arm, and identifiability is decided there, not at a nominal tool
//! point that may lie on the last joint's axis; identifiability sees the frames (they are projected out of
//! the arm's columns, [`Problem::group_factors`], and the solve from that point takes its first
//! normal equations from those factors, `factored`); the tool point is freed (and held at its
//! nominal value when no session turns it: then it and each frame's shift are one thing); the
//! problem is solved, and solved again with the frames' rotations re-centred at the solution
//! (up to [`PASSES`] passes) only when a solve stops without converging. Restarts, when asked for, start the arm at random points inside its bounds, with
//! each frame at its closed form for that arm.

use crate::calib::error::CalibError;
use crate::calib::error_stats::{AngleStats, ErrorStats};
use crate::calib::identify::{self, Identifiability};
use crate::calib::layout::Layout;
use crate::calib::nuisance::drift::{drift_slots, DriftSlot, SessionDrift};
use crate::calib::nuisance::frame::{rotation_vector, Frame, FRAME_UNKNOWNS};
use crate::calib::nuisance::tool::{
    length_std, model_points, orientation_spread_deg, start_probe_rotation, FloatedTool, ToolRotation,
    CONSTANT_ORIENTATION_DEG,
};
use crate::calib::problem::{projected_arm_columns, Problem};
use crate::calib::setup::{Resolved, Setup, SolveOptions};
use crate::calib::terms::{self, Term, TermChoice};
use crate::data::{Encoders, Kind, Observations};
use crate::model::{ArmModel, ParamId};
use crate::numerics::solver::{self, KnownStart, Loss, Residuals, SolverOptions, StopReason, Termination};
use nalgebra::{Matrix3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Half-range of the tool point when the model does not free it and frames are fitted, mm.
pub const TOOL_HALF_RANGE_MM: f64 = 500.0;
/// Most Gauss–Newton passes with frames, each re-centring the frames at their solution.
pub const PASSES: usize = 3;
/// Most times the base set is re-checked at a solution and the problem solved again.
const MAX_IDENTIFIABILITY_PASSES: usize = 3;
/// Change of a residual, mm, over a parameter's whole range below which it counts as none.
const NEGLIGIBLE_MM: f64 = 1e-9;
/// Relative cost difference within which two calibrations of one problem reached the same
/// minimum as far as the solver can tell: the framed solves' function tolerance, and at least
/// the dense solves' (1e-12). A choice between them keeps the earlier on a tie ([`beats`]).
pub(crate) const TIE_FTOL: f64 = 1e-10;
/// Solver settings of each pass when frames are fitted (the passes re-centre between solves).
/// Gauss–Newton steps from a start near the data (the frames at their closed form, or a
/// refit's warm start) are accepted nearly always: each trial point's normal equations are
/// evaluated with its residuals, once, instead of its residuals first and the normal equations
/// again once accepted.
const FRAMED_SOLVER: SolverOptions = SolverOptions {
    loss: Loss::Linear,
    max_iterations: 100,
    ftol: TIE_FTOL,
    xtol: 1e-10,
    gtol: 1e-10,
    termination: Termination::Ceres,
    trial_normal: true,
};

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
    /// `estimated`, or `fixed: unidentifiable` when the data cannot determine it; a run marks an
    /// estimate that ended on a bound `estimated, on its lower bound` (or upper).
    #[serde(default = "estimated")]
    pub status: String,
}

fn estimated() -> String {
    "estimated".into()
}

/// The residuals at the solution, per kind.
#[derive(Clone, Debug, Default)]
pub struct FitStats {
    /// Distance errors between touches, mm.
    pub distances: Option<ErrorStats>,
    /// Lengths of the point errors, mm.
    pub points: Option<ErrorStats>,
    /// Angles of the orientation errors, degrees.
    pub orientations: Option<AngleStats>,
}

/// The result of a calibration.
#[derive(Clone, Debug)]
pub struct Fit {
    /// The calibrated model (same free set and bounds as the one calibrated, the tool point freed
    /// when frames are fitted).
    pub model: ArmModel,
    /// The options as they applied.
    pub options: Resolved,
    /// Cost Σρ at the solution.
    pub cost: f64,
    /// Calibration RMS, mm: of the distances when there are touches, else of the point errors.
    pub rms_mm: f64,
    /// The residuals at the solution, per kind.
    pub stats: FitStats,
    /// Identifiability of all free parameters at the nominal values (the frames projected out).
    pub before: Identifiability,
    /// Identifiability at the solution (without block unknowns).
    pub after: Option<Identifiability>,
    /// Sentences on what the data cannot separate and what was held therefore.
    pub statements: Vec<String>,
    /// Orientation spread of the tool within each session, degrees (session, spread).
    pub orientation_spread_deg: Vec<(String, f64)>,
    /// Parameters estimated.
    pub estimated: Vec<ParamId>,
    /// Parameters held because the data cannot determine them.
    pub fixed: Vec<ParamId>,
    /// Estimates with standard deviations.
    pub estimates: Vec<Estimate>,
    /// Parameter pairs correlated beyond ±0.9.
    pub correlations: Vec<(String, String, f64)>,
    /// Every start, in order.
    pub starts: Vec<StartOutcome>,
    /// Jacobian evaluations over all passes of the start kept.
    pub iterations: usize,
    /// Each framed block's frame, by block name.
    pub frames: Vec<(String, Frame)>,
    /// Tool offsets of the floated groups.
    pub tool_offsets: Vec<FloatedTool>,
    /// Drift rates of the drifting sessions.
    pub drifts: Vec<SessionDrift>,
    /// The probe's orientation on the flange (6-DoF probes).
    pub tool_rotation: Option<ToolRotation>,
    /// The sines and cosines of the encoder angles calibrated on, for the refits.
    pub(crate) encoders: Encoders,
}

/// What the data can and cannot determine, in words, as a run's summary holds it.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct IdentifiabilityReport {
    /// Free parameters estimated.
    pub estimated: Vec<String>,
    /// Free parameters held at their nominal value because the data cannot determine them.
    pub fixed: Vec<String>,
    /// Sentences a user reads: what cannot be separated, and why.
    #[serde(default)]
    pub statements: Vec<String>,
    /// Directions of the arm parameters (frames projected out) the data cannot determine.
    pub unidentifiable: Vec<identify::Combination>,
    /// Directions it determines only weakly.
    pub poorly_identified: Vec<identify::Combination>,
    /// Orientation spread of the tool within each session, degrees (session, spread).
    #[serde(default)]
    pub orientation_spread_deg: Vec<(String, f64)>,
}

impl Fit {
    /// What the data determine, in words.
    pub fn identifiability(&self) -> IdentifiabilityReport {
        IdentifiabilityReport {
            estimated: self.estimated.iter().map(|p| self.model.param_name(*p)).collect(),
            fixed: self.fixed.iter().map(|p| self.model.param_name(*p)).collect(),
            statements: self.statements.clone(),
            unidentifiable: self.before.unidentifiable.clone(),
            poorly_identified: self.before.poorly_identified.clone(),
            orientation_spread_deg: self.orientation_spread_deg.clone(),
        }
    }

    /// Group `name`'s floated tool offset (zero unless floated), mm.
    pub fn tool_offset(&self, name: &str) -> Vector3<f64> {
        self.tool_offsets
            .iter()
            .find(|t| t.session == name)
            .map_or(Vector3::zeros(), |t| Vector3::from(t.offset_mm))
    }

    /// Block `name`'s frame, when it has one.
    pub fn frame(&self, name: &str) -> Option<Frame> {
        self.frames.iter().find(|f| f.0 == name).map(|f| f.1)
    }

    /// The probe's rotation on the flange (the identity without one).
    pub fn probe(&self) -> Matrix3<f64> {
        self.tool_rotation.map_or(Matrix3::identity(), |t| t.rotation())
    }
}

mod dense;
mod factored;
use factored::Factored;
mod framed;
mod outcome;
mod pieces;
mod shared;
#[cfg(test)]
mod tests;

use dense::*;
pub(crate) use framed::ToolFirstFit;
use framed::*;
use outcome::*;
pub(crate) use pieces::beats;
pub(crate) use pieces::SharedTerms;
use pieces::*;
pub use shared::SessionSums;

/// Every refusal of `data` for calibrating `model` before any solving: the joint count, a session
/// too small for its frame, no free parameter, too few residuals, non-finite positions, or
/// observations that carry no information. `calibrate` refuses with these errors, and so does
/// `diagnose` on a RUN's data, with the same messages. Tracker sessions' data are checked by
/// their residuals at the start only: data whose residuals are finite but whose derivatives are
/// not pass here and are refused by `calibrate` (the same error) when it factors them.
pub fn check_data(model: &ArmModel, data: &Observations, options: &SolveOptions) -> Result<(), CalibError> {
    check_data_on(model, data, data.encoders(), options)
}

/// [`check_data`] with `data`'s encoder table.
pub fn check_data_on(
    model: &ArmModel,
    data: &Observations,
    encoders: &Encoders,
    options: &SolveOptions,
) -> Result<(), CalibError> {
    check_data_sharing(model, data, encoders, options, &ToolFirstFit::default(), None)
}

/// [`check_data_on`], the closed-form frames of `model` taken from `start` (and kept there for
/// the calibrations from `model` on `data`, see [`ToolFirstFit`]), the terms of `data` from
/// `terms` when given (built and kept there when it holds none yet).
pub(crate) fn check_data_sharing<'a>(
    model: &ArmModel,
    data: &'a Observations,
    encoders: &Encoders,
    options: &SolveOptions,
    start: &ToolFirstFit,
    terms: Option<&'a SharedTerms<'a>>,
) -> Result<(), CalibError> {
    if let Some(own) = data.without_orientations_of(&options.float_tool) {
        return check_data_sharing(model, &own, encoders, options, start, None);
    }
    let pieces = Pieces::new_sharing(model, data, options, encoders, terms.map(TermSource::Shared))?;
    let all: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
    if pieces.blocked() {
        let frames = start.closed_form_frames(&pieces);
        let probe = start_probe_rotation(&pieces.model, data, &frames);
        let full = pieces.problem(all, &pieces.model, &frames, probe);
        let tools = vec![Vector3::zeros(); data.groups.len()];
        let x0 = pieces.x_of(&full, &pieces.model, &frames, &tools, &vec![Vec::new(); data.blocks.len()]);
        // The residuals alone (no derivatives, no factors: the fit factors the groups where it
        // decides identifiability, and refuses non-finite derivatives there).
        return check_residuals(&full, &x0);
    }
    check_dense(&pieces, &all).map(|_| ())
}

impl Setup {
    /// Calibrate `start` (a model with this setup's effects, often a calibrated one: a warm
    /// start) on `cal` as this setup asks.
    pub fn calibrate(&self, start: &ArmModel, cal: &Observations) -> Result<Fit, CalibError> {
        let kept = self.data(cal)?;
        calibrate(start, &kept, &self.solve_options(&kept))
    }
}

/// Calibrate the free parameters of `nominal` on `data` (see the module doc).
pub fn calibrate(nominal: &ArmModel, data: &Observations, options: &SolveOptions) -> Result<Fit, CalibError> {
    calibrate_on(nominal, data, data.encoders(), options)
}

/// [`calibrate`] with `data`'s encoder table (a run's, shared by its calibrations).
pub fn calibrate_on(
    nominal: &ArmModel,
    data: &Observations,
    encoders: &Encoders,
    options: &SolveOptions,
) -> Result<Fit, CalibError> {
    calibrate_on_sharing(nominal, data, encoders, options, &ToolFirstFit::default(), None)
}

/// [`calibrate_on`] of `nominal`, and of `reference` when given: the same arm's values with
/// fewer parameters free, the tool point among them (a run's tool-only nominal model). With
/// block unknowns both start with the closed-form frames, orientation spreads and tool point's
/// first fit of these values, each taken once (or taken from `start`, see [`ToolFirstFit`]).
/// Both take the terms of `data` from `terms` when given ([`SharedTerms`]). The reference's own
/// error is its result's.
pub(crate) fn calibrate_with_reference_on<'a>(
    nominal: &ArmModel,
    reference: Option<&ArmModel>,
    data: &'a Observations,
    encoders: &Encoders,
    options: &SolveOptions,
    start: &ToolFirstFit,
    terms: Option<&'a SharedTerms<'a>>,
) -> Result<(Fit, Option<Result<Fit, CalibError>>), CalibError> {
    let fit = calibrate_on_sharing(nominal, data, encoders, options, start, terms)?;
    let reference = reference.map(|r| calibrate_on_sharing(r, data, encoders, options, start, terms));
    Ok((fit, reference))
}

/// [`calibrate_on`], the tool point's first fit from `first_fit` (see [`ToolFirstFit`]), the
/// terms from `terms` when given.
fn calibrate_on_sharing<'a>(
    nominal: &ArmModel,
    data: &'a Observations,
    encoders: &Encoders,
    options: &SolveOptions,
    first_fit: &ToolFirstFit,
    terms: Option<&'a SharedTerms<'a>>,
) -> Result<Fit, CalibError> {
    if let Some(own) = data.without_orientations_of(&options.float_tool) {
        return calibrate_on_sharing(nominal, &own, encoders, options, first_fit, None);
    }
    let pieces = Pieces::new_sharing(nominal, data, options, encoders, terms.map(TermSource::Shared))?;
    if pieces.blocked() {
        calibrate_framed(nominal, &pieces, None, None, first_fit)
    } else {
        calibrate_dense(nominal, &pieces, options)
    }
}

/// Calibrate as [`calibrate`] does, for data or options close to those of `warm` (one more tool
/// floated, a drift, a few points left out: the data-error scoring's refits). With block
/// unknowns the solve starts at `warm`'s solution (arm, frames, tools, drifts, probe) instead of
/// the nominal values and the closed-form frames, on `warm`'s base set with its identifiability
/// and orientation spreads (no tool pre-fit, no factorisation: a floated tool, a drift or a few
/// points less leave what the other sessions determine of the arm), and reaches the same minimum
/// in fewer iterations; without block unknowns it is [`calibrate`].
pub fn recalibrate(
    nominal: &ArmModel,
    data: &Observations,
    options: &SolveOptions,
    warm: &Fit,
) -> Result<Fit, CalibError> {
    recalibrate_from(nominal, data, options, warm, None)
}

/// [`recalibrate`] from `sums.fit()`, its first normal equations assembled from `sums` (see
/// [`SessionSums`]): the same solve, one evaluation of every session fewer.
pub fn recalibrate_with(
    nominal: &ArmModel,
    data: &Observations,
    options: &SolveOptions,
    sums: &SessionSums,
) -> Result<Fit, CalibError> {
    recalibrate_from(nominal, data, options, sums.fit(), Some(sums))
}

fn recalibrate_from(
    nominal: &ArmModel,
    data: &Observations,
    options: &SolveOptions,
    warm: &Fit,
    sums: Option<&SessionSums>,
) -> Result<Fit, CalibError> {
    if let Some(own) = data.without_orientations_of(&options.float_tool) {
        return recalibrate_from(nominal, &own, options, warm, sums);
    }
    let kept = sums.and_then(|s| s.kept()).map(TermSource::Kept);
    let pieces = Pieces::new_sharing(nominal, data, options, &warm.encoders, kept)?;
    if pieces.blocked() {
        calibrate_framed(nominal, &pieces, Some(warm), sums, &ToolFirstFit::default())
    } else {
        calibrate_dense(nominal, &pieces, options)
    }
}

/// Solve for `params` (free in `start`, with its bounds) on `data` from `start`'s values: one
/// warm start, no identifiability analysis, no restarts, no uncertainty. For refits whose base
/// set is already known (leave-one-out refits, the diagnosis' candidate refits).
pub fn solve_warm(
    start: &ArmModel,
    params: &[ParamId],
    data: &Observations,
    options: &SolveOptions,
) -> Result<ArmModel, CalibError> {
    solve_warm_from(start, params, data, options, None, None)
}

/// [`solve_warm`], with block unknowns started at `warm`'s solution when given (else the frames
/// at their closed form for `start`).
fn solve_warm_from(
    start: &ArmModel,
    params: &[ParamId],
    data: &Observations,
    options: &SolveOptions,
    warm: Option<&Fit>,
    sums: Option<&SessionSums>,
) -> Result<ArmModel, CalibError> {
    if let Some(own) = data.without_orientations_of(&options.float_tool) {
        return solve_warm_from(start, params, &own, options, warm, sums);
    }
    let encoders = warm.map_or_else(|| data.encoders().clone(), |w| w.encoders.clone());
    let pieces = Pieces::new(start, data, options, &encoders)?;
    if pieces.blocked() {
        let from = match warm {
            Some(warm) => warm_start(&pieces, warm),
            None => {
                let frames = pieces.closed_form_frames(start);
                let probe = start_probe_rotation(start, data, &frames)
                    .filter(|_| pieces.resolved.orientation_weight_mm_per_rad.is_some());
                Solved::at(start.clone(), frames, probe, data)
            }
        };
        let sums = sums.filter(|_| warm.is_some());
        let given = |problem: &Problem, _: &[f64]| sums.and_then(|s| s.normal_at_start(&pieces, problem));
        return Ok(solve_framed_from(&pieces, params, from, 0, given).model);
    }
    let frames = vec![Frame::identity(); data.blocks.len()];
    let problem = pieces.problem(params.to_vec(), start, &frames, None);
    let pairs = pieces.distance_rows();
    if pairs < params.len() {
        return Err(CalibError::TooFewPairs { pairs, params: params.len() });
    }
    let n = problem.layout.unknowns();
    let (lower, upper) = pieces.bounds(params, n);
    let mut x0: Vec<f64> = params.iter().map(|&id| start.get(id)).collect();
    x0.resize(n, 0.0);
    let solver_options = dense::dense_solver(&pieces, options);
    let (_, solution, _) =
        solve_from_starts(&problem, &x0, (&lower, &upper), &solver_options, options.seed, 0..=0, None);
    Ok(problem.state(&solution.x).model)
}

/// The residuals and the dense Jacobian (row-major, `params.len()` columns) of the frame-free
/// terms of `data` (artefact distances, with their relative orientations when `lever_mm` is
/// given) at `model`'s values of `params`.
pub fn dense_jacobian(
    model: &ArmModel,
    params: &[ParamId],
    data: &Observations,
    lever_mm: Option<f64>,
) -> (Vec<f64>, Vec<f64>) {
    let pairs = data.landmark_pairs();
    let mut terms = terms::distance::terms(data, &pairs);
    if let Some(lever) = lever_mm {
        terms.extend(terms::relative_orientation::terms(data, &pairs, lever));
    }
    let layout = Layout::new(
        params.to_vec(),
        &vec![false; data.blocks.len()],
        &vec![false; data.groups.len()],
        false,
        &vec![None; data.blocks.len()],
    );
    let problem =
        Problem::new(layout, model, data, &terms, vec![Matrix3::identity(); data.blocks.len()], None);
    let x: Vec<f64> = params.iter().map(|&id| model.get(id)).collect();
    jacobian_at(&problem, &x)
}

/// Solve again for the parameters `fit` estimated, on other data (a landmark or block left out),
/// starting from `fit`'s solution (its frames, tools, drifts and probe too): no identifiability
/// analysis, no restarts, no uncertainty.
pub fn refit(fit: &Fit, data: &Observations, options: &SolveOptions) -> Result<ArmModel, CalibError> {
    solve_warm_from(&fit.model, &fit.estimated, data, options, Some(fit), None)
}

/// [`refit`] of `sums.fit()`, its first normal equations assembled from `sums` (see
/// [`SessionSums`]): the same solve, one evaluation of every session fewer.
pub fn refit_with(
    sums: &SessionSums,
    data: &Observations,
    options: &SolveOptions,
) -> Result<ArmModel, CalibError> {
    let fit = sums.fit();
    solve_warm_from(&fit.model, &fit.estimated, data, options, Some(fit), Some(sums))
}
