//! `kincal calibrate`: one path for every kind of data (artefact placements, tracker sessions,
//! both): run, write RUN/, print the figures of each kind the data hold and the verdict.

use anyhow::{bail, Result};
use clap::{Args, ValueEnum};
use kincal::api::{self, RunInputs, Summary};
use kincal::calib::nuisance::drift::DriftSpec;
use kincal::calib::setup::{Objective, SolveOptions, HUBER_DELTA_RANGE_MM, LEVER_RANGE_MM, MAX_RESTARTS};
use kincal::model::effects::Effect;
use std::path::{Path, PathBuf};

use crate::args::{count, real};

/// Most random subsets per placement count in a study.
pub const MAX_SUBSETS: usize = 10_000;

#[derive(Clone, Copy, ValueEnum)]
pub enum ObjectiveArg {
    /// Positions only: distances between touches (thesis eq. 3.1), measured points.
    Distance,
    /// Positions and orientations: the relative orientation of the asymmetric pillars, a 6-DoF
    /// probe's orientations.
    SixDof,
}

#[derive(Args)]
pub struct SolveArgs {
    /// Seed of the random restarts.
    #[arg(long, default_value_t = 1, allow_negative_numbers = true)]
    pub seed: u64,
    /// Random restarts inside the bounds (besides the nominal start) [default: 8 with artefact
    /// touches, 0 on tracker points alone]. The start of lowest cost is kept; costs apart by less
    /// than the solver's function tolerance (relative) are a tie, won by the earliest start.
    #[arg(long, allow_negative_numbers = true, value_parser = count(0, MAX_RESTARTS))]
    pub restarts: Option<usize>,
    /// Huber threshold δ, mm [default: 1.35 with artefact touches; plain least squares on
    /// tracker points alone].
    #[arg(long, allow_negative_numbers = true, value_parser = real(HUBER_DELTA_RANGE_MM.0, HUBER_DELTA_RANGE_MM.1, "mm"))]
    pub huber_delta_mm: Option<f64>,
    /// Residuals to minimise [default: distance for artefact touches; with a 6-DoF probe's
    /// orientations, six-dof weighed by the stated σ].
    #[arg(long, value_enum)]
    pub objective: Option<ObjectiveArg>,
    /// Millimetres per radian of orientation error (with --objective six-dof) [default: 100 for
    /// artefact touches, σ_position/σ_orientation for a probe].
    #[arg(long, allow_negative_numbers = true, value_parser = real(LEVER_RANGE_MM.0, LEVER_RANGE_MM.1, "mm per radian"))]
    pub lever_mm: Option<f64>,
}

impl SolveArgs {
    /// The solve options, `--lever-mm` refused without `--objective six-dof`.
    pub fn options(&self) -> Result<SolveOptions> {
        let objective = match (self.objective, self.lever_mm) {
            (Some(ObjectiveArg::SixDof), lever_mm) => Some(Objective::SixDof { lever_mm }),
            (_, Some(_)) => bail!("--lever-mm weighs orientation rows: it needs --objective six-dof"),
            (Some(ObjectiveArg::Distance), None) => Some(Objective::Distance),
            (None, None) => None,
        };
        Ok(SolveOptions {
            huber_delta_mm: self.huber_delta_mm,
            restarts: self.restarts,
            seed: self.seed,
            objective,
            ..SolveOptions::default()
        })
    }
}

#[derive(Args)]
pub struct InputArgs {
    /// Arm model file (kincal-arm/1, .toml or .json).
    #[arg(long)]
    pub model: PathBuf,
    /// Artefact file (suta-artefact/1), for artefact sessions; leave it out for tracker sessions
    /// alone (kincal-tracker/1).
    #[arg(long)]
    pub artefact: Option<PathBuf>,
    /// Folder of calibration sessions (suta-session/1 JSON, kincal-tracker/1 CSV, or both).
    #[arg(long)]
    pub data: PathBuf,
    /// Folder of validation sessions.
    #[arg(long)]
    pub validate: PathBuf,
}

impl InputArgs {
    /// The run's inputs, nothing else set.
    pub fn inputs(&self) -> RunInputs {
        RunInputs::new(self.model.clone(), self.artefact.clone(), self.data.clone(), self.validate.clone())
    }
}

