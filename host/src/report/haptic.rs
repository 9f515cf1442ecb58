//! The haptic calibration report: errors before/after, sensor models, error maps over directions,
//! workspace regions and joint ranges, or the failing step of a refused calibration.

use super::svg::{self, escape};
use super::{page, table};
use crate::haptic::pipeline::HapticCalibration;
use std::fmt::Write;
use std::path::Path;

/// The verdict of a haptic calibration written into `dir`: the held-out position error against
/// the tracker's noise at the tip (the pivot residual), and the next step.
pub fn verdict_lines(c: &HapticCalibration, dir: &Path) -> Vec<String> {
    let (after, noise) = (c.position_mm.after, c.tip_mm.1);
    let ratio = after / noise;
    let times = if !ratio.is_finite() {
        "against an unknown tracker noise".to_string()
    } else if ratio > 100.0 {
        format!("more than 100× the tracker's noise at the tip ({noise:.3} mm, pivot residual)")
    } else {
        format!("≈ {ratio:.1}× the tracker's noise at the tip ({noise:.3} mm, pivot residual)")
    };
    let judged = if ratio.is_finite() && ratio <= 1.5 {
        "what remains is about the tracker's own noise"
    } else {
        "the device model leaves an error the tracker's noise does not explain: the maps below show where"
    };
    vec![
        format!("position error {after:.3} mm RMS on held-out samples (from {:.3} mm), {times}: {judged}", c.position_mm.before),
        format!(
            "next: the calibration (sensor models, delay, device → tracker) is in {}; calibrating a new recording the same way checks that it holds",
            dir.join("summary.json").display()
        ),
    ]
}

/// The report of a haptic calibration (or of a refused one: the failing step and what was
/// computed up to it) written into `dir`.
pub fn haptic_report(summary: &crate::haptic::pipeline::HapticSummary, dir: &Path) -> String {
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
        "<h2>Verdict</h2><ul>{}</ul>",
        verdict_lines(c, dir).iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>()
    );
    let _ = write!(
        body,
        "<p>Delay of the tracker behind the device: {:.2} ms (rounds: {}; peak correlation {:.4}). Gimbal sensor model: {} (held-out axis error linear {:.3}°, quadratic {:.3}°). Errors on {} held-out samples. Start of the joint calibration: {} (held-out residual: landmark {}, pose-based {:.3} mm{}). Wild tracker samples rejected: {}; occlusion gaps: {}. Tracker noise at the HIP (pivot RMS): {:.3} mm. Joint convention: <code>{}</code>.</p>{}",
        c.delay_ms,
        c.delay_rounds_ms.iter().map(|d| format!("{d:.3}")).collect::<Vec<_>>().join(" → "),
        c.delay_correlation,
        c.gimbal_model.words(),
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
