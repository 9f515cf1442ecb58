//! What the calibration data say about each candidate, before the held-out test: the per-kind
//! part of the diagnosis besides its units and its floor.
//!
//! Both kinds refit every candidate warm from the calibrated model and hand the held-out test
//! the same thing ([`Refitted`]): the candidate's held-out errors and the *order* of the fixed
//! sequence, which must come from the calibration data alone. They differ in how the calibration
//! data rank the candidates, each the route that is cheap and sound for its data:
//!
//! * artefact placements ([`super::screen::ScoreTest`]): one Jacobian with every candidate
//!   parameter freed, a score test per candidate, the strongest refitted; the order is the
//!   calibration evidence, a normal deviate;
//! * instrument sessions ([`super::cross_validate::CrossValidation`]): every candidate refitted
//!   in full (each session's frame has a closed form), the strongest cross-validated over
//!   contiguous pose folds of the calibration sessions; the order is the cross-validated gain.

use super::data_errors::touches::{DisturbedBlock, MisSeatedTouch};
use super::data_errors::DataError;
use super::floor::Floor;
use super::words::mm;
use super::JointResiduals;
use crate::calib::floor::Gap;
use crate::calib::setup::Change;
use crate::model::effects::{Effect, EffectKind};

/// What the calibration data say about a candidate: its place in the fixed sequence and the
/// figures behind it.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Ranking {
    /// Its place in the fixed sequence, larger first; `None`: the calibration data do not
    /// promise enough for it to be tested.
    pub order: Option<f64>,
    /// Calibration evidence as a standard normal deviate.
    pub calibration_z: f64,
    /// ln(MSE_before / MSE_with) over the cross-validated calibration points, when
    /// cross-validated.
    pub cv_gain: Option<f64>,
    /// Change of BIC on the calibration data (negative favours the change), when computed.
    pub delta_bic: Option<f64>,
    /// Calibration RMS with the change, mm, when refitted in full.
    pub calibration_rms_mm: Option<f64>,
    /// Refitted (nonlinear) rather than scored from a linearised step.
    pub refitted: bool,
}

/// A candidate refitted on the calibration data, ready for the held-out test.
#[derive(Clone, Debug)]
pub struct Refitted {
    /// The change.
    pub change: Change,
    /// Held-out errors with the change (the layout of [`super::units::Measure::errors`]).
    pub errors: Vec<f64>,
    /// What the calibration data say about it.
    pub ranking: Ranking,
    /// The effect's parameters as fitted.
    pub fitted: Vec<FittedValue>,
    /// For a data error: what was found, in words. For an effect: what was held and why.
    pub words: String,
}

/// One parameter of a candidate effect as fitted.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FittedValue {
    /// The parameter.
    pub param: String,
    /// Its value, in `unit`.
    pub value: f64,
    /// Its change from the calibrated model.
    pub change: f64,
    /// One standard deviation, when the refit estimated it.
    pub std: Option<f64>,
    /// Unit.
    pub unit: String,
}

/// Data errors a detector flagged, beside those scored by the held-out test.
#[derive(Clone, Debug, Default)]
pub struct Flagged {
    /// Calibration blocks whose artefact seems to have moved within the repeat.
    pub disturbed: Vec<DisturbedBlock>,
    /// Calibration touches far off their repeats.
    pub mis_seated: Vec<MisSeatedTouch>,
    /// A tool moved in a held-out session (its offset is fitted on that session's own points,
    /// so the held-out test would be in-sample: judged by its own rule).
    pub held_out_tools: Vec<DataError>,
}

/// An effect the data cannot identify next to the current model.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct NotIdentifiable {
    /// Effect name.
    pub effect: String,
    /// What absorbs it.
    pub reason: String,
}

/// The per-kind evidence of the calibration data (see the module doc).
pub trait Evidence: Sync {
    /// The calibrated model the held-out test starts from.
    fn baseline(&self) -> &crate::model::ArmModel;
    /// Every library effect not in the model, refitted; and those not identifiable.
    fn effects(&self) -> (Vec<Refitted>, Vec<NotIdentifiable>);
    /// The data errors' remedies, refitted; and what the detectors flagged.
    fn data_errors(&self) -> (Vec<Refitted>, Flagged);
    /// Held-out errors with both `a` and `b`, refitted together (warm).
    fn both(&self, a: &Refitted, b: &Refitted) -> Option<Vec<f64>>;
    /// How far the calibration data separate `a` from `b`, in noise variances, when computed.
    fn separability(&self, a: &Refitted, b: &Refitted) -> Option<f64>;
    /// The floor of the held-out data and the gap of the calibrated model to it.
    fn floor(&self) -> Floor;
    /// The gap `rms_mm` held out would leave to the same floor.
    fn gap_at(&self, rms_mm: f64) -> Option<Gap>;
}

