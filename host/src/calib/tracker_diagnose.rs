//! Diagnosis of a tracker run: which library effect or data error the calibrated model misses,
//! chosen on the calibration sessions, confirmed on the held-out sessions (each base refitted).
//!
//! *Candidates.* Every effect of the library (`Effect::library`: geometry, harmonics 1–4,
//! compliance, scale) not yet free in the model is added to the calibrated model and refitted
//! warm on the calibration sessions (bases, tool and every free parameter together, the
//! identifiability step included: an effect whose parameters the session bases and the tool
//! absorb is *not identifiable* and named so). Beside them the data errors of
//! [`crate::calib::tracker_errors`]: the tool moved in a calibration session (`--float-tool`), a
//! session's base drifting (`--drift-session`) and single bad points (`--exclude-point`).
//!
//! *Selection* never sees the held-out sessions. The [`CROSS_VALIDATED`] arm effects with the
//! largest drop of the calibration residual (on the χ² scale, a normal deviate) and every
//! calibration-session data error are cross-validated: each calibration session is cut into
//! [`FOLDS`] contiguous pose blocks, fold k leaves block k of every session out, and the left-out
//! points are predicted with the bases fitted on the rest. The *CV gain* is ln(MSE_before /
//! MSE_with) over the left-out points.
//!
//! *Confirmation* on the held-out sessions. The unit of the test is a contiguous block of poses of
//! a held-out session (at most [`UNITS_PER_SESSION`] per session, at least [`MIN_UNIT_POINTS`]
//! points each): instrument noise is independent from point to point, so under "no effect" the
//! blocks' log MSE ratios ln(MSE_before / MSE_with) are independent and (up to the candidate's own
//! fitted noise, which only makes the held-out error worse) symmetric about zero. The base of each
//! held-out session is refitted on the whole session for each model, which couples the blocks of a
//! session through six values fitted on all of its points (small against the points). The p value
//! is `diagnose::held_out_p` (sign-flip and t test, weighted Bonferroni). Candidates are tested in
//! a fixed sequence, in the order of their CV gain (calibration data only), each at
//! [`FAMILY_ALPHA`], stopping at the first that fails: the family-wise error stays at 0.05. A
//! candidate enters the sequence only when its CV gain promises the practical gain (a CV RMS
//! lower by [`SIGNIFICANT_GAIN`] for an arm effect, [`MIN_GAIN`] for a data error), and must
//! then lower the held-out RMS by as much.
//!
//! *Naming.* The first significant candidate leads. Every other significant one that it does not
//! beat on the held-out blocks (paired sign-flip and t test of ln(MSE_B / MSE_A) at
//! [`FAMILY_ALPHA`]) is its rival: "A or B: these data cannot tell them apart", never A alone. A
//! significant data error whose held-out RMS is within [`DATA_ERROR_EXPLAINS`] of the leading arm
//! effect's is named instead and no arm effect is claimed. A tool moved in a held-out session is
//! scored by `tracker_errors` (its offset is fitted on that session's own points, so the held-out
//! test would be in-sample) and reported with its own rule.
//!
//! *Floor and the model-free check.* The floor is [`point_floor`] (repeated poses, else the
//! stated σ, else unknown: then the model is never said to explain the data). The model explains
//! the data within [`EXPLAINS_WITHIN`] of the floor; it misses when the gap is beyond [`GAP_Z`]
//! standard errors of what the fitted parameters and the sampling allow (`Gap`); in between,
//! kincal cannot tell. Whatever the floor,
//! the *neighbour bound* U = √(½ · mean |r_i − r_nn(i)|²), with r the held-out residuals (base
//! refitted) and nn(i) the nearest other point of the same session in joint space (degrees),
//! bounds from above the noise (3-D RMS) plus the part of the model error that differs between
//! neighbours: U² = σ²₃ + ½·mean |f(q_i) − f(q_nn(i))|² for residuals r = f(q) + noise. A held-out
//! RMS beyond [`NEIGHBOUR_MARGIN`] × U therefore shows a model error that changes slowly over the
//! joint space, beyond the noise: the model is called incomplete without any stated σ. A held-out
//! RMS below it says nothing (neighbours too far apart for a smooth error to agree).

use crate::calib::diagnose::{chi2_z, held_out_p, DATA_ERROR_EXPLAINS, FAMILY_ALPHA, SIGNIFICANT_GAIN};
use crate::calib::fit::{calibrate, Fit};
use crate::calib::floor::{point_floor, PointFloor};
use crate::calib::nuisance::drift::DriftSpec;
use crate::calib::run::{exclude_points, RunError, EXPLAINS_WITHIN};
use crate::calib::setup::SolveOptions;
use crate::calib::summary::{RunInputs, Summary};
use crate::calib::tracker_errors::sessions;
use crate::calib::tracker_errors::{data_error_candidates, DataError, MIN_GAIN};
use crate::calib::validate::{calibration_errors, fit_session_with_tool, session_residuals};
use crate::data::Observations;
use crate::model::effects::{Effect, EffectKind};
use crate::model::ArmModel;
use rayon::prelude::*;

/// Contiguous pose blocks per calibration session for the cross-validation.
pub const FOLDS: usize = 5;
/// Arm effects cross-validated, largest calibration evidence first.
pub const CROSS_VALIDATED: usize = 5;
/// Most test units (contiguous pose blocks) per held-out session.
pub const UNITS_PER_SESSION: usize = 8;
/// Fewest points of a test unit.
pub const MIN_UNIT_POINTS: usize = 6;
/// Held-out RMS beyond this many neighbour bounds: the model is incomplete (model-free check).
pub const NEIGHBOUR_MARGIN: f64 = 1.5;
/// Fewest held-out points for the neighbour bound.
pub const MIN_NEIGHBOUR_POINTS: usize = 20;

/// What a tracker calibration is given: the model and the options the command line sets.
#[derive(Clone, Debug)]
pub struct TrackerSetup {
    /// The model file's arm with the added effects.
    pub model: ArmModel,
    /// Effects added (`--add`).
    pub added: Vec<String>,
    /// Sessions whose tool floats (`--float-tool`), calibration or held out.
    pub float_tool: Vec<String>,
    /// Calibration sessions that drift, and how (`--drift-session SESSION:KIND`).
    pub drift_sessions: Vec<DriftSpec>,
    /// Calibration points left out (`--exclude-point SESSION:LINE`).
    pub exclude_points: Vec<String>,
    /// `--orientation-sigma-deg`.
    pub orientation_sigma_deg: Option<f64>,
    /// `--sigma-mm`.
    pub stated_sigma_mm: Option<f64>,
}

