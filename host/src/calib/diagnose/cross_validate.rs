//! The calibration evidence of instrument sessions: every candidate refitted in full, the
//! strongest cross-validated.
//!
//! Every effect of the library (geometry, harmonics 1–4, compliance, scale; not the tool point,
//! which the sessions' frames free anyway) not yet free in the model is added to the calibrated
//! model and refitted warm on the calibration sessions (frames, tool and every free parameter
//! together, the identifiability step included: an effect whose parameters the frames and the
//! tool absorb is *not identifiable* and named so). Beside them the data errors of
//! [`super::data_errors::sessions`]: the tool moved in a calibration session, a session's base
//! drifting, single bad points, each refitted warm with its remedy.
//!
//! The order of the fixed sequence never sees the held-out sessions. The [`CROSS_VALIDATED`] arm
//! effects with the largest drop of the calibration residual (on the χ² scale, a normal deviate)
//! and every calibration-session data error are cross-validated: each calibration session is cut
//! into [`FOLDS`] contiguous pose blocks, fold k leaves block k of every session out, and the
//! left-out points are predicted with the frames fitted on the rest. The *CV gain* is
//! ln(MSE_before / MSE_with) over the left-out points; a candidate is tested when its CV gain
//! promises the practical gain (a CV RMS lower by [`super::SIGNIFICANT_GAIN`]), in the order of
//! its CV gain.

use super::data_errors::sessions::data_error_candidates;
use super::data_errors::DataSet;
use super::evidence::{Evidence, FittedValue, Flagged, NotIdentifiable, Ranking, Refitted};
use super::floor::Floor;
use super::units::Measure;
use super::SIGNIFICANT_GAIN;
use crate::calib::error::CalibError;
use crate::calib::fit::Fit;
use crate::calib::floor::{point_floor, point_gap, Gap};
use crate::calib::setup::{Change, Setup};
use crate::calib::validate::calibration_errors;
use crate::data::Observations;
use crate::model::effects::{Effect, EffectKind};
use crate::model::ArmModel;
use crate::numerics::stats::chi2_normal_deviate as chi2_z;
use rayon::prelude::*;

/// Contiguous pose blocks per calibration session for the cross-validation.
pub const FOLDS: usize = 5;
/// Arm effects cross-validated, largest calibration evidence first.
pub const CROSS_VALIDATED: usize = 5;

/// Cross-validated error of every calibration point (fold left out), per session in file order;
/// `None` for points the setup leaves out.
fn cross_validate(setup: &Setup, cal: &Observations, start: &ArmModel) -> Option<Vec<Vec<Option<f64>>>> {
    let left_out = setup.left_out(cal).ok()?;
    let sessions = cal.sessions();
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
                    left_out[k] || (fold_of(n, i) == fold) != leave
                })
            };
            let (train, test) = (pick(false), pick(true));
            let fit = crate::calib::fit::calibrate(start, &train, &setup.solve_options(&train)).ok()?;
            let errors = calibration_errors(&fit, &test, None);
            let tested: Vec<String> = test.sessions().into_iter().map(|b| test.block_name(b)).collect();
            let mut out = Vec::new();
            for (s, &b) in sessions.iter().enumerate() {
                let Some(at) = tested.iter().position(|n| *n == cal.block_name(b)) else { continue };
                let members = &cal.blocks[b].members;
                let n = members.len();
                let indices = (0..n).filter(|&i| !left_out[members[i]] && fold_of(n, i) == fold);
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

/// Drop of the calibration mean square from `baseline` to `with` as a standard normal deviate
/// (χ² with `k` parameters on the calibration points' coordinates).
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

/// The evidence of instrument sessions (see the module doc). The held-out test starts from the
/// calibrated model as given; the setup is calibrated again (warm from it, so to the same
/// solution) for what the calibration side needs: each session's frame and residuals.
pub struct CrossValidation<'a> {
    setup: &'a Setup,
    /// The calibrated model the held-out test starts from.
    calibrated: &'a ArmModel,
    cal: &'a Observations,
    val: &'a Observations,
    /// The setup calibrated again, warm from the calibrated model: its frames and residuals.
    fit: Fit,
    /// Cross-validated errors of the setup as it is (`None`: a fold could not be fitted).
    cv_before: Option<Vec<Vec<Option<f64>>>>,
}

impl<'a> CrossValidation<'a> {
    /// Calibrate `setup` again on `cal`, warm from `calibrated`, and cross-validate it.
    pub fn new(
        setup: &'a Setup,
        calibrated: &'a ArmModel,
        cal: &'a Observations,
        val: &'a Observations,
    ) -> Result<CrossValidation<'a>, CalibError> {
        let fit = setup.calibrate(calibrated, cal)?;
        let cv_before = cross_validate(setup, cal, &fit.model);
        Ok(CrossValidation { setup, calibrated, cal, val, fit, cv_before })
    }

    /// `change` refitted warm from the calibrated model, with its held-out errors.
    fn refit(&self, change: &Change) -> Option<(Fit, Vec<f64>)> {
        let (setup, start) = self.setup.apply(change, &self.fit.model);
        let fit = setup.calibrate(&start, self.cal).ok()?;
        let errors = Measure::Points.errors(&fit.model, self.val, &setup.float_tool);
        Some((fit, errors))
    }

    /// The CV gain of `change`, and its place in the fixed sequence when it promises the
    /// practical gain.
    fn cross_validated(&self, change: &Change) -> (Option<f64>, Option<f64>) {
        let Some(before) = &self.cv_before else { return (None, None) };
        let (setup, start) = self.setup.apply(change, &self.fit.model);
        let gain = cross_validate(&setup, self.cal, &start).map(|after| cv_gain(before, &after));
        (gain, gain.filter(|g| *g >= -2.0 * (1.0 - SIGNIFICANT_GAIN).ln()))
    }
}

