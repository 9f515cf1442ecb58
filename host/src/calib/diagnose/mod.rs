//! The diagnosis: where the calibrated model fails, and which change — an effect of the library
//! or the remedy of a data error — it is missing. One engine for every kind of held-out data.
//!
//! 1. *Where it fails* ([`apparent`]): the held-out residuals after each block's frame is
//!    refitted, as apparent joint errors against each joint's angle and gravity lever.
//! 2. *Candidates* ([`evidence`]): every library effect not in the model and the remedy of every
//!    data error a detector finds ([`data_errors`]), each a typed [`Change`], refitted warm on the
//!    calibration data, which also give the order of the test. How the calibration data rank
//!    candidates is one of the three parts each kind of held-out data defines: a score test on
//!    artefact placements ([`screen`]), cross-validation on instrument sessions
//!    ([`cross_validate`]).
//! 3. *The held-out test* ([`units`]): each candidate's held-out errors against the calibrated
//!    model's, unit by unit (a validation placement, or a block of poses of a held-out session:
//!    the second per-kind part), by an exact sign-flip and a t test
//!    ([`crate::numerics::significance`]); candidates in a fixed sequence, equivalents, rivals and
//!    what is named ([`sequence`]); of an effect and its refinement, the effect first
//!    ([`hierarchy`]: joint compliance before lateral compliance).
//! 4. *How far from done* ([`floor`]): the floor of the held-out data and the gap to it (the
//!    third per-kind part), and the verdict in words.
//!
//! [`auto`] applies what the diagnosis names and diagnoses again; [`compare`] tests one
//! calibration against another on the same held-out units.

pub mod apparent;
pub mod auto;
pub mod compare;
pub mod cross_validate;
pub mod data_errors;
pub mod evidence;
pub mod floor;
pub mod hierarchy;
pub mod screen;
pub mod sequence;
pub mod summary;
pub mod units;
pub mod words;

pub use apparent::{JointResiduals, Sinusoid};
pub use evidence::{FittedValue, NotIdentifiable, Ranking};
pub use floor::{Floor, NeighbourBound};
pub use sequence::{Rival, RivalVerdict, DATA_ERROR_EXPLAINS, FAMILY_ALPHA, SIGNIFICANT_GAIN};
pub use units::Measure;

use crate::calib::error::CalibError;
use crate::calib::error_stats::ErrorStats;
use crate::calib::setup::{Change, Setup};
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::stats::rms;
use data_errors::touches::{DisturbedBlock, MisSeatedTouch};
use data_errors::DataError;
use evidence::{effect_words, Evidence, Refitted};
use rayon::prelude::*;

/// Why a diagnosis cannot run.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    /// The held-out data hold both kinds, or neither.
    #[error("the held-out data must be artefact placements or instrument sessions, one kind: the held-out test compares units of one kind")]
    HeldOutKind,
    /// Calibrating the setup again failed.
    #[error(transparent)]
    Calibration(#[from] CalibError),
}

/// One candidate change, scored on the held-out data.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Candidate {
    /// The effect (`eccentricity:5`), or the data error's kind and place (`landmark:S2`,
    /// `tool moved: session_2`).
    pub name: String,
    /// The change, typed.
    pub change: Change,
    /// The `kincal calibrate` options that apply it.
    pub action: String,
    /// Held-out RMS with the change refitted, mm.
    pub held_out_rms_mm: f64,
    /// Share of the held-out mean square error removed (0–1).
    pub explained: f64,
    /// Held-out units (placements, or blocks of poses) whose number is positive, and units.
    pub units_improved: (usize, usize),
    /// Parts of the units (a placement's repeats) whose error fell, and parts.
    pub parts_improved: (usize, usize),
    /// Mean over the parts of ln(MSE_before / MSE_after).
    pub mean_log_ratio: f64,
    /// Held-out p over the units: a weighted Bonferroni of an exact one-sided sign-flip test
    /// and a one-sided t test, at most 1.
    pub p_value: f64,
    /// The fixed sequence reached it.
    pub tested: bool,
    /// The fixed sequence found it significant (p and practical gain).
    pub significant: bool,
    /// What the calibration data say about it, and its place in the fixed sequence.
    #[serde(flatten)]
    pub ranking: Ranking,
    /// The effect's parameters as fitted.
    pub fitted: Vec<FittedValue>,
    /// What it is and what it would do, in words.
    pub evidence: String,
    /// Other candidates that change the held-out errors the same way.
    pub equivalent: Vec<String>,
    /// The better-ranked candidate this one is equivalent to, if any.
    pub equivalent_to: Option<String>,
}

/// A large held-out error.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Worst {
    /// The placement or session.
    pub group: String,
    /// What was measured: the two landmarks, or the point's line.
    pub what: String,
    /// The error, mm (measured minus certified distance, or a point error's length).
    pub error_mm: f64,
}

