//! Controller commands: info, params, upload, stream, record, and the demo loop.

use crate::arm::simulate_to;
use anyhow::{bail, Context, Result};
use clap::Args;
use kincal::calib::calibrate::CalibrationOptions;
use kincal::calib::run::RunInputs;
use kincal::data::{Artefact, Dataset};
use kincal::model::ArmModel;
use kincal::simulate::SimulationOptions;
use std::path::PathBuf;

#[derive(Args)]
pub struct DemoArgs {
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
    /// The emulated controller's firmware image (`cargo build-emulated` writes it here).
    #[arg(long, default_value = "firmware/target/thumbv7em-none-eabihf/release/emulated")]
    firmware: PathBuf,
}

#[derive(Args)]
pub struct PortArgs {
    /// Serial device or pty path (/dev/ttyUSB0, /dev/pts/3) or tcp:HOST:PORT.
    #[arg(long)]
    port: String,
}

#[derive(Args)]
pub struct UploadArgs {
    #[command(flatten)]
    port: PortArgs,
    /// The calibrated model (RUN/model.toml).
    model: PathBuf,
    /// Version number stored with the parameters.
    #[arg(long, default_value_t = 1)]
    version: u32,
}

#[derive(Args)]
pub struct StreamArgs {
    #[command(flatten)]
    port: PortArgs,
    /// Stream raw joint angles (default).
    #[arg(long, conflicts_with = "pose")]
    raw: bool,
    /// Stream the calibrated tool pose computed on the controller.
    #[arg(long)]
    pose: bool,
    /// Also write every sample to this CSV file (a new file: an existing one is never replaced;
    /// written as `.NAME.partial` and renamed when the stream stops, Ctrl-C included).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
}

