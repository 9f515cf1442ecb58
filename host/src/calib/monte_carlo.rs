//! Monte Carlo checks of the diagnosis' statistics on simulated data from the independent
//! forward path ([`crate::simulate`]): how often clean data get a false call, and how often
//! each library effect, hidden alone, is the one the diagnosis names.
//!
//! A *false call* on clean data is any of: an arm effect called significant, a data error
//! called significant, a block flagged as disturbed (a knock) or a touch as mis-seated, and the
//! gap test saying the model misses something. Rates come with a 95 % Wilson interval.

use crate::calib::diagnose::{diagnose, DiagnoseError, Diagnosis};
use crate::calib::fit::calibrate;
use crate::calib::setup::{Setup, SolveOptions};
use crate::data::Observations;
use crate::model::effects::{Effect, EffectKind};
use crate::model::{ArmModel, ParamId};
use crate::simulate::{simulate, SimulationOptions};

/// What one clean run called falsely.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FalseCalls {
    /// An arm effect was called significant.
    pub effect: bool,
    /// A data error (landmark, block, touch) was called significant.
    pub data_error: bool,
    /// A block was flagged as disturbed or a touch as mis-seated.
    pub knock: bool,
    /// The gap test said the model misses something.
    pub misses: bool,
}

impl FalseCalls {
    /// Any false call at all.
    pub fn any(&self) -> bool {
        self.effect || self.data_error || self.knock || self.misses
    }
}

/// A count of hits over runs, with its 95 % Wilson interval.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rate {
    /// Runs with the event.
    pub hits: usize,
    /// Runs.
    pub runs: usize,
}

impl Rate {
    /// Count the runs for which `event` holds.
    pub fn of<T>(runs: &[T], event: impl Fn(&T) -> bool) -> Rate {
        Rate { hits: runs.iter().filter(|r| event(r)).count(), runs: runs.len() }
    }

    /// The 95 % Wilson score interval of the rate (0–1).
    pub fn interval(&self) -> (f64, f64) {
        let (k, n, z) = (self.hits as f64, self.runs.max(1) as f64, 1.959_964);
        let p = k / n;
        let centre = (p + z * z / (2.0 * n)) / (1.0 + z * z / n);
        let half = z / (1.0 + z * z / n) * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt();
        ((centre - half).max(0.0), (centre + half).min(1.0))
    }
}

impl std::fmt::Display for Rate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (lo, hi) = self.interval();
        write!(
            f,
            "{}/{} = {:.1} % (95 % CI {:.1}–{:.1} %)",
            self.hits,
            self.runs,
            100.0 * self.hits as f64 / self.runs.max(1) as f64,
            100.0 * lo,
            100.0 * hi
        )
    }
}

/// Simulate the thesis-sized problem of `seed` with `hidden` effects, calibrate the thesis
/// model (2 restarts) and diagnose it.
pub fn simulate_and_diagnose(seed: u64, hidden: Vec<(ParamId, f64)>) -> Result<Diagnosis, DiagnoseError> {
    let nominal = ArmModel::suta_nominal();
    let sim = simulate(&nominal, &SimulationOptions { seed, hidden, ..SimulationOptions::default() });
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let options = SolveOptions { restarts: Some(2), seed, ..SolveOptions::default() };
    let fit = calibrate(&nominal, &cal, &options)?;
    diagnose(&Setup::new(options), &fit.model, &cal, &val)
}

/// The false calls of a diagnosis of clean data.
pub fn false_calls(d: &Diagnosis) -> FalseCalls {
    FalseCalls {
        effect: d.candidates.iter().any(|c| c.significant),
        data_error: d.data_errors.iter().any(|c| c.significant),
        knock: !d.disturbed.is_empty() || !d.mis_seated.is_empty(),
        misses: d.floor.gap.as_ref().is_some_and(|g| g.significant),
    }
}

/// Hidden parameter values for `effect` alone, sized like the project's tests (a clear lift of
/// validation RMS over the floor on most joints): 0.15° for angle errors (a second term of
/// 0.6× that on the cosine of periodic ones), 0.5 mm for link offsets, 0.2 °/m for compliance,
/// 1 mm for the tool offset, 1500 ppm for scale.
pub fn hidden_for(effect: Effect) -> Vec<(ParamId, f64)> {
    let params = effect.params();
    let size = match effect.kind {
        EffectKind::LinkOffset | EffectKind::Length => 0.5,
        EffectKind::Compliance => 0.2,
        EffectKind::Tcp => 1.0,
        EffectKind::Scale => 1500.0,
        _ => 0.15,
    };
    params.iter().enumerate().map(|(k, &p)| (p, if k == 0 { size } else { 0.6 * size })).collect()
}

/// Whether the diagnosis names `effect`: first of the named effects, among rivals it cannot
/// tell apart, or exactly equivalent to the first.
pub fn names(d: &Diagnosis, effect: Effect) -> bool {
    let name = effect.to_string();
    d.named.contains(&name)
        || d.named
            .first()
            .and_then(|n| d.candidates.iter().find(|c| c.name == *n))
            .is_some_and(|c| c.equivalent.contains(&name))
}
