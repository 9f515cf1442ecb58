//! `kincal calibrate` on tracker sessions: run, write RUN/, print the figures and the verdict.

use anyhow::Result;
use kincal::calib::tracker_diagnose::{
    auto_tracker, check_run_data, compare_tracker, diagnose_tracker, fit_setup, TrackerSetup,
};
use kincal::calib::tracker_run::{run_tracker, TrackerInputs, TrackerSummary, TRACKER_RUN_FORMAT};
use kincal::data::Observations;
use kincal::model::ArmModel;
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
        if let Some(b) = &f.same_base {
            let (c, n) = (&b.calibrated, &b.nominal);
            println!(
                "  {:<22} with the base of {} (same placement): RMS {:.4} mm (mean {:.4}, max {:.4}), nominal {:.4} mm{}",
                f.calibrated.name,
                b.calibration_session,
                c.rms_mm,
                c.mean_mm,
                c.max_mm,
                n.rms_mm,
                if c.rms_mm <= n.rms_mm { "" } else { "  does not transfer" }
            );
        }
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
        o.count, o.rms_mm, o.mean_mm, o.max_mm, n.rms_mm
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

/// The summary of RUN when it is a tracker run (`None` for an artefact run).
pub fn tracker_summary(run: &Path) -> Result<Option<TrackerSummary>> {
    let path = run.join("summary.json");
    let Ok(text) = std::fs::read_to_string(&path) else { return Ok(None) };
    let tag = format!("\"format\": \"{TRACKER_RUN_FORMAT}\"");
    if !text.contains(&tag) {
        return Ok(None);
    }
    let summary = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("{}: not a readable tracker run summary: {e}", path.display()))?;
    Ok(Some(summary))
}

/// The setup and data of a tracker RUN, checked to be the data it was made from.
fn load_run(run: &Path, summary: &TrackerSummary) -> Result<(TrackerSetup, Observations, Observations)> {
    let nominal = ArmModel::load(&run.join("nominal.toml"))?;
    let i = &summary.inputs;
    let cal = kincal::data::tracker::load_dir(&i.calibration)?;
    let val = kincal::data::tracker::load_dir(&i.validation)?;
    let setup = TrackerSetup::of(i, nominal);
    let fitted = fit_setup(&setup, &cal, &val, None)?;
    check_run_data(summary, &cal, &val, fitted.fit.rms_mm)?;
    Ok((setup, cal, val))
}

