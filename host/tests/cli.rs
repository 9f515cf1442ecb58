//! The `kincal` binary: output contract and bad-input handling.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn kincal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kincal")).args(args).output().expect("kincal runs")
}

/// Whether a page's first section is its verdict, the verdict names a next step, and no internal
/// name reaches the reader; the failure says which.
fn check_leads_with_verdict(page: &Path) {
    let html = std::fs::read_to_string(page).unwrap_or_else(|e| panic!("{}: {e}", page.display()));
    let first = html.find("<h2>").map(|k| &html[k..]).unwrap_or_default();
    assert!(
        first.starts_with("<h2>Verdict</h2>"),
        "{}: the first section is not the verdict",
        page.display()
    );
    let verdict = &first[..first[4..].find("<h2>").map_or(first.len(), |k| k + 4)];
    assert!(
        ["next:", "what to do", "what to measure next"].iter().any(|w| verdict.contains(w)),
        "{}: the verdict names no next step: {verdict}",
        page.display()
    );
    for internal in
        ["AtFloor", "NothingSignificant", "CannotTell", "CostConverged", "Quadratic", "kincal diagnose RUN"]
    {
        assert!(!html.contains(internal), "{}: {internal:?} reaches the reader", page.display());
    }
}

fn example_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/suta/model.toml")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn simulate_into(dir: &Path) {
    let out = kincal(&[
        "simulate",
        "--model",
        example_model().to_str().unwrap(),
        "--out",
        dir.to_str().unwrap(),
        "--seed",
        "4",
        "--repeats",
        "1",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

fn calibrate_args<'a>(data: &'a str, run: &'a str, model: &'a str) -> Vec<String> {
    [
        "calibrate",
        "--model",
        model,
        "--artefact",
        &format!("{data}/artefact.json"),
        "--data",
        &format!("{data}/cal"),
        "--validate",
        &format!("{data}/val"),
        "--out",
        run,
        "--restarts",
        "1",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

#[test]
fn calibrate_writes_a_run_whose_model_loads_again() {
    let dir = scratch("ok");
    let data = dir.join("data");
    simulate_into(&data);
    let run = dir.join("run");
    let model = example_model();
    let mut args = calibrate_args(data.to_str().unwrap(), run.to_str().unwrap(), model.to_str().unwrap());
    args.push("--json".into());
    let out = Command::new(env!("CARGO_BIN_EXE_kincal")).args(&args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let printed: serde_json::Value = serde_json::from_slice(&out.stdout).expect("--json prints summary.json");
    let stored: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    assert_eq!(printed, stored);
    for key in ["rms_mm", "mean_mm", "std_mm", "max_mm", "count"] {
        assert!(
            stored["validation"]["distances"]["calibrated"][key].is_number()
                && stored["validation"]["distances"]["nominal"][key].is_number(),
            "{key}"
        );
    }
    // The same file read back as the type diagnose and compare use.
    let folder = kincal::api::load(&run).expect("RUN reads back as kincal-run/2");
    assert_eq!(folder.summary.format, kincal::calib::summary::RUN_FORMAT);
    let distances = folder.summary.validation.distances.as_ref().expect("held-out distances");
    assert!(folder.summary.calibration.rms_mm < distances.nominal.rms_mm);
    assert_eq!(folder.residuals().expect("residuals.json reads back").len(), distances.calibrated.count);
    let calibrated =
        kincal::model::ArmModel::load(&run.join("model.toml")).expect("calibrated model loads again");
    assert_eq!(calibrated.free.len(), kincal::model::ArmModel::load(&model).unwrap().free.len());
    let html = std::fs::read_to_string(run.join("report.html")).unwrap();
    assert!(html.contains("<svg") && html.contains("Outlier diagnostics"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_input_names_file_and_field_and_leaves_no_run() {
    let dir = scratch("bad");
    let data = dir.join("data");
    simulate_into(&data);
    let session = data.join("cal/A_O.json");
    let good = std::fs::read_to_string(&session).unwrap();
    let parsed: serde_json::Value = serde_json::from_str(&good).unwrap();
    let first_angle = parsed["measurements"][0]["joints_deg"][0].to_string();
    let mut five_joints = parsed.clone();
    if let Some(joints) = five_joints["measurements"][0]["joints_deg"].as_array_mut() {
        joints.pop();
    }
    let cases: Vec<(&str, String, &str)> = vec![
        ("malformed JSON", good[..good.len() / 2].to_string(), "A_O.json"),
        ("wrong format tag", good.replacen("suta-session/1", "suta-session/7", 1), "`format`"),
        (
            "unknown landmark",
            good.replacen("\"landmark\": \"O\"", "\"landmark\": \"Q7\"", 1),
            "measurements[0].landmark",
        ),
        ("NaN", good.replacen(&first_angle, "NaN", 1), "A_O.json"),
        ("wrong joint count", five_joints.to_string(), "measurements[0].joints_deg"),
    ];
    let model = example_model();
    for (what, text, expect) in cases {
        assert!(text != good, "{what}: the corruption must change the file");
        std::fs::write(&session, &text).unwrap();
        let run = dir.join("run");
        let args = calibrate_args(data.to_str().unwrap(), run.to_str().unwrap(), model.to_str().unwrap());
        let out = Command::new(env!("CARGO_BIN_EXE_kincal")).args(&args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{what}: {stderr}");
        assert!(
            stderr.contains("A_O.json") && stderr.contains(expect),
            "{what}: `{stderr}` should name {expect}"
        );
        assert!(!stderr.contains("panicked"), "{what}: {stderr}");
        assert!(!run.exists(), "{what}: no RUN folder may be left behind");
    }
    std::fs::write(&session, &good).unwrap();
    // An empty calibration folder.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let out = kincal(&[
        "calibrate",
        "--model",
        model.to_str().unwrap(),
        "--artefact",
        data.join("artefact.json").to_str().unwrap(),
        "--data",
        empty.to_str().unwrap(),
        "--validate",
        data.join("val").to_str().unwrap(),
        "--out",
        dir.join("run").to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no session files"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // A missing model file.
    let out = kincal(&[
        "calibrate",
        "--model",
        "/nonexistent/model.toml",
        "--artefact",
        "a",
        "--data",
        "b",
        "--validate",
        "c",
        "--out",
        "d",
    ]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/model.toml"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_whole_loop_finds_adds_and_compares_a_hidden_effect() {
    let dir = scratch("loop");
    let data = dir.join("data");
    let model = example_model();
    let out = kincal(&[
        "simulate",
        "--model",
        model.to_str().unwrap(),
        "--out",
        data.to_str().unwrap(),
        "--seed",
        "5",
        "--hidden",
        "eccentricity_sin:5=0.2",
        "--hidden",
        "eccentricity_cos:5=-0.1",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (before, after) = (dir.join("before"), dir.join("after"));
    let base = calibrate_args(data.to_str().unwrap(), before.to_str().unwrap(), model.to_str().unwrap());
    assert!(Command::new(env!("CARGO_BIN_EXE_kincal")).args(&base).status().unwrap().success());
    let out = kincal(&["diagnose", before.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let d: serde_json::Value = serde_json::from_slice(&out.stdout).expect("--json prints the diagnosis");
    let first = &d["candidates"][0];
    assert_eq!(first["name"], "eccentricity:5");
    assert_eq!(first["significant"], true);
    let explained = first["explained"].as_f64().unwrap();
    assert!((0.0..=1.0).contains(&explained) && explained > 0.5, "{explained}");
    assert!(first["evidence"].as_str().unwrap().contains("eccentricity"), "{}", first["evidence"]);
    assert!(first["held_out_rms_mm"].as_f64().unwrap() < d["baseline"]["rms_mm"].as_f64().unwrap());
    assert!(before.join("diagnosis.html").exists());
    let mut with = calibrate_args(data.to_str().unwrap(), after.to_str().unwrap(), model.to_str().unwrap());
    with.extend(["--add".to_string(), "eccentricity:5".to_string()]);
    assert!(Command::new(env!("CARGO_BIN_EXE_kincal")).args(&with).status().unwrap().success());
    let calibrated = kincal::model::ArmModel::load(&after.join("model.toml")).unwrap();
    assert!(
        kincal::model::effects::Effect::parse("eccentricity:5").unwrap().is_in(&calibrated),
        "the added effect is saved with the model"
    );
    let page = dir.join("compare.html");
    let out = kincal(&[
        "compare",
        before.to_str().unwrap(),
        after.to_str().unwrap(),
        "--out",
        page.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("RMS mm") && text.contains("eccentricity:5"), "{text}");
    assert!(text.starts_with("the second run"), "compare prints its verdict first: {text}");
    for page in [before.join("report.html"), before.join("diagnosis.html"), page.clone()] {
        check_leads_with_verdict(&page);
    }
    let report = std::fs::read_to_string(before.join("report.html")).unwrap();
    assert!(
        report.contains(&format!("kincal diagnose {}", before.display())),
        "the next command names the run"
    );
    let rms = |run: &Path| -> f64 { kincal::api::load(run).expect("typed RUN").summary.held_out_rms_mm() };
    assert!(rms(&after) < 0.6 * rms(&before), "{} → {}", rms(&before), rms(&after));
    assert!(std::fs::read_to_string(&page).unwrap().contains("<svg"));
    // What to measure next: rivals and weak parameters, a pose list, the plan as JSON.
    let (plan, poses, notes) = (dir.join("plan.json"), dir.join("poses.csv"), dir.join("notes.txt"));
    std::fs::write(&notes, "mine").unwrap();
    let run = before.to_str().unwrap();
    let out = kincal(&["plan", run, "--rivals", "wobble:9,twist:3"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("not an effect"));
    let out = kincal(&["plan", run, "--out", notes.to_str().unwrap()]);
    assert!(
        !out.status.success() && String::from_utf8_lossy(&out.stderr).contains("not a file kincal wrote")
    );
    assert_eq!(std::fs::read_to_string(&notes).unwrap(), "mine");
    let (plan_arg, poses_arg) = (plan.to_str().unwrap(), poses.to_str().unwrap());
    let out = kincal(&[
        "plan",
        run,
        "--rivals",
        "twist:3,link_offset:3",
        "--count",
        "1",
        "--out",
        plan_arg,
        "--csv",
        poses_arg,
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("to tell twist:3 from link_offset:3") && text.contains("joint 3 passes"), "{text}");
    let p: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&plan).unwrap()).unwrap();
    assert_eq!(p["format"], "kincal-plan/1");
    let (now, after) = (&p["rivals"]["before_sigma2"], &p["rivals"]["after_sigma2"]);
    assert!(after[0].as_f64().unwrap() >= now[0].as_f64().unwrap(), "{now} → {after}");
    let csv = std::fs::read_to_string(&poses).unwrap();
    assert!(
        csv.starts_with(kincal::store::PLAN_CSV_HEADER) && csv.lines().count() > 2 * 6,
        "header and two placements of at least 6 touches: {csv}"
    );
    // Bad effect names and bad runs are reported, not panicked on.
    let mut bad = base.clone();
    bad.extend(["--add".to_string(), "wobble:9".to_string()]);
    let out = Command::new(env!("CARGO_BIN_EXE_kincal")).args(&bad).output().unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("unknown effect"));
    let out = kincal(&["diagnose", dir.join("nope").to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("model.toml"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn haptic_simulate_and_calibrate_write_the_summary_and_refuse_bad_recordings() {
    let dir = scratch("haptic");
    let rec = dir.join("rec");
    let out = kincal(&[
        "haptic",
        "simulate",
        "--out",
        rec.to_str().unwrap(),
        "--delay-ms",
        "17",
        "--joints-seconds",
        "30",
        "--t2-height-mm",
        "-80",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let run = dir.join("run");
    let out =
        kincal(&["haptic", "calibrate", rec.to_str().unwrap(), "--out", run.to_str().unwrap(), "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let s: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!((s["delay_ms"].as_f64().unwrap() - 17.0).abs() < 0.25, "{}", s["delay_ms"]);
    assert!(
        s["position"]["after_mm"].as_f64().unwrap() < 0.3
            && s["position"]["before_mm"].as_f64().unwrap() > 3.0
    );
    assert!(
        s["orientation"]["after_deg"].as_f64().unwrap() < 0.15
            && s["orientation"]["before_deg"].as_f64().unwrap() > 1.0
    );
    assert_eq!(s["gimbal_model"], "quadratic");
    assert!(std::fs::read_to_string(run.join("report.html")).unwrap().contains("Hammer"));
    check_leads_with_verdict(&run.join("report.html"));
    // A stream with a time going backwards is named by file and line; nothing panics.
    let device = rec.join("joints/device.csv");
    let text = std::fs::read_to_string(&device).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines.swap(100, 101);
    std::fs::write(&device, lines.join("\n")).unwrap();
    let out = kincal(&["haptic", "calibrate", rec.to_str().unwrap(), "--out", run.to_str().unwrap()]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("joints/device.csv:102") && stderr.contains("does not increase"), "{stderr}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn demo_offline_and_simulate_run_from_an_empty_folder_outside_the_repository() {
    let dir = scratch("anywhere");
    let run = |args: &[&str]| {
        let child = Command::new(env!("CARGO_BIN_EXE_kincal"))
            .args(args)
            .current_dir(&dir)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("kincal runs");
        let pid = child.id();
        let out = child.wait_with_output().expect("kincal ends");
        assert!(out.status.success(), "kincal {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        (pid, String::from_utf8_lossy(&out.stdout).into_owned())
    };
    let (pid, _) = run(&["simulate", "--out", "data", "--repeats", "1"]);
    for file in ["artefact.json", "truth.toml", "cal", "val"] {
        assert!(dir.join("data").join(file).exists(), "simulate wrote no data/{file}");
    }
    let model_file = std::env::temp_dir().join(format!("kincal-suta-model-{pid}.toml"));
    assert!(!model_file.exists(), "the built-in model's file outlived the command");

    let (_, printed) = run(&["demo", "--offline"]);
    assert!(printed.contains("missing effect: compliance:2"), "{printed}");
    let out = dir.join("runs/demo-offline");
    for file in ["nominal.toml", "run/diagnosis.html", "run/report.html", "run-added/model.toml"] {
        assert!(out.join(file).exists(), "demo --offline wrote no {file}");
    }
    for page in ["run/report.html", "run/diagnosis.html", "run/auto/report.html", "run-added/report.html"] {
        check_leads_with_verdict(&out.join(page));
    }
    let nominal = kincal::model::ArmModel::load(&out.join("nominal.toml")).unwrap();
    assert_eq!(nominal, kincal::model::ArmModel::load(&example_model()).unwrap());
    std::fs::remove_dir_all(&dir).ok();
}
