//! The library's front door: what `kincal` does, as calls the command line and tests share —
//! [`load`] a RUN, [`calibrate`] (and [`write()`]), [`validate`] on other held-out data,
//! [`diagnose`], [`auto`], [`plan`], [`compare`]. Each takes any kind of data (artefact
//! placements, tracker sessions, both) or refuses naming the command and the kind.

use crate::calib::diagnose::auto::{auto_loop, AutoLoop};
use crate::calib::diagnose::compare::{compare as compare_runs, Comparison, Side};
use crate::calib::diagnose::{diagnose as diagnose_run, DiagnoseError, Diagnosis, Measure, RivalVerdict};
use crate::calib::error::CalibError;
use crate::calib::floor::{noise_floor, point_floor};
use crate::calib::plan::{plan as plan_placements, Plan, PlanError, PlanOptions};
use crate::calib::run::check_same_data;
use crate::calib::setup::Setup;
use crate::data::{Artefact, DataKind, Observations};
use crate::files::FileError;
use crate::report::compare::ComparedRun;
use crate::store::OutputError;
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
    /// The diagnosis could not run.
    #[error(transparent)]
    Diagnose(#[from] DiagnoseError),
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
    /// The plan needs the measurement noise, and the RUN's data give no floor.
    #[error(
        "{0}: no repeated touches or poses and no stated σ, so the noise is unknown; give --touch-std-mm"
    )]
    UnknownTouchNoise(std::path::PathBuf),
    /// The two runs of a comparison hold different held-out data.
    #[error("{0} and {1}: compare needs two runs validated on the same held-out data")]
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
    let run = run_on(nominal, cal, val, &inputs, &options, 0, !s.outliers_skipped)?;
    let same = run.calibration.model.free.iter().zip(&folder.model.free).all(|(a, b)| a.id == b.id)
        && run.calibration.model.free.len() == folder.model.free.len()
        && run
            .calibration
            .estimates
            .iter()
            .zip(&s.calibration.estimates)
            .all(|(a, b)| (a.value - b.value).abs() <= 1e-9 * a.value.abs().max(1.0));
    if !same {
        return Err(RunError::DataChanged {
            path: s.inputs.calibration.clone(),
            what: "calibrated again, the model differs from the RUN's".into(),
        }
        .into());
    }
    Ok(run)
}

/// A RUN's setup and data (its exclusions applied), checked to be the data it was made from: the
/// same groups and counts, and for held-out sessions the same calibration RMS when the setup is
/// calibrated again (warm from the RUN's model).
pub fn run_data(folder: &RunFolder) -> Result<(Setup, Observations, Observations), ApiError> {
    if folder.summary.kind == DataKind::Mixed {
        return Err(ApiError::NotForKind {
            command: "diagnose",
            kind: "mixed",
            why: "the held-out test compares units of one kind: validate on artefact placements or on instrument sessions"
                .into(),
        });
    }
    let s = &folder.summary;
    let (cal, val) = folder.data()?;
    let groups: Vec<String> = cal.groups.iter().map(|g| g.name.clone()).collect();
    let setup = s.inputs.setup(&s.options.solve_options(&s.inputs, &groups));
    let refitted = match Measure::of(&val) {
        Some(Measure::Points) => Some(setup.calibrate(&folder.model, &cal)?.rms_mm),
        _ => None,
    };
    check_same_data(s, &cal, &val, refitted)?;
    Ok((setup, cal, val))
}

/// Where the calibrated model of `folder` fails and what is missing (an effect or a data error).
pub fn diagnose(folder: &RunFolder) -> Result<Diagnosis, ApiError> {
    let (setup, cal, val) = run_data(folder)?;
    Ok(diagnose_run(&setup, &folder.model, &cal, &val)?)
}

