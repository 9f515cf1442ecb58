//! `RUN/diagnosis.html`: where the model fails and which effect is missing.

use super::svg::{self, escape};
use super::{mm, page, table};
use std::fmt::Write;

/// The diagnosis page: where the model fails and which effect is missing.
pub fn diagnosis_report(d: &crate::calib::diagnose::Diagnosis) -> String {
    let mut body = String::new();
    let _ = write!(
        body,
        "<h2>Summary</h2><ul>{}</ul>",
        d.summary.iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>()
    );
    // Pictures first: the gap, candidates and data errors against the floor, per-joint patterns.
    let mut bars: Vec<(String, f64, bool)> = vec![("now (as calibrated)".into(), d.baseline.rms_mm, false)];
    bars.extend(
        d.candidates
            .iter()
            .filter(|c| c.equivalent_to.is_none())
            .take(8)
            .map(|c| (format!("+ {}", c.effect), c.validation_rms_mm, c.significant)),
    );
    bars.extend(
        d.data_errors
            .iter()
            .take(3)
            .map(|c| (format!("data: {}", c.effect), c.validation_rms_mm, c.significant)),
    );
    let mut references: Vec<(&str, f64)> = Vec::new();
    if let Some(g) = &d.gap {
        references.push(("expected from repeatability (the floor for this model)", g.expected_mm));
    }
    let _ = write!(
        body,
        "<h2>The gap to the floor, and what closes it</h2><figure>{}<figcaption>validation RMS now and with each candidate effect or data error (best first; orange = significant), against the floor expected from repeatability (dashed)</figcaption></figure>",
        svg::hbars(&bars, &references, "validation RMS (mm)")
    );
    body.push_str("<h2>Where it fails</h2><h3>Apparent joint error against joint angle (the curve: harmonics 1–4 fitted together, drawn where touches are)</h3><p>Touches where a joint barely moves the tip (its Jacobian column near zero, close to a singularity) give huge apparent errors of that joint; the axes are set by the bulk of the touches and such points are drawn as triangles at the edge.</p>");
    for j in &d.joints {
        let pts: Vec<(f64, f64)> = j.points.iter().map(|p| (p.0, p.1)).collect();
        let s = j.sinusoid;
        // The harmonics fitted together, drawn only within 10° of angles the touches visit
        // (elsewhere the fit is not constrained).
        let (lo, hi) =
            pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.0), b.max(p.0)));
        let curve: Vec<(f64, f64)> = (0..=72)
            .map(|k| lo + (hi - lo) * k as f64 / 72.0)
            .filter(|phi| phi.is_finite() && pts.iter().any(|p| (p.0 - phi).abs() < 10.0))
            .map(|phi| {
                let value: f64 = j
                    .spectrum
                    .iter()
                    .map(|(n, h)| {
                        h.amplitude_deg * (f64::from(*n) * phi.to_radians() + h.phase_deg.to_radians()).sin()
                    })
                    .sum();
                (phi, value + s.mean_deg)
            })
            .collect();
        let _ = write!(
            body,
            "<figure>{}<figcaption>joint {}: 1/rev {:.3}°, {:.0} % explained</figcaption></figure>",
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
    if let (Some(f), Some(g)) = (&d.floor, &d.gap) {
        let encoder =
            f.encoder_rms_mm.map_or("not reported by the sessions".into(), |e| format!("{} mm", mm(e)));
        let rows = vec![
            vec!["validation RMS measured".into(), mm(g.measured_mm)],
            vec!["expected from repeatability (this model's parameters fitted)".into(), mm(g.expected_mm)],
            vec!["noise floor of the true arm (distances)".into(), mm(f.distance_rms_mm)],
            vec!["scatter of one touch, per axis".into(), mm(f.touch_std_mm)],
            vec!["of which encoder noise (distances)".into(), encoder],
            vec![
                "the model misses about".into(),
                if g.significant { mm(g.missing_mm) } else { "nothing beyond noise".into() },
            ],
            vec![
                "missing part, 95 % interval".into(),
                format!("{}–{}", mm(g.missing_95_mm.0), mm(g.missing_95_mm.1)),
            ],
            vec!["smallest missing part the gap test calls (even odds)".into(), mm(g.detectable_mm)],
            vec!["gap in standard errors".into(), format!("{:+.1}", g.z)],
            vec!["groups of repeats pooled / degrees of freedom".into(), format!("{} / {}", f.groups, f.dof)],
        ];
        let _ = write!(body, "<h2>How far from done</h2><p>The floor comes from repeated touches of the same landmark in the same placement and arm configuration, propagated to the validation distances.</p>{}", table(&["", "mm"], &rows));
        if !f.inconsistent.is_empty() {
            let bad: Vec<Vec<String>> =
                f.inconsistent.iter().map(|(p, l, s)| vec![escape(p), escape(l), mm(*s)]).collect();
            let _ = write!(
                body,
                "<h3>Repeats that disagree beyond noise (left out of the floor)</h3>{}",
                table(&["placement", "landmark", "scatter per axis mm"], &bad)
            );
        }
    }
    let rows: Vec<Vec<String>> = d
        .candidates
        .iter()
        .map(|c| {
            vec![
                escape(&c.effect)
                    + &c.equivalent_to.as_ref().map_or(String::new(), |l| format!(" (≡ {})", escape(l))),
                mm(c.validation_rms_mm),
                format!("{:.2}", c.explained),
                format!("{}/{} (p = {:.3})", c.placements_improved.0, c.placements_improved.1, c.p_value),
                format!("{:.1}", c.calibration_z),
                if c.significant { "<span class=flag>yes</span>".into() } else { "no".into() },
                escape(&c.evidence),
            ]
        })
        .collect();
    let _ = write!(body, "<h2>Which effect is missing</h2><p>Baseline validation RMS {} mm. Each effect is screened by a score test on the calibration data (its evidence as a normal deviate), refitted and scored on the held-out placements: an exact sign-flip test over the placements, in a fixed sequence by calibration evidence.</p>{}", mm(d.baseline.rms_mm), table(&["effect", "val RMS mm", "explained", "placements improved", "calibration evidence z", "significant", "evidence"], &rows));
    if !d.rivals.is_empty() {
        let rivals: Vec<Vec<String>> = d
            .rivals
            .iter()
            .map(|r| {
                let verdict = match &r.verdict {
                    crate::calib::diagnose::RivalVerdict::Proxy { cause, proxy } => {
                        format!("{} is a proxy of {}", escape(proxy), escape(cause))
                    }
                    crate::calib::diagnose::RivalVerdict::Both => "both are missing".into(),
                    crate::calib::diagnose::RivalVerdict::CannotTell => format!(
                        "these data cannot tell them apart (where to measure: <code>kincal plan RUN --rivals {},{}</code>)",
                        escape(&r.a),
                        escape(&r.b)
                    ),
                };
                vec![
                    escape(&r.a),
                    escape(&r.b),
                    mm(r.both_rms_mm),
                    format!("{:.3}", r.b_adds_p),
                    format!("{:.3}", r.a_adds_p),
                    format!("{:.1}", r.separability),
                    verdict,
                ]
            })
            .collect();
        let _ = write!(
            body,
            "<h3>Rivals of the leading effect</h3>{}",
            table(
                &[
                    "A",
                    "B",
                    "A+B val RMS mm",
                    "p (B added to A)",
                    "p (A added to B)",
                    "separability λ",
                    "verdict"
                ],
                &rivals
            )
        );
    }
    let data: Vec<Vec<String>> = d
        .data_errors
        .iter()
        .map(|c| {
            vec![
                escape(&c.effect),
                mm(c.validation_rms_mm),
                format!("{}/{} (p = {:.3})", c.placements_improved.0, c.placements_improved.1, c.p_value),
                if c.significant { "<span class=flag>yes</span>".into() } else { "no".into() },
                escape(&c.evidence),
                escape(c.action.as_deref().unwrap_or("")),
            ]
        })
        .collect();
    let _ = write!(body, "<h2>Data errors, scored beside the arm effects</h2><p>A wrong certificate (the landmark's position freed), a placement disturbed within a repeat, a mis-seated touch. When one explains the residuals as well as an arm effect, it is named and no arm effect is claimed.</p>{}", table(&["data error", "val RMS mm", "placements improved", "significant", "evidence", "what to do"], &data));
    let ni: Vec<Vec<String>> =
        d.not_identifiable.iter().map(|n| vec![escape(&n.effect), escape(&n.reason)]).collect();
    let _ = write!(body, "<h3>Not identifiable</h3>{}", table(&["effect", "why"], &ni));
    let spectrum: Vec<Vec<String>> = d
        .joints
        .iter()
        .map(|j| {
            std::iter::once(j.joint.to_string())
                .chain(
                    j.spectrum
                        .iter()
                        .map(|(_, s)| format!("{:.3}° ({:.0} %)", s.amplitude_deg, 100.0 * s.explained)),
                )
                .collect()
        })
        .collect();
    let _ = write!(body, "<h3>Periodic apparent error per joint: amplitude (share of variance) by cycles per revolution</h3>{}", table(&["joint", "1/rev", "2/rev", "3/rev", "4/rev"], &spectrum));
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
