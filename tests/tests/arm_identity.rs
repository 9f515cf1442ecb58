//! A calibration that belongs to its arm (issue 32), on the emulator started as two arms: two
//! QEMU controllers with their own identities, posed from their own geometries.
//!
//! * a model calibrated on arm A is refused on arm B, both named, and B keeps what it holds;
//! * on A the stored set shows the RUN's hash (the one `sha256sum` gives) and its date;
//! * a set whose validity has passed is warned about at every connect;
//! * `kincal check` through the record path says "holds" on A's own geometry and "does not hold"
//!   after a knock, with the figures, and writes its session naming arm A;
//! * sessions recorded on A and on B are not one arm's.

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

#[test]
fn a_calibration_belongs_to_its_arm_on_the_emulator_started_as_two_arms() {
    let dir = scratch();
    let elf = emulated_firmware();
    let (_a, port_a) = Emulator::start_server_as(&elf, Some("lab-arm-A")).expect("QEMU starts as arm A");
    let (_b, port_b) = Emulator::start_server_as(&elf, Some("lab-arm-B")).expect("QEMU starts as arm B");
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/suta/model.toml");
    let example = example.to_str().unwrap();
    // Arm A's geometry and data, its RUN; the RUN's model names arm A (what calibrate records
    // from sessions that name it).
    ok(&dir, &["simulate", "--model", example, "--out", "armA", "--seed", "1"]);
    ok(
        &dir,
        &[
            "calibrate",
            "--model",
            example,
            "--artefact",
            "armA/artefact.json",
            "--data",
            "armA/cal",
            "--validate",
            "armA/val",
            "--out",
            "run",
            "--restarts",
            "1",
        ],
    );
    let mut model = kincal::model::ArmModel::load(&dir.join("run/model.toml")).unwrap();
    model.arm = Some(kincal::trace::ArmIdentity::of("lab-arm-A"));
    model.save(&dir.join("run/model.toml")).unwrap();
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
    let (info_a, _) = ok(&dir, &["info", "--port", &port_a]);
    let validated = std::fs::metadata(dir.join("run/summary.json")).unwrap().modified().unwrap();
    let validated = validated.duration_since(std::time::UNIX_EPOCH).unwrap().as_secs();
    let date = kincal::controller::signing::utc(validated);
    assert!(info_a.contains(&format!("RUN        sha256:{run_hash}")), "{info_a}");
    assert!(info_a.contains(&format!("validated  {date}")), "{info_a}");
    assert!(info_a.contains("(364 days left)") || info_a.contains("(365 days left)"), "{info_a}");
    let (_, params_err) = ok(&dir, &["params", "--port", &port_a]);
    assert!(params_err.contains(&run_hash) && params_err.contains("signature valid"), "{params_err}");

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
    // The check's touches are arm A's; a session recorded on B is another arm's.
    let same = dir.join("same/V_A.json");
    let arm = kincal::data::session_arm(&same).unwrap().expect("the check's session names its arm");
    assert_eq!((arm.id.as_str(), arm.board.as_deref()), ("lab-arm-A", Some("mps2-an386 (emulated)")));
    ok(
        &dir,
        &[
            "record",
            "--port",
            &port_b,
            "--artefact",
            artefact,
            "--placement",
            "V_A",
            "--out",
            "b",
            "--script",
            "same.json",
            "--repeats",
            "1",
            "--order",
            "O,M1,M2",
            "--window-ticks",
            "96",
        ],
    );
    let sessions: Vec<_> = [same, dir.join("b/V_A.json")]
        .into_iter()
        .map(|p| {
            let arm = kincal::data::session_arm(&p).unwrap();
            (p, arm)
        })
        .collect();
    let mixed = kincal::trace::one_arm(&sessions).unwrap_err().to_string();
    assert!(
        mixed.contains("lab-arm-A") && mixed.contains("lab-arm-B") && mixed.contains("b/V_A.json"),
        "{mixed}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
