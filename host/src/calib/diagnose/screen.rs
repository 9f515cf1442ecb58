//! The calibration evidence of artefact placements: a score test with no refit, then the
//! strongest candidates refitted.
//!
//! The calibration evidence and the refits use at most [`SCREEN_BLOCKS`] calibration blocks,
//! evenly spaced (all of them on data of thesis size; a subsample at scale, where 150 blocks are
//! ten times the thesis' data); the held-out scores always use every validation touch, so the
//! tests stay exact. The calibrated model's Jacobian with every candidate parameter freed is
//! evaluated once and shared:
//! * *Identifiability*: a candidate's parameters that add no rank to the identifiable base set
//!   are held at zero and named; a candidate with none left is not identifiable.
//! * *Screen*: a score (Lagrange-multiplier) test with no refit. With r the calibration
//!   residuals and J_M, J_c the model's and the candidate's columns,
//!   s = J_cᵀ(I − P_M)r and LM = sᵀ[J_cᵀ(I − P_M)J_c]⁻¹s/σ², χ²_k under no effect (computed as
//!   the drop of the Gauss–Newton objective of the augmented fit, from the shared normal
//!   matrix), turned into the standard normal deviate with the same upper tail, computed exactly
//!   in log space: the candidate's *calibration evidence*, the order of the fixed sequence.
//! * *Refit*: the [`REFITTED`] candidates with the strongest calibration evidence are refitted
//!   warm (nonlinear, every calibration touch, from the calibrated values), and their evidence
//!   is then the exact drop, rows × (1 − RSS_after/RSS_before), on the score test's scale; the
//!   others are scored from the shared Gauss–Newton step.
//! * *Separability* of two candidates A and B: λ = min(λ_AB, λ_BA), λ_AB = ‖(I − P_\[M,B\])J_Aδ_A‖²/σ²
//!   on the calibration data (a projection with no refit).
//!
//! Data errors ([`super::data_errors::touches`]): every landmark's certificate freed (its
//! likelihood ratio from the BIC change), and each flagged block and touch dropped (the split or
//! touch χ²), refitted warm.

use super::data_errors::touches::{refit_with_landmark_freed, suspicious, DisturbedBlock, MisSeatedTouch};
use super::evidence::{Evidence, FittedValue, Flagged, NotIdentifiable, Ranking, Refitted};
use super::floor::Floor;
use super::words::mm;
use crate::calib::fit::{dense_jacobian, solve_warm};
use crate::calib::floor::{gap, noise_floor, Gap, NoiseFloor};
use crate::calib::identify;
use crate::calib::setup::{Change, SolveOptions};
use crate::calib::validate::distance_errors;
use crate::data::Observations;
use crate::model::effects::Effect;
use crate::model::{ArmModel, ParamId};
use crate::numerics::solver::normal_equations;
use crate::numerics::stats::{chi2_normal_deviate as chi2_z, rms};
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use std::borrow::Cow;

/// Most calibration (placement, repeat) blocks the screening (shared Jacobian, refits, calibration
/// evidence) uses; larger data are subsampled evenly. Held-out scores use every validation touch.
pub const SCREEN_BLOCKS: usize = 150;
/// Candidates refitted in full (warm, nonlinear), strongest calibration evidence first.
pub const REFITTED: usize = 10;
/// Flagged blocks and touches scored at most (each kind).
const MAX_FLAGGED: usize = 3;

/// `data` with at most [`SCREEN_BLOCKS`] (placement, repeat) blocks, evenly spaced.
fn screening_subset(data: &Observations) -> Cow<'_, Observations> {
    let blocks = data.blocks.len();
    if blocks <= SCREEN_BLOCKS {
        return Cow::Borrowed(data);
    }
    let keep: Vec<usize> = (0..SCREEN_BLOCKS).map(|k| k * blocks / SCREEN_BLOCKS).collect();
    Cow::Owned(data.without(|t| !keep.contains(&data.obs[t].block)))
}

