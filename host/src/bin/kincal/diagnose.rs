//! `kincal diagnose RUN [--auto]` and `kincal compare RUN_A RUN_B`: one path for every kind of
//! held-out data; the library ([`kincal::api`]) diagnoses, this prints it.

use anyhow::Result;
use clap::Args;
use kincal::api::{self, RunFolder};
use kincal::calib::diagnose::auto::AutoLoop;
use kincal::calib::diagnose::{Candidate, Diagnosis, Measure};
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
        let run = api::auto(&folder, a.max_steps)?;
        return print_auto(a, &folder, &run, started.elapsed().as_secs_f64());
    }
    let spinner = crate::progress::spinner("diagnosing");
    let diagnosis = api::diagnose(&folder);
    spinner.finish_and_clear();
    let d = diagnosis?;
    store::write_diagnosis(&d, &a.run, Some(&folder.summary.inputs))?;
    if a.json {
        println!("{}", store::diagnosis_json(&d));
        return Ok(());
    }
    print_diagnosis(&d, &a.run, &folder.summary.inputs);
    println!("report: {}", a.run.join("diagnosis.html").display());
    Ok(())
}

/// The held-out units' word in tables.
fn units_word(measure: Measure) -> &'static str {
    match measure {
        Measure::Distances => "placements",
        Measure::Points => "blocks",
    }
}

/// A candidate's row: name, held-out RMS, share explained, units improved, significant.
fn row(c: &Candidate) -> String {
    let units = format!("{}/{}", c.units_improved.0, c.units_improved.1);
    format!(
        "  {:<16} {:>10.3} {:>9.2} {:>10}  {}",
        c.name,
        c.held_out_rms_mm,
        c.explained,
        units,
        if c.significant { "yes" } else { "no" }
    )
}

/// The diagnosis: the summary, then the candidates and data errors best first.
fn print_diagnosis(d: &Diagnosis, run: &std::path::Path, inputs: &kincal::calib::summary::RunInputs) {
    for line in kincal::report::diagnosis::summary_lines(d, run, Some(inputs)) {
        println!("{line}");
    }
    println!(
        "\n{} candidate effects scored in {:.2} s (held-out validation RMS, best first):",
        d.candidates.len(),
        d.seconds
    );
    println!(
        "  {:<16} {:>10} {:>9} {:>10}  significant",
        "effect",
        "val RMS mm",
        "explained",
        units_word(d.measure)
    );
    for c in d.candidates.iter().filter(|c| c.equivalent_to.is_none()).take(8) {
        let same = if c.equivalent.is_empty() {
            String::new()
        } else {
            format!("  (indistinguishable here: {})", c.equivalent.join(", "))
        };
        println!("{}{same}", row(c));
    }
    if !d.not_identifiable.is_empty() {
        let names: Vec<&str> = d.not_identifiable.iter().map(|n| n.effect.as_str()).collect();
        println!("  not identifiable from these data: {}", names.join(", "));
    }
    if !d.data_errors.is_empty() {
        println!("\ndata errors scored beside them (best first):");
        for c in d.data_errors.iter().take(4) {
            println!("{}", row(c));
        }
    }
}

/// The loop: each step, the last diagnosis, why it stopped and the last step as a run.
fn print_auto(a: &DiagnoseArgs, folder: &RunFolder, run: &AutoLoop, elapsed: f64) -> Result<()> {
    store::write_auto(run, &a.run)?;
    let dir = a.run.join("auto");
    if a.json {
        println!("{}", store::auto_json(run));
        return Ok(());
    }
    println!(
        "stopped after {} steps in {elapsed:.2} s: {}",
        run.steps.len() - 1,
        kincal::report::auto::stop_words(&run.stop)
    );
    println!("step  added              val RMS mm  expected mm  held-out p");
    for (k, s) in run.steps.iter().enumerate() {
        println!(
            "{k:>4}  {:<18} {:>10.3}  {:>11}  {}",
            s.applied.as_deref().unwrap_or("(start)"),
            s.held_out_rms_mm,
            s.expected_rms_mm.map_or("–".into(), |e| format!("{e:.3}")),
            s.p_value.map_or("–".into(), |p| format!("{p:.1e}"))
        );
    }
    for line in &run.last.summary {
        println!("{}", kincal::report::run::name_run(line, &a.run));
    }
    println!(
        "the last step as a run: {}",
        folder.summary.inputs.with_changes(&run.setup).calibrate_command("RUN2")
    );
    println!(
        "models: {}/step-0.toml … step-{}.toml; report: {}",
        dir.display(),
        run.steps.len() - 1,
        dir.join("report.html").display()
    );
    Ok(())
}

pub fn cmd_compare(a: &CompareArgs) -> Result<()> {
    let compared = api::compare(&a.before, &a.after)?;
    for run in &compared.runs {
        for problem in &run.summary.not_trustworthy {
            eprintln!("warning: {} is marked not trustworthy: {problem}", run.name);
        }
    }
    for line in kincal::report::compare::compare_lines(&compared.comparison, &compared.runs) {
        println!("{line}");
    }
    let html = kincal::report::compare::compare_report(&compared.comparison, &compared.runs);
    store::write_page(&a.out, "<title>kincal compare</title>", &html)?;
    println!("side by side: {}", a.out.display());
    Ok(())
}
