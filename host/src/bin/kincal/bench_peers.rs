//! `kincal bench --peers`: kincal beside Ceres Solver (`bench/ceres/`) and SciPy
//! (`bench/scipy_peer.py`, `bench/tracker_peer.py`) on the same two problems in the same run, CPU
//! and wall time, with the limit estimate of this machine (`bench_limit.rs`); and
//! `kincal bench --peers-check`: only whether kincal and Ceres reach the same cost and RMS, on
//! small instances, untimed (the test `ceres_peer` runs it).
//!
//! The peers read problem files that carry data, not kincal's code: the arm's DH rows, tool point
//! and scale, the touches or tracker points, the free parameters by name with their bounds, and
//! the starts. Each peer solves for the parameters kincal estimated (its base set); kincal's
//! random restarts are drawn here as kincal draws them and exported as points, and each start's
//! initial cost is checked against kincal's own before any figure is printed.

use crate::bench_args::BenchArgs;
use crate::bench_limit;
use crate::cpu_time::{children_cpu_ms, process_cpu_ms};
use anyhow::{bail, Context, Result};
use kincal::calib::bench_problem;
use kincal::calib::fit::{calibrate, Fit, TOOL_HALF_RANGE_MM};
use kincal::calib::peer::{thesis_sized_problem, write_peer_problem};
use kincal::calib::setup::SolveOptions;
use kincal::data::Observations;
use kincal::model::{ArmModel, Convention, ParamId};
use kincal::numerics::stats::median;
use rand::{RngExt, SeedableRng};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

/// Cost agreement demanded of kincal and Ceres, relative.
const COST_AGREEMENT: f64 = 1e-9;
/// RMS agreement demanded of kincal and Ceres, relative.
const RMS_AGREEMENT: f64 = 1e-9;

/// CPU (all threads of the process) and wall time of one piece of work, ms, and the iterations
/// (Jacobian evaluations; function evaluations for SciPy) it took.
#[derive(Clone, Copy, Debug)]
struct Figure {
    cpu_ms: f64,
    wall_ms: f64,
    iterations: Option<u64>,
}

impl Figure {
    fn cell(self) -> String {
        let it = self.iterations.map_or(String::new(), |i| format!(" ({i})"));
        format!("{:.1} / {:.1}{it}", self.cpu_ms, self.wall_ms)
    }
}

/// One line of the table.
struct Row {
    problem: String,
    kincal: Option<Figure>,
    ceres: Option<Figure>,
    scipy: Option<Figure>,
    /// (optimistic bound, estimate), ms.
    limit_ms: Option<(f64, f64)>,
}

/// The median CPU and wall time of `repeats` runs of `work`, and its last result.
fn timed<T>(repeats: usize, mut work: impl FnMut() -> Result<T>) -> Result<(Figure, T)> {
    let (mut cpu, mut wall, mut last) = (Vec::new(), Vec::new(), None);
    for _ in 0..repeats.max(1) {
        let (t, c) = (Instant::now(), process_cpu_ms());
        last = Some(work()?);
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        cpu.push(process_cpu_ms() - c);
    }
    let figure = Figure { cpu_ms: median(cpu), wall_ms: median(wall), iterations: None };
    last.map(|l| (figure, l)).context("no run")
}

/// Run a process that prints JSON (a peer, `kincal calibrate --json`): its output and its CPU
/// (all threads) and wall time.
fn run_json(command: &mut Command) -> Result<(Value, Figure)> {
    let (t, c) = (Instant::now(), children_cpu_ms());
    let out = command.output().with_context(|| format!("could not start {command:?}"))?;
    let figure =
        Figure { cpu_ms: children_cpu_ms() - c, wall_ms: t.elapsed().as_secs_f64() * 1e3, iterations: None };
    if !out.status.success() {
        bail!("{command:?} failed: {}", String::from_utf8_lossy(&out.stderr).trim());
    }
    let value = serde_json::from_slice(&out.stdout)
        .with_context(|| format!("{command:?} printed no JSON: {}", String::from_utf8_lossy(&out.stdout)))?;
    Ok((value, figure))
}

fn number(v: &Value, path: &str) -> Result<f64> {
    v.pointer(path)
        .and_then(Value::as_f64)
        .with_context(|| format!("peer output has no number at {path}: {v}"))
}