#[derive(Args)]
pub struct CalibrateArgs {
    #[command(flatten)]
    inputs: InputArgs,
    /// Output folder RUN: model.toml, nominal.toml, summary.json, residuals.json, report.html.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    solve: SolveArgs,
    /// Also run the dataset-size study with this many subsets per count of calibration groups
    /// (placements or sessions; 0: no study).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true, value_parser = count(0, MAX_SUBSETS))]
    study_subsets: usize,
    /// Add an effect of the library to the model, e.g. eccentricity:5 (repeatable).
    #[arg(long = "add", value_parser = crate::args::parse_effect)]
    add: Vec<Effect>,
    /// Leave a landmark's touches out of both folders, e.g. a wrong certificate (repeatable).
    #[arg(long, value_name = "ID")]
    exclude_landmark: Vec<String>,
    /// Leave a calibration block out: PLACEMENT/REPEAT (e.g. C_A/2 when the artefact moved) or a
    /// tracker session (repeatable).
    #[arg(long, value_name = "BLOCK")]
    exclude_block: Vec<String>,
    /// Leave one calibration observation out: SESSION:LINE of a tracker point, or
    /// PLACEMENT/REPEAT/LANDMARK of a touch (a single bad point, as the data-error diagnosis
    /// suggests; repeatable).
    #[arg(long, value_name = "POINT")]
    exclude_point: Vec<String>,
    /// Skip the outlier metrics per landmark and per calibration session (Cook's distance and the
    /// leave-one-out refit of each): about a third of the process's work on thesis-sized data;
    /// summary.json then says `outliers_skipped` and nothing is flagged.
    #[arg(long)]
    no_outliers: bool,
    /// Let the tool float in a placement or session (its own tool offset: the probe or ball was
    /// re-mounted there), as the data-error diagnosis suggests (repeatable).
    #[arg(long, value_name = "GROUP")]
    float_tool: Vec<String>,
    /// Tracker sessions: the instrument's stated σ per axis, mm, for rows without a sigma_mm or
    /// u95_mm column (sets the floor when no pose is repeated).
    #[arg(long, allow_negative_numbers = true, value_parser = real(0.0001, 10.0, "mm"))]
    sigma_mm: Option<f64>,
    /// Tracker sessions with a 6-DoF probe (qw,qx,qy,qz): its stated orientation σ per axis,
    /// degrees, which weighs orientations against points [default: 0.01]
    #[arg(long, allow_negative_numbers = true, value_parser = real(0.00001, 10.0, "deg"))]
    orientation_sigma_deg: Option<f64>,
    /// Tracker sessions: let calibration SESSION drift linearly, as the data-error diagnosis
    /// suggests (repeatable, one kind per session). KIND: offset-time (the default: the base
    /// shifts with time_s), scale-time (the length scale changes with time_s), offset-temp or
    /// scale-temp (the same against temp_C).
    #[arg(long, value_name = "SESSION[:KIND]", value_parser = crate::args::parse_drift)]
    drift_session: Vec<DriftSpec>,
    /// Tracker sessions: held-out session HELD_OUT was measured from calibration session
    /// CALIBRATION's instrument placement (the instrument did not move): validate it with that
    /// calibrated base too, besides its own refitted base (protocol S; repeatable).
    #[arg(long, value_name = "HELD_OUT=CALIBRATION")]
    same_base: Vec<String>,
    /// Print summary.json to stdout.
    #[arg(long)]
    json: bool,
}

pub fn cmd_calibrate(a: &CalibrateArgs) -> Result<()> {
    let inputs = RunInputs {
        add: a.add.iter().map(ToString::to_string).collect(),
        exclude_landmarks: a.exclude_landmark.clone(),
        exclude_blocks: a.exclude_block.clone(),
        exclude_points: a.exclude_point.clone(),
        float_tool: a.float_tool.clone(),
        drift_sessions: a.drift_session.clone(),
        same_base: a.same_base.clone(),
        stated_sigma_mm: a.sigma_mm,
        orientation_sigma_deg: a.orientation_sigma_deg,
        ..a.inputs.inputs()
    };
    let options = a.solve.options()?;
    // Refused before the work, not after: a folder holding the user's files or an uploaded RUN.
    let mut input_paths = vec![&*inputs.model, &*inputs.calibration, &*inputs.validation];
    input_paths.extend(inputs.artefact.as_deref());
    kincal::store::check_output_folder(&a.out, kincal::store::FolderKind::Run, &input_paths)?;
    let started = std::time::Instant::now();
    let spinner = crate::progress::spinner("calibrating");
    let result = api::calibrate(&inputs, &options, a.study_subsets, !a.no_outliers);
    spinner.finish_and_clear();
    let run = result?;
    api::write(&run, &a.out)?;
    let s = &run.summary;
    if a.json {
        println!("{}", kincal::store::run_json(&run));
    }
    if !s.not_trustworthy.is_empty() {
        bail!(
            "the calibration is not trustworthy; no figure is reported as a result:\n  - {}\n\
             {} written for inspection (summary.json lists these reasons under `not_trustworthy`)",
            s.not_trustworthy
                .iter()
                .map(|r| kincal::report::run::name_run(r, &a.out))
                .collect::<Vec<_>>()
                .join("\n  - "),
            a.out.display()
        );
    }
    if !a.json {
        print_run(s, &a.out, started.elapsed().as_secs_f64());
    }
    Ok(())
}

