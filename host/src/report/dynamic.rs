//! The dynamic validation page: the verdict (latency with its uncertainty, error at rest and in
//! motion, where it grows) and the next command first, then the error along the path, against
//! speed and acceleration, the clock alignment and, on the emulator, the truth beside every
//! figure.

use super::svg::{self, escape};
use super::{page, table};
use crate::motion::truth::TruthRow;
use crate::motion::{Bin, Category, Dynamic, ErrorStat};
use std::fmt::Write;

/// Title of the page (also how kincal recognises a page it wrote).
pub const TITLE: &str = "kincal dynamic validation";

/// What the page names: the two recordings and the command that serves the pose.
pub struct PageInputs<'a> {
    /// The arm's pose recording.
    pub arm: &'a str,
    /// The reference tracker's recording.
    pub tracker: &'a str,
}

fn figure(e: &ErrorStat) -> String {
    escape(&e.text())
}

fn bins_table(bins: &[Bin], unit: &str) -> String {
    let rows: Vec<Vec<String>> = bins
        .iter()
        .map(|b| {
            let to = if b.to.is_finite() { format!("{}", b.to) } else { "∞".into() };
            vec![
                format!("{} – {to} {unit}", b.from),
                b.error.samples.to_string(),
                format!("{:.3}", b.error.measured_rms_mm),
                figure(&b.error),
            ]
        })
        .collect();
    table(&["range", "samples", "measured RMS (mm)", "path error (mm)"], &rows)
}

