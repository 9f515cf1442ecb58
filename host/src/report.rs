//! `report.html`: what a person opens after a run. Reads results, never recomputes them.

use crate::run::Run;
use crate::svg::{self, escape};
use std::fmt::Write;

const STYLE: &str = "body{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#f4f4f4}td:first-child{text-align:left}.flag{color:#b00;font-weight:bold}figure{display:inline-block;margin:4px}";

/// Wrap body HTML into a page.
pub fn page(title: &str, body: &str) -> String {
    format!("<!doctype html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head><body><h1>{t}</h1>{body}</body></html>", t = escape(title))
}

/// HTML table from a header and rows of already formatted cells.
pub fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut out = String::from("<table><tr>");
    for h in header {
        let _ = write!(out, "<th>{}</th>", escape(h));
    }
    out.push_str("</tr>");
    for row in rows {
        out.push_str("<tr>");
        for cell in row {
            let _ = write!(out, "<td>{cell}</td>");
        }
        out.push_str("</tr>");
    }
    out + "</table>"
}

fn mm(v: f64) -> String {
    format!("{v:.3}")
}

/// The calibration report of one run.
pub fn calibration_report(run: &Run) -> String {
    let s = &run.summary;
    let mut body = String::new();
    let stats_row = |name: &str, v: &crate::validate::ErrorStats| {
        vec![name.to_string(), mm(v.rms_mm), mm(v.mean_mm), mm(v.std_mm), mm(v.max_mm), v.pairs.to_string()]
    };
    let _ = write!(
        body,
        "<h2>Validation (held-out placements)</h2>{}",
        table(
            &["model", "RMS mm", "mean mm", "std mm", "max mm", "pairs"],
            &[stats_row("nominal", &s.nominal_validation), stats_row("calibrated", &s.validation)]
        )
    );
    let _ = write!(body, "<p>Calibration RMS {} mm on {} pairs from {} touches; objective {:?}, Huber δ = {} mm, {} random restarts (seed {}).</p>", mm(s.calibration.rms_mm), s.calibration.pairs, s.calibration.touches, s.options.objective, s.options.huber_delta_mm, s.options.restarts, s.options.seed);
    let nominal: Vec<f64> = run.nominal_validation.errors.iter().map(|e| e.error_mm).collect();
    let calibrated: Vec<f64> = run.validation.errors.iter().map(|e| e.error_mm).collect();
    let _ = write!(
        body,
        "<h3>Distance errors, nominal</h3>{}",
        svg::histogram(&[("nominal", &nominal)], 40, "distance error (mm)")
    );
    let _ = write!(
        body,
        "<h3>Distance errors, calibrated</h3>{}",
        svg::histogram(&[("calibrated", &calibrated)], 40, "distance error (mm)")
    );
    let names: Vec<String> = s.validation_detail.per_landmark.iter().map(|g| g.name.clone()).collect();
    let nominal_rms: Vec<f64> = names
        .iter()
        .map(|n| {
            s.validation_detail
                .nominal_per_landmark
                .iter()
                .find(|g| &g.name == n)
                .map_or(0.0, |g| g.stats.rms_mm)
        })
        .collect();
    let calibrated_rms: Vec<f64> = s.validation_detail.per_landmark.iter().map(|g| g.stats.rms_mm).collect();
    let _ = write!(
        body,
        "<h3>RMS error per landmark</h3>{}",
        svg::bars(&names, &[("calibrated", calibrated_rms.clone())], "RMS (mm)")
    );
    let _ = write!(
        body,
        "{}",
        table(
            &["landmark", "nominal RMS mm", "calibrated RMS mm"],
            &names
                .iter()
                .enumerate()
                .map(|(i, n)| vec![escape(n), mm(nominal_rms[i]), mm(calibrated_rms[i])])
                .collect::<Vec<_>>()
        )
    );
    let placements: Vec<Vec<String>> = s
        .validation_detail
        .per_placement
        .iter()
        .zip(&s.validation_detail.nominal_per_placement)
        .map(|(c, n)| {
            vec![escape(&c.name), mm(n.stats.rms_mm), mm(c.stats.rms_mm), c.stats.pairs.to_string()]
        })
        .collect();
    let _ = write!(
        body,
        "<h3>Per placement</h3>{}",
        table(&["placement", "nominal RMS mm", "calibrated RMS mm", "pairs"], &placements)
    );
    body.push_str("<h3>Calibrated residuals against each joint angle</h3>");
    for j in 0..crate::model::JOINTS {
        let pts: Vec<(f64, f64)> = run
            .validation
            .errors
            .iter()
            .flat_map(|e| {
                [e.touches.0, e.touches.1].map(|t| (run.validation_data.touches[t].enc_deg[j], e.error_mm))
            })
            .collect();
        let _ = write!(
            body,
            "<figure>{}</figure>",
            svg::scatter(&pts, &[], &format!("encoder {} (deg)", j + 1), "error (mm)")
        );
    }
    let rep: Vec<Vec<String>> = s
        .validation_detail
        .repeatability
        .iter()
        .map(|r| vec![escape(&r.landmark), r.touches.to_string(), mm(r.rms_mm), mm(r.rp_mm)])
        .collect();
    let _ = write!(
        body,
        "<h3>Repeatability (ISO 9283 RP = mean + 3·std of distance to barycentre)</h3>{}",
        table(&["landmark", "touches", "RMS mm", "RP mm"], &rep)
    );
    let est: Vec<Vec<String>> = s
        .calibration
        .estimates
        .iter()
        .map(|e| {
            vec![
                e.param.clone(),
                e.unit.to_string(),
                format!("{:.4}", e.nominal),
                format!("{:.4}", e.value),
                e.std.map_or("—".into(), |v| format!("{v:.4}")),
                e.status.clone(),
            ]
        })
        .collect();
    let _ = write!(
        body,
        "<h2>Parameters</h2>{}",
        table(&["parameter", "unit", "nominal", "calibrated", "std", "status"], &est)
    );
    let combos = |list: &[crate::identify::Combination]| {
        list.iter()
            .map(|c| format!("<li>{} (σ/σ₁ = {:.1e})</li>", escape(&c.text), c.relative_singular_value))
            .collect::<String>()
    };
    let _ = write!(body, "<h2>Identifiability</h2><p>Before solving (nominal values), condition number {:.3e}. Unidentifiable:</p><ul>{}</ul><p>Poorly identified:</p><ul>{}</ul>", s.identifiability.before.condition_number, combos(&s.identifiability.before.unidentifiable), combos(&s.identifiability.before.poorly_identified));
    let _ = write!(
        body,
        "<p>At the solution, unidentifiable:</p><ul>{}</ul><p>Poorly identified:</p><ul>{}</ul>",
        combos(&s.identifiability.after.unidentifiable),
        combos(&s.identifiability.after.poorly_identified)
    );
    let _ =
        write!(body, "<p>Fixed at nominal: {}</p>", escape(&s.calibration.fixed_unidentifiable.join(", ")));
    let corr: Vec<Vec<String>> = s
        .calibration
        .correlations
        .iter()
        .map(|(a, b, r)| vec![escape(a), escape(b), format!("{r:+.3}")])
        .collect();
    let _ = write!(body, "<h3>Strong correlations (|ρ| &gt; 0.9)</h3>{}", table(&["a", "b", "ρ"], &corr));
    let oc = &s.objective_comparison;
    let _ = write!(body, "<h3>What relative orientation adds</h3><p>Identifiable from distances: {}. With relative orientation: {}. Gained: {}.</p>", escape(&oc.identifiable_by_distance.join(", ")), escape(&oc.identifiable_by_six_dof.join(", ")), if oc.gained_by_orientation.is_empty() { "none".into() } else { escape(&oc.gained_by_orientation.join(", ")) });
    let std_rows: Vec<Vec<String>> = oc
        .std
        .iter()
        .map(|(p, a, b)| {
            vec![
                escape(p),
                a.map_or("—".into(), |v| format!("{v:.4}")),
                b.map_or("—".into(), |v| format!("{v:.4}")),
            ]
        })
        .collect();
    let _ = write!(body, "{}", table(&["parameter", "std, distances", "std, + orientation"], &std_rows));
    let out_rows: Vec<Vec<String>> = s
        .outliers
        .iter()
        .map(|o| {
            let cell = |v: f64, name: &str| {
                if o.exceeded.contains(&name) {
                    format!("<span class=flag>{v:.3}</span>")
                } else {
                    format!("{v:.3}")
                }
            };
            vec![
                escape(&o.landmark),
                cell(o.contribution_pct, "contribution"),
                cell(o.cooks_distance, "cooks_distance"),
                cell(o.loo_impact_pct, "leave_one_out"),
                cell(o.bias_mm, "bias"),
                if o.flagged { "<span class=flag>flagged</span>".into() } else { String::new() },
            ]
        })
        .collect();
    let _ = write!(body, "<h2>Outlier diagnostics (thesis appendix F)</h2><p>Thresholds: contribution &gt; 1.5× its share, Cook's distance &gt; 4/L, leave-one-out improvement &gt; 5 %, bias &gt; 1 mm; flagged when two or more exceed.</p>{}", table(&["landmark", "contribution %", "Cook's D", "LOO impact %", "bias mm", ""], &out_rows));
    if let Some(rows) = &s.study {
        let _ = write!(body, "<h2>Dataset-size study</h2>{}", crate::study::study_body(rows));
    }
    let starts: Vec<Vec<String>> = s
        .calibration
        .starts
        .iter()
        .map(|st| {
            vec![
                st.start.to_string(),
                format!("{:.4}", st.initial_cost),
                format!("{:.6}", st.final_cost),
                st.iterations.to_string(),
                format!("{:?}", st.stop),
            ]
        })
        .collect();
    let _ = write!(
        body,
        "<h2>Solver starts</h2>{}",
        table(&["start", "initial cost", "final cost", "iterations", "stop"], &starts)
    );
    page("kincal calibration report", &body)
}