/// Everything `kincal diagnose` finds.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Diagnosis {
    /// What the held-out data measure.
    pub measure: Measure,
    /// The calibrated model's held-out errors, mm.
    pub baseline: ErrorStats,
    /// Held-out test units.
    pub units: usize,
    /// Held-out errors per group (placement or session): name, count, RMS mm.
    pub by_group: Vec<(String, usize, f64)>,
    /// The floor and the gap to it.
    pub floor: Floor,
    /// The model explains the held-out data: at the floor.
    pub explains: bool,
    /// The model is shown incomplete: by the gap, or by the neighbour check.
    pub incomplete: bool,
    /// Arm-effect candidates, best (lowest held-out RMS) first.
    pub candidates: Vec<Candidate>,
    /// Data-error candidates, best first.
    pub data_errors: Vec<Candidate>,
    /// Calibration blocks whose artefact seems to have moved within the repeat.
    pub disturbed: Vec<DisturbedBlock>,
    /// Calibration touches far off their repeats.
    pub mis_seated: Vec<MisSeatedTouch>,
    /// A tool moved in a held-out session (judged by its own rule).
    pub held_out_tools: Vec<DataError>,
    /// The leading arm effect against the other significant ones it does not clearly beat.
    pub rivals: Vec<Rival>,
    /// What is named: one change, or effects the data cannot tell apart (empty: nothing).
    pub named: Vec<String>,
    /// A refinement the data name first, and whether its main effect is named in its place
    /// ([`hierarchy`]).
    pub refinement: Option<hierarchy::Refinement>,
    /// The `kincal calibrate` options of what is named first.
    pub action: Option<String>,
    /// The change of what is named first.
    pub change: Option<Change>,
    /// Effects the data cannot identify next to the model.
    pub not_identifiable: Vec<NotIdentifiable>,
    /// Apparent joint errors.
    pub joints: Vec<JointResiduals>,
    /// (height z mm, |residual| mm) per held-out observation.
    pub by_height: Vec<(f64, f64)>,
    /// (reach √(x²+y²) mm, |residual| mm) per held-out observation.
    pub by_reach: Vec<(f64, f64)>,
    /// Largest held-out errors.
    pub worst: Vec<Worst>,
    /// The verdict, in words.
    pub summary: Vec<String>,
    /// Seconds spent.
    pub seconds: f64,
    /// The calibrated model diagnosed.
    #[serde(skip)]
    pub model: Option<ArmModel>,
}

impl Diagnosis {
    /// A named candidate, arm effect or data error.
    pub fn candidate(&self, name: &str) -> Option<&Candidate> {
        self.candidates.iter().chain(&self.data_errors).find(|c| c.name == name)
    }
}

/// A candidate from its refit and its held-out score against the calibrated model.
fn scored(
    r: &Refitted,
    units: &units::Units,
    before: &units::PartMse,
    baseline: &ErrorStats,
    words: String,
) -> Candidate {
    let score = units.score(before, &r.errors);
    let base_ms = baseline.rms_mm.powi(2).max(1e-300);
    Candidate {
        name: r.change.name(),
        action: r.change.action(),
        change: r.change.clone(),
        explained: ((base_ms - score.rms_mm.powi(2)) / base_ms).clamp(0.0, 1.0),
        held_out_rms_mm: score.rms_mm,
        units_improved: score.units_improved,
        parts_improved: score.parts_improved,
        mean_log_ratio: score.mean_log_ratio,
        p_value: score.p_value,
        tested: false,
        significant: false,
        ranking: r.ranking.clone(),
        fitted: r.fitted.clone(),
        evidence: words,
        equivalent: Vec::new(),
        equivalent_to: None,
    }
}

/// Sort refits and their candidates together by held-out RMS, best first.
fn by_held_out_rms(refits: Vec<Refitted>, candidates: Vec<Candidate>) -> (Vec<Refitted>, Vec<Candidate>) {
    let mut pairs: Vec<(Refitted, Candidate)> = refits.into_iter().zip(candidates).collect();
    pairs.sort_by(|a, b| a.1.held_out_rms_mm.total_cmp(&b.1.held_out_rms_mm));
    pairs.into_iter().unzip()
}

/// The largest held-out errors and each group's RMS.
fn worst_and_groups(
    measure: Measure,
    errors: &[f64],
    val: &Observations,
) -> (Vec<Worst>, Vec<(String, usize, f64)>) {
    let located: Vec<(usize, String)> = match measure {
        Measure::Distances => val
            .landmark_pairs()
            .into_iter()
            .map(|(a, b)| {
                let id = |k: usize| val.landmarks[val.obs[k].touched()].id.clone();
                (val.obs[a].group, format!("{}–{}", id(a), id(b)))
            })
            .collect(),
        Measure::Points => val
            .sessions()
            .into_iter()
            .flat_map(|b| val.blocks[b].members.iter().filter(|&&k| val.obs[k].point_mm().is_some()))
            .map(|&k| (val.obs[k].group, format!("line {}", val.obs[k].line)))
            .collect(),
    };
    let mut order: Vec<usize> = (0..errors.len()).collect();
    order.sort_by(|&a, &b| errors[b].abs().total_cmp(&errors[a].abs()));
    let worst = order
        .into_iter()
        .take(10)
        .map(|i| Worst {
            group: val.groups[located[i].0].name.clone(),
            what: located[i].1.clone(),
            error_mm: errors[i],
        })
        .collect();
    let groups = (0..val.groups.len())
        .filter_map(|g| {
            let e: Vec<f64> = (0..errors.len()).filter(|&i| located[i].0 == g).map(|i| errors[i]).collect();
            (!e.is_empty()).then(|| (val.groups[g].name.clone(), e.len(), rms(&e)))
        })
        .collect();
    (worst, groups)
}