/// What was calibrated on, in words.
fn headline(s: &Summary, seconds: f64) -> String {
    let c = &s.calibration;
    let points = c.points.map_or(0, |p| p.count);
    let touches = c.observations - points;
    let sessions = s.calibration.groups.len();
    match (c.distances.is_some(), points > 0) {
        (true, false) => format!("calibrated {touches} touches ({} pairs) in {seconds:.2} s", c.pairs),
        (false, _) => format!(
            "calibrated {} joints on {points} tracker points in {sessions} sessions in {seconds:.2} s",
            s.joints
        ),
        (true, true) => format!(
            "calibrated {} joints on {touches} touches ({} pairs) and {points} tracker points in {sessions} \
             placements and sessions in {seconds:.2} s",
            s.joints, c.pairs
        ),
    }
}

/// Print a run: the verdict and the next command first, then the figures of the calibration and
/// of each kind of held-out data.
fn print_run(s: &Summary, out: &Path, seconds: f64) {
    for w in &s.warnings {
        println!("warning: {}", kincal::report::run::name_run(w, out));
    }
    println!("{}", headline(s, seconds));
    for v in kincal::report::run::verdict_lines(s, out) {
        println!("  {v}");
    }
    if let Some(arm) = &s.provenance.arm {
        println!("  arm {arm}: named by every session; {}/model.toml names it", out.display());
    }
    let c = &s.calibration;
    if let Some(d) = &c.distances {
        println!("  calibration RMS            {:8.3} mm", d.rms_mm);
    }
    if let Some(p) = &c.points {
        println!("  calibration RMS {:.4} mm (mean {:.4}, max {:.4})", p.rms_mm, p.mean_mm, p.max_mm);
    }
    if let (Some(o), Some(t)) = (&c.orientations, &c.tool_rotation) {
        let [x, y, z] = t.rotation_vector_deg;
        println!(
            "  calibration orientation RMS {:.5}° (mean {:.5}, max {:.5}) on {} probe orientations",
            o.rms_deg, o.mean_deg, o.max_deg, o.orientations
        );
        let std = t
            .std_deg
            .map_or("no deviation: singular".into(), |[a, b, c]| format!("± {a:.5}, {b:.5}, {c:.5}°"));
        println!("  probe on the flange: rotation vector ({x:.4}, {y:.4}, {z:.4})° {std}");
    }
    if let Some(v) = &s.validation.distances {
        for (name, e) in [("nominal   ", &v.nominal), ("calibrated", &v.calibrated)] {
            println!(
                "  validation RMS  {name} {:8.3} mm   (mean {:+.3}, max {:.3}, {} pairs)",
                e.rms_mm, e.mean_mm, e.max_mm, e.count
            );
        }
    }
    let ident = &s.identifiability.report;
    if ident.statements.is_empty() && !ident.fixed.is_empty() {
        println!("  fixed at nominal, not identifiable from this data: {}", ident.fixed.join(", "));
    }
    println!("  estimated: {}", ident.estimated.join(", "));
    for t in &ident.statements {
        println!("  {t}");
    }
    for combination in s.identifiability.after.iter().flat_map(|a| &a.poorly_identified) {
        println!("  poorly identified: {}", combination.text);
    }
    for t in &c.tool_offsets {
        if (0..3).all(|k| t.determined(k)) {
            let [x, y, z] = t.offset_mm;
            println!("  tool floating in {}: ({x:.3}, {y:.3}, {z:.3}) mm ± {:.3}", t.session, t.size_std_mm);
            continue;
        }
        let shown: Vec<String> = (0..3)
            .map(|k| if t.determined(k) { format!("{:.3}", t.offset_mm[k]) } else { "—".into() })
            .collect();
        let not: Vec<String> = (0..3)
            .filter(|&k| !t.determined(k))
            .map(|k| format!("{} (σ {:.3} mm)", ["x", "y", "z"][k], t.std_mm[k]))
            .collect();
        println!(
            "  tool floating in {}: ({}) mm; not determined by these data: {}",
            t.session,
            shown.join(", "),
            not.join(", ")
        );
    }
    for d in &c.drifts {
        let rate: Vec<String> = d.rate.iter().map(|v| format!("{v:.4}")).collect();
        println!(
            "  {} drifting ({}): ({}) {} ± {:.4}",
            d.session,
            d.kind.name(),
            rate.join(", "),
            d.unit,
            d.rate_std
        );
    }
    if s.outliers_skipped {
        println!("  outlier metrics skipped (--no-outliers): no landmark or session was checked");
    }
    for o in s.outliers.iter().filter(|o| o.flagged) {
        let metrics: Vec<&str> = o.exceeded.iter().map(|e| outlier_metric_words(e)).collect();
        println!(
            "  {} {} stands out: {} (a screen, not a verdict: kincal diagnose {} tests it as a data error)",
            o.what,
            o.name,
            metrics.join(", "),
            kincal::files::shell_word(out)
        );
    }
    if let Some(rows) = &s.study {
        let means: Vec<String> = rows.iter().map(|r| format!("{}: {:.3}", r.groups, r.mean_mm)).collect();
        println!("  study, mean held-out RMS by calibration groups used: {} mm", means.join(", "));
    }
    if let Some(v) = &s.validation.sessions {
        print_sessions(v);
        let floor = s.point_floor();
        match floor.rms_mm {
            Some(f) => println!("  floor {f:.4} mm ({})", floor.source),
            None => println!("  floor unknown"),
        }
    }
    println!("  report: {}", out.join("report.html").display());
}

