//! `RUN/certificate.html`: the calibration certificate of one RUN, as a calibration laboratory
//! issues one — printable to PDF from a browser. It leads with its verdict and the next command,
//! then states which arm was calibrated, by which RUN (its hash, so the record can be checked
//! against the files and against the set a controller stores), against which reference and data,
//! with which result against the noise floor and its uncertainty, for how long, what the
//! calibration does not cover, and how to re-check it. It reads what [`Certificate`] holds and
//! computes nothing.

use super::svg::escape;
use super::{mm, table};
use crate::calib::floor::Gap;
use crate::calib::run::EXPLAINS_WITHIN;
use crate::calib::summary::Summary;
use crate::trace::{utc, UploadRecord};
use std::fmt::Write;
use std::path::PathBuf;

/// Title of the page (and what marks a certificate kincal wrote).
pub const CERTIFICATE_TITLE: &str = "Calibration certificate";

/// Whether an input file is still the one the RUN read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileState {
    /// Its SHA-256 is the one the RUN recorded.
    Unchanged,
    /// It exists with another content.
    Changed,
    /// It is gone (moved, deleted).
    Missing,
    /// The RUN recorded no hash of it (written before kincal recorded them).
    NotRecorded,
}

impl FileState {
    fn words(self) -> &'static str {
        match self {
            FileState::Unchanged => "unchanged",
            FileState::Changed => "CHANGED since",
            FileState::Missing => "MISSING",
            FileState::NotRecorded => "not recorded",
        }
    }
}

/// One input file of the RUN: its recorded hash and whether it still matches.
#[derive(Clone, Debug)]
pub struct InputFile {
    /// What it is: `model`, `artefact`, `calibration`, `validation`.
    pub role: String,
    /// The file.
    pub path: PathBuf,
    /// The SHA-256 the RUN recorded (hex).
    pub sha256: Option<String>,
    /// Whether the file on disk still has it.
    pub state: FileState,
}

/// One session (artefact placement or instrument session) the RUN read.
#[derive(Clone, Debug)]
pub struct SessionFacts {
    /// `calibration` or `validation`.
    pub purpose: &'static str,
    /// `artefact`, `tracker` or `point-distances`.
    pub kind: &'static str,
    /// Placement or session name.
    pub name: String,
    /// Observations read (touches or points).
    pub observations: usize,
    /// Repeats of the placement (1 for an instrument session).
    pub repeats: u32,
    /// First and last touch, Unix seconds, when the session records them.
    pub recorded_unix_s: Option<(u64, u64)>,
    /// Lowest and highest temperature of its rows, °C, when recorded.
    pub temp_c: Option<(f64, f64)>,
    /// The arm its file names.
    pub arm: Option<String>,
}

/// The readings of one joint the data visited: the shortest arc of the circle holding them all.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointArc {
    /// Start of the arc, degrees in [0, 360).
    pub from_deg: f64,
    /// Its length, degrees (0 to 360).
    pub span_deg: f64,
}

/// Everything the certificate states, gathered from the RUN folder and its inputs.
#[derive(Clone, Debug)]
pub struct Certificate {
    /// The RUN folder.
    pub run: PathBuf,
    /// Its hash as the files on disk give it ([`crate::trace::run_sha256`], hex).
    pub run_sha256: String,
    /// `summary.json`.
    pub summary: Summary,
    /// The calibrated model's name.
    pub model_name: String,
    /// Uploads of the RUN's model (`uploads.json`), oldest first.
    pub uploads: Vec<UploadRecord>,
    /// Every input file with its state.
    pub inputs: Vec<InputFile>,
    /// The sessions read, calibration first; empty when the inputs could not be read again.
    pub sessions: Vec<SessionFacts>,
    /// Per joint, the arc of readings visited (calibration and validation); empty when the
    /// inputs could not be read again.
    pub coverage: Vec<JointArc>,
    /// Why the inputs could not be read again (sessions and coverage are then not shown).
    pub inputs_unreadable: Option<String>,
    /// The artefact's landmarks and their largest distance, mm, when there is one.
    pub artefact_landmarks: Option<(usize, f64)>,
    /// Who issues the certificate (`--operator`).
    pub operator: Option<String>,
    /// When it was issued, Unix seconds.
    pub issued_at_unix_s: u64,
}

