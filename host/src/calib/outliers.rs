//! Outlier metrics (thesis appendix F) of what a user can leave out of the calibration data: a
//! landmark of the artefact (its touches in every placement), or an instrument session. Each
//! metric with its threshold:
//!
//! * error contribution: the unit's share of the squared calibration residual (a distance shared
//!   by two landmarks counts half for each), flagged above 1.5 × 100/L %;
//! * Cook's distance D = Σ (ŷ − ŷ₍ᵤ₎)² / (p · MSE) over every calibration residual, ŷ₍ᵤ₎ those of
//!   the model refitted without unit u (a session's frame refitted in closed form for each model),
//!   flagged above 4/L;
//! * leave-one-out impact (RMS_full − RMS_without)/RMS_full · 100 % on the held-out data
//!   (calibration data if none), flagged above 5 %;
//! * systematic bias: for a landmark, the RMS of its residual after a rigid fit of the artefact
//!   to the measured positions of each placement, flagged above [`BIAS_MM`]; for a session, the
//!   RMS of its point errors (its frame refitted), flagged above [`SESSION_BIAS_FACTOR`] × the
//!   RMS of every calibration point.
//!
//! A unit is flagged when at least two metrics exceed their thresholds.

use crate::calib::diagnose::Measure;
use crate::calib::fit::{refit, refit_with, Fit, SessionSums};
use crate::calib::nuisance::tool::ModelPoses;
use crate::calib::setup::Setup;
use crate::calib::validate::{distance_errors, placement_residuals, session_offset_mm, SessionFit};
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::stats::rms;
use rayon::prelude::*;

/// Leave-one-out impact (percent) above which a unit is suspicious.
pub const LOO_IMPACT_PCT: f64 = 5.0;
/// Systematic bias of a landmark (mm) above which it is suspicious.
pub const BIAS_MM: f64 = 1.0;
/// A session whose points' RMS is this many times that of every calibration point is suspicious.
pub const SESSION_BIAS_FACTOR: f64 = 1.5;

/// The four metrics of one landmark or session.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Outlier {
    /// `landmark` or `session`.
    #[serde(default = "landmark")]
    pub what: String,
    /// Landmark id, or session name.
    #[serde(alias = "landmark")]
    pub name: String,
    /// Share of the squared calibration error, percent.
    pub contribution_pct: f64,
    /// Cook's distance of leaving the unit out; `None` when the data without the unit cannot be
    /// calibrated (the only session, or too few points left).
    pub cooks_distance: Option<f64>,
    /// Held-out RMS improvement when the unit is left out, percent; `None` as for
    /// `cooks_distance`.
    pub loo_impact_pct: Option<f64>,
    /// A landmark's residual after a rigid fit of the artefact per placement, or a session's
    /// point errors with its frame refitted, RMS, mm.
    pub bias_mm: f64,
    /// Metrics beyond their thresholds.
    pub exceeded: Vec<String>,
    /// At least two metrics exceeded.
    pub flagged: bool,
}

fn landmark() -> String {
    "landmark".into()
}

/// Per-landmark RMS residual after a rigid fit of the artefact in every placement, mm.
pub fn landmark_bias(model: &ArmModel, data: &Observations) -> Vec<f64> {
    let mut sum = vec![0.0; data.landmarks.len()];
    let mut count = vec![0usize; data.landmarks.len()];
    for (k, r) in placement_residuals(model, data, 3).into_iter().enumerate() {
        let Some(r) = r else { continue };
        let l = data.obs[k].touched();
        sum[l] += r.norm_squared();
        count[l] += 1;
    }
    sum.iter().zip(&count).map(|(s, &c)| if c > 0 { (s / c as f64).sqrt() } else { 0.0 }).collect()
}

/// What can be left out.
#[derive(Clone, Copy)]
enum Unit {
    /// A landmark (index).
    Landmark(usize),
    /// An instrument session (block).
    Session(usize),
}

/// The calibration residual rows of `model` on `cal`, and the units each belongs to (two keys,
/// the same one twice for a single unit): a distance between two touches (both landmarks), or a
/// coordinate of a point error (its session's frame refitted in closed form, its tool floated
/// where the setup floats it); the points' poses read from `poses` when they are of `model` on
/// `cal`.
fn rows(
    model: &ArmModel,
    cal: &Observations,
    setup: &Setup,
    poses: Option<&ModelPoses>,
) -> (Vec<f64>, Vec<[usize; 2]>) {
    let distances = distance_errors(model, cal);
    let count = distances.len() + 3 * cal.point_count();
    let (mut values, mut owners) = (Vec::with_capacity(count), Vec::with_capacity(count));
    for e in distances {
        values.push(e.error_mm);
        owners.push([e.landmarks.0, e.landmarks.1]);
    }
    for b in cal.sessions() {
        let offset = session_offset_mm(model, cal, b, &setup.float_tool);
        let fit = SessionFit::with_poses(model, cal, b, offset, poses);
        for r in fit.residuals() {
            for v in [r.x, r.y, r.z] {
                values.push(v);
                owners.push([cal.landmarks.len() + b; 2]);
            }
        }
    }
    (values, owners)
}

