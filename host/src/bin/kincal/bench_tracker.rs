//! `kincal bench`, tracker case: 3 600 points of a 7-joint arm in 5 sessions, 26 free
//! parameters (23 of the arm, the tool point), calibrate and validate on a held-out session (the
//! same problem beside Ceres and SciPy: `bench_peers.rs`). The points come from kincal's own
//! kinematics with noise: this measures speed only (accuracy is tested on the independent
//! generator in `tests/`).

use crate::bench::{children_cpu_ms, process_cpu_ms};
use anyhow::{Context, Result};
use kincal::calib::fit::calibrate;
use kincal::calib::setup::SolveOptions;
use kincal::calib::validate::validate_session;
use kincal::data::tracker::TRACKER_FORMAT;
use kincal::data::{Joints, Kind, Observation, Observations, Target};
use kincal::model::kinematics::tool_pose;
use kincal::model::{ArmModel, Joint, ParamId};
use kincal::numerics::stats::median;
use nalgebra::{Rotation3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::Distribution;
use std::path::Path;
use std::time::Instant;

const SESSIONS: usize = 5;
const POINTS: usize = 3600;

/// The 7-joint bench arm, its 23 free parameters bounded.
pub(crate) fn arm() -> ArmModel {
    let alpha = [-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0];
    let d = [360.0, 0.0, 420.0, 0.0, 400.0, 0.0, 126.0];
    let mut model = ArmModel::suta_nominal();
    model.name = "7R bench arm".into();
    model.joints = (0..7).map(|j| Joint { d_mm: d[j], alpha_deg: alpha[j], ..Joint::default() }).collect();
    model.tcp_mm = [40.0, -25.0, 120.0];
    model.free.clear();
    for j in 1..7 {
        model.free_param(ParamId::Offset(j), -5.0, 5.0);
    }
    for (j, dj) in d.iter().enumerate().take(6).skip(1) {
        model.free_param(ParamId::Length(j), dj - 10.0, dj + 10.0);
    }
    for (j, aj) in alpha.iter().enumerate().take(6) {
        model.free_param(ParamId::LinkOffset(j), -10.0, 10.0);
        model.free_param(ParamId::Twist(j), aj - 5.0, aj + 5.0);
    }
    model
}

/// `count` sessions of `points` random poses of `truth`, each seen from its own base, with 0.02 mm noise.
pub(crate) fn sessions(truth: &ArmModel, count: usize, points: usize, seed: u64) -> Result<Observations> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = rand_distr::Normal::new(0.0, 0.02)?;
    let mut data = Observations::new(7, Vec::new());
    for s in 0..count {
        let group = data.push_group(format!("bench_{}", s + 1), "bench.csv".into(), Kind::Tracker);
        let rotation = Rotation3::from_euler_angles(0.1, -0.05, 1.2 * s as f64).into_inner();
        let shift = Vector3::new(2500.0, -300.0 * s as f64, 400.0);
        for i in 0..points {
            let q: Vec<f64> = (0..7).map(|_| rng.random_range(-120.0..120.0)).collect();
            let p = rotation * tool_pose(truth, &q).position_mm + shift;
            let n = Vector3::from_fn(|_, _| noise.sample(&mut rng));
            data.obs.push(Observation {
                block: 0,
                group,
                repeat: 1,
                q_deg: Joints::new(&q).context("seven joint angles")?,
                q_sigma_deg: None,
                target: Target::Point { xyz_mm: p + n, orientation: None },
                sigma_mm: Some(0.02),
                time_s: None,
                temp_c: None,
                pose: None,
                line: i + 3,
                tip: 0,
            });
        }
    }
    data.rebuild_blocks();
    Ok(data)
}

/// Write `data`'s sessions as `kincal-tracker/1` files into `dir` (full precision).
fn write_sessions(data: &Observations, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    for (g, group) in data.groups.iter().enumerate() {
        let mut text = format!("# {TRACKER_FORMAT}\n");
        let joints: Vec<String> = (1..=data.joints).map(|j| format!("q{j}_deg")).collect();
        text += &format!("{},x_mm,y_mm,z_mm,sigma_mm\n", joints.join(","));
        for p in data.obs.iter().filter(|o| o.group == g) {
            let q: Vec<String> = p.q_deg.iter().map(|v| format!("{v:?}")).collect();
            let point = p.point_mm().unwrap_or_default();
            let [x, y, z] = [point.x, point.y, point.z];
            text += &format!("{},{x:?},{y:?},{z:?},{:?}\n", q.join(","), p.sigma_mm.unwrap_or(0.02));
        }
        let path = dir.join(format!("{}.csv", group.name));
        std::fs::write(&path, text).with_context(|| path.display().to_string())?;
    }
    Ok(())
}

