//! `kincal`: the command-line edge. Parses arguments, calls the library, prints.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use kincal::calibrate::CalibrationOptions;
use kincal::data::{Artefact, Dataset};
use kincal::effects::Effect;
use kincal::model::{ArmModel, ParamId};
use kincal::objective::Objective;
use kincal::run::{run, RunInputs};
use kincal::simulate::{simulate, SimulationOptions};
use kincal::study::{study, study_report, StudyOptions};
use std::path::{Path, PathBuf};

mod cli_emulated_arm;

#[derive(Parser)]
#[command(name = "kincal", version, about = "Calibrate tracker arms from artefact touches")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write an artefact and calibration/validation sessions from a simulated "true" arm.
    Simulate(SimulateArgs),
    /// Calibrate the arm model from artefact touches and validate it on held-out sessions.
    Calibrate(CalibrateArgs),
    /// Dataset-size study: calibrate on random subsets of placements, validate each.
    Study(StudyArgs),
    /// Where the calibrated model of RUN fails and which physical effect is missing.
    Diagnose(DiagnoseArgs),
    /// Compare two runs: validation errors, per landmark, residual plots side by side.
    Compare(CompareArgs),
    /// The whole loop on the emulated controller: record, calibrate, upload, stream the pose.
    Demo(DemoArgs),
    /// Controller identity, protocol match, stored parameters and encoder health.
    Info(PortArgs),
    /// Read back the parameters stored on the controller.
    Params(PortArgs),
    /// Send a calibrated model to the controller (chunked, read back, committed).
    Upload(UploadArgs),
    /// Live joint angles or calibrated tool pose, with rate, gap and error statistics.
    Stream(StreamArgs),
    /// Guided measurement of one artefact placement; resumes an interrupted session.
    Record(RecordArgs),
    /// Emulated controller only: pose the arm, inject encoder noise and faults.
    #[command(subcommand)]
    EmulatedArm(cli_emulated_arm::EmulatedArmCommand),
    /// Haptic device (PHANToM) workspace calibration.
    #[command(subcommand)]
    Haptic(HapticCommand),
    /// Benchmarks: calibration time, study throughput, and SciPy on the same problem.
    Bench(kincal::bench::BenchArgs),
}

#[derive(Args)]
struct SimulateArgs {
    /// Nominal arm model; the truth is this model with its free parameters perturbed.
    #[arg(long, default_value = "examples/suta/model.toml")]
    model: PathBuf,
    /// Output folder: artefact.json, truth.toml, cal/, val/.
    #[arg(long)]
    out: PathBuf,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Size of the angle perturbations, degrees.
    #[arg(long, default_value_t = 2.0)]
    perturb_deg: f64,
    /// Size of the length perturbations, mm.
    #[arg(long, default_value_t = 2.0)]
    perturb_mm: f64,
    /// Seating noise per axis, mm (standard deviation).
    #[arg(long, default_value_t = 0.1)]
    seating_noise_mm: f64,
    /// Noise of each averaged encoder angle, degrees (standard deviation).
    #[arg(long, default_value_t = 0.003)]
    encoder_noise_deg: f64,
    /// Repeats of each landmark per placement.
    #[arg(long, default_value_t = 3)]
    repeats: u32,
    /// Hidden effect: PARAM=DELTA added to the true arm, e.g. eccentricity_sin:5=0.3 (repeatable).
    #[arg(long, value_parser = parse_hidden)]
    hidden: Vec<(ParamId, f64)>,
}

fn parse_effect(text: &str) -> Result<Effect, String> {
    Effect::parse(text).ok_or_else(|| format!("unknown effect `{text}`; expected e.g. eccentricity:5, eccentricity2:3, compliance:2, twist:4, link_offset:3, axis:2, tcp, scale"))
}

