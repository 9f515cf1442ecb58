//! `kincal compare`: two runs side by side.

use super::svg::{self, escape};
use super::{page, table};
use crate::calib::summary::{StoredPairError, Summary, ValidationDetail};
use crate::calib::validate::ErrorStats;
use std::fmt::Write;

/// One side of a comparison: what a RUN folder's typed files hold.
pub struct ComparedRun {
    /// How the run is named on the page (its folder).
    pub name: String,
    /// Its `summary.json`.
    pub summary: Summary,
    /// Its `residuals.json`.
    pub residuals: Vec<StoredPairError>,
}

impl ComparedRun {
    /// The held-out distances' figures (none without artefact placements held out).
    fn distances(&self) -> (ErrorStats, Option<&ValidationDetail>) {
        self.summary
            .validation
            .distances
            .as_ref()
            .map_or((ErrorStats::default(), None), |d| (d.calibrated, Some(&d.detail)))
    }
}

/// Two runs side by side.
pub struct Comparison {
    runs: [ComparedRun; 2],
}

impl Comparison {
    /// Compare `before` with `after`.
    pub fn new(before: ComparedRun, after: ComparedRun) -> Comparison {
        Comparison { runs: [before, after] }
    }

    /// Each run's name and summary.
    pub fn summaries(&self) -> [(&str, &Summary); 2] {
        [0, 1].map(|k| (self.runs[k].name.as_str(), &self.runs[k].summary))
    }

    fn stats(&self, k: usize) -> [(&'static str, f64); 4] {
        let v = self.runs[k].distances().0;
        [("rms_mm", v.rms_mm), ("mean_mm", v.mean_mm), ("std_mm", v.std_mm), ("max_mm", v.max_mm)]
    }

    /// The printed comparison table.
    pub fn table_lines(&self) -> Vec<String> {
        let mut lines = vec![format!("{:<24} {:>12} {:>12}", "validation", "before", "after")];
        for ((key, a), (_, b)) in self.stats(0).into_iter().zip(self.stats(1)) {
            lines.push(format!("{key:<24} {a:>12.4} {b:>12.4}"));
        }
        let effects = |k: usize| self.runs[k].summary.inputs.add.join(", ");
        lines.push(format!("{:<24} {:>12} {:>12}", "added effects", effects(0), effects(1)));
        let figure = |v: f64| if v.is_finite() { format!("{v:.4}") } else { "–".into() };
        for (l, (a, b)) in self.per_landmark() {
            lines.push(format!("  landmark {:<14} {:>12} {:>12}", l, figure(a), figure(b)));
        }
        lines
    }

    /// Per landmark: validation RMS before and after (NaN when the landmark is missing after).
    fn per_landmark(&self) -> Vec<(String, (f64, f64))> {
        let [before, after] = &self.runs;
        let after = after.distances().1.map_or(&[][..], |d| &d.per_landmark);
        before
            .distances()
            .1
            .map_or(&[][..], |d| &d.per_landmark)
            .iter()
            .map(|g| {
                let y = after.iter().find(|h| h.name == g.name).map_or(f64::NAN, |h| h.stats.rms_mm);
                (g.name.clone(), (g.stats.rms_mm, y))
            })
            .collect()
    }

    /// The side-by-side page.
    pub fn html(&self) -> String {
        let mut body = String::new();
        let rows: Vec<Vec<String>> = self
            .stats(0)
            .into_iter()
            .zip(self.stats(1))
            .map(|((k, a), (_, b))| vec![k.to_string(), format!("{a:.4}"), format!("{b:.4}")])
            .collect();
        let _ = write!(
            body,
            "<p>Before: {}<br>After: {}</p>{}",
            escape(&self.runs[0].name),
            escape(&self.runs[1].name),
            table(&["validation", "before", "after"], &rows)
        );
        let lm = self.per_landmark();
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
        let errors = |k: usize| self.runs[k].residuals.iter().map(|e| e.error_mm).collect::<Vec<f64>>();
        let (a, b) = (errors(0), errors(1));
        let _ = write!(
            body,
            "<h3>Distance errors</h3>{}",
            svg::histogram(&[("before", &a), ("after", &b)], 40, "distance error (mm)")
        );
        body.push_str("<h3>Residuals against each joint angle: before (left), after (right)</h3>");
        let joints = self.runs[0].residuals.first().map_or(0, |e| e.enc_deg.0.len());
        for j in 0..joints {
            for k in 0..2 {
                let pts: Vec<(f64, f64)> = self.runs[k]
                    .residuals
                    .iter()
                    .flat_map(|e| [(e.enc_deg.0[j], e.error_mm), (e.enc_deg.1[j], e.error_mm)])
                    .collect();
                let _ = write!(
                    body,
                    "<figure>{}</figure>",
                    svg::scatter(&pts, &[], &format!("encoder {} (deg)", j + 1), "error (mm)")
                );
            }
            body.push_str("<br>");
        }
        page("kincal compare", &body)
    }
}
