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
//! the nominal arm ([`Frame::fit`]); identifiability sees the frames (they are projected out of
//! the arm's columns, [`Problem::group_factors`]); the tool point is freed (and held at its
//! nominal value when no session turns it: then it and each frame's shift are one thing); the
//! problem is solved, and solved again with the frames' rotations re-centred at the solution
//! (up to [`PASSES`] passes) only when a solve stops without converging. Restarts, when asked for, start the arm at random points inside its bounds, with
//! each frame at its closed form for that arm.

use crate::calib::identify::{self, Identifiability};
use crate::calib::layout::Layout;
use crate::calib::nuisance::drift::{drift_slots, DriftError, DriftSlot, SessionDrift};
use crate::calib::nuisance::frame::{rotation_vector, Frame, FRAME_UNKNOWNS};
use crate::calib::nuisance::tool::{
    length_std, model_point, orientation_spread_deg, start_probe_rotation, FloatedTool, ToolRotation,
};
use crate::calib::problem::{projected_arm_columns, Problem};
use crate::calib::setup::{Resolved, SolveOptions};
use crate::calib::terms::{self, Term, TermChoice};
use crate::calib::validate::{AngleStats, ErrorStats};
use crate::data::{Kind, Observations};
use crate::model::{ArmModel, ParamId};
use crate::numerics::solver::{self, Loss, Residuals, SolverOptions, StopReason, Termination};
use nalgebra::{Matrix3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Spread of the tool orientation within a session, degrees, below which the session is said
/// to hold the orientation constant.
pub const CONSTANT_ORIENTATION_DEG: f64 = 1.0;
/// Half-range of the tool point when the model does not free it and frames are fitted, mm.
pub const TOOL_HALF_RANGE_MM: f64 = 500.0;
/// Most Gauss–Newton passes with frames, each re-centring the frames at their solution.
pub const PASSES: usize = 3;
/// Most times the base set is re-checked at a solution and the problem solved again.
const MAX_IDENTIFIABILITY_PASSES: usize = 3;
/// Change of a residual, mm, over a parameter's whole range below which it counts as none.
const NEGLIGIBLE_MM: f64 = 1e-9;
/// Solver settings of each pass when frames are fitted (the passes re-centre between solves).
const FRAMED_SOLVER: SolverOptions = SolverOptions {
    loss: Loss::Linear,
    max_iterations: 100,
    ftol: 1e-10,
    xtol: 1e-10,
    gtol: 1e-10,
    termination: Termination::Ceres,
};

/// Why a calibration could not run.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// The sessions' joint count differs from the model's.
    #[error("the {kind} sessions {record} {data} {what}, the model has {model} joints")]
    JointCount {
        /// `artefact` or `tracker`.
        kind: &'static str,
        /// How the sessions hold the joints.
        record: &'static str,
        /// Joints in the data.
        data: usize,
        /// What they are.
        what: &'static str,
        /// Joints of the model.
        model: usize,
    },
    /// Too few distances for the free parameters.
    #[error("{pairs} landmark pairs cannot determine {params} parameters: touch more landmarks per placement and repeat")]
    TooFewPairs {
        /// Distance residuals available.
        pairs: usize,
        /// Parameters to determine.
        params: usize,
    },
    /// More unknowns than residuals.
    #[error("{residuals} measured coordinates cannot determine {unknowns} unknowns: measure more points")]
    TooFewResiduals {
        /// Residual rows.
        residuals: usize,
        /// Unknowns (arm, tool, frames).
        unknowns: usize,
    },
    /// A session has too few points to place its frame.
    #[error(
        "{path}: session \"{session}\" has {points} points: at least 3 not on one line are needed to place its base"
    )]
    TooFewPoints {
        /// The session's file.
        path: String,
        /// The session.
        session: String,
        /// Its points.
        points: usize,
    },
    /// A group named by `--float-tool` is not in the data.
    #[error("--float-tool / --drift-session {0}: no calibration session of that name")]
    UnknownSession(String),
    /// A drift asked for cannot be fitted.
    #[error(transparent)]
    Drift(#[from] DriftError),
    /// The model has no free parameter.
    #[error("the model has no free parameter: give bounds in its [free] table")]
    NothingFree,
    /// No free parameter changes any residual on these observations.
    #[error(
        "none of the free parameters changes any measured distance: the touches carry no information \
         (all at one pose, or the same joint angles copied into every measurement?)"
    )]
    NothingIdentifiable,
    /// The model gives positions that are not finite numbers.
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
            estimated: self.estimated.iter().map(|p| p.to_string()).collect(),
            fixed: self.fixed.iter().map(|p| p.to_string()).collect(),
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