impl Evidence for CrossValidation<'_> {
    fn baseline(&self) -> &ArmModel {
        self.calibrated
    }

    fn effects(&self) -> (Vec<Refitted>, Vec<NotIdentifiable>) {
        let library: Vec<Effect> = Effect::library_for(&self.fit.model)
            .into_iter()
            .filter(|e| e.kind != EffectKind::Tcp && !e.is_in(&self.fit.model))
            .collect();
        let refits: Vec<Option<(Fit, Vec<f64>)>> =
            library.par_iter().map(|&e| self.refit(&Change::Effect(e))).collect();
        let mut not_identifiable = Vec::new();
        let mut effects = Vec::new();
        for (&e, refit) in library.iter().zip(refits) {
            let Some((fit, errors)) = refit else {
                not_identifiable
                    .push(NotIdentifiable { effect: e.to_string(), reason: "the refit failed".into() });
                continue;
            };
            let names: Vec<String> = e.params().iter().map(|p| p.to_string()).collect();
            let estimated = e.params().iter().filter(|p| fit.estimated.contains(p)).count();
            if estimated == 0 {
                let reason = fit
                    .statements
                    .iter()
                    .find(|s| names.iter().any(|n| s.starts_with(&format!("{n} "))))
                    .cloned()
                    .unwrap_or_else(|| "the data cannot determine it".into());
                not_identifiable.push(NotIdentifiable { effect: e.to_string(), reason });
                continue;
            }
            let fitted = e
                .params()
                .iter()
                .filter_map(|p| {
                    let name = p.to_string();
                    let est = fit.estimates.iter().find(|x| x.param == name)?;
                    Some(FittedValue {
                        change: est.value - self.fit.model.get(*p),
                        param: name,
                        value: est.value,
                        std: est.std,
                        unit: est.unit.clone(),
                    })
                })
                .collect();
            let ranking = Ranking {
                order: None,
                calibration_z: calibration_z(&self.fit, &fit, estimated),
                cv_gain: None,
                delta_bic: None,
                calibration_rms_mm: Some(fit.rms_mm),
                refitted: true,
            };
            effects.push(Refitted {
                change: Change::Effect(e),
                errors,
                ranking,
                fitted,
                words: String::new(),
            });
        }
        effects.sort_by(|a, b| b.ranking.calibration_z.total_cmp(&a.ranking.calibration_z));
        let orders: Vec<(Option<f64>, Option<f64>)> =
            effects.par_iter().take(CROSS_VALIDATED).map(|s| self.cross_validated(&s.change)).collect();
        for (s, (gain, order)) in effects.iter_mut().zip(orders) {
            (s.ranking.cv_gain, s.ranking.order) = (gain, order);
        }
        (effects, not_identifiable)
    }

    fn data_errors(&self) -> (Vec<Refitted>, Flagged) {
        let Ok(kept) = self.setup.data(self.cal) else { return (Vec::new(), Flagged::default()) };
        let options = crate::calib::setup::SolveOptions {
            float_tool: self.setup.float_tool.clone(),
            ..self.setup.solve_options(&kept)
        };
        let found = data_error_candidates(&self.fit.model, &kept, self.val, &self.fit, &options);
        let held_out_tools = found.iter().filter(|d| d.set == DataSet::HeldOut).cloned().collect();
        let errors: Vec<Refitted> = found
            .iter()
            .filter(|d| d.set == DataSet::Calibration)
            .collect::<Vec<_>>()
            .par_iter()
            .filter_map(|d| {
                let change = d.change.clone()?;
                let (fit, errors) = self.refit(&change)?;
                let (cv_gain, order) = self.cross_validated(&change);
                let ranking = Ranking {
                    order,
                    calibration_z: calibration_z(&self.fit, &fit, 3),
                    cv_gain,
                    delta_bic: None,
                    calibration_rms_mm: Some(fit.rms_mm),
                    refitted: true,
                };
                Some(Refitted { change, errors, ranking, fitted: Vec::new(), words: d.text.clone() })
            })
            .collect();
        (errors, Flagged { held_out_tools, ..Flagged::default() })
    }

    fn both(&self, a: &Refitted, b: &Refitted) -> Option<Vec<f64>> {
        let (setup, start) = self.setup.apply(&a.change, &self.fit.model);
        let (setup, start) = setup.apply(&b.change, &start);
        let fit = setup.calibrate(&start, self.cal).ok()?;
        Some(Measure::Points.errors(&fit.model, self.val, &setup.float_tool))
    }

    fn separability(&self, _a: &Refitted, _b: &Refitted) -> Option<f64> {
        None
    }

    fn floor(&self) -> Floor {
        Floor::of_points(self.setup, &self.fit, self.calibrated, self.val)
    }

    fn gap_at(&self, rms_mm: f64) -> Option<Gap> {
        point_gap(&point_floor(self.val, self.setup.stated_sigma_mm), rms_mm, &self.fit, self.val)
    }
}
