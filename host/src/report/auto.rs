//! `RUN/auto/report.html`: the held-out error step by step as `diagnose --auto` applies what the
//! diagnosis names.

use super::run::{name_run, shell_word};
use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::diagnose::auto::{AutoLoop, Stop};
use std::fmt::Write;
use std::path::Path;

/// Why the loop stopped, in words (the page's and the CLI's verdict).
pub fn stop_words(stop: &Stop) -> String {
    match stop {
        Stop::AtFloor => "the held-out error is at the floor: the model explains the data".into(),
        Stop::NothingSignificant => {
            "the model is incomplete: a gap to the floor remains (or the floor is unknown) and no \
                                     candidate effect or data error closes it"
                .into()
        }
        Stop::CannotTell => {
            "cannot tell: no candidate is significant, and these data cannot show whether the error is \
                             at the floor"
                .into()
        }
        Stop::DataError(name) => {
            format!("a data error ({name}) explains the residuals as well as any effect: fix the data first")
        }
        Stop::StepLimit => "the step limit was reached before the error came to the floor".into(),
    }
}

/// Why the loop stopped, its last diagnosis and the next command, first on the page.
fn verdict(body: &mut String, run: &AutoLoop, run_dir: &Path) {
    let run_word = shell_word(run_dir);
    let keep = if run.options.is_empty() {
        "next: nothing to add; the run as calibrated is the model to keep".to_string()
    } else {
        format!(
            "next: kincal calibrate with the run's inputs and <code>{}</code> keeps this model (it is also in {}/auto/step-{}.toml)",
            escape(&run.options),
            escape(&run_word),
            run.steps.len().saturating_sub(1)
        )
    };
    let next = match &run.stop {
        Stop::AtFloor => keep,
        Stop::NothingSignificant => format!(
            "next: read {}/diagnosis.html (the apparent joint errors point to an error outside the library), or <code>kincal plan {}</code> for where to measure",
            escape(&run_word),
            escape(&run_word)
        ),
        Stop::CannotTell => "next: measure more held-out placements or sessions, then diagnose again".to_string(),
        Stop::DataError(_) => {
            format!("next: fix the data first, then <code>kincal diagnose {} --auto</code> again", escape(&run_word))
        }
        Stop::StepLimit => {
            format!("next: <code>kincal diagnose {} --auto --max-steps N</code> with a larger N", escape(&run_word))
        }
    };
    let why = escape(&stop_words(&run.stop));
    let _ = write!(
        body,
        "<h2>Verdict</h2><ul><li>{why}</li>{}<li>{next}</li></ul>",
        run.last
            .summary
            .iter()
            .map(|l| format!("<li>{}</li>", escape(&name_run(l, run_dir))))
            .collect::<String>()
    );
}

/// The "watch the error fall" page: held-out RMS and what a complete model leaves per step, and
/// each step's evidence.
pub fn auto_report(run: &AutoLoop, run_dir: &Path) -> String {
    let mut body = String::new();
    verdict(&mut body, run, run_dir);
    let labels: Vec<String> = run
        .steps
        .iter()
        .enumerate()
        .map(|(k, s)| format!("{k}: {}", s.applied.as_deref().unwrap_or("start")))
        .collect();
    let measured: Vec<f64> = run.steps.iter().map(|s| s.held_out_rms_mm).collect();
    let expected: Vec<f64> = run.steps.iter().map(|s| s.expected_rms_mm.unwrap_or(0.0)).collect();
    let _ = write!(
        body,
        "<h2>Held-out error by step</h2><figure>{}<figcaption>held-out RMS after each step, beside what a complete model leaves (0 where the floor is unknown)</figcaption></figure>",
        svg::bars(&labels, &[("held-out RMS", measured), ("what a complete model leaves", expected)], "RMS (mm)")
    );
    let rows: Vec<Vec<String>> = run
        .steps
        .iter()
        .enumerate()
        .map(|(k, s)| {
            vec![
                k.to_string(),
                escape(s.applied.as_deref().unwrap_or("(the run as calibrated)")),
                format!("<code>{}</code>", escape(s.action.as_deref().unwrap_or(""))),
                mm(s.held_out_rms_mm),
                s.expected_rms_mm.map_or("–".into(), mm),
                s.floor_mm.map_or("unknown".into(), mm),
                s.p_value.map_or("–".into(), |p| format!("{p:.1e}")),
                escape(s.evidence.as_deref().unwrap_or("")),
            ]
        })
        .collect();
    let _ = write!(
        body,
        "{}",
        table(
            &[
                "step",
                "applied",
                "option",
                "held-out RMS mm",
                "expected mm",
                "floor mm",
                "held-out p",
                "evidence"
            ],
            &rows
        )
    );
    page("kincal diagnose --auto", &body)
}