/// The certificate's verdict: its class, headline and sentence.
#[derive(Clone, Debug)]
pub struct Verdict {
    /// `pass` (calibrated, at the floor), `warn` (calibrated, with a reservation the sentence
    /// states) or `fail` (no calibration can be certified: not a result, no arm, inputs or
    /// model changed since).
    pub class: &'static str,
    /// The headline, e.g. `CALIBRATED`.
    pub headline: String,
    /// The result in one paragraph.
    pub sentence: String,
}

impl Certificate {
    /// Inputs whose content is no longer what the RUN read.
    fn altered_inputs(&self) -> Vec<&InputFile> {
        self.inputs.iter().filter(|f| matches!(f.state, FileState::Changed | FileState::Missing)).collect()
    }

    /// The uploads whose set names another RUN hash than the files give now.
    fn foreign_uploads(&self) -> Vec<&UploadRecord> {
        self.uploads.iter().filter(|u| u.run_sha256 != self.run_sha256).collect()
    }

    /// The verdict the page leads with.
    pub fn verdict(&self) -> Verdict {
        let s = &self.summary;
        if !s.not_trustworthy.is_empty() {
            return Verdict {
                class: "fail",
                headline: "NOT CALIBRATED".into(),
                sentence: format!(
                    "The figures of this RUN are not a result: {}. No certificate of calibration can be issued.",
                    s.not_trustworthy.join("; ")
                ),
            };
        }
        if s.provenance.arm.is_none() {
            return Verdict {
                class: "fail",
                headline: "NO ARM IDENTIFIED".into(),
                sentence: "The sessions of this RUN name no arm (simulated, hand-written, or recorded before kincal \
                           wrote the arm's identity): the result belongs to no identified device. Record the \
                           sessions with `kincal record` on the arm."
                    .into(),
            };
        }
        let (class, headline, result) = match (&s.floor.distance_gap, s.validation.sessions.as_ref()) {
            (Some(g), _) => gap_verdict(g),
            (None, Some(v)) => match s.point_floor().rms_mm.filter(|f| f.is_finite() && *f > 0.0) {
                Some(floor) if v.overall.rms_mm <= EXPLAINS_WITHIN * floor => (
                    "pass",
                    "CALIBRATED",
                    format!(
                        "held-out point error {} mm RMS over {} points, within {:.0} % of the floor {} mm ({})",
                        mm(v.overall.rms_mm),
                        v.overall.count,
                        (EXPLAINS_WITHIN - 1.0) * 100.0,
                        mm(floor),
                        s.point_floor().source
                    ),
                ),
                Some(floor) => (
                    "warn",
                    "CALIBRATED, ABOVE THE FLOOR",
                    format!(
                        "held-out point error {} mm RMS over {} points, above the floor {} mm ({}): the model misses something",
                        mm(v.overall.rms_mm),
                        v.overall.count,
                        mm(floor),
                        s.point_floor().source
                    ),
                ),
                None => (
                    "warn",
                    "CALIBRATED, FLOOR UNKNOWN",
                    format!(
                        "held-out point error {} mm RMS over {} points; the floor is unknown (no repeated poses, no stated σ)",
                        mm(v.overall.rms_mm),
                        v.overall.count
                    ),
                ),
            },
            (None, None) => (
                "warn",
                "CALIBRATED, FLOOR UNKNOWN",
                format!(
                    "held-out distance error {} mm RMS; no landmark was touched twice, so the floor is unknown",
                    mm(s.held_out_rms_mm())
                ),
            ),
        };
        let mut sentence = format!("{}: {result}.", arm_words(s));
        let altered = self.altered_inputs();
        let foreign = self.foreign_uploads();
        let class = if altered.is_empty() && foreign.is_empty() { class } else { "fail" };
        if !altered.is_empty() {
            let names: Vec<String> =
                altered.iter().map(|f| format!("{} ({})", f.path.display(), f.state.words())).collect();
            let _ = write!(
                sentence,
                " The inputs on disk are no longer the ones calibrated: {}.",
                names.join(", ")
            );
        }
        if !foreign.is_empty() {
            let _ = write!(
                sentence,
                " {} upload(s) recorded here carry another RUN hash than these files give: model.toml or \
                 summary.json changed after the upload.",
                foreign.len()
            );
        }
        Verdict { class, headline: headline.into(), sentence }
    }

