//! `RUN/report.html`, one page for every kind of data: the verdict and the next command first,
//! then where the model fails, pictures first — held-out distances of artefact placements
//! (histograms, per landmark and placement, against each joint angle), held-out tracker sessions
//! (RMS per session against nominal and the floor; every point's residual against its order,
//! against each joint angle, and its direction) — then summary.json's tables: the fit, the
//! estimates, what the data cannot separate, outliers, data errors, solver starts, inputs.

use super::svg::{self, escape};
use super::{mm, page_end, page_start, table};
use crate::calib::diagnose::data_errors::sessions::MIN_GAIN;
use crate::calib::diagnose::data_errors::DataErrorKind;
use crate::calib::nuisance::tool::CONSTANT_ORIENTATION_DEG;
use crate::calib::run::{PointResidual, Run, SessionResiduals};
use crate::calib::setup::Objective;
use crate::calib::summary::{SessionFigures, Summary};
use crate::files::shell_word;
use crate::numerics::solver::StopReason;
use std::fmt::Write;
use std::path::Path;

/// The page is wider than the other reports: four residual plots side by side.
const WIDE: &str =
    "<style>body{max-width:1320px}p.note{color:#555;max-width:1000px}.words td{text-align:left}</style>";

/// A figure with `decimals` decimals, "—" when it is not a number (never `inf` or `NaN`).
fn num(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "—".into()
    }
}

/// A length in mm as the tracker run prints it (four decimals, as the CLI).
fn mm4(v: f64) -> String {
    num(v, 4)
}

/// A small ratio in scientific notation, "—" when it is not a number.
fn sci(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1e}")
    } else {
        "—".into()
    }
}

/// A value and its standard deviation, both to two significant digits of the deviation (at
/// least four decimals).
fn with_std(value: f64, std: Option<f64>) -> (String, String) {
    let decimals = match std {
        Some(s) if s.is_finite() && s > 0.0 => ((1.0 - s.log10().floor()).max(4.0) as usize).min(9),
        _ => 4,
    };
    (num(value, decimals), std.map_or("—".into(), |s| num(s, decimals)))
}

/// The run's verdict as the CLI prints it and the page shows it: the next command names the run's
/// folder `run_dir` (summary.json keeps the placeholder `RUN`, as it may be moved).
pub fn verdict_lines(s: &Summary, run_dir: &Path) -> Vec<String> {
    s.verdict.iter().map(|v| name_run(v, run_dir)).collect()
}

/// A line with the placeholder `RUN` of `kincal diagnose RUN` or `kincal plan RUN` replaced by
/// the run's folder, so the next command can be pasted as it is.
pub fn name_run(line: &str, run_dir: &Path) -> String {
    let run = shell_word(run_dir);
    ["diagnose", "plan"].iter().fold(line.to_string(), |text, command| {
        text.replace(&format!("kincal {command} RUN"), &format!("kincal {command} {run}"))
    })
}

/// The report of one run, written into `run_dir`.
pub fn run_report(run: &Run, run_dir: &Path) -> String {
    let mut page = String::with_capacity(residual_plot_bytes(run));
    let Ok(()) = run_report_in_parts(run, run_dir, &mut page, |_| Ok::<(), std::convert::Infallible>(()));
    page
}

/// [`run_report`] written at the end of `body` and handed to `part` piece by piece (after the
/// first sections, after each session's plots, at the end), which may take the text away: a
/// tracker run's page is megabytes of plots, and written to its file as it is made it is never
/// that much fresh memory at once. The pieces in order are the page; `part`'s error stops it.
pub(crate) fn run_report_in_parts<E>(
    run: &Run,
    run_dir: &Path,
    body: &mut String,
    mut part: impl FnMut(&mut String) -> Result<(), E>,
) -> Result<(), E> {
    let s = &run.summary;
    body.push_str(&page_start("kincal calibration report"));
    body.push_str(WIDE);
    if !s.not_trustworthy.is_empty() {
        let items: String =
            s.not_trustworthy.iter().map(|p| format!("<li>{}</li>", escape(&name_run(p, run_dir)))).collect();
        let _ = write!(body, "<h2>Not trustworthy: these figures are not a result</h2><ul>{items}</ul>");
    }
    verdict(body, s, run_dir);
    if run.distances.is_some() {
        distance_plots(body, run);
    }
    if s.validation.sessions.is_some() {
        rms_per_session(body, s);
    }
    part(body)?;
    for session in &run.held_out {
        body.reserve(session_plot_bytes(session));
        let figures = s.held_out_sessions().iter().find(|f| f.calibrated.name == session.name);
        held_out_plots(body, session, figures, s.inputs.float_tool.contains(&session.name));
        part(body)?;
    }
    for session in &run.calibration_residuals {
        body.reserve(session_plot_bytes(session));
        let points = s.calibration.groups.get(&session.name).copied().unwrap_or(session.points.len());
        let _ = write!(
            body,
            "<h2>Calibration session {}: the fit's residuals over {points} points</h2>",
            escape(&session.name)
        );
        residual_plots(body, &session.points, "the base, tool and drift fitted with the arm");
        part(body)?;
    }
    directions(body, s, &run.held_out);
    distance_tables(body, s);
    validation_tables(body, s);
    floor_section(body, s);
    calibration_tables(body, s);
    identifiability(body, s);
    objective_comparison(body, s);
    outliers(body, s);
    if let Some(rows) = &s.study {
        let _ = write!(body, "<h2>Dataset-size study</h2>{}", crate::report::study::study_body(rows));
    }
    data_errors(body, s);
    starts(body, s);
    inputs(body, s, run_dir);
    *body = page_end(std::mem::take(body));
    part(body)
}