impl TrackerSetup {
    /// The setup of a run's inputs, `model` being its nominal model with the added effects.
    pub fn of(inputs: &RunInputs, model: ArmModel) -> TrackerSetup {
        TrackerSetup {
            model,
            added: inputs.add.clone(),
            float_tool: inputs.float_tool.clone(),
            drift_sessions: inputs.drift_sessions.clone(),
            exclude_points: inputs.exclude_points.clone(),
            orientation_sigma_deg: inputs.orientation_sigma_deg,
            stated_sigma_mm: inputs.stated_sigma_mm,
        }
    }

    /// The command-line options that make this setup, beyond the data folders and the model.
    pub fn options_text(&self) -> String {
        let mut out = Vec::new();
        out.extend(self.added.iter().map(|e| format!("--add {e}")));
        out.extend(self.float_tool.iter().map(|s| format!("--float-tool {s}")));
        out.extend(self.drift_sessions.iter().map(|s| format!("--drift-session {s}")));
        out.extend(self.exclude_points.iter().map(|s| format!("--exclude-point {s}")));
        out.join(" ")
    }
}

/// One change to a setup: an effect added, or a data error's remedy.
#[derive(Clone, Debug, PartialEq)]
pub enum Change {
    /// Add a library effect to the model.
    Effect(Effect),
    /// Let the tool float in a session (a re-mounted probe).
    FloatTool(String),
    /// Let a calibration session drift (its base or its scale, in time or temperature).
    Drift(DriftSpec),
    /// Leave calibration points out (`SESSION:LINE`).
    Exclude(Vec<String>),
}

impl Change {
    /// The setup with this change.
    pub fn apply(&self, setup: &TrackerSetup) -> TrackerSetup {
        let mut out = setup.clone();
        match self {
            Change::Effect(e) => {
                e.add_to(&mut out.model);
                out.added.push(e.to_string());
            }
            Change::FloatTool(s) => out.float_tool.push(s.clone()),
            Change::Drift(s) => out.drift_sessions.push(s.clone()),
            Change::Exclude(points) => out.exclude_points.extend(points.iter().cloned()),
        }
        out
    }

    /// The `kincal calibrate` option that applies it.
    pub fn action(&self) -> String {
        match self {
            Change::Effect(e) => format!("--add {e}"),
            Change::FloatTool(s) => format!("--float-tool {s}"),
            Change::Drift(s) => format!("--drift-session {s}"),
            Change::Exclude(points) => {
                points.iter().map(|p| format!("--exclude-point {p}")).collect::<Vec<_>>().join(" ")
            }
        }
    }

    /// Its name in the diagnosis: the effect, or the data error's kind and place.
    pub fn name(&self) -> String {
        match self {
            Change::Effect(e) => e.to_string(),
            Change::FloatTool(x) => format!("tool moved: {x}"),
            Change::Drift(x) => format!("drift: {x}"),
            Change::Exclude(p) => format!("bad points: {}", p.join(", ")),
        }
    }

    /// The remedy of a data error of `tracker_errors`.
    fn of_data_error(d: &DataError) -> Option<Change> {
        match d.kind.as_str() {
            "tool moved" => Some(Change::FloatTool(d.session.clone())),
            "drift" => d.action.strip_prefix("--drift-session ")?.trim().parse().ok().map(Change::Drift),
            "bad points" => {
                let points: Vec<String> = d
                    .action
                    .split_whitespace()
                    .filter(|w| *w != "--exclude-point")
                    .map(str::to_string)
                    .collect();
                (!points.is_empty()).then_some(Change::Exclude(points))
            }
            _ => None,
        }
    }
}

/// A setup calibrated, with its held-out errors.
#[derive(Clone, Debug)]
pub struct Fitted {
    /// The calibration.
    pub fit: Fit,
    /// Position error of every held-out point, per held-out session in file order, mm (each
    /// session's base refitted, and its tool where it floats).
    pub held_out: Vec<Vec<f64>>,
}

impl Fitted {
    /// Pooled held-out RMS, mm.
    pub fn held_out_rms_mm(&self) -> f64 {
        pooled_rms(self.held_out.iter().flatten())
    }
}

fn pooled_rms<'a>(errors: impl Iterator<Item = &'a f64>) -> f64 {
    let (sum, n) = errors.fold((0.0, 0usize), |(s, n), e| (s + e * e, n + 1));
    (sum / n.max(1) as f64).sqrt()
}

fn calibration_options(setup: &TrackerSetup, cal: &Observations) -> SolveOptions {
    SolveOptions {
        float_tool: setup.float_tool.iter().filter(|n| cal.find_group(n).is_some()).cloned().collect(),
        orientation_sigma_deg: setup.orientation_sigma_deg,
        drift_sessions: setup.drift_sessions.clone(),
        ..SolveOptions::default()
    }
}

/// The tool offset a held-out session gets: its own (fitted there) when it floats.
fn held_out_offset(model: &ArmModel, val: &Observations, b: usize, float_tool: &[String]) -> [f64; 3] {
    if float_tool.contains(&val.block_name(b)) {
        fit_session_with_tool(model, val, b).0.offset_mm
    } else {
        [0.0; 3]
    }
}

/// Held-out residual vectors of `model` on every session of `val`, mm (each base refitted, and
/// the tool of the sessions in `float_tool`).
pub fn held_out_residuals(
    model: &ArmModel,
    val: &Observations,
    float_tool: &[String],
) -> Vec<Vec<nalgebra::Vector3<f64>>> {
    sessions(val)
        .into_iter()
        .map(|b| session_residuals(model, val, b, held_out_offset(model, val, b, float_tool)))
        .collect()
}

/// Calibrate `setup` (warm from `start` when given: a calibrated model with the same free
/// parameters, or more) and validate it on `val`.
pub fn fit_setup(
    setup: &TrackerSetup,
    cal: &Observations,
    val: &Observations,
    start: Option<&ArmModel>,
) -> Result<Fitted, RunError> {
    let kept = exclude_points(cal, &setup.exclude_points)?;
    let fit = calibrate(start.unwrap_or(&setup.model), &kept, &calibration_options(setup, &kept))?;
    let held_out = held_out_residuals(&fit.model, val, &setup.float_tool)
        .iter()
        .map(|r| r.iter().map(|v| v.norm()).collect())
        .collect();
    Ok(Fitted { fit, held_out })
}

