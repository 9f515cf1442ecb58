//! Arm data commands: simulate, study; the parsers of effects, drifts and hidden changes.

use anyhow::{bail, Result};
use clap::Args;
use kincal::calib::run::RunError;
use kincal::calib::setup::{Setup, SolveOptions, MAX_RESTARTS};
use kincal::calib::study::{check_study_size, study, study_problems, StudyOptions};
use kincal::model::{ArmModel, ParamId};
use kincal::simulate::{simulate, SimulationOptions};
use kincal::store;
use std::path::{Path, PathBuf};

use crate::args::{count, parse_hidden, real};
use crate::calibrate::{InputArgs, MAX_SUBSETS};

#[derive(Args)]
pub struct SimulateArgs {
    /// Nominal arm model; the truth is this model with its free parameters perturbed. Default:
    /// the SUTA model built into kincal (the file examples/suta/model.toml where it exists).
    #[arg(long, default_value = kincal::model::file::SUTA_MODEL_PATH, hide_default_value = true)]
    model: PathBuf,
    /// Output folder: artefact.json, truth.toml, cal/, val/.
    #[arg(long)]
    out: PathBuf,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Size of the angle perturbations, degrees.
    #[arg(long, default_value_t = 2.0, allow_negative_numbers = true, value_parser = real(0.0, 20.0, "degrees"))]
    perturb_deg: f64,
    /// Size of the length perturbations, mm.
    #[arg(long, default_value_t = 2.0, allow_negative_numbers = true, value_parser = real(0.0, 50.0, "mm"))]
    perturb_mm: f64,
    /// Seating noise per axis, mm (standard deviation).
    #[arg(long, default_value_t = 0.1, allow_negative_numbers = true, value_parser = real(0.0, 10.0, "mm"))]
    seating_noise_mm: f64,
    /// Noise of each averaged encoder angle, degrees (standard deviation).
    #[arg(long, default_value_t = 0.003, allow_negative_numbers = true, value_parser = real(0.0, 1.0, "degrees"))]
    encoder_noise_deg: f64,
    /// Repeats of each landmark per placement.
    #[arg(long, default_value_t = 3, allow_negative_numbers = true, value_parser = count(1, 20))]
    repeats: usize,
    /// Hidden effect: PARAM=DELTA added to the true arm, e.g. eccentricity_sin:5=0.3 (repeatable).
    #[arg(long, allow_negative_numbers = true, value_parser = parse_hidden)]
    hidden: Vec<(ParamId, f64)>,
}

#[derive(Args)]
pub struct StudyArgs {
    #[command(flatten)]
    inputs: InputArgs,
    /// Output folder: study.json and report.html.
    #[arg(long)]
    out: PathBuf,
    /// Random subsets per number of calibration groups (placements or sessions).
    #[arg(long, default_value_t = 100, allow_negative_numbers = true, value_parser = count(1, MAX_SUBSETS))]
    subsets: usize,
    /// Seed of the subset draws and restarts.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Random restarts per calibration (besides the nominal start).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = count(0, MAX_RESTARTS))]
    restarts: usize,
    /// Print study.json to stdout.
    #[arg(long)]
    json: bool,
}

pub fn simulate_to(model: &Path, out: &Path, options: &SimulationOptions) -> Result<()> {
    let nominal = ArmModel::load(model)?;
    if nominal.joints.len() != kincal::model::SUTA_JOINTS {
        anyhow::bail!(
            "{}: the artefact simulator makes SUTA sessions ({} encoders); this model has {} joints",
            model.display(),
            kincal::model::SUTA_JOINTS,
            nominal.joints.len()
        );
    }
    if let Some((id, _)) =
        options.hidden.iter().find(|(id, _)| id.joint().is_some_and(|j| j >= nominal.joints.len()))
    {
        bail!("--hidden {id}: the model has {} joints, there is no such joint", nominal.joints.len());
    }
    let sim = simulate(&nominal, options);
    store::write_simulation(&sim, out)?;
    let count = |s: &[kincal::data::Session]| s.iter().map(|s| s.measurements.len()).sum::<usize>();
    println!(
        "simulated {} calibration and {} validation touches ({} unreachable, skipped) into {}",
        count(&sim.calibration),
        count(&sim.validation),
        sim.skipped,
        out.display()
    );
    Ok(())
}

pub fn cmd_simulate(a: &SimulateArgs) -> Result<()> {
    let options = SimulationOptions {
        seed: a.seed,
        perturb_deg: a.perturb_deg,
        perturb_mm: a.perturb_mm,
        seating_noise_mm: a.seating_noise_mm,
        encoder_noise_deg: a.encoder_noise_deg,
        repeats: a.repeats as u32,
        hidden: a.hidden.clone(),
    };
    simulate_to(&a.model, &a.out, &options)
}

pub fn cmd_study(a: &StudyArgs) -> Result<()> {
    let inputs = a.inputs.inputs();
    let nominal = ArmModel::load(&inputs.model)?;
    let (cal, val) = inputs.read_folders()?;
    if val.pair_count() == 0 && val.point_count() == 0 {
        return Err(RunError::NoValidationPairs { path: a.inputs.validate.clone() }.into());
    }
    check_study_size(&cal, a.subsets)?;
    let calibration = SolveOptions { restarts: Some(a.restarts), seed: a.seed, ..SolveOptions::default() };
    let options =
        StudyOptions { subsets: a.subsets, seed: a.seed, setup: Setup::new(calibration), progress: !a.json };
    let started = std::time::Instant::now();
    let rows = study(&nominal, &cal, &val, &options);
    let elapsed = started.elapsed().as_secs_f64();
    let problems = study_problems(&rows);
    if !problems.is_empty() {
        bail!("the study has no result, nothing was written:\n  - {}", problems.join("\n  - "));
    }
    let i = &inputs;
    let mut paths = vec![&*i.model, &*i.calibration, &*i.validation];
    paths.extend(i.artefact.as_deref());
    store::write_study(&rows, &a.out, &paths)?;
    if a.json {
        println!("{}", store::study_json(&rows));
        return Ok(());
    }
    let total: usize = rows.iter().map(|r| r.calibrations + r.failed).sum();
    println!("{total} calibrations in {elapsed:.2} s on {} threads", rayon::current_num_threads());
    for line in kincal::report::study::verdict_lines(&rows) {
        println!("  {line}");
    }
    println!("    groups  distinct subsets  calibrations  mean mm   std mm    min mm    max mm");
    for r in &rows {
        let drawn = r.calibrations + r.failed + r.implausible;
        let subsets = format!("{drawn} of {}", possible(r.possible_subsets));
        if r.calibrations == 0 {
            println!(
                "{:>10}  {subsets:>16}  {:>12}  no calibration succeeded ({} failed)",
                r.groups, 0, r.failed
            );
            continue;
        }
        println!(
            "{:>10}  {subsets:>16}  {:>12}  {:7.3}  {:7.3}  {:7.3}  {:7.3}",
            r.groups, r.calibrations, r.mean_mm, r.std_mm, r.min_mm, r.max_mm
        );
    }
    println!("report: {}", a.out.join("report.html").display());
    Ok(())
}

/// A subset count for people: C(N, k) saturates at `usize::MAX`.
fn possible(count: usize) -> String {
    if count == usize::MAX {
        "more than 10^19".into()
    } else {
        count.to_string()
    }
}
