//! Arm calibration commands: simulate, calibrate, study, diagnose, compare.

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use kincal::calib::run::{run, RunFolder, RunInputs};
use kincal::calib::setup::{Objective, SolveOptions, HUBER_DELTA_RANGE_MM, LEVER_RANGE_MM, MAX_RESTARTS};
use kincal::calib::study::{check_study_size, study, study_problems, StudyOptions};
use kincal::data::{Artefact, Observations, Purpose};
use kincal::model::effects::Effect;
use kincal::model::{ArmModel, ParamId};
use kincal::output;
use kincal::report::compare::{ComparedRun, Comparison};
use kincal::simulate::{simulate, SimulationOptions};
use std::path::{Path, PathBuf};

use crate::args::{count, real};

/// Most random subsets per placement count in a study.
pub const MAX_SUBSETS: usize = 10_000;

#[derive(Args)]
pub struct SimulateArgs {
    /// Nominal arm model; the truth is this model with its free parameters perturbed.
    #[arg(long, default_value = "examples/suta/model.toml")]
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

/// A spinner with the elapsed time on stderr while a long step runs (hidden when stderr is not
/// a terminal).
fn spinner(what: &str) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        bar.set_style(style);
    }
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

pub fn parse_effect(text: &str) -> Result<Effect, String> {
    Effect::parse(text).ok_or_else(|| format!("unknown effect `{text}`; expected e.g. eccentricity:5, eccentricity2:3, harmonic:3:3 (joint 3, 3 per revolution), compliance:2, twist:4, link_offset:3, axis:2, tcp, scale"))
}

#[derive(Args)]
pub struct DiagnoseArgs {
    /// A RUN folder written by `kincal calibrate`.
    run: PathBuf,
    /// Print diagnosis.json to stdout.
    #[arg(long)]
    json: bool,
    /// Add the best significant effect, refit and repeat until at the floor; each step's model
    /// goes to RUN/auto/step-K.toml, the steps to RUN/auto/auto.json and RUN/auto/report.html.
    #[arg(long)]
    auto: bool,
    /// At most this many effects added by --auto.
    #[arg(long, default_value_t = 8)]
    max_steps: usize,
}

#[derive(Args)]
pub struct CompareArgs {
    /// The run before.
    before: PathBuf,
    /// The run after.
    after: PathBuf,
    /// Where to write the side-by-side HTML.
    #[arg(long, default_value = "compare.html")]
    out: PathBuf,
}

/// `--drift-session SESSION[:KIND]`.
pub fn parse_drift(text: &str) -> Result<kincal::calib::nuisance::drift::DriftSpec, String> {
    text.parse()
}

pub fn parse_hidden(text: &str) -> Result<(ParamId, f64), String> {
    let (name, value) = text.split_once('=').ok_or("expected PARAM=DELTA, e.g. eccentricity_sin:5=0.3")?;
    let id = ParamId::parse(name.trim()).ok_or_else(|| format!("unknown parameter `{name}`"))?;
    let delta: f64 = value.trim().parse().map_err(|_| format!("`{value}` is not a number"))?;
    let limit = kincal::model::file::plausible_limit(id);
    if !(delta.is_finite() && delta.abs() <= limit) {
        return Err(format!("`{value}`: expected a finite change of at most {limit} {}", id.unit()));
    }
    Ok((id, delta))
}

#[derive(Clone, Copy, ValueEnum)]
pub enum ObjectiveArg {
    /// Pairwise distances (thesis eq. 3.1).
    Distance,
    /// Distances plus relative orientation from the asymmetric pillars.
    SixDof,
}

#[derive(Args)]
pub struct SolveArgs {
    /// Seed of the random restarts.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Random restarts inside the bounds (besides the nominal start).
    #[arg(long, default_value_t = 8, allow_negative_numbers = true, value_parser = count(0, MAX_RESTARTS))]
    restarts: usize,
    /// Huber threshold δ, mm.
    #[arg(long, default_value_t = 1.35, allow_negative_numbers = true, value_parser = real(HUBER_DELTA_RANGE_MM.0, HUBER_DELTA_RANGE_MM.1, "mm"))]
    huber_delta_mm: f64,
    /// Residual blocks to minimise.
    #[arg(long, value_enum, default_value_t = ObjectiveArg::Distance)]
    objective: ObjectiveArg,
    /// Millimetres per radian of orientation error (six-dof objective).
    #[arg(long, default_value_t = 100.0, allow_negative_numbers = true, value_parser = real(LEVER_RANGE_MM.0, LEVER_RANGE_MM.1, "mm per radian"))]
    lever_mm: f64,
}

