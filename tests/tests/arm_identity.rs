//! A calibration that belongs to its arm (issue 32), on the emulator started as two arms: two
//! QEMU controllers with their own identities, posed from their own geometries.
//!
//! * arm A's placements recorded through its controller calibrate into a RUN that names arm A,
//!   its validation date and the SHA-256 of every input; sessions of A and B mixed in one
//!   calibration are refused, both named;
//! * a model calibrated on arm A is refused on arm B, both named, and B keeps what it holds;
//! * on A the stored set shows the RUN's hash (the one `sha256sum` gives) and its date;
//! * the RUN's certificate leads with its verdict and names the arm, the RUN hash, the signer,
//!   the validity, what it does not cover and every input's hash; a changed input voids it, and
//!   an uploaded RUN is never replaced;
//! * a set whose validity has passed is warned about at every connect;
//! * `kincal check` through the record path says "holds" on A's own geometry and "does not hold"
//!   after a knock, with the figures, and writes its session naming arm A;
//! * tracker sessions (and tracker with artefact sessions) of two arms are refused too.

use kincal::controller::emulator::Emulator;
use kincal::controller::link::Link;
use kincal_e2e::{emulated_firmware, kincal_bin};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Exit code, stdout and stderr of `kincal args` run in `dir`.
fn kincal(dir: &Path, args: &[&str]) -> (Option<i32>, String, String) {
    let out = Command::new(kincal_bin()).args(args).current_dir(dir).output().unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

/// `kincal args` in `dir`, which must succeed; its stdout and stderr.
fn ok(dir: &Path, args: &[&str]) -> (String, String) {
    let (code, out, err) = kincal(dir, args);
    assert_eq!(code, Some(0), "kincal {args:?}: {out}\n{err}");
    (out, err)
}

fn scratch() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-arm-identity-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// What `cd RUN && sha256sum model.toml summary.json | sha256sum` prints: the RUN hash computed
/// by the system's tools, not by kincal.
fn sha256sum_of_run(run: &Path) -> String {
    let lines =
        Command::new("sha256sum").args(["model.toml", "summary.json"]).current_dir(run).output().unwrap();
    assert!(lines.status.success(), "sha256sum (coreutils) is needed");
    let mut hash = Command::new("sha256sum")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    {
        use std::io::Write;
        hash.stdin.take().unwrap().write_all(&lines.stdout).unwrap();
    }
    let out = hash.wait_with_output().unwrap();
    String::from_utf8_lossy(&out.stdout).split_whitespace().next().unwrap().to_string()
}

/// The session files of `dir`, by placement name (file stem), sorted.
fn placements(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .map(|p| p.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Record `placement` on the emulated arm at `port`, posed from `geometry` (`repeats` repeats,
/// 16-tick windows), as `purpose` into `out`.
fn record_on(
    dir: &Path,
    port: &str,
    geometry: &str,
    placement: &str,
    purpose: &str,
    repeats: &str,
    out: &str,
) {
    let script = format!("script-{out}-{placement}.json").replace('/', "-");
    let seed = (placement.bytes().map(u64::from).sum::<u64>() % 1000).to_string();
    ok(
        dir,
        &[
            "emulated-arm",
            "script",
            "--geometry",
            geometry,
            "--artefact",
            "armA/artefact.json",
            "--placement",
            placement,
            "--repeats",
            repeats,
            "--seed",
            &seed,
            "--out",
            &script,
        ],
    );
    ok(
        dir,
        &[
            "record",
            "--port",
            port,
            "--artefact",
            "armA/artefact.json",
            "--placement",
            placement,
            "--purpose",
            purpose,
            "--out",
            out,
            "--script",
            &script,
            "--repeats",
            repeats,
            "--window-ticks",
            "16",
        ],
    );
}

/// SHA-256 of a file as `sha256sum` prints it.
fn sha256sum(file: &Path) -> String {
    let out = Command::new("sha256sum").arg(file).output().unwrap();
    assert!(out.status.success(), "sha256sum (coreutils) is needed");
    String::from_utf8_lossy(&out.stdout).split_whitespace().next().unwrap().to_string()
}

#[test]
fn a_calibration_belongs_to_its_arm_on_the_emulator_started_as_two_arms() {
    let dir = scratch();
    let elf = emulated_firmware();
    let (_a, port_a) = Emulator::start_server_as(&elf, Some("lab-arm-A")).expect("QEMU starts as arm A");
    let (_b, port_b) = Emulator::start_server_as(&elf, Some("lab-arm-B")).expect("QEMU starts as arm B");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/suta/model.toml");
    let example = example.to_str().unwrap();
    // Arm A's geometry and artefact; its placements recorded through the controller of arm A,
    // posed from that geometry, so every session names arm A.
    ok(&dir, &["simulate", "--model", example, "--out", "armA", "--seed", "1"]);
    let mut artefact: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("armA/artefact.json")).unwrap()).unwrap();
    artefact["certificate"] = "DKD-K-12345 2026-03".into();
    std::fs::write(dir.join("armA/artefact.json"), artefact.to_string()).unwrap();
    let started = std::time::Instant::now();
    for (purpose, folder) in [("calibration", "cal"), ("validation", "val")] {
        for placement in placements(&dir.join("armA").join(folder)) {
            record_on(&dir, &port_a, "armA/truth.toml", &placement, purpose, "3", &format!("recA/{folder}"));
        }
    }
    println!("recorded arm A's placements in {:.1} s", started.elapsed().as_secs_f64());
    let calibrate = |data: &str, out: &str| {
        kincal(
            &dir,
            &[
                "calibrate",
                "--model",
                example,
                "--artefact",
                "armA/artefact.json",
                "--data",
                data,
                "--validate",
                "recA/val",
                "--out",
                out,
                "--restarts",
                "1",
            ],
        )
    };
    let (code, out, err) = calibrate("recA/cal", "run");
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(out.contains("arm lab-arm-A (kincal-fw"), "calibrate names the arm: {out}");
    // The RUN carries the arm, the validation date and the SHA-256 of every input file.
    let model = kincal::model::ArmModel::load(&dir.join("run/model.toml")).unwrap();
    assert_eq!(model.arm.as_ref().map(|a| a.id.as_str()), Some("lab-arm-A"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("run/summary.json")).unwrap()).unwrap();
    assert_eq!(summary["arm"]["id"], "lab-arm-A");
    assert_eq!(summary["artefact_certificate"], "DKD-K-12345 2026-03");
    let validated_at = summary["validated_at_unix_s"].as_u64().expect("the validation date");
    let hashes = summary["input_files"].as_array().unwrap();
    let session = std::fs::canonicalize(dir.join("recA/cal/C_A.json")).unwrap();
    let recorded = hashes.iter().find(|h| h["path"].as_str() == session.to_str()).expect("C_A.json hashed");
    assert_eq!(recorded["sha256"].as_str().unwrap(), sha256sum(&session));
    assert_eq!(
        hashes.len(),
        2 + placements(&dir.join("recA/cal")).len() + placements(&dir.join("recA/val")).len()
    );

    // Sessions of A and B mixed in one calibration are refused, both arms and files named.
    record_on(&dir, &port_b, "armA/truth.toml", "V_E", "calibration", "1", "recB");
    kincal_e2e::corpus::copy_tree(&dir.join("recA/cal"), &dir.join("mixed"));
    std::fs::copy(dir.join("recB/V_E.json"), dir.join("mixed/V_E.json")).unwrap();
    let (code, _, err) = calibrate("mixed", "run-mixed");
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("recorded on arm lab-arm-A")
            && err.contains("mixed/V_E.json on arm lab-arm-B")
            && err.contains("one calibration is of one arm"),
        "{err}"
    );
    assert!(!dir.join("run-mixed").exists(), "nothing written");

    ok(&dir, &["key", "new", "--out", "station.key"]);
    let upload = |port: &str, extra: &[&str]| {
        let mut args = vec!["upload", "--key", "station.key", "--port", port, "run/model.toml"];
        args.extend(extra);
        kincal(&dir, &args)
    };

    // Refused on B, both arms named; B still holds nothing.
    let (code, _, err) = upload(&port_b, &[]);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("run/model.toml was calibrated on arm lab-arm-A")
            && err.contains("the connected controller is arm lab-arm-B")
            && err.contains("nothing was uploaded"),
        "{err}"
    );
    let (info_b, _) = ok(&dir, &["info", "--port", &port_b]);
    assert!(info_b.contains("arm        lab-arm-B") && info_b.contains("parameters none stored"), "{info_b}");

    // Stored on A with its RUN hash, date and a year's validity; `info` and `params` show them.
    let (out, _) = ok(
        &dir,
        &["upload", "--key", "station.key", "--port", &port_a, "run/model.toml", "--valid-days", "365"],
    );
    let run_hash = sha256sum_of_run(&dir.join("run"));
    assert!(out.contains(&format!("sha256:{run_hash}")), "{out}");
    assert!(!out.contains("modification time"), "the RUN records its validation date: {out}");
    assert!(out.contains("recorded in run/uploads.json"), "{out}");
    let (info_a, _) = ok(&dir, &["info", "--port", &port_a]);
    let date = kincal::controller::signing::utc(validated_at);
    assert!(info_a.contains(&format!("RUN        sha256:{run_hash}")), "{info_a}");
    assert!(info_a.contains(&format!("validated  {date}")), "{info_a}");
    assert!(info_a.contains("(364 days left)") || info_a.contains("(365 days left)"), "{info_a}");
    let (_, params_err) = ok(&dir, &["params", "--port", &port_a]);
    assert!(params_err.contains(&run_hash) && params_err.contains("signature valid"), "{params_err}");

    // The certificate of the RUN: verdict first, the arm, the RUN hash as sha256sum gives it, the
    // reference, the key that signed the stored set, the validity, what it does not cover, the
    // re-check, and every input's hash checked against the file.
    let (code, out, err) = kincal(&dir, &["certificate", "run", "--operator", "A. Metrologist"]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(out.starts_with("CALIBRATED"), "{out}");
    let page = std::fs::read_to_string(dir.join("run/certificate.html")).unwrap();
    let uploads: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("run/uploads.json")).unwrap()).unwrap();
    let signer = uploads["uploads"][0]["signer"].as_str().unwrap().to_string();
    assert!(signer.starts_with("ed25519:"), "{uploads}");
    let verdict_at = page.find("class=\"verdict").expect("a verdict");
    assert!(verdict_at < page.find("1. Device calibrated").unwrap(), "the page leads with its verdict");
    assert!(
        !page[verdict_at..].starts_with("class=\"verdict fail"),
        "{}",
        &page[verdict_at..verdict_at + 400]
    );
    let c_a = sha256sum(&session);
    let artefact_file = std::fs::canonicalize(dir.join("armA/artefact.json")).unwrap();
    let recheck = format!("kincal check --port PORT --artefact {} --placement V_A", artefact_file.display());
    for needle in [
        "<code>lab-arm-A</code>",
        run_hash.as_str(),
        "DKD-K-12345 2026-03",
        signer.as_str(),
        "valid until",
        "A. Metrologist",
        recheck.as_str(),
        c_a.as_str(),
        "What this calibration does not cover",
        "readings visited",
        "Temperature was not recorded",
        "U (k = 2)",
    ] {
        assert!(page.contains(needle), "the certificate lacks {needle:?}");
    }
    assert!(!page.contains("CHANGED since") && !page.contains("MISSING"), "every input unchanged");
    // An input changed after the calibration: the certificate says so and certifies nothing.
    let mut text = std::fs::read_to_string(&session).unwrap();
    text.push(' ');
    std::fs::write(&session, text).unwrap();
    let (code, _, err) = kincal(&dir, &["certificate", "run", "--out", "changed.html"]);
    assert_eq!(code, Some(2), "{err}");
    let changed = std::fs::read_to_string(dir.join("changed.html")).unwrap();
    assert!(changed.contains("class=\"verdict fail") && changed.contains("CHANGED since"), "changed input");
    // An uploaded RUN is never replaced: a controller holds a set that names its hash.
    let (code, _, err) = calibrate("recA/cal", "run");
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("uploaded to arm lab-arm-A") && err.contains("the RUN is kept"), "{err}");

    // A set whose validity has passed (validated 400 days ago, valid 365): warned at connect.
    let now = kincal::controller::traceability::unix_now();
    let mut link = Link::open(&port_a).unwrap();
    link.hello().unwrap();
    let trace = kincal_protocol::signed::SetTrace {
        run_sha256: kincal::trace::run_sha256(&dir.join("run")).unwrap(),
        validated_at_unix_s: now - 400 * 86_400,
        valid_until_unix_s: now - 35 * 86_400,
    };
    let key = kincal::controller::signing::StationKey::load(&dir.join("station.key")).unwrap().key;
    let set = kincal::controller::device::traced_parameter_set(&model, 2, "lab-arm-A", &key, &trace).unwrap();
    link.upload(&set).unwrap();
    drop(link);
    let (info_a, warning) = ok(&dir, &["info", "--port", &port_a]);
    assert!(
        warning.contains("warning: the calibration stored on arm lab-arm-A (parameters version 2")
            && warning.contains("(35 days ago)")
            && warning.contains("kincal check"),
        "{warning}"
    );
    assert!(info_a.contains("EXPIRED 35 days ago"), "{info_a}");

    // `kincal check` on A: posed from A's geometry it holds, after a knock it does not.
    let artefact = "armA/artefact.json";
    let check = |name: &str, knock: &[&str]| {
        let script = format!("{name}.json");
        let mut args = vec![
            "emulated-arm",
            "script",
            "--geometry",
            "armA/truth.toml",
            "--artefact",
            artefact,
            "--placement",
            "V_A",
            "--out",
            &script,
        ];
        args.extend(knock);
        ok(&dir, &args);
        kincal(
            &dir,
            &[
                "check",
                "--port",
                &port_a,
                "--artefact",
                artefact,
                "--placement",
                "V_A",
                "--out",
                name,
                "--script",
                &script,
                "--window-ticks",
                "96",
            ],
        )
    };
    let (code, out, err) = check("same", &[]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(err.contains("expired"), "the warning at connect: {err}");
    assert!(out.contains("HOLDS: distance RMS") && out.contains("expected from repeatability"), "{out}");
    assert!(out.contains(&format!("RUN        sha256:{run_hash}")), "{out}");
    let result: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("same/check.json")).unwrap()).unwrap();
    assert_eq!(result["verdict"], "holds");
    assert_eq!(result["run_sha256"].as_str(), Some(run_hash.as_str()));
    assert_eq!(
        (result["param_version"].as_u64(), result["arm"]["id"].as_str()),
        (Some(2), Some("lab-arm-A"))
    );
    let (measured, expected) =
        (result["measured_rms_mm"].as_f64().unwrap(), result["expected_rms_mm"].as_f64().unwrap());
    assert!(measured > 0.05 && measured < 1.5 * expected, "{measured} mm against {expected} mm");
    println!("unchanged: {}", out.lines().last().unwrap_or(""));
    let (code, out, err) = check("knocked", &["--knock", "offset:2=+0.05"]);
    assert_eq!(code, Some(2), "{out}\n{err}");
    assert!(out.contains("DOES NOT HOLD: distance RMS") && out.contains("calibrate it again"), "{out}");
    println!("knocked:   {}", out.lines().last().unwrap_or(""));
    // The check's touches are arm A's.
    let same = dir.join("same/V_A.json");
    let arm = kincal::data::session_arm(&same).unwrap().expect("the check's session names its arm");
    assert_eq!((arm.id.as_str(), arm.board.as_deref()), ("lab-arm-A", Some("mps2-an386 (emulated)")));
    std::fs::remove_dir_all(&dir).ok();
}