#[derive(Args)]
struct DiagnoseArgs {
    /// A RUN folder written by `kincal calibrate`.
    run: PathBuf,
    /// Print diagnosis.json to stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct CompareArgs {
    /// The run before.
    before: PathBuf,
    /// The run after.
    after: PathBuf,
    /// Where to write the side-by-side HTML.
    #[arg(long, default_value = "compare.html")]
    out: PathBuf,
}

fn parse_hidden(text: &str) -> Result<(ParamId, f64), String> {
    let (name, value) = text.split_once('=').ok_or("expected PARAM=DELTA, e.g. eccentricity_sin:5=0.3")?;
    let id = ParamId::parse(name.trim()).ok_or_else(|| format!("unknown parameter `{name}`"))?;
    let delta: f64 = value.trim().parse().map_err(|_| format!("`{value}` is not a number"))?;
    if !delta.is_finite() {
        return Err(format!("`{value}` is not finite"));
    }
    Ok((id, delta))
}

#[derive(Clone, Copy, ValueEnum)]
enum ObjectiveArg {
    /// Pairwise distances (thesis eq. 3.1).
    Distance,
    /// Distances plus relative orientation from the asymmetric pillars.
    SixDof,
}

#[derive(Args)]
struct SolveArgs {
    /// Seed of the random restarts.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Random restarts inside the bounds (besides the nominal start).
    #[arg(long, default_value_t = 8)]
    restarts: usize,
    /// Huber threshold δ, mm.
    #[arg(long, default_value_t = 1.35)]
    huber_delta_mm: f64,
    /// Residual blocks to minimise.
    #[arg(long, value_enum, default_value_t = ObjectiveArg::Distance)]
    objective: ObjectiveArg,
    /// Millimetres per radian of orientation error (six-dof objective).
    #[arg(long, default_value_t = 100.0)]
    lever_mm: f64,
}

impl SolveArgs {
    fn options(&self) -> CalibrationOptions {
        let objective = match self.objective {
            ObjectiveArg::Distance => Objective::Distance,
            ObjectiveArg::SixDof => Objective::SixDof { lever_mm: self.lever_mm },
        };
        CalibrationOptions {
            huber_delta_mm: self.huber_delta_mm,
            restarts: self.restarts,
            seed: self.seed,
            objective,
            ..CalibrationOptions::default()
        }
    }
}

#[derive(Args)]
struct InputArgs {
    /// Arm model file (kincal-arm/1, .toml or .json).
    #[arg(long)]
    model: PathBuf,
    /// Artefact file (suta-artefact/1).
    #[arg(long)]
    artefact: PathBuf,
    /// Folder of calibration sessions (suta-session/1).
    #[arg(long)]
    data: PathBuf,
    /// Folder of validation sessions.
    #[arg(long)]
    validate: PathBuf,
}

#[derive(Args)]
struct CalibrateArgs {
    #[command(flatten)]
    inputs: InputArgs,
    /// Output folder RUN: model.toml, summary.json, report.html.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    solve: SolveArgs,
    /// Also run the dataset-size study with this many subsets per placement count (0: no study).
    #[arg(long, default_value_t = 0)]
    study_subsets: usize,
    /// Add an effect of the library to the model, e.g. eccentricity:5 (repeatable).
    #[arg(long = "add", value_parser = parse_effect)]
    add: Vec<Effect>,
    /// Print summary.json to stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct StudyArgs {
    #[command(flatten)]
    inputs: InputArgs,
    /// Output folder: study.json and report.html.
    #[arg(long)]
    out: PathBuf,
    /// Random subsets per number of placements.
    #[arg(long, default_value_t = 100)]
    subsets: usize,
    /// Seed of the subset draws and restarts.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Random restarts per calibration (besides the nominal start).
    #[arg(long, default_value_t = 0)]
    restarts: usize,
    /// Print study.json to stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct DemoArgs {
    /// Nominal arm model.
    #[arg(long, default_value = "examples/suta/model.toml")]
    model: PathBuf,
    /// Folder for the data and the run.
    #[arg(long, default_value = "runs/demo")]
    out: PathBuf,
    /// Seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Window per touch, ticks (1536 = 2 s as on the real arm).
    #[arg(long, default_value_t = 96)]
    window_ticks: u16,
    /// Host only: simulate sessions directly and calibrate (no emulated controller).
    #[arg(long)]
    offline: bool,
}

