//! Whether the figures of a calibration are a result: judged against scales that do not depend
//! on the (possibly wrong) model being calibrated.
//!
//! Two scales bound what a calibration RMS of distances can be:
//! - the artefact: an RMS larger than [`SPAN_FRACTION`] of the largest certified distance
//!   between its landmarks is never a calibration, whatever the model (a 477 mm RMS on an
//!   artefact whose landmarks lie at most 198 mm apart measured nothing);
//! - the touches' own spread: repeated touches of one landmark in one placement in the same pose
//!   (joint angles within [`SAME_POSE_DEG`]) differ in joint space by the arm's repeatability
//!   plus the seating; that difference propagated through the *nominal* model (the one
//!   calibration starts from, never the fitted one, which a wrong model can bend into any shape)
//!   is a spread in millimetres that hardly depends on the model, since a small joint change
//!   moves the tool by lever × angle whatever the model's errors. A distance RMS many times that
//!   spread means the model cannot describe the touches.
//!
//! A wrong-but-valid model (a sign flipped, a length in metres, two joints swapped, another
//! arm's geometry, a 180° offset) leaves the fit far beyond both; a fitted model measured against
//! itself (its own repeatability) could look fine.

use crate::calib::fit::Fit;
use crate::calib::nuisance::tool::positions;
use crate::calib::validate::Validation;
use crate::data::Observations;
use crate::model::ArmModel;
use std::collections::HashMap;

/// Share of the artefact's largest certified distance above which a distance RMS is never a
/// calibration.
pub const SPAN_FRACTION: f64 = 0.05;
/// Calibration RMS, mm, below which a fit is never suspect on account of its size alone.
pub const RMS_ALWAYS_SUSPECT_MM: f64 = 1.0;
/// How many times the touches' spread (RMS distance of repeated touches from their barycentre,
/// through the nominal model) the calibration RMS may be.
pub const RMS_REPEATABILITY_FACTOR: f64 = 5.0;
/// Calibration RMS, mm, above which a fit is not trusted when the data has no repeats.
pub const RMS_WITHOUT_REPEATS_MM: f64 = 5.0;
/// How many times the calibration RMS (or its limit) the validation RMS may be.
pub const VALIDATION_FACTOR: f64 = 5.0;

/// Largest difference of any joint, degrees, between two touches of one landmark in one
/// placement for them to count as a repeat of one pose: beyond it the arm was in another pose
/// (another elbow or wrist branch, or a re-seated hand), and a wrong model would turn the pose
/// change into a spread.
pub const SAME_POSE_DEG: f64 = 0.5;

/// Whether two touches hold the same pose within [`SAME_POSE_DEG`] on every joint (angles wrap).
fn same_pose(a: &[f64], b: &[f64]) -> bool {
    a.iter().zip(b).all(|(x, y)| {
        let d = (x - y).rem_euclid(360.0);
        d.min(360.0 - d) <= SAME_POSE_DEG
    })
}

/// The model-independent scales a calibration is judged against.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrustScales {
    /// Largest certified distance between two landmarks, mm.
    pub span_mm: f64,
    /// RMS distance of same-pose repeated touches from their pair's barycentre through the
    /// nominal model, mm (calibration and validation touches); `None` when no landmark was
    /// touched twice in one pose in a placement.
    pub repeat_spread_mm: Option<f64>,
}

impl TrustScales {
    /// The scales of these touches on this artefact, the touches taken through `nominal`.
    pub fn of(nominal: &ArmModel, cal: &Observations, val: &Observations) -> TrustScales {
        let (mut sum_sq, mut pairs) = (0.0, 0usize);
        for data in [cal, val] {
            let positions = positions(nominal, data);
            let mut groups: HashMap<(usize, usize), Vec<usize>> = HashMap::new();
            for (k, t) in data.obs.iter().enumerate() {
                if let Some(l) = t.landmark() {
                    groups.entry((t.group, l)).or_default().push(k);
                }
            }
            for touches in groups.values() {
                for (i, &a) in touches.iter().enumerate() {
                    for &b in &touches[i + 1..] {
                        if same_pose(&data.obs[a].q_deg, &data.obs[b].q_deg) {
                            // Each touch lies half the difference from the pair's barycentre.
                            sum_sq += ((positions[a] - positions[b]).norm() / 2.0).powi(2);
                            pairs += 1;
                        }
                    }
                }
            }
        }
        let repeat_spread_mm = (pairs > 0).then(|| (sum_sq / pairs as f64).sqrt());
        TrustScales { span_mm: cal.landmark_span_mm(), repeat_spread_mm }
    }