/// The diagnosis page: where the model fails and which effect is missing.
pub fn diagnosis_report(d: &crate::diagnose::Diagnosis) -> String {
    let mut body = String::new();
    let _ = write!(
        body,
        "<h2>Summary</h2><ul>{}</ul>",
        d.summary.iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>()
    );
    let rows: Vec<Vec<String>> = d
        .candidates
        .iter()
        .map(|c| {
            vec![
                escape(&c.effect)
                    + &c.equivalent_to.as_ref().map_or(String::new(), |l| format!(" (≡ {})", escape(l))),
                mm(c.validation_rms_mm),
                format!("{:.2}", c.explained),
                format!("{}/{} (p = {:.1e})", c.blocks_improved.0, c.blocks_improved.1, c.p_value),
                format!("{:+.1}", c.delta_bic),
                if c.significant { "<span class=flag>yes</span>".into() } else { "no".into() },
                escape(&c.evidence),
            ]
        })
        .collect();
    let _ = write!(body, "<h2>Which effect is missing</h2><p>Baseline validation RMS {} mm. Each effect is added, refitted on the calibration data and scored on the held-out placements.</p>{}", mm(d.baseline.rms_mm), table(&["effect", "val RMS mm", "explained", "blocks improved", "ΔBIC", "significant", "evidence"], &rows));
    let ni: Vec<Vec<String>> =
        d.not_identifiable.iter().map(|n| vec![escape(&n.effect), escape(&n.reason)]).collect();
    let _ = write!(body, "<h3>Not identifiable</h3>{}", table(&["effect", "why"], &ni));
    body.push_str("<h2>Where it fails</h2><h3>Apparent joint error against joint angle (with the best-fitting sinusoid)</h3>");
    for j in &d.joints {
        let pts: Vec<(f64, f64)> = j.points.iter().map(|p| (p.0, p.1)).collect();
        let s = j.sinusoid;
        let curve: Vec<(f64, f64)> = (0..=72)
            .map(|k| {
                let phi = k as f64 * 5.0;
                (phi, s.amplitude_deg * (phi.to_radians() + s.phase_deg.to_radians()).sin() + s.mean_deg)
            })
            .collect();
        let _ = write!(
            body,
            "<figure>{}<figcaption>joint {}: amplitude {:.3}°, {:.0} % explained</figcaption></figure>",
            svg::scatter(&pts, &curve, &format!("encoder {} (deg)", j.joint), "apparent error (deg)"),
            j.joint,
            s.amplitude_deg,
            100.0 * s.explained
        );
    }
    body.push_str("<h3>Apparent joint error against gravity lever</h3>");
    for j in d.joints.iter().filter(|j| j.gravity.iter().any(|g| g.0.abs() > 1e-6)) {
        let _ = write!(
            body,
            "<figure>{}<figcaption>joint {}: slope {:+.3} °/m</figcaption></figure>",
            svg::scatter(
                &j.gravity,
                &[],
                &format!("gravity lever joint {} (m)", j.joint),
                "apparent error (deg)"
            ),
            j.joint,
            j.gravity_slope_deg_per_m
        );
    }
    let _ = write!(
        body,
        "<h3>Residual against height and reach</h3><figure>{}</figure><figure>{}</figure>",
        svg::scatter(&d.by_height, &[], "tool height z (mm)", "|residual| (mm)"),
        svg::scatter(&d.by_reach, &[], "reach (mm)", "|residual| (mm)")
    );
    let place: Vec<Vec<String>> = d.by_placement.iter().map(|(n, r)| vec![escape(n), mm(*r)]).collect();
    let _ = write!(body, "<h3>By placement</h3>{}", table(&["placement", "RMS mm"], &place));
    let worst: Vec<Vec<String>> = d
        .worst
        .iter()
        .map(|w| {
            vec![
                escape(&w.placement),
                format!("{}–{}", escape(&w.landmarks.0), escape(&w.landmarks.1)),
                mm(w.error_mm),
            ]
        })
        .collect();
    let _ =
        write!(body, "<h3>Worst measurements</h3>{}", table(&["placement", "landmarks", "error mm"], &worst));
    page("kincal diagnosis", &body)
}