    /// The command to run next.
    pub fn next_command(&self) -> String {
        let run = self.run.display();
        let arm = self.summary.provenance.arm.as_ref().map_or("ARM".to_string(), |a| a.id.clone());
        if !self.summary.not_trustworthy.is_empty() || self.summary.provenance.arm.is_none() {
            return format!("kincal diagnose {run}");
        }
        if self.uploads.is_empty() {
            return format!(
                "kincal upload --key STATION.key --port PORT {run}/model.toml --valid-days 365   # arm {arm}"
            );
        }
        self.check_command()
    }

    /// The command that re-checks the arm against its stored set.
    fn check_command(&self) -> String {
        let artefact =
            self.summary.inputs.artefact.as_ref().map_or("ARTEFACT.json".into(), |a| a.display().to_string());
        let placement = self
            .sessions
            .iter()
            .find(|s| s.purpose == "validation" && s.kind == "artefact")
            .map_or("PLACEMENT".to_string(), |s| s.name.clone());
        format!(
            "kincal check --port PORT --artefact {artefact} --placement {placement} --out checks/YYYY-MM-DD"
        )
    }
}

/// The headline and the result sentence of a distance gap.
fn gap_verdict(g: &Gap) -> (&'static str, &'static str, String) {
    let head = format!(
        "held-out distance error {} mm RMS against {} mm expected from repeatability",
        mm(g.measured_mm),
        mm(g.expected_mm)
    );
    if g.significant {
        (
            "warn",
            "CALIBRATED, ABOVE THE FLOOR",
            format!(
                "{head}: the model misses {}–{} mm (95 %), {:.1} standard errors above the floor",
                mm(g.missing_95_mm.0),
                mm(g.missing_95_mm.1),
                g.z
            ),
        )
    } else if g.at_floor {
        (
            "pass",
            "CALIBRATED",
            format!(
                "{head}: at the noise floor (anything the model misses is at most {} mm at 95 %)",
                mm(g.missing_95_mm.1)
            ),
        )
    } else {
        (
            "warn",
            "CALIBRATED, AT THE FLOOR NOT SHOWN",
            format!(
                "{head}: not significantly above the floor, yet these held-out data cannot show it is at the floor \
                 (a miss below {} mm goes unseen)",
                mm(g.detectable_mm)
            ),
        )
    }
}

fn arm_words(s: &Summary) -> String {
    match &s.provenance.arm {
        Some(arm) => format!("Arm {}", arm.id),
        None => "No identified arm".into(),
    }
}

/// Definition-list rows `(term, already escaped HTML)`.
fn facts(rows: &[(&str, String)]) -> String {
    let mut out = String::from("<table class=\"facts\">");
    for (term, value) in rows {
        let _ = write!(out, "<tr><th>{}</th><td>{value}</td></tr>", escape(term));
    }
    out + "</table>"
}

fn code(text: &str) -> String {
    format!("<code>{}</code>", escape(text))
}

fn date(unix_s: Option<u64>) -> String {
    unix_s.map_or("not recorded".into(), |t| escape(&utc(t)))
}

