//! Host ↔ controller logic against the in-process fake controller (the firmware's own state
//! machine on the host): fast, no QEMU.

use kincal::controller::link::{Link, LinkError};
use kincal::data::{Artefact, Session};
use kincal_e2e::{kincal_bin, FakeController};
use kincal_protocol::messages::{Request, PARAM_CHUNK, PROTOCOL_VERSION, SCHEMA_HASH};
use kincal_protocol::params::BLOB_CRC;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-host-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn artefact_file(dir: &Path) -> (Artefact, PathBuf) {
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
    let artefact = kincal::simulate::suta_artefact(&mut rng);
    let path = dir.join("artefact.json");
    artefact.save(&path).unwrap();
    (artefact, path)
}

fn script(dir: &Path, artefact: &Artefact) -> PathBuf {
    let steps: Vec<serde_json::Value> = artefact.landmarks.iter().enumerate().map(|(k, l)| serde_json::json!({"landmark": l.id, "repeat": 1, "pose_counts": [k * 1000, 2000, 3000, 4000, 5000, 6000]})).collect();
    let path = dir.join("script.json");
    std::fs::write(&path, serde_json::json!({ "steps": steps }).to_string()).unwrap();
    path
}

fn measured(path: &Path, artefact: &Artefact) -> Vec<(String, u32)> {
    Session::load(path, artefact)
        .map(|s| s.measurements.into_iter().map(|m| (m.landmark, m.repeat)).collect())
        .unwrap_or_default()
}

#[test]
fn a_killed_record_resumes_without_losing_or_repeating_landmarks() {
    let fake = FakeController::start(2);
    let dir = scratch("record");
    let (artefact, artefact_path) = artefact_file(&dir);
    let script = script(&dir, &artefact);
    let out = dir.join("sessions");
    let session = out.join("C_A.json");
    let args = |window: &str| -> Vec<String> {
        [
            "record",
            "--port",
            &fake.port,
            "--artefact",
            artefact_path.to_str().unwrap(),
            "--placement",
            "C_A",
            "--out",
            out.to_str().unwrap(),
            "--repeats",
            "1",
            "--window-ticks",
            window,
            "--script",
            script.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect()
    };
    // Kill the recorder once a few landmarks are on disk.
    let mut child = Command::new(kincal_bin()).args(args("384")).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    while measured(&session, &artefact).len() < 4 {
        assert!(Instant::now() < deadline, "recording made no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    let _ = child.wait();
    let before = measured(&session, &artefact);
    assert!(before.len() >= 4 && before.len() < 15, "{} measured before the kill", before.len());
    let out = Command::new(kincal_bin()).args(args("96")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let after = measured(&session, &artefact);
    assert_eq!(&after[..before.len()], &before[..], "what was measured stays as it was");
    let mut unique = after.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(unique.len(), 15, "every landmark once: {after:?}");
    assert_eq!(after.len(), 15, "no landmark measured twice");
    assert!(String::from_utf8_lossy(&out.stdout).contains(&format!("{} resumed", before.len())));
    // The poses came through: landmark k was measured at k·1000 counts on joint 1.
    let s = Session::load(&session, &artefact).unwrap();
    for m in &s.measurements {
        let k = artefact.index_of(&m.landmark).unwrap() as f64;
        assert!((m.joints_deg[0] - k * 1000.0 * 360.0 / 4_194_304.0).abs() < 1e-6, "{m:?}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_interrupted_upload_keeps_the_old_parameters_and_a_retry_succeeds() {
    let fake = FakeController::start(1);
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    let old = kincal::controller::device::parameter_blob(&kincal::model::ArmModel::suta_nominal(), 1);
    link.upload(&old).unwrap();
    let mut new_model = kincal::model::ArmModel::suta_nominal();
    new_model.joints[2].d_mm += 1.5;
    let new = kincal::controller::device::parameter_blob(&new_model, 2);
    link.command(Request::ParamBegin { len: new.len() as u16, crc: BLOB_CRC.checksum(&new) }, "begin")
        .unwrap();
    for (k, chunk) in new.chunks(PARAM_CHUNK).take(3).enumerate() {
        link.command(
            Request::ParamChunk {
                offset: (k * PARAM_CHUNK) as u16,
                data: heapless::Vec::from_slice(chunk).unwrap(),
            },
            "chunk",
        )
        .unwrap();
    }
    drop(link); // the connection closes halfway through the upload
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    assert_eq!(link.info().unwrap().param_version, 1, "the old parameters stay active");
    assert_eq!(link.read_params(false, 4096).unwrap(), old);
    assert!(
        matches!(link.command(Request::ParamCommit, "commit"), Err(LinkError::Refused(_, _))),
        "a half upload cannot be committed"
    );
    link.upload(&new).unwrap();
    assert_eq!(link.info().unwrap().param_version, 2);
    assert_eq!(link.read_params(false, 4096).unwrap(), new);
}

#[test]
fn a_version_mismatch_is_reported_with_both_versions() {
    let fake = FakeController::start(1);
    let mut link = Link::open(&fake.port).unwrap();
    let err = link.hello_as(PROTOCOL_VERSION + 3, SCHEMA_HASH ^ 1).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("protocol mismatch")
            && text.contains(&format!("version {}", PROTOCOL_VERSION + 3))
            && text.contains(&format!("controller version {PROTOCOL_VERSION}")),
        "{text}"
    );
}

#[test]
fn info_params_and_upload_commands_work_through_the_cli() {
    let fake = FakeController::start(1);
    let dir = scratch("cli");
    let model = dir.join("model.toml");
    kincal::model::ArmModel::suta_nominal().save(&model).unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(kincal_bin()).args(args).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    assert!(run(&["info", "--port", &fake.port]).contains("parameters none stored"));
    let up = run(&["upload", "--port", &fake.port, model.to_str().unwrap(), "--version", "5"]);
    assert!(up.contains("parameters version 5"), "{up}");
    let info = run(&["info", "--port", &fake.port]);
    assert!(info.contains("version 5") && info.contains("matches this host"), "{info}");
    assert!(run(&["params", "--port", &fake.port]).contains("\"version\": 5"));
    let stream = run(&[
        "stream",
        "--port",
        &fake.port,
        "--raw",
        "--seconds",
        "1",
        "--csv",
        dir.join("raw.csv").to_str().unwrap(),
    ]);
    assert!(stream.contains("0 lost, 0 corrupt"), "{stream}");
    let rows = std::fs::read_to_string(dir.join("raw.csv")).unwrap().lines().count();
    assert!(rows > 500, "{rows} CSV rows for one second at 768 Hz");
    // A port that is not there is reported, not panicked on.
    let out = Command::new(kincal_bin()).args(["info", "--port", "tcp:127.0.0.1:1"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot open tcp:127.0.0.1:1"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_controller_that_disappears_mid_stream_is_reported() {
    let fake = FakeController::start(1);
    let child = Command::new(kincal_bin())
        .args(["stream", "--port", &fake.port, "--raw", "--seconds", "30"])
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    drop(fake); // the port goes away
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("closed the link"), "{stderr}");
}