/// What a calibration of some observations is made of, whatever the arm's values.
struct Pieces<'a> {
    data: &'a Observations,
    model: ArmModel,
    terms: Vec<Box<dyn Term>>,
    framed: Vec<bool>,
    floated: Vec<bool>,
    drift: Vec<Option<DriftSlot>>,
    resolved: Resolved,
}

impl<'a> Pieces<'a> {
    /// Check `data` against `nominal` and `options` and assemble the terms and the unknowns.
    fn new(
        nominal: &ArmModel,
        data: &'a Observations,
        options: &SolveOptions,
    ) -> Result<Pieces<'a>, CalibError> {
        if !data.obs.is_empty() && nominal.joints.len() != data.joints {
            let tracker = data.obs.iter().any(|o| o.point_mm().is_some());
            return Err(CalibError::JointCount {
                kind: if tracker { "tracker" } else { "artefact" },
                record: if tracker { "have" } else { "record" },
                data: data.joints,
                what: if tracker { "joint columns (q1_deg …)" } else { "encoder angles" },
                model: nominal.joints.len(),
            });
        }
        let framed: Vec<bool> =
            data.blocks.iter().map(|b| data.groups[b.group].kind == Kind::Tracker).collect();
        for (b, block) in data.blocks.iter().enumerate().filter(|(b, _)| framed[*b]) {
            if block.members.len() < 3 {
                let group = &data.groups[block.group];
                return Err(CalibError::TooFewPoints {
                    path: group.source.display().to_string(),
                    session: data.block_name(b),
                    points: block.members.len(),
                });
            }
        }
        for name in &options.float_tool {
            if data.find_group(name).is_none() {
                return Err(CalibError::UnknownSession(name.clone()));
            }
        }
        let floated = data.groups.iter().map(|g| options.float_tool.contains(&g.name)).collect();
        let drift = drift_slots(data, &options.drift_sessions)?;
        let mut model = nominal.clone();
        // An instrument's tool point (a reflector, a probe) is never known to the data's accuracy.
        let instrument = framed.iter().any(|f| *f) || data.obs.iter().any(|o| o.unframed_mm().is_some());
        if instrument {
            for k in 0..3 {
                if !model.free.iter().any(|f| f.id == ParamId::Tcp(k)) {
                    let v = model.tcp_mm[k];
                    model.free_param(ParamId::Tcp(k), v - TOOL_HALF_RANGE_MM, v + TOOL_HALF_RANGE_MM);
                }
            }
        }
        let mut resolved = options.resolve(data);
        if data.kind() == Some(crate::data::DataKind::Mixed) {
            let touch_std_mm = crate::calib::floor::touch_std_mm(nominal, data);
            resolved.point_weight = options.point_weight(data, touch_std_mm);
        }
        let choice = TermChoice {
            relative_orientation_lever_mm: resolved.relative_lever_mm,
            orientation_weight_mm_per_rad: resolved.orientation_weight_mm_per_rad,
            point_weight: resolved.point_weight,
        };
        Ok(Pieces { data, model, terms: terms::build(data, &choice), framed, floated, drift, resolved })
    }

    /// Whether any block or group has unknowns of its own (frames, floated tools, drifts).
    fn blocked(&self) -> bool {
        self.framed.iter().chain(&self.floated).any(|f| *f) || self.drift.iter().any(Option::is_some)
    }

    fn layout(&self, arm: Vec<ParamId>) -> Layout {
        let rotation = self.resolved.orientation_weight_mm_per_rad.is_some();
        Layout::new(arm, &self.framed, &self.floated, rotation, &self.drift)
    }

    /// The problem over `arm` around `model`, frames starting at `frames`, the probe at `probe`.
    fn problem<'p>(
        &'p self,
        arm: Vec<ParamId>,
        model: &'p ArmModel,
        frames: &[Frame],
        probe: Option<Matrix3<f64>>,
    ) -> Problem<'p> {
        Problem::new(
            self.layout(arm),
            model,
            self.data,
            &self.terms,
            frames.iter().map(|f| f.rotation).collect(),
            probe.filter(|_| self.resolved.orientation_weight_mm_per_rad.is_some()),
        )
    }

    /// Each block's frame at its closed form for `model` (tool offsets zero), the identity for a
    /// block without one.
    fn closed_form_frames(&self, model: &ArmModel) -> Vec<Frame> {
        let data = self.data;
        let zero = Vector3::zeros();
        (0..data.blocks.len())
            .map(|b| {
                if !self.framed[b] {
                    return Frame::identity();
                }
                let members = &data.blocks[b].members;
                let robot: Vec<Vector3<f64>> =
                    members.iter().map(|&k| model_point(model, &data.obs[k].q_deg, &zero)).collect();
                let measured: Vec<Vector3<f64>> =
                    members.iter().map(|&k| data.obs[k].point_mm().unwrap_or_default()).collect();
                Frame::fit(&robot, &measured)
            })
            .collect()
    }

    /// The unknowns at `model`'s values with `frames` (rotations re-centred), the groups' tool
    /// offsets `tools`, the probe at its start and the drifts `drifts`.
    fn x_of(
        &self,
        problem: &Problem,
        model: &ArmModel,
        frames: &[Frame],
        tools: &[Vector3<f64>],
        drifts: &[Vec<f64>],
    ) -> Vec<f64> {
        let layout = &problem.layout;
        let mut x: Vec<f64> = layout.arm.iter().map(|id| model.get(*id)).collect();
        x.resize(layout.unknowns(), 0.0);
        for (b, f) in frames.iter().enumerate() {
            if let Some(c) = layout.frame_column(b) {
                x[c..c + 3].copy_from_slice(&[0.0; 3]);
                x[c + 3..c + FRAME_UNKNOWNS].copy_from_slice(f.translation_mm.as_slice());
            }
        }
        for (g, t) in tools.iter().enumerate() {
            if let Some(c) = layout.tool_column(g) {
                x[c..c + 3].copy_from_slice(t.as_slice());
            }
        }
        for (b, d) in drifts.iter().enumerate() {
            if let Some((c, slot)) = layout.drift(b) {
                for k in 0..slot.kind.unknowns() {
                    x[c + k] = d.get(k).copied().unwrap_or(0.0);
                }
            }
        }
        x
    }

    fn bounds(&self, params: &[ParamId], unknowns: usize) -> (Vec<f64>, Vec<f64>) {
        let bound = |id: &ParamId| self.model.free.iter().find(|f| f.id == *id);
        let mut lower: Vec<f64> =
            params.iter().map(|id| bound(id).map_or(f64::NEG_INFINITY, |f| f.lower)).collect();
        let mut upper: Vec<f64> =
            params.iter().map(|id| bound(id).map_or(f64::INFINITY, |f| f.upper)).collect();
        lower.resize(unknowns, -1e9);
        upper.resize(unknowns, 1e9);
        (lower, upper)
    }

    fn range(&self, id: ParamId) -> f64 {
        self.model.free.iter().find(|f| f.id == id).map_or(1.0, |f| (f.upper - f.lower).max(1e-9))
    }

    fn distance_rows(&self) -> usize {
        self.terms.iter().filter(|t| t.rows() == 1 && t.is_position()).count()
    }
}

