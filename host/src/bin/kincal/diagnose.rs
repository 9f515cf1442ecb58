//! `kincal diagnose RUN [--auto]` and `kincal compare RUN_A RUN_B`: one path for every kind of
//! data; the library ([`kincal::api`]) picks what the RUN's data call for, this prints it.

use anyhow::Result;
use clap::Args;
use kincal::api::{self, Auto, Comparison, Diagnosis, RunFolder};
use kincal::calib::auto::AutoLoop;
use kincal::calib::tracker_diagnose::{
    TrackerAuto, TrackerCandidate, TrackerComparison, TrackerDiagnosis, TrackerSetup,
};
use kincal::store;
use std::path::PathBuf;

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

pub fn cmd_diagnose(a: &DiagnoseArgs) -> Result<()> {
    let folder = api::load(&a.run)?;
    for problem in &folder.summary.not_trustworthy {
        eprintln!("warning: this run is marked not trustworthy: {problem}");
    }
    let started = std::time::Instant::now();
    if a.auto {
        match api::auto(&folder, a.max_steps)? {
            Auto::Distances(run) => print_auto(a, &run, started.elapsed().as_secs_f64())?,
            Auto::Sessions(run) => print_tracker_auto(a, &folder, &run.0, &run.1, started)?,
        }
        return Ok(());
    }
    let spinner = crate::arm::spinner("diagnosing");
    let diagnosis = api::diagnose(&folder);
    spinner.finish_and_clear();
    match diagnosis? {
        Diagnosis::Distances(d) => {
            store::write_diagnosis(&d, &a.run)?;
            if a.json {
                println!("{}", store::diagnosis_json(&d));
                return Ok(());
            }
            print_distances(&d, started.elapsed().as_secs_f64());
        }
        Diagnosis::Sessions(d) => {
            store::write_tracker_diagnosis(&d, &a.run)?;
            if a.json {
                println!("{}", store::tracker_diagnosis_json(&d));
                return Ok(());
            }
            print_sessions(&d);
        }
    }
    println!("report: {}", a.run.join("diagnosis.html").display());
    Ok(())
}

/// The diagnosis of held-out distances.
fn print_distances(diagnosis: &kincal::calib::diagnose::Diagnosis, elapsed: f64) {
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
}

/// The diagnosis of held-out tracker sessions.
fn print_sessions(d: &TrackerDiagnosis) {
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
    let row = |c: &TrackerCandidate| {
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
}

/// The loop on held-out distances.
fn print_auto(a: &DiagnoseArgs, run: &AutoLoop, elapsed: f64) -> Result<()> {
    store::write_auto(run, &a.run)?;
    let dir = a.run.join("auto");
    if a.json {
        println!("{}", store::auto_json(run));
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

/// The loop on held-out tracker sessions.
fn print_tracker_auto(
    a: &DiagnoseArgs,
    folder: &RunFolder,
    result: &TrackerAuto,
    last: &TrackerSetup,
    started: std::time::Instant,
) -> Result<()> {
    store::write_tracker_auto(result, &a.run)?;
    if a.json {
        println!("{}", store::tracker_auto_json(result));
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
    let i = &folder.summary.inputs;
    println!(
        "the last step as a run: kincal calibrate --model {} --data {} --validate {} --out RUN2 {}{}",
        i.model.display(),
        i.calibration.display(),
        i.validation.display(),
        last.options_text(),
        i.stated_sigma_mm.map_or(String::new(), |s| format!(" --sigma-mm {s}"))
    );
    println!("report: {}", a.run.join("auto").join("report.html").display());
    Ok(())
}

pub fn cmd_compare(a: &CompareArgs) -> Result<()> {
    match api::compare(&a.before, &a.after)? {
        Comparison::Distances(comparison) => {
            for (name, summary) in comparison.summaries() {
                for problem in &summary.not_trustworthy {
                    eprintln!("warning: {name} is marked not trustworthy: {problem}");
                }
            }
            for line in comparison.table_lines() {
                println!("{line}");
            }
            store::write_page(&a.out, "<title>kincal compare</title>", &comparison.html())?;
        }
        Comparison::Sessions(c) => {
            print_compared_sessions(&c);
            let names = (a.before.display().to_string(), a.after.display().to_string());
            let html = kincal::report::tracker_diagnosis::tracker_compare_report(&c, (&names.0, &names.1));
            store::write_page(&a.out, "<title>kincal compare (tracker runs)</title>", &html)?;
        }
    }
    println!("side by side: {}", a.out.display());
    Ok(())
}

/// Two tracker runs' held-out sessions side by side.
fn print_compared_sessions(c: &TrackerComparison) {
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
}