/// Plain words for a fitted effect that brings the held-out RMS from `before` to `after`.
pub fn effect_words(
    effect: Effect,
    fitted: &[FittedValue],
    joints: &[JointResiduals],
    before: f64,
    after: f64,
) -> String {
    let gain = format!("would bring validation RMS from {} to {} mm", mm(before), mm(after));
    let value = |k: usize| fitted.get(k).map_or(0.0, |f| f.change);
    let j = effect.joint.map_or(0, |j| j + 1);
    match effect.kind {
        EffectKind::Eccentricity | EffectKind::Eccentricity2 | EffectKind::Harmonic3 | EffectKind::Harmonic4 => {
            let order = effect.kind.harmonic_order().unwrap_or(1);
            let n = if order == 1 { String::new() } else { order.to_string() };
            let seen = joints
                .get(j.saturating_sub(1))
                .and_then(|r| r.spectrum.iter().find(|s| s.0 == order).map(|s| s.1));
            let residual = match seen {
                Some(s) if s.explained > 0.1 && s.is_plausible(order) => format!("the residual follows sin {n}θ{j} with {:.3}° amplitude ({:.0} % of its variance); ", s.amplitude_deg, 100.0 * s.explained),
                _ => String::new(),
            };
            let what = match order {
                1 => "encoder eccentricity".to_string(),
                2 => "second-harmonic encoder error".to_string(),
                _ => format!("{order}-per-revolution encoder error"),
            };
            format!("{residual}{what} of joint {j} (Δθ = {:.3}°·sin {n}φ {:+.3}°·cos {n}φ, amplitude {:.3}°) {gain}", value(0), value(1), value(0).hypot(value(1)))
        }
        EffectKind::Compliance => {
            let slope = joints.get(j.saturating_sub(1)).map_or(0.0, |r| r.gravity_slope_deg_per_m);
            let fitted = value(0);
            // The calibration already moved parameters that absorb part of a sag, so the apparent
            // error's slope alone can be far smaller than the fitted compliance, or of the other sign.
            let seen = if slope * fitted > 0.0 && slope.abs() >= fitted.abs() / 3.0 {
                format!("the residual grows with its gravity lever ({slope:+.3} °/m seen, {fitted:+.3} °/m fitted)")
            } else {
                format!("a deflection proportional to its gravity lever fits the residuals ({fitted:+.3} °/m fitted; the apparent error against the lever alone shows {slope:+.3} °/m, because the parameters already calibrated absorb part of the sag)")
            };
            format!("joint {j} sags under gravity: {seen}; compliance of joint {j} {gain}")
        }
        EffectKind::Sag | EffectKind::Bend => {
            let (what, cause) = match effect.kind {
                EffectKind::Sag => (
                    "sag",
                    "sags under the torque of the links beyond it (every branch it carries), not only the tool's",
                ),
                _ => (
                    "bend",
                    "bends across its axis under the gravity moment of the links beyond it (bearing or link \
                     compliance), which its own spring cannot give",
                ),
            };
            if effect.joint.is_some() {
                return format!("joint {j} {cause}: {what}:{j} = {:+.3} °/(kN·m) {gain}", value(0));
            }
            let mut largest: Vec<&FittedValue> = fitted.iter().filter(|f| f.change != 0.0).collect();
            largest.sort_by(|a, b| b.change.abs().total_cmp(&a.change.abs()));
            let named: Vec<String> =
                largest.iter().take(4).map(|f| format!("{} {:+.2}", f.param, f.change)).collect();
            format!(
                "the load-bearing joints' deflection under the masses: each joint {cause} (largest {} °/(kN·m)); \
                 {what} on every joint {gain}",
                named.join(", ")
            )
        }
        EffectKind::Twist => format!("the axis after joint {j} is twisted by {:+.3}° more than the model says; twist of joint {j} {gain}", value(0)),
        EffectKind::Axis => format!("consecutive axes at joint {j} are tilted by {:+.3}° about y; axis misalignment of joint {j} {gain}", value(0)),
        EffectKind::LinkOffset => format!("axes at joint {j} miss each other by {:+.3} mm; link offset a{j} {gain}", value(0)),
        EffectKind::Length => format!("link length d{j} is off by {:+.3} mm; {gain}", value(0)),
        EffectKind::Offset => format!("encoder {j} zero is off by {:+.3}°; {gain}", value(0)),
        EffectKind::Tcp => format!("the tool tip sits off by ({:+.3}, {:+.3}, {:+.3}) mm in the last frame; a 3-D tool offset {gain}", value(0), value(1), value(2)),
        EffectKind::Scale => format!("lengths scale by {:+.0} ppm (temperature or artefact scale); {gain}", value(0)),
        EffectKind::Mass => {
            let changes: Vec<String> = fitted.iter().map(|f| format!("{} {:+.3} kg", f.param, f.change)).collect();
            format!("the arm carries other masses than its table says ({}); {gain}", changes.join(", "))
        }
    }
}
