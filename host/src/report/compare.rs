//! `kincal compare`: two runs side by side.

use super::svg::{self, escape};
use super::{page, table};
use std::fmt::Write;

/// Two runs side by side, read from their RUN folders.
pub struct Comparison {
    names: [String; 2],
    summaries: [serde_json::Value; 2],
    residuals: [Vec<crate::calib::run::StoredPairError>; 2],
}

/// Why two runs could not be compared.
#[derive(Debug, thiserror::Error)]
pub enum CompareError {
    /// A file of a run could not be read.
    #[error("{path}: {message}")]
    Read {
        /// The file.
        path: std::path::PathBuf,
        /// What went wrong.
        message: String,
    },
}

impl Comparison {
    /// Read `summary.json` and `residuals.json` of both runs.
    pub fn load(before: &std::path::Path, after: &std::path::Path) -> Result<Comparison, CompareError> {
        fn read<T: serde::de::DeserializeOwned>(path: std::path::PathBuf) -> Result<T, CompareError> {
            let text = std::fs::read_to_string(&path)
                .map_err(|e| CompareError::Read { path: path.clone(), message: e.to_string() })?;
            serde_json::from_str(&text).map_err(|e| CompareError::Read { path, message: e.to_string() })
        }
        Ok(Comparison {
            names: [before.display().to_string(), after.display().to_string()],
            summaries: [read(before.join("summary.json"))?, read(after.join("summary.json"))?],
            residuals: [read(before.join("residuals.json"))?, read(after.join("residuals.json"))?],
        })
    }

    fn stat(&self, k: usize, key: &str) -> f64 {
        self.summaries[k]["validation"][key].as_f64().unwrap_or(f64::NAN)
    }

    /// The printed comparison table.
    pub fn table_lines(&self) -> Vec<String> {
        let mut lines = vec![format!("{:<24} {:>12} {:>12}", "validation", "before", "after")];
        for key in ["rms_mm", "mean_mm", "std_mm", "max_mm"] {
            lines.push(format!("{:<24} {:>12.4} {:>12.4}", key, self.stat(0, key), self.stat(1, key)));
        }
        let effects = |k: usize| {
            self.summaries[k]["options"]["added_effects"]
                .as_array()
                .map(|a| a.iter().filter_map(|v| v.as_str()).collect::<Vec<_>>().join(", "))
                .unwrap_or_default()
        };
        lines.push(format!("{:<24} {:>12} {:>12}", "added effects", effects(0), effects(1)));
        for (l, (a, b)) in self.per_landmark() {
            lines.push(format!("  landmark {:<14} {:>12.4} {:>12.4}", l, a, b));
        }
        lines
    }

    fn per_landmark(&self) -> Vec<(String, (f64, f64))> {
        let get = |k: usize| -> Vec<(String, f64)> {
            self.summaries[k]["validation_detail"]["per_landmark"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .map(|g| {
                            (
                                g["name"].as_str().unwrap_or("?").to_string(),
                                g["stats"]["rms_mm"].as_f64().unwrap_or(f64::NAN),
                            )
                        })
                        .collect()
                })
                .unwrap_or_default()
        };
        let (a, b) = (get(0), get(1));
        a.into_iter()
            .map(|(name, x)| {
                let y = b.iter().find(|g| g.0 == name).map_or(f64::NAN, |g| g.1);
                (name, (x, y))
            })
            .collect()
    }

    /// The side-by-side page.
    pub fn html(&self) -> String {
        let mut body = String::new();
        let rows: Vec<Vec<String>> = ["rms_mm", "mean_mm", "std_mm", "max_mm"]
            .iter()
            .map(|k| {
                vec![k.to_string(), format!("{:.4}", self.stat(0, k)), format!("{:.4}", self.stat(1, k))]
            })
            .collect();
        let _ = write!(
            body,
            "<p>Before: {}<br>After: {}</p>{}",
            escape(&self.names[0]),
            escape(&self.names[1]),
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
        let errors = |k: usize| self.residuals[k].iter().map(|e| e.error_mm).collect::<Vec<f64>>();
        let (a, b) = (errors(0), errors(1));
        let _ = write!(
            body,
            "<h3>Distance errors</h3>{}",
            svg::histogram(&[("before", &a), ("after", &b)], 40, "distance error (mm)")
        );
        body.push_str("<h3>Residuals against each joint angle: before (left), after (right)</h3>");
        for j in 0..crate::model::JOINTS {
            for k in 0..2 {
                let pts: Vec<(f64, f64)> = self.residuals[k]
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
