//! The loop in one call: diagnose, add the effect the diagnosis names (the first of rivals it
//! cannot tell apart), refit, repeat — until nothing significant remains, the noise floor is
//! reached (shown by the equivalence test), or a data error must be fixed first. Each step
//! selects and tests on the same validation data, so the later steps' held-out figures are
//! not independent of the choices made before them. Every step keeps its calibrated model and its evidence, so the validation error
//! can be drawn step by step ("watch the error fall").

use crate::calib::diagnose::{diagnose, Diagnosis};
use crate::calib::fit::{calibrate, CalibError};
use crate::calib::setup::SolveOptions;
use crate::data::Observations;
use crate::model::effects::Effect;
use crate::model::ArmModel;

/// One step of the loop: the model after it and why the effect was added.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Step {
    /// Effect added at this step (`None` for the starting model).
    pub added: Option<String>,
    /// Validation RMS of this step's calibrated model, mm.
    pub validation_rms_mm: f64,
    /// Validation RMS expected from repeatability for this model, mm.
    pub expected_rms_mm: Option<f64>,
    /// Evidence for the effect added (from the previous step's diagnosis).
    pub evidence: Option<String>,
    /// Held-out p-value of the effect added.
    pub p_value: Option<f64>,
    /// This step's calibrated model.
    #[serde(skip)]
    pub model: ArmModel,
    /// This step's diagnosis summary.
    pub summary: Vec<String>,
}

/// Why the loop stopped.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub enum Stop {
    /// Validation error at the floor expected from repeatability (an equivalence test shows it).
    AtFloor,
    /// Nothing significant, no gap shown, and closeness to the floor not shown either: these data
    /// cannot tell whether anything is missing.
    CannotTell,
    /// No candidate effect is significant although a gap remains: the model is incomplete.
    NothingSignificant,
    /// A data error explains the residuals at least as well: fix it first (its name).
    DataError(String),
    /// The step limit was reached.
    StepLimit,
}

/// The whole loop.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AutoLoop {
    /// Step 0 is the starting calibration.
    pub steps: Vec<Step>,
    /// Why it stopped.
    pub stop: Stop,
    /// The last step's full diagnosis.
    pub last: Diagnosis,
}

/// Run the loop from `calibrated` (a model calibrated on `cal`, free set and bounds as
/// calibrated), adding at most `max_steps` effects.
pub fn auto_loop(
    calibrated: &ArmModel,
    cal: &Observations,
    val: &Observations,
    options: &SolveOptions,
    max_steps: usize,
) -> Result<AutoLoop, CalibError> {
    let mut model = calibrated.clone();
    let mut steps = Vec::new();
    let mut added: Option<(String, String, f64)> = None;
    loop {
        let d = diagnose(&model, cal, val, options);
        steps.push(Step {
            added: added.as_ref().map(|a| a.0.clone()),
            validation_rms_mm: d.baseline.rms_mm,
            expected_rms_mm: d.gap.as_ref().map(|g| g.expected_mm),
            evidence: added.as_ref().map(|a| a.1.clone()),
            p_value: added.as_ref().map(|a| a.2),
            model: model.clone(),
            summary: d.summary.clone(),
        });
        let at_floor = d.gap.as_ref().is_some_and(|g| g.at_floor);
        let gap_shown = d.gap.as_ref().is_none_or(|g| g.significant);
        let best_arm = d.named.first().and_then(|n| d.candidates.iter().find(|c| c.effect == *n));
        let best_data = d.data_errors.iter().find(|c| c.significant);
        let stop = if at_floor {
            Some(Stop::AtFloor)
        } else if let Some(data) = best_data.filter(|data| {
            best_arm.is_none_or(|a| {
                data.validation_rms_mm <= crate::calib::diagnose::DATA_ERROR_EXPLAINS * a.validation_rms_mm
            })
        }) {
            Some(Stop::DataError(data.effect.clone()))
        } else if best_arm.is_none() && gap_shown {
            Some(Stop::NothingSignificant)
        } else if best_arm.is_none() {
            Some(Stop::CannotTell)
        } else if steps.len() > max_steps {
            Some(Stop::StepLimit)
        } else {
            None
        };
        let (Some(best), None) = (best_arm, &stop) else {
            return Ok(AutoLoop { steps, stop: stop.unwrap_or(Stop::NothingSignificant), last: d });
        };
        let Some(effect) = Effect::parse(&best.effect) else {
            return Ok(AutoLoop { steps, stop: Stop::NothingSignificant, last: d });
        };
        added = Some((best.effect.clone(), best.evidence.clone(), best.p_value));
        let mut next = model.clone();
        effect.add_to(&mut next);
        // Warm start from this step's solution; the seeded restarts still guard the new terms.
        model = calibrate(&next, cal, options)?.model;
    }
}