/// The test units: contiguous pose blocks of each held-out session, `(session, first, end)`.
pub fn test_units(val: &Observations) -> Vec<(usize, usize, usize)> {
    let mut out = Vec::new();
    for (s, b) in sessions(val).into_iter().enumerate() {
        let n = val.blocks[b].members.len();
        let blocks = (n / MIN_UNIT_POINTS).clamp(1, UNITS_PER_SESSION);
        out.extend((0..blocks).map(|b| (s, b * n / blocks, (b + 1) * n / blocks)));
    }
    out
}

fn unit_mse(errors: &[Vec<f64>], units: &[(usize, usize, usize)]) -> Vec<f64> {
    units
        .iter()
        .map(|&(s, a, b)| errors[s][a..b].iter().map(|e| e * e).sum::<f64>() / (b - a).max(1) as f64)
        .collect()
}

/// Per test unit, ln(MSE_before / MSE_after): positive where `after` is better.
fn log_ratios(before: &[Vec<f64>], after: &[Vec<f64>], units: &[(usize, usize, usize)]) -> Vec<f64> {
    unit_mse(before, units)
        .iter()
        .zip(unit_mse(after, units))
        .map(|(b, a)| (b.max(1e-300) / a.max(1e-300)).ln())
        .collect()
}

/// One candidate scored.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerCandidate {
    /// `compliance:2`, or a data error's kind and session.
    pub name: String,
    /// `effect` or `data error`.
    pub kind: String,
    /// The `kincal calibrate` option that applies it.
    pub action: String,
    /// Calibration RMS with it, mm.
    pub calibration_rms_mm: f64,
    /// Drop of the calibration residual as a standard normal deviate (χ² with the candidate's
    /// parameter count, on the calibration points).
    pub calibration_z: f64,
    /// ln(MSE_before / MSE_with) over the cross-validated calibration points, when
    /// cross-validated.
    pub cv_gain: Option<f64>,
    /// Held-out RMS with it, mm.
    pub held_out_rms_mm: f64,
    /// Test units improved, of all.
    pub units_improved: (usize, usize),
    /// Held-out p, when the fixed sequence reached it.
    pub p_value: Option<f64>,
    /// Significant (sequence, p, practical gain, CV gain).
    pub significant: bool,
    /// Fitted values of the effect's parameters `(name, value, std)`.
    pub fitted: Vec<(String, f64, Option<f64>)>,
    /// The sentence a user reads.
    pub text: String,
}

/// An effect the data cannot determine.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct NotDetermined {
    /// The effect.
    pub effect: String,
    /// Why, from the identifiability step.
    pub reason: String,
}

/// The neighbour bound of one held-out session's residuals (see the module's doc comment).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct NeighbourBound {
    /// The held-out session.
    pub session: String,
    /// Its points.
    pub points: usize,
    /// Its held-out RMS, mm.
    pub rms_mm: f64,
    /// U = √(½ · mean |r_i − r_nn(i)|²), mm: at least the noise's 3-D RMS.
    pub bound_mm: f64,
    /// Median joint-space distance to the nearest neighbour, degrees.
    pub median_distance_deg: f64,
    /// Held-out RMS beyond [`NEIGHBOUR_MARGIN`] × U.
    pub incomplete: bool,
}

/// The diagnosis of a tracker run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerDiagnosis {
    /// Held-out RMS of the calibrated model, mm.
    pub held_out_rms_mm: f64,
    /// Held-out RMS per session `(name, points, rms_mm)`.
    pub sessions: Vec<(String, usize, f64)>,
    /// Test units (contiguous pose blocks of the held-out sessions).
    pub units: usize,
    /// The floor.
    pub floor: PointFloor,
    /// The neighbour bound of each held-out session with enough points.
    pub neighbours: Vec<NeighbourBound>,
    /// Arm effects, in the order of the fixed sequence (cross-validated first), then the others.
    pub candidates: Vec<TrackerCandidate>,
    /// Data errors scored beside them (calibration sessions), in sequence order.
    pub data_errors: Vec<TrackerCandidate>,
    /// A tool moved in a held-out session (`tracker_errors`' own rule), best first.
    pub held_out_tools: Vec<DataError>,
    /// Effects the data cannot determine.
    pub not_identifiable: Vec<NotDetermined>,
    /// What is named: one candidate, or rivals the data cannot tell apart.
    pub named: Vec<String>,
    /// The remedy of what is named first, as `kincal calibrate` options.
    pub action: Option<String>,
    /// The model explains the held-out data (a known floor, within [`EXPLAINS_WITHIN`]).
    pub explains: bool,
    /// The model is shown incomplete (a gap to the floor beyond [`GAP_Z`] standard errors, or by
    /// the neighbour bound).
    pub incomplete: bool,
    /// The verdict, in words.
    pub summary: Vec<String>,
    /// Seconds spent.
    pub seconds: f64,
    /// The change of what is named first (not serialised).
    #[serde(skip)]
    pub change: Option<Change>,
    /// The calibrated model diagnosed (not serialised).
    #[serde(skip)]
    pub model: Option<ArmModel>,
}

/// The neighbour bound of each held-out session with enough points, from its residuals.
fn neighbour_bounds(val: &Observations, residuals: &[Vec<nalgebra::Vector3<f64>>]) -> Vec<NeighbourBound> {
    let mut out = Vec::new();
    for (b, r) in sessions(val).into_iter().zip(residuals) {
        let q: Vec<&[f64]> = val.blocks[b].members.iter().map(|&k| &val.obs[k].q_deg[..]).collect();
        if q.len() < MIN_NEIGHBOUR_POINTS {
            continue;
        }
        let mut squares = Vec::new();
        let mut distances = Vec::new();
        for i in 0..q.len() {
            let nearest = (0..q.len())
                .filter(|&j| j != i)
                .map(|j| (j, q[i].iter().zip(q[j]).map(|(a, b)| (a - b).powi(2)).sum::<f64>()))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((j, d2)) = nearest {
                squares.push((r[i] - r[j]).norm_squared());
                distances.push(d2.sqrt());
            }
        }
        let bound_mm = (squares.iter().sum::<f64>() / (2.0 * squares.len() as f64)).sqrt();
        let rms_mm = pooled_rms(r.iter().map(|v| v.norm()).collect::<Vec<_>>().iter());
        out.push(NeighbourBound {
            session: val.block_name(b),
            points: q.len(),
            rms_mm,
            bound_mm,
            median_distance_deg: crate::numerics::stats::median(distances),
            incomplete: rms_mm > NEIGHBOUR_MARGIN * bound_mm,
        });
    }
    out
}