fn jacobian_at(problem: &Problem, x: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let m = problem.len();
    let mut r = vec![0.0; m];
    let mut jac = vec![0.0; m * x.len()];
    problem.evaluate(x, &mut r, Some(&mut jac));
    (r, jac)
}

/// Solve from the nominal values (start 0) or from random points inside the bounds (starts 1..),
/// keeping the lowest cost (the earliest start on a tie). Random start k is the same point
/// whichever starts are run; the starts run in parallel on every core.
fn solve_from_starts(
    problem: &Problem,
    x_nominal: &[f64],
    lower: &[f64],
    upper: &[f64],
    options: &SolverOptions,
    seed: u64,
    starts: std::ops::RangeInclusive<usize>,
) -> (solver::Solution, Vec<StartOutcome>) {
    let points = start_points(x_nominal, lower, upper, seed, starts);
    let solved: Vec<(StartOutcome, solver::Solution)> = points
        .par_iter()
        .map(|(start, x0)| {
            let mut r0 = vec![0.0; problem.len()];
            problem.evaluate(x0, &mut r0, None);
            let s = solver::solve(problem, x0, lower, upper, options);
            let outcome = StartOutcome {
                start: *start,
                initial_cost: options.loss.cost(&r0),
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
    let best = best.unwrap_or_else(|| solver::solve(problem, x_nominal, lower, upper, options));
    (best, outcomes)
}

/// The start points `starts`: 0 the nominal values, k ≥ 1 the k-th seeded random point inside the
/// bounds (the same whichever starts are run).
fn start_points(
    x_nominal: &[f64],
    lower: &[f64],
    upper: &[f64],
    seed: u64,
    starts: std::ops::RangeInclusive<usize>,
) -> Vec<(usize, Vec<f64>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..=*starts.end())
        .map(|start| {
            let x0: Vec<f64> = if start == 0 {
                x_nominal.to_vec()
            } else {
                lower.iter().zip(upper).map(|(l, u)| l + (u - l) * rng.random::<f64>()).collect()
            };
            (start, x0)
        })
        .filter(|(start, _)| starts.contains(start))
        .collect()
}

/// Every refusal of `data` for calibrating `model` before any solving: the joint count, a session
/// too small for its frame, no free parameter, too few residuals, non-finite positions, or
/// observations that carry no information. `calibrate` refuses with these errors, and so does
/// `diagnose` on a RUN's data, with the same messages.
pub fn check_data(model: &ArmModel, data: &Observations, options: &SolveOptions) -> Result<(), CalibError> {
    let pieces = Pieces::new(model, data, options)?;
    let all: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
    if pieces.blocked() {
        let frames = pieces.closed_form_frames(&pieces.model);
        let probe = start_probe_rotation(&pieces.model, data, &frames);
        let full = pieces.problem(all, &pieces.model, &frames, probe);
        let tools = vec![Vector3::zeros(); data.groups.len()];
        let x0 = pieces.x_of(&full, &pieces.model, &frames, &tools, &vec![Vec::new(); data.blocks.len()]);
        return check_framed(&full, &x0).map(|_| ());
    }
    check_dense(&pieces, &all).map(|_| ())
}

/// The dense Jacobian at the nominal values after the checks of a problem without frames.
fn check_dense<'p>(pieces: &'p Pieces, all: &[ParamId]) -> Result<(Problem<'p>, Vec<f64>), CalibError> {
    if all.is_empty() {
        return Err(CalibError::NothingFree);
    }
    let full =
        pieces.problem(all.to_vec(), &pieces.model, &vec![Frame::identity(); pieces.data.blocks.len()], None);
    let unknowns = full.layout.unknowns();
    let pairs = pieces.distance_rows();
    if pairs < all.len() {
        return Err(CalibError::TooFewPairs { pairs, params: all.len() });
    }
    if full.len() < unknowns {
        return Err(CalibError::TooFewResiduals { residuals: full.len(), unknowns });
    }
    let mut x0 = pieces.model.free_values();
    x0.resize(unknowns, 0.0);
    let (r0, jac) = jacobian_at(&full, &x0);
    if !r0.iter().chain(&jac).all(|v| v.is_finite()) {
        return Err(CalibError::NonFinite);
    }
    // Over its whole range, no free parameter moves any residual by a measurable amount.
    let ranges: Vec<f64> = all.iter().map(|&id| pieces.range(id)).collect();
    let n = unknowns;
    if jac.iter().enumerate().all(|(k, v)| k % n >= all.len() || (v * ranges[k % n]).abs() < NEGLIGIBLE_MM) {
        return Err(CalibError::NothingIdentifiable);
    }
    Ok((full, jac))
}

/// The group factors at `x0` after the checks of a problem with frames.
fn check_framed(full: &Problem, x0: &[f64]) -> Result<Vec<crate::calib::problem::GroupFactor>, CalibError> {
    let unknowns = full.layout.unknowns();
    if full.len() < unknowns {
        return Err(CalibError::TooFewResiduals { residuals: full.len(), unknowns });
    }
    full.group_factors(x0).ok_or(CalibError::NonFinite)
}

/// Calibrate the free parameters of `nominal` on `data` (see the module doc).
pub fn calibrate(nominal: &ArmModel, data: &Observations, options: &SolveOptions) -> Result<Fit, CalibError> {
    let pieces = Pieces::new(nominal, data, options)?;
    if pieces.blocked() {
        calibrate_framed(nominal, &pieces)
    } else {
        calibrate_dense(nominal, &pieces, options)
    }
}

fn calibrate_dense(nominal: &ArmModel, pieces: &Pieces, options: &SolveOptions) -> Result<Fit, CalibError> {
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
        correlations: correlations(&estimated, cov.as_ref()),
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
fn arm_columns(jac: &[f64], n: usize, arm: usize) -> std::borrow::Cow<'_, [f64]> {
    if n == arm {
        return std::borrow::Cow::Borrowed(jac);
    }
    std::borrow::Cow::Owned(jac.chunks_exact(n.max(1)).flat_map(|row| row[..arm].iter().copied()).collect())
}

/// A solution with frames: the model, each block's frame, each group's tool, the probe and the
/// drifts, with its cost, iterations and how its last pass stopped.
struct Solved {
    model: ArmModel,
    frames: Vec<Frame>,
    tools: Vec<Vector3<f64>>,
    probe: Option<Matrix3<f64>>,
    drifts: Vec<Vec<f64>>,
    outcome: StartOutcome,
}

/// Solve for `estimated` from `start` (frames at `frames`, probe at `probe`); again from its
/// solution with the frames' rotations (and the probe's) re-centred, while a solve stops without
/// converging (up to [`PASSES`] passes).
fn solve_framed(
    pieces: &Pieces,
    estimated: &[ParamId],
    start: ArmModel,
    frames: Vec<Frame>,
    probe: Option<Matrix3<f64>>,
    number: usize,
) -> Solved {
    let data = pieces.data;
    let options = SolverOptions { loss: pieces.resolved.loss, ..FRAMED_SOLVER };
    let mut s = Solved {
        model: start,
        frames,
        tools: vec![Vector3::zeros(); data.groups.len()],
        probe,
        drifts: vec![Vec::new(); data.blocks.len()],
        outcome: StartOutcome {
            start: number,
            initial_cost: f64::NAN,
            final_cost: f64::INFINITY,
            iterations: 0,
            stop: StopReason::NoProgress,
        },
    };
    let mut last_cost = f64::INFINITY;
    for pass in 0..PASSES {
        let problem = pieces.problem(estimated.to_vec(), &s.model, &s.frames, s.probe);
        let n = problem.layout.unknowns();
        let x0 = pieces.x_of(&problem, &s.model, &s.frames, &s.tools, &s.drifts);
        let (lower, upper) = pieces.bounds(estimated, n);
        if pass == 0 {
            let mut r0 = vec![0.0; problem.len()];
            problem.evaluate(&x0, &mut r0, None);
            s.outcome.initial_cost = options.loss.cost(&r0);
        }
        let solution = solver::solve(&problem, &x0, &lower, &upper, &options);
        s.outcome.iterations += solution.iterations;
        s.outcome.stop = solution.stop;
        s.outcome.final_cost = solution.cost;
        let state = problem.state(&solution.x);
        s.tools = state.tools;
        s.frames = state.frames;
        s.probe = s.probe.map(|_| state.probe);
        s.drifts = state.drifts;
        s.model = state.model;
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

fn calibrate_framed(nominal: &ArmModel, pieces: &Pieces) -> Result<Fit, CalibError> {
    let data = pieces.data;
    let model = &pieces.model;
    let all: Vec<ParamId> = model.free.iter().map(|f| f.id).collect();
    let start_frames = pieces.closed_form_frames(model);
    let probe = start_probe_rotation(model, data, &start_frames)
        .filter(|_| pieces.resolved.orientation_weight_mm_per_rad.is_some());
    // Identifiability at the nominal values, frames at their closed form.
    let full = pieces.problem(all.clone(), model, &start_frames, probe);
    let tools0 = vec![Vector3::zeros(); data.groups.len()];
    let x0 = pieces.x_of(&full, model, &start_frames, &tools0, &vec![Vec::new(); data.blocks.len()]);
    let factors = check_framed(&full, &x0)?;
    let (raw, projected) = projected_arm_columns(&full.layout, &factors);
    let ranges: Vec<f64> = all.iter().map(|&id| pieces.range(id)).collect();
    let (kept, _) = identify::base_columns(&projected, all.len(), &ranges);
    let before = identify::analyse(&projected, &all, &ranges);
    let spreads: Vec<(String, f64)> = (0..data.blocks.len())
        .filter(|&b| pieces.framed[b])
        .map(|b| (data.block_name(b), orientation_spread_deg(model, data, b)))
        .collect();
    // No session turns the tool and no touch pins it: its point is the frames' translation,
    // whatever a small model error makes the Jacobian say; it stays at its nominal value.
    let pinned = data.obs.iter().any(|o| o.landmark().is_some());
    let tool_turns = pinned || spreads.iter().any(|s| s.1 >= CONSTANT_ORIENTATION_DEG);
    let is_tool = |c: &usize| matches!(all[*c], ParamId::Tcp(_));
    let estimated: Vec<ParamId> =
        kept.iter().filter(|c| tool_turns || !is_tool(c)).map(|&c| all[c]).collect();
    let fixed: Vec<ParamId> =
        (0..all.len()).filter(|c| !estimated.contains(&all[*c])).map(|c| all[c]).collect();
    let probe_turns = full.layout.rotation_column().is_some();
    let statements = identify::explain(&all, &raw, &projected, probe_turns, &fixed, &spreads, &ranges);
    // Solve from the nominal values, then from the random starts.
    let mut solved = solve_framed(pieces, &estimated, model.clone(), start_frames, probe, 0);
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
                solve_framed(pieces, &estimated, start, frames, probe, *k)
            })
            .collect();
        for other in others {
            starts.push(other.outcome.clone());
            if other.outcome.final_cost < solved.outcome.final_cost {
                solved = other;
            }
        }
    }
    // Uncertainty at the solution (frames, floated tools and drifts marginalised).
    let problem = pieces.problem(estimated.clone(), &solved.model, &solved.frames, solved.probe);
    let x = pieces.x_of(&problem, &solved.model, &solved.frames, &solved.tools, &solved.drifts);
    let mut r = vec![0.0; problem.len()];
    let loss = pieces.resolved.loss;
    let (normal, _) = problem.normal_equations(&x, &mut r, loss);
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
        correlations: correlations(&estimated, cov.as_ref()),
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
    })
}