/// The arc `from` to `from + span` as readings, e.g. `12.3° to 147.8°`, or `305.5° through 0°
/// to 56.5°` when it wraps.
fn arc_words(arc: &JointArc) -> String {
    let end = arc.from_deg + arc.span_deg;
    if end >= 360.0 {
        format!("{:.1}° through 0° to {:.1}°", arc.from_deg, end - 360.0)
    } else {
        format!("{:.1}° to {:.1}°", arc.from_deg, end)
    }
}

const STYLE: &str = "body{font-family:Georgia,'DejaVu Serif',serif;max-width:900px;margin:2em auto;color:#111;line-height:1.35}\
h1{font-size:1.6em;margin:0}h2{font-size:1.15em;border-bottom:1px solid #999;margin-top:1.6em}\
.head{display:flex;justify-content:space-between;align-items:flex-end;border-bottom:3px double #333;padding-bottom:.4em}\
.head .no{font-family:monospace;font-size:.85em;text-align:right}\
.verdict{border:3px solid;padding:.6em 1em;margin:1em 0}.verdict h2{border:0;margin:0 0 .3em 0;font-size:1.4em}\
.pass{border-color:#1a7f37;background:#eef8f0}.pass h2{color:#1a7f37}\
.warn{border-color:#b26b00;background:#fff6e5}.warn h2{color:#8a5300}\
.fail{border-color:#b00;background:#fdecec}.fail h2{color:#b00}\
.next code{font-size:.9em}table{border-collapse:collapse;margin:.6em 0;font-size:.92em}\
td,th{border:1px solid #bbb;padding:3px 7px;text-align:right;vertical-align:top}th{background:#f1f1f1}\
td:first-child{text-align:left}table.facts th{text-align:left;width:14em}table.facts td{text-align:left}\
code{font-family:monospace;word-break:break-all}.hash{font-family:monospace;font-size:.85em;word-break:break-all}\
.sign{display:flex;gap:3em;margin-top:2.5em}.sign div{flex:1;border-top:1px solid #333;padding-top:.3em;font-size:.9em}\
.flag{color:#b00;font-weight:bold}p.small{font-size:.85em;color:#444}\
@media print{body{margin:0;max-width:none}.verdict{break-inside:avoid}h2{break-after:avoid}}";