/// Tracker sessions naming their arm (`# arm: ID`): two arms in one calibration are refused
/// before anything is fitted, both files and arms named; so are an artefact session of one arm
/// with a tracker session of another.
#[test]
fn tracker_sessions_of_two_arms_are_refused() {
    let dir = std::env::temp_dir().join(format!("kincal-arm-identity-tracker-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    for sub in ["cal", "val", "mixed"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    let session = |arm: &str, shift: f64| {
        let mut text = format!("# kincal-tracker/1\n# arm: {arm}\npose,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm\n");
        for k in 0..8 {
            let q = 10.0 * k as f64;
            text.push_str(&format!(
                "{k},{q},{},{},0,{q},5,{},{},{}\n",
                20.0 + q,
                150.0 - q,
                400.0 + 30.0 * k as f64 + shift,
                50.0 * (k % 3) as f64,
                300.0 - 10.0 * k as f64
            ));
        }
        text
    };
    std::fs::write(dir.join("cal/a1.csv"), session("lab-arm-A", 0.0)).unwrap();
    std::fs::write(dir.join("cal/b1.csv"), session("lab-arm-B", 1.0)).unwrap();
    std::fs::write(dir.join("val/a2.csv"), session("lab-arm-A", 2.0)).unwrap();
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/suta/model.toml");
    let (code, _, err) = kincal(
        &dir,
        &[
            "calibrate",
            "--model",
            example.to_str().unwrap(),
            "--data",
            "cal",
            "--validate",
            "val",
            "--out",
            "run",
        ],
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("cal/a1.csv was recorded on arm lab-arm-A")
            && err.contains("cal/b1.csv on arm lab-arm-B"),
        "{err}"
    );
    // An artefact session recorded on B beside a tracker session of A.
    ok(&dir, &["simulate", "--model", example.to_str().unwrap(), "--out", "sim", "--seed", "2"]);
    let mut c_a: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("sim/cal/C_A.json")).unwrap()).unwrap();
    c_a["arm"] = serde_json::json!({"id": "lab-arm-B"});
    std::fs::write(dir.join("mixed/C_A.json"), c_a.to_string()).unwrap();
    std::fs::copy(dir.join("cal/a1.csv"), dir.join("mixed/a1.csv")).unwrap();
    let (code, _, err) = kincal(
        &dir,
        &[
            "calibrate",
            "--model",
            example.to_str().unwrap(),
            "--artefact",
            "sim/artefact.json",
            "--data",
            "mixed",
            "--validate",
            "val",
            "--out",
            "run",
        ],
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("lab-arm-A") && err.contains("lab-arm-B") && err.contains("mixed/"), "{err}");
    assert!(!dir.join("run").exists(), "nothing written");
    std::fs::remove_dir_all(&dir).ok();
}