impl SolveArgs {
    fn options(&self) -> SolveOptions {
        let objective = match self.objective {
            ObjectiveArg::Distance => Objective::Distance,
            ObjectiveArg::SixDof => Objective::SixDof { lever_mm: Some(self.lever_mm) },
        };
        SolveOptions {
            huber_delta_mm: Some(self.huber_delta_mm),
            restarts: Some(self.restarts),
            seed: self.seed,
            objective: Some(objective),
            ..SolveOptions::default()
        }
    }
}

#[derive(Args)]
pub struct InputArgs {
    /// Arm model file (kincal-arm/1, .toml or .json).
    #[arg(long)]
    model: PathBuf,
    /// Artefact file (suta-artefact/1); leave it out for tracker sessions (kincal-tracker/1).
    #[arg(long)]
    artefact: Option<PathBuf>,
    /// Folder of calibration sessions (suta-session/1, or kincal-tracker/1 CSV files).
    #[arg(long)]
    data: PathBuf,
    /// Folder of validation sessions.
    #[arg(long)]
    validate: PathBuf,
}

#[derive(Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    inputs: InputArgs,
    /// Output folder RUN: model.toml, summary.json, report.html.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    solve: SolveArgs,
    /// Also run the dataset-size study with this many subsets per placement count (0: no study).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = count(0, MAX_SUBSETS))]
    study_subsets: usize,
    /// Add an effect of the library to the model, e.g. eccentricity:5 (repeatable).
    #[arg(long = "add", value_parser = parse_effect)]
    add: Vec<Effect>,
    /// Leave a landmark's touches out of both datasets, e.g. a wrong certificate (repeatable).
    #[arg(long, value_name = "ID")]
    exclude_landmark: Vec<String>,
    /// Leave a calibration block PLACEMENT/REPEAT out, e.g. C_A/2 when the artefact moved (repeatable).
    #[arg(long, value_name = "PLACEMENT/REPEAT")]
    exclude_block: Vec<String>,
    /// Skip the per-landmark outlier metrics (Cook's distance and the leave-one-out refit of each
    /// landmark): about a third of the process's work on thesis-sized data; summary.json then says
    /// `outliers_skipped` and no landmark is flagged.
    #[arg(long)]
    no_outliers: bool,
    /// Tracker sessions: let the tool float in SESSION (its own tool offset; the probe was
    /// re-mounted there), as the data-error diagnosis suggests (repeatable).
    #[arg(long, value_name = "SESSION")]
    float_tool: Vec<String>,
    /// Tracker sessions: leave the calibration point SESSION:LINE out (a single bad point, as the
    /// data-error diagnosis suggests; repeatable).
    #[arg(long, value_name = "SESSION:LINE")]
    exclude_point: Vec<String>,
    /// Tracker sessions: the instrument's stated σ per axis, mm, for rows without a sigma_mm or
    /// u95_mm column (sets the floor when no pose is repeated).
    #[arg(long, allow_negative_numbers = true, value_parser = real(0.0001, 10.0, "mm"))]
    sigma_mm: Option<f64>,
    /// Tracker sessions with a 6-DoF probe (qw,qx,qy,qz): its stated orientation σ per axis,
    /// degrees, which weighs orientations against points [default: 0.01]
    #[arg(long, allow_negative_numbers = true, value_parser = real(0.00001, 10.0, "deg"))]
    orientation_sigma_deg: Option<f64>,
    /// Tracker sessions: let calibration SESSION drift linearly, as the data-error diagnosis
    /// suggests (repeatable, one kind per session). KIND: offset-time (the default: the base
    /// shifts with time_s), scale-time (the length scale changes with time_s), offset-temp or
    /// scale-temp (the same against temp_C).
    #[arg(long, value_name = "SESSION[:KIND]", value_parser = parse_drift)]
    drift_session: Vec<kincal::calib::nuisance::drift::DriftSpec>,
    /// Tracker sessions: held-out session HELD_OUT was measured from calibration session
    /// CALIBRATION's instrument placement (the instrument did not move): validate it with that
    /// calibrated base too, besides its own refitted base (protocol S; repeatable).
    #[arg(long, value_name = "HELD_OUT=CALIBRATION")]
    same_base: Vec<String>,
    /// Print summary.json to stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct StudyArgs {
    #[command(flatten)]
    inputs: InputArgs,
    /// Output folder: study.json and report.html.
    #[arg(long)]
    out: PathBuf,
    /// Random subsets per number of placements.
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
    output::write_simulation(&sim, out)?;
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