#[derive(Args)]
pub struct RecordArgs {
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

pub fn cmd_demo(a: &DemoArgs) -> Result<()> {
    if a.offline {
        return cmd_demo_offline(a);
    }
    let nominal = ArmModel::load(&a.model)?;
    println!("starting the emulated controller on QEMU (mps2-an386): {}", a.firmware.display());
    let (_emulator, mut link) = kincal::controller::emulator::Emulator::start(&a.firmware)?;
    link.hello()?;
    let info = link.info()?;
    println!("connected: {} on {}", info.firmware, info.board);
    let options = kincal::controller::demo::LoopOptions {
        seed: a.seed,
        window_ticks: a.window_ticks,
        out: a.out.clone(),
        ..Default::default()
    };
    let report =
        kincal::controller::demo::run_loop(&mut link, &nominal, &options, &mut |step| println!("  {step}"))?;
    println!("recorded {} touches through the controller; loop took {:.0} s", report.touches, report.seconds);
    println!("the emulated arm hides {} (the nominal model lacks it)", report.hidden.join(", "));
    for line in
        report.diagnosis.iter().filter(|l| l.starts_with("missing effect") || l.contains("measured, ≈"))
    {
        println!("  {line}");
    }
    print_mission(&report.steps, report.truth_validation_rms_mm, &report.stop);
    println!(
        "runs: {} (as given, with diagnosis.html and auto/), {} (with the added effects; uploaded)",
        a.out.join("run").display(),
        a.out.join("run-added").display()
    );
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

/// The calibrate → diagnose → add steps against the floor.
fn print_mission(steps: &[kincal::controller::demo::MissionStep], truth_rms_mm: f64, stop: &str) {
    println!("step  added              val RMS mm  floor (repeatability) mm  × true floor  held-out p");
    for (k, s) in steps.iter().enumerate() {
        println!(
            "{k:>4}  {:<18} {:>10.3}  {:>24}  {:>12.2}  {}",
            s.added.as_deref().unwrap_or("(as given)"),
            s.validation_rms_mm,
            s.expected_floor_mm.map_or("–".into(), |e| format!("{e:.3}")),
            s.validation_rms_mm / truth_rms_mm.max(1e-12),
            s.p_value.map_or("–".into(), |p| format!("{p:.1e}"))
        );
    }
    println!("diagnose → add stopped: {stop}; true arm on the same validation data {truth_rms_mm:.3} mm");
}

pub fn connect(port: &PortArgs) -> Result<kincal::controller::link::Link> {
    let mut link = kincal::controller::link::Link::open(&port.port)?;
    link.hello().with_context(|| format!("handshake with the controller on {}", port.port))?;
    Ok(link)
}

pub fn cmd_info(a: &PortArgs) -> Result<()> {
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

pub fn cmd_params(a: &PortArgs) -> Result<()> {
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

pub fn cmd_upload(a: &UploadArgs) -> Result<()> {
    let model = ArmModel::load(&a.model)?;
    let beyond = kincal::model::effects::beyond_controller(&model);
    if !beyond.is_empty() {
        let names: Vec<String> = beyond.iter().map(|p| p.to_string()).collect();
        bail!(
            "{}: the controller cannot evaluate {} (harmonics above the second); nothing was uploaded",
            a.model.display(),
            names.join(", ")
        );
    }
    let blob = kincal::controller::device::parameter_blob(&model, a.version)
        .with_context(|| format!("{}: parameters version {}", a.model.display(), a.version))?;
    let mut link = connect(&a.port)?;
    let before = link.held_params()?;
    let started = std::time::Instant::now();
    let uploaded = match link.upload(&blob) {
        Ok(u) => u,
        Err(e @ kincal::controller::link::LinkError::CommitUnconfirmed { .. }) => bail!("upload failed: {e}"),
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

pub fn cmd_stream(a: &StreamArgs) -> Result<()> {
    use kincal_protocol::messages::{Stream, StreamPose, StreamRaw};
    if let Some(path) = &a.csv {
        CsvRecording::refuse_existing(path)?;
    }
    let mut link = connect(&a.port)?;
    catch_ctrl_c();
    let mut csv = match &a.csv {
        Some(path) => Some(CsvRecording::create(path)?),
        None => None,
    };
    use std::io::Write;
    if let Some(w) = csv.as_mut().map(|c| &mut c.writer) {
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
        if let Some(w) = csv.as_mut().map(|c| &mut c.writer) {
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
    if let Some(c) = csv {
        c.finish()?;
    }
    println!(
        "{frames} frames in {:.1} s ({:.1} Hz), {} lost, {} corrupt",
        started.elapsed().as_secs_f64(),
        frames as f64 / started.elapsed().as_secs_f64(),
        link.stats.stream_gaps,
        link.stats.bad_frames
    );
    Ok(())
}

/// A CSV file being written during a stream: a new file only, written under a temporary name
/// beside it and renamed by [`CsvRecording::finish`] (or when dropped after an error, so what
/// was recorded is kept).
struct CsvRecording {
    writer: std::io::BufWriter<std::fs::File>,
    partial: PathBuf,
    path: PathBuf,
}

impl CsvRecording {
    /// Refuse a path that exists (checked before connecting, so nothing is created on a refusal).
    fn refuse_existing(path: &std::path::Path) -> Result<()> {
        if path.exists() {
            anyhow::bail!(
                "{} exists; kincal never replaces a file with a stream recording: choose a new name or remove it",
                path.display()
            );
        }
        Ok(())
    }

    fn create(path: &std::path::Path) -> Result<CsvRecording> {
        Self::refuse_existing(path)?;
        let name = path.file_name().with_context(|| format!("{} is not a file name", path.display()))?;
        let partial = path.with_file_name(format!(".{}.partial", name.to_string_lossy()));
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&partial)
            .with_context(|| format!("creating {}", partial.display()))?;
        Ok(CsvRecording { writer: std::io::BufWriter::new(file), partial, path: path.to_path_buf() })
    }

    /// Flush and give the file its name (never over a file that appeared meanwhile).
    fn finish(mut self) -> Result<()> {
        self.keep()
    }

    fn keep(&mut self) -> Result<()> {
        use std::io::Write;
        self.writer.flush().with_context(|| format!("writing {}", self.partial.display()))?;
        std::fs::hard_link(&self.partial, &self.path).with_context(|| {
            format!("naming the recording {} (kept as {})", self.path.display(), self.partial.display())
        })?;
        std::fs::remove_file(&self.partial)
            .with_context(|| format!("removing {}", self.partial.display()))?;
        Ok(())
    }
}

impl Drop for CsvRecording {
    fn drop(&mut self) {
        if self.partial.exists() {
            if let Err(e) = self.keep() {
                eprintln!("{e:#}");
            }
        }
    }
}

/// Set by Ctrl-C while streaming.
pub static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

extern "C" fn on_sigint(_: libc::c_int) {
    INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
}

/// Make Ctrl-C stop a stream cleanly instead of killing the process.
pub fn catch_ctrl_c() {
    #[cfg(unix)]
    // SAFETY: the handler only stores to an atomic flag (async-signal-safe).
    unsafe {
        libc::signal(libc::SIGINT, on_sigint as *const () as libc::sighandler_t);
    }
}

pub fn cmd_record(a: &RecordArgs) -> Result<()> {
    let artefact = Artefact::load(&a.artefact)?;
    let order = if a.order.is_empty() {
        artefact.landmarks.iter().map(|l| l.id.clone()).collect()
    } else {
        a.order.clone()
    };
    let plan = kincal::controller::record::Plan {
        placement: a.placement.clone(),
        purpose: a.purpose.clone(),
        order,
        repeats: a.repeats,
        window_ticks: a.window_ticks,
        out: a.out.clone(),
    };
    let mut link = connect(&a.port)?;
    let mut script;
    let mut operator = kincal::controller::record::Operator;
    let guide: &mut dyn kincal::controller::record::Guide = match &a.script {
        Some(path) => {
            script = kincal::controller::record::Script::load(path)?;
            &mut script
        }
        None => &mut operator,
    };
    let done = kincal::controller::record::record(&mut link, &artefact, &plan, guide)?;
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

pub fn cmd_demo_offline(a: &DemoArgs) -> Result<()> {
    let data = a.out.join("data");
    let hidden = vec![kincal::controller::demo::DEMO_HIDDEN];
    let names: Vec<String> = hidden.iter().map(|(id, d)| format!("{id} = {d:+}")).collect();
    println!(
        "1/3 simulate: a true arm off the nominal model by degrees and millimetres, hiding {}",
        names.join(", ")
    );
    simulate_to(
        &a.model,
        &data,
        &SimulationOptions { seed: a.seed, hidden, ..SimulationOptions::default() },
    )?;
    println!(
        "2/3 calibrate on {}, validate on {}, diagnose, add",
        data.join("cal").display(),
        data.join("val").display()
    );
    let inputs =
        RunInputs::new(a.model.clone(), data.join("artefact.json"), data.join("cal"), data.join("val"));
    let mission = kincal::controller::demo::calibrate_diagnose_add(
        &inputs,
        &CalibrationOptions { seed: a.seed, ..CalibrationOptions::default() },
        &a.out,
        &mut |step| println!("  {step}"),
    )?;
    let truth = ArmModel::load(&data.join("truth.toml"))?;
    let artefact = Artefact::load(&inputs.artefact)?;
    let val = Dataset::load_dir(&inputs.validation, &artefact, kincal::data::Purpose::Validation)?;
    let floor = kincal::calib::validate::validate(&truth, &artefact, &val).overall;
    println!("3/3 the steps against the floor");
    print_mission(&mission.steps, floor.rms_mm, &kincal::controller::demo::stop_words(&mission.auto.stop));
    for line in &mission.auto.steps[0].summary {
        println!("  {line}");
    }
    let last = mission.final_run();
    if !last.summary.not_trustworthy.is_empty() {
        bail!("the final calibration is not trustworthy: {}", last.summary.not_trustworthy.join("; "));
    }
    let dir = if mission.last.is_some() { a.out.join("run-added") } else { a.out.join("run") };
    println!(
        "validation RMS  nominal {:.3} mm → as given {:.3} mm → with {} {:.3} mm; noise floor {:.3} mm; run: {}",
        mission.first.summary.nominal_validation.rms_mm,
        mission.first.summary.validation.rms_mm,
        if mission.added.is_empty() { "nothing".to_string() } else { mission.added.join(" + ") },
        last.summary.validation.rms_mm,
        floor.rms_mm,
        dir.display()
    );
    Ok(())
}
