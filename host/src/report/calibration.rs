//! `RUN/report.html`: validation, per-landmark errors, parameters, identifiability, outliers.

use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::run::Run;
use std::fmt::Write;

/// The calibration report of one run.
pub fn calibration_report(run: &Run) -> String {
    let s = &run.summary;
    let mut body = String::new();
    if !s.not_trustworthy.is_empty() {
        let items: String = s.not_trustworthy.iter().map(|p| format!("<li>{}</li>", escape(p))).collect();
        let _ = write!(body, "<h2>Not trustworthy: these figures are not a result</h2><ul>{items}</ul>");
    }
    let stats_row = |name: &str, v: &crate::calib::validate::ErrorStats| {
        vec![name.to_string(), mm(v.rms_mm), mm(v.mean_mm), mm(v.std_mm), mm(v.max_mm), v.count.to_string()]
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
            vec![escape(&c.name), mm(n.stats.rms_mm), mm(c.stats.rms_mm), c.stats.count.to_string()]
        })
        .collect();
    let _ = write!(
        body,
        "<h3>Per placement</h3>{}",
        table(&["placement", "nominal RMS mm", "calibrated RMS mm", "pairs"], &placements)
    );
    body.push_str("<h3>Calibrated residuals against each joint angle</h3>");
    for j in 0..run.nominal.joints.len() {
        let pts: Vec<(f64, f64)> = run
            .validation
            .errors
            .iter()
            .flat_map(|e| {
                [e.touches.0, e.touches.1].map(|t| (run.validation_data.obs[t].q_deg[j], e.error_mm))
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
    let combos = |list: &[crate::calib::identify::Combination]| {
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
                if o.exceeded.iter().any(|e| e == name) {
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
    if s.outliers_skipped {
        body.push_str("<h2>Outlier diagnostics (thesis appendix F)</h2><p>Skipped (<code>--no-outliers</code>): no landmark was checked.</p>");
    } else {
        let _ = write!(body, "<h2>Outlier diagnostics (thesis appendix F)</h2><p>Thresholds: contribution &gt; 1.5× its share, Cook's distance &gt; 4/L, leave-one-out improvement &gt; 5 %, bias &gt; 1 mm; flagged when two or more exceed.</p>{}", table(&["landmark", "contribution %", "Cook's D", "LOO impact %", "bias mm", ""], &out_rows));
    }
    if let Some(rows) = &s.study {
        let _ = write!(body, "<h2>Observations-size study</h2>{}", crate::report::study::study_body(rows));
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
