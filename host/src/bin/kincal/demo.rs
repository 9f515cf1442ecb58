//! The demo: the whole loop on the emulated controller (record, calibrate, upload, stream, the
//! arm in motion), or on the host alone (`--offline`).

use crate::arm::simulate_to;
use anyhow::{bail, Context, Result};
use clap::Args;
use kincal::calib::setup::SolveOptions;
use kincal::calib::summary::RunInputs;
use kincal::data::{Artefact, Observations};
use kincal::model::ArmModel;
use kincal::simulate::SimulationOptions;
use std::path::PathBuf;

#[derive(Args)]
pub struct DemoArgs {
    /// Nominal arm model (default: the SUTA model built into kincal, examples/suta/model.toml).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Folder for the data and the runs (default `runs/demo`, with `--offline` `runs/demo-offline`,
    /// so the two demos never share a folder).
    #[arg(long)]
    out: Option<PathBuf>,
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
    /// Only the arm in motion (no recording, no calibration; the true arm's parameters are
    /// uploaded): it follows a trajectory with direction changes, its pose is served over
    /// OpenIGTLink and validated against a simulated optical tracker (latency, dynamic error).
    /// Without it the whole demo ends with this step.
    #[arg(long, conflicts_with = "offline")]
    motion: bool,
    /// Latency of the simulated optical tracker, ms (optical trackers: 5 to 20).
    #[arg(long, default_value_t = 12.0, value_parser = tracker_latency_ms)]
    tracker_latency_ms: f64,
}

/// `--tracker-latency-ms`: a latency the simulated tracker can have, 0 to 150 ms.
fn tracker_latency_ms(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if (0.0..=150.0).contains(&v) => Ok(v),
        Ok(v) => Err(format!("{v} ms is outside 0 to 150 ms (optical trackers deliver in 5 to 20 ms)")),
        Err(_) => Err(format!("expected a number of milliseconds (e.g. 12), found `{text}`")),
    }
}

impl DemoArgs {
    /// The folder this demo writes.
    fn out(&self) -> PathBuf {
        self.out
            .clone()
            .unwrap_or_else(|| PathBuf::from(if self.offline { "runs/demo-offline" } else { "runs/demo" }))
    }

    /// The nominal model: `--model`, or the built-in SUTA model.
    fn nominal(&self) -> Result<ArmModel> {
        Ok(match &self.model {
            Some(path) => ArmModel::load(path)?,
            None => ArmModel::suta_nominal(),
        })
    }

    /// The nominal model as a file the runs can name: `--model`, or the built-in SUTA model
    /// written to OUT/nominal.toml.
    fn nominal_file(&self) -> Result<PathBuf> {
        if let Some(path) = &self.model {
            return Ok(path.clone());
        }
        let path = self.out().join("nominal.toml");
        std::fs::create_dir_all(self.out()).with_context(|| format!("creating {}", self.out().display()))?;
        ArmModel::suta_nominal().save(&path)?;
        Ok(path)
    }
}