/// About the size of a scatter plot's point (one `<circle>` element, its fill the group's).
const POINT_BYTES: usize = 40;
/// About the size of a scatter plot's frame (axes, ticks, labels).
const PLOT_BYTES: usize = 4096;

/// About the bytes of the sessions' residual plots, reserved for a whole page at its start: they
/// are most of it (megabytes), and growing the page as they are written copied it again and again.
fn residual_plot_bytes(run: &Run) -> usize {
    run.held_out.iter().chain(&run.calibration_residuals).map(session_plot_bytes).sum()
}

/// About the bytes of one session's residual plots.
fn session_plot_bytes(session: &SessionResiduals) -> usize {
    let joints = session.points.iter().map(|p| p.q_deg.len()).max().unwrap_or(0);
    // Size, three components, orientation, and one plot per joint.
    let plots = 5 + joints;
    plots * (PLOT_BYTES + POINT_BYTES * session.points.len())
}

fn verdict(body: &mut String, s: &Summary, run_dir: &Path) {
    let items: String = verdict_lines(s, run_dir).iter().map(|v| format!("<li>{}</li>", escape(v))).collect();
    let _ = write!(body, "<h2>Verdict</h2><ul>{items}</ul>");
}

/// The floor in words: its value and source, or why it is unknown.
fn floor_words(s: &Summary) -> String {
    let floor = s.point_floor();
    match floor.rms_mm.filter(|f| f.is_finite()) {
        Some(f) => format!("The floor is {} mm ({})", mm4(f), escape(&floor.source)),
        None => "The floor is unknown: the held-out sessions have no repeated poses (rows sharing a <code>pose</code> id) \
                 and no stated uncertainty (a <code>sigma_mm</code> or <code>u95_mm</code> column, or \
                 <code>--sigma-mm</code>), so the model is never said to explain the data"
            .into(),
    }
}

fn rms_per_session(body: &mut String, s: &Summary) {
    let sessions = s.held_out_sessions();
    if sessions.is_empty() {
        return;
    }
    let names: Vec<String> = sessions
        .iter()
        .map(|f| if f.transfers { f.calibrated.name.clone() } else { format!("{} ✗", f.calibrated.name) })
        .collect();
    let mut series = vec![
        ("calibrated", sessions.iter().map(|f| f.calibrated.rms_mm).collect::<Vec<_>>()),
        ("nominal", sessions.iter().map(|f| f.nominal.rms_mm).collect()),
    ];
    if let Some(f) = s.point_floor().rms_mm.filter(|f| f.is_finite()) {
        series.push(("floor", vec![f; sessions.len()]));
    }
    let failing: Vec<&str> =
        sessions.iter().filter(|f| !f.transfers).map(|f| f.calibrated.name.as_str()).collect();
    let transfer = if failing.is_empty() {
        "The calibration does better than nominal on every held-out session.".to_string()
    } else {
        format!(
            "<span class=flag>✗ does not transfer</span> to {}: the calibrated model is worse there than the nominal one.",
            escape(&failing.join(", "))
        )
    };
    let values: Vec<String> = sessions
        .iter()
        .map(|f| {
            format!(
                "{} {} mm (nominal {} mm)",
                escape(&f.calibrated.name),
                mm4(f.calibrated.rms_mm),
                mm4(f.nominal.rms_mm)
            )
        })
        .collect();
    let _ = write!(
        body,
        "<h2>Held-out RMS per session</h2>{}<p class=note>{}. Each held-out session's base refitted (closed form) \
         for the calibrated and for the nominal model (the nominal arm with only its tool fitted). {transfer} {}.</p>",
        svg::bars(&names, &series, "held-out RMS (mm)"),
        values.join("; "),
        floor_words(s)
    );
    let angles: Vec<(&SessionFigures, f64, f64)> = sessions
        .iter()
        .filter_map(|f| Some((f, f.orientation?.rms_deg, f.nominal_orientation?.rms_deg)))
        .collect();
    if !angles.is_empty() {
        let names: Vec<String> = angles.iter().map(|a| a.0.calibrated.name.clone()).collect();
        let _ = write!(
            body,
            "<h3>Held-out orientation RMS per session (6-DoF probe)</h3>{}",
            svg::bars(
                &names,
                &[
                    ("calibrated", angles.iter().map(|a| a.1).collect()),
                    ("nominal", angles.iter().map(|a| a.2).collect())
                ],
                "orientation RMS (deg)"
            )
        );
    }
}

