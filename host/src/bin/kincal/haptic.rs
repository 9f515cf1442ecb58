//! Haptic device commands: simulate a recording, calibrate from one.

use anyhow::Result;
use clap::{Args, Subcommand};
use kincal::store;
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum HapticCommand {
    /// Write a simulated recording (device, tracker, delay, sensor errors) with known truth.
    Simulate(HapticSimulateArgs),
    /// Calibrate from a recording folder: delay, position, orientation.
    Calibrate(HapticCalibrateArgs),
}

#[derive(Args)]
pub struct HapticSimulateArgs {
    /// Output recording folder.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the noise.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    seed: u64,
    /// Tracker delay behind the device, ms.
    #[arg(long, default_value_t = 13.0, allow_negative_numbers = true, value_parser = crate::args::real(0.0, 200.0, "ms"))]
    delay_ms: f64,
    /// Linear gimbal sensors instead of potentiometer-like quadratic ones.
    #[arg(long)]
    linear_gimbals: bool,
    /// Seconds of free motion in joints/.
    #[arg(long, default_value_t = 60.0, allow_negative_numbers = true, value_parser = crate::args::real(1.0, 600.0, "s"))]
    joints_seconds: f64,
    /// Height of landmark target T2 above the central joint, mm (negative: below, 0: beside).
    #[arg(long, default_value_t = 50.0, allow_negative_numbers = true, value_parser = crate::args::real(-300.0, 300.0, "mm"))]
    t2_height_mm: f64,
}

#[derive(Args)]
pub struct HapticCalibrateArgs {
    /// Recording folder (haptic-recording/1).
    recording: PathBuf,
    /// Output folder: summary.json, report.html.
    #[arg(long)]
    out: PathBuf,
    /// Print summary.json.
    #[arg(long)]
    json: bool,
}

pub fn cmd_haptic_simulate(a: &HapticSimulateArgs) -> Result<()> {
    let options = kincal::haptic::simulate::HapticSimOptions {
        seed: a.seed,
        delay_ms: a.delay_ms,
        quadratic_gimbals: !a.linear_gimbals,
        joints_seconds: a.joints_seconds,
        t2_height_mm: a.t2_height_mm,
        ..Default::default()
    };
    let (recording, _) = kincal::haptic::simulate::simulate_recording(&options);
    store::write_haptic_recording(&recording, &a.out)?;
    println!(
        "simulated recording (delay {} ms, {} gimbals) in {}",
        a.delay_ms,
        if a.linear_gimbals { "linear" } else { "quadratic" },
        a.out.display()
    );
    Ok(())
}

pub fn cmd_haptic_calibrate(a: &HapticCalibrateArgs) -> Result<()> {
    use kincal::haptic::pipeline::{calibrate_recording, HapticFailure, HapticSummary};
    let write = |summary: &HapticSummary| -> Result<String> {
        store::write_haptic(summary, &a.out, &a.recording)?;
        Ok(store::haptic_json(summary))
    };
    let recording = match kincal::haptic::recording::load(&a.recording) {
        Ok(r) => r,
        Err(e) => {
            write(&HapticFailure::unreadable(&e))?;
            return Err(e.into());
        }
    };
    let started = std::time::Instant::now();
    let result = match calibrate_recording(&recording) {
        Ok(r) => r,
        Err(failure) => {
            let json = write(&failure.summary())?;
            if a.json {
                println!("{json}");
            }
            if let Some(p) = &failure.partial {
                eprintln!(
                    "not a calibration: position {:.3} → {:.3} mm, orientation {:.3} → {:.3}° on {} held-out samples",
                    p.position_mm.before, p.position_mm.after, p.orientation_deg.before, p.orientation_deg.after, p.held_out
                );
            }
            return Err(anyhow::anyhow!(
                "{failure}\nsummary (marked failed): {}",
                a.out.join("summary.json").display()
            ));
        }
    };
    let seconds = started.elapsed().as_secs_f64();
    let json = write(&result.summary())?;
    if a.json {
        println!("{json}");
        return Ok(());
    }
    println!("calibrated in {seconds:.2} s");
    for line in kincal::report::haptic::verdict_lines(&result, &a.out) {
        println!("  {line}");
    }
    println!("  delay        {:8.2} ms (tracker behind device)", result.delay_ms);
    println!(
        "  position     {:8.3} mm → {:.3} mm (RMS, {} held-out samples)",
        result.position_mm.before, result.position_mm.after, result.held_out
    );
    println!(
        "  orientation  {:8.3} °  → {:.3} °",
        result.orientation_deg.before, result.orientation_deg.after
    );
    println!("  gimbals      {} sensor model (chosen on held-out error)", result.gimbal_model.words());
    println!(
        "  start        {} (held-out joint residual: landmark {}, pose-based {:.3} mm)",
        result.start.chosen,
        result.start.landmark_mm.map_or("—".to_string(), |v| format!("{v:.3} mm")),
        result.start.pose_mm
    );
    if result.rejected_samples > 0 || result.tracker_gaps > 0 {
        println!(
            "  tracker      {} wild samples rejected, {} occlusion gaps",
            result.rejected_samples, result.tracker_gaps
        );
    }
    println!("  report: {}", a.out.join("report.html").display());
    Ok(())
}
