//! Plans checked on simulated data: the planned placements measured by the simulator's
//! independent forward path against as many random reachable ones.

use super::candidates::{candidate_placements, Candidate, Place};
use super::design::{blocks, plan_rivals, plan_weak, rigid_residuals};
use super::{PlanOptions, SuggestedPlacement};
use crate::calib::diagnose::{diagnose, DiagnoseError};
use crate::calib::error::CalibError;
use crate::calib::fit::{calibrate, Fit};
use crate::calib::setup::{Setup, SolveOptions};
use crate::data::{Artefact, Observations, Session, SESSION_FORMAT};
use crate::model::effects::Effect;
use crate::model::{ArmModel, ParamId};
use crate::simulate::{SimulatedData, SimulationOptions};
use nalgebra::Vector3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Measure placements with a (simulated) true arm: every planned touch `repeats` times, posed by
/// the true arm's inverse kinematics started from the planned configuration, with the seating
/// and encoder noise of `sim`. One session per placement, named `name_prefix` + its number.
pub fn measure(
    truth: &ArmModel,
    artefact: &Artefact,
    placements: &[&Candidate],
    sim: &SimulationOptions,
    name_prefix: &str,
    rng: &mut ChaCha8Rng,
) -> Vec<Session> {
    use rand_distr::{Distribution, Normal};
    let seat = Normal::new(0.0, sim.seating_noise_mm.max(0.0)).ok();
    let enc_noise = Normal::new(0.0, sim.encoder_noise_deg.max(0.0)).ok();
    placements
        .iter()
        .enumerate()
        .filter_map(|(k, c)| {
            let Place::Placement(placement) = &c.place else { return None };
            let mut measurements = Vec::new();
            for repeat in 1..=sim.repeats {
                for (_, l, planned) in &c.poses {
                    let Some(l) = l else { continue };
                    let draw = |rng: &mut ChaCha8Rng| seat.map_or(0.0, |n| n.sample(rng));
                    let noise = Vector3::new(draw(rng), draw(rng), draw(rng));
                    let landmark = &artefact.landmarks[*l];
                    let Ok(near) = <[f64; crate::model::SUTA_JOINTS]>::try_from(&planned[..]) else {
                        continue;
                    };
                    let Some(enc) =
                        crate::simulate::touch_encoders_from(truth, placement, landmark, noise, &near, rng)
                    else {
                        continue;
                    };
                    measurements.push(crate::data::Measurement {
                        landmark: landmark.id.clone(),
                        repeat,
                        joints_deg: enc
                            .iter()
                            .map(|v| (v + enc_noise.map_or(0.0, |n| n.sample(rng))).rem_euclid(360.0))
                            .collect(),
                        std_deg: None,
                        samples: None,
                        rejected: None,
                        at_unix_s: None,
                    });
                }
            }
            Some(Session {
                format: SESSION_FORMAT.into(),
                placement: format!("{name_prefix}{}", k + 1),
                purpose: "calibration".into(),
                measurements,
                arm: None,
            })
        })
        .collect()
}

/// Sum of squared touch residuals after a rigid fit per (placement, repeat), in σ².
fn rigid_ssr(model: &ArmModel, data: &Observations, sigma2: f64) -> f64 {
    blocks(data).iter().filter_map(|b| rigid_residuals(model, data, b)).map(|r| r.norm_squared()).sum::<f64>()
        / sigma2
}

/// How clearly `data` tell rival `a` (the true one) from `b`: each is added to `calibrated`
/// and refitted on `data` (warm start, no restarts); the result is (SSR_b − SSR_a)/σ² of the
/// touch residuals after a rigid fit per block. Above [`super::SEPARABLE_SIGMA2`] the data prefer `a`
/// clearly.
pub fn separation(
    calibrated: &ArmModel,
    data: &Observations,
    a: Effect,
    b: Effect,
    touch_std_mm: f64,
) -> Result<f64, CalibError> {
    let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
    let ssr = |e: Effect| -> Result<f64, CalibError> {
        let mut model = calibrated.clone();
        e.add_to(&mut model);
        let fit = calibrate(&model, data, &options)?;
        Ok(rigid_ssr(&fit.model, data, touch_std_mm.powi(2)))
    };
    Ok(ssr(b)? - ssr(a)?)
}

/// Outcome of one seed of the plan check.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrialOutcome {
    /// Figure on the data so far.
    pub before: f64,
    /// Figure with the planned placements measured.
    pub planned: f64,
    /// Figure with as many random candidate placements measured, one value per random draw.
    pub random: Vec<f64>,
}

/// The simulated old data of a trial: the first `placements` calibration sessions of `sim`.
fn old_sessions(sim: &SimulatedData, placements: usize) -> Vec<Session> {
    sim.calibration.iter().take(placements).cloned().collect()
}