/// The x axis of a session's residuals against its order: `time_s` when every row has it, else
/// a numeric `pose` id, else the row's place in the file.
fn order_axis(points: &[PointResidual]) -> (Vec<f64>, &'static str) {
    if let Some(t) = points.iter().map(|p| p.time_s).collect::<Option<Vec<f64>>>() {
        return (t, "time (s)");
    }
    let pose = |p: &PointResidual| p.pose.as_deref()?.trim().parse::<f64>().ok().filter(|v| v.is_finite());
    if let Some(ids) = points.iter().map(pose).collect::<Option<Vec<f64>>>() {
        return (ids, "pose id");
    }
    ((1..=points.len()).map(|k| k as f64).collect(), "point (file order)")
}

/// A [`svg::scatter`] of `points` in a `<figure>`, written straight into the page; nothing when
/// there is nothing to draw.
fn scatter_figure(body: &mut String, points: &[(f64, f64)], x_label: &str, y_label: &str) {
    let start = body.len();
    body.push_str("<figure>");
    if svg::scatter_into(body, points, &[], x_label, y_label) {
        body.push_str("</figure>");
    } else {
        body.truncate(start);
    }
}

fn held_out_plots(
    body: &mut String,
    session: &SessionResiduals,
    figures: Option<&SessionFigures>,
    tool_floated: bool,
) {
    let headline = figures.map_or(String::new(), |f| {
        format!(
            ": {} mm RMS over {} points (nominal {} mm){}{}",
            mm4(f.calibrated.rms_mm),
            f.calibrated.points,
            mm4(f.nominal.rms_mm),
            if tool_floated { ", its own tool fitted (<code>--float-tool</code>)" } else { "" },
            if f.transfers { "" } else { ", <span class=flag>does not transfer</span>" }
        )
    });
    let _ = write!(body, "<h2>Held-out session {}{headline}</h2>", escape(&session.name));
    residual_plots(body, &session.points, "the session's base refitted");
}

/// A session's residuals against its order (size, components, orientation) and against each
/// joint angle; `base` says how the session's base was found.
fn residual_plots(body: &mut String, points: &[PointResidual], base: &str) {
    if points.is_empty() {
        return;
    }
    // Each point's size once, for its plot against the order and those against each joint.
    let sizes: Vec<f64> =
        points.iter().map(|p| p.residual_mm.iter().map(|v| v * v).sum::<f64>().sqrt()).collect();
    let (order, order_label) = order_axis(points);
    let against = |values: &dyn Fn(&PointResidual) -> f64| -> Vec<(f64, f64)> {
        order.iter().zip(points).map(|(x, p)| (*x, values(p))).collect()
    };
    let _ = write!(
        body,
        "<p class=note>The residual (measured − predicted, {base}, turned into the robot's base frame) of each \
         point against {order_label}: its size, then its x, y and z components. A trend or a \
         period here is drift or a cause that repeats with the motion.</p>"
    );
    let size_points: Vec<(f64, f64)> = order.iter().copied().zip(sizes.iter().copied()).collect();
    scatter_figure(body, &size_points, order_label, "|residual| (mm)");
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        scatter_figure(body, &against(&|p| p.residual_mm[k]), order_label, &format!("{axis} residual (mm)"));
    }
    if points.iter().any(|p| p.orientation_error_deg.is_some()) {
        let angles: Vec<(f64, f64)> =
            order.iter().zip(points).filter_map(|(x, p)| Some((*x, p.orientation_error_deg?))).collect();
        scatter_figure(body, &angles, order_label, "orientation error (deg)");
    }
    let _ = write!(
        body,
        "<p class=note>The residual's size against each joint angle: a pattern that follows one joint (a \
         period in its angle, a sine of the gravity lever) is a cause of that joint the model lacks.</p>"
    );
    let joints = points.iter().map(|p| p.q_deg.len()).max().unwrap_or(0);
    for j in 0..joints {
        let pts: Vec<(f64, f64)> =
            points.iter().zip(&sizes).filter_map(|(p, size)| Some((*p.q_deg.get(j)?, *size))).collect();
        scatter_figure(body, &pts, &format!("q{} (deg)", j + 1), "|residual| (mm)");
    }
}

/// Largest size, in its session's RMS, the direction map tells apart.
const DIRECTION_CAP: f64 = 3.0;

