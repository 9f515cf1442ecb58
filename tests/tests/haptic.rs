//! `kincal haptic calibrate` on recordings from the independent generator
//! (`kincal_e2e::haptic_gen`, which shares no code with `kincal::haptic`): every T2 placement ×
//! device × gimbal sensor type reaches the tracker noise floor; recordings that cannot give a
//! trustworthy calibration are refused with the cause named; wild samples and occlusions change
//! nothing.

use kincal::haptic::gimbal::GimbalModel;
use kincal::haptic::pipeline::{calibrate_recording, HapticCalibration};
use kincal_e2e::haptic_gen::{generate, Convention, GenOptions, GenTruth, Phantom, T2Mount};
use std::path::PathBuf;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-haptic-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// Generate, load and calibrate; the folder is removed afterwards.
fn run(name: &str, options: &GenOptions) -> (GenTruth, Result<HapticCalibration, String>) {
    let dir = scratch(name);
    let truth = generate(options, &dir).expect("generator writes the recording");
    let result = kincal::haptic::recording::load(&dir)
        .map_err(|e| e.to_string())
        .and_then(|rec| calibrate_recording(&rec).map_err(|e| e.to_string()));
    std::fs::remove_dir_all(&dir).ok();
    (truth, result)
}

/// Delay within 0.25 ms, position and orientation within 10 % of the noise floor, the right
/// gimbal model; the landmark start (whatever T2's mounting) as good as the pose-based one.
fn check(label: &str, options: &GenOptions, truth: &GenTruth, r: &HapticCalibration) -> Vec<String> {
    let mut failures = Vec::new();
    let line = format!(
        "{label}: delay {:.3} ms (truth {:.3}, rounds {:?}), position {:.3} → {:.3} mm (floor {:.3}), orientation {:.3} → {:.3}° (floor {:.3}), gimbals {:?} {:?}, start {} (landmark {:?} mm, pose {:.3} mm), rejected {}, gaps {}",
        r.delay_ms,
        truth.delay_ms,
        r.delay_rounds_ms.iter().map(|d| (d * 1000.0).round() / 1000.0).collect::<Vec<_>>(),
        r.position_mm.before,
        r.position_mm.after,
        truth.floor_mm,
        r.orientation_deg.before,
        r.orientation_deg.after,
        truth.floor_deg,
        r.gimbal_model,
        r.gimbal_held_out_deg,
        r.start.chosen,
        r.start.landmark_mm,
        r.start.pose_mm,
        r.rejected_samples,
        r.tracker_gaps
    );
    eprintln!("{line}");
    let rounds = &r.delay_rounds_ms;
    if rounds.len() < 3 || (rounds[rounds.len() - 1] - rounds[rounds.len() - 2]).abs() >= 0.05 {
        failures.push(format!("{label}: the delay was not re-estimated until it settled: {rounds:?}"));
    }
    if (r.delay_ms - truth.delay_ms).abs() >= 0.25 {
        failures.push(format!("{label}: delay off by {:.3} ms", r.delay_ms - truth.delay_ms));
    }
    if r.position_mm.after > 1.10 * truth.floor_mm {
        failures.push(format!(
            "{label}: position {:.4} mm > 1.1 × floor {:.4}",
            r.position_mm.after, truth.floor_mm
        ));
    }
    if r.orientation_deg.after > 1.10 * truth.floor_deg {
        failures.push(format!(
            "{label}: orientation {:.4}° > 1.1 × floor {:.4}",
            r.orientation_deg.after, truth.floor_deg
        ));
    }
    let expected = if options.quadratic_gimbals { GimbalModel::Quadratic } else { GimbalModel::Linear };
    if r.gimbal_model != expected {
        failures.push(format!("{label}: gimbal model {:?}, expected {expected:?}", r.gimbal_model));
    }
    match r.start.landmark_mm {
        Some(l) if l <= 1.05 * r.start.pose_mm.max(truth.floor_mm) => {}
        other => failures.push(format!(
            "{label}: landmark start {other:?} mm ({:?}) not as good as pose-based {:.3} mm",
            r.start.landmark_note, r.start.pose_mm
        )),
    }
    failures
}