fn count(v: &Value, path: &str) -> Result<u64> {
    v.pointer(path)
        .and_then(Value::as_u64)
        .with_context(|| format!("peer output has no count at {path}: {v}"))
}

/// A source file of the peers, in the source tree.
fn bench_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench").join(name)
}

/// Build the Ceres peer for problems of these free-parameter counts (next to this executable,
/// in `ceres-peer/`); its path.
fn build_ceres_peer(sizes: &[usize]) -> Result<PathBuf> {
    let exe = std::env::current_exe()?;
    let dir = exe.parent().context("executable without a folder")?.join("ceres-peer");
    let out = Command::new("bash")
        .arg(bench_file("ceres/build.sh"))
        .arg(&dir)
        .args(sizes.iter().map(|n| n.to_string()))
        .output()
        .context("could not run bash bench/ceres/build.sh")?;
    if !out.status.success() {
        bail!(
            "building the Ceres peer failed (scripts/setup.sh installs libceres-dev and nlohmann-json3-dev):\n{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()))
}

/// kincal's random restarts for parameters bounded by `lower`, `upper`: start k (from 1) is
/// lower + (upper − lower)·u with u the k-th n uniform draws of ChaCha8 seeded with `seed`.
fn kincal_restarts(lower: &[f64], upper: &[f64], seed: u64, restarts: usize) -> Vec<Vec<f64>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..restarts)
        .map(|_| lower.iter().zip(upper).map(|(l, u)| l + (u - l) * rng.random::<f64>()).collect())
        .collect()
}

/// The artefact problem file for the parameters `fit` estimated, from the nominal values and
/// kincal's random restarts.
fn write_artefact_problem(path: &Path, nominal: &ArmModel, fit: &Fit, data: &Observations) -> Result<()> {
    let huber = fit.options.huber_delta_mm().context("the artefact fit has no Huber loss")?;
    write_peer_problem(path, nominal, &fit.estimated, data, huber)?;
    let text = std::fs::read_to_string(path).with_context(|| path.display().to_string())?;
    let mut problem: Value = serde_json::from_str(&text)?;
    let bound = |key: &str| -> Vec<f64> {
        problem[key].as_array().map_or(Vec::new(), |v| v.iter().filter_map(Value::as_f64).collect())
    };
    let starts = kincal_restarts(&bound("lower"), &bound("upper"), fit.options.seed, fit.options.restarts);
    problem["starts"] = json!(starts);
    std::fs::write(path, problem.to_string()).with_context(|| path.display().to_string())
}

/// Each start's initial cost, kincal's and the peer's, must match: else the peer's start, data
/// or model is not kincal's.
fn check_starts(fit: &Fit, peer: &Value) -> Result<()> {
    let peer_starts = peer["starts"].as_array().context("Ceres peer printed no starts")?;
    for outcome in &fit.starts {
        let theirs = peer_starts
            .get(outcome.start)
            .and_then(|s| s["initial_cost"].as_f64())
            .with_context(|| format!("Ceres peer did not solve start {}", outcome.start))?;
        if (theirs - outcome.initial_cost).abs() > 1e-9 * outcome.initial_cost.abs() {
            bail!(
                "start {}: initial cost {} for kincal, {} for the Ceres peer: the peer does not solve kincal's problem (its start, data or model differ)",
                outcome.start,
                outcome.initial_cost,
                theirs
            );
        }
    }
    Ok(())
}

/// The tracker problem file: the DH rows, tool point, the parameters kincal estimated with
/// kincal's bounds, the sessions.
fn write_tracker_problem(path: &Path, nominal: &ArmModel, fit: &Fit, data: &Observations) -> Result<()> {
    if nominal.convention != Convention::Classic || nominal.scale_ppm != 0.0 {
        bail!("the tracker peers model a classic DH arm without scale error");
    }
    let mut params = Vec::new();
    let (mut lower, mut upper) = (Vec::new(), Vec::new());
    for &id in &fit.estimated {
        let (l, u) = match (nominal.free.iter().find(|f| f.id == id), id) {
            (Some(f), _) => (f.lower, f.upper),
            (None, ParamId::Tcp(k)) => {
                (nominal.tcp_mm[k] - TOOL_HALF_RANGE_MM, nominal.tcp_mm[k] + TOOL_HALF_RANGE_MM)
            }
            (None, _) => bail!("{id} is not free in the model"),
        };
        params.push(id.to_string());
        lower.push(l);
        upper.push(u);
    }
    let problem = json!({
        "dh": nominal.joints.iter().map(|j| [j.offset_deg, j.d_mm, j.a_mm, j.alpha_deg]).collect::<Vec<_>>(),
        "tool_mm": nominal.tcp_mm,
        "params": params,
        "lower": lower,
        "upper": upper,
        "sessions": (0..data.groups.len()).map(|g| {
            let points: Vec<_> = data.group_members(g).into_iter().map(|k| &data.obs[k]).collect();
            json!({
                "q_deg": points.iter().map(|p| p.q_deg.to_vec()).collect::<Vec<_>>(),
                "x_mm": points.iter().map(|p| p.point_mm().map(|x| [x.x, x.y, x.z])).collect::<Option<Vec<_>>>(),
            })
        }).collect::<Vec<_>>(),
    });
    std::fs::write(path, problem.to_string()).with_context(|| path.display().to_string())
}