/// Cross-validated error of every calibration point (fold left out), per session in file order;
/// `None` for points the setup leaves out.
fn cross_validate(
    setup: &TrackerSetup,
    cal: &Observations,
    start: &ArmModel,
) -> Option<Vec<Vec<Option<f64>>>> {
    let mut kept = vec![true; cal.obs.len()];
    for name in &setup.exclude_points {
        let found = cal.find_point(name);
        if found.is_empty() {
            return None;
        }
        found.into_iter().for_each(|k| kept[k] = false);
    }
    let sessions = sessions(cal);
    // Each observation's block size and place in its block.
    let mut place = vec![(0usize, 0usize); cal.obs.len()];
    for &b in &sessions {
        let members = &cal.blocks[b].members;
        for (i, &k) in members.iter().enumerate() {
            place[k] = (members.len(), i);
        }
    }
    let fold_of = |n: usize, i: usize| i * FOLDS / n.max(1);
    let folds: Vec<Option<Vec<(usize, usize, f64)>>> = (0..FOLDS)
        .into_par_iter()
        .map(|fold| {
            let pick = |leave: bool| {
                cal.without(|k| {
                    let (n, i) = place[k];
                    !(kept[k] && ((fold_of(n, i) == fold) == leave))
                })
            };
            let (train, test) = (pick(false), pick(true));
            let fit = calibrate(start, &train, &calibration_options(setup, &train)).ok()?;
            let errors = calibration_errors(&fit, &test);
            let tested: Vec<String> = crate::calib::tracker_errors::sessions(&test)
                .into_iter()
                .map(|b| test.block_name(b))
                .collect();
            let mut out = Vec::new();
            for (s, &b) in sessions.iter().enumerate() {
                let Some(at) = tested.iter().position(|n| *n == cal.block_name(b)) else { continue };
                let members = &cal.blocks[b].members;
                let n = members.len();
                let indices = (0..n).filter(|&i| kept[members[i]] && fold_of(n, i) == fold);
                out.extend(indices.zip(&errors[at]).map(|(i, &err)| (s, i, err)));
            }
            Some(out)
        })
        .collect();
    let mut out: Vec<Vec<Option<f64>>> =
        sessions.iter().map(|&b| vec![None; cal.blocks[b].members.len()]).collect();
    for fold in folds {
        for (s, i, e) in fold? {
            out[s][i] = Some(e);
        }
    }
    Some(out)
}

/// ln(MSE_before / MSE_after) over the points both cross-validations predicted.
fn cv_gain(before: &[Vec<Option<f64>>], after: &[Vec<Option<f64>>]) -> f64 {
    let (mut b, mut a) = (0.0, 0.0);
    for (x, y) in before.iter().flatten().zip(after.iter().flatten()) {
        if let (Some(x), Some(y)) = (x, y) {
            b += x * x;
            a += y * y;
        }
    }
    (b.max(1e-300) / a.max(1e-300)).ln()
}

/// A candidate refitted: its change, fit and calibration evidence.
struct Scored {
    change: Change,
    fitted: Fitted,
    calibration_z: f64,
    cv_gain: Option<f64>,
    text: String,
}

fn calibration_z(baseline: &Fit, with: &Fit, k: usize) -> f64 {
    let points = |f: &Fit| f.stats.points.unwrap_or_default();
    let rss = |f: &Fit| points(f).rms_mm.powi(2) * points(f).count as f64;
    let rows = 3.0 * points(baseline).count as f64;
    // Points left out (bad points) change the sum itself: compare mean squares.
    let drop = rows
        * (1.0
            - (rss(with) / points(with).count.max(1) as f64)
                / (rss(baseline) / points(baseline).count.max(1) as f64).max(1e-300));
    chi2_z(drop, k)
}