/// Median wall and CPU time (all threads), s, of the whole `kincal calibrate` process (this
/// executable: reading the files, calibrating, validating, scoring the data errors, writing
/// RUN/) on `cal` and `val`, and the runs.
pub(crate) fn whole_process(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
) -> Result<(f64, f64, usize)> {
    let dir = std::env::temp_dir().join(format!("kincal-bench-tracker-run-{}", std::process::id()));
    write_sessions(cal, &dir.join("cal"))?;
    write_sessions(val, &dir.join("val"))?;
    nominal.save(&dir.join("nominal.toml"))?;
    let exe = std::env::current_exe()?;
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    const RUNS: usize = 5;
    for _ in 0..RUNS {
        let (t, c) = (Instant::now(), children_cpu_ms());
        let out = std::process::Command::new(&exe)
            .arg("calibrate")
            .arg("--model")
            .arg(dir.join("nominal.toml"))
            .arg("--data")
            .arg(dir.join("cal"))
            .arg("--validate")
            .arg(dir.join("val"))
            .arg("--out")
            .arg(dir.join("run"))
            .output()?;
        wall.push(t.elapsed().as_secs_f64());
        cpu.push((children_cpu_ms() - c) * 1e-3);
        if !out.status.success() {
            anyhow::bail!(
                "kincal calibrate on the tracker bench failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
    Ok((median(wall), median(cpu), RUNS))
}

/// The bench arm's truth: every free parameter moved by up to 0.2 from its nominal value.
pub(crate) fn truth(nominal: &ArmModel) -> ArmModel {
    let mut truth = nominal.clone();
    for (k, f) in nominal.free.iter().enumerate() {
        truth.set(f.id, nominal.get(f.id) + 0.2 * ((k as f64 * 1.7).sin()));
    }
    truth
}

/// The bench problem: the nominal arm, 5 calibration sessions (3 600 points) and a held-out one.
pub(crate) fn bench_problem() -> Result<(ArmModel, Observations, Observations)> {
    let nominal = arm();
    let truth = truth(&nominal);
    let cal = sessions(&truth, SESSIONS, POINTS / SESSIONS, 1)?;
    let mut val = sessions(&truth, 1, POINTS / SESSIONS, 2)?;
    val.groups[0].name = "bench_held_out".into();
    Ok((nominal, cal, val))
}

/// Print the tracker figures: kincal's calibrate + validate, the whole process, the cost per
/// point (beside Ceres and SciPy: `bench_peers.rs`).
pub fn tracker_benchmark() -> Result<()> {
    let (nominal, cal, val) = bench_problem()?;
    let truth = truth(&nominal);
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..5 {
        let t = Instant::now();
        let fit = calibrate(&nominal, &cal, &SolveOptions::default())?;
        let v = validate_session(&fit.model, &val, 0, [0.0; 3]);
        times.push(t.elapsed().as_secs_f64());
        last = Some((fit, v));
    }
    let Some((fit, v)) = last else { return Ok(()) };
    let (whole, whole_cpu, runs) = whole_process(&nominal, &cal, &val)?;
    println!(
        "tracker: whole `kincal calibrate` process on the same files (read, calibrate, validate, score the data errors: 7 calibrations; write RUN/): median {whole:.3} s wall, {whole_cpu:.3} s CPU (all threads) over {runs} runs  (target <= 1 s on 2 cores)"
    );
    let best = times.iter().cloned().fold(f64::INFINITY, f64::min);
    println!(
        "tracker: {} points, {} sessions, {} free ({} estimated), {} threads: calibrate + validate median {:.3} s, min {best:.3} s  (target <= 1 s on 2 cores); fit {:.4} mm, held out {:.4} mm",
        cal.point_count(),
        cal.groups.len(),
        nominal.free.len() + 3,
        fit.estimated.len(),
        rayon::current_num_threads(),
        median(times.clone()),
        fit.rms_mm,
        v.rms_mm
    );
    // Each size is calibrated several times (the median is printed): a single run of a few
    // milliseconds says more about the machine's other load than about the solver.
    for n in [40, 400, 4000, 40_000] {
        let data = sessions(&truth, SESSIONS, n / SESSIONS, 3)?;
        let runs = (40_000 / n).clamp(3, 25);
        let (mut seconds, mut cpu_ms) = (Vec::new(), Vec::new());
        let mut iterations = 0;
        for _ in 0..runs {
            let (t, c) = (Instant::now(), process_cpu_ms());
            iterations = calibrate(&nominal, &data, &SolveOptions::default())?.iterations;
            seconds.push(t.elapsed().as_secs_f64());
            cpu_ms.push(process_cpu_ms() - c);
        }
        let (s, cpu) = (median(seconds), median(cpu_ms) * 1e-3);
        println!(
            "tracker cost per point: {n:>6} points {s:>8.4} s (median of {runs})  {:>6.2} µs wall, {:>6.2} µs CPU per point; {iterations} Gauss–Newton iterations",
            s * 1e6 / n as f64,
            cpu * 1e6 / n as f64,
        );
    }
    Ok(())
}
