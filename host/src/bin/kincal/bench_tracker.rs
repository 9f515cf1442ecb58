//! `kincal bench`, tracker case ([`kincal::calib::bench_problem`]): 3 600 points of a 7-joint arm
//! in 5 sessions, 26 free parameters (23 of the arm, the tool point), calibrate and validate on a
//! held-out session (the same problem beside Ceres and SciPy: `bench_peers.rs`).

use crate::cpu_time::{children_cpu_ms, process_cpu_ms};
use anyhow::{Context, Result};
use kincal::calib::bench_problem::{problem, sessions, truth, write_sessions, SESSIONS};
use kincal::calib::fit::calibrate;
use kincal::calib::setup::SolveOptions;
use kincal::calib::validate::validate_session;
use kincal::data::Observations;
use kincal::model::ArmModel;
use kincal::numerics::stats::median;
use std::time::Instant;

/// Wall and CPU time (all threads), s.
pub(crate) type WallCpuS = (f64, f64);

/// Median wall and CPU time (all threads), s, of the whole `kincal calibrate` process (this
/// executable: reading the files, calibrating, validating, scoring the data errors, writing
/// RUN/) on `cal` and `val`, and the runs; with `peer`, that command run after each of them
/// (interleaved, so that both see the same load of a shared machine) and its median wall and CPU
/// time, s.
pub(crate) fn whole_process(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    mut peer: Option<&mut std::process::Command>,
) -> Result<(WallCpuS, usize, Option<WallCpuS>)> {
    let dir = std::env::temp_dir().join(format!("kincal-bench-tracker-run-{}", std::process::id()));
    write_sessions(cal, &dir.join("cal")).with_context(|| dir.display().to_string())?;
    write_sessions(val, &dir.join("val")).with_context(|| dir.display().to_string())?;
    nominal.save(&dir.join("nominal.toml"))?;
    let exe = std::env::current_exe()?;
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    let (mut peer_wall, mut peer_cpu) = (Vec::new(), Vec::new());
    const RUNS: usize = 9;
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
        if let Some(command) = peer.as_deref_mut() {
            let (t, c) = (Instant::now(), children_cpu_ms());
            let out = command.output().with_context(|| format!("could not start {command:?}"))?;
            peer_wall.push(t.elapsed().as_secs_f64());
            peer_cpu.push((children_cpu_ms() - c) * 1e-3);
            if !out.status.success() {
                anyhow::bail!("{command:?} failed: {}", String::from_utf8_lossy(&out.stderr).trim());
            }
        }
    }
    std::fs::remove_dir_all(&dir).ok();
    let peer = (!peer_cpu.is_empty()).then(|| (median(peer_wall), median(peer_cpu)));
    Ok(((median(wall), median(cpu)), RUNS, peer))
}

/// Print the tracker figures: kincal's calibrate + validate, the whole process, the cost per
/// point (beside Ceres and SciPy: `bench_peers.rs`).
pub fn tracker_benchmark() -> Result<()> {
    let (nominal, cal, val) = problem();
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
    let ((whole, whole_cpu), runs, _) = whole_process(&nominal, &cal, &val, None)?;
    println!(
        "tracker: whole `kincal calibrate` process on the same files (read, calibrate, validate, outlier metrics and data errors: the fit and 10 warm refits; write RUN/): median {whole:.3} s wall, {whole_cpu:.3} s CPU (all threads) over {runs} runs  (target <= 1 s on 2 cores)"
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
        let data = sessions(&truth, SESSIONS, n / SESSIONS, 3);
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