/// Diagnose the setup: score every candidate, test them, name what is missing.
pub fn diagnose_tracker(
    setup: &TrackerSetup,
    cal: &Observations,
    val: &Observations,
) -> Result<TrackerDiagnosis, RunError> {
    let started = std::time::Instant::now();
    let baseline = fit_setup(setup, cal, val, None)?;
    let before_rms = baseline.held_out_rms_mm();
    let units = test_units(val);
    let floor = point_floor(val, setup.stated_sigma_mm);
    let residuals = held_out_residuals(&baseline.fit.model, val, &setup.float_tool);
    let neighbours = neighbour_bounds(val, &residuals);
    // Arm effects, each refitted warm.
    let joints = setup.model.joints.len();
    let library: Vec<Effect> = Effect::library(joints)
        .into_iter()
        .filter(|e| e.kind != EffectKind::Tcp && !e.is_in(&baseline.fit.model))
        .collect();
    let refits: Vec<(Effect, Option<Fitted>)> = library
        .par_iter()
        .map(|&e| {
            let change = Change::Effect(e);
            let mut start = baseline.fit.model.clone();
            e.add_to(&mut start);
            (e, fit_setup(&change.apply(setup), cal, val, Some(&start)).ok())
        })
        .collect();
    let mut not_identifiable = Vec::new();
    let mut effects = Vec::new();
    for (e, fitted) in refits {
        let Some(fitted) = fitted else {
            not_identifiable.push(NotDetermined { effect: e.to_string(), reason: "the refit failed".into() });
            continue;
        };
        let names: Vec<String> = e.params().iter().map(|p| p.to_string()).collect();
        let estimated = e.params().iter().filter(|p| fitted.fit.estimated.contains(p)).count();
        if estimated == 0 {
            let reason = fitted
                .fit
                .statements
                .iter()
                .find(|s| names.iter().any(|n| s.starts_with(&format!("{n} "))))
                .cloned()
                .unwrap_or_else(|| "the data cannot determine it".into());
            not_identifiable.push(NotDetermined { effect: e.to_string(), reason });
            continue;
        }
        let z = calibration_z(&baseline.fit, &fitted.fit, estimated);
        effects.push(Scored {
            change: Change::Effect(e),
            fitted,
            calibration_z: z,
            cv_gain: None,
            text: String::new(),
        });
    }
    effects.sort_by(|a, b| b.calibration_z.total_cmp(&a.calibration_z));
    // Data errors of the calibration sessions; a tool moved in a held-out session keeps its rule.
    let options = SolveOptions { float_tool: setup.float_tool.clone(), ..calibration_options(setup, cal) };
    let kept = exclude_points(cal, &setup.exclude_points)?;
    let found = data_error_candidates(&setup.model, &kept, val, &baseline.fit, &options);
    let held_out_tools: Vec<DataError> = found.iter().filter(|d| d.set == "validation").cloned().collect();
    let mut errors: Vec<Scored> = found
        .iter()
        .filter(|d| d.set == "calibration")
        .filter_map(|d| {
            let change = Change::of_data_error(d)?;
            let fitted = fit_setup(&change.apply(setup), cal, val, Some(&baseline.fit.model)).ok()?;
            let z = calibration_z(&baseline.fit, &fitted.fit, 3);
            Some(Scored { change, fitted, calibration_z: z, cv_gain: None, text: d.text.clone() })
        })
        .collect();
    // Cross-validate the strongest arm effects and every data error.
    let cv_before = cross_validate(setup, cal, &baseline.fit.model);
    if let Some(before) = &cv_before {
        let chosen: Vec<&mut Scored> =
            effects.iter_mut().take(CROSS_VALIDATED).chain(errors.iter_mut()).collect();
        let gains: Vec<Option<f64>> = chosen
            .par_iter()
            .map(|s| {
                let changed = s.change.apply(setup);
                let mut start = baseline.fit.model.clone();
                if let Change::Effect(e) = s.change {
                    e.add_to(&mut start);
                }
                cross_validate(&changed, cal, &start).map(|after| cv_gain(before, &after))
            })
            .collect();
        for (s, g) in chosen.into_iter().zip(gains) {
            s.cv_gain = g;
        }
    }
    // The fixed sequence: cross-validated candidates whose CV gain promises the practical gain,
    // by CV gain.
    let promising = |s: &Scored, needed: f64| s.cv_gain.is_some_and(|g| g >= -2.0 * (1.0 - needed).ln());
    let mut sequence: Vec<(bool, usize)> = (0..effects.len())
        .filter(|&k| promising(&effects[k], SIGNIFICANT_GAIN))
        .map(|k| (false, k))
        .chain((0..errors.len()).filter(|&k| promising(&errors[k], MIN_GAIN)).map(|k| (true, k)))
        .collect();
    let gain_of = |&(is_error, k): &(bool, usize)| {
        if is_error { errors[k].cv_gain } else { effects[k].cv_gain }.unwrap_or(f64::NEG_INFINITY)
    };
    sequence.sort_by(|a, b| gain_of(b).total_cmp(&gain_of(a)));
    let score = |s: &Scored, tested: Option<f64>, significant: bool, is_error: bool| {
        let after = s.fitted.held_out_rms_mm();
        let ratios = log_ratios(&baseline.held_out, &s.fitted.held_out, &units);
        let fitted: Vec<(String, f64, Option<f64>)> = match s.change {
            Change::Effect(e) => e
                .params()
                .iter()
                .filter_map(|p| {
                    let name = p.to_string();
                    let est = s.fitted.fit.estimates.iter().find(|x| x.param == name)?;
                    Some((name, est.value, est.std))
                })
                .collect(),
            _ => Vec::new(),
        };
        let values = fitted
            .iter()
            .map(|(n, v, sd)| match sd {
                Some(sd) => format!("{n} = {v:.4} ± {sd:.4}"),
                None => format!("{n} = {v:.4} (held)"),
            })
            .collect::<Vec<_>>()
            .join(", ");
        let name = s.change.name();
        let text = if is_error {
            s.text.clone()
        } else {
            format!("{name} ({values}): held-out RMS {before_rms:.4} → {after:.4} mm")
        };
        TrackerCandidate {
            name,
            kind: if is_error { "data error" } else { "effect" }.into(),
            action: s.change.action(),
            calibration_rms_mm: s.fitted.fit.rms_mm,
            calibration_z: s.calibration_z,
            cv_gain: s.cv_gain,
            held_out_rms_mm: after,
            units_improved: (ratios.iter().filter(|r| **r > 0.0).count(), ratios.len()),
            p_value: tested,
            significant,
            fitted,
            text,
        }
    };
    let mut outcome: Vec<(bool, usize, Option<f64>, bool)> = Vec::new();
    let mut open = true;
    for &(is_error, k) in &sequence {
        if !open {
            outcome.push((is_error, k, None, false));
            continue;
        }
        let s = if is_error { &errors[k] } else { &effects[k] };
        let p = held_out_p(&log_ratios(&baseline.held_out, &s.fitted.held_out, &units));
        let needed = if is_error { MIN_GAIN } else { SIGNIFICANT_GAIN };
        let gain = 1.0 - s.fitted.held_out_rms_mm() / before_rms.max(1e-300);
        let significant = p < FAMILY_ALPHA && gain >= needed;
        open = significant;
        outcome.push((is_error, k, Some(p), significant));
    }
    let mut candidates = Vec::new();
    let mut data_errors = Vec::new();
    for &(is_error, k, p, significant) in &outcome {
        if is_error {
            data_errors.push(score(&errors[k], p, significant, true));
        } else {
            candidates.push(score(&effects[k], p, significant, false));
        }
    }
    for (k, s) in effects.iter().enumerate() {
        if !sequence.contains(&(false, k)) {
            candidates.push(score(s, None, false, false));
        }
    }
    for (k, s) in errors.iter().enumerate() {
        if !sequence.contains(&(true, k)) {
            data_errors.push(score(s, None, false, true));
        }
    }
    // Naming: the first significant leads; rivals it does not beat on the held-out blocks.
    let significant: Vec<(bool, usize)> = outcome.iter().filter(|o| o.3).map(|o| (o.0, o.1)).collect();
    let scored_of = |&(is_error, k): &(bool, usize)| if is_error { &errors[k] } else { &effects[k] };
    let mut named = Vec::new();
    let mut change = None;
    let mut summary = Vec::new();
    let best_error = significant.iter().find(|s| s.0);
    let lead = significant.first().map(|first| match (first.0, best_error) {
        (false, Some(e))
            if scored_of(e).fitted.held_out_rms_mm()
                <= DATA_ERROR_EXPLAINS * scored_of(first).fitted.held_out_rms_mm() =>
        {
            *e
        }
        _ => *first,
    });
    if let Some(lead) = lead {
        let a = scored_of(&lead);
        named.push(a.change.name());
        change = Some(a.change.clone());
        let mut rivals = Vec::new();
        if !lead.0 {
            for other in significant.iter().filter(|o| !o.0 && **o != lead) {
                let b = scored_of(other);
                // ln(MSE_B / MSE_A) per unit: positive where A is better.
                let d = log_ratios(&b.fitted.held_out, &a.fitted.held_out, &units);
                let p = held_out_p(&d);
                if p >= FAMILY_ALPHA {
                    rivals.push(format!(
                        "{} reaches {:.4} mm held out (that {} does better: p {p:.2})",
                        b.change.name(),
                        b.fitted.held_out_rms_mm(),
                        a.change.name()
                    ));
                    named.push(b.change.name());
                }
            }
        }
        let c = score(a, None, true, lead.0);
        if lead.0 {
            summary.push(format!(
                "data error: {} ({}/{} held-out blocks improved); no arm effect is claimed: fix the data first",
                c.text, c.units_improved.0, c.units_improved.1
            ));
        } else if rivals.is_empty() {
            summary.push(format!(
                "missing effect: {} ({}/{} held-out blocks improved)",
                c.text, c.units_improved.0, c.units_improved.1
            ));
        } else {
            summary.push(format!(
                "missing effect: {} or {}: these held-out data cannot tell them apart; {}",
                named[0],
                named[1..].join(" or "),
                c.text
            ));
            summary.push(format!("rivals of {}: {}", named[0], rivals.join("; ")));
        }
        summary.push(format!(
            "what to do: kincal calibrate … {} (the run's options: {})",
            a.change.action(),
            if setup.options_text().is_empty() { "none".into() } else { setup.options_text() }
        ));
    } else if !sequence.is_empty() {
        summary.push("no candidate effect or data error improves the held-out sessions significantly".into());
    } else {
        summary.push(
            "no candidate effect or data error promises a practical gain in the cross-validation on the calibration \
             sessions: none was tested on the held-out sessions"
                .into(),
        );
    }
    for t in held_out_tools.iter().filter(|d| d.significant) {
        summary.push(format!("data error in a held-out session: {} (apply with {})", t.text, t.action));
    }
    // How far from done.
    let with = lead.map(|l| scored_of(&l).fitted.held_out_rms_mm());
    let gap =
        floor.rms_mm.map(|f| Gap::of(f, before_rms, &baseline.fit, val, floor.source == "repeated poses"));
    let (explains, mut incomplete) = match (floor.rms_mm, &gap) {
        (Some(f), Some(g)) => {
            let explains = before_rms <= EXPLAINS_WITHIN * f;
            let misses = !explains && g.z > GAP_Z;
            summary.insert(
                0,
                if explains {
                    format!(
                        "the model explains the held-out data: {before_rms:.4} mm against a floor of {f:.4} mm ({})",
                        floor.source
                    )
                } else if misses {
                    format!(
                        "{before_rms:.4} mm held out, floor {f:.4} mm ({}): the model misses about {:.4} mm ({:.1} \
                         standard errors above what the fitted parameters and the noise leave)",
                        floor.source,
                        (before_rms * before_rms - f * f).max(0.0).sqrt(),
                        g.z
                    )
                } else {
                    format!(
                        "{before_rms:.4} mm held out, floor {f:.4} mm ({}): {:.2}× the floor, within what the fitted \
                         parameters and the sampling of {} held-out points allow ({:.1} standard errors): cannot tell; \
                         more held-out points would tell",
                        floor.source,
                        before_rms / f,
                        val.point_count(),
                        g.z
                    )
                },
            );
            (explains, misses)
        }
        _ => {
            summary.insert(
                0,
                format!(
                    "{before_rms:.4} mm held out; the floor is unknown (no repeated poses, no stated uncertainty): \
                     the model cannot be called explained"
                ),
            );
            (false, false)
        }
    };
    for n in &neighbours {
        let line = format!(
            "neighbour check of {} (no floor needed): residuals of the nearest poses in joint space (median {:.1}° \
             apart) differ by {:.4} mm (RMS/√2), an upper bound on noise plus small-scale error",
            n.session, n.median_distance_deg, n.bound_mm
        );
        if n.incomplete {
            incomplete = true;
            summary.push(format!(
                "{line}; {:.4} mm held out there is {:.2}× that: the model is incomplete (an error that varies slowly \
                 over the joint space is left)",
                n.rms_mm,
                n.rms_mm / n.bound_mm
            ));
        } else {
            summary.push(format!(
                "{line}; {:.4} mm held out there is {:.2}× that, within {NEIGHBOUR_MARGIN}×: this check cannot tell",
                n.rms_mm,
                n.rms_mm / n.bound_mm
            ));
        }
    }
    if let (Some(f), Some(w), Some(g)) = (floor.rms_mm, with, &gap) {
        if w > EXPLAINS_WITHIN * f && g.at(w) > GAP_Z {
            summary.push(format!(
                "even with {} the model would miss about {:.4} mm ({w:.4} mm held out against {f:.4} mm): the model \
                 is incomplete",
                named.first().map_or("it", |s| s.as_str()),
                (w * w - f * f).max(0.0).sqrt()
            ));
        }
    }
    if incomplete && lead.is_none() {
        summary.push("the cause is not in the effect library nor among the data errors kincal scores".into());
    }
    Ok(TrackerDiagnosis {
        held_out_rms_mm: before_rms,
        sessions: sessions(val)
            .into_iter()
            .zip(&baseline.held_out)
            .map(|(b, e)| (val.block_name(b), e.len(), pooled_rms(e.iter())))
            .collect(),
        units: units.len(),
        floor,
        neighbours,
        candidates,
        data_errors,
        held_out_tools,
        not_identifiable,
        action: change.as_ref().map(Change::action),
        named,
        explains,
        incomplete,
        summary,
        seconds: started.elapsed().as_secs_f64(),
        change,
        model: Some(baseline.fit.model),
    })
}