/// `count` random candidates (seeded), for the comparison with the plan.
fn random_pick<'a>(candidates: &'a [Candidate], count: usize, rng: &mut ChaCha8Rng) -> Vec<&'a Candidate> {
    let mut picked: Vec<usize> = Vec::new();
    while picked.len() < count.min(candidates.len()) {
        let k = rng.random_range(0..candidates.len());
        if !picked.contains(&k) {
            picked.push(k);
        }
    }
    picked.into_iter().map(|k| &candidates[k]).collect()
}

/// Settings of a plan check on simulated data.
#[derive(Clone, Debug)]
pub struct TrialOptions {
    /// Seed of the simulated arm, its data and the random placements.
    pub seed: u64,
    /// Calibration placements of the data so far (of the simulator's five).
    pub placements: usize,
    /// Placements planned (and drawn at random).
    pub count: usize,
    /// Random designs compared with the plan.
    pub random_draws: usize,
}

/// The candidates a plan chose, by their placement.
fn chosen<'a>(candidates: &'a [Candidate], suggested: &[SuggestedPlacement]) -> Vec<&'a Candidate> {
    suggested
        .iter()
        .filter_map(|p| {
            candidates.iter().find(|c| match &c.place {
                Place::Placement(placement) => {
                    Some(placement.origin_mm) == p.origin_mm && Some(placement.yaw_deg) == p.yaw_deg
                }
                Place::Session(name) => p.session.as_ref() == Some(name),
            })
        })
        .collect()
}

/// A simulated arm, its sessions and the data so far, for a plan check.
struct Trial {
    sim: SimulatedData,
    sim_options: SimulationOptions,
    old: Vec<Session>,
    cal: Observations,
}

impl Trial {
    /// Simulate the arm of `trial.seed` with `hidden`; the data so far are its first
    /// `trial.placements` calibration placements.
    fn new(nominal: &ArmModel, hidden: &[(ParamId, f64)], trial: &TrialOptions) -> Trial {
        let sim_options =
            SimulationOptions { seed: trial.seed, hidden: hidden.to_vec(), ..SimulationOptions::default() };
        let sim = crate::simulate::simulate(nominal, &sim_options);
        let old = old_sessions(&sim, trial.placements);
        let cal = Observations::from_sessions(&old, &sim.artefact);
        Trial { sim, sim_options, old, cal }
    }

    /// `figure` of the data so far plus the `suggested` placements measured on the true arm, and
    /// of the data so far plus `trial.random_draws` random designs of as many placements.
    fn planned_and_random(
        &self,
        candidates: &[Candidate],
        suggested: &[SuggestedPlacement],
        trial: &TrialOptions,
        figure: impl Fn(&Observations) -> Result<f64, CalibError>,
    ) -> Result<(f64, Vec<f64>), CalibError> {
        let mut rng = ChaCha8Rng::seed_from_u64(trial.seed ^ 0x9e37_79b9);
        let score = |design: &[&Candidate], rng: &mut ChaCha8Rng| {
            let mut sessions = self.old.clone();
            sessions.extend(measure(
                &self.sim.truth,
                &self.sim.artefact,
                design,
                &self.sim_options,
                "N",
                rng,
            ));
            figure(&Observations::from_sessions(&sessions, &self.sim.artefact))
        };
        let with_plan = score(&chosen(candidates, suggested), &mut rng)?;
        let mut random = Vec::new();
        for _ in 0..trial.random_draws {
            let design = random_pick(candidates, trial.count, &mut rng);
            random.push(score(&design, &mut rng)?);
        }
        Ok((with_plan, random))
    }
}

/// Outcome of one seed of the rivals check.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RivalOutcome {
    /// What the diagnosis names on the data so far.
    pub named_before: Vec<String>,
    /// What it names with the planned placements measured.
    pub named_planned: Vec<String>,
    /// What it names with each random design measured.
    pub named_random: Vec<Vec<String>>,
    /// [`separation`] of the true rival from the other on every measured touch (σ²).
    pub separation: TrialOutcome,
}

impl RivalOutcome {
    /// Whether `named` is the true rival `a` alone.
    pub fn alone(named: &[String], a: Effect) -> bool {
        named.len() == 1 && named[0] == a.to_string()
    }
}

