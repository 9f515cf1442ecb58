//! The pages of the loop on tracker runs: `RUN/diagnosis.html`, `RUN/auto/report.html` and the
//! side-by-side page of `kincal compare` (the plots and tables of the artefact pages, on the
//! figures of [`crate::calib::tracker_diagnose`]).

use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::tracker_diagnose::{
    TrackerAuto, TrackerCandidate, TrackerComparison, TrackerDiagnosis, TrackerStop,
};
use std::fmt::Write;

fn list(lines: &[String]) -> String {
    format!("<ul>{}</ul>", lines.iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>())
}

fn candidate_rows(candidates: &[TrackerCandidate]) -> Vec<Vec<String>> {
    candidates
        .iter()
        .map(|c| {
            vec![
                escape(&c.name),
                mm(c.held_out_rms_mm),
                format!("{}/{}", c.units_improved.0, c.units_improved.1),
                c.cv_gain.map_or("–".into(), |g| format!("{g:+.3}")),
                format!("{:.1}", c.calibration_z),
                c.p_value.map_or("not tested".into(), |p| format!("{p:.1e}")),
                if c.significant { "<span class=\"flag\">yes</span>".into() } else { "no".into() },
                format!("<code>{}</code>", escape(&c.action)),
            ]
        })
        .collect()
}

const CANDIDATE_HEADER: [&str; 8] = [
    "candidate",
    "held-out RMS mm",
    "blocks improved",
    "CV gain",
    "calibration z",
    "held-out p",
    "significant",
    "apply with",
];

/// The diagnosis page of a tracker run: the gap to the floor and what closes it, then the tables.
pub fn tracker_diagnosis_report(d: &TrackerDiagnosis) -> String {
    let mut body = format!("<h2>Summary</h2>{}", list(&d.summary));
    let mut bars: Vec<(String, f64, bool)> = vec![("now (as calibrated)".into(), d.held_out_rms_mm, false)];
    bars.extend(
        d.candidates.iter().take(8).map(|c| (format!("+ {}", c.name), c.held_out_rms_mm, c.significant)),
    );
    bars.extend(
        d.data_errors.iter().take(4).map(|c| (format!("data: {}", c.name), c.held_out_rms_mm, c.significant)),
    );
    let mut references: Vec<(&str, f64)> = Vec::new();
    if let Some(f) = d.floor.rms_mm {
        references.push(("the floor", f));
    }
    let largest_bound = d.neighbours.iter().map(|n| n.bound_mm).fold(f64::NAN, f64::max);
    if largest_bound.is_finite() {
        references.push((
            "largest neighbour bound of a held-out session (noise + small-scale error, at most)",
            largest_bound,
        ));
    }
    let _ = write!(
        body,
        "<h2>The gap to the floor, and what closes it</h2><figure>{}<figcaption>held-out RMS (each held-out base refitted) now and with each candidate effect or data error (in the order of the test; orange = significant), against the floor ({}) and the neighbour bound (dashed)</figcaption></figure>",
        svg::hbars(&bars, &references, "held-out RMS (mm)"),
        escape(&d.floor.source)
    );
    let sessions: Vec<Vec<String>> =
        d.sessions.iter().map(|(n, p, r)| vec![escape(n), p.to_string(), mm(*r)]).collect();
    let _ = write!(body, "<h2>Held-out sessions</h2>{}", table(&["session", "points", "RMS mm"], &sessions));
    let _ = write!(
        body,
        "<h2>Candidate effects</h2><p>Tested in a fixed sequence (cross-validated on the calibration sessions, best CV gain first), each on {} contiguous pose blocks of the held-out sessions; the sequence stops at the first that fails.</p>{}",
        d.units,
        table(&CANDIDATE_HEADER, &candidate_rows(&d.candidates))
    );
    if d.data_errors.is_empty() {
        body.push_str(
            "<h2>Data errors</h2><p>None could be scored: a tool moved in a calibration session needs \
             another calibration session that turns the tool, a drift needs <code>time_s</code> or \
             <code>temp_C</code> spanning a minute or 0.5 K, and no point lies beyond 5 × the median \
             error.</p>",
        );
    } else {
        let _ =
            write!(body, "<h2>Data errors</h2>{}", table(&CANDIDATE_HEADER, &candidate_rows(&d.data_errors)));
    }
    if !d.held_out_tools.is_empty() {
        let rows: Vec<Vec<String>> = d
            .held_out_tools
            .iter()
            .map(|t| {
                vec![
                    escape(&t.session),
                    escape(&t.text),
                    if t.significant { "yes".into() } else { "no".into() },
                ]
            })
            .collect();
        let _ = write!(
            body,
            "<h3>Tool moved in a held-out session</h3>{}",
            table(&["session", "finding", "called"], &rows)
        );
    }
    if !d.not_identifiable.is_empty() {
        let rows: Vec<Vec<String>> =
            d.not_identifiable.iter().map(|n| vec![escape(&n.effect), escape(&n.reason)]).collect();
        let _ =
            write!(body, "<h2>Not identifiable from these sessions</h2>{}", table(&["effect", "why"], &rows));
    }
    page("kincal diagnose (tracker run)", &body)
}