/// Relative difference of `b` from `a`.
fn relative(a: f64, b: f64) -> f64 {
    (b - a).abs() / a.abs().max(f64::MIN_POSITIVE)
}

/// One agreement line; an error when kincal and Ceres differ beyond the demanded agreement.
fn agreement(what: &str, kincal: (f64, f64), ceres: (f64, f64), scipy: Option<(f64, f64)>) -> Result<String> {
    let (cost, rms) = (relative(kincal.0, ceres.0), relative(kincal.1, ceres.1));
    let scipy = scipy.map_or(String::new(), |(c, r)| {
        format!("; SciPy {c:.12} ({:.1e}), {r:.9} mm ({:.1e})", relative(kincal.0, c), relative(kincal.1, r))
    });
    let line = format!(
        "  {what}: cost kincal {:.12}, Ceres {:.12} (relative difference {cost:.1e}); RMS {:.9} mm, {:.9} mm ({rms:.1e}){scipy}",
        kincal.0, ceres.0, kincal.1, ceres.1
    );
    if !(cost <= COST_AGREEMENT && rms <= RMS_AGREEMENT) {
        bail!("kincal and Ceres disagree beyond {COST_AGREEMENT:e} in cost or {RMS_AGREEMENT:e} in RMS:\n{line}");
    }
    Ok(line)
}

/// The load average of the last minute, when the system says it.
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg").ok()?.split_whitespace().next()?.parse().ok()
}

/// A scratch folder, removed when dropped unless it is the user's.
struct Scratch(PathBuf, bool);