/// Rivals check on the simulator's thesis-sized data (five calibration and five validation
/// placements, 3 repeats) of a true arm with `hidden` (effect `a`'s parameters): calibrate,
/// diagnose, plan `trial.count` placements to tell `a` from `b`, measure them on the true arm
/// (the simulator's independent forward path, 3 repeats), add them to the calibration data,
/// recalibrate and diagnose again on the same validation placements; the same with
/// `trial.random_draws` designs of as many random reachable placements. `trial.placements` is
/// not used: all ten simulated placements are the data so far.
pub fn rival_trial(
    nominal: &ArmModel,
    hidden: &[(ParamId, f64)],
    a: Effect,
    b: Effect,
    trial: &TrialOptions,
) -> Result<RivalOutcome, DiagnoseError> {
    let sim_options =
        SimulationOptions { seed: trial.seed, hidden: hidden.to_vec(), ..SimulationOptions::default() };
    let sim = crate::simulate::simulate(nominal, &sim_options);
    let artefact = &sim.artefact;
    let cal = Observations::from_sessions(&sim.calibration, artefact);
    let val = Observations::from_sessions(&sim.validation, artefact);
    let calibration = SolveOptions { restarts: Some(2), seed: trial.seed, ..SolveOptions::default() };
    let fit = calibrate(nominal, &cal, &calibration)?;
    let sigma = sim_options.seating_noise_mm;
    let options = PlanOptions { count: trial.count, seed: trial.seed, touch_std_mm: sigma };
    let candidates = candidate_placements(&fit.model, artefact, trial.seed);
    let planned = plan_rivals(&fit.model, &cal, &val, a, b, &candidates, &options);
    // The user's next step: measure the placements, add them to the calibration data,
    // recalibrate (warm) and diagnose again on the same validation placements.
    let setup = Setup::new(calibration.clone());
    let outcome = |design: &[&Candidate], rng: &mut ChaCha8Rng| {
        let new = measure(&sim.truth, artefact, design, &sim_options, "N", rng);
        let everything: Vec<Session> =
            sim.calibration.iter().chain(&sim.validation).chain(&new).cloned().collect();
        let separated =
            separation(&fit.model, &Observations::from_sessions(&everything, artefact), a, b, sigma)?;
        let sessions: Vec<Session> = sim.calibration.iter().chain(&new).cloned().collect();
        let more = Observations::from_sessions(&sessions, artefact);
        let refit = calibrate(&fit.model, &more, &SolveOptions { restarts: Some(0), ..calibration.clone() })?;
        let named = diagnose(&setup, &refit.model, &more, &val)?.named;
        Ok::<_, DiagnoseError>((named, separated))
    };
    let before = diagnose(&setup, &fit.model, &cal, &val)?.named;
    let so_far: Vec<Session> = sim.calibration.iter().chain(&sim.validation).cloned().collect();
    let separated_before =
        separation(&fit.model, &Observations::from_sessions(&so_far, artefact), a, b, sigma)?;
    let mut rng = ChaCha8Rng::seed_from_u64(trial.seed ^ 0x9e37_79b9);
    let (named_planned, separated_planned) = outcome(&chosen(&candidates, &planned.placements), &mut rng)?;
    let (mut named_random, mut separated_random) = (Vec::new(), Vec::new());
    for _ in 0..trial.random_draws {
        let design = random_pick(&candidates, trial.count, &mut rng);
        let (named, separated) = outcome(&design, &mut rng)?;
        named_random.push(named);
        separated_random.push(separated);
    }
    Ok(RivalOutcome {
        named_before: before,
        named_planned,
        named_random,
        separation: TrialOutcome {
            before: separated_before,
            planned: separated_planned,
            random: separated_random,
        },
    })
}

/// Weak-parameter check: plan `trial.count` placements (D-optimal) on `trial.placements`
/// calibration placements of a simulated arm, measure them, recalibrate, and compare the std of
/// the parameter the plan names weakest with that after as many random placements. Returns the
/// parameter and its stds (as the calibration reports them).
pub fn weak_trial(nominal: &ArmModel, trial: &TrialOptions) -> Result<(String, TrialOutcome), CalibError> {
    let t = Trial::new(nominal, &[], trial);
    let (artefact, cal) = (&t.sim.artefact, &t.cal);
    let calibration = SolveOptions { restarts: Some(0), seed: trial.seed, ..SolveOptions::default() };
    let fit = calibrate(nominal, cal, &calibration)?;
    let options =
        PlanOptions { count: trial.count, seed: trial.seed, touch_std_mm: t.sim_options.seating_noise_mm };
    let candidates = candidate_placements(&fit.model, artefact, trial.seed);
    let planned = plan_weak(&fit.model, cal, &candidates, &options);
    let worst = planned.stds.first().map(|s| s.0.clone()).unwrap_or_default();
    let std_of =
        |fit: &Fit| fit.estimates.iter().find(|e| e.param == worst).and_then(|e| e.std).unwrap_or(f64::NAN);
    let before = std_of(&fit);
    let (planned_std, random) = t.planned_and_random(&candidates, &planned.placements, trial, |data| {
        Ok(std_of(&calibrate(&fit.model, data, &calibration)?))
    })?;
    Ok((worst, TrialOutcome { before, planned: planned_std, random }))
}
