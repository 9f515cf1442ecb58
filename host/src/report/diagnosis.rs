//! `RUN/diagnosis.html`: the verdict, where the model fails and what is missing, for every kind of
//! held-out data.

use super::run::name_run;
use super::svg::{self, escape};
use super::{mm, page, table};
use crate::calib::diagnose::{Candidate, Diagnosis, Measure, RivalVerdict};
use std::fmt::Write;
use std::path::Path;

/// The diagnosis's summary as the CLI prints it and the page leads with it: the run's folder in
/// its commands, and a next step when the summary names none.
pub fn summary_lines(d: &Diagnosis, run_dir: &Path) -> Vec<String> {
    let mut lines: Vec<String> = d.summary.iter().map(|l| name_run(l, run_dir)).collect();
    let names_a_step = lines.iter().any(|l| {
        [
            "what to do",
            "what to measure next",
            "fix the data",
            "measure at least",
            "hold out more",
            "apply with",
        ]
        .iter()
        .any(|w| l.contains(w))
    });
    if !names_a_step {
        lines.push(match &d.floor.gap {
            Some(g) if g.at_floor => {
                format!("next: nothing to add; {}/model.toml is the calibration to keep", run_dir.display())
            }
            Some(g) if g.significant => {
                "next: the model lacks something outside the effect library: the apparent joint \
                                         errors below show which joint and how it varies"
                    .into()
            }
            _ => "next: more held-out data (placements or sessions) would tell whether anything is missing"
                .into(),
        });
    }
    lines
}

fn list(lines: &[String]) -> String {
    format!("<ul>{}</ul>", lines.iter().map(|l| format!("<li>{}</li>", escape(l))).collect::<String>())
}

/// A held-out p as the tables show it: only where the fixed sequence reached the candidate.
fn p_cell(c: &Candidate) -> String {
    if c.tested {
        format!("{:.1e}", c.p_value)
    } else {
        format!("not tested ({:.1e})", c.p_value)
    }
}

fn yes(significant: bool) -> String {
    if significant {
        "<span class=flag>yes</span>".into()
    } else {
        "no".into()
    }
}

/// The tables of candidates: arm effects or data errors.
fn candidate_table(candidates: &[Candidate], units: &str) -> String {
    let rows: Vec<Vec<String>> = candidates
        .iter()
        .map(|c| {
            vec![
                escape(&c.name)
                    + &c.equivalent_to.as_ref().map_or(String::new(), |l| format!(" (≡ {})", escape(l))),
                mm(c.held_out_rms_mm),
                format!("{:.2}", c.explained),
                format!("{}/{}", c.units_improved.0, c.units_improved.1),
                format!("{:.1}", c.ranking.calibration_z),
                c.ranking.cv_gain.map_or("–".into(), |g| format!("{g:+.3}")),
                p_cell(c),
                yes(c.significant),
                format!("<code>{}</code>", escape(&c.action)),
                escape(&c.evidence),
            ]
        })
        .collect();
    table(
        &[
            "candidate",
            "held-out RMS mm",
            "explained",
            units,
            "calibration evidence z",
            "CV gain",
            "held-out p",
            "significant",
            "apply with",
            "evidence",
        ],
        &rows,
    )
}

