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
                    crate::calib::diagnose::RivalVerdict::CannotTell => {
                        "these data cannot tell them apart".into()
                    }
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