/// The residual statistics per kind from the residuals `r` of `problem`'s terms.
fn residual_stats(problem: &Problem, r: &[f64]) -> FitStats {
    let (mut distances, mut points, mut angles) = (Vec::new(), Vec::new(), Vec::new());
    for (t, &at) in problem.terms().iter().zip(problem.offsets()) {
        let rows = &r[at..at + t.rows()];
        let size = || Vector3::new(rows[0], rows[1], rows[2]).norm() / t.weight();
        match (t.rows(), t.is_position()) {
            (1, true) => distances.push(rows[0]),
            (3, true) => points.push(size()),
            (3, false) => angles.push(size().to_degrees()),
            _ => {}
        }
    }
    FitStats {
        distances: (!distances.is_empty()).then(|| ErrorStats::of(&distances)),
        points: (!points.is_empty()).then(|| ErrorStats::of(&points)),
        orientations: (!angles.is_empty()).then(|| AngleStats::of(&angles)),
    }
}

fn covariance_block(cov: Option<&nalgebra::DMatrix<f64>>, at: usize) -> Matrix3<f64> {
    cov.map_or(Matrix3::zeros(), |c| c.fixed_view::<3, 3>(at, at).into_owned())
}

/// Each floated group's tool offset with the deviation of its length.
fn floated_tools(
    problem: &Problem,
    data: &Observations,
    tools: &[Vector3<f64>],
    cov: Option<&nalgebra::DMatrix<f64>>,
) -> Vec<FloatedTool> {
    (0..data.groups.len())
        .filter_map(|g| {
            let c = problem.layout.tool_column(g)?;
            Some(FloatedTool::new(data.groups[g].name.clone(), &tools[g], &covariance_block(cov, c)))
        })
        .collect()
}