/// Standard errors above which the gap between the held-out RMS and the floor is called.
pub const GAP_Z: f64 = 2.5;

/// The test of the gap to the floor: the held-out mean square M against what a complete model
/// leaves, E = floor² · (1 + p / (ν_cal − 6·S)) (p the estimated arm and tool values, ν_cal = 3 per
/// calibration point, six base values per calibration session), with the standard error of M/E
/// √(2/ν_val + 2/ν_floor) (ν_val = 3 per held-out point less six per session; ν_floor from the
/// repeats when the floor comes from them, none for a stated σ). Gaussian noise assumed.
#[derive(Clone, Copy, Debug)]
struct Gap {
    expected_ms: f64,
    standard_error: f64,
    z: f64,
}

impl Gap {
    fn of(floor_mm: f64, rms_mm: f64, fit: &Fit, val: &Observations, repeats: bool) -> Gap {
        let frames = fit.frames.len() as f64;
        let points = fit.stats.points.map_or(0, |p| p.count);
        let nu_cal = (3.0 * points as f64 - 6.0 * frames).max(1.0_f64);
        let p = fit.estimated.len() as f64;
        let expected_ms = floor_mm * floor_mm * (1.0 + p / nu_cal);
        let nu_val = (3.0 * val.point_count() as f64 - 6.0 * sessions(val).len() as f64).max(1.0_f64);
        let nu_floor = if repeats { 3.0 * repeat_groups_dof(val) as f64 } else { f64::INFINITY };
        let standard_error = (2.0 / nu_val + 2.0 / nu_floor.max(1.0)).sqrt();
        let mut gap = Gap { expected_ms, standard_error, z: 0.0 };
        gap.z = gap.at(rms_mm);
        gap
    }

