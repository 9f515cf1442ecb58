//! The library's front door: what `kincal` does, as calls the command line and tests share —
//! [`load`] a RUN, [`calibrate`] (and [`write()`]), [`validate`] on other held-out data,
//! [`diagnose`], [`auto`], [`plan`], [`compare`]. Each takes any kind of data (artefact
//! placements, tracker sessions, both) or refuses naming the command and the kind.

use crate::calib::auto::{auto_loop, AutoLoop};
use crate::calib::diagnose::{diagnose as diagnose_distances, RivalVerdict};
use crate::calib::fit::CalibError;
use crate::calib::floor::noise_floor;
use crate::calib::plan::{plan as plan_placements, Plan, PlanError, PlanOptions};
use crate::calib::tracker_diagnose::{
    auto_tracker, check_run_data, compare_tracker, diagnose_tracker, fit_setup, TrackerAuto,
    TrackerComparison, TrackerDiagnoseError, TrackerDiagnosis, TrackerSetup,
};
use crate::data::{Artefact, DataKind, Observations};
use crate::files::FileError;
use crate::report::compare::Comparison as DistanceComparison;
use crate::store::{run_folder::compared_run, OutputError};
use std::path::Path;

pub use crate::calib::run::{run_on, Run, RunError};
pub use crate::calib::setup::SolveOptions;
pub use crate::calib::summary::{RunInputs, Summary};
pub use crate::store::RunFolder;