/// BIC of a fit with `params` parameters from its distance residuals.
fn bic(residuals: &[f64], params: usize) -> f64 {
    let m = residuals.len().max(1) as f64;
    let rss = residuals.iter().map(|r| r * r).sum::<f64>().max(1e-300);
    m * (rss / m).ln() + params as f64 * m.ln()
}

fn distance_residuals(model: &ArmModel, data: &Observations) -> Vec<f64> {
    distance_errors(model, data).iter().map(|e| e.error_mm).collect()
}

fn subset_jacobian(jac: &[f64], n: usize, cols: &[usize]) -> Vec<f64> {
    jac.chunks_exact(n).flat_map(|row| cols.iter().map(move |&c| row[c])).collect()
}

/// The calibrated model's Jacobian with every candidate parameter freed, evaluated once on the
/// calibration data (the screening subsample at scale) and shared by every candidate.
struct Screen {
    params: Vec<ParamId>,
    ranges: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    values: Vec<f64>,
    jac: Vec<f64>,
    /// JᵀWJ and JᵀWr (Huber weights at the calibrated residuals).
    gram: DMatrix<f64>,
    grad: DVector<f64>,
    /// Residual variance per row.
    sigma2: f64,
    rows: usize,
    /// Identifiable base set of the current parameters (column indices).
    base: Vec<usize>,
    /// Drop of the Gauss–Newton objective with the base set alone (≈ 0 at the optimum).
    base_drop: f64,
}

impl Screen {
    fn new(calibrated: &ArmModel, effects: &[Effect], cal: &Observations, options: &SolveOptions) -> Screen {
        let mut augmented = calibrated.clone();
        for e in effects {
            e.add_to(&mut augmented);
        }
        let params: Vec<ParamId> = augmented.free.iter().map(|f| f.id).collect();
        let ranges: Vec<f64> = augmented.free.iter().map(|f| (f.upper - f.lower).max(1e-9)).collect();
        let resolved = options.resolve(cal);
        let (r, jac) = dense_jacobian(&augmented, &params, cal, resolved.relative_lever_mm);
        let values = augmented.free_values();
        let (rows, n) = (r.len(), params.len());
        let loss = resolved.loss;
        let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
        let (gram, grad) = normal_equations(&jac, &r, &weights, n);
        let current: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
        let lower: Vec<f64> = augmented.free.iter().map(|f| f.lower).collect();
        let upper: Vec<f64> = augmented.free.iter().map(|f| f.upper).collect();
        // A parameter the calibration left at a bound is held there (its gradient is not zero).
        let at_bound = |c: usize| (values[c] - lower[c]).min(upper[c] - values[c]) <= 1e-6 * ranges[c];
        let existing: Vec<usize> = (0..n).filter(|&c| current.contains(&params[c]) && !at_bound(c)).collect();
        let existing_ranges: Vec<f64> = existing.iter().map(|&c| ranges[c]).collect();
        let base: Vec<usize> =
            identify::base_columns(&subset_jacobian(&jac, n, &existing), existing.len(), &existing_ranges)
                .0
                .into_iter()
                .map(|k| existing[k])
                .collect();
        let rss: f64 = r.iter().zip(&weights).map(|(v, w)| w * v * v).sum();
        let mut screen = Screen {
            lower,
            upper,
            sigma2: (rss / rows.saturating_sub(base.len()).max(1) as f64).max(1e-300),
            params,
            ranges,
            values,
            jac,
            gram,
            grad,
            rows,
            base,
            base_drop: 0.0,
        };
        screen.base_drop = screen.step(&screen.base.clone()).map_or(0.0, |s| s.0);
        screen
    }

    /// Column index of a parameter.
    fn column(&self, id: ParamId) -> Option<usize> {
        self.params.iter().position(|p| *p == id)
    }

    /// Gauss–Newton step with columns `cols` free: (drop of the objective, step).
    fn step(&self, cols: &[usize]) -> Option<(f64, DVector<f64>)> {
        let g = DMatrix::from_fn(cols.len(), cols.len(), |a, b| self.gram[(cols[a], cols[b])]);
        let rhs = DVector::from_fn(cols.len(), |a, _| self.grad[cols[a]]);
        let x = g.cholesky()?.solve(&rhs);
        Some((rhs.dot(&x), -x))
    }