/// `kincal diagnose RUN [--auto]` on a tracker run.
pub fn diagnose_tracker_run(
    run: &Path,
    summary: &TrackerSummary,
    json: bool,
    auto: bool,
    max_steps: usize,
) -> Result<()> {
    let (setup, cal, val) = load_run(run, summary)?;
    if auto {
        let started = std::time::Instant::now();
        let (result, last) = auto_tracker(&setup, &cal, &val, max_steps)?;
        output::write_tracker_auto(&result, run)?;
        if json {
            println!("{}", output::tracker_auto_json(&result));
            return Ok(());
        }
        println!("step  applied                  held-out RMS mm   floor mm  held-out p");
        for (k, s) in result.steps.iter().enumerate() {
            println!(
                "{k:>4}  {:<24} {:>15.4}  {:>9}  {}",
                s.applied.as_deref().unwrap_or("(start)"),
                s.held_out_rms_mm,
                s.floor_mm.map_or("unknown".into(), |f| format!("{f:.4}")),
                s.p_value.map_or("–".into(), |p| format!("{p:.1e}"))
            );
        }
        for line in &result.last.summary {
            println!("{line}");
        }
        println!(
            "stopped: {:?} after {} steps in {:.2} s",
            result.stop,
            result.steps.len() - 1,
            started.elapsed().as_secs_f64()
        );
        let i = &summary.inputs;
        println!(
            "the last step as a run: kincal calibrate --model {} --data {} --validate {} --out RUN2 {}{}",
            i.model.display(),
            i.calibration.display(),
            i.validation.display(),
            last.options_text(),
            i.stated_sigma_mm.map_or(String::new(), |s| format!(" --sigma-mm {s}"))
        );
        println!("report: {}", run.join("auto").join("report.html").display());
        return Ok(());
    }
    let d = diagnose_tracker(&setup, &cal, &val)?;
    output::write_tracker_diagnosis(&d, run)?;
    if json {
        println!("{}", output::tracker_diagnosis_json(&d));
        return Ok(());
    }
    for line in &d.summary {
        println!("{line}");
    }
    let tested = d.candidates.iter().filter(|c| c.cv_gain.is_some()).count();
    println!(
        "\n{} candidate effects refitted, {tested} cross-validated, tested on {} held-out blocks in {:.2} s (test order):",
        d.candidates.len(),
        d.units,
        d.seconds
    );
    let header = format!(
        "  {:<28} {:>10} {:>8} {:>8} {:>9}  significant",
        "candidate", "held-out mm", "blocks", "CV gain", "p"
    );
    let row = |c: &kincal::calib::tracker_diagnose::TrackerCandidate| {
        format!(
            "  {:<28} {:>10.4} {:>8} {:>8} {:>9}  {}",
            c.name,
            c.held_out_rms_mm,
            format!("{}/{}", c.units_improved.0, c.units_improved.1),
            c.cv_gain.map_or("–".into(), |g| format!("{g:+.3}")),
            c.p_value.map_or("–".into(), |p| format!("{p:.1e}")),
            if c.significant { "yes" } else { "no" }
        )
    };
    println!("{header}");
    for c in d.candidates.iter().take(8) {
        println!("{}", row(c));
    }
    if !d.not_identifiable.is_empty() {
        let names: Vec<&str> = d.not_identifiable.iter().map(|n| n.effect.as_str()).collect();
        println!("  not identifiable from these sessions: {}", names.join(", "));
    }
    if !d.data_errors.is_empty() {
        println!("\ndata errors scored beside them:\n{header}");
        for c in &d.data_errors {
            println!("{}", row(c));
        }
    }
    println!("report: {}", run.join("diagnosis.html").display());
    Ok(())
}

/// `kincal compare RUN_A RUN_B` on two tracker runs.
pub fn compare_tracker_runs(a: &Path, b: &Path, out: &Path) -> Result<()> {
    let (Some(sa), Some(sb)) = (tracker_summary(a)?, tracker_summary(b)?) else {
        anyhow::bail!(
            "{} and {}: compare needs two tracker runs or two artefact runs, not one of each",
            a.display(),
            b.display()
        );
    };
    let model = |run: &Path| ArmModel::load(&run.join("model.toml"));
    let (ma, mb) = (model(a)?, model(b)?);
    let val = kincal::data::tracker::load_dir(&sa.inputs.validation)?;
    for f in &sa.validation.sessions {
        match val.find_block(&f.calibrated.name) {
            Some(b) if val.blocks[b].members.len() == f.calibrated.points => {}
            _ => anyhow::bail!(
                "{}: held-out session {} is not as {} used it; the data changed since the calibration",
                sa.inputs.validation.display(),
                f.calibrated.name,
                a.display()
            ),
        }
    }
    let c = compare_tracker((&sa, &ma), (&sb, &mb), &val);
    println!("  held-out session        points   (1) RMS mm   (2) RMS mm   (1) pairwise   (2) pairwise");
    for s in &c.sessions {
        println!(
            "  {:<22} {:>7} {:>12.4} {:>12.4} {:>14.4} {:>14.4}",
            s.name, s.points, s.before_rms_mm, s.after_rms_mm, s.pairwise_rms_mm.0, s.pairwise_rms_mm.1
        );
    }
    println!(
        "  {:<22} {:>7} {:>12.4} {:>12.4}",
        "all",
        c.sessions.iter().map(|s| s.points).sum::<usize>(),
        c.before_rms_mm,
        c.after_rms_mm
    );
    for v in &c.verdict {
        println!("{v}");
    }
    let names = (a.display().to_string(), b.display().to_string());
    let html = kincal::report::tracker_diagnosis::tracker_compare_report(&c, (&names.0, &names.1));
    output::write_page(out, "<title>kincal compare (tracker runs)</title>", &html)?;
    println!("side by side: {}", out.display());
    Ok(())
}