/// Every held-out residual's direction on one map, coloured by its size against its session's
/// RMS (so that sessions of different sizes share the colours).
fn directions(body: &mut String, s: &Summary, sessions: &[SessionResiduals]) {
    let points: Vec<(f64, f64, f64)> = sessions
        .iter()
        .flat_map(|session| {
            let rms = s
                .held_out_sessions()
                .iter()
                .find(|f| f.calibrated.name == session.name)
                .map_or(f64::NAN, |f| f.calibrated.rms_mm);
            session.points.iter().filter_map(move |p| {
                let [x, y, z] = p.residual_mm;
                let size = (x * x + y * y + z * z).sqrt();
                let relative = (size / rms).min(DIRECTION_CAP);
                (size > 0.0 && relative.is_finite())
                    .then(|| (y.atan2(x), (z / size).clamp(-1.0, 1.0).asin(), relative))
            })
        })
        .collect();
    if points.is_empty() {
        return;
    }
    let _ = write!(
        body,
        "<h2>Directions of the held-out residuals</h2><p class=note>Each held-out point's residual direction in \
         the robot's base frame (equal-area map: latitude asin(z), so the top is +z, up for a floor-mounted arm, \
         and the bottom −z; longitude atan2(y, x), the centre +x, the edges −x). Noise spreads evenly; a \
         cluster is a direction the model misses in every pose (gravity sag points down). Colour: the residual's \
         size in its session's RMS, capped at {DIRECTION_CAP}.</p>{}",
        svg::hammer_map(&points, "residual size / its session's RMS")
    );
}

fn validation_tables(body: &mut String, s: &Summary) {
    let Some(v) = &s.validation.sessions else { return };
    let mut rows: Vec<Vec<String>> = v
        .sessions
        .iter()
        .map(|f| {
            let (c, n) = (&f.calibrated, &f.nominal);
            vec![
                escape(&c.name),
                c.points.to_string(),
                mm4(c.rms_mm),
                mm4(c.mean_mm),
                mm4(c.max_mm),
                mm4(c.pairwise_rms_mm),
                mm4(n.rms_mm),
                mm4(n.mean_mm),
                mm4(n.max_mm),
                mm4(n.pairwise_rms_mm),
                if f.transfers { "yes".into() } else { "<span class=flag>does not transfer</span>".into() },
            ]
        })
        .collect();
    let (o, n) = (&v.overall, &v.nominal_overall);
    rows.push(vec![
        "all held-out sessions".into(),
        o.count.to_string(),
        mm4(o.rms_mm),
        mm4(o.mean_mm),
        mm4(o.max_mm),
        String::new(),
        mm4(n.rms_mm),
        mm4(n.mean_mm),
        mm4(n.max_mm),
        String::new(),
        String::new(),
    ]);
    let _ = write!(
        body,
        "<h2>Validation on held-out sessions</h2><p class=note>Each session's base refitted; pairwise: the RMS \
         error of the distances between the session's points (no base at all).</p>{}",
        table(
            &[
                "session",
                "points",
                "RMS mm",
                "mean mm",
                "max mm",
                "pairwise mm",
                "nominal RMS mm",
                "nominal mean mm",
                "nominal max mm",
                "nominal pairwise mm",
                "transfers",
            ],
            &rows
        )
    );
    let mut angle_rows: Vec<Vec<String>> = v
        .sessions
        .iter()
        .filter_map(|f| {
            let (c, n) = (f.orientation?, f.nominal_orientation?);
            Some(vec![
                escape(&f.calibrated.name),
                c.orientations.to_string(),
                num(c.rms_deg, 5),
                num(c.mean_deg, 5),
                num(c.max_deg, 5),
                num(n.rms_deg, 5),
            ])
        })
        .collect();
    if let Some(o) = &v.orientation_overall {
        angle_rows.push(vec![
            "all held-out sessions".into(),
            o.orientations.to_string(),
            num(o.rms_deg, 5),
            num(o.mean_deg, 5),
            num(o.max_deg, 5),
            String::new(),
        ]);
    }
    let withheld: Vec<String> =
        v.sessions.iter().filter_map(|f| f.orientation_withheld.as_deref()).map(escape).collect();
    if !angle_rows.is_empty() || !withheld.is_empty() {
        let _ = write!(
            body,
            "<h3>Orientation (6-DoF probe), held out</h3>{}",
            table(
                &["session", "orientations", "RMS deg", "mean deg", "max deg", "nominal RMS deg"],
                &angle_rows
            )
        );
        for why in withheld {
            let _ = write!(body, "<p class=note>No orientation figure for {why}.</p>");
        }
    }
}

fn floor_section(body: &mut String, s: &Summary) {
    if let Some(g) = &s.floor.distance_gap {
        let _ = write!(body, "<h2>Floor of the held-out distances</h2><p>{}</p>", escape(&g.sentence()));
    }
    let Some(floor) = &s.floor.points else { return };
    let how = match floor.source.as_str() {
        "repeated poses" => {
            " The pooled scatter of rows sharing a pose id in the held-out sessions, shrunk by \
                             √(1 − 2/n) for the refitted base."
        }
        "stated uncertainty" => {
            " The stated σ per axis (a <code>sigma_mm</code> or <code>u95_mm</code> column, or \
                                 <code>--sigma-mm</code>) as a 3-D RMS σ·√3, shrunk by √(1 − 2/n) for the \
                                 refitted base."
        }
        _ => "",
    };
    let _ = write!(body, "<h2>Floor</h2><p>{}.{how}</p>", floor_words(s));
}