    /// ‖(I − P_T) J_S δ‖² / σ²: the part of the change a step `delta` on columns `s` makes to
    /// the residuals that columns `t` cannot make.
    fn unexplained(&self, s: &[usize], delta: &DVector<f64>, t: &[usize]) -> f64 {
        let gss = DMatrix::from_fn(s.len(), s.len(), |a, b| self.gram[(s[a], s[b])]);
        let gts = DMatrix::from_fn(t.len(), s.len(), |a, b| self.gram[(t[a], s[b])]);
        let gtt = DMatrix::from_fn(t.len(), t.len(), |a, b| self.gram[(t[a], t[b])]);
        let whole = delta.dot(&(&gss * delta));
        let projected = gts * delta;
        let explained = gtt.cholesky().map_or(0.0, |c| projected.dot(&c.solve(&projected)));
        (whole - explained).max(0.0) / self.sigma2
    }
}

/// A candidate screened on the shared Jacobian.
struct Screened {
    effect: Effect,
    /// Columns fitted: the base set and the candidate's identifiable parameters.
    cols: Vec<usize>,
    /// The candidate's identifiable parameters.
    added: Vec<ParamId>,
    /// Its parameters held at zero (not identifiable next to the model).
    held: Vec<ParamId>,
    /// Why they are held.
    held_reason: Vec<String>,
    lm: f64,
    z: f64,
    /// The Gauss–Newton step on `cols`.
    delta: DVector<f64>,
}

impl Screened {
    /// `calibrated` with the effect added (held parameters fixed) at the calibrated values.
    fn start(&self, calibrated: &ArmModel) -> ArmModel {
        let mut model = calibrated.clone();
        self.effect.add_to(&mut model);
        for p in &self.held {
            model.fix_param(*p);
        }
        model
    }

    /// The model after the shared Gauss–Newton step (within the bounds).
    fn one_step(&self, calibrated: &ArmModel, screen: &Screen) -> ArmModel {
        let mut model = self.start(calibrated);
        for (a, &c) in self.cols.iter().enumerate() {
            let v = (screen.values[c] + self.delta[a]).clamp(screen.lower[c], screen.upper[c]);
            model.set(screen.params[c], v);
        }
        model
    }
}

/// Identifiability and the score test of `effect` on the shared Jacobian.
fn screen_candidate(
    effect: Effect,
    screen: &Screen,
    current: &[ParamId],
) -> Result<Screened, NotIdentifiable> {
    let n = screen.params.len();
    let extra: Vec<usize> =
        effect.params().iter().filter(|p| !current.contains(p)).filter_map(|&p| screen.column(p)).collect();
    let rank = identify::added_rank(&screen.jac, n, &screen.ranges, &screen.base, &extra);
    let describe = |k: usize| {
        let r = &rank[k];
        let name = screen.params[extra[k]];
        if r.moves_nothing {
            return format!("{name} changes no distance");
        }
        let mut terms: Vec<(ParamId, f64, f64)> = screen
            .base
            .iter()
            .enumerate()
            .map(|(i, &c)| (screen.params[c], -r.like[i], r.share[i]))
            .filter(|t| t.2.abs() > 1e-3)
            .collect();
        terms.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
        let list: Vec<String> = terms
            .iter()
            .take(4)
            .map(|(p, b, _)| format!("{p} ({b:+.4} {} per {})", p.unit(), name.unit()))
            .collect();
        format!("{name}'s effect on distances is absorbed by {}", list.join(", "))
    };
    let held_idx: Vec<usize> = (0..extra.len()).filter(|&k| !rank[k].adds).collect();
    let not_identifiable = |reason: String| NotIdentifiable { effect: effect.to_string(), reason };
    if held_idx.len() == extra.len() {
        let reasons: Vec<String> = held_idx.iter().map(|&k| describe(k)).collect();
        return Err(not_identifiable(format!("not identifiable from these touches: {}", reasons.join("; "))));
    }
    let added_cols: Vec<usize> = (0..extra.len()).filter(|&k| rank[k].adds).map(|k| extra[k]).collect();
    let cols: Vec<usize> = screen.base.iter().chain(&added_cols).copied().collect();
    let (drop, delta) = screen
        .step(&cols)
        .ok_or_else(|| not_identifiable("its normal equations are singular next to the model".into()))?;
    let lm = (drop - screen.base_drop).max(0.0) / screen.sigma2;
    Ok(Screened {
        effect,
        added: added_cols.iter().map(|&c| screen.params[c]).collect(),
        held: held_idx.iter().map(|&k| screen.params[extra[k]]).collect(),
        held_reason: held_idx.iter().map(|&k| describe(k)).collect(),
        z: chi2_z(lm, added_cols.len()),
        lm,
        cols,
        delta,
    })
}