pub fn cmd_demo(a: &DemoArgs) -> Result<()> {
    if a.offline {
        return cmd_demo_offline(a);
    }
    let nominal = a.nominal()?;
    println!("starting the emulated controller on QEMU (mps2-an386): {}", a.firmware.display());
    let (_emulator, mut link) = kincal::controller::emulator::Emulator::start(&a.firmware)?;
    link.hello()?;
    let info = link.info()?;
    println!("connected: {} on {}", info.firmware, info.board);
    if a.motion {
        let truth = kincal::controller::demo::demo_truth(&nominal, a.seed);
        let key = kincal::controller::demo::demo_station_key(&a.out())?;
        kincal::controller::demo::upload_model(&mut link, &truth, &key, None)?;
        println!("uploaded the true arm's parameters (as after a perfect calibration; seed {})", a.seed);
        return demo_motion(a, &mut link, &truth);
    }
    kincal::controller::demo::forget_emulated_uploads(&a.out())?;
    let options = kincal::controller::demo::LoopOptions {
        seed: a.seed,
        window_ticks: a.window_ticks,
        out: a.out(),
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
        a.out().join("run").display(),
        a.out().join("run-added").display()
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
    println!("parameter upload took {:.2} s; run: {}", report.upload_seconds, a.out().join("run").display());
    let certificate =
        kincal::api::certificate(&report.uploaded_run, None, kincal::controller::traceability::unix_now())?;
    let path = kincal::store::certificate::write_certificate(&certificate, None)?;
    println!("certificate of the uploaded RUN: {} ({})", path.display(), certificate.verdict().headline);
    let truth = ArmModel::load(&a.out().join("data").join("truth.toml"))?;
    demo_motion(a, &mut link, &truth)
}

/// The demo's last step: the arm in motion, its pose over OpenIGTLink, latency and dynamic error
/// against a simulated optical tracker, each beside its truth.
fn demo_motion(a: &DemoArgs, link: &mut kincal::controller::link::Link, truth: &ArmModel) -> Result<()> {
    let tracker = kincal::simulate::optical::OpticalOptions {
        latency_ms: a.tracker_latency_ms,
        seed: a.seed,
        ..kincal::simulate::optical::OpticalOptions::default()
    };
    println!("the arm in motion:");
    let r =
        kincal::controller::motion::motion_demo(link, truth, &tracker, &a.out(), &mut |s| println!("  {s}"))?;
    println!(
        "OpenIGTLink: the client received {} transforms of the {} valid poses streamed while it was connected ({} lost), {}; controller link: {} frames lost",
        r.received,
        r.received + r.lost_by_client,
        r.lost_by_client,
        r.received_vs_streamed_um
            .map_or("none matched the host's poses".into(), |u| format!("each within {u:.2} µm of the host's pose")),
        r.stream.lost
    );
    let d = &r.dynamic;
    println!(
        "latency of the tracker behind the arm: {} (true {:.2} ms)",
        d.latency_text(),
        r.tracker.latency_ms
    );
    println!(
        "tracker clock: {:+.2} ± {:.2} ms at its first sample, drift {:+.1} ± {:.1} ppm (true {:+.2} ms, {:+.1} ppm)",
        d.clock_offset_at_start_ms,
        d.clock_offset_at_start_u95_ms,
        d.clock.drift_ppm,
        d.clock.drift_u95_ppm,
        r.tracker.clock_offset_s * 1000.0,
        r.tracker.drift_ppm
    );
    println!("dynamic error after a rigid registration, the tracker's noise ({:.3} mm) removed:", d.noise_mm);
    for row in &r.truth {
        println!(
            "  {:<48} {:>34}   true {:.3} mm{}",
            row.category.label(),
            row.measured.text(),
            row.truth_rms_mm,
            if row.agrees { "" } else { "  (outside the uncertainty)" }
        );
    }
    for f in &d.findings {
        println!("  {f}");
    }
    println!(
        "report: {}; again from the recordings: kincal dynamic --arm {} --tracker {} --out {}",
        r.report_dir.join("report.html").display(),
        r.arm_csv.display(),
        r.tracker_csv.display(),
        r.report_dir.display()
    );
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

pub fn cmd_demo_offline(a: &DemoArgs) -> Result<()> {
    let data = a.out().join("data");
    let hidden = vec![kincal::controller::demo::DEMO_HIDDEN];
    let names: Vec<String> = hidden.iter().map(|(id, d)| format!("{id} = {d:+}")).collect();
    println!(
        "1/3 simulate: a true arm off the nominal model by degrees and millimetres, hiding {}",
        names.join(", ")
    );
    let model = a.nominal_file()?;
    simulate_to(&model, &data, &SimulationOptions { seed: a.seed, hidden, ..SimulationOptions::default() })?;
    println!(
        "2/3 calibrate on {}, validate on {}, diagnose, add",
        data.join("cal").display(),
        data.join("val").display()
    );
    let inputs = RunInputs::new(model, Some(data.join("artefact.json")), data.join("cal"), data.join("val"));
    let mission = kincal::controller::demo::calibrate_diagnose_add(
        &inputs,
        &SolveOptions { seed: a.seed, ..SolveOptions::default() },
        &a.out(),
        &mut |step| println!("  {step}"),
    )?;
    let truth = ArmModel::load(&data.join("truth.toml"))?;
    let artefact = Artefact::load(&data.join("artefact.json"))?;
    let val =
        Observations::load_artefact_dir(&inputs.validation, &artefact, kincal::data::Purpose::Validation)?;
    let floor = kincal::calib::validate::validate(&truth, &val).overall;
    println!("3/3 the steps against the floor");
    print_mission(&mission.steps, floor.rms_mm, &kincal::controller::demo::stop_words(&mission.auto.stop));
    for line in &mission.auto.steps[0].summary {
        println!("  {line}");
    }
    let last = mission.final_run();
    if !last.summary.not_trustworthy.is_empty() {
        bail!("the final calibration is not trustworthy: {}", last.summary.not_trustworthy.join("; "));
    }
    let dir = if mission.last.is_some() { a.out().join("run-added") } else { a.out().join("run") };
    println!(
        "validation RMS  nominal {:.3} mm → as given {:.3} mm → with {} {:.3} mm; noise floor {:.3} mm; run: {}",
        mission.first.summary.nominal_held_out_rms_mm(),
        mission.first.summary.held_out_rms_mm(),
        if mission.added.is_empty() { "nothing".to_string() } else { mission.added.join(" + ") },
        last.summary.held_out_rms_mm(),
        floor.rms_mm,
        dir.display()
    );
    Ok(())
}