    /// Largest distance RMS, mm, any calibration on the artefact may have (`None` without
    /// landmarks: instrument points alone have no artefact to bound them).
    pub fn artefact_limit_mm(&self) -> Option<f64> {
        (self.span_mm > 0.0).then_some(SPAN_FRACTION * self.span_mm)
    }

    /// Largest calibration RMS, mm, the touches' spread allows.
    pub fn spread_limit_mm(&self) -> f64 {
        match self.repeat_spread_mm {
            Some(spread) => (RMS_REPEATABILITY_FACTOR * spread).max(RMS_ALWAYS_SUSPECT_MM),
            None => RMS_WITHOUT_REPEATS_MM,
        }
    }

    /// Why a calibration RMS and a validation RMS (mm) are beyond these scales; empty when
    /// within. Non-finite figures are beyond every scale.
    pub fn beyond(&self, calibration_rms_mm: f64, validation_rms_mm: f64) -> Vec<String> {
        let mut problems = self.calibration_beyond(calibration_rms_mm);
        problems.extend(self.validation_beyond(validation_rms_mm));
        problems
    }

    /// Why a calibration RMS (mm) is beyond the artefact's scale or the touches' spread.
    pub fn calibration_beyond(&self, rms_mm: f64) -> Vec<String> {
        if let Some(problem) = self.artefact_beyond("calibration", rms_mm) {
            return vec![problem];
        }
        let limit = self.spread_limit_mm();
        (rms_mm > limit)
            .then(|| {
                format!(
                    "calibration RMS {rms_mm:.3} mm is far beyond what the data's repeatability allows \
                     ({limit:.3} mm; {}): the model cannot describe these touches — {CAUSE}",
                    self.spread_text()
                )
            })
            .into_iter()
            .collect()
    }

    /// Why a validation RMS (mm) is beyond the artefact's scale or [`VALIDATION_FACTOR`] times
    /// what the touches' spread allows a calibration.
    pub fn validation_beyond(&self, rms_mm: f64) -> Vec<String> {
        if let Some(problem) = self.artefact_beyond("validation", rms_mm) {
            return vec![problem];
        }
        let limit = VALIDATION_FACTOR * self.spread_limit_mm();
        (rms_mm > limit)
            .then(|| {
                format!(
                    "validation RMS {rms_mm:.3} mm is beyond {limit:.3} mm, {VALIDATION_FACTOR}× what the \
                     data's repeatability allows a calibration ({}): the model or the validation sessions \
                     do not describe this arm — {CAUSE}",
                    self.spread_text()
                )
            })
            .into_iter()
            .collect()
    }

    /// Why an RMS (mm) is not finite or beyond the artefact's scale.
    fn artefact_beyond(&self, what: &str, rms_mm: f64) -> Option<String> {
        if !rms_mm.is_finite() {
            return Some(format!("the {what} RMS is not a finite number"));
        }
        let limit = self.artefact_limit_mm()?;
        if rms_mm > limit {
            Some(format!(
                "{what} RMS {rms_mm:.3} mm exceeds {:.0} % of the artefact's largest certified distance \
                 ({:.1} mm → {limit:.3} mm): no calibration measures distances this badly — {CAUSE}",
                SPAN_FRACTION * 100.0,
                self.span_mm
            ))
        } else {
            None
        }
    }

    fn spread_text(&self) -> String {
        match self.repeat_spread_mm {
            Some(s) => format!("repeated touches scatter by {s:.3} mm RMS through the nominal model"),
            None => "no landmark was touched twice in one pose in a placement".to_string(),
        }
    }
}

/// The likely causes of figures beyond the scales.
const CAUSE: &str = "a model file of another arm or with a wrong number (a sign, a unit, an offset, joints \
                     in another order), artefact coordinates that are not the pillars touched (units, \
                     landmark ids swapped), or sessions mixed from different setups";