/// The evidence of artefact placements (see the module doc).
pub struct ScoreTest<'a> {
    calibrated: &'a ArmModel,
    cal: &'a Observations,
    /// The calibration data the screen and the refits use (a subsample at scale).
    fit_data: Cow<'a, Observations>,
    val: &'a Observations,
    options: SolveOptions,
    screen: Screen,
    /// The identifiable parameters refitted.
    base_params: Vec<ParamId>,
    /// Every candidate effect screened (the not identifiable ones left out), strongest first.
    screened: Vec<Screened>,
    not_identifiable: Vec<NotIdentifiable>,
    floor: Option<NoiseFloor>,
    baseline_errors: Vec<f64>,
}

impl<'a> ScoreTest<'a> {
    /// Screen every library effect not in `calibrated` (whose free set and bounds are those it
    /// was calibrated with) on `cal`.
    pub fn new(
        calibrated: &'a ArmModel,
        cal: &'a Observations,
        val: &'a Observations,
        options: SolveOptions,
    ) -> ScoreTest<'a> {
        let fit_data = screening_subset(cal);
        let effects: Vec<Effect> =
            Effect::library_for(calibrated).into_iter().filter(|e| !e.is_in(calibrated)).collect();
        let screen = Screen::new(calibrated, &effects, &fit_data, &options);
        let base_params: Vec<ParamId> = screen.base.iter().map(|&c| screen.params[c]).collect();
        let floor = noise_floor(calibrated, cal, val, screen.base.len())
            .map(|f| f.with_estimate_noise(calibrated, &base_params, &fit_data, val));
        let current: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
        let mut screened = Vec::new();
        let mut not_identifiable = Vec::new();
        for r in effects.par_iter().map(|&e| screen_candidate(e, &screen, &current)).collect::<Vec<_>>() {
            match r {
                Ok(s) => screened.push(s),
                Err(n) => not_identifiable.push(n),
            }
        }
        screened.sort_by(|a, b| b.z.total_cmp(&a.z));
        ScoreTest {
            baseline_errors: distance_residuals(calibrated, val),
            calibrated,
            cal,
            fit_data,
            val,
            options,
            screen,
            base_params,
            screened,
            not_identifiable,
            floor,
        }
    }

    fn screened(&self, change: &Change) -> Option<&Screened> {
        match change {
            Change::Effect(e) => self.screened.iter().find(|s| s.effect == *e),
            _ => None,
        }
    }

    /// A data error's remedy refitted, with its calibration evidence and words.
    fn data_error(
        &self,
        change: Change,
        errors: Vec<f64>,
        z: f64,
        delta_bic: Option<f64>,
        words: String,
    ) -> Refitted {
        let ranking = Ranking {
            order: Some(z),
            calibration_z: z,
            cv_gain: None,
            delta_bic,
            calibration_rms_mm: None,
            refitted: true,
        };
        Refitted { change, errors, ranking, fitted: Vec::new(), words }
    }
}