fn calibration_tables(body: &mut String, s: &Summary) {
    let c = &s.calibration;
    let groups: Vec<Vec<String>> =
        c.groups.iter().map(|(name, n)| vec![escape(name), n.to_string()]).collect();
    let what = match (&c.distances, &c.points) {
        (Some(d), _) => format!(
            "calibration RMS {} mm on {} distance pairs from {} observations",
            mm(d.rms_mm),
            c.pairs,
            c.observations
        ),
        (None, Some(p)) => format!(
            "calibration RMS {} mm (mean {}, max {}) on {} points",
            mm4(p.rms_mm),
            mm4(p.mean_mm),
            mm4(p.max_mm),
            p.count
        ),
        (None, None) => format!("calibration RMS {} mm", mm4(c.rms_mm)),
    };
    let huber =
        s.options.huber_delta_mm.map_or("plain least squares".into(), |d| format!("Huber δ = {d} mm"));
    let _ = write!(
        body,
        "<h2>Calibration</h2><p>{} joints; {what}; objective: {}, {huber}, {} random restarts (seed {}).</p>{}",
        s.joints,
        objective_words(&s.options.objective),
        s.options.restarts,
        s.options.seed,
        table(&["calibration placement or session", "observations"], &groups)
    );
    if let (Some(d), Some(p)) = (&c.distances, &c.points) {
        let _ = write!(
            body,
            "<p>Distances {} mm RMS over {} pairs; points {} mm RMS over {}.</p>",
            mm(d.rms_mm),
            d.count,
            mm4(p.rms_mm),
            p.count
        );
    }
    if let Some(o) = &c.orientations {
        let _ = write!(
            body,
            "<p>Calibration orientation RMS {}° (mean {}, max {}) on {} probe orientations.</p>",
            num(o.rms_deg, 5),
            num(o.mean_deg, 5),
            num(o.max_deg, 5),
            o.orientations
        );
    }
    let ident = &s.identifiability.report;
    let rows: Vec<Vec<String>> = c
        .estimates
        .iter()
        .map(|e| {
            let (value, std) = with_std(e.value, e.std);
            let change = with_std(e.value - e.nominal, e.std).0;
            let status = if ident.estimated.contains(&e.param) {
                e.status.as_str()
            } else if ident.fixed.contains(&e.param) {
                "held at nominal: not identifiable"
            } else {
                "fixed by the model"
            };
            vec![escape(&e.param), escape(&e.unit), num(e.nominal, 4), value, std, change, status.into()]
        })
        .collect();
    let _ = write!(
        body,
        "<h3>Estimates</h3>{}",
        table(&["parameter", "unit", "nominal", "calibrated", "σ", "change", "status"], &rows)
    );
    if let Some(t) = &c.tool_rotation {
        let [x, y, z] = t.rotation_vector_deg;
        let std = t.std_deg.map_or("no deviation: the normal matrix is singular".into(), |[a, b, c]| {
            format!("σ about the probe's axes {}, {}, {}°", num(a, 5), num(b, 5), num(c, 5))
        });
        let _ = write!(
            body,
            "<p>The probe on the flange (6-DoF): rotation vector ({}, {}, {})°, {std}.</p>",
            num(x, 4),
            num(y, 4),
            num(z, 4)
        );
    }
    if !c.tool_offsets.is_empty() {
        let rows: Vec<Vec<String>> = c
            .tool_offsets
            .iter()
            .map(|t| {
                let cell = |k: usize| {
                    if t.determined(k) {
                        mm4(t.offset_mm[k])
                    } else {
                        format!("— (σ {})", mm4(t.std_mm[k]))
                    }
                };
                vec![escape(&t.session), cell(0), cell(1), cell(2), mm4(t.size_std_mm)]
            })
            .collect();
        let _ = write!(
            body,
            "<h3>Floated tools (<code>--float-tool</code>, flange frame)</h3>{}",
            table(&["session", "x mm", "y mm", "z mm", "σ of the length mm"], &rows)
        );
    }
    if !c.drifts.is_empty() {
        let rows: Vec<Vec<String>> = c
            .drifts
            .iter()
            .map(|d| {
                let rate: Vec<String> = d.rate.iter().map(|v| mm4(*v)).collect();
                vec![
                    escape(&d.session),
                    escape(d.kind.name()),
                    format!("({})", rate.join(", ")),
                    escape(&d.unit),
                    mm4(d.rate_std),
                    mm4(d.centre),
                ]
            })
            .collect();
        let _ = write!(
            body,
            "<h3>Drifting sessions (<code>--drift-session</code>; a shift's rate in the instrument frame)</h3>{}",
            table(&["session", "kind", "rate", "unit", "σ of the rate", "zero at (h or °C)"], &rows)
        );
    }
}