/// Runs `jobs` on two threads, collecting their failure lists.
fn parallel(jobs: Vec<Box<dyn FnOnce() -> Vec<String> + Send>>) -> Vec<String> {
    let queue = std::sync::Mutex::new(jobs);
    let failures = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| loop {
                let Some(job) = queue.lock().unwrap().pop() else { break };
                let f = job();
                failures.lock().unwrap().extend(f);
            });
        }
    });
    failures.into_inner().unwrap()
}

#[test]
fn every_t2_placement_device_and_gimbal_type_reaches_the_noise_floor() {
    let mut jobs: Vec<Box<dyn FnOnce() -> Vec<String> + Send>> = Vec::new();
    let mut i = 0u64;
    for t2 in [T2Mount::Above, T2Mount::Below, T2Mount::Beside] {
        for phantom in [Phantom::Omni, Phantom::Premium15] {
            for quadratic_gimbals in [true, false] {
                i += 1;
                // Some devices record with a non-default driver convention, declared in
                // recording.json: θ3 relative to θ2, a flipped sign, degrees, permuted columns.
                let convention = match i % 4 {
                    1 => Convention { theta3_relative: true, ..Convention::default() },
                    2 => Convention {
                        degrees: true,
                        sign: [1.0, -1.0, 1.0, 1.0, -1.0, 1.0],
                        ..Convention::default()
                    },
                    3 => Convention { columns: [2, 1, 3, 4, 6, 5], ..Convention::default() },
                    _ => Convention::default(),
                };
                let options = GenOptions {
                    seed: 100 + i,
                    phantom,
                    quadratic_gimbals,
                    t2,
                    delay_ms: 4.7 + 2.9 * i as f64,
                    tracker_hz: [60.0, 90.0, 120.0, 240.0][i as usize % 4],
                    recorded: convention,
                    declared: Some(convention),
                    ..GenOptions::default()
                };
                jobs.push(Box::new(move || {
                    let label =
                        format!("{t2:?} {phantom:?} quadratic={quadratic_gimbals} {}Hz", options.tracker_hz);
                    match run(&format!("matrix-{i}"), &options) {
                        (truth, Ok(r)) => check(&label, &options, &truth, &r),
                        (_, Err(e)) => vec![format!("{label}: {e}")],
                    }
                }));
            }
        }
    }
    let failures = parallel(jobs);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn occlusion_gaps_keep_the_accuracy() {
    let mut jobs: Vec<Box<dyn FnOnce() -> Vec<String> + Send>> = Vec::new();
    for (k, (t2, phantom, quadratic_gimbals)) in
        [(T2Mount::Below, Phantom::Omni, true), (T2Mount::Beside, Phantom::Premium15, false)]
            .into_iter()
            .enumerate()
    {
        jobs.push(Box::new(move || {
            let options = GenOptions {
                seed: 300 + k as u64,
                phantom,
                quadratic_gimbals,
                t2,
                occlusion: 0.1,
                joints_seconds: 40.0,
                ..GenOptions::default()
            };
            match run(&format!("occluded-{k}"), &options) {
                (truth, Ok(r)) => {
                    let mut f = check(&format!("occluded {t2:?} {phantom:?}"), &options, &truth, &r);
                    if r.tracker_gaps < 20 {
                        f.push(format!("only {} gaps seen", r.tracker_gaps));
                    }
                    f
                }
                (_, Err(e)) => vec![format!("occluded {t2:?} {phantom:?}: {e}")],
            }
        }));
    }
    let failures = parallel(jobs);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_few_wild_tracker_samples_change_nothing() {
    let base = GenOptions { seed: 77, t2: T2Mount::Below, ..GenOptions::default() };
    let wild = GenOptions { wild_per_stream: 3, ..base.clone() };
    let results = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for (name, o) in [("clean", &base), ("wild", &wild)] {
            let results = &results;
            s.spawn(move || {
                let r = run(name, o);
                results.lock().unwrap().push((name, r));
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|r| r.0);
    let [(_, (truth_c, clean)), (_, (truth_w, wild))] = <[_; 2]>::try_from(results).ok().unwrap();
    let (clean, wild) = (clean.unwrap(), wild.unwrap());
    let mut failures = check("clean", &base, &truth_c, &clean);
    failures.extend(check("wild", &wild_options(&base), &truth_w, &wild));
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(clean.rejected_samples, 0, "nothing rejected from a clean recording");
    assert_eq!(wild.rejected_samples, truth_w.wild_written, "every wild sample rejected, nothing else");
    assert!((clean.delay_ms - wild.delay_ms).abs() < 0.05, "{} vs {}", clean.delay_ms, wild.delay_ms);
    assert!(
        (clean.position_mm.after - wild.position_mm.after).abs() < 0.02 * clean.position_mm.after,
        "{} vs {}",
        clean.position_mm.after,
        wild.position_mm.after
    );
    assert!(
        (clean.orientation_deg.after - wild.orientation_deg.after).abs() < 0.02 * clean.orientation_deg.after,
        "{} vs {}",
        clean.orientation_deg.after,
        wild.orientation_deg.after
    );
}

fn wild_options(base: &GenOptions) -> GenOptions {
    GenOptions { wild_per_stream: 3, ..base.clone() }
}

/// Runs the CLI on a generated recording: exit code, stderr, summary.json.
fn cli(name: &str, options: &GenOptions) -> (Option<i32>, String, serde_json::Value) {
    let dir = scratch(name);
    generate(options, &dir.join("rec")).expect("generator writes the recording");
    let out = std::process::Command::new(kincal_e2e::kincal_bin())
        .args(["haptic", "calibrate"])
        .arg(dir.join("rec"))
        .arg("--out")
        .arg(dir.join("run"))
        .output()
        .expect("kincal runs");
    let summary = std::fs::read_to_string(dir.join("run/summary.json"))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or(serde_json::Value::Null);
    std::fs::remove_dir_all(&dir).ok();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned(), summary)
}

#[test]
fn recordings_that_cannot_be_trusted_are_refused_naming_the_cause() {
    let base = GenOptions { seed: 500, joints_seconds: 20.0, ..GenOptions::default() };
    let relative = Convention { theta3_relative: true, ..Convention::default() };
    let swapped = Convention { columns: [1, 3, 2, 4, 5, 6], ..Convention::default() };
    let cases: Vec<(&str, GenOptions, Vec<&str>)> = vec![
        (
            "wrong-convention",
            GenOptions { recorded: relative, ..base.clone() },
            vec![
                "joint calibration (joints/) failed",
                "joint convention looks wrong",
                "θ3 is reported relative to θ2",
                "\"theta3\":\"relative\"",
            ],
        ),
        (
            "swapped-columns",
            GenOptions { recorded: swapped, ..base.clone() },
            vec![
                "failed",
                "joint convention looks wrong",
                "columns of θ2 and θ3 are swapped",
                "\"columns\":[1,3,2,4,5,6]",
            ],
        ),
        (
            "little-motion",
            GenOptions { motion_scale: 0.1, ..base.clone() },
            vec!["joint calibration (joints/) failed", "too little motion", "θ1 moved through"],
        ),
        (
            "theta1-sign",
            GenOptions {
                recorded: Convention { sign: [-1.0, 1.0, 1.0, 1.0, 1.0, 1.0], ..Convention::default() },
                ..base.clone()
            },
            vec![
                "failed",
                "joint convention looks wrong",
                "θ1 has the opposite sign",
                "\"sign\":[-1.0,1.0,1.0,1.0,1.0,1.0]",
            ],
        ),
        (
            "theta4-sign",
            GenOptions {
                recorded: Convention { sign: [1.0, 1.0, 1.0, -1.0, 1.0, 1.0], ..Convention::default() },
                ..base.clone()
            },
            vec!["gimbal calibration (gimbal/, reference/) failed", "θ4 has the opposite sign"],
        ),
        (
            "gimbal-columns",
            GenOptions {
                recorded: Convention { columns: [1, 2, 3, 5, 4, 6], ..Convention::default() },
                ..base.clone()
            },
            vec!["gimbal calibration (gimbal/, reference/) failed", "columns of θ4 and θ5 are swapped"],
        ),
        ("late-tracker", GenOptions { delay_ms: 500.0, ..base.clone() }, vec!["time delay (delay/) failed"]),
        (
            "degrees",
            GenOptions { recorded: Convention { degrees: true, ..Convention::default() }, ..base.clone() },
            vec!["device.csv:2", "look like degrees", "\"unit\": \"deg\""],
        ),
    ];
    let jobs: Vec<Box<dyn FnOnce() -> Vec<String> + Send>> = cases
        .into_iter()
        .map(|(name, options, needles)| -> Box<dyn FnOnce() -> Vec<String> + Send> {
            Box::new(move || {
                let (code, stderr, summary) = cli(name, &options);
                eprintln!("{name}: exit {code:?}: {stderr}");
                let mut f = Vec::new();
                if code == Some(0) || code.is_none() {
                    f.push(format!("{name}: exit {code:?}, expected a refusal"));
                }
                for n in needles {
                    if !stderr.contains(n) {
                        f.push(format!("{name}: stderr does not name `{n}`: {stderr}"));
                    }
                }
                if summary["status"] != "failed"
                    || summary["failure"]["message"].as_str().is_none_or(str::is_empty)
                {
                    f.push(format!("{name}: summary.json not marked failed: {summary}"));
                }
                if name == "wrong-convention"
                    && summary["failure"]["maps"]["joints"][2].as_array().is_none_or(|cells| cells.len() < 3)
                {
                    f.push(format!("{name}: no residual maps of the refused joint calibration: {summary}"));
                }
                if name == "late-tracker"
                    && !(stderr.contains("window edge") || stderr.contains("no clear correlation peak"))
                {
                    f.push(format!("{name}: the delay window is not named: {stderr}"));
                }
                f
            })
        })
        .collect();
    let failures = parallel(jobs);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

#[test]
fn a_calibration_is_never_worse_than_the_uncalibrated_device() {
    // A device with perfect sensors: calibration cannot improve it. Either the result is better
    // on held-out samples, or it is refused as worse with the reason named.
    let jobs: Vec<Box<dyn FnOnce() -> Vec<String> + Send>> = (0..2)
        .map(|k| -> Box<dyn FnOnce() -> Vec<String> + Send> {
            Box::new(move || {
                let options = GenOptions { seed: 700 + k, sensor_error_scale: 0.0, ..GenOptions::default() };
                match run(&format!("perfect-{k}"), &options) {
                    (_, Ok(r))
                        if r.position_mm.after < r.position_mm.before
                            && r.orientation_deg.after < r.orientation_deg.before =>
                    {
                        eprintln!(
                            "perfect {k}: accepted, {:.4} → {:.4} mm",
                            r.position_mm.before, r.position_mm.after
                        );
                        vec![]
                    }
                    (_, Ok(r)) => vec![format!(
                        "perfect {k}: accepted although worse: {:.4} → {:.4} mm, {:.4} → {:.4}°",
                        r.position_mm.before,
                        r.position_mm.after,
                        r.orientation_deg.before,
                        r.orientation_deg.after
                    )],
                    (_, Err(e)) if e.contains("worse after calibration") => {
                        eprintln!("perfect {k}: refused: {e}");
                        vec![]
                    }
                    (_, Err(e)) => vec![format!("perfect {k}: unexpected refusal: {e}")],
                }
            })
        })
        .collect();
    let failures = parallel(jobs);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
