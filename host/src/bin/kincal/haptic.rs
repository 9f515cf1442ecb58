//! Haptic device commands: simulate a recording, calibrate from one.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use kincal::output;
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

pub fn cmd_haptic_calibrate(a: &HapticCalibrateArgs) -> Result<()> {
    let recording = kincal::haptic::recording::load(&a.recording)?;
    let started = std::time::Instant::now();
    let result = kincal::haptic::pipeline::calibrate_recording(&recording)?;
    let seconds = started.elapsed().as_secs_f64();
    let summary = result.summary();
    output::write_haptic(&summary, &a.out, &a.recording)?;
    if a.json {
        println!("{}", output::haptic_json(&summary));
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