/// The held-out RMS of `model` on `val` as a setup validates it (each session's frame refitted,
/// and its tool where it floats), mm.
pub fn held_out_rms_mm(setup: &Setup, model: &ArmModel, val: &Observations) -> Option<f64> {
    Measure::of(val).map(|m| rms(&m.errors(model, val, &setup.float_tool)))
}

/// Diagnose `calibrated`, a model calibrated on `cal` as `setup` asks (its free set and bounds
/// those it was calibrated with), on the held-out data `val`.
pub fn diagnose(
    setup: &Setup,
    calibrated: &ArmModel,
    cal: &Observations,
    val: &Observations,
) -> Result<Diagnosis, DiagnoseError> {
    let started = std::time::Instant::now();
    let measure = Measure::of(val).ok_or(DiagnoseError::HeldOutKind)?;
    let kept = setup.data(cal)?;
    let evidence: Box<dyn Evidence> = match measure {
        Measure::Distances => {
            Box::new(screen::ScoreTest::new(calibrated, &kept, val, setup.solve_options(&kept)))
        }
        Measure::Points => Box::new(cross_validate::CrossValidation::new(setup, calibrated, cal, val)?),
    };
    let model = evidence.baseline();
    let units = measure.units(val);
    let errors = measure.errors(model, val, &setup.float_tool);
    let baseline = ErrorStats::of(&errors);
    let before = units.mse(&errors);
    let (joints, by_height, by_reach) = apparent::apparent(model, val, &setup.float_tool);
    let ((effects, not_identifiable), (errors_found, flagged)) =
        rayon::join(|| evidence.effects(), || evidence.data_errors());
    let candidates: Vec<Candidate> = effects
        .par_iter()
        .map(|r| {
            let after = rms(&r.errors);
            let words = match r.change {
                Change::Effect(e) => effect_words(e, &r.fitted, &joints, baseline.rms_mm, after) + &r.words,
                _ => r.words.clone(),
            };
            scored(r, &units, &before, &baseline, words)
        })
        .collect();
    let (effects, mut candidates) = by_held_out_rms(effects, candidates);
    let changes: Vec<&[f64]> = effects.iter().map(|r| r.errors.as_slice()).collect();
    sequence::group_equivalents(&mut candidates, &changes, &errors);
    let scored_errors: Vec<Candidate> =
        errors_found.iter().map(|r| scored(r, &units, &before, &baseline, r.words.clone())).collect();
    let (_, mut data_errors) = by_held_out_rms(errors_found, scored_errors);
    sequence::decide(&mut candidates, &mut data_errors, baseline.rms_mm);
    let contest = sequence::Contest {
        candidates: &candidates,
        refits: &effects,
        units: &units,
        baseline_rms_mm: baseline.rms_mm,
    };
    let (rivals, mut named) = sequence::rivals(&contest, evidence.as_ref());
    let (main_first, mut refinement) = hierarchy::main_first(&named, &candidates, model);
    // A held-out session's own data error (its tool moved, its probe turned) spoils the held-out
    // test of every arm effect: it is named alone, and no arm effect is claimed.
    let held_out_error = flagged.held_out_tools.iter().find(|t| t.significant).and_then(|t| t.change.clone());
    let change = match (sequence::named_data_error(&data_errors, &candidates, &named), held_out_error) {
        (Some(d), _) => {
            named = vec![d.name.clone()];
            refinement = None;
            Some(d.change.clone())
        }
        (None, Some(change)) => {
            named = vec![change.name()];
            refinement = None;
            Some(change)
        }
        (None, None) => {
            named = main_first;
            named.first().and_then(|n| candidates.iter().find(|c| c.name == *n)).map(|c| c.change.clone())
        }
    };
    let floor = evidence.floor();
    let (worst, by_group) = worst_and_groups(measure, &errors, val);
    let mut d = Diagnosis {
        measure,
        baseline,
        units: units.len(),
        by_group,
        explains: floor.explains(),
        incomplete: floor.incomplete(),
        floor,
        candidates,
        data_errors,
        disturbed: flagged.disturbed,
        mis_seated: flagged.mis_seated,
        held_out_tools: flagged.held_out_tools,
        rivals,
        named,
        refinement,
        action: change.as_ref().map(Change::action),
        change,
        not_identifiable,
        joints,
        by_height,
        by_reach,
        worst,
        summary: Vec::new(),
        seconds: 0.0,
        model: Some(model.clone()),
    };
    let with = d.named.first().and_then(|n| d.candidate(n)).and_then(|c| evidence.gap_at(c.held_out_rms_mm));
    d.summary = summary::lines(&d, setup, with.as_ref());
    d.seconds = started.elapsed().as_secs_f64();
    Ok(d)
}