/// Apply what the diagnosis names, refit and repeat, at most `max_steps` times, until the floor.
pub fn auto(folder: &RunFolder, max_steps: usize) -> Result<AutoLoop, ApiError> {
    let (setup, cal, val) = run_data(folder)?;
    Ok(auto_loop(&setup, &folder.model, &cal, &val, max_steps)?)
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

/// What to measure next: artefact placements (for an artefact run) or sessions of arm poses
/// (for an instrument run) that tell rivals apart and pin down weak parameters.
pub fn plan(folder: &RunFolder, request: &PlanRequest) -> Result<Planned, ApiError> {
    let (setup, cal, val) = run_data(folder)?;
    let artefact = match (Measure::of(&val), folder.summary.inputs.artefact.as_deref()) {
        (Some(Measure::Distances), Some(path)) => Some(Artefact::load(path)?),
        _ => None,
    };
    let from_diagnosis = match request.rivals {
        Some(_) => None,
        None => {
            let d = diagnose_run(&setup, &folder.model, &cal, &val)?;
            Some(
                d.rivals
                    .iter()
                    .find(|r| r.verdict == RivalVerdict::CannotTell)
                    .map(|r| (r.a.clone(), r.b.clone())),
            )
        }
    };
    let rivals = request
        .rivals
        .or(from_diagnosis.as_ref().and_then(|p| p.as_ref()).map(|(a, b)| (a.as_str(), b.as_str())));
    // The noise per axis: a touch's scatter from the repeats, or a held-out point's floor (its
    // 3-D RMS) over √3.
    let floor = match artefact {
        Some(_) => noise_floor(&folder.model, &cal, &val, folder.model.free.len()).map(|f| f.touch_std_mm),
        None => point_floor(&val, setup.stated_sigma_mm).rms_mm.map(|f| f / 3f64.sqrt()),
    };
    let Some(touch_std_mm) = request.touch_std_mm.or(floor) else {
        return Err(ApiError::UnknownTouchNoise(folder.dir.clone()));
    };
    let options = PlanOptions { count: request.count, seed: request.seed, touch_std_mm };
    let plan = plan_placements(&folder.model, artefact.as_ref(), &cal, &val, rivals, &options)?;
    Ok(Planned { plan, from_diagnosis })
}

/// Two runs compared on the held-out data both validated on, and the runs as read.
pub struct Compared {
    /// The held-out test of the second run against the first.
    pub comparison: Comparison,
    /// Each run's summary and stored residuals, for the side-by-side page.
    pub runs: [ComparedRun; 2],
}

/// The held-out groups `summary` validated on.
fn held_out_groups(summary: &Summary) -> Vec<String> {
    let sessions = summary.held_out_sessions().iter().map(|f| f.calibrated.name.clone());
    let placements = summary
        .validation
        .distances
        .iter()
        .flat_map(|d| d.detail.per_placement.iter().map(|g| g.name.clone()));
    sessions.chain(placements).collect()
}

/// One side of a comparison: the run's model, floated tools and floor verdict.
fn side(folder: &RunFolder) -> Side<'_> {
    let s = &folder.summary;
    let (floor_mm, floor_source, at_floor) = match &s.floor.distance_gap {
        Some(g) => (Some(g.expected_mm), "expected from repeatability".to_string(), g.at_floor),
        None => {
            let f = s.point_floor();
            let at_floor =
                f.rms_mm.is_some_and(|f| s.held_out_rms_mm() <= crate::calib::floor::EXPLAINS_WITHIN * f);
            (f.rms_mm, f.source, at_floor)
        }
    };
    Side { model: &folder.model, float_tool: &s.inputs.float_tool, floor_mm, floor_source, at_floor }
}

/// Compare the run `before` with the run `after` on the held-out data both validated on (the
/// data of `before`, checked to be those it was made from).
pub fn compare(before: &Path, after: &Path) -> Result<Compared, ApiError> {
    let (a, b) = (load(before)?, load(after)?);
    let (cal, val) = a.data()?;
    check_same_data(&a.summary, &cal, &val, None)?;
    let differ = || ApiError::KindsDiffer(before.display().to_string(), after.display().to_string());
    let shared = held_out_groups(&b.summary);
    let keep: Vec<usize> = (0..val.groups.len()).filter(|&g| shared.contains(&val.groups[g].name)).collect();
    let comparison = compare_runs(&side(&a), &side(&b), &val.subset(&keep)).ok_or_else(differ)?;
    let run = |f: &RunFolder, dir: &Path| -> Result<ComparedRun, ApiError> {
        Ok(ComparedRun {
            name: dir.display().to_string(),
            summary: f.summary.clone(),
            residuals: f.residuals()?,
        })
    };
    Ok(Compared { runs: [run(&a, before)?, run(&b, after)?], comparison })
}