#[derive(Subcommand)]
enum HapticCommand {
    /// Write a simulated recording (device, tracker, delay, sensor errors) with known truth.
    Simulate(HapticSimulateArgs),
    /// Calibrate from a recording folder: delay, position, orientation.
    Calibrate(HapticCalibrateArgs),
}

#[derive(Args)]
struct HapticSimulateArgs {
    /// Output recording folder.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Tracker delay behind the device, ms.
    #[arg(long, default_value_t = 13.0)]
    delay_ms: f64,
    /// Linear gimbal sensors instead of potentiometer-like quadratic ones.
    #[arg(long)]
    linear_gimbals: bool,
    /// Seconds of free motion in joints/.
    #[arg(long, default_value_t = 60.0)]
    joints_seconds: f64,
}

#[derive(Args)]
struct HapticCalibrateArgs {
    /// Recording folder (haptic-recording/1).
    recording: PathBuf,
    /// Output folder: summary.json, report.html.
    #[arg(long)]
    out: PathBuf,
    /// Print summary.json.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
struct PortArgs {
    /// Serial device or pty path (/dev/ttyUSB0, /dev/pts/3) or tcp:HOST:PORT.
    #[arg(long)]
    port: String,
}

#[derive(Args)]
struct UploadArgs {
    #[command(flatten)]
    port: PortArgs,
    /// The calibrated model (RUN/model.toml).
    model: PathBuf,
    /// Version number stored with the parameters.
    #[arg(long, default_value_t = 1)]
    version: u32,
}

#[derive(Args)]
struct StreamArgs {
    #[command(flatten)]
    port: PortArgs,
    /// Stream raw joint angles (default).
    #[arg(long, conflicts_with = "pose")]
    raw: bool,
    /// Stream the calibrated tool pose computed on the controller.
    #[arg(long)]
    pose: bool,
    /// Also write every sample to this CSV file.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
}

#[derive(Args)]
struct RecordArgs {
    #[command(flatten)]
    port: PortArgs,
    /// Artefact file.
    #[arg(long)]
    artefact: PathBuf,
    /// Placement name, e.g. C_A.
    #[arg(long)]
    placement: String,
    /// calibration or validation.
    #[arg(long, default_value = "calibration")]
    purpose: String,
    /// Output folder; the session is OUT/<placement>.json.
    #[arg(long)]
    out: PathBuf,
    /// Landmark order, comma separated (default: the artefact file's).
    #[arg(long, value_delimiter = ',')]
    order: Vec<String>,
    /// Repeats of the sequence.
    #[arg(long, default_value_t = 3)]
    repeats: u32,
    /// Window per touch, ticks (1536 = 2 s).
    #[arg(long, default_value_t = 1536)]
    window_ticks: u16,
    /// Non-interactive: steps from a JSON script (landmarks, emulated poses, skips).
    #[arg(long)]
    script: Option<PathBuf>,
}

fn main() {
    // Behave like other command-line tools when the reader of stdout goes away (`| head`).
    #[cfg(unix)]
    // SAFETY: resetting a signal disposition to its default before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Simulate(a) => cmd_simulate(&a),
        Command::Calibrate(a) => cmd_calibrate(&a),
        Command::Study(a) => cmd_study(&a),
        Command::Diagnose(a) => cmd_diagnose(&a),
        Command::Compare(a) => cmd_compare(&a),
        Command::Demo(a) => cmd_demo(&a),
        Command::Info(a) => cmd_info(&a),
        Command::Params(a) => cmd_params(&a),
        Command::Upload(a) => cmd_upload(&a),
        Command::Stream(a) => cmd_stream(&a),
        Command::Record(a) => cmd_record(&a),
        Command::EmulatedArm(c) => cli_emulated_arm::run(&c),
        Command::Haptic(HapticCommand::Simulate(a)) => cmd_haptic_simulate(&a),
        Command::Haptic(HapticCommand::Calibrate(a)) => cmd_haptic_calibrate(&a),
        Command::Bench(a) => kincal::bench::run_benchmarks(&a).map_err(anyhow::Error::from),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn simulate_to(model: &Path, out: &Path, options: &SimulationOptions) -> Result<()> {
    let nominal = ArmModel::load(model)?;
    let sim = simulate(&nominal, options);
    sim.write(out)?;
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

fn cmd_simulate(a: &SimulateArgs) -> Result<()> {
    let options = SimulationOptions {
        seed: a.seed,
        perturb_deg: a.perturb_deg,
        perturb_mm: a.perturb_mm,
        seating_noise_mm: a.seating_noise_mm,
        encoder_noise_deg: a.encoder_noise_deg,
        repeats: a.repeats,
        hidden: a.hidden.clone(),
    };
    simulate_to(&a.model, &a.out, &options)
}

fn inputs(a: &InputArgs) -> RunInputs {
    RunInputs {
        model: a.model.clone(),
        artefact: a.artefact.clone(),
        calibration: a.data.clone(),
        validation: a.validate.clone(),
    }
}

fn calibrate_and_report(
    inputs: &RunInputs,
    out: &Path,
    options: &CalibrationOptions,
    effects: &[Effect],
    study_subsets: usize,
    json: bool,
) -> Result<()> {
    let started = std::time::Instant::now();
    let result = run(inputs, options, effects, study_subsets)?;
    result.write(out)?;
    let s = &result.summary;
    if json {
        println!("{}", serde_json::to_string_pretty(s)?);
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
        s.nominal_validation.pairs
    );
    println!(
        "  validation RMS  calibrated {:8.3} mm   (mean {:+.3}, max {:.3}, {} pairs)",
        s.validation.rms_mm, s.validation.mean_mm, s.validation.max_mm, s.validation.pairs
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

fn cmd_calibrate(a: &CalibrateArgs) -> Result<()> {
    calibrate_and_report(&inputs(&a.inputs), &a.out, &a.solve.options(), &a.add, a.study_subsets, a.json)
}

fn cmd_study(a: &StudyArgs) -> Result<()> {
    let nominal = ArmModel::load(&a.inputs.model)?;
    let artefact = Artefact::load(&a.inputs.artefact)?;
    let cal = Dataset::load_dir(&a.inputs.data, &artefact)?;
    let val = Dataset::load_dir(&a.inputs.validate, &artefact)?;
    if a.subsets == 0 {
        bail!("--subsets must be at least 1");
    }
    let calibration =
        CalibrationOptions { restarts: a.restarts, seed: a.seed, ..CalibrationOptions::default() };
    let options = StudyOptions { subsets: a.subsets, seed: a.seed, calibration, progress: !a.json };
    let started = std::time::Instant::now();
    let rows = study(&nominal, &artefact, &cal, &val, &options);
    let elapsed = started.elapsed().as_secs_f64();
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let json = serde_json::to_string_pretty(&rows)?;
    kincal::fsutil::write_atomic(&a.out.join("study.json"), json.as_bytes())
        .with_context(|| format!("writing {}", a.out.join("study.json").display()))?;
    kincal::fsutil::write_atomic(&a.out.join("report.html"), study_report(&rows).as_bytes())
        .with_context(|| format!("writing {}", a.out.join("report.html").display()))?;
    if a.json {
        println!("{json}");
        return Ok(());
    }
    let total: usize = rows.iter().map(|r| r.calibrations + r.failed).sum();
    println!("{total} calibrations in {elapsed:.2} s on {} threads", rayon::current_num_threads());
    println!("placements  calibrations  mean mm   std mm    min mm    max mm");
    for r in &rows {
        println!(
            "{:>10}  {:>12}  {:7.3}  {:7.3}  {:7.3}  {:7.3}",
            r.placements, r.calibrations, r.mean_mm, r.std_mm, r.min_mm, r.max_mm
        );
    }
    println!("report: {}", a.out.join("report.html").display());
    Ok(())
}

fn cmd_demo(a: &DemoArgs) -> Result<()> {
    if a.offline {
        return cmd_demo_offline(a);
    }
    let nominal = ArmModel::load(&a.model)?;
    println!("building the emulated controller firmware and starting QEMU (mps2-an386)");
    let elf = kincal::emulator::build_firmware()?;
    let (_emulator, mut link) = kincal::emulator::Emulator::start(&elf)?;
    link.hello()?;
    let info = link.info()?;
    println!("connected: {} on {}", info.firmware, info.board);
    let options = kincal::workflow::LoopOptions {
        seed: a.seed,
        window_ticks: a.window_ticks,
        out: a.out.clone(),
        ..Default::default()
    };
    let report = kincal::workflow::run_loop(&mut link, &nominal, &options, &mut |step| println!("  {step}"))?;
    println!("recorded {} touches through the controller; loop took {:.0} s", report.touches, report.seconds);
    println!("validation distance RMS   nominal {:8.3} mm   calibrated {:7.3} mm   true arm on the same data {:.3} mm (noise floor)", report.nominal_validation_rms_mm, report.calibrated_validation_rms_mm, report.truth_validation_rms_mm);
    println!("streamed pose error (RMS after rigid registration, {} validation touches):", report.poses);
    println!("  nominal parameters    {:8.3} mm", report.nominal_pose_rms_mm);
    println!(
        "  calibrated parameters {:8.3} mm   (the host predicts {:.3} mm for this model)",
        report.calibrated_pose_rms_mm, report.host_calibrated_pose_rms_mm
    );
    println!(
        "  true arm's parameters {:8.3} mm   (floor: encoder noise and f32 on the controller)",
        report.floor_pose_rms_mm
    );
    println!("parameter upload took {:.2} s; run: {}", report.upload_seconds, a.out.join("run").display());
    Ok(())
}

fn connect(port: &PortArgs) -> Result<kincal::link::Link> {
    let mut link = kincal::link::Link::open(&port.port)?;
    link.hello().with_context(|| format!("handshake with the controller on {}", port.port))?;
    Ok(link)
}

fn cmd_info(a: &PortArgs) -> Result<()> {
    let mut link = connect(a)?;
    let info = link.info()?;
    println!("firmware   {} on {}", info.firmware, info.board);
    println!(
        "protocol   version {} schema {:08x}: matches this host",
        kincal_protocol::messages::PROTOCOL_VERSION,
        kincal_protocol::messages::SCHEMA_HASH
    );
    if info.param_version == 0 {
        println!("parameters none stored");
    } else {
        println!("parameters version {} (CRC-32 {:08x})", info.param_version, info.param_crc);
    }
    println!("late ticks {} (encoder reads started over a tick late)", info.late_ticks);
    println!(
        "uptime     {} ticks ({:.1} s)",
        info.ticks,
        kincal_protocol::messages::ticks_to_seconds(info.ticks)
    );
    println!("joint  accepted  crc-errors  error-bits  warnings  dropouts");
    for (j, h) in info.encoders.iter().enumerate() {
        println!(
            "{:>5}  {:>8}  {:>10}  {:>10}  {:>8}  {:>8}",
            j + 1,
            h.accepted,
            h.crc_errors,
            h.error_bits,
            h.warnings,
            h.dropouts
        );
    }
    Ok(())
}

fn cmd_params(a: &PortArgs) -> Result<()> {
    let mut link = connect(a)?;
    let blob = link.read_params(false, kincal_protocol::params::MAX_PARAM_BLOB)?;
    if blob.is_empty() {
        println!("no parameters stored");
        return Ok(());
    }
    let params = kincal_protocol::params::decode_blob(&blob)
        .map_err(|e| anyhow::anyhow!("the stored parameter blob does not decode: {e:?}"))?;
    println!("{}", serde_json::to_string_pretty(&params)?);
    Ok(())
}

fn cmd_upload(a: &UploadArgs) -> Result<()> {
    let model = ArmModel::load(&a.model)?;
    let blob = kincal::device::parameter_blob(&model, a.version)
        .with_context(|| format!("{}: parameters version {}", a.model.display(), a.version))?;
    let mut link = connect(&a.port)?;
    let before = link.held_params()?;
    let started = std::time::Instant::now();
    let uploaded = match link.upload(&blob) {
        Ok(u) => u,
        Err(e @ kincal::link::LinkError::CommitUnconfirmed { .. }) => bail!("upload failed: {e}"),
        Err(e) => {
            bail!("upload failed: {e}. Nothing was committed: the controller keeps {before}; run the upload again")
        }
    };
    if uploaded.commit_reply_lost {
        eprintln!(
            "the first commit request went unanswered; asked again, the controller confirms the new set"
        );
    }
    let now = link.held_params()?;
    println!(
        "uploaded {} bytes in {:.2} s; the controller now holds {now}, previously {before}",
        blob.len(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn cmd_stream(a: &StreamArgs) -> Result<()> {
    use kincal_protocol::messages::{Stream, StreamPose, StreamRaw};
    let mut link = connect(&a.port)?;
    catch_ctrl_c();
    let mut csv = match &a.csv {
        Some(path) => Some(std::io::BufWriter::new(
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
        )),
        None => None,
    };
    use std::io::Write;
    if let Some(w) = csv.as_mut() {
        writeln!(
            w,
            "{}",
            if a.pose {
                "seq,tick,x_mm,y_mm,z_mm,zx,zy,zz"
            } else {
                "seq,tick,j1_deg,j2_deg,j3_deg,j4_deg,j5_deg,j6_deg,rejected"
            }
        )?;
    }
    if a.pose {
        link.call(StreamPose { divider: 1 })?;
    } else {
        link.call(StreamRaw { on: true })?;
    }
    let started = std::time::Instant::now();
    let mut frames = 0u64;
    let mut last_report = started;
    while !INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst)
        && a.seconds.is_none_or(|s| started.elapsed().as_secs_f64() < s)
    {
        let Some((seq, item)) = link.next_stream(std::time::Duration::from_millis(200))? else { continue };
        frames += 1;
        if let Some(w) = csv.as_mut() {
            match item {
                Stream::Raw(r) => {
                    let deg = kincal_protocol::messages::unpack_counts(&r.packed)
                        .map(|c| kincal_protocol::biss::counts_to_deg(c as f64));
                    writeln!(
                        w,
                        "{seq},{},{},{},{},{},{},{},{}",
                        r.tick, deg[0], deg[1], deg[2], deg[3], deg[4], deg[5], r.rejected
                    )?;
                }
                Stream::Pose(p) => writeln!(
                    w,
                    "{seq},{},{},{},{},{},{},{}",
                    p.tick,
                    p.position_mm[0],
                    p.position_mm[1],
                    p.position_mm[2],
                    p.z_axis[0],
                    p.z_axis[1],
                    p.z_axis[2]
                )?,
                Stream::Window(_) => {}
            }
        }
        if last_report.elapsed().as_secs_f64() >= 1.0 {
            last_report = std::time::Instant::now();
            eprintln!(
                "{:.0} frames/s, {} lost, {} corrupt",
                frames as f64 / started.elapsed().as_secs_f64(),
                link.stats.stream_gaps,
                link.stats.bad_frames
            );
        }
    }
    let _ = link.call(StreamRaw { on: false });
    let _ = link.call(StreamPose { divider: 0 });
    println!(
        "{frames} frames in {:.1} s ({:.1} Hz), {} lost, {} corrupt",
        started.elapsed().as_secs_f64(),
        frames as f64 / started.elapsed().as_secs_f64(),
        link.stats.stream_gaps,
        link.stats.bad_frames
    );
    Ok(())
}

/// Set by Ctrl-C while streaming.
static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

extern "C" fn on_sigint(_: libc::c_int) {
    INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
}

/// Make Ctrl-C stop a stream cleanly instead of killing the process.
fn catch_ctrl_c() {
    #[cfg(unix)]
    // SAFETY: the handler only stores to an atomic flag (async-signal-safe).
    unsafe {
        libc::signal(libc::SIGINT, on_sigint as *const () as libc::sighandler_t);
    }
}

fn cmd_record(a: &RecordArgs) -> Result<()> {
    let artefact = Artefact::load(&a.artefact)?;
    let order = if a.order.is_empty() {
        artefact.landmarks.iter().map(|l| l.id.clone()).collect()
    } else {
        a.order.clone()
    };
    let plan = kincal::record::Plan {
        placement: a.placement.clone(),
        purpose: a.purpose.clone(),
        order,
        repeats: a.repeats,
        window_ticks: a.window_ticks,
        out: a.out.clone(),
    };
    let mut link = connect(&a.port)?;
    let mut script;
    let mut operator = kincal::record::Operator;
    let guide: &mut dyn kincal::record::Guide = match &a.script {
        Some(path) => {
            script = kincal::record::Script::load(path)?;
            &mut script
        }
        None => &mut operator,
    };
    let done = kincal::record::record(&mut link, &artefact, &plan, guide)?;
    println!(
        "{}: {} measured now, {} resumed from disk, {} skipped, {} re-taken → {}",
        plan.placement,
        done.measured,
        done.resumed,
        done.skipped,
        done.retakes,
        plan.session_path().display()
    );
    Ok(())
}

fn cmd_demo_offline(a: &DemoArgs) -> Result<()> {
    let data = a.out.join("data");
    println!("1/2 simulate: a true arm off the nominal model by degrees and millimetres");
    simulate_to(&a.model, &data, &SimulationOptions { seed: a.seed, ..SimulationOptions::default() })?;
    println!(
        "2/2 calibrate on {} and validate on {}",
        data.join("cal").display(),
        data.join("val").display()
    );
    let inputs = RunInputs {
        model: a.model.clone(),
        artefact: data.join("artefact.json"),
        calibration: data.join("cal"),
        validation: data.join("val"),
    };
    calibrate_and_report(
        &inputs,
        &a.out.join("run"),
        &CalibrationOptions { seed: a.seed, ..CalibrationOptions::default() },
        &[],
        20,
        false,
    )?;
    let truth = ArmModel::load(&data.join("truth.toml"))?;
    let artefact = Artefact::load(&inputs.artefact)?;
    let val = Dataset::load_dir(&inputs.validation, &artefact)?;
    let floor = kincal::validate::validate(&truth, &artefact, &val).overall;
    println!("  noise floor (true arm on the same validation data) {:.3} mm", floor.rms_mm);
    Ok(())
}

fn cmd_diagnose(a: &DiagnoseArgs) -> Result<()> {
    let folder = kincal::run::RunFolder::load(&a.run)?;
    let (artefact, cal, val) = folder.data()?;
    let started = std::time::Instant::now();
    let diagnosis = kincal::diagnose::diagnose(
        &folder.model,
        &artefact,
        &cal,
        &val,
        &folder.record.options.calibration_options(),
    );
    let elapsed = started.elapsed().as_secs_f64();
    let json = serde_json::to_string_pretty(&diagnosis)?;
    kincal::fsutil::write_atomic(&a.run.join("diagnosis.json"), json.as_bytes())
        .with_context(|| format!("writing {}", a.run.join("diagnosis.json").display()))?;
    let html = kincal::report::diagnosis_report(&diagnosis);
    kincal::fsutil::write_atomic(&a.run.join("diagnosis.html"), html.as_bytes())
        .with_context(|| format!("writing {}", a.run.join("diagnosis.html").display()))?;
    if a.json {
        println!("{json}");
        return Ok(());
    }
    for line in &diagnosis.summary {
        println!("{line}");
    }
    println!(
        "\n{} candidate effects scored in {elapsed:.2} s (held-out validation RMS, best first):",
        diagnosis.candidates.len()
    );
    println!("  {:<16} {:>10} {:>9} {:>8}  significant", "effect", "val RMS mm", "explained", "blocks");
    for c in diagnosis.candidates.iter().filter(|c| c.equivalent_to.is_none()).take(8) {
        let blocks = format!("{}/{}", c.blocks_improved.0, c.blocks_improved.1);
        let same = if c.equivalent.is_empty() {
            String::new()
        } else {
            format!("  (indistinguishable here: {})", c.equivalent.join(", "))
        };
        println!(
            "  {:<16} {:>10.3} {:>9.2} {:>8}  {}{same}",
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
    println!("report: {}", a.run.join("diagnosis.html").display());
    Ok(())
}

fn cmd_compare(a: &CompareArgs) -> Result<()> {
    let comparison = kincal::report::Comparison::load(&a.before, &a.after)?;
    for line in comparison.table_lines() {
        println!("{line}");
    }
    kincal::fsutil::write_atomic(&a.out, comparison.html().as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    println!("side by side: {}", a.out.display());
    Ok(())
}

fn cmd_haptic_simulate(a: &HapticSimulateArgs) -> Result<()> {
    let options = kincal::haptic::simulate::HapticSimOptions {
        seed: a.seed,
        delay_ms: a.delay_ms,
        quadratic_gimbals: !a.linear_gimbals,
        joints_seconds: a.joints_seconds,
        ..Default::default()
    };
    let (recording, _) = kincal::haptic::simulate::simulate_recording(&options);
    kincal::haptic::simulate::write_recording(&recording, &a.out)
        .with_context(|| format!("writing {}", a.out.display()))?;
    println!(
        "simulated recording (delay {} ms, {} gimbals) in {}",
        a.delay_ms,
        if a.linear_gimbals { "linear" } else { "quadratic" },
        a.out.display()
    );
    Ok(())
}

fn cmd_haptic_calibrate(a: &HapticCalibrateArgs) -> Result<()> {
    let recording = kincal::haptic::recording::load(&a.recording)?;
    let started = std::time::Instant::now();
    let result = kincal::haptic::pipeline::calibrate_recording(&recording)?;
    let seconds = started.elapsed().as_secs_f64();
    let summary = result.summary();
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let json = serde_json::to_string_pretty(&summary)?;
    kincal::fsutil::write_atomic(&a.out.join("summary.json"), json.as_bytes())
        .with_context(|| format!("writing {}", a.out.join("summary.json").display()))?;
    kincal::fsutil::write_atomic(
        &a.out.join("report.html"),
        kincal::report::haptic_report(&summary).as_bytes(),
    )
    .with_context(|| format!("writing {}", a.out.join("report.html").display()))?;
    if a.json {
        println!("{json}");
        return Ok(());
    }
    println!("calibrated in {seconds:.2} s");
    println!("  delay        {:8.2} ms (tracker behind device)", summary.delay_ms);
    println!(
        "  position     {:8.3} mm → {:.3} mm (RMS, {} held-out samples)",
        summary.position.before_mm, summary.position.after_mm, result.held_out
    );
    println!(
        "  orientation  {:8.3} °  → {:.3} °",
        summary.orientation.before_deg, summary.orientation.after_deg
    );
    println!("  gimbals      {:?} sensor model (chosen on held-out error)", summary.gimbal_model);
    println!("  report: {}", a.out.join("report.html").display());
    Ok(())
}