/// Two runs side by side, read from their RUN folders.
pub struct Comparison {
    names: [String; 2],
    summaries: [serde_json::Value; 2],
    residuals: [Vec<crate::run::StoredPairError>; 2],
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

/// The report of a haptic calibration (or of a refused one: the failing step and what was
/// computed up to it).
pub fn haptic_report(summary: &crate::haptic::pipeline::HapticSummary) -> String {
    use crate::haptic::report_data::Cell;
    let mut body = String::new();
    if let Some(f) = &summary.failure {
        let _ = write!(
            body,
            "<p style=\"color:#b00\"><b>Calibration refused</b> — {} failed: {}</p>",
            escape(f.step),
            escape(&f.message)
        );
    }
    let cells = |cells: &[Cell]| -> Vec<Vec<String>> {
        cells
            .iter()
            .map(|c| {
                vec![
                    escape(&c.label),
                    c.count.to_string(),
                    format!("{:.3}", c.position_rms_mm),
                    format!("{:+.3}, {:+.3}, {:+.3}", c.bias_mm[0], c.bias_mm[1], c.bias_mm[2]),
                    format!("{:.3}", c.axis_rms_deg),
                ]
            })
            .collect()
    };
    let header = ["cell", "samples", "position RMS (mm)", "mean error x, y, z (mm)", "axis RMS (deg)"];
    let maps_html = |maps: &crate::haptic::report_data::ErrorMaps| -> String {
        let b = maps.bias_mm;
        let mut out = format!(
            "<h3>Where the errors are</h3><p>Mean error vector over all held-out samples: {:+.3}, {:+.3}, {:+.3} mm (device frame). Errors that grow along one joint's range point to that joint's convention or sensor model; a common error direction in one region points to a missing effect or a flipped axis.</p><h4>By workspace region (thirds of the held-out positions)</h4>{}<h4>By stylus direction</h4>{}",
            b[0],
            b[1],
            b[2],
            table(&header, &cells(&maps.regions)),
            table(&header, &cells(&maps.directions))
        );
        for (j, profile) in maps.joints.iter().enumerate() {
            let labels: Vec<String> = profile.iter().map(|c| c.label.clone()).collect();
            let values: Vec<f64> = profile.iter().map(|c| c.position_rms_mm).collect();
            let _ = write!(
                out,
                "<h4>Against θ{}</h4>{}",
                j + 1,
                svg::bars(&labels, &[("position RMS", values)], "position error (mm)")
            );
        }
        out
    };
    let Some(c) = &summary.calibration else {
        body.push_str("<p>No calibration result: the procedure stopped before the end.</p>");
        if let Some(maps) = summary.failure.as_ref().and_then(|f| f.maps.as_ref()) {
            body.push_str("<p>The refused joint calibration's residuals on held-out blocks of joints/ (axis errors not computed):</p>");
            body += &maps_html(maps);
        }
        return page("kincal haptic calibration", &body);
    };
    let rows = vec![
        vec![
            "position (mm)".to_string(),
            format!("{:.3}", c.position_mm.before),
            format!("{:.3}", c.position_mm.after),
        ],
        vec![
            "orientation (deg)".to_string(),
            format!("{:.3}", c.orientation_deg.before),
            format!("{:.3}", c.orientation_deg.after),
        ],
    ];
    let _ = write!(
        body,
        "<p>Delay of the tracker behind the device: {:.2} ms (rounds: {}; peak correlation {:.4}). Gimbal sensor model: {:?} (held-out axis error linear {:.3}°, quadratic {:.3}°). Errors on {} held-out samples. Start of the joint calibration: {} (held-out residual: landmark {}, pose-based {:.3} mm{}). Wild tracker samples rejected: {}; occlusion gaps: {}. Tracker noise at the HIP (pivot RMS): {:.3} mm. Joint convention: <code>{}</code>.</p>{}",
        c.delay_ms,
        c.delay_rounds_ms.iter().map(|d| format!("{d:.3}")).collect::<Vec<_>>().join(" → "),
        c.delay_correlation,
        c.gimbal_model,
        c.gimbal_held_out_deg.0,
        c.gimbal_held_out_deg.1,
        c.held_out,
        c.start.chosen,
        c.start.landmark_mm.map_or("—".to_string(), |v| format!("{v:.3} mm")),
        c.start.pose_mm,
        c.start.landmark_note.as_deref().map_or(String::new(), |n| format!("; landmarks not used: {}", escape(n))),
        c.rejected_samples,
        c.tracker_gaps,
        c.tip_mm.1,
        escape(&c.convention.json()),
        table(&["RMS error", "before", "after"], &rows)
    );
    let sensors: Vec<Vec<String>> = c
        .sensors
        .iter()
        .enumerate()
        .map(|(i, m)| {
            vec![format!("θ{}", i + 1), format!("{:.5}", m.j), format!("{:.5}", m.k), format!("{:.5}", m.m)]
        })
        .collect();
    body += &format!(
        "<h3>Sensor models θ = j·raw² + k·raw + m</h3>{}",
        table(&["joint", "j", "k", "m (rad)"], &sensors)
    );
    let dirs = |f: &dyn Fn(&crate::haptic::report_data::HeldOutSample) -> f64| -> Vec<(f64, f64, f64)> {
        c.samples
            .iter()
            .map(|s| (s.direction.x.atan2(s.direction.z), s.direction.y.clamp(-1.0, 1.0).asin(), f(s)))
            .collect()
    };
    body += &format!(
        "<h3>Orientation error over stylus directions (Hammer projection)</h3>{}",
        svg::hammer_map(&dirs(&|s| s.axis_error_deg), "axis error after calibration (deg)")
    );
    body += &format!(
        "<h3>Position error over stylus directions</h3>{}",
        svg::hammer_map(&dirs(&|s| s.error_mm.norm()), "position error after calibration (mm)")
    );
    body += &maps_html(&c.maps);
    let pos: Vec<f64> = c.samples.iter().map(|s| s.error_mm.norm()).collect();
    body += &format!(
        "<h3>Position errors after calibration</h3>{}",
        svg::histogram(&[("after", &pos)], 30, "position error (mm)")
    );
    page("kincal haptic calibration", &body)
}