/// The artefact file, required unless the data are tracker sessions.
fn artefact_of(a: &InputArgs) -> Result<PathBuf> {
    a.artefact.clone().ok_or_else(|| {
        anyhow::anyhow!(
            "--artefact is required: {} holds no tracker sessions (*.csv starting with \"# {}\")",
            a.data.display(),
            kincal::data::tracker::TRACKER_FORMAT
        )
    })
}

pub fn inputs(a: &InputArgs) -> Result<RunInputs> {
    Ok(RunInputs::new(a.model.clone(), artefact_of(a)?, a.data.clone(), a.validate.clone()))
}

pub fn calibrate_and_report(
    inputs: &RunInputs,
    out: &Path,
    options: &SolveOptions,
    effects: &[Effect],
    study_subsets: usize,
    outliers: bool,
    json: bool,
) -> Result<()> {
    let started = std::time::Instant::now();
    let spinner = spinner("calibrating");
    let result = run(inputs, options, effects, study_subsets, outliers);
    spinner.finish_and_clear();
    let result = result?;
    output::write_run(&result, out)?;
    let s = &result.summary;
    if json {
        println!("{}", output::run_json(&result));
    }
    if !s.not_trustworthy.is_empty() {
        bail!(
            "the calibration is not trustworthy; no figure is reported as a result:\n  - {}\n\
             {} written for inspection (summary.json lists these reasons under `not_trustworthy`)",
            s.not_trustworthy.join("\n  - "),
            out.display()
        );
    }
    if json {
        return Ok(());
    }
    println!(
        "calibrated {} touches ({} pairs) in {:.2} s",
        s.calibration.touches,
        s.calibration.pairs,
        started.elapsed().as_secs_f64()
    );
    println!("  calibration RMS            {:8.3} mm", s.calibration.rms_mm);
    println!(
        "  validation RMS  nominal    {:8.3} mm   (mean {:+.3}, max {:.3}, {} pairs)",
        s.nominal_validation.rms_mm,
        s.nominal_validation.mean_mm,
        s.nominal_validation.max_mm,
        s.nominal_validation.count
    );
    println!(
        "  validation RMS  calibrated {:8.3} mm   (mean {:+.3}, max {:.3}, {} pairs)",
        s.validation.rms_mm, s.validation.mean_mm, s.validation.max_mm, s.validation.count
    );
    if !s.calibration.fixed_unidentifiable.is_empty() {
        println!(
            "  fixed at nominal, not identifiable from this data: {}",
            s.calibration.fixed_unidentifiable.join(", ")
        );
    }
    for c in &s.identifiability.after.poorly_identified {
        println!("  poorly identified: {}", c.text);
    }
    if s.outliers_skipped {
        println!("  outlier metrics skipped (--no-outliers): no landmark was checked");
    }
    for o in s.outliers.iter().filter(|o| o.flagged) {
        println!("  landmark {} flagged as outlier ({})", o.landmark, o.exceeded.join(", "));
    }
    if let Some(rows) = &s.study {
        let means: Vec<String> = rows.iter().map(|r| format!("{}: {:.3}", r.placements, r.mean_mm)).collect();
        println!("  study, mean validation RMS by placements used: {} mm", means.join(", "));
    }
    println!("  report: {}", out.join("report.html").display());
    Ok(())
}

