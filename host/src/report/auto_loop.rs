//! `RUN/auto/report.html`: the validation error step by step as `diagnose --auto` adds effects.

use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::auto::{AutoLoop, Stop};
use std::fmt::Write;

/// The "watch the error fall" page: validation RMS and the expected floor per step, and each
/// step's evidence.
pub fn auto_loop_report(run: &AutoLoop) -> String {
    let mut body = String::new();
    let labels: Vec<String> = run
        .steps
        .iter()
        .enumerate()
        .map(|(k, s)| format!("{k}: {}", s.added.as_deref().unwrap_or("start")))
        .collect();
    let measured: Vec<f64> = run.steps.iter().map(|s| s.validation_rms_mm).collect();
    let expected: Vec<f64> = run.steps.iter().map(|s| s.expected_rms_mm.unwrap_or(0.0)).collect();
    let _ = write!(
        body,
        "<h2>Validation error by step</h2><figure>{}<figcaption>validation RMS after each added effect, beside the error expected from repeatability (0 where unknown)</figcaption></figure>",
        svg::bars(&labels, &[("validation RMS", measured), ("expected from repeatability", expected)], "RMS (mm)")
    );
    let rows: Vec<Vec<String>> = run
        .steps
        .iter()
        .enumerate()
        .map(|(k, s)| {
            vec![
                k.to_string(),
                escape(s.added.as_deref().unwrap_or("(calibrated input model)")),
                mm(s.validation_rms_mm),
                s.expected_rms_mm.map_or("–".into(), mm),
                s.p_value.map_or("–".into(), |p| format!("{p:.1e}")),
                escape(s.evidence.as_deref().unwrap_or("")),
            ]
        })
        .collect();
    let _ = write!(
        body,
        "{}",
        table(&["step", "added", "val RMS mm", "expected mm", "held-out p", "evidence"], &rows)
    );
    let why = match &run.stop {
        Stop::AtFloor => "the validation error is at the floor expected from repeatability".to_string(),
        Stop::NothingSignificant => {
            "no candidate is significant although a gap remains: the model is incomplete".to_string()
        }
        Stop::CannotTell => "no candidate is significant, and whether the error is at the floor cannot be told from these data (more validation placements would tell)".to_string(),
        Stop::DataError(name) => {
            format!("a data error ({name}) explains the residuals as well: fix the data first")
        }
        Stop::StepLimit => "the step limit was reached".to_string(),
    };
    let _ = write!(
        body,
        "<h2>Stopped</h2><p>{}</p><ul>{}</ul>",
        escape(&why),
        run.last.summary.iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>()
    );
    page("kincal diagnose --auto", &body)
}