    /// Standard errors by which `rms_mm` lies above what a complete model leaves.
    fn at(&self, rms_mm: f64) -> f64 {
        (rms_mm * rms_mm / self.expected_ms - 1.0) / self.standard_error
    }
}

/// Degrees of freedom of the repeated poses of `val` (repeats beyond the first of each pose).
fn repeat_groups_dof(val: &Observations) -> usize {
    let mut dof = 0;
    for b in sessions(val) {
        let mut groups: std::collections::BTreeMap<&str, usize> = std::collections::BTreeMap::new();
        for p in val.blocks[b].members.iter().map(|&k| &val.obs[k]) {
            if let Some(pose) = &p.pose {
                *groups.entry(pose).or_default() += 1;
            }
        }
        dof += groups.values().map(|n| n.saturating_sub(1)).sum::<usize>();
    }
    dof
}

/// Why the auto loop stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TrackerStop {
    /// The held-out RMS is within [`EXPLAINS_WITHIN`] of a known floor.
    AtFloor,
    /// Nothing is significant.
    NothingSignificant,
    /// The step limit.
    MaxSteps,
}

/// One step of the auto loop.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerStep {
    /// What was applied (`None` for the start).
    pub applied: Option<String>,
    /// Its `kincal calibrate` option.
    pub action: Option<String>,
    /// Held-out RMS after it, mm.
    pub held_out_rms_mm: f64,
    /// The floor, mm.
    pub floor_mm: Option<f64>,
    /// Its held-out p in the step before.
    pub p_value: Option<f64>,
    /// What this step's diagnosis named (one candidate, or rivals), and whether it is
    /// incomplete.
    pub named: Vec<String>,
    /// This step's diagnosis shows the model incomplete.
    pub incomplete: bool,
    /// The step's calibrated model (not serialised).
    #[serde(skip)]
    pub model: Option<ArmModel>,
}

/// The auto loop on a tracker run.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerAuto {
    /// Steps, the start first.
    pub steps: Vec<TrackerStep>,
    /// Why it stopped.
    pub stop: TrackerStop,
    /// The options of the last step's setup.
    pub options: String,
    /// The last diagnosis.
    pub last: TrackerDiagnosis,
}

/// Diagnose, apply what is named first, recalibrate; until at the floor, nothing is
/// significant, or `max_steps` changes.
pub fn auto_tracker(
    setup: &TrackerSetup,
    cal: &Observations,
    val: &Observations,
    max_steps: usize,
) -> Result<(TrackerAuto, TrackerSetup), RunError> {
    let mut current = setup.clone();
    let mut steps = Vec::new();
    let mut pending: Option<(String, String, Option<f64>)> = None;
    loop {
        let d = diagnose_tracker(&current, cal, val)?;
        let (applied, action, p_value) = match pending.take() {
            Some((a, b, p)) => (Some(a), Some(b), p),
            None => (None, None, None),
        };
        steps.push(TrackerStep {
            applied,
            action,
            held_out_rms_mm: d.held_out_rms_mm,
            floor_mm: d.floor.rms_mm,
            p_value,
            named: d.named.clone(),
            incomplete: d.incomplete,
            model: d.model.clone(),
        });
        let next = match (&d.change, d.explains) {
            (_, true) => Err(TrackerStop::AtFloor),
            (None, _) => Err(TrackerStop::NothingSignificant),
            (Some(_), _) if steps.len() > max_steps => Err(TrackerStop::MaxSteps),
            (Some(c), _) => Ok(c.clone()),
        };
        let change = match next {
            Ok(change) => change,
            Err(stop) => {
                let options = current.options_text();
                return Ok((TrackerAuto { steps, stop, options, last: d }, current));
            }
        };
        let lead = d.candidates.iter().chain(&d.data_errors).find(|c| c.action == change.action());
        pending = Some((
            d.named.first().cloned().unwrap_or_default(),
            change.action(),
            lead.and_then(|c| c.p_value),
        ));
        current = change.apply(&current);
    }
}

/// Why a tracker RUN cannot be diagnosed.
#[derive(Debug, thiserror::Error)]
pub enum TrackerDiagnoseError {
    /// Reading or calibrating failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// The data are not those the RUN was made from.
    #[error("{path}: {what}; the data changed since the calibration (calibrate again)")]
    DataChanged {
        /// The file or folder.
        path: std::path::PathBuf,
        /// What differs.
        what: String,
    },
}