pub fn cmd_calibrate(a: &CalibrateArgs) -> Result<()> {
    if a.inputs.artefact.is_none() && kincal::data::tracker::is_tracker_folder(&a.inputs.data) {
        let i = &a.inputs;
        let inputs = kincal::calib::tracker_run::TrackerInputs {
            model: i.model.clone(),
            calibration: i.data.clone(),
            validation: i.validate.clone(),
            float_tool: a.float_tool.clone(),
            stated_sigma_mm: a.sigma_mm,
            exclude_points: a.exclude_point.clone(),
            orientation_sigma_deg: a.orientation_sigma_deg,
            drift_sessions: a.drift_session.clone(),
            same_base: a.same_base.clone(),
            add: a.add.iter().map(|e| e.to_string()).collect(),
        };
        return crate::tracker::calibrate_tracker_and_report(&inputs, &a.out, a.json);
    }
    if !a.float_tool.is_empty()
        || !a.exclude_point.is_empty()
        || !a.drift_session.is_empty()
        || a.orientation_sigma_deg.is_some()
    {
        bail!(
            "--float-tool, --exclude-point, --drift-session and --orientation-sigma-deg apply to tracker sessions; {} holds artefact sessions",
            a.inputs.data.display()
        );
    }
    if !a.same_base.is_empty() {
        bail!("--same-base applies to tracker sessions; {} holds artefact sessions", a.inputs.data.display());
    }
    let inputs = RunInputs {
        exclude_landmarks: a.exclude_landmark.clone(),
        exclude_blocks: a.exclude_block.clone(),
        ..inputs(&a.inputs)?
    };
    let outliers = !a.no_outliers;
    calibrate_and_report(&inputs, &a.out, &a.solve.options(), &a.add, a.study_subsets, outliers, a.json)
}