/// The metrics of every landmark touched in `cal` and every calibration session, for the
/// calibration `fit` of `setup`.
pub fn outliers(fit: &Fit, cal: &Observations, val: Option<&Observations>, setup: &Setup) -> Vec<Outlier> {
    outliers_with(fit, cal, val, setup, None, None)
}

/// [`outliers`], the sessions' refits starting from `sums` when they are of `fit` (else from
/// sums taken here): a run takes them once for these refits and the data-error scoring's; the
/// fit's rows read from `poses` when they are of its model on `cal` (a run takes them once for
/// these rows, the calibration residuals and the data-error scoring).
pub fn outliers_with(
    fit: &Fit,
    cal: &Observations,
    val: Option<&Observations>,
    setup: &Setup,
    sums: Option<&SessionSums>,
    poses: Option<&ModelPoses>,
) -> Vec<Outlier> {
    let options = setup.solve_options(cal);
    let units: Vec<Unit> = (0..cal.landmarks.len())
        .filter(|&l| cal.obs.iter().any(|t| t.landmark() == Some(l)))
        .map(Unit::Landmark)
        .chain(cal.sessions().into_iter().map(Unit::Session))
        .collect();
    let count = units.len().max(1) as f64;
    let key = |u: Unit| match u {
        Unit::Landmark(l) => l,
        Unit::Session(b) => cal.landmarks.len() + b,
    };
    let (full, owners) = rows(&fit.model, cal, setup, poses);
    let total: f64 = full.iter().map(|v| v * v).sum::<f64>().max(1e-300);
    let held_out = val.unwrap_or(cal);
    let rms_on = |model: &ArmModel| {
        Measure::of(held_out).map_or(f64::NAN, |m| rms(&m.errors(model, held_out, &setup.float_tool)))
    };
    let full_rms = rms_on(&fit.model).max(1e-300);
    let p = fit.estimated.len();
    let dof = full.len() as f64 - p as f64 - 6.0 * cal.sessions().len() as f64;
    let mse = total / dof.max(1.0);
    let bias = landmark_bias(&fit.model, cal);
    let points_rms =
        |rows: &[f64]| (rows.iter().map(|v| v * v).sum::<f64>() / (rows.len() / 3).max(1) as f64).sqrt();
    let session_rows = |b: usize| -> Vec<f64> {
        full.iter()
            .zip(&owners)
            .filter(|(_, o)| o.contains(&(cal.landmarks.len() + b)))
            .map(|(v, _)| *v)
            .collect()
    };
    // A session's refit starts from the other sessions' normal equations at the fit's solution.
    let own;
    let sums = match sums.filter(|s| std::ptr::eq(s.fit(), fit)) {
        Some(sums) => Some(sums),
        None => {
            own = SessionSums::of(&fit.model, fit, cal, &options);
            own.as_ref()
        }
    };
    let all_points: Vec<f64> =
        full.iter().zip(&owners).filter(|(_, o)| o[0] >= cal.landmarks.len()).map(|(v, _)| *v).collect();
    units
        .par_iter()
        .map(|&u| {
            let own: f64 =
                full.iter().zip(&owners).filter(|(_, o)| o.contains(&key(u))).map(|(v, _)| v * v).sum();
            let (what, name, share, without, bias_mm, biased) = match u {
                Unit::Landmark(l) => {
                    let name = cal.landmarks[l].id.clone();
                    ("landmark", name, 2.0, cal.without_landmark(l), bias[l], bias[l] > BIAS_MM)
                }
                Unit::Session(b) => {
                    let own_rms = points_rms(&session_rows(b));
                    let biased = own_rms > SESSION_BIAS_FACTOR * points_rms(&all_points);
                    (
                        "session",
                        cal.block_name(b),
                        1.0,
                        cal.without(|k| cal.obs[k].block == b),
                        own_rms,
                        biased,
                    )
                }
            };
            let contribution_pct = 100.0 * own / (share * total);
            let refitted = match (sums, u) {
                (Some(sums), Unit::Session(_)) => refit_with(sums, &without, &options),
                _ => refit(fit, &without, &options),
            };
            let (cooks_distance, loo_impact_pct) = match refitted {
                Ok(model) => {
                    let (moved, _) = rows(&model, cal, setup, None);
                    let change: f64 = full.iter().zip(&moved).map(|(a, b)| (a - b).powi(2)).sum();
                    (
                        Some(change / (p.max(1) as f64 * mse.max(1e-300))),
                        Some(100.0 * (full_rms - rms_on(&model)) / full_rms).filter(|v| v.is_finite()),
                    )
                }
                Err(_) => (None, None),
            };
            let mut exceeded = Vec::new();
            if contribution_pct > 1.5 * 100.0 / count {
                exceeded.push("contribution");
            }
            if cooks_distance.is_some_and(|d| d > 4.0 / count) {
                exceeded.push("cooks_distance");
            }
            if loo_impact_pct.is_some_and(|v| v > LOO_IMPACT_PCT) {
                exceeded.push("leave_one_out");
            }
            if biased {
                exceeded.push("bias");
            }
            Outlier {
                what: what.into(),
                name,
                contribution_pct,
                cooks_distance,
                loo_impact_pct,
                bias_mm,
                flagged: exceeded.len() >= 2,
                exceeded: exceeded.into_iter().map(String::from).collect(),
            }
        })
        .collect()
}