fn identifiability(body: &mut String, s: &Summary) {
    let ident = &s.identifiability.report;
    let statements: String = ident.statements.iter().map(|t| format!("<li>{}</li>", escape(t))).collect();
    let _ = write!(
        body,
        "<h2>What the data cannot separate</h2><ul>{}</ul>",
        if statements.is_empty() {
            "<li>nothing: every free parameter is estimated</li>".into()
        } else {
            statements
        }
    );
    let spread: Vec<Vec<String>> = ident
        .orientation_spread_deg
        .iter()
        .map(|(name, deg)| {
            let constant = if *deg < CONSTANT_ORIENTATION_DEG {
                "constant: its tool point and base translation are one thing"
            } else {
                "turns"
            };
            vec![escape(name), num(*deg, 2), constant.into()]
        })
        .collect();
    if !spread.is_empty() {
        let _ = write!(
            body,
            "<h3>Tool orientation within each calibration session</h3>{}",
            table(&["session", "spread deg", "orientation"], &spread)
        );
    }
    let combos = |list: &[crate::calib::identify::Combination]| -> String {
        list.iter()
            .map(|c| match c.relative_singular_value {
                // Summaries written before the threshold carry rounding-level figures: not shown.
                Some(relative) if relative >= crate::calib::identify::EXACT_NULL_BELOW => {
                    format!("<li>{} (σ/σ₁ = {})</li>", escape(&c.text), sci(relative))
                }
                _ => format!("<li>{} (σ/σ₁ zero at rounding level)</li>", escape(&c.text)),
            })
            .collect()
    };
    if !ident.unidentifiable.is_empty() {
        let _ = write!(
            body,
            "<p>Directions the data cannot determine:</p><ul>{}</ul>",
            combos(&ident.unidentifiable)
        );
    }
    if !ident.poorly_identified.is_empty() {
        let _ = write!(
            body,
            "<p>Directions it determines only weakly:</p><ul>{}</ul>",
            combos(&ident.poorly_identified)
        );
    }
    if let Some(before) = &s.identifiability.before {
        let _ = write!(
            body,
            "<p>Before solving (nominal values, block unknowns projected out): condition number {}; \
             {} directions not determined, {} weakly.</p>",
            // σ_n = 0 when a direction is not determined: the ratio is no number, it is unbounded.
            if before.condition_number.is_finite() {
                sci(before.condition_number)
            } else {
                "unbounded".into()
            },
            before.unidentifiable.len(),
            before.poorly_identified.len()
        );
    }
    let corr: Vec<Vec<String>> = s
        .calibration
        .correlations
        .iter()
        .map(|(a, b, r)| vec![escape(a), escape(b), format!("{r:+.3}")])
        .collect();
    if !corr.is_empty() {
        let _ = write!(body, "<h3>Strong correlations (|ρ| &gt; 0.9)</h3>{}", table(&["a", "b", "ρ"], &corr));
    }
}

/// The held-out distances of artefact placements: histograms, per landmark, against each joint.
fn distance_plots(body: &mut String, run: &Run) {
    let Some((calibrated, nominal)) = &run.distances else { return };
    let errors = |v: &crate::calib::validate::Validation| -> Vec<f64> {
        v.errors.iter().map(|e| e.error_mm).collect()
    };
    let _ = write!(
        body,
        "<h2>Held-out distances</h2><h3>Distance errors, nominal</h3>{}<h3>Distance errors, calibrated</h3>{}",
        svg::histogram(&[("nominal", &errors(nominal))], 40, "distance error (mm)"),
        svg::histogram(&[("calibrated", &errors(calibrated))], 40, "distance error (mm)")
    );
    let names: Vec<String> = calibrated.per_landmark.iter().map(|g| g.name.clone()).collect();
    let rms: Vec<f64> = calibrated.per_landmark.iter().map(|g| g.stats.rms_mm).collect();
    let _ = write!(
        body,
        "<h3>RMS error per landmark</h3>{}",
        svg::bars(&names, &[("calibrated", rms)], "RMS (mm)")
    );
    let _ = write!(
        body,
        "<h3>Calibrated distance errors against each joint angle</h3><p class=note>Each held-out distance's \
         error at both touches' angles: a pattern that follows one joint (a period in its angle) is a cause of \
         that joint the model lacks.</p>"
    );
    let val = &run.validation_data;
    for j in 0..run.nominal.joints.len() {
        let pts: Vec<(f64, f64)> = calibrated
            .errors
            .iter()
            .flat_map(|e| [e.touches.0, e.touches.1].map(|t| (val.obs[t].q_deg[j], e.error_mm)))
            .collect();
        scatter_figure(body, &pts, &format!("encoder {} (deg)", j + 1), "error (mm)");
    }
}