/// An outlier metric over its threshold (summary.json's name), in words.
fn outlier_metric_words(metric: &str) -> &str {
    match metric {
        "contribution" => "a large share of the cost",
        "cooks_distance" => "a large pull on the parameters (Cook's distance)",
        "leave_one_out" => "the fit improves when it is left out",
        "bias" => "a mean error well away from zero",
        other => other,
    }
}

/// The held-out sessions' table.
fn print_sessions(v: &kincal::calib::summary::SessionsValidation) {
    println!("  held-out session        points   RMS mm  mean mm   max mm  pairwise mm   nominal RMS mm");
    for f in &v.sessions {
        let c = &f.calibrated;
        println!(
            "  {:<22} {:>7} {:>8.4} {:>8.4} {:>8.4} {:>12.4} {:>16.4}{}",
            c.name,
            c.points,
            c.rms_mm,
            c.mean_mm,
            c.max_mm,
            c.pairwise_rms_mm,
            f.nominal.rms_mm,
            if f.transfers { "" } else { "  does not transfer" }
        );
    }
    for f in &v.sessions {
        if let Some(b) = &f.same_base {
            let (c, n) = (&b.calibrated, &b.nominal);
            println!(
                "  {:<22} with the base of {} (same placement): RMS {:.4} mm (mean {:.4}, max {:.4}), nominal {:.4} mm{}",
                f.calibrated.name,
                b.calibration_session,
                c.rms_mm,
                c.mean_mm,
                c.max_mm,
                n.rms_mm,
                if c.rms_mm <= n.rms_mm { "" } else { "  does not transfer" }
            );
        }
    }
    for f in &v.sessions {
        if let (Some(c), Some(n)) = (&f.orientation, &f.nominal_orientation) {
            println!(
                "  {:<22} orientation RMS {:.5}° (mean {:.5}, max {:.5}), nominal {:.5}°",
                f.calibrated.name, c.rms_deg, c.mean_deg, c.max_deg, n.rms_deg
            );
        }
        if let Some(why) = &f.orientation_withheld {
            println!("  {:<22} no orientation figure: {why}", f.calibrated.name);
        }
    }
    let (o, n) = (&v.overall, &v.nominal_overall);
    println!(
        "  held out, all sessions   {:>6} {:>8.4} {:>8.4} {:>8.4} {:>29.4}",
        o.count, o.rms_mm, o.mean_mm, o.max_mm, n.rms_mm
    );
}