pub fn cmd_study(a: &StudyArgs) -> Result<()> {
    let nominal = ArmModel::load(&a.inputs.model)?;
    let artefact_path = artefact_of(&a.inputs)?;
    let artefact = Artefact::load(&artefact_path)?;
    let cal = Observations::load_artefact_dir(&a.inputs.data, &artefact, Purpose::Calibration)?;
    let val = Observations::load_artefact_dir(&a.inputs.validate, &artefact, Purpose::Validation)?;
    if val.pair_count() == 0 {
        return Err(
            kincal::calib::run::RunError::NoValidationPairs { path: a.inputs.validate.clone() }.into()
        );
    }
    check_study_size(&cal, a.subsets)?;
    let calibration = SolveOptions { restarts: Some(a.restarts), seed: a.seed, ..SolveOptions::default() };
    let options = StudyOptions { subsets: a.subsets, seed: a.seed, calibration, progress: !a.json };
    let started = std::time::Instant::now();
    let rows = study(&nominal, &cal, &val, &options);
    let elapsed = started.elapsed().as_secs_f64();
    let problems = study_problems(&rows);
    if !problems.is_empty() {
        bail!("the study has no result, nothing was written:\n  - {}", problems.join("\n  - "));
    }
    let i = &a.inputs;
    output::write_study(&rows, &a.out, &[&i.model, &artefact_path, &i.data, &i.validate])?;
    if a.json {
        println!("{}", output::study_json(&rows));
        return Ok(());
    }
    let total: usize = rows.iter().map(|r| r.calibrations + r.failed).sum();
    println!("{total} calibrations in {elapsed:.2} s on {} threads", rayon::current_num_threads());
    println!("placements  distinct subsets  calibrations  mean mm   std mm    min mm    max mm");
    for r in &rows {
        let drawn = r.calibrations + r.failed + r.implausible;
        let subsets = format!("{drawn} of {}", possible(r.possible_subsets));
        if r.calibrations == 0 {
            println!(
                "{:>10}  {subsets:>16}  {:>12}  no calibration succeeded ({} failed)",
                r.placements, 0, r.failed
            );
            continue;
        }
        println!(
            "{:>10}  {subsets:>16}  {:>12}  {:7.3}  {:7.3}  {:7.3}  {:7.3}",
            r.placements, r.calibrations, r.mean_mm, r.std_mm, r.min_mm, r.max_mm
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

pub fn cmd_diagnose(a: &DiagnoseArgs) -> Result<()> {
    if let Some(summary) = crate::tracker::tracker_summary(&a.run)? {
        return crate::tracker::diagnose_tracker_run(&a.run, &summary, a.json, a.auto, a.max_steps);
    }
    let folder = RunFolder::load(&a.run)?;
    let (_, cal, val) = folder.data()?;
    for problem in &folder.summary.not_trustworthy {
        eprintln!("warning: this run is marked not trustworthy: {problem}");
    }
    if a.auto {
        return cmd_diagnose_auto(a, &folder, &cal, &val);
    }
    let started = std::time::Instant::now();
    let spinner = spinner("diagnosing");
    let diagnosis = kincal::calib::diagnose::diagnose(
        &folder.model,
        &cal,
        &val,
        &folder.summary.options.calibration_options(),
    );
    spinner.finish_and_clear();
    let elapsed = started.elapsed().as_secs_f64();
    output::write_diagnosis(&diagnosis, &a.run)?;
    if a.json {
        println!("{}", output::diagnosis_json(&diagnosis));
        return Ok(());
    }
    for line in &diagnosis.summary {
        println!("{line}");
    }
    println!(
        "\n{} candidate effects scored in {elapsed:.2} s (held-out validation RMS, best first):",
        diagnosis.candidates.len()
    );
    println!("  {:<16} {:>10} {:>9} {:>10}  significant", "effect", "val RMS mm", "explained", "placements");
    for c in diagnosis.candidates.iter().filter(|c| c.equivalent_to.is_none()).take(8) {
        let blocks = format!("{}/{}", c.placements_improved.0, c.placements_improved.1);
        let same = if c.equivalent.is_empty() {
            String::new()
        } else {
            format!("  (indistinguishable here: {})", c.equivalent.join(", "))
        };
        println!(
            "  {:<16} {:>10.3} {:>9.2} {:>10}  {}{same}",
            c.effect,
            c.validation_rms_mm,
            c.explained,
            blocks,
            if c.significant { "yes" } else { "no" }
        );
    }
    if !diagnosis.not_identifiable.is_empty() {
        let names: Vec<&str> = diagnosis.not_identifiable.iter().map(|n| n.effect.as_str()).collect();
        println!("  not identifiable from these touches: {}", names.join(", "));
    }
    println!("\ndata errors scored beside them (best first):");
    for c in diagnosis.data_errors.iter().take(4) {
        let blocks = format!("{}/{}", c.placements_improved.0, c.placements_improved.1);
        let yes = if c.significant { "yes" } else { "no" };
        println!(
            "  {:<16} {:>10.3} {:>9.2} {:>10}  {yes}",
            c.effect, c.validation_rms_mm, c.explained, blocks
        );
    }
    println!("report: {}", a.run.join("diagnosis.html").display());
    Ok(())
}

fn cmd_diagnose_auto(
    a: &DiagnoseArgs,
    folder: &RunFolder,
    cal: &Observations,
    val: &Observations,
) -> Result<()> {
    let options = folder.summary.options.calibration_options();
    let started = std::time::Instant::now();
    let run = kincal::calib::auto::auto_loop(&folder.model, cal, val, &options, a.max_steps)?;
    let elapsed = started.elapsed().as_secs_f64();
    output::write_auto(&run, &a.run)?;
    let dir = a.run.join("auto");
    if a.json {
        println!("{}", output::auto_json(&run));
        return Ok(());
    }
    println!("step  added              val RMS mm  expected mm  held-out p");
    for (k, s) in run.steps.iter().enumerate() {
        println!(
            "{k:>4}  {:<18} {:>10.3}  {:>11}  {}",
            s.added.as_deref().unwrap_or("(start)"),
            s.validation_rms_mm,
            s.expected_rms_mm.map_or("–".into(), |e| format!("{e:.3}")),
            s.p_value.map_or("–".into(), |p| format!("{p:.1e}"))
        );
    }
    for line in &run.last.summary {
        println!("{line}");
    }
    println!("stopped: {:?} after {} steps in {elapsed:.2} s", run.stop, run.steps.len() - 1);
    println!(
        "models: {}/step-0.toml … step-{}.toml; report: {}",
        dir.display(),
        run.steps.len() - 1,
        dir.join("report.html").display()
    );
    Ok(())
}

pub fn cmd_compare(a: &CompareArgs) -> Result<()> {
    if crate::tracker::tracker_summary(&a.before)?.is_some()
        || crate::tracker::tracker_summary(&a.after)?.is_some()
    {
        return crate::tracker::compare_tracker_runs(&a.before, &a.after, &a.out);
    }
    let (before, after) = (ComparedRun::load(&a.before)?, ComparedRun::load(&a.after)?);
    for run in [&before, &after] {
        for problem in &run.summary.not_trustworthy {
            eprintln!("warning: {} is marked not trustworthy: {problem}", run.name);
        }
    }
    let comparison = Comparison::new(before, after);
    for line in comparison.table_lines() {
        println!("{line}");
    }
    output::write_page(&a.out, "<title>kincal compare</title>", &comparison.html())?;
    println!("side by side: {}", a.out.display());
    Ok(())
}
