//! The haptic calibration report: errors before/after, sensor models, error maps over directions.

use super::svg;
use super::{page, table};

/// The report of a haptic calibration.
pub fn haptic_report(summary: &crate::haptic::pipeline::HapticSummary) -> String {
    let c = &summary.calibration;
    let rows = vec![
        vec![
            "position (mm)".to_string(),
            format!("{:.3}", summary.position.before_mm),
            format!("{:.3}", summary.position.after_mm),
        ],
        vec![
            "orientation (deg)".to_string(),
            format!("{:.3}", summary.orientation.before_deg),
            format!("{:.3}", summary.orientation.after_deg),
        ],
    ];
    let mut body = format!("<p>Delay of the tracker behind the device: {:.2} ms. Gimbal sensor model: {:?}. Errors on {} held-out samples.</p>{}", summary.delay_ms, summary.gimbal_model, c.held_out, table(&["RMS error", "before", "after"], &rows));
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
    let dirs = |f: &dyn Fn(&crate::haptic::pipeline::HeldOut) -> f64| -> Vec<(f64, f64, f64)> {
        c.samples.iter().map(|s| (s.0.x.atan2(s.0.z), s.0.y.clamp(-1.0, 1.0).asin(), f(s))).collect()
    };
    body += &format!(
        "<h3>Orientation error over stylus directions (Hammer projection)</h3>{}",
        svg::hammer_map(&dirs(&|s| s.1), "axis error after calibration (deg)")
    );
    body += &format!(
        "<h3>Position error over stylus directions</h3>{}",
        svg::hammer_map(&dirs(&|s| s.2), "position error after calibration (mm)")
    );
    let pos: Vec<f64> = c.samples.iter().map(|s| s.2).collect();
    body += &format!(
        "<h3>Position errors after calibration</h3>{}",
        svg::histogram(&[("after", &pos)], 30, "position error (mm)")
    );
    page("kincal haptic calibration", &body)
}
