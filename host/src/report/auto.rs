//! `RUN/auto/report.html`: the held-out error step by step as `diagnose --auto` applies what the
//! diagnosis names.

use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::diagnose::auto::{AutoLoop, Stop};
use std::fmt::Write;

/// The "watch the error fall" page: held-out RMS and what a complete model leaves per step, and
/// each step's evidence.
pub fn auto_report(run: &AutoLoop) -> String {
    let mut body = String::new();
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
    let why = match &run.stop {
        Stop::AtFloor => "the held-out error is at the floor".to_string(),
        Stop::NothingSignificant => {
            "no candidate is significant although a gap remains (or the floor is unknown): the model is incomplete".to_string()
        }
        Stop::CannotTell => "no candidate is significant, and whether the error is at the floor cannot be told from these data (more held-out data would tell)".to_string(),
        Stop::DataError(name) => format!("a data error ({name}) explains the residuals as well: fix the data first"),
        Stop::StepLimit => "the step limit was reached".to_string(),
    };
    let _ = write!(
        body,
        "<h2>Stopped</h2><p>{}</p><p>options of the last step: <code>{}</code></p><ul>{}</ul>",
        escape(&why),
        escape(&run.options),
        run.last.summary.iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>()
    );
    page("kincal diagnose --auto", &body)
}