/// The held-out distances' tables: both models, per landmark, per placement, repeatability.
fn distance_tables(body: &mut String, s: &Summary) {
    let Some(v) = &s.validation.distances else { return };
    let stats_row = |name: &str, v: &crate::calib::error_stats::ErrorStats| {
        vec![name.to_string(), mm(v.rms_mm), mm(v.mean_mm), mm(v.std_mm), mm(v.max_mm), v.count.to_string()]
    };
    let _ = write!(
        body,
        "<h2>Validation (held-out placements)</h2>{}",
        table(
            &["model", "RMS mm", "mean mm", "std mm", "max mm", "pairs"],
            &[stats_row("nominal", &v.nominal), stats_row("calibrated", &v.calibrated)]
        )
    );
    let d = &v.detail;
    let landmarks: Vec<Vec<String>> = d
        .per_landmark
        .iter()
        .map(|c| {
            let nominal =
                d.nominal_per_landmark.iter().find(|g| g.name == c.name).map_or(f64::NAN, |g| g.stats.rms_mm);
            vec![escape(&c.name), num(nominal, 3), mm(c.stats.rms_mm)]
        })
        .collect();
    let _ = write!(body, "{}", table(&["landmark", "nominal RMS mm", "calibrated RMS mm"], &landmarks));
    let placements: Vec<Vec<String>> = d
        .per_placement
        .iter()
        .zip(&d.nominal_per_placement)
        .map(|(c, n)| {
            vec![escape(&c.name), mm(n.stats.rms_mm), mm(c.stats.rms_mm), c.stats.count.to_string()]
        })
        .collect();
    let _ = write!(
        body,
        "<h3>Per placement</h3>{}",
        table(&["placement", "nominal RMS mm", "calibrated RMS mm", "pairs"], &placements)
    );
    let rep: Vec<Vec<String>> = d
        .repeatability
        .iter()
        .map(|r| vec![escape(&r.landmark), r.touches.to_string(), mm(r.rms_mm), mm(r.rp_mm)])
        .collect();
    let _ = write!(
        body,
        "<h3>Repeatability (ISO 9283 RP = mean + 3·std of distance to barycentre)</h3>{}",
        table(&["landmark", "touches", "RMS mm", "RP mm"], &rep)
    );
}

/// What relative orientation adds to distances (artefact touches).
fn objective_comparison(body: &mut String, s: &Summary) {
    let Some(oc) = &s.objective_comparison else { return };
    let list = |v: &[String]| if v.is_empty() { "none".into() } else { escape(&v.join(", ")) };
    let rows: Vec<Vec<String>> = oc
        .std
        .iter()
        .map(|(p, a, b)| {
            vec![escape(p), a.map_or("—".into(), |v| num(v, 4)), b.map_or("—".into(), |v| num(v, 4))]
        })
        .collect();
    let _ = write!(
        body,
        "<h3>What relative orientation adds</h3><p>Identifiable from distances: {}. With relative orientation: {}. \
         Gained: {}.</p>{}",
        list(&oc.identifiable_by_distance),
        list(&oc.identifiable_by_six_dof),
        list(&oc.gained_by_orientation),
        table(&["parameter", "std, distances", "std, + orientation"], &rows)
    );
}

/// The appendix-F outlier metrics per landmark and per calibration session.
fn outliers(body: &mut String, s: &Summary) {
    if s.outliers_skipped {
        body.push_str(
            "<h2>Outlier diagnostics (thesis appendix F)</h2><p>Skipped (<code>--no-outliers</code>): no \
             landmark or session was checked.</p>",
        );
        return;
    }
    if s.outliers.is_empty() {
        return;
    }
    let rows: Vec<Vec<String>> = s
        .outliers
        .iter()
        .map(|o| {
            let cell = |v: Option<f64>, name: &str| {
                // No figure when the refit without the unit was impossible (the only session).
                let Some(v) = v else { return "–".to_string() };
                // Only a flagged row is coloured: one metric over its threshold is common on clean data.
                if o.flagged && o.exceeded.iter().any(|e| e == name) {
                    format!("<span class=flag>{}</span>", num(v, 3))
                } else {
                    num(v, 3)
                }
            };
            vec![
                format!("{} {}", escape(&o.what), escape(&o.name)),
                cell(Some(o.contribution_pct), "contribution"),
                cell(o.cooks_distance, "cooks_distance"),
                cell(o.loo_impact_pct, "leave_one_out"),
                cell(Some(o.bias_mm), "bias"),
                if o.flagged { "<span class=flag>flagged</span>".into() } else { "not flagged".into() },
            ]
        })
        .collect();
    let _ = write!(
        body,
        "<h2>Outlier diagnostics (thesis appendix F)</h2><p>Thresholds: contribution &gt; 1.5× its share, Cook's \
         distance &gt; 4/L, leave-one-out improvement &gt; 5 %, bias &gt; 1 mm (a landmark) or 1.5× the \
         RMS of every point (a session); flagged when two or more exceed.</p>{}",
        table(&["landmark or session", "contribution %", "Cook's D", "LOO impact %", "bias mm", "verdict"], &rows)
    );
}

