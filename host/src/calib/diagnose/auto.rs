//! The loop in one call: diagnose, apply what the diagnosis names first (an effect, or the remedy
//! of a data error), calibrate again (from the step's model and from the first
//! model with every change so far, the lower cost kept), repeat — until the held-out
//! error is at the floor, nothing is significant, a certificate must be checked (the loop cannot
//! fix the held-out data themselves), or the step limit. Each step selects and tests on the same
//! held-out data, so the later steps' figures are not independent of the choices made before
//! them. Every step keeps its calibrated model and its evidence, so the held-out error can be drawn
//! step by step ("watch the error fall").

use super::{diagnose, DiagnoseError, Diagnosis};
use crate::calib::fit::{beats, TIE_FTOL};
use crate::calib::setup::{Change, Setup};
use crate::data::Observations;
use crate::model::ArmModel;

/// One step of the loop: the calibration after it and why its change was applied.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Step {
    /// What was applied at this step (`None` for the start).
    pub applied: Option<String>,
    /// Its `kincal calibrate` options.
    pub action: Option<String>,
    /// Held-out RMS of this step's calibrated model, mm.
    pub held_out_rms_mm: f64,
    /// Held-out RMS a complete model would leave, from the floor, mm.
    pub expected_rms_mm: Option<f64>,
    /// The floor of the held-out data, mm.
    pub floor_mm: Option<f64>,
    /// The evidence for what was applied (from the previous step's diagnosis).
    pub evidence: Option<String>,
    /// Its held-out p in the previous step's diagnosis.
    pub p_value: Option<f64>,
    /// What this step's diagnosis named.
    pub named: Vec<String>,
    /// This step's diagnosis shows the model incomplete.
    pub incomplete: bool,
    /// This step's diagnosis summary.
    pub summary: Vec<String>,
    /// This step's calibrated model.
    #[serde(skip)]
    pub model: Option<ArmModel>,
}

/// Why the loop stopped.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Stop {
    /// The held-out error is at the floor.
    AtFloor,
    /// Nothing significant, no gap shown, and closeness to the floor not shown either: these data
    /// cannot tell whether anything is missing.
    CannotTell,
    /// Nothing is significant although a gap remains (or the floor is unknown).
    NothingSignificant,
    /// A landmark's certificate must be checked first (its name).
    DataError(String),
    /// The step limit was reached.
    StepLimit,
}

/// The whole loop.
#[derive(Clone, Debug, serde::Serialize)]
pub struct AutoLoop {
    /// Step 0 is the calibration the loop started from.
    pub steps: Vec<Step>,
    /// Why it stopped.
    pub stop: Stop,
    /// The options of the last step's setup, as `kincal calibrate` spells them.
    pub options: String,
    /// The last step's full diagnosis.
    pub last: Diagnosis,
    /// The last step's setup.
    #[serde(skip)]
    pub setup: Setup,
}

/// Run the loop from `calibrated` (calibrated on `cal` as `setup` asks), applying at most
/// `max_steps` changes.
pub fn auto_loop(
    setup: &Setup,
    calibrated: &ArmModel,
    cal: &Observations,
    val: &Observations,
    max_steps: usize,
) -> Result<AutoLoop, DiagnoseError> {
    let (mut setup, mut model) = (setup.clone(), calibrated.clone());
    // The loop's first model with every change applied so far: the second start of each step.
    let mut first = calibrated.clone();
    let mut steps = Vec::new();
    let mut applied: Option<(String, String, String, f64)> = None;
    loop {
        let d = diagnose(&setup, &model, cal, val)?;
        let step_model = d.model.clone().unwrap_or(model);
        steps.push(Step {
            applied: applied.as_ref().map(|a| a.0.clone()),
            action: applied.as_ref().map(|a| a.1.clone()),
            held_out_rms_mm: d.baseline.rms_mm,
            expected_rms_mm: d.floor.expected_mm(),
            floor_mm: d.floor.floor_mm,
            evidence: applied.as_ref().map(|a| a.2.clone()),
            p_value: applied.as_ref().map(|a| a.3),
            named: d.named.clone(),
            incomplete: d.incomplete,
            summary: d.summary.clone(),
            model: Some(step_model.clone()),
        });
        let stop = if d.explains {
            Some(Stop::AtFloor)
        } else {
            match &d.change {
                None if d.incomplete || d.floor.gap.is_none() => Some(Stop::NothingSignificant),
                None => Some(Stop::CannotTell),
                Some(Change::FreeLandmark(_)) => Some(Stop::DataError(d.named[0].clone())),
                Some(_) if steps.len() > max_steps => Some(Stop::StepLimit),
                Some(_) => None,
            }
        };
        let (Some(change), None) = (d.change.clone(), &stop) else {
            let options = setup.options_text();
            return Ok(AutoLoop {
                steps,
                stop: stop.unwrap_or(Stop::NothingSignificant),
                options,
                last: d,
                setup,
            });
        };
        let lead = d.candidate(&change.name());
        applied = Some((
            change.name(),
            change.action(),
            lead.map_or(String::new(), |c| c.evidence.clone()),
            lead.map_or(f64::NAN, |c| c.p_value),
        ));
        let (next, start) = setup.apply(&change, &step_model);
        first = setup.apply(&change, &first).1;
        // Two starts, the lower cost kept (the warm one on a tie): this step's solution (warm) and the first model with
        // every change applied. A warm start alone can settle in a poorer minimum: on a humanoid,
        // the solution with `bend` alone (its bends stretched to mimic the missing sag) led the
        // refit with `sag` added to a cost 0.45 % above the one both starts can reach, and a
        // weakly seen wrist compliance 3.5 standard deviations off.
        // At the first step both starts are the same model: it is fitted once.
        model = if first == start {
            next.calibrate(&start, cal)?.model
        } else {
            let (warm, again) = rayon::join(|| next.calibrate(&start, cal), || next.calibrate(&first, cal));
            match (warm?, again?) {
                (w, a) if beats(a.cost, w.cost, TIE_FTOL) => a.model,
                (w, _) => w.model,
            }
        };
        setup = next;
    }
}