impl Scratch {
    fn new(name: &str) -> Result<Scratch> {
        let dir = std::env::temp_dir().join(format!("kincal-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| dir.display().to_string())?;
        Ok(Scratch(dir, true))
    }

    /// The user's folder `dir` when given (kept), else a new scratch folder.
    fn kept_or_new(dir: Option<&PathBuf>, name: &str) -> Result<Scratch> {
        match dir {
            Some(dir) => {
                std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
                Ok(Scratch(dir.clone(), false))
            }
            None => Scratch::new(name),
        }
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if self.1 {
            std::fs::remove_dir_all(&self.0).ok();
        }
    }
}

/// kincal's fits and the exported problem files of both problems.
struct Problems {
    nominal: ArmModel,
    sim: kincal::simulate::SimulatedData,
    cal: Observations,
    options: SolveOptions,
    fit: Fit,
    tracker_nominal: ArmModel,
    tracker_cal: Observations,
    tracker_val: Observations,
    tracker_fit: Fit,
    artefact_file: PathBuf,
    tracker_file: PathBuf,
}

/// Fit both problems with kincal and write their problem files into `dir`: the thesis-sized
/// artefact problem of `seed` with `restarts`, and the tracker bench arm with `points` points.
fn problems(dir: &Path, seed: u64, restarts: usize, points: Option<usize>) -> Result<Problems> {
    let (nominal, sim) = thesis_sized_problem(seed);
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let options = SolveOptions { restarts: Some(restarts), ..SolveOptions::default() };
    let fit = calibrate(&nominal, &cal, &options)?;
    let artefact_file = dir.join("artefact_problem.json");
    write_artefact_problem(&artefact_file, &nominal, &fit, &cal)?;
    let (tracker_nominal, mut tracker_cal, tracker_val) = bench_problem::problem();
    if let Some(n) = points {
        let truth = bench_problem::truth(&tracker_nominal);
        let count = tracker_cal.groups.len();
        tracker_cal = bench_problem::sessions(&truth, count, n / count, 3);
    }
    let tracker_fit = calibrate(&tracker_nominal, &tracker_cal, &SolveOptions::default())?;
    let tracker_file = dir.join("tracker_problem.json");
    write_tracker_problem(&tracker_file, &tracker_nominal, &tracker_fit, &tracker_cal)?;
    Ok(Problems {
        nominal,
        sim,
        cal,
        options,
        fit,
        tracker_nominal,
        tracker_cal,
        tracker_val,
        tracker_fit,
        artefact_file,
        tracker_file,
    })
}

/// A second artefact instance for the check, on the parts of the chain the benchmark problems
/// leave out: the modified DH convention, a Hayati axis and a scale error (both held: the
/// distances cannot determine them here), a twist, a link offset and the tool's x free; data
/// simulated from that model (seed 3).
fn modified_instance(dir: &Path) -> Result<(Fit, PathBuf)> {
    let mut nominal = ArmModel::suta_nominal();
    nominal.convention = Convention::Modified;
    nominal.joints[4].axis_deg = 0.3;
    nominal.scale_ppm = 120.0;
    nominal.free_param(ParamId::Twist(2), -95.0, -85.0);
    nominal.free_param(ParamId::LinkOffset(3), -5.0, 5.0);
    nominal.free_param(ParamId::Tcp(0), -10.0, 10.0);
    let sim = kincal::simulate::simulate(
        &nominal,
        &kincal::simulate::SimulationOptions { seed: 3, ..Default::default() },
    );
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let options = SolveOptions { restarts: Some(1), ..SolveOptions::default() };
    let fit = calibrate(&nominal, &cal, &options)?;
    let file = dir.join("artefact_modified_problem.json");
    write_artefact_problem(&file, &nominal, &fit, &cal)?;
    Ok((fit, file))
}

/// `kincal bench --peers-check`: kincal and Ceres on small instances, untimed: the thesis-sized
/// artefact problem from the nominal start and 2 restarts, a modified-DH artefact problem with
/// more kinds of parameters free, the tracker arm with 200 points. An error unless every start's
/// initial cost and the final costs and RMS agree.
pub fn peers_check(args: &BenchArgs) -> Result<()> {
    let scratch = Scratch::kept_or_new(args.peer_problems.as_ref(), "peers-check")?;
    let p = problems(&scratch.0, 2, 2, Some(200))?;
    let (modified, modified_file) = modified_instance(&scratch.0)?;
    let ceres =
        build_ceres_peer(&[p.fit.estimated.len(), modified.estimated.len(), p.tracker_fit.estimated.len()])?;
    println!("kincal and Ceres on the same problems (agreement demanded: {COST_AGREEMENT:e} relative in cost and RMS):");
    for (name, fit, file) in
        [("artefact", &p.fit, &p.artefact_file), ("artefact, modified DH", &modified, &modified_file)]
    {
        let (artefact, _) = run_json(Command::new(&ceres).arg("artefact").arg(file))?;
        check_starts(fit, &artefact)?;
        for (k, outcome) in fit.starts.iter().enumerate() {
            println!(
                "  {name} ({} parameters), start {k}: initial cost {:.9} both; final cost kincal {:.12}, Ceres {:.12}",
                fit.estimated.len(),
                outcome.initial_cost,
                outcome.final_cost,
                number(&artefact, &format!("/starts/{k}/cost"))?
            );
        }
        let line = agreement(
            &format!("{name}, nominal + {} restarts, best", fit.starts.len() - 1),
            (fit.cost, fit.rms_mm),
            (number(&artefact, "/solve/cost")?, number(&artefact, "/solve/rms_mm")?),
            None,
        )?;
        println!("{line}");
    }
    let (tracker, _) = run_json(Command::new(&ceres).arg("tracker").arg(&p.tracker_file))?;
    let line = agreement(
        &format!("tracker, {} points", p.tracker_cal.point_count()),
        (p.tracker_fit.cost, p.tracker_fit.rms_mm),
        (number(&tracker, "/solve/cost")?, number(&tracker, "/solve/rms_mm")?),
        None,
    )?;
    println!("{line}");
    Ok(())
}

/// SciPy's figure, output and (cost, RMS mm) of one run.
type ScipyRun = (Figure, Value, (f64, f64));

/// The SciPy peers' runs: the artefact from every start and from the nominal one, the tracker.
/// The processes' figures are those of the runs from every start and of the tracker.
struct ScipyRuns {
    all: ScipyRun,
    one: ScipyRun,
    tracker: ScipyRun,
    all_process: Figure,
    tracker_process: Figure,
}

impl ScipyRuns {
    fn run(python: &str, p: &Problems) -> Result<ScipyRuns> {
        let script = bench_file("scipy_peer.py");
        let solve = |command: &mut Command| -> Result<(ScipyRun, Figure)> {
            let (v, process) = run_json(command)?;
            let figure = Figure {
                cpu_ms: number(&v, "/cpu_seconds")? * 1e3,
                wall_ms: number(&v, "/seconds")? * 1e3,
                iterations: Some(count(&v, "/nfev")?),
            };
            let result = (number(&v, "/cost")?, number(&v, "/rms_mm")?);
            Ok(((figure, v, result), process))
        };
        let (all, all_process) =
            solve(Command::new(python).arg(&script).arg(&p.artefact_file).arg("--all-starts"))?;
        let (one, _) = solve(Command::new(python).arg(&script).arg(&p.artefact_file))?;
        let (tracker, tracker_process) =
            solve(Command::new(python).arg(bench_file("tracker_peer.py")).arg(&p.tracker_file))?;
        Ok(ScipyRuns { all, one, tracker, all_process, tracker_process })
    }
}

/// The artefact's whole `kincal calibrate --no-outliers` process on `p`'s data written to files:
/// median CPU (all threads) and wall time over `runs`; and those of `peer`, run after each of them
/// (interleaved: the same load for both).
fn artefact_process(p: &Problems, dir: &Path, runs: usize, peer: &mut Command) -> Result<(Figure, Figure)> {
    p.sim.write(&dir.join("data"))?;
    p.nominal.save(&dir.join("nominal.toml"))?;
    let exe = std::env::current_exe()?;
    let file = |name: &str| dir.join(name).into_os_string();
    let arguments = [
        "--model".into(),
        file("nominal.toml"),
        "--artefact".into(),
        file("data/artefact.json"),
        "--data".into(),
        file("data/cal"),
        "--validate".into(),
        file("data/val"),
        "--out".into(),
        file("run"),
        "--no-outliers".into(),
        "--json".into(),
    ];
    let (mut figures, mut peer_figures) = (Vec::new(), Vec::new());
    for _ in 0..runs {
        let (_, figure) = run_json(Command::new(&exe).arg("calibrate").args(&arguments))?;
        figures.push(figure);
        peer_figures.push(run_json(peer)?.1);
    }
    Ok((median_figure(&figures), median_figure(&peer_figures)))
}

/// The median CPU and wall time of `figures`.
fn median_figure(figures: &[Figure]) -> Figure {
    Figure {
        cpu_ms: median(figures.iter().map(|f| f.cpu_ms).collect()),
        wall_ms: median(figures.iter().map(|f| f.wall_ms).collect()),
        iterations: None,
    }
}

/// `kincal bench --peers`: the table of the three tools and the limit, and the agreement.
pub fn peers_benchmark(args: &BenchArgs) -> Result<()> {
    let (python, repeats) = (args.python.as_str(), args.repeats);
    let scratch = Scratch::kept_or_new(args.peer_problems.as_ref(), "peers")?;
    let p = problems(&scratch.0, 1, kincal::calib::setup::DEFAULT_RESTARTS, None)?;
    let (n, tracker_n) = (p.fit.estimated.len(), p.tracker_fit.estimated.len());
    let ceres = build_ceres_peer(&[n, tracker_n])?;
    let load_before = load_average();
    let rates = bench_limit::measure();

    // kincal, in this process.
    let options_one = SolveOptions { restarts: Some(0), ..p.options.clone() };
    let (mut kincal_all, _) = timed(repeats, || Ok(calibrate(&p.nominal, &p.cal, &p.options)?))?;
    let (mut kincal_one, one_fit) = timed(repeats, || Ok(calibrate(&p.nominal, &p.cal, &options_one)?))?;
    let (mut kincal_tracker, _) =
        timed(repeats, || Ok(calibrate(&p.tracker_nominal, &p.tracker_cal, &SolveOptions::default())?))?;
    let kincal_iterations: u64 = p.fit.starts.iter().map(|s| s.iterations as u64).sum();
    kincal_all.iterations = Some(kincal_iterations);
    kincal_one.iterations = one_fit.starts.first().map(|s| s.iterations as u64);
    kincal_tracker.iterations = Some(p.tracker_fit.iterations as u64);

    // Ceres: the solves timed inside the peer (median of `repeats`), then the whole process once.
    let repeats_arg = repeats.max(1).to_string();
    let ceres_run = |kind: &str, file: &Path, extra: &[&str]| {
        run_json(Command::new(&ceres).arg(kind).arg(file).args(["--repeats", &repeats_arg]).args(extra))
    };
    let (artefact, _) = ceres_run("artefact", &p.artefact_file, &[])?;
    check_starts(&p.fit, &artefact)?;
    let (artefact_one, _) = ceres_run("artefact", &p.artefact_file, &["--starts", "1"])?;
    let (tracker, _) = ceres_run("tracker", &p.tracker_file, &[])?;
    let inside = |v: &Value| -> Result<Figure> {
        Ok(Figure {
            cpu_ms: number(v, "/solve/cpu_ms")?,
            wall_ms: number(v, "/solve/wall_ms")?,
            iterations: Some(count(v, "/solve/iterations")?),
        })
    };
    let (ceres_all, ceres_one, ceres_tracker) =
        (inside(&artefact)?, inside(&artefact_one)?, inside(&tracker)?);

    // SciPy: once each (seconds).
    let scipy = if args.no_scipy { None } else { Some(ScipyRuns::run(python, &p)?) };

    // The whole processes, kincal's and Ceres' interleaved, last (seconds each).
    let artefact_dir = Scratch::new("peers-artefact-run")?;
    let (kincal_artefact_process, ceres_artefact_process) =
        artefact_process(&p, &artefact_dir.0, 9, Command::new(&ceres).arg("artefact").arg(&p.artefact_file))?;
    let mut ceres_tracker_command = Command::new(&ceres);
    ceres_tracker_command.arg("tracker").arg(&p.tracker_file);
    let ((wall_s, cpu_s), _, peer) = crate::bench_tracker::whole_process(
        &p.tracker_nominal,
        &p.tracker_cal,
        &p.tracker_val,
        Some(&mut ceres_tracker_command),
    )?;
    let kincal_tracker_process = Figure { cpu_ms: cpu_s * 1e3, wall_ms: wall_s * 1e3, iterations: None };
    let (peer_wall_s, peer_cpu_s) = peer.context("the Ceres tracker process was not run")?;
    let ceres_tracker_process =
        Figure { cpu_ms: peer_cpu_s * 1e3, wall_ms: peer_wall_s * 1e3, iterations: None };

    // The limit: the fewer Jacobian evaluations of kincal and Ceres, at this core's rates.
    let joints = p.nominal.joints.len();
    let rows = count(&artefact, "/residuals")? as usize;
    let artefact_work = bench_limit::artefact(p.cal.obs.len(), joints, n, rows);
    let points = p.tracker_cal.point_count();
    let sessions = p.tracker_cal.groups.len();
    let tracker_work = bench_limit::tracker(points, p.tracker_nominal.joints.len(), tracker_n, sessions);
    let fewer = |a: Figure, b: Figure| a.iterations.unwrap_or(0).min(b.iterations.unwrap_or(0)) as usize;

    let rows = vec![
        Row {
            problem: format!("artefact, nominal + {} restarts", p.fit.options.restarts),
            kincal: Some(kincal_all),
            ceres: Some(ceres_all),
            scipy: scipy.as_ref().map(|s| s.all.0),
            limit_ms: Some(artefact_work.ms(&rates, fewer(kincal_all, ceres_all))),
        },
        Row {
            problem: "artefact, one start (nominal)".into(),
            kincal: Some(kincal_one),
            ceres: Some(ceres_one),
            scipy: scipy.as_ref().map(|s| s.one.0),
            limit_ms: Some(artefact_work.ms(&rates, fewer(kincal_one, ceres_one))),
        },
        Row {
            problem: "tracker, one calibration".into(),
            kincal: Some(kincal_tracker),
            ceres: Some(ceres_tracker),
            scipy: scipy.as_ref().map(|s| s.tracker.0),
            limit_ms: Some(tracker_work.ms(&rates, fewer(kincal_tracker, ceres_tracker))),
        },
        Row {
            problem: "artefact, whole process".into(),
            kincal: Some(kincal_artefact_process),
            ceres: Some(ceres_artefact_process),
            scipy: scipy.as_ref().map(|s| s.all_process),
            limit_ms: None,
        },
        Row {
            problem: "tracker, whole process".into(),
            kincal: Some(kincal_tracker_process),
            ceres: Some(ceres_tracker_process),
            scipy: scipy.as_ref().map(|s| s.tracker_process),
            limit_ms: None,
        },
    ];

    let scipy_version = scipy.as_ref().and_then(|s| s.all.1["scipy_version"].as_str().map(str::to_string));
    println!(
        "peers: kincal, Ceres {} and SciPy {} on the same problems in this run. CPU / wall ms (CPU of all the \
         process's threads: kincal runs on {}, Ceres on one) and (iterations: kincal's Jacobian evaluations, \
         Ceres' steps, SciPy's function evaluations); kincal and Ceres the median of {} runs, SciPy one",
        artefact["ceres_version"].as_str().unwrap_or("?"),
        scipy_version.as_deref().unwrap_or("(not run)"),
        rayon::current_num_threads(),
        repeats.max(1)
    );
    println!(
        "  artefact: {} touches, {rows_n} pair distances, {n} parameters (kincal's base set of {}), Huber δ {} mm; \
         tracker: {points} points, {sessions} sessions, {tracker_n} arm parameters + {} base unknowns, plain least squares",
        p.cal.obs.len(),
        p.nominal.free.len(),
        p.fit.options.huber_delta_mm().unwrap_or(f64::NAN),
        6 * sessions,
        rows_n = count(&artefact, "/residuals")?
    );
    println!(
        "  {:<34} {:>22} {:>22} {:>24} {:>18}",
        "problem", "kincal", "Ceres", "SciPy", "limit (bound–est.)"
    );
    let cell = |f: Option<Figure>| f.map_or("–".to_string(), Figure::cell);
    for row in &rows {
        let limit = row.limit_ms.map_or("–".to_string(), |(b, e)| format!("{b:.2}–{e:.2} ms"));
        println!(
            "  {:<34} {:>22} {:>22} {:>24} {:>18}",
            row.problem,
            cell(row.kincal),
            cell(row.ceres),
            cell(row.scipy),
            limit
        );
    }
    println!(
        "  whole process: `kincal calibrate` (artefact with --no-outliers; tracker with its outlier metrics and data-error \
         scoring: the fit and 10 warm refits) and the Ceres peer reading its problem file and solving once (artefact: every \
         start), run one after the other 9 times, the median of each; SciPy's interpreter with its imports, once"
    );
    println!(
        "  limit: one Gauss–Newton iteration {:.2} Mflop (artefact), {:.2} Mflop (tracker), times the fewer \
         Jacobian evaluations of kincal and Ceres; this core: dense product {:.1} GFLOP/s, kinematics kernel {:.1} \
         GFLOP/s (bench_limit.rs states the counts)",
        artefact_work.total() * 1e-6,
        tracker_work.total() * 1e-6,
        rates.product * 1e-9,
        rates.kinematics * 1e-9
    );
    let load_after = load_average();
    println!(
        "  load average (1 min) before / after: {} / {}",
        load_before.map_or("?".into(), |l| format!("{l:.2}")),
        load_after.map_or("?".into(), |l| format!("{l:.2}"))
    );
    println!("agreement on the same problems (kincal and Ceres must agree to {COST_AGREEMENT:e} relative):");
    println!(
        "{}",
        agreement(
            &format!("artefact, nominal + {} restarts", p.fit.options.restarts),
            (p.fit.cost, p.fit.rms_mm),
            (number(&artefact, "/solve/cost")?, number(&artefact, "/solve/rms_mm")?),
            scipy.as_ref().map(|s| s.all.2),
        )?
    );
    println!(
        "{}",
        agreement(
            "artefact, one start",
            (one_fit.cost, one_fit.rms_mm),
            (number(&artefact_one, "/solve/cost")?, number(&artefact_one, "/solve/rms_mm")?),
            scipy.as_ref().map(|s| s.one.2),
        )?
    );
    println!(
        "{}",
        agreement(
            "tracker",
            (p.tracker_fit.cost, p.tracker_fit.rms_mm),
            (number(&tracker, "/solve/cost")?, number(&tracker, "/solve/rms_mm")?),
            scipy.as_ref().map(|s| s.tracker.2),
        )?
    );
    Ok(())
}
