//! `kincal compare`: two runs side by side, the held-out test of the second against the first
//! first.

use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::diagnose::compare::Comparison;
use crate::calib::error_stats::ErrorStats;
use crate::calib::summary::{StoredPairError, Summary, ValidationDetail};
use std::fmt::Write;

/// One side of a comparison: what a RUN folder's typed files hold.
pub struct ComparedRun {
    /// How the run is named on the page (its folder).
    pub name: String,
    /// Its `summary.json`.
    pub summary: Summary,
    /// Its `residuals.json` (empty without held-out distances).
    pub residuals: Vec<StoredPairError>,
}

impl ComparedRun {
    /// The held-out distances' figures (none without artefact placements held out).
    fn distances(&self) -> Option<(ErrorStats, &ValidationDetail)> {
        self.summary.validation.distances.as_ref().map(|d| (d.calibrated, &d.detail))
    }

    /// A held-out session's frame-free pairwise-distance RMS, mm.
    fn pairwise_mm(&self, session: &str) -> Option<f64> {
        self.summary
            .held_out_sessions()
            .iter()
            .find(|f| f.calibrated.name == session)
            .map(|f| f.calibrated.pairwise_rms_mm)
    }
}

/// Per landmark: held-out RMS before and after (NaN where the landmark is missing after).
fn per_landmark(runs: &[ComparedRun; 2]) -> Vec<(String, (f64, f64))> {
    let (Some((_, before)), Some((_, after))) = (runs[0].distances(), runs[1].distances()) else {
        return Vec::new();
    };
    before
        .per_landmark
        .iter()
        .map(|g| {
            let y = after.per_landmark.iter().find(|h| h.name == g.name).map_or(f64::NAN, |h| h.stats.rms_mm);
            (g.name.clone(), (g.stats.rms_mm, y))
        })
        .collect()
}

/// The comparison's verdict and the next command.
fn verdict_lines(c: &Comparison, runs: &[ComparedRun; 2]) -> Vec<String> {
    let mut lines = c.verdict.clone();
    lines.push(format!(
        "next: kincal diagnose {} says what the second run still misses",
        crate::files::shell_word(std::path::Path::new(&runs[1].name))
    ));
    lines
}

/// The printed comparison: the verdict, each held-out group, then (held-out distances) the runs'
/// statistics and each landmark.
pub fn compare_lines(c: &Comparison, runs: &[ComparedRun; 2]) -> Vec<String> {
    let figure = |v: Option<f64>| v.filter(|v| v.is_finite()).map_or("–".into(), |v| format!("{v:.4}"));
    let mut lines = verdict_lines(c, runs);
    lines.push(format!(
        "  {:<22} {:>7} {:>12} {:>12} {:>14} {:>14}",
        "held-out group", "errors", "(1) RMS mm", "(2) RMS mm", "(1) pairwise", "(2) pairwise"
    ));
    for g in &c.groups {
        lines.push(format!(
            "  {:<22} {:>7} {:>12.4} {:>12.4} {:>14} {:>14}",
            g.name,
            g.count,
            g.before_rms_mm,
            g.after_rms_mm,
            figure(runs[0].pairwise_mm(&g.name)),
            figure(runs[1].pairwise_mm(&g.name))
        ));
    }
    lines.push(format!(
        "  {:<22} {:>7} {:>12.4} {:>12.4}",
        "all",
        c.groups.iter().map(|g| g.count).sum::<usize>(),
        c.before_rms_mm,
        c.after_rms_mm
    ));
    if let (Some((a, _)), Some((b, _))) = (runs[0].distances(), runs[1].distances()) {
        lines.push(format!("{:<24} {:>12} {:>12}", "validation", "before", "after"));
        for (key, x, y) in [
            ("RMS mm", a.rms_mm, b.rms_mm),
            ("mean mm", a.mean_mm, b.mean_mm),
            ("standard deviation mm", a.std_mm, b.std_mm),
            ("largest mm", a.max_mm, b.max_mm),
        ] {
            lines.push(format!("{key:<24} {x:>12.4} {y:>12.4}"));
        }
    }
    let effects = |k: usize| runs[k].summary.inputs.add.join(", ");
    lines.push(format!("{:<24} {:>12} {:>12}", "added effects", effects(0), effects(1)));
    for (l, (a, b)) in per_landmark(runs) {
        lines.push(format!("  landmark {:<14} {:>12} {:>12}", l, figure(Some(a)), figure(Some(b))));
    }
    lines
}