impl Evidence for ScoreTest<'_> {
    fn baseline(&self) -> &ArmModel {
        self.calibrated
    }

    fn effects(&self) -> (Vec<Refitted>, Vec<NotIdentifiable>) {
        let current = self.calibrated.free.len();
        let baseline_cal = distance_residuals(self.calibrated, &self.fit_data);
        let baseline_bic = bic(&baseline_cal, current);
        let baseline_rss: f64 = baseline_cal.iter().map(|r| r * r).sum::<f64>().max(1e-300);
        let screen = &self.screen;
        let m_screen = screen.rows.max(2) as f64;
        let refitted = self
            .screened
            .par_iter()
            .enumerate()
            .map(|(rank, c)| {
                let refit = (rank < REFITTED)
                    .then(|| {
                        let params: Vec<ParamId> = self.base_params.iter().chain(&c.added).copied().collect();
                        solve_warm(&c.start(self.calibrated), &params, &self.fit_data, &self.options).ok()
                    })
                    .flatten();
                let refitted = refit.is_some();
                let model = refit.unwrap_or_else(|| c.one_step(self.calibrated, screen));
                let k = c.added.len();
                // A refit replaces the score test's linearised drop by the exact one, on the same
                // scale: rows × (1 − RSS_after / RSS_before).
                let (delta_bic, z) = if refitted {
                    let residuals = distance_residuals(&model, &self.fit_data);
                    let rss: f64 = residuals.iter().map(|r| r * r).sum();
                    let exact = m_screen * (1.0 - rss / baseline_rss).max(0.0);
                    (bic(&residuals, current + k) - baseline_bic, chi2_z(exact, k))
                } else {
                    let rss = screen.sigma2 * (screen.rows.saturating_sub(screen.base.len()).max(1)) as f64;
                    let drop = m_screen * (1.0 - (c.lm * screen.sigma2 / rss).min(0.999_999)).ln()
                        + k as f64 * m_screen.ln();
                    (drop, c.z)
                };
                let fitted = c
                    .effect
                    .params()
                    .iter()
                    .map(|p| FittedValue {
                        param: p.to_string(),
                        value: model.get(*p),
                        change: model.get(*p) - self.calibrated.get(*p),
                        std: None,
                        unit: p.unit().to_string(),
                    })
                    .collect();
                let words = if c.held_reason.is_empty() {
                    String::new()
                } else {
                    format!(" (held at zero: {})", c.held_reason.join("; "))
                };
                let ranking = Ranking {
                    order: Some(z),
                    calibration_z: z,
                    cv_gain: None,
                    delta_bic: Some(delta_bic),
                    calibration_rms_mm: None,
                    refitted,
                };
                Refitted {
                    change: Change::Effect(c.effect),
                    errors: distance_residuals(&model, self.val),
                    ranking,
                    fitted,
                    words,
                }
            })
            .collect();
        (refitted, self.not_identifiable.clone())
    }

    fn data_errors(&self) -> (Vec<Refitted>, Flagged) {
        let (disturbed, mis_seated) = match &self.floor {
            Some(f) => suspicious(self.calibrated, self.cal, f.touch_std_mm.powi(2)),
            None => (Vec::new(), Vec::new()),
        };
        let disturbed: Vec<DisturbedBlock> = disturbed.into_iter().take(MAX_FLAGGED).collect();
        let mis_seated: Vec<MisSeatedTouch> = mis_seated.into_iter().take(MAX_FLAGGED).collect();
        let (cal, val, options) = (self.cal, self.val, &self.options);
        let before = rms(&self.baseline_errors);
        let baseline_bic =
            bic(&distance_residuals(self.calibrated, &self.fit_data), self.calibrated.free.len());
        let refit = |data: &Observations| solve_warm(self.calibrated, &self.base_params, data, options);
        let mut out: Vec<Refitted> = (0..cal.landmarks.len())
            .into_par_iter()
            .filter_map(|l| {
                let (model, corrected) =
                    refit_with_landmark_freed(self.calibrated, &self.base_params, &self.fit_data, l, options).ok()?;
                let errors = distance_residuals(&model, &val.with_landmarks(&corrected));
                let residuals = distance_residuals(&model, &self.fit_data.with_landmarks(&corrected));
                let m = residuals.len().max(2) as f64;
                let delta_bic = bic(&residuals, self.calibrated.free.len() + 3) - baseline_bic;
                // Likelihood ratio of the freed certificate (3 parameters), from the BIC change.
                let z = chi2_z(-(delta_bic - 3.0 * m.ln()), 3);
                let id = &cal.landmarks[l].id;
                let (was, now) = (cal.landmarks[l].xyz_mm, corrected[l].xyz_mm);
                let d = [now[0] - was[0], now[1] - was[1], now[2] - was[2]];
                let off = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let words = format!(
                    "landmark {id} is measured {off:.2} mm from its certified position (Δ = ({:+.2}, {:+.2}, {:+.2}) mm in the artefact frame); with its position freed validation RMS goes from {} to {} mm; check its certificate",
                    d[0], d[1], d[2], mm(before), mm(rms(&errors))
                );
                Some(self.data_error(Change::FreeLandmark(id.clone()), errors, z, Some(delta_bic), words))
            })
            .collect();
        for b in &disturbed {
            let placement = &cal.groups[b.placement].name;
            let name = format!("{placement}/{}", b.repeat);
            let kept = cal.without(|k| cal.obs[k].group == b.placement && cal.obs[k].repeat == b.repeat);
            let Ok(model) = refit(&kept) else { continue };
            let errors = distance_residuals(&model, val);
            let words = format!(
                "in calibration placement {placement} repeat {} the touches from #{} ({}) on sit {:.2} mm off the rigid placement of the first {} (χ² {:.0} for 6 degrees of freedom): the artefact moved during the repeat; without the block validation RMS goes from {} to {} mm",
                b.repeat, b.after_touch + 1, b.first_moved, b.moved_mm, b.after_touch, b.chi2, mm(before), mm(rms(&errors))
            );
            out.push(self.data_error(Change::ExcludeBlock(name), errors, chi2_z(b.chi2, 6), None, words));
        }
        for m in &mis_seated {
            let t = &cal.obs[m.touch];
            let id = &cal.landmarks[t.touched()].id;
            let Ok(model) = refit(&cal.without(|k| k == m.touch)) else { continue };
            let errors = distance_residuals(&model, val);
            let words = format!(
                "the touch of {id} in calibration placement {} repeat {} sits {:.2} mm off its repeats (χ² {:.0} for 3 degrees of freedom): mis-seated; without it validation RMS goes from {} to {} mm",
                cal.groups[t.group].name, t.repeat, m.residual_mm, m.chi2, mm(before), mm(rms(&errors))
            );
            let change = Change::ExcludePoints(vec![cal.point_name(m.touch)]);
            out.push(self.data_error(change, errors, chi2_z(m.chi2, 3), None, words));
        }
        (out, Flagged { disturbed, mis_seated, held_out_tools: Vec::new() })
    }

    fn both(&self, a: &Refitted, b: &Refitted) -> Option<Vec<f64>> {
        let (sa, sb) = (self.screened(&a.change)?, self.screened(&b.change)?);
        let mut start = sa.start(self.calibrated);
        for p in sb.effect.params() {
            if !sb.held.contains(&p) && !start.free.iter().any(|f| f.id == p) {
                let h = crate::model::effects::default_half_range(p);
                let v = start.get(p);
                start.free_param(p, v - h, v + h);
            }
        }
        let params: Vec<ParamId> =
            self.base_params.iter().chain(&sa.added).chain(&sb.added).copied().collect();
        let both = solve_warm(&start, &params, &self.fit_data, &self.options).ok()?;
        Some(distance_residuals(&both, self.val))
    }

    fn separability(&self, a: &Refitted, b: &Refitted) -> Option<f64> {
        let (sa, sb) = (self.screened(&a.change)?, self.screened(&b.change)?);
        Some(
            self.screen
                .unexplained(&sa.cols, &sa.delta, &sb.cols)
                .min(self.screen.unexplained(&sb.cols, &sb.delta, &sa.cols)),
        )
    }

    fn floor(&self) -> Floor {
        Floor::of_distances(self.floor.clone(), rms(&self.baseline_errors), self.val)
    }

    fn gap_at(&self, rms_mm: f64) -> Option<Gap> {
        self.floor.as_ref().map(|f| gap(f, rms_mm, self.val))
    }
}