/// Why a call failed.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// Reading the inputs, calibrating or validating failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// A file kincal wrote could not be read back.
    #[error(transparent)]
    File(#[from] FileError),
    /// An output could not be written.
    #[error(transparent)]
    Output(#[from] OutputError),
    /// The diagnosis of tracker sessions could not run.
    #[error(transparent)]
    Diagnose(#[from] TrackerDiagnoseError),
    /// A calibration inside the loop failed.
    #[error(transparent)]
    Calibration(#[from] CalibError),
    /// The plan could not be made.
    #[error(transparent)]
    Plan(#[from] PlanError),
    /// The command has no meaning on this kind of data (yet).
    #[error("{command}: not for {kind} data: {why}")]
    NotForKind {
        /// The command.
        command: &'static str,
        /// The kind of data of the RUN.
        kind: &'static str,
        /// What it needs.
        why: String,
    },
    /// The plan needs the touch noise, and the RUN's data hold no repeated touches.
    #[error("{0}: no repeated touches, so the touch noise is unknown; give --touch-std-mm")]
    UnknownTouchNoise(std::path::PathBuf),
    /// The two runs of a comparison hold different kinds of held-out data.
    #[error("{0} and {1}: compare needs two runs validated on the same kind of data (artefact or tracker)")]
    KindsDiffer(String, String),
}

/// The calibration certificate of the RUN in `dir`, issued by `operator` at `now` (Unix
/// seconds); [`crate::store::certificate::write_certificate`] writes it.
pub fn certificate(
    dir: &Path,
    operator: Option<&str>,
    now: u64,
) -> Result<crate::report::certificate::Certificate, crate::store::certificate::CertificateError> {
    crate::store::certificate::gather(dir, operator, now)
}

/// Read a RUN folder (any version kincal wrote).
pub fn load(dir: &Path) -> Result<RunFolder, ApiError> {
    Ok(RunFolder::load(dir)?)
}

/// Read the inputs, calibrate, validate on the held-out folder and judge ([`crate::calib::run::run`]):
/// `study_subsets` random subsets per group count for the dataset-size study (0: none), the
/// outlier metrics with `outliers`.
pub fn calibrate(
    inputs: &RunInputs,
    options: &SolveOptions,
    study_subsets: usize,
    outliers: bool,
) -> Result<Run, ApiError> {
    Ok(crate::calib::run::run(inputs, options, study_subsets, outliers)?)
}

/// Write RUN/ (models, summary.json, residuals.json, report.html) as one folder.
pub fn write(run: &Run, dir: &Path) -> Result<(), ApiError> {
    Ok(crate::store::write_run(run, dir)?)
}

/// The calibration of `folder` validated on another held-out folder: its inputs calibrated again
/// (deterministic: the model is the RUN's, checked) and judged on `held_out`.
pub fn validate(folder: &RunFolder, held_out: &Path) -> Result<Run, ApiError> {
    let s = &folder.summary;
    let inputs = RunInputs { validation: held_out.to_owned(), ..s.inputs.clone() };
    let nominal = folder.nominal()?;
    let (cal, val) = inputs.read_folders()?;
    let groups: Vec<String> = cal.groups.iter().map(|g| g.name.clone()).collect();
    let options = s.options.solve_options(&inputs, &groups);
    let run = run_on(nominal, &cal, &val, &inputs, &options, 0, !s.outliers_skipped)?;
    let same = run.calibration.model.free.iter().zip(&folder.model.free).all(|(a, b)| a.id == b.id)
        && run.calibration.model.free.len() == folder.model.free.len()
        && run
            .calibration
            .estimates
            .iter()
            .zip(&s.calibration.estimates)
            .all(|(a, b)| (a.value - b.value).abs() <= 1e-9 * a.value.abs().max(1.0));
    if !same {
        return Err(TrackerDiagnoseError::DataChanged {
            path: s.inputs.calibration.clone(),
            what: "calibrated again, the model differs from the RUN's".into(),
        }
        .into());
    }
    Ok(run)
}

/// The diagnosis of a RUN, of its kind of data.
pub enum Diagnosis {
    /// Held-out distances of artefact placements.
    Distances(crate::calib::diagnose::Diagnosis),
    /// Held-out tracker sessions.
    Sessions(TrackerDiagnosis),
}

/// The data of a tracker RUN as read (exclusions not applied: the setup carries them), and its
/// setup, checked to be the data the RUN was made from.
fn tracker_data(folder: &RunFolder) -> Result<(TrackerSetup, Observations, Observations), ApiError> {
    let (cal, val) = folder.summary.inputs.read_folders()?;
    let setup = TrackerSetup::of(&folder.summary.inputs, folder.nominal()?);
    let fitted = fit_setup(&setup, &cal, &val, None)?;
    check_run_data(&folder.summary, &cal, &val, fitted.fit.rms_mm)?;
    Ok((setup, cal, val))
}

/// Refuse mixed data until the diagnosis scores both kinds of held-out data together.
fn kind_of(folder: &RunFolder, command: &'static str) -> Result<DataKind, ApiError> {
    match folder.summary.kind {
        DataKind::Mixed => Err(ApiError::NotForKind {
            command,
            kind: "mixed",
            why: "the diagnosis scores artefact distances or tracker sessions, one kind at a time".into(),
        }),
        kind => Ok(kind),
    }
}

/// Where the calibrated model of `folder` fails and what is missing (an effect or a data error).
pub fn diagnose(folder: &RunFolder) -> Result<Diagnosis, ApiError> {
    if kind_of(folder, "diagnose")? == DataKind::Tracker {
        let (setup, cal, val) = tracker_data(folder)?;
        return Ok(Diagnosis::Sessions(diagnose_tracker(&setup, &cal, &val)?));
    }
    let (cal, val) = folder.data()?;
    let groups: Vec<String> = cal.groups.iter().map(|g| g.name.clone()).collect();
    let options = folder.summary.options.solve_options(&folder.summary.inputs, &groups);
    Ok(Diagnosis::Distances(diagnose_distances(&folder.model, &cal, &val, &options)))
}

/// The loop of a RUN, of its kind of data.
pub enum Auto {
    /// On held-out distances.
    Distances(Box<AutoLoop>),
    /// On held-out tracker sessions, with the setup of its last step.
    Sessions(Box<(TrackerAuto, TrackerSetup)>),
}

/// Add what the diagnosis names, refit and repeat, at most `max_steps` times, until the floor.
pub fn auto(folder: &RunFolder, max_steps: usize) -> Result<Auto, ApiError> {
    if kind_of(folder, "diagnose --auto")? == DataKind::Tracker {
        let (setup, cal, val) = tracker_data(folder)?;
        let (result, last) = auto_tracker(&setup, &cal, &val, max_steps)?;
        return Ok(Auto::Sessions(Box::new((result, last))));
    }
    let (cal, val) = folder.data()?;
    let groups: Vec<String> = cal.groups.iter().map(|g| g.name.clone()).collect();
    let options = folder.summary.options.solve_options(&folder.summary.inputs, &groups);
    Ok(Auto::Distances(Box::new(auto_loop(&folder.model, &cal, &val, &options, max_steps)?)))
}

/// What `plan` was asked, beyond the RUN.
pub struct PlanRequest<'a> {
    /// Two rival effects to tell apart (`None`: the first pair the diagnosis cannot tell apart).
    pub rivals: Option<(&'a str, &'a str)>,
    /// Placements to suggest, each.
    pub count: usize,
    /// Seed of the candidate touches' arm configurations.
    pub seed: u64,
    /// Touch noise per axis, mm (`None`: the RUN's repeatability floor).
    pub touch_std_mm: Option<f64>,
}

/// A plan and the rival pair it planned for, when the diagnosis chose it.
pub struct Planned {
    /// The plan.
    pub plan: Plan,
    /// The pair the diagnosis could not tell apart, when no rivals were given (`None` inside:
    /// it names none).
    pub from_diagnosis: Option<Option<(String, String)>>,
}

/// What to measure next: placements that tell rivals apart and pin down weak parameters.
pub fn plan(folder: &RunFolder, request: &PlanRequest) -> Result<Planned, ApiError> {
    let kind = folder.summary.kind;
    let Some(artefact) = folder.summary.inputs.artefact.as_deref().filter(|_| kind == DataKind::Artefact)
    else {
        return Err(ApiError::NotForKind {
            command: "plan",
            kind: kind.word(),
            why: "it suggests artefact placements, and the RUN was calibrated on tracker sessions".into(),
        });
    };
    let artefact = Artefact::load(artefact)?;
    let (cal, val) = folder.data()?;
    let from_diagnosis = request.rivals.is_none().then(|| {
        let groups: Vec<String> = cal.groups.iter().map(|g| g.name.clone()).collect();
        let options = folder.summary.options.solve_options(&folder.summary.inputs, &groups);
        let d = diagnose_distances(&folder.model, &cal, &val, &options);
        d.rivals.iter().find(|r| r.verdict == RivalVerdict::CannotTell).map(|r| (r.a.clone(), r.b.clone()))
    });
    let rivals = request
        .rivals
        .or(from_diagnosis.as_ref().and_then(|p| p.as_ref()).map(|(a, b)| (a.as_str(), b.as_str())));
    let touch_std_mm = match request.touch_std_mm {
        Some(s) => s,
        None => match noise_floor(&folder.model, &cal, &val, folder.model.free.len()) {
            Some(f) => f.touch_std_mm,
            None => return Err(ApiError::UnknownTouchNoise(folder.dir.clone())),
        },
    };
    let options = PlanOptions { count: request.count, seed: request.seed, touch_std_mm };
    let plan = plan_placements(&folder.model, &artefact, &cal, &val, rivals, &options)?;
    Ok(Planned { plan, from_diagnosis })
}

/// Two runs side by side, of their kind of held-out data.
pub enum Comparison {
    /// Held-out distances.
    Distances(Box<DistanceComparison>),
    /// Held-out tracker sessions.
    Sessions(TrackerComparison),
}

/// Compare the run `before` with the run `after` on the held-out data both validated on.
pub fn compare(before: &Path, after: &Path) -> Result<Comparison, ApiError> {
    let (a, b) = (load(before)?, load(after)?);
    let sessions = |f: &RunFolder| f.summary.validation.distances.is_none();
    match (sessions(&a), sessions(&b)) {
        (false, false) => Ok(Comparison::Distances(Box::new(DistanceComparison::new(
            compared_run(before)?,
            compared_run(after)?,
        )))),
        (true, true) => {
            let val = crate::data::tracker::load_dir(&a.summary.inputs.validation)?;
            for f in a.summary.held_out_sessions() {
                match val.find_block(&f.calibrated.name) {
                    Some(k) if val.blocks[k].members.len() == f.calibrated.points => {}
                    _ => {
                        return Err(TrackerDiagnoseError::DataChanged {
                            path: a.summary.inputs.validation.clone(),
                            what: format!(
                                "held-out session {} is not as {} used it",
                                f.calibrated.name,
                                before.display()
                            ),
                        }
                        .into())
                    }
                }
            }
            Ok(Comparison::Sessions(compare_tracker((&a.summary, &a.model), (&b.summary, &b.model), &val)))
        }
        _ => Err(ApiError::KindsDiffer(before.display().to_string(), after.display().to_string())),
    }
}