/// Check that `cal` (as read, before exclusions) and `val` are the data `summary` was made from:
/// the same sessions with the same point counts, the same held-out figures, and `calibration_rms_mm`
/// (a fresh calibration of the setup) equal to the stored one.
pub fn check_run_data(
    summary: &Summary,
    cal: &Observations,
    val: &Observations,
    calibration_rms_mm: f64,
) -> Result<(), TrackerDiagnoseError> {
    let changed =
        |path: &std::path::Path, what: String| TrackerDiagnoseError::DataChanged { path: path.into(), what };
    let kept = exclude_points(cal, &summary.inputs.exclude_points)?;
    let source = |data: &Observations, b: usize| data.groups[data.blocks[b].group].source.clone();
    for (name, points) in &summary.calibration.groups {
        match kept.find_group(name) {
            None => {
                return Err(changed(
                    &summary.inputs.calibration,
                    format!("calibration session {name} is no longer there"),
                ))
            }
            Some(g) if kept.group_members(g).len() != *points => {
                let now = kept.group_members(g).len();
                return Err(changed(&kept.groups[g].source, format!("{points} points used, {now} now")));
            }
            Some(_) => {}
        }
    }
    if let Some(b) =
        sessions(&kept).into_iter().find(|&b| !summary.calibration.groups.contains_key(&kept.block_name(b)))
    {
        return Err(changed(&source(&kept, b), "a calibration session the run did not use".into()));
    }
    for f in summary.held_out_sessions() {
        let name = &f.calibrated.name;
        let Some(b) = val.find_block(name) else {
            return Err(changed(
                &summary.inputs.validation,
                format!("held-out session {name} is no longer there"),
            ));
        };
        let now = val.blocks[b].members.len();
        if now != f.calibrated.points {
            return Err(changed(
                &source(val, b),
                format!("{} points held out, {now} now", f.calibrated.points),
            ));
        }
    }
    let stored = summary.calibration.rms_mm;
    if (calibration_rms_mm - stored).abs() > 1e-6 * stored.max(1e-3) {
        return Err(changed(
            &summary.inputs.calibration,
            format!(
                "calibration RMS {stored:.6} mm in summary.json, {calibration_rms_mm:.6} mm on these files"
            ),
        ));
    }
    Ok(())
}

/// One held-out session of two runs side by side.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ComparedSession {
    /// Session name.
    pub name: String,
    /// Points.
    pub points: usize,
    /// Held-out RMS of the run before, mm.
    pub before_rms_mm: f64,
    /// Held-out RMS of the run after, mm.
    pub after_rms_mm: f64,
    /// Base-free pairwise-distance RMS before and after, mm.
    pub pairwise_rms_mm: (f64, f64),
}

/// Two tracker runs on the same held-out sessions.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerComparison {
    /// The held-out sessions both runs validated on.
    pub sessions: Vec<ComparedSession>,
    /// Pooled held-out RMS before and after, mm.
    pub before_rms_mm: f64,
    /// Pooled held-out RMS after, mm.
    pub after_rms_mm: f64,
    /// The floor of each run, mm.
    pub floors_mm: (Option<f64>, Option<f64>),
    /// Test units improved by the run after, of all.
    pub units_improved: (usize, usize),
    /// Held-out p that the run after is better.
    pub p_better: f64,
    /// Held-out p that it is worse.
    pub p_worse: f64,
    /// The verdict, in words.
    pub verdict: Vec<String>,
}

/// Compare two calibrated models (`before`, `after`, each with its run's summary) on the held-out
/// sessions `val` both runs validated on, with the same test units as the diagnosis.
pub fn compare_tracker(
    before: (&Summary, &ArmModel),
    after: (&Summary, &ArmModel),
    val: &Observations,
) -> TrackerComparison {
    let shared = |s: &Summary, name: &str| s.held_out_sessions().iter().any(|f| f.calibrated.name == name);
    let keep: Vec<usize> = (0..val.groups.len())
        .filter(|&g| shared(before.0, &val.groups[g].name) && shared(after.0, &val.groups[g].name))
        .collect();
    let val = val.subset(&keep);
    let errors = |run: (&Summary, &ArmModel)| -> Vec<Vec<f64>> {
        held_out_residuals(run.1, &val, &run.0.inputs.float_tool)
            .iter()
            .map(|r| r.iter().map(|v| v.norm()).collect())
            .collect()
    };
    let (b, a) = (errors(before), errors(after));
    let units = test_units(&val);
    let ratios = log_ratios(&b, &a, &units);
    let negated: Vec<f64> = ratios.iter().map(|r| -r).collect();
    let (p_better, p_worse) = (held_out_p(&ratios), held_out_p(&negated));
    let pairwise = |s: &Summary, name: &str| {
        s.held_out_sessions()
            .iter()
            .find(|f| f.calibrated.name == name)
            .map_or(0.0, |f| f.calibrated.pairwise_rms_mm)
    };
    let sessions: Vec<ComparedSession> = sessions(&val)
        .into_iter()
        .zip(b.iter().zip(&a))
        .map(|(s, (eb, ea))| {
            let name = val.block_name(s);
            ComparedSession {
                points: val.blocks[s].members.len(),
                before_rms_mm: pooled_rms(eb.iter()),
                after_rms_mm: pooled_rms(ea.iter()),
                pairwise_rms_mm: (pairwise(before.0, &name), pairwise(after.0, &name)),
                name,
            }
        })
        .collect();
    let (rb, ra) = (pooled_rms(b.iter().flatten()), pooled_rms(a.iter().flatten()));
    let improved = ratios.iter().filter(|r| **r > 0.0).count();
    let mut verdict = vec![if sessions.is_empty() {
        "the two runs share no held-out session: nothing to compare".to_string()
    } else if p_better < FAMILY_ALPHA && ra < (1.0 - SIGNIFICANT_GAIN) * rb {
        format!("the second run is better on the held-out sessions: {rb:.4} → {ra:.4} mm ({improved}/{} blocks improved, p {p_better:.1e})", ratios.len())
    } else if p_worse < FAMILY_ALPHA && rb < (1.0 - SIGNIFICANT_GAIN) * ra {
        format!("the second run is worse on the held-out sessions: {rb:.4} → {ra:.4} mm ({improved}/{} blocks improved, p {p_worse:.1e})", ratios.len())
    } else {
        format!("no significant difference on the held-out sessions: {rb:.4} vs {ra:.4} mm ({improved}/{} blocks improved)", ratios.len())
    }];
    if let Some(f) = after.0.point_floor().rms_mm {
        verdict.push(if ra <= EXPLAINS_WITHIN * f {
            format!(
                "the second run explains the held-out data: {ra:.4} mm against a floor of {f:.4} mm ({})",
                after.0.point_floor().source
            )
        } else {
            format!(
                "the second run is {:.2}× its floor of {f:.4} mm ({})",
                ra / f,
                after.0.point_floor().source
            )
        });
    } else {
        verdict.push("the second run's floor is unknown: it cannot be called explained".into());
    }
    TrackerComparison {
        sessions,
        before_rms_mm: rb,
        after_rms_mm: ra,
        floors_mm: (before.0.point_floor().rms_mm, after.0.point_floor().rms_mm),
        units_improved: (improved, ratios.len()),
        p_better,
        p_worse,
        verdict,
    }
}