/// The certificate page.
pub fn certificate_page(c: &Certificate) -> String {
    let s = &c.summary;
    let p = &s.provenance;
    let verdict = c.verdict();
    let mut body = String::new();
    let _ = write!(
        body,
        "<div class=\"head\"><div><h1>{CERTIFICATE_TITLE}</h1><div>kinematic calibration of a serial arm</div></div>\
         <div class=\"no\">certificate of RUN<br>sha256:{}<br>issued {}</div></div>",
        escape(&c.run_sha256[..16.min(c.run_sha256.len())]),
        escape(&utc(c.issued_at_unix_s))
    );
    let _ = write!(
        body,
        "<div class=\"verdict {}\"><h2>{}</h2><p>{}</p><p class=\"next\">Next: {}</p></div>",
        verdict.class,
        escape(&verdict.headline),
        escape(&verdict.sentence),
        code(&c.next_command())
    );

    // 1. The device and the record.
    let arm = p.arm.as_ref();
    let uploads_words = if c.uploads.is_empty() {
        "not uploaded yet".to_string()
    } else {
        c.uploads
            .iter()
            .map(|u| {
                format!(
                    "version {} on arm {} by {} at {}{}",
                    u.param_version,
                    escape(&u.arm.id),
                    code(&u.signer),
                    escape(&utc(u.signed_at_unix_s)),
                    if u.run_sha256 == c.run_sha256 {
                        ""
                    } else {
                        " <span class=\"flag\">(another RUN hash)</span>"
                    }
                )
            })
            .collect::<Vec<_>>()
            .join("<br>")
    };
    let _ = write!(
        body,
        "<h2>1. Device calibrated</h2>{}",
        facts(&[
            (
                "Arm (controller identity)",
                arm.map_or("<span class=\"flag\">none named by the sessions</span>".into(), |a| code(&a.id))
            ),
            (
                "Controller firmware",
                arm.and_then(|a| a.firmware.as_deref()).map_or("not recorded".into(), escape)
            ),
            ("Controller board", arm.and_then(|a| a.board.as_deref()).map_or("not recorded".into(), escape)),
            ("Calibrated and validated", date(p.validated_at_unix_s)),
            (
                "RUN",
                format!(
                    "{}<br><span class=\"hash\">sha256:{}</span>",
                    code(&c.run.display().to_string()),
                    escape(&c.run_sha256)
                )
            ),
            ("Stored on the controller", uploads_words),
            ("Computed by", format!("kincal {}", escape(&s.kincal_version))),
        ])
    );

    // 2. Reference and data.
    let mut reference = Vec::new();
    if let Some(artefact) = &s.inputs.artefact {
        let landmarks = c
            .artefact_landmarks
            .map_or(String::new(), |(n, span)| format!("; {n} landmarks over {} mm", mm(span)));
        reference.push((
            "Artefact",
            format!(
                "{}; certificate {}{landmarks}",
                code(&artefact.display().to_string()),
                p.artefact_certificate
                    .as_deref()
                    .map_or("<span class=\"flag\">not stated in the artefact file</span>".into(), escape)
            ),
        ));
    }
    if s.validation.sessions.is_some() || s.calibration.points.is_some() {
        let sigma =
            s.inputs.stated_sigma_mm.map_or("as its files state, or from repeated poses".into(), |v| {
                format!("{} mm per axis (stated)", mm(v))
            });
        reference
            .push(("Instrument sessions", format!("points measured by an instrument; uncertainty {sigma}")));
    }
    reference.push(("Data kind", escape(s.kind.word())));
    let _ = write!(body, "<h2>2. Reference and data</h2>{}", facts(&reference));
    if let Some(why) = &c.inputs_unreadable {
        let _ = write!(body, "<p class=\"flag\">The sessions could not be read again: {}. Coverage and per-session figures are not shown.</p>", escape(why));
    } else {
        let rows: Vec<Vec<String>> = c
            .sessions
            .iter()
            .map(|f| {
                vec![
                    escape(&f.name),
                    f.purpose.into(),
                    f.kind.into(),
                    f.observations.to_string(),
                    f.repeats.to_string(),
                    match f.recorded_unix_s {
                        Some((a, b)) if a / 86_400 == b / 86_400 => {
                            format!("{} – {}", escape(&utc(a)), escape(&utc(b)[11..]))
                        }
                        Some((a, b)) => format!("{} – {}", escape(&utc(a)), escape(&utc(b))),
                        None => "not recorded".into(),
                    },
                    f.temp_c.map_or("not recorded".into(), |(lo, hi)| format!("{lo:.1}–{hi:.1}")),
                    f.arm.as_deref().map_or("<span class=\"flag\">none</span>".into(), escape),
                ]
            })
            .collect();
        let _ = write!(
            body,
            "{}",
            table(
                &[
                    "placement / session",
                    "purpose",
                    "kind",
                    "observations",
                    "repeats",
                    "recorded",
                    "temperature °C",
                    "arm"
                ],
                &rows
            )
        );
    }

    // 3. Model and results.
    let estimated: Vec<&crate::calib::fit::Estimate> =
        s.calibration.estimates.iter().filter(|e| e.status == "estimated").collect();
    let _ = write!(
        body,
        "<h2>3. Model and calibrated values</h2><p>Model {}, {} joints; {} parameters estimated, {} held at their nominal values. \
         Expanded uncertainty U = 2·σ (k = 2, about 95 %), from the fit's covariance scaled by its residuals.</p>",
        escape(&c.model_name),
        s.joints,
        estimated.len(),
        s.identifiability.report.fixed.len()
    );
    let rows: Vec<Vec<String>> = estimated
        .iter()
        .map(|e| {
            let decimals = if e.unit == "mm" { 3 } else { 4 };
            vec![
                code(&e.param),
                format!("{:.decimals$}", e.nominal),
                format!("{:.decimals$}", e.value),
                e.std.map_or("—".into(), |sd| format!("{:.decimals$}", 2.0 * sd)),
                escape(&e.unit),
            ]
        })
        .collect();
    let _ = write!(body, "{}", table(&["parameter", "nominal", "calibrated", "U (k = 2)", "unit"], &rows));

    // 4. Validation against the floor.
    let _ = write!(body, "<h2>4. Validation on held-out data</h2>");
    let mut validation = Vec::new();
    if let Some(d) = &s.validation.distances {
        validation.push((
            "Held-out distances",
            format!(
                "{} mm RMS over {} distances (nominal model {} mm); largest {} mm",
                mm(d.calibrated.rms_mm),
                d.calibrated.count,
                mm(d.nominal.rms_mm),
                mm(d.calibrated.max_mm)
            ),
        ));
    }
    if let Some(f) = &s.floor.distances {
        validation.push(("Noise floor", format!("{} mm expected from repeatability ({} degrees of freedom, one touch scatters {} mm per axis)", mm(f.expected_rms_mm), f.dof, mm(f.touch_std_mm))));
    }
    if let Some(g) = &s.floor.distance_gap {
        validation.push((
            "Measured / expected",
            format!(
                "mean-square ratio {:.2}, at most {:.2} at 95 %; {:+.1} standard errors",
                (g.measured_mm / g.expected_mm).powi(2),
                g.ratio_upper_95,
                g.z
            ),
        ));
        validation.push((
            "What the model misses",
            format!(
                "{}–{} mm (95 % interval); a miss below about {} mm goes unseen with these data",
                mm(g.missing_95_mm.0),
                mm(g.missing_95_mm.1),
                mm(g.detectable_mm)
            ),
        ));
    }
    if let Some(v) = &s.validation.sessions {
        validation.push((
            "Held-out points",
            format!(
                "{} mm RMS over {} points (nominal model {} mm), each session's frame refitted",
                mm(v.overall.rms_mm),
                v.overall.count,
                mm(v.nominal_overall.rms_mm)
            ),
        ));
        let floor = s.point_floor();
        validation.push((
            "Noise floor",
            floor.rms_mm.map_or("unknown".into(), |f| format!("{} mm ({})", mm(f), escape(&floor.source))),
        ));
    }
    let _ = write!(body, "{}", facts(&validation));

    // 5. Validity.
    let validity = match c.uploads.iter().rev().find(|u| u.run_sha256 == c.run_sha256) {
        Some(u) => match u.valid_until_unix_s {
            Some(until) => format!(
                "valid until {} (set at upload: the host warns at every connect once it has passed)",
                escape(&utc(until))
            ),
            None => "no validity period was set at upload (<code>kincal upload … --valid-days N</code>)".into(),
        },
        None => "set when the model is uploaded (<code>kincal upload … --valid-days N</code>), counted from the validation date".into(),
    };
    let _ = write!(body, "<h2>5. Validity</h2><p>{validity}. The calibration holds while the arm is unchanged: a knock, a loose joint, another tool or a firmware change calls for a re-check.</p>");

    // 6. What it does not cover.
    let mut limits: Vec<String> = Vec::new();
    let report = &s.identifiability.report;
    if !report.fixed.is_empty() {
        limits.push(format!(
            "Parameters these data cannot determine, held at their nominal values: {}.",
            report.fixed.iter().map(|f| code(f)).collect::<Vec<_>>().join(", ")
        ));
    }
    // A direction of a single parameter already listed as held says nothing more.
    let listed =
        |c: &&crate::calib::identify::Combination| c.terms.len() == 1 && report.fixed.contains(&c.terms[0].0);
    for combination in report.unidentifiable.iter().filter(|c| !listed(c)) {
        limits.push(format!("Not separable by these data: {}.", code(&combination.text)));
    }
    limits.extend(report.statements.iter().map(|t| escape(t)));
    if !c.coverage.is_empty() {
        let rows: Vec<Vec<String>> = c
            .coverage
            .iter()
            .enumerate()
            .map(|(j, a)| {
                let gap = JointArc {
                    from_deg: (a.from_deg + a.span_deg).rem_euclid(360.0),
                    span_deg: 360.0 - a.span_deg,
                };
                vec![
                    format!("joint {}", j + 1),
                    format!("{} ({:.0}°)", arc_words(a), a.span_deg),
                    if gap.span_deg < 0.05 {
                        "—".into()
                    } else {
                        format!("{} ({:.0}°)", arc_words(&gap), gap.span_deg)
                    },
                ]
            })
            .collect();
        limits.push(format!(
            "Poses whose joint readings (the controller's) lie outside what the calibration and validation visited: \
             there the model is extrapolated, not validated.{}",
            table(&["joint", "readings visited", "not visited"], &rows)
        ));
    }
    let temps: Vec<(f64, f64)> = c.sessions.iter().filter_map(|f| f.temp_c).collect();
    if temps.is_empty() {
        limits.push(
            "Temperature was not recorded: the calibration does not state the temperature it holds at."
                .into(),
        );
    } else {
        let lo = temps.iter().map(|t| t.0).fold(f64::INFINITY, f64::min);
        let hi = temps.iter().map(|t| t.1).fold(f64::NEG_INFINITY, f64::max);
        limits.push(format!("Measured at {lo:.1}–{hi:.1} °C; other temperatures are not covered."));
    }
    limits.push("Physical effects outside the model (listed above as its parameters) are corrected only as far as the validation figure shows.".into());
    let items: String = limits.iter().map(|l| format!("<li>{l}</li>")).collect();
    let _ = write!(body, "<h2>6. What this calibration does not cover</h2><ul>{items}</ul>");

    // 7. How to re-check.
    let _ = write!(
        body,
        "<h2>7. How to re-check</h2><ul>\
         <li>Whether the arm still holds it (a few touches against the stored set and the floor of their repeats): {}</li>\
         <li>That the stored set is this calibration: <code>kincal info --port PORT</code> shows the RUN hash it carries, which must read sha256:{}.</li>\
         <li>That these files are the RUN: {} must print the hash above.</li></ul>",
        code(&c.check_command()),
        escape(&c.run_sha256),
        code(&format!("cd {} && sha256sum model.toml summary.json | sha256sum", c.run.display()))
    );

    // 8. Inputs and their hashes.
    let rows: Vec<Vec<String>> = c
        .inputs
        .iter()
        .map(|f| {
            let state = f.state.words();
            vec![
                escape(&f.role),
                code(&f.path.display().to_string()),
                f.sha256
                    .as_deref()
                    .map_or("—".into(), |h| format!("<span class=\"hash\">{}</span>", escape(h))),
                if matches!(f.state, FileState::Changed | FileState::Missing) {
                    format!("<span class=\"flag\">{state}</span>")
                } else {
                    state.into()
                },
            ]
        })
        .collect();
    let _ = write!(
        body,
        "<h2>8. Input files</h2>{}",
        table(&["role", "file", "SHA-256 when calibrated", "now"], &rows)
    );

    let _ = write!(
        body,
        "<div class=\"sign\"><div>Issued by: {}</div><div>Date: {}</div><div>Signature</div></div>\
         <p class=\"small\">This certificate describes the RUN whose hash it names and is valid only with its files. \
         It was written by kincal from the RUN folder; the figures are those of <code>summary.json</code>.</p>",
        c.operator.as_deref().map_or(String::new(), escape),
        escape(&utc(c.issued_at_unix_s)[..10])
    );
    format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>{CERTIFICATE_TITLE} — {}</title><style>{STYLE}</style></head><body>{body}</body></html>",
        escape(&p.arm.as_ref().map_or("no identified arm".into(), |a| a.id.clone()))
    )
}