/// Why the figures of a finished calibration cannot be taken as a result: a non-finite figure,
/// figures beyond the model-independent `scales`, a fit that did not move from its start, a
/// validation error far beyond the calibration error. Each reason names the likely cause.
pub fn result_problems(fit: &Fit, validation: &Validation, scales: &TrustScales) -> Vec<String> {
    let mut problems = Vec::new();
    let v = &validation.overall;
    let figures = [fit.rms_mm, fit.cost, v.rms_mm, v.mean_mm, v.std_mm, v.max_mm];
    if figures.iter().any(|x| !x.is_finite()) {
        problems.push("a calibration or validation figure is not a finite number".to_string());
        return problems;
    }
    if v.count == 0 {
        problems.push("no validation pair: the fit was not checked on held-out touches".to_string());
    }
    problems.extend(scales.beyond(fit.rms_mm, if v.count > 0 { v.rms_mm } else { 0.0 }));
    let moved = fit.estimates.iter().any(|e| e.status.starts_with("estimated") && e.value != e.nominal);
    if !moved && fit.rms_mm > RMS_ALWAYS_SUSPECT_MM {
        problems.push(format!(
            "the fit did not move from its start (calibration RMS {:.3} mm): the solver found no step \
             that lowers the cost — bounds too tight around the start, or a Huber threshold far below \
             the residuals",
            fit.rms_mm
        ));
    }
    if v.count > 0 && v.rms_mm > (VALIDATION_FACTOR * fit.rms_mm).max(RMS_ALWAYS_SUSPECT_MM) {
        problems.push(format!(
            "validation RMS {:.3} mm is {:.0}× the calibration RMS {:.3} mm: the validation sessions look \
             like another arm, another artefact or a moved setup, or the calibration data is too thin",
            v.rms_mm,
            v.rms_mm / fit.rms_mm.max(1e-9),
            fit.rms_mm
        ));
    }
    problems
}

/// Largest calibration orientation RMS of a 6-DoF probe that can be a result, degrees: a probe on
/// a calibrated arm misses its own orientations by hundredths of a degree.
pub const ORIENTATION_SUSPECT_DEG: f64 = 10.0;