/// The side-by-side page.
pub fn compare_report(c: &Comparison, runs: &[ComparedRun; 2]) -> String {
    let rows: Vec<Vec<String>> = c
        .groups
        .iter()
        .map(|g| vec![escape(&g.name), g.count.to_string(), mm(g.before_rms_mm), mm(g.after_rms_mm)])
        .collect();
    let bars: Vec<(String, f64, bool)> = c
        .groups
        .iter()
        .flat_map(|g| {
            [
                // Before in orange and after in blue, as in the page's other plots.
                (format!("{} (1)", g.name), g.before_rms_mm, true),
                (format!("{} (2)", g.name), g.after_rms_mm, false),
            ]
        })
        .collect();
    let references: Vec<(&str, f64)> =
        c.floors_mm.1.map(|f| ("floor of the second run", f)).into_iter().collect();
    let mut body = format!(
        "<p>(1) {}<br>(2) {}</p><h2>Verdict</h2><ul>{}</ul><figure>{}<figcaption>held-out RMS per group (each held-out frame refitted)</figcaption></figure>{}",
        escape(&runs[0].name),
        escape(&runs[1].name),
        verdict_lines(c, runs).iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>(),
        svg::hbars(&bars, &references, "held-out RMS (mm)"),
        table(&["held-out group", "errors", "RMS mm (1)", "RMS mm (2)"], &rows)
    );
    let lm = per_landmark(runs);
    if !lm.is_empty() {
        let names: Vec<String> = lm.iter().map(|l| l.0.clone()).collect();
        let _ = write!(
            body,
            "<h3>RMS per landmark</h3>{}",
            svg::bars(
                &names,
                &[
                    ("before", lm.iter().map(|l| l.1 .0).collect()),
                    ("after", lm.iter().map(|l| l.1 .1).collect())
                ],
                "RMS (mm)"
            )
        );
    }
    let errors = |k: usize| runs[k].residuals.iter().map(|e| e.error_mm).collect::<Vec<f64>>();
    let (a, b) = (errors(0), errors(1));
    if !a.is_empty() || !b.is_empty() {
        let _ = write!(
            body,
            "<h3>Distance errors</h3>{}",
            svg::histogram(&[("before", &a), ("after", &b)], 40, "distance error (mm)")
        );
        body.push_str("<h3>Residuals against each joint angle: before (left), after (right)</h3>");
        let joints = runs[0].residuals.first().map_or(0, |e| e.enc_deg.0.len());
        for j in 0..joints {
            let pts: Vec<Vec<(f64, f64)>> = runs
                .iter()
                .map(|run| {
                    run.residuals
                        .iter()
                        .flat_map(|e| [(e.enc_deg.0[j], e.error_mm), (e.enc_deg.1[j], e.error_mm)])
                        .collect()
                })
                .collect();
            // One y axis for before and after, so the fall is seen, not rescaled away.
            let ys: Vec<f64> = pts.iter().flatten().map(|p| p.1).collect();
            let y = svg::robust_range(&ys);
            for run_pts in &pts {
                let _ = write!(
                    body,
                    "<figure>{}</figure>",
                    svg::scatter_on(run_pts, &[], &format!("encoder {} (deg)", j + 1), "error (mm)", y)
                );
            }
            body.push_str("<br>");
        }
    }
    page("kincal compare", &body)
}