/// The auto loop's page: held-out RMS step by step against the floor.
pub fn tracker_auto_report(run: &TrackerAuto) -> String {
    let labels: Vec<String> = run
        .steps
        .iter()
        .enumerate()
        .map(|(k, s)| format!("{k}: {}", s.applied.as_deref().unwrap_or("start")))
        .collect();
    let measured: Vec<f64> = run.steps.iter().map(|s| s.held_out_rms_mm).collect();
    let floor: Vec<f64> = run.steps.iter().map(|s| s.floor_mm.unwrap_or(0.0)).collect();
    let mut body = format!(
        "<h2>Held-out error by step</h2><figure>{}<figcaption>held-out RMS after each step, beside the floor (0 where unknown)</figcaption></figure>",
        svg::bars(&labels, &[("held-out RMS", measured), ("floor", floor)], "RMS (mm)")
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
                s.floor_mm.map_or("unknown".into(), mm),
                s.p_value.map_or("–".into(), |p| format!("{p:.1e}")),
            ]
        })
        .collect();
    let _ = write!(
        body,
        "{}",
        table(&["step", "applied", "option", "held-out RMS mm", "floor mm", "held-out p"], &rows)
    );
    let why = match run.stop {
        TrackerStop::AtFloor => "the held-out error is at the floor",
        TrackerStop::NothingSignificant => "no candidate is significant",
        TrackerStop::MaxSteps => "the step limit was reached",
    };
    let _ = write!(
        body,
        "<h2>Stopped: {}</h2><p>options of the last step: <code>{}</code></p>{}",
        escape(why),
        escape(&run.options),
        list(&run.last.summary)
    );
    page("kincal diagnose --auto (tracker run)", &body)
}

/// Two tracker runs side by side on their shared held-out sessions.
pub fn tracker_compare_report(c: &TrackerComparison, names: (&str, &str)) -> String {
    let rows: Vec<Vec<String>> = c
        .sessions
        .iter()
        .map(|s| {
            vec![
                escape(&s.name),
                s.points.to_string(),
                mm(s.before_rms_mm),
                mm(s.after_rms_mm),
                mm(s.pairwise_rms_mm.0),
                mm(s.pairwise_rms_mm.1),
            ]
        })
        .collect();
    let bars: Vec<(String, f64, bool)> = c
        .sessions
        .iter()
        .flat_map(|s| {
            [
                (format!("{} (1)", s.name), s.before_rms_mm, false),
                (format!("{} (2)", s.name), s.after_rms_mm, true),
            ]
        })
        .collect();
    let references: Vec<(&str, f64)> =
        c.floors_mm.1.map(|f| ("floor of the second run", f)).into_iter().collect();
    let body = format!(
        "<p>(1) {}<br>(2) {}</p><h2>Verdict</h2>{}<figure>{}<figcaption>held-out RMS per session, each base refitted</figcaption></figure>{}",
        escape(names.0),
        escape(names.1),
        list(&c.verdict),
        svg::hbars(&bars, &references, "held-out RMS (mm)"),
        table(&["held-out session", "points", "RMS mm (1)", "RMS mm (2)", "pairwise mm (1)", "pairwise mm (2)"], &rows)
    );
    page("kincal compare (tracker runs)", &body)
}