/// The diagnosis page: the verdict first, then the pictures, then the tables.
pub fn diagnosis_report(d: &Diagnosis, run_dir: &Path) -> String {
    let (units, unit_words) = match d.measure {
        Measure::Distances => ("placements improved", "validation placements (their repeats averaged)"),
        Measure::Points => ("blocks improved", "contiguous blocks of poses of the held-out sessions"),
    };
    let mut body = format!("<h2>Verdict</h2>{}", list(&summary_lines(d, run_dir)));
    // Pictures first: the gap, candidates and data errors against the floor, per-joint patterns.
    let mut bars: Vec<(String, f64, bool)> = vec![("now (as calibrated)".into(), d.baseline.rms_mm, false)];
    bars.extend(
        d.candidates
            .iter()
            .filter(|c| c.equivalent_to.is_none())
            .take(8)
            .map(|c| (format!("+ {}", c.name), c.held_out_rms_mm, c.significant)),
    );
    bars.extend(
        d.data_errors.iter().take(4).map(|c| (format!("data: {}", c.name), c.held_out_rms_mm, c.significant)),
    );
    let mut references: Vec<(&str, f64)> = Vec::new();
    if let Some(e) = d.floor.expected_mm() {
        references.push(("what a complete model leaves (the floor for this model)", e));
    }
    let largest_bound = d.floor.neighbours.iter().map(|n| n.bound_mm).fold(f64::NAN, f64::max);
    if largest_bound.is_finite() {
        references.push((
            "largest neighbour bound of a held-out session (noise + small-scale error, at most)",
            largest_bound,
        ));
    }
    let _ = write!(
        body,
        "<h2>The gap to the floor, and what closes it</h2><figure>{}<figcaption>held-out RMS now and with each candidate effect or data error (best first; orange = significant), against the floor ({}; dashed)</figcaption></figure>",
        svg::hbars(&bars, &references, "held-out RMS (mm)"),
        escape(&d.floor.source)
    );
    body.push_str("<h2>Where it fails</h2><h3>Apparent joint error against joint angle (the curve: harmonics 1–4 fitted together, drawn where observations are)</h3><p>Where a joint is seen over part of its turn only, the harmonics and the mean trade off and the once-per-revolution amplitude is not given. Observations where a joint barely moves the tip (its Jacobian column near zero, close to a singularity) give huge apparent errors of that joint; the axes are set by the bulk of the observations and such points are drawn as triangles at the edge.</p>");
    for j in &d.joints {
        let pts: Vec<(f64, f64)> = j.points.iter().map(|p| (p.0, p.1)).collect();
        let s = j.sinusoid;
        // The harmonics fitted together, drawn only within 10° of angles the observations visit
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
        // Over a part of the turn the 1/rev amplitude is an extrapolation (the harmonics and the
        // mean trade off): give it only when the drawn curve's half-range where the joint was
        // seen reaches it.
        let (low, high) =
            curve.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| (a.min(c.1), b.max(c.1)));
        let half_range = if high >= low { 0.5 * (high - low) } else { 0.0 };

        let once = if s.amplitude_deg <= 1.5 * half_range + 1e-6 {
            format!("1/rev {:.3}°", s.amplitude_deg)
        } else {
            "1/rev not determined over the angles seen".to_string()
        };
        let _ = write!(
            body,
            "<figure>{}<figcaption>joint {}: {once}, {:.0} % explained</figcaption></figure>",
            svg::scatter(&pts, &curve, &format!("joint {} (deg)", j.joint), "apparent error (deg)"),
            j.joint,
            100.0 * s.explained
        );
    }
    body.push_str("<h3>Apparent joint error against gravity lever</h3><p>The lever is the gravity torque on the joint per unit weight of each link beyond it, summed over those links (so it can exceed the arm's reach). The slope is the raw trend of the residuals: the calibrated parameters absorb part of a sag, so it can differ from a fitted compliance, whose value the verdict gives.</p>");
    for j in d.joints.iter().filter(|j| j.gravity.iter().any(|g| g.0.abs() > 1e-6)) {
        let _ = write!(
            body,
            "<figure>{}<figcaption>joint {}: raw slope {:+.3} °/m</figcaption></figure>",
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
    if let Some(g) = &d.floor.gap {
        let mut rows = vec![
            vec!["held-out RMS measured".into(), mm(g.measured_mm)],
            vec!["what a complete model with these parameters leaves".into(), mm(g.expected_mm)],
        ];
        if let Some(f) = &d.floor.distances {
            let encoder =
                f.encoder_rms_mm.map_or("not reported by the sessions".into(), |e| format!("{} mm", mm(e)));
            rows.push(vec!["noise floor of the true arm (distances)".into(), mm(f.distance_rms_mm)]);
            rows.push(vec!["scatter of one touch, per axis".into(), mm(f.touch_std_mm)]);
            rows.push(vec!["of which encoder noise (distances)".into(), encoder]);
            rows.push(vec![
                "groups of repeats pooled / degrees of freedom".into(),
                format!("{} / {}", f.groups, f.dof),
            ]);
        } else if let Some(f) = d.floor.floor_mm {
            rows.push(vec![format!("floor of the held-out points ({})", escape(&d.floor.source)), mm(f)]);
        }
        rows.extend([
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
        ]);
        let _ = write!(
            body,
            "<h2>How far from done</h2><p>The floor: {}.</p>{}",
            escape(&d.floor.source),
            table(&["", "mm"], &rows)
        );
        if let Some(f) = d.floor.distances.as_ref().filter(|f| !f.inconsistent.is_empty()) {
            let bad: Vec<Vec<String>> =
                f.inconsistent.iter().map(|(p, l, s)| vec![escape(p), escape(l), mm(*s)]).collect();
            let _ = write!(
                body,
                "<h3>Repeats that disagree beyond noise (left out of the floor)</h3>{}",
                table(&["placement", "landmark", "scatter per axis mm"], &bad)
            );
        }
    }
    if !d.floor.neighbours.is_empty() {
        let rows: Vec<Vec<String>> = d
            .floor
            .neighbours
            .iter()
            .map(|n| {
                vec![
                    escape(&n.session),
                    n.points.to_string(),
                    mm(n.rms_mm),
                    mm(n.bound_mm),
                    format!("{:.1}", n.median_distance_deg),
                    yes(n.incomplete),
                ]
            })
            .collect();
        let _ = write!(
            body,
            "<h3>Neighbour check (no floor needed)</h3>{}",
            table(
                &[
                    "held-out session",
                    "points",
                    "RMS mm",
                    "bound mm",
                    "median neighbour distance °",
                    "incomplete"
                ],
                &rows
            )
        );
    }
    let _ = write!(
        body,
        "<h2>Which effect is missing</h2><p>Baseline held-out RMS {} mm. Each effect is refitted on the calibration data, which also order the test, and scored on the {} held-out units ({}): an exact sign-flip test and a t test over the units, in a fixed sequence that stops at the first that fails.</p>{}",
        mm(d.baseline.rms_mm),
        d.units,
        unit_words,
        candidate_table(&d.candidates, units)
    );
    if !d.rivals.is_empty() {
        let rivals: Vec<Vec<String>> = d
            .rivals
            .iter()
            .map(|r| {
                let verdict = match &r.verdict {
                    RivalVerdict::Proxy { cause, proxy } => format!("{} is a proxy of {}", escape(proxy), escape(cause)),
                    RivalVerdict::Both => "both are missing".into(),
                    RivalVerdict::CannotTell => format!(
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
                    r.separability.map_or("–".into(), |l| format!("{l:.1}")),
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
                    "A+B held-out RMS mm",
                    "p (B added to A)",
                    "p (A added to B)",
                    "separability λ",
                    "verdict"
                ],
                &rivals
            )
        );
    }
    let _ = write!(
        body,
        "<h2>Data errors, scored beside the arm effects</h2><p>A wrong certificate (the landmark's position freed), a placement disturbed within a repeat, a mis-seated touch; a tool re-mounted in a session, a session drifting, single bad points. When one explains the residuals as well as an arm effect, it is named and no arm effect is claimed.</p>{}",
        candidate_table(&d.data_errors, units)
    );
    if !d.held_out_tools.is_empty() {
        let rows: Vec<Vec<String>> = d
            .held_out_tools
            .iter()
            .map(|t| vec![escape(&t.session), escape(&t.text), yes(t.significant)])
            .collect();
        let _ = write!(
            body,
            "<h3>Tool moved in a held-out session</h3>{}",
            table(&["session", "finding", "called"], &rows)
        );
    }
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
    let groups: Vec<Vec<String>> =
        d.by_group.iter().map(|(n, count, r)| vec![escape(n), count.to_string(), mm(*r)]).collect();
    let _ = write!(
        body,
        "<h3>By held-out group</h3>{}",
        table(&["placement or session", "errors", "RMS mm"], &groups)
    );
    let worst: Vec<Vec<String>> =
        d.worst.iter().map(|w| vec![escape(&w.group), escape(&w.what), mm(w.error_mm)]).collect();
    let _ = write!(
        body,
        "<h3>Worst measurements</h3>{}",
        table(&["placement or session", "what", "error mm"], &worst)
    );
    page("kincal diagnosis", &body)
}