/// Why the figures of a calibration on instrument points cannot be a result: a calibration RMS
/// beyond [`SPAN_FRACTION`] of the arm's reach `reach_mm` (a model-independent scale: no
/// calibrated model of the right arm misses its own points by that much), or a probe's
/// orientations missed by more than [`ORIENTATION_SUSPECT_DEG`].
pub fn point_problems(fit: &Fit, reach_mm: f64) -> Vec<String> {
    let mut problems = Vec::new();
    let limit = SPAN_FRACTION * reach_mm;
    if !fit.rms_mm.is_finite() || fit.rms_mm > limit.max(RMS_ALWAYS_SUSPECT_MM) {
        problems.push(format!(
            "calibration RMS {:.3} mm is beyond {:.0} % of the arm's reach ({reach_mm:.0} mm): no calibrated model \
             of this arm misses its own points by that much — columns swapped or mislabelled, angles in another \
             unit, a quaternion written scalar-last under qw,qx,qy,qz, or another arm's model",
            fit.rms_mm,
            100.0 * SPAN_FRACTION
        ));
    }
    if let Some(o) =
        fit.stats.orientations.as_ref().filter(|o| o.rms_deg.is_nan() || o.rms_deg > ORIENTATION_SUSPECT_DEG)
    {
        problems.push(format!(
            "calibration orientation RMS {:.1}° over {} probe orientations is beyond {ORIENTATION_SUSPECT_DEG}°: a \
             probe on a calibrated arm misses its own orientations by hundredths of a degree — a quaternion written \
             scalar-last (qx,qy,qz,qw) under qw,qx,qy,qz, the probe turned on its mount in a session (kincal \
             diagnose RUN names it; --float-tool SESSION), or orientations in another frame than the probe's",
            o.rms_deg, o.orientations
        ));
    }
    problems
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::fit::calibrate;
    use crate::calib::setup::SolveOptions;
    use crate::calib::validate::validate;
    use crate::model::{ArmModel, Joint, ParamId};
    use crate::simulate::{simulate, SimulationOptions};

    /// `model` with `id` set to `value` and its bounds moved with it (same width).
    fn moved(mut model: ArmModel, id: ParamId, value: f64) -> ArmModel {
        let shift = value - model.get(id);
        model.set(id, value);
        if let Some(f) = model.free.iter_mut().find(|f| f.id == id) {
            (f.lower, f.upper) = (f.lower + shift, f.upper + shift);
        }
        model
    }

    /// Five plausible-looking models of the wrong arm, each with bounds around its own values.
    fn wrong_models() -> Vec<(&'static str, ArmModel)> {
        let suta = ArmModel::suta_nominal();
        let swapped = {
            let mut m = suta.clone();
            m.joints.swap(2, 4);
            let mut fresh = m.clone();
            fresh.free.clear();
            for f in &m.free {
                let (lo, hi) = (f.lower - suta.get(f.id), f.upper - suta.get(f.id));
                fresh.free_param(f.id, m.get(f.id) + lo, m.get(f.id) + hi);
            }
            fresh
        };
        let other_arm = {
            // A PUMA-like industrial arm: lengths along x, other twists.
            let mut m = suta.clone();
            let rows = [(0.0, 0.0, 90.0), (0.0, 431.8, 0.0), (149.1, 20.3, -90.0), (433.1, 0.0, 90.0)];
            for (j, &(d_mm, a_mm, alpha_deg)) in rows.iter().enumerate() {
                m.joints[j] = Joint { d_mm, a_mm, alpha_deg, ..m.joints[j] };
            }
            m.joints[4] = Joint { d_mm: 0.0, alpha_deg: -90.0, ..m.joints[4] };
            m.joints[5] = Joint { d_mm: 56.2, ..m.joints[5] };
            let mut fresh = m.clone();
            fresh.free.clear();
            for f in &suta.free {
                fresh.free_param(f.id, m.get(f.id) - 10.0, m.get(f.id) + 10.0);
            }
            fresh
        };
        vec![
            ("a sign flipped (d5 = −371 mm)", moved(suta.clone(), ParamId::Length(4), -371.0)),
            ("a length in metres (d3 = 0.571)", moved(suta.clone(), ParamId::Length(2), 0.571)),
            ("joints 3 and 5 swapped", swapped),
            ("another arm's geometry (PUMA-like)", other_arm),
            ("a 180° offset (joint 2)", moved(suta.clone(), ParamId::Offset(1), 20.7 + 180.0)),
        ]
    }

    #[test]
    fn wrong_but_valid_models_are_never_a_calibration() {
        let truth_nominal = ArmModel::suta_nominal();
        let sim = simulate(&truth_nominal, &SimulationOptions::default());
        let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
        let val = Observations::from_sessions(&sim.validation, &sim.artefact);
        let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
        let right = calibrate(&truth_nominal, &cal, &options).unwrap();
        let scales = TrustScales::of(&truth_nominal, &cal, &val);
        let fine = result_problems(&right, &validate(&right.model, &val), &scales);
        assert!(fine.is_empty(), "the right model: {fine:?}");
        for (name, wrong) in wrong_models() {
            let scales = TrustScales::of(&wrong, &cal, &val);
            // The touches' spread through the wrong model stays a repeatability (sub-millimetre):
            // the scale does not grow with the model's error.
            assert!(scales.repeat_spread_mm.is_some_and(|s| s < 1.0), "{name}: {scales:?}");
            let fit = calibrate(&wrong, &cal, &options).expect("a fit, however bad");
            let validation = validate(&fit.model, &val);
            let problems = result_problems(&fit, &validation, &scales);
            assert!(
                !problems.is_empty(),
                "{name}: calibration {:.3} mm, validation {:.3} mm taken as a result (scales {scales:?})",
                fit.rms_mm,
                validation.overall.rms_mm
            );
        }
    }

    #[test]
    fn the_scales_bound_each_figure() {
        let scales = TrustScales { span_mm: 200.0, repeat_spread_mm: Some(0.1) };
        assert!(scales.beyond(0.2, 0.3).is_empty());
        assert!(scales.beyond(1.5, 0.3)[0].contains("repeatability"));
        assert!(scales.beyond(477.0, 595.0).iter().all(|p| p.contains("largest certified distance")));
        assert_eq!(scales.beyond(f64::NAN, 0.3).len(), 1);
        let no_repeats = TrustScales { repeat_spread_mm: None, ..scales };
        assert!(no_repeats.beyond(4.0, 4.0).is_empty() && !no_repeats.beyond(6.0, 4.0).is_empty());
    }
}