/// Every free parameter's estimate: its value in `model`, its std when estimated.
fn estimates(
    nominal: &ArmModel,
    model: &ArmModel,
    all: &[ParamId],
    estimated: &[ParamId],
    cov: Option<&nalgebra::DMatrix<f64>>,
) -> Vec<Estimate> {
    all.iter()
        .map(|&id| {
            let k = estimated.iter().position(|e| *e == id);
            Estimate {
                param: id.to_string(),
                unit: id.unit().to_string(),
                nominal: nominal.get(id),
                value: model.get(id),
                std: k.and_then(|k| cov.map(|c| c[(k, k)].max(0.0).sqrt())),
                status: if k.is_some() { "estimated".into() } else { "fixed: unidentifiable".into() },
            }
        })
        .collect()
}

/// Estimated pairs correlated beyond ±0.9.
fn correlations(estimated: &[ParamId], cov: Option<&nalgebra::DMatrix<f64>>) -> Vec<(String, String, f64)> {
    let mut out = Vec::new();
    if let Some(c) = cov {
        let n = estimated.len();
        for a in 0..n {
            for b in a + 1..n {
                let rho = c[(a, b)] / (c[(a, a)] * c[(b, b)]).sqrt();
                if rho.abs() > 0.9 {
                    out.push((estimated[a].to_string(), estimated[b].to_string(), rho));
                }
            }
        }
    }
    out
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
    let pieces = Pieces::new(start, data, options)?;
    if pieces.blocked() {
        let frames = pieces.closed_form_frames(start);
        let probe = start_probe_rotation(start, data, &frames)
            .filter(|_| pieces.resolved.orientation_weight_mm_per_rad.is_some());
        return Ok(solve_framed(&pieces, params, start.clone(), frames, probe, 0).model);
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
    let solver_options = SolverOptions { loss: pieces.resolved.loss, ..options.solver };
    let (solution, _) =
        solve_from_starts(&problem, &x0, &lower, &upper, &solver_options, options.seed, 0..=0);
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
/// starting from `fit`'s solution: no identifiability analysis, no restarts, no uncertainty.
pub fn refit(fit: &Fit, data: &Observations, options: &SolveOptions) -> Result<ArmModel, CalibError> {
    solve_warm(&fit.model, &fit.estimated, data, options)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::validate::validate_session;
    use crate::data::{Joints, Landmark, Observation, Target};
    use crate::model::kinematics::tool_pose;
    use crate::model::Joint;
    use nalgebra::{Rotation3, UnitQuaternion};

    /// A 7-joint arm with lengths and twists free (consistency of the solver with its own
    /// kinematics only; accuracy is tested on the independent generator in `tests/`).
    fn arm() -> ArmModel {
        let alpha = [-90.0, 90.0, -90.0, 90.0, -90.0, 90.0, 0.0];
        let d = [340.0, 0.0, 400.0, 0.0, 400.0, 0.0, 126.0];
        let mut model = ArmModel::suta_nominal();
        model.joints =
            (0..7).map(|j| Joint { d_mm: d[j], alpha_deg: alpha[j], ..Joint::default() }).collect();
        model.tcp_mm = [10.0, 20.0, 80.0];
        model.free.clear();
        for (j, dj) in d.iter().enumerate() {
            model.free_param(ParamId::Offset(j), -5.0, 5.0);
            model.free_param(ParamId::Length(j), dj - 10.0, dj + 10.0);
        }
        model
    }

    /// Three sessions of 40 noise-free points of `truth`, each seen from its own frame, with the
    /// probe's orientation when `probe` is given.
    fn sessions(truth: &ArmModel, probe: Option<Matrix3<f64>>) -> Observations {
        let mut data = Observations::new(7, Vec::new());
        for s in 0..3 {
            let group = data.push_group(format!("s{s}"), "s.csv".into(), Kind::Tracker);
            let frame = Frame {
                rotation: Rotation3::from_euler_angles(0.1 * s as f64, -0.05, 0.3 * s as f64).into_inner(),
                translation_mm: Vector3::new(2000.0, -500.0 * s as f64, 300.0),
            };
            for i in 0..40 {
                let f = (i + 40 * s) as f64;
                let q: Vec<f64> = (0..7).map(|j| 60.0 * (0.37 * f * (j + 1) as f64).sin()).collect();
                let pose = tool_pose(truth, &q);
                let orientation = probe.map(|p| {
                    let r = frame.rotation * crate::calib::nuisance::tool::flange_rotation(&pose) * p;
                    UnitQuaternion::from_matrix(&r)
                });
                data.obs.push(Observation {
                    block: 0,
                    group,
                    repeat: 1,
                    q_deg: Joints::new(&q).unwrap(),
                    q_sigma_deg: None,
                    target: Target::Point { xyz_mm: frame.apply(&pose.position_mm), orientation },
                    sigma_mm: None,
                    time_s: None,
                    temp_c: None,
                    pose: None,
                    line: i + 3,
                });
            }
        }
        data.rebuild_blocks();
        data
    }

    #[test]
    fn noise_free_points_of_its_own_kinematics_are_fitted_exactly() {
        let nominal = arm();
        let mut truth = nominal.clone();
        truth.joints[2].d_mm += 1.5;
        truth.joints[3].offset_deg += 0.2;
        truth.tcp_mm[2] += 2.0;
        let data = sessions(&truth, None);
        let fit = calibrate(&nominal, &data, &SolveOptions::default()).unwrap();
        assert!(fit.rms_mm < 1e-6, "{:?}", fit.stats);
        assert!(fit.fixed.contains(&ParamId::Offset(0)), "{:?}", fit.fixed);
        assert!(
            fit.statements.iter().any(|s| s.contains("offset:1 is absorbed by the session bases")),
            "{:?}",
            fit.statements
        );
        let v = validate_session(&fit.model, &data, 1, [0.0; 3]);
        assert!(v.rms_mm < 1e-6 && v.pairwise_rms_mm < 1e-6, "{v:?}");
    }

    /// ∂r/∂x of `problem` at `x` by central differences against its own Jacobian, and its sparse
    /// normal equations against JᵀJ of the dense one. (A floated tool's offset Δ is taken at zero:
    /// the arm columns leave out ∂(R_F·Δ)/∂θ, second order for an offset of millimetres.)
    fn check_jacobian(problem: &Problem, x: &[f64], h: f64) {
        let (m, n) = (problem.len(), x.len());
        let (r, jac) = jacobian_at(problem, x);
        for c in 0..n {
            let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
            xp[c] += h;
            xm[c] -= h;
            let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
            problem.evaluate(&xp, &mut rp, None);
            problem.evaluate(&xm, &mut rm, None);
            for i in 0..m {
                let fd = (rp[i] - rm[i]) / (2.0 * h);
                assert!(
                    (jac[i * n + c] - fd).abs() < 1e-4 * (1.0 + fd.abs()),
                    "row {i} column {c}: {} vs {fd}",
                    jac[i * n + c]
                );
            }
        }
        let mut r2 = vec![0.0; m];
        let (h, g) = problem.normal_equations(x, &mut r2, Loss::Linear);
        let (hd, gd) = solver::normal_equations(&jac, &r, &vec![1.0; m], n);
        assert!((&h - &hd).norm() <= 1e-9 * hd.norm() && (&g - &gd).norm() <= 1e-9 * gd.norm().max(1.0));
    }

    #[test]
    fn six_dof_jacobian_matches_central_differences() {
        let model = ArmModel::suta_nominal();
        let landmarks: Vec<Landmark> = (0..3)
            .map(|i| Landmark {
                id: format!("L{i}"),
                xyz_mm: [10.0 * i as f64, 5.0, 20.0],
                yaw_deg: 30.0 * i as f64,
            })
            .collect();
        let touches: [(usize, usize, u32, &[f64]); 3] = [
            (0, 0, 1, &[10.0, 200.0, 30.0, 300.0, 40.0, 120.0]),
            (0, 1, 1, &[12.0, 205.0, 28.0, 290.0, 45.0, 100.0]),
            (0, 2, 1, &[8.0, 190.0, 35.0, 310.0, 50.0, 80.0]),
        ];
        let data = Observations::from_touches(&["A"], landmarks, &touches);
        let params = ParamId::all();
        let options = SolveOptions {
            objective: Some(crate::calib::setup::Objective::SixDof { lever_mm: Some(100.0) }),
            float_tool: vec!["A".into()],
            ..SolveOptions::default()
        };
        let pieces = Pieces::new(&model, &data, &options).unwrap();
        let frames = vec![Frame::identity(); data.blocks.len()];
        let problem = pieces.problem(params.clone(), &model, &frames, None);
        let mut x: Vec<f64> = params.iter().map(|p| model.get(*p)).collect();
        x.extend([0.0; 3]);
        check_jacobian(&problem, &x, 1e-6);
    }

    #[test]
    fn point_and_orientation_jacobians_match_central_differences() {
        let nominal = arm();
        let probe = Rotation3::from_euler_angles(0.2, -0.1, 0.4).into_inner();
        let data = sessions(&nominal, Some(probe)).subset(&[0]);
        let options = SolveOptions { float_tool: vec!["s0".into()], ..SolveOptions::default() };
        let pieces = Pieces::new(&nominal, &data, &options).unwrap();
        let frames = pieces.closed_form_frames(&pieces.model);
        let start = start_probe_rotation(&pieces.model, &data, &frames);
        let arm: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
        let problem = pieces.problem(arm, &pieces.model, &frames, start);
        let tools = vec![Vector3::zeros()];
        // Near the solution: an orientation row's derivative takes its residual for small (and
        // the rotation vector of a rotation of 1e-8 rad reads as zero).
        let mut x = pieces.x_of(&problem, &pieces.model, &frames, &tools, &[Vec::new()]);
        let c = problem.layout.rotation_column().expect("the probe rotation is fitted");
        x[c..c + 3].copy_from_slice(&[0.02, -0.01, 0.015]);
        // A larger step: the rotation vector of an orientation residual is extracted iteratively,
        // to about 1e-12 rad, which a step of 1e-6 would show.
        check_jacobian(&problem, &x, 1e-4);
    }
}