/// The page of a dynamic validation `d` of `inputs`; `truth` (simulations) adds the true error
/// of every category beside the measured one.
pub fn dynamic_report(d: &Dynamic, inputs: &PageInputs, truth: Option<&[TruthRow]>) -> String {
    let mut body = String::new();
    let grows: Vec<&String> = d.findings.iter().filter(|f| f.starts_with("the error grows")).collect();
    let _ = write!(
        body,
        "<p style=\"font-size:1.15em\"><b>Latency</b> {}.<br><b>Path error</b> at rest {}, in motion {}.<br><b>Where it grows:</b> {}</p>",
        escape(&d.latency_text()),
        figure(d.error(Category::AtRest)),
        figure(d.error(Category::InMotion)),
        if grows.is_empty() {
            "nowhere the measurement can tell (speed, acceleration, direction changes looked at).".to_string()
        } else {
            grows.iter().map(|f| escape(f.trim_start_matches("the error grows "))).collect::<Vec<_>>().join("; ")
        }
    );
    let _ = write!(
        body,
        "<p><b>Next:</b> serve this pose to navigation software with <code>kincal stream --port PORT --pose --igtl</code> (OpenIGTLink, port 18944); a navigation system that fuses it with this tracker must delay the arm's pose by the latency above. Where the error grows, the arm's model is static: a tool or link that bends under acceleration, or a stream that lags the joints, shows there.</p>"
    );
    let _ = write!(
        body,
        "<p>Arm: <code>{}</code> ({} poses, {} invalid rows skipped). Tracker: <code>{}</code> ({} samples compared at {:.1} Hz, {} gaps). Direction changes found: {}.</p>",
        escape(inputs.arm),
        d.arm_samples,
        d.arm_gaps,
        escape(inputs.tracker),
        d.tracker_samples,
        d.tracker_rate_hz,
        d.tracker_gaps,
        d.turns_s.len()
    );
    body.push_str("<h2>Path error by motion</h2>");
    let mut header = vec!["category", "samples", "measured RMS (mm)", "path error, noise removed (mm)"];
    if truth.is_some() {
        header.extend(["true error (mm)", "within the uncertainty"]);
    }
    let rows: Vec<Vec<String>> = d
        .categories
        .iter()
        .map(|(c, e)| {
            let mut row = vec![
                c.label().to_string(),
                e.samples.to_string(),
                format!("{:.3}", e.measured_rms_mm),
                figure(e),
            ];
            if let Some(t) = truth.and_then(|t| t.iter().find(|t| t.category == *c)) {
                row.push(format!("{:.3}", t.truth_rms_mm));
                row.push(if t.agrees { "yes".into() } else { "<span class=\"flag\">no</span>".into() });
            }
            row
        })
        .collect();
    body += &table(&header, &rows);
    body.push_str("<ul>");
    for f in &d.findings {
        let _ = write!(body, "<li>{}</li>", escape(f));
    }
    body.push_str("</ul>");
    let still: Vec<(f64, f64)> =
        d.series.iter().filter(|s| !s.near_turn).map(|s| (s.t_s, s.error_mm)).collect();
    let turning: Vec<(f64, f64)> =
        d.series.iter().filter(|s| s.near_turn).map(|s| (s.t_s, s.error_mm)).collect();
    let speed: Vec<(f64, f64)> = d.series.iter().map(|s| (s.t_s, s.speed_mm_s)).collect();
    let _ = write!(
        body,
        "<h2>Along the path</h2><p>Distance between the registered tracker sample and the arm's pose at its instant (noise included); dashed lines: direction changes.</p>{}{}",
        svg::timeline(
            &[("elsewhere", &still), ("near a direction change", &turning)],
            &d.turns_s,
            "time (s)",
            "distance (mm)"
        ),
        svg::timeline(&[("the arm's speed", &speed)], &d.turns_s, "time (s)", "speed (mm/s)")
    );
    let by_speed: Vec<(f64, f64)> = d.series.iter().map(|s| (s.speed_mm_s, s.error_mm)).collect();
    let by_accel: Vec<(f64, f64)> = d.series.iter().map(|s| (s.accel_m_s2, s.error_mm)).collect();
    let _ = write!(
        body,
        "<h2>Against speed and acceleration</h2><figure>{}</figure><figure>{}</figure><h3>By speed</h3>{}<h3>By acceleration</h3>{}",
        svg::scatter(&by_speed, &[], "speed (mm/s)", "distance (mm)"),
        svg::scatter(&by_accel, &[], "acceleration (m/s²)", "distance (mm)"),
        bins_table(&d.by_speed, "mm/s"),
        bins_table(&d.by_acceleration, "m/s²")
    );
    let c = &d.clock;
    let lags: Vec<(f64, f64)> = c.windows.iter().map(|w| (w.at_s - c.at_s, w.lag_ms - c.lag_ms)).collect();
    let ends =
        lags.iter().map(|p| p.0).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), t| (a.min(t), b.max(t)));
    let line: Vec<(f64, f64)> = [ends.0, ends.1].iter().map(|t| (*t, c.drift_ppm * 1e-3 * t)).collect();
    let _ = write!(
        body,
        "<h2>Time alignment</h2><p>The tracker's timestamps against the arm's sample instants: {:+.3} ± {:.3} ms at its first sample, drift {:+.1} ± {:.1} ppm, from {} windows of motion (points: each window's lag, relative to {:.3} ms; line: the fit). Noise of the tracker: {:.3} mm per axis.</p><figure>{}</figure>",
        d.clock_offset_at_start_ms,
        d.clock_offset_at_start_u95_ms,
        c.drift_ppm,
        c.drift_u95_ppm,
        c.windows.len(),
        c.lag_ms,
        d.noise_mm,
        svg::scatter(&lags, &line, "time from the windows' centre (s)", "lag − mean (ms)")
    );
    body.push_str("<h2>How it is measured</h2><p>The tracker's recording is aligned to the arm's pose stream by the tool's speed (the delay estimator the haptic calibration uses), then, after a rigid registration, by a least-squares time shift per window of motion and a line through them (clock offset and drift). The latency is the mean time from each sample's instant, on the arm's clock, to its arrival on the host. The path error is the distance between the registered tracker sample and the arm's pose at that instant; the tracker's white noise, estimated from second differences of consecutive samples, is removed from every figure (RMS² − 3σ²). A figure the noise hides is given as a 95 % upper bound. What a rigid registration absorbs, a constant offset of the whole path, is not in the error.</p>");
    page(TITLE, &body)
}