/// Why a solver start stopped, in words.
fn stop_words(stop: StopReason) -> &'static str {
    match stop {
        StopReason::CostConverged => "the cost stopped falling",
        StopReason::StepConverged => "the step became negligible",
        StopReason::GradientConverged => "the gradient vanished",
        StopReason::NoProgress => "no step lowered the cost",
        StopReason::IterationLimit => "iteration limit",
    }
}

/// The objective in words.
fn objective_words(objective: &Objective) -> String {
    match objective {
        Objective::Distance => "positions only".into(),
        Objective::SixDof { lever_mm: Some(l) } => format!("positions and orientations ({l} mm per radian)"),
        Objective::SixDof { lever_mm: None } => "positions and orientations".into(),
    }
}

/// Every solver start.
fn starts(body: &mut String, s: &Summary) {
    let rows: Vec<Vec<String>> = s
        .calibration
        .starts
        .iter()
        .map(|st| {
            vec![
                st.start.to_string(),
                num(st.initial_cost, 4),
                num(st.final_cost, 6),
                st.iterations.to_string(),
                stop_words(st.stop).into(),
            ]
        })
        .collect();
    if !rows.is_empty() {
        let _ = write!(
            body,
            "<h2>Solver starts</h2>{}",
            table(&["start", "initial cost", "final cost", "iterations", "stop"], &rows)
        );
    }
}

fn data_errors(body: &mut String, s: &Summary) {
    if s.validation.sessions.is_none() {
        return;
    }
    if s.data_errors.is_empty() {
        body.push_str("<h2>Data errors</h2><p>No candidate was scored.</p>");
        return;
    }
    let rows: Vec<Vec<String>> = s
        .data_errors
        .iter()
        .map(|d| {
            let unit = match d.kind {
                DataErrorKind::Drift => "mm/h",
                DataErrorKind::ProbeTurned => "°",
                _ => "mm",
            };
            vec![
                escape(d.kind.word()),
                escape(&d.session),
                escape(d.set.word()),
                format!("{} ± {} {unit}", mm4(d.size_mm), mm4(d.size_std_mm)),
                format!("{} → {}", mm4(d.held_out_before_mm), mm4(d.held_out_after_mm)),
                if d.significant { "<span class=flag>called</span>".into() } else { "not called".into() },
                format!("<code>{}</code>", escape(&d.action)),
                escape(&d.text),
            ]
        })
        .collect();
    let _ = write!(
        body,
        "<h2>Data errors</h2><p class=note>Candidates scored on the held-out sessions, best first; one is called \
         when its size is beyond 3 σ and it lowers the held-out error by {:.0} % or more. Apply it with its \
         option and run again.</p><div class=words>{}</div>",
        100.0 * MIN_GAIN,
        table(&["kind", "session", "set", "size", "held-out RMS mm", "called", "option", "what it means"], &rows)
    );
}

fn inputs(body: &mut String, s: &Summary, run_dir: &Path) {
    let i = &s.inputs;
    let mut items = vec![
        format!("model <code>{}</code>", escape(&i.model.display().to_string())),
        format!("calibration sessions <code>{}</code>", escape(&i.calibration.display().to_string())),
        format!("held-out sessions <code>{}</code>", escape(&i.validation.display().to_string())),
    ];
    if let Some(a) = &i.artefact {
        items.insert(1, format!("artefact <code>{}</code>", escape(&a.display().to_string())));
    }
    if let Some(sigma) = i.stated_sigma_mm {
        items.push(format!("<code>--sigma-mm {}</code>", num(sigma, 4)));
    }
    if let Some(sigma) = i.orientation_sigma_deg {
        items.push(format!("<code>--orientation-sigma-deg {}</code>", num(sigma, 4)));
    }
    let drifts: Vec<String> = i.drift_sessions.iter().map(ToString::to_string).collect();
    for (option, values) in [
        ("--add", &i.add),
        ("--exclude-landmark", &i.exclude_landmarks),
        ("--exclude-block", &i.exclude_blocks),
        ("--float-tool", &i.float_tool),
        ("--exclude-point", &i.exclude_points),
        ("--drift-session", &drifts),
        ("--same-base", &i.same_base),
    ] {
        for v in values {
            items.push(format!("<code>{option} {}</code>", escape(v)));
        }
    }
    items.extend(s.warnings.iter().map(|w| format!("warning: {}", escape(&name_run(w, run_dir)))));
    let list: String = items.iter().map(|t| format!("<li>{t}</li>")).collect();
    let _ = write!(body, "<h2>Inputs</h2><ul>{list}</ul><p>kincal {}</p>", escape(&s.kincal_version));
}
