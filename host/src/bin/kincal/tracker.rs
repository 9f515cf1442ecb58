//! `kincal calibrate` on tracker sessions: run, write RUN/, print the figures and the verdict.

use anyhow::Result;
use kincal::calib::tracker_run::{run_tracker, TrackerInputs};
use kincal::output;
use std::path::Path;

/// Calibrate on tracker sessions, validate on held-out ones, write RUN/ and print.
pub fn calibrate_tracker_and_report(inputs: &TrackerInputs, out: &Path, json: bool) -> Result<()> {
    let started = std::time::Instant::now();
    let run = run_tracker(inputs, None)?;
    let elapsed = started.elapsed().as_secs_f64();
    output::write_tracker_run(&run, out)?;
    let s = &run.summary;
    if json {
        println!("{}", serde_json::to_string_pretty(s)?);
        return Ok(());
    }
    for w in &s.warnings {
        println!("warning: {w}");
    }
    let points: usize = s.calibration_sessions.values().sum();
    println!(
        "calibrated {} joints on {points} tracker points in {} sessions in {elapsed:.2} s",
        s.joints,
        s.calibration_sessions.len()
    );
    println!("  calibration RMS {:.4} mm (mean {:.4}, max {:.4})", s.fit.rms_mm, s.fit.mean_mm, s.fit.max_mm);
    if let (Some(o), Some(t)) = (&s.orientation_fit, &s.tool_rotation) {
        let [x, y, z] = t.rotation_vector_deg;
        println!(
            "  calibration orientation RMS {:.5}° (mean {:.5}, max {:.5}) on {} probe orientations",
            o.rms_deg, o.mean_deg, o.max_deg, o.orientations
        );
        let std = t
            .std_deg
            .map_or("no deviation: singular".into(), |[a, b, c]| format!("± {a:.5}, {b:.5}, {c:.5}°"));
        println!("  probe on the flange: rotation vector ({x:.4}, {y:.4}, {z:.4})° {std}");
    }
    println!("  estimated: {}", s.identifiability.estimated.join(", "));
    for t in &s.identifiability.statements {
        println!("  {t}");
    }
    for t in &s.tool_offsets {
        let [x, y, z] = t.offset_mm;
        println!("  tool floating in {}: ({x:.3}, {y:.3}, {z:.3}) mm ± {:.3}", t.session, t.size_std_mm);
    }
    for d in &s.drifts {
        let rate: Vec<String> = d.rate.iter().map(|v| format!("{v:.4}")).collect();
        println!(
            "  {} drifting ({}): ({}) {} ± {:.4}",
            d.session,
            d.kind.name(),
            rate.join(", "),
            d.unit,
            d.rate_std
        );
    }
    println!("  held-out session        points   RMS mm  mean mm   max mm  pairwise mm   nominal RMS mm");
    for f in &s.validation.sessions {
        let v = &f.calibrated;
        println!(
            "  {:<22} {:>7} {:>8.4} {:>8.4} {:>8.4} {:>12.4} {:>16.4}{}",
            v.name,
            v.points,
            v.rms_mm,
            v.mean_mm,
            v.max_mm,
            v.pairwise_rms_mm,
            f.nominal.rms_mm,
            if f.transfers { "" } else { "  does not transfer" }
        );
    }
    for f in &s.validation.sessions {
        if let (Some(c), Some(n)) = (&f.orientation, &f.nominal_orientation) {
            println!(
                "  {:<22} orientation RMS {:.5}° (mean {:.5}, max {:.5}), nominal {:.5}°",
                f.calibrated.name, c.rms_deg, c.mean_deg, c.max_deg, n.rms_deg
            );
        }
    }
    let (o, n) = (&s.validation.overall, &s.validation.nominal_overall);
    println!(
        "  held out, all sessions   {:>6} {:>8.4} {:>8.4} {:>8.4} {:>29.4}",
        o.points, o.rms_mm, o.mean_mm, o.max_mm, n.rms_mm
    );
    match s.floor.rms_mm {
        Some(f) => println!("  floor {f:.4} mm ({})", s.floor.source),
        None => println!("  floor unknown"),
    }
    for v in &s.verdict {
        println!("  {v}");
    }
    println!("  written: {}", out.join("summary.json").display());
    Ok(())
}

/// Refuse a tracker RUN for a command that reads artefact runs only, saying where its results are.
pub fn refuse_tracker_run(run: &Path, command: &str) -> Result<()> {
    let summary = std::fs::read_to_string(run.join("summary.json")).unwrap_or_default();
    let tag = format!("\"format\": \"{}\"", kincal::calib::tracker_run::TRACKER_RUN_FORMAT);
    if summary.contains(&tag) {
        anyhow::bail!(
            "{}: a tracker run; `kincal {command}` reads artefact runs only so far. Its held-out figures, \
             floor, data errors (with the option that applies each) and verdict are in summary.json",
            run.display()
        );
    }
    Ok(())
}
