//! Host ↔ controller logic against the in-process fake controller (the firmware's own state
//! machine on the host): fast, no QEMU.

use kincal::controller::link::{Link, LinkError};
use kincal::data::{Artefact, Session};
use kincal_e2e::{kincal_bin, FakeController, Fault};
use kincal_protocol::messages::{
    Hello, ParamBegin, ParamChunk, ParamCommit, SimFaults, PARAM_CHUNK, PROTOCOL_VERSION, SCHEMA_HASH,
};
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

/// The nominal model as calibrated on the fake controller's arm (it names that arm).
fn model_of_the_fake_arm() -> kincal::model::ArmModel {
    let mut model = kincal::model::ArmModel::suta_nominal();
    model.arm = Some(kincal::trace::ArmIdentity::of("emulated-arm"));
    model
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
    let (artefact_arg, out_arg, script_arg) =
        (artefact_path.to_str().unwrap(), out.to_str().unwrap(), script.to_str().unwrap());
    let args = |window: &'static str| {
        let mut args = record_args(&fake.port, artefact_arg, out_arg, window);
        args.extend(["--script", script_arg]);
        args
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
    // The session names the arm it was recorded on; touches of another arm are never added.
    let arm = kincal::data::session_arm(&session).unwrap().expect("the session names its arm");
    assert_eq!(
        (arm.id.as_str(), arm.firmware.as_deref(), arm.board.as_deref()),
        ("emulated-arm", Some("kincal-fw fake"), Some("host (fake)"))
    );
    let text = std::fs::read_to_string(&session).unwrap();
    std::fs::write(&session, text.replace("\"emulated-arm\"", "\"lab-arm-7\"")).unwrap();
    let out = Command::new(kincal_bin()).args(args("96")).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("C_A.json: recorded on lab-arm-7") && err.contains("is emulated-arm"), "{err}");
    std::fs::write(&session, text.replace("\"arm\"", "\"arm_before\"")).unwrap();
    let out = Command::new(kincal_bin()).args(args("96")).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("names no arm") && err.contains("another --out"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_interrupted_upload_keeps_the_old_parameters_and_a_retry_succeeds() {
    let fake = FakeController::start(1);
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    let old = kincal_e2e::signed_set(&kincal::model::ArmModel::suta_nominal(), 1);
    link.upload(&old).unwrap();
    let mut new_model = kincal::model::ArmModel::suta_nominal();
    new_model.joints[2].d_mm += 1.5;
    let new = kincal_e2e::signed_set(&new_model, 2);
    link.call(ParamBegin { len: new.len() as u16, crc: BLOB_CRC.checksum(&new) }).unwrap();
    for (k, chunk) in new.chunks(PARAM_CHUNK).take(3).enumerate() {
        link.call(ParamChunk {
            offset: (k * PARAM_CHUNK) as u16,
            data: heapless::Vec::from_slice(chunk).unwrap(),
        })
        .unwrap();
    }
    drop(link); // the connection closes halfway through the upload
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    assert_eq!(link.info().unwrap().param_version, 1, "the old parameters stay active");
    assert_eq!(link.read_params(false, 4096).unwrap(), old);
    assert!(
        matches!(link.call(ParamCommit), Err(LinkError::Refused(_, _))),
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
    let key_file = kincal_e2e::station_key_file(&dir);
    let key = key_file.to_str().unwrap();
    let model = dir.join("model.toml");
    model_of_the_fake_arm().save(&model).unwrap();
    let run = |args: &[&str]| {
        let out = Command::new(kincal_bin()).args(args).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    assert!(run(&["info", "--port", &fake.port]).contains("parameters none stored"));
    let model_arg = model.to_str().unwrap();
    let without_key =
        Command::new(kincal_bin()).args(["upload", "--port", &fake.port, model_arg]).output().unwrap();
    assert!(!without_key.status.success());
    let refusal = String::from_utf8_lossy(&without_key.stderr);
    assert!(refusal.contains("only signed parameter sets: pass --key"), "{refusal}");
    let up = run(&["upload", "--key", key, "--port", &fake.port, model_arg, "--version", "5"]);
    assert!(up.contains("parameters version 5"), "{up}");
    let fingerprint = kincal::controller::signing::fingerprint(
        &kincal::controller::signing::StationKey::load(&key_file).unwrap().key.public_key(),
    );
    assert!(up.contains(&fingerprint), "{up}");
    let info = run(&["info", "--port", &fake.port]);
    assert!(info.contains("version 5") && info.contains("matches this host"), "{info}");
    assert!(
        info.contains(&format!("signed by  {fingerprint}")) && info.contains("arm        emulated-arm"),
        "{info}"
    );
    let params = Command::new(kincal_bin()).args(["params", "--port", &fake.port]).output().unwrap();
    assert!(String::from_utf8_lossy(&params.stdout).contains("\"version\": 5"));
    let provenance = String::from_utf8_lossy(&params.stderr);
    assert!(provenance.contains(&fingerprint) && provenance.contains("signature valid"), "{provenance}");
    // Older values go back only as a newer version: --version 4 is refused, no --version is 6.
    let (code, _, err) = kincal(&["upload", "--key", key, "--port", &fake.port, model_arg, "--version", "4"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("would be a rollback") && err.contains("--version 6"), "{err}");
    assert!(run(&["upload", "--key", key, "--port", &fake.port, model_arg])
        .contains("now holds parameters version 6"));
    // A model that names no arm goes only where its arm is named, and only to that arm.
    let unnamed = dir.join("nominal.toml");
    kincal::model::ArmModel::suta_nominal().save(&unnamed).unwrap();
    let unnamed = unnamed.to_str().unwrap();
    let (code, _, err) = kincal(&["upload", "--key", key, "--port", &fake.port, unnamed]);
    assert_eq!(code, Some(1));
    assert!(err.contains("nominal.toml names no arm") && err.contains("--for-arm"), "{err}");
    let (code, _, err) =
        kincal(&["upload", "--key", key, "--port", &fake.port, unnamed, "--for-arm", "arm-B"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("--for-arm arm-B") && err.contains("controller is arm emulated-arm"), "{err}");
    let named = run(&["upload", "--key", key, "--port", &fake.port, unnamed, "--for-arm", "emulated-arm"]);
    assert!(named.contains("now holds parameters version 7") && named.contains("not from a RUN"), "{named}");
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
    assert!(!dir.join(".raw.csv.partial").exists(), "the temporary name is gone");
    // A second stream to the same file is refused before connecting; the recording is untouched.
    let before = std::fs::read(dir.join("raw.csv")).unwrap();
    let csv = dir.join("raw.csv");
    let (code, _, err) =
        kincal(&["stream", "--port", &fake.port, "--raw", "--seconds", "1", "--csv", csv.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("raw.csv exists") && err.contains("never replaces"), "{err}");
    assert_eq!(std::fs::read(dir.join("raw.csv")).unwrap(), before);
    // A port that is not there is reported, not panicked on.
    let out = Command::new(kincal_bin()).args(["info", "--port", "tcp:127.0.0.1:1"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot open tcp:127.0.0.1:1"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_controller_that_disappears_mid_stream_is_reported_and_the_recording_kept() {
    let fake = FakeController::start(1);
    let dir = scratch("gone");
    let csv = dir.join("stream.csv");
    let child = Command::new(kincal_bin())
        .args(["stream", "--port", &fake.port, "--raw", "--seconds", "30", "--csv", csv.to_str().unwrap()])
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
    let rows = std::fs::read_to_string(&csv).map(|t| t.lines().count()).unwrap_or(0);
    assert!(rows > 100, "{rows} rows kept of about 1.5 s of stream");
    std::fs::remove_dir_all(&dir).ok();
}

/// The CLI's exit code, stdout and stderr.
fn kincal(args: &[&str]) -> (Option<i32>, String, String) {
    let out = Command::new(kincal_bin()).args(args).output().unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).to_string(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

/// A fake controller, a scratch folder `name`, a station key file and the nominal model file.
fn upload_fixture(name: &str) -> (FakeController, PathBuf, String, String) {
    let dir = scratch(name);
    let key = kincal_e2e::station_key_file(&dir).to_str().unwrap().to_string();
    let model = dir.join("model.toml");
    model_of_the_fake_arm().save(&model).unwrap();
    (FakeController::start(1), dir.clone(), key, model.to_str().unwrap().to_string())
}

#[test]
fn a_lost_commit_reply_is_reported_as_what_the_controller_holds() {
    let (fake, dir, key, model) = upload_fixture("commit");
    let (key, model) = (key.as_str(), model.as_str());
    let (code, out, err) = kincal(&["upload", "--key", key, "--port", &fake.port, model, "--version", "10"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("now holds parameters version 10"), "{out}");
    let commit = |r: &kincal_protocol::messages::Request| {
        matches!(r, kincal_protocol::messages::Request::ParamCommit(_))
    };
    // The commit happens but every answer to it is lost (the first and the repeat): the host
    // asks what the controller holds, and reports the new set.
    fake.fault_next(commit, Fault::LoseReply, 2);
    let (code, out, err) = kincal(&["upload", "--key", key, "--port", &fake.port, model, "--version", "77"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(err.contains("first commit request went unanswered"), "{err}");
    assert!(
        out.contains("now holds parameters version 77") && out.contains("previously parameters version 10")
    );
    // The commit request is lost, and its repeat too: the host asks, and reports the set still
    // held.
    fake.fault_next(commit, Fault::LoseRequest, 2);
    let (code, _, err) = kincal(&["upload", "--key", key, "--port", &fake.port, model, "--version", "78"]);
    assert_eq!(code, Some(1));
    assert!(
        err.contains("not confirmed") && err.contains("the controller holds parameters version 77"),
        "{err}"
    );
    assert!(!err.contains("version 78") && !err.contains("keeps"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn version_0_and_absurd_sets_are_refused_by_the_host_and_by_the_controller() {
    let fake = FakeController::start(1);
    let dir = scratch("envelope");
    let key_file = kincal_e2e::station_key_file(&dir);
    let key = key_file.to_str().unwrap();
    let path = dir.join("model.toml");
    let mut far = model_of_the_fake_arm();
    // Plausible for a model file (≤ 5000 mm), outside what the controller accepts (±2000 mm).
    far.joints[2].a_mm = 3e3;
    far.save(&path).unwrap();
    let (code, _, err) =
        kincal(&["upload", "--key", key, "--port", &fake.port, path.to_str().unwrap(), "--version", "3"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("joint 3 a_mm = 3e3 is outside the envelope ±2000"), "{err}");
    // Absurd already as a model file: refused when it is read, before any upload.
    far.joints[2].a_mm = 1e6;
    far.save(&path).unwrap();
    let (code, _, err) =
        kincal(&["upload", "--key", key, "--port", &fake.port, path.to_str().unwrap(), "--version", "3"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("link_offset:3") && err.contains("beyond any plausible arm"), "{err}");
    model_of_the_fake_arm().save(&path).unwrap();
    let (code, _, err) =
        kincal(&["upload", "--key", key, "--port", &fake.port, path.to_str().unwrap(), "--version", "0"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("version 0 is reserved"), "{err}");
    // Sent raw, past the host's check: the controller refuses with the reason.
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    let mut params = kincal::controller::device::device_params(&kincal::model::ArmModel::suta_nominal(), 0)
        .expect("six joints");
    let mut blob = [0u8; kincal_protocol::params::MAX_PARAM_BLOB];
    let n = kincal_protocol::params::encode_blob(&params, &mut blob).unwrap();
    let e = link.upload(&kincal_e2e::sign_blob(&blob[..n])).unwrap_err();
    assert!(e.to_string().contains("version 0 is reserved"), "{e}");
    params.version = 4;
    params.scale_ppm = 1e12;
    let n = kincal_protocol::params::encode_blob(&params, &mut blob).unwrap();
    let e = link.upload(&kincal_e2e::sign_blob(&blob[..n])).unwrap_err();
    assert!(e.to_string().contains("scale_ppm = 1e12 is outside the envelope ±1000"), "{e}");
    assert_eq!(link.info().unwrap().param_version, 0, "nothing was stored");
    assert!(link.read_params(false, 4096).unwrap().is_empty(), "`params` agrees with `info`");
    std::fs::remove_dir_all(&dir).ok();
}

fn record_args<'a>(port: &'a str, artefact: &'a str, out: &'a str, window: &'a str) -> Vec<&'a str> {
    vec![
        "record",
        "--port",
        port,
        "--artefact",
        artefact,
        "--placement",
        "C_A",
        "--out",
        out,
        "--repeats",
        "1",
        "--window-ticks",
        window,
    ]
}

fn set_dropouts(port: &str, dropouts_per_10k: u16) {
    let mut link = Link::open(port).unwrap();
    link.hello().unwrap();
    link.call(SimFaults { dropouts_per_10k, ..SimFaults::default() }).unwrap();
}

#[test]
fn a_window_with_every_frame_dropped_is_refused_and_never_written() {
    let fake = FakeController::start(2);
    let dir = scratch("dropped");
    let (artefact, artefact_path) = artefact_file(&dir);
    let script = script(&dir, &artefact);
    let out = dir.join("sessions");
    set_dropouts(&fake.port, 10_000);
    let mut args = record_args(&fake.port, artefact_path.to_str().unwrap(), out.to_str().unwrap(), "96");
    args.extend(["--script", script.to_str().unwrap()]);
    let (code, _, err) = kincal(&args);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("window refused") && err.contains("joint 1 accepted 0 of 96 samples"), "{err}");
    assert!(measured(&out.join("C_A.json"), &artefact).is_empty(), "no touch is written");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn end_of_input_at_a_retake_question_ends_the_interactive_record() {
    let fake = FakeController::start(2);
    let dir = scratch("eof");
    let (artefact, artefact_path) = artefact_file(&dir);
    let out = dir.join("sessions");
    // 5 % dropouts: usable, but flagged, so the operator is asked about a re-take.
    set_dropouts(&fake.port, 500);
    let args = record_args(&fake.port, artefact_path.to_str().unwrap(), out.to_str().unwrap(), "96");
    let mut child = Command::new(kincal_bin())
        .args(&args)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    {
        use std::io::Write;
        let mut stdin = child.stdin.take().unwrap();
        stdin.write_all(b"\n").unwrap(); // Enter at the first landmark, then end of input
    }
    let deadline = Instant::now() + Duration::from_secs(20);
    while child.try_wait().unwrap().is_none() {
        if Instant::now() > deadline {
            child.kill().unwrap();
            panic!("record kept running after the end of input");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let output = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{err}");
    assert!(err.contains("take it again") && err.contains("stopped; 0 measurements are saved"), "{err}");
    assert!(measured(&out.join("C_A.json"), &artefact).is_empty());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn sixteen_tick_windows_record_reliably_over_tcp() {
    let fake = FakeController::start(1);
    let dir = scratch("short");
    let (artefact, artefact_path) = artefact_file(&dir);
    let script = script(&dir, &artefact);
    let out = dir.join("sessions");
    for _ in 0..3 {
        std::fs::remove_dir_all(&out).ok();
        let mut args = record_args(&fake.port, artefact_path.to_str().unwrap(), out.to_str().unwrap(), "16");
        args.extend(["--script", script.to_str().unwrap()]);
        let (code, stdout, err) = kincal(&args);
        assert_eq!(code, Some(0), "{err}");
        assert!(stdout.contains("15 measured now"), "{stdout}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_first_request_after_line_noise_is_answered() {
    use std::io::Write;
    let fake = FakeController::start(1);
    let mut stream = std::net::TcpStream::connect(fake.port.strip_prefix("tcp:").unwrap()).unwrap();
    // Noise with no delimiter: without one at the start of the request, the request would be
    // glued to it and lost.
    stream.write_all(&[0x55, 0x12, 0xA7, 0x3C, 0x01]).unwrap();
    let mut link = Link::over(Box::new(stream));
    // One attempt, no retry.
    let answer =
        link.call_within(Hello { version: PROTOCOL_VERSION, schema: SCHEMA_HASH }, Duration::from_secs(1));
    assert!(answer.is_ok(), "{answer:?}");
}

#[test]
fn the_emulated_arm_is_posed_and_faulted_from_the_cli() {
    let fake = FakeController::start(2);
    let (code, out, err) =
        kincal(&["emulated-arm", "pose", "--port", &fake.port, "--deg", "10,20,30,40,350.5,0"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("350.5000") && out.contains("96/96"), "{out}");
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    let w = kincal::controller::record::measure_window(&mut link, 32).unwrap();
    let deg: Vec<f64> =
        w.joints.iter().map(|j| kincal_protocol::biss::counts_to_deg(j.mean_counts)).collect();
    for (got, want) in deg.iter().zip([10.0, 20.0, 30.0, 40.0, 350.5, 0.0]) {
        assert!((got - want).abs() < 1e-4, "{deg:?}");
    }
    drop(link);
    let (code, out, err) =
        kincal(&["emulated-arm", "faults", "--port", &fake.port, "--dropouts-per-10k", "10000"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("10000 dropouts"), "{out}");
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    let w = kincal::controller::record::measure_window(&mut link, 32).unwrap();
    assert!(w.joints.iter().all(|j| j.accepted == 0), "{w:?}");
    drop(link);
    // Joints 2 and 5 unplugged (every other fault off again): only they answer no more.
    let (code, out, err) = kincal(&["emulated-arm", "faults", "--port", &fake.port, "--unplug", "2,5"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("unplugged joints: 2, 5"), "{out}");
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    let w = kincal::controller::record::measure_window(&mut link, 32).unwrap();
    let accepted: Vec<u16> = w.joints.iter().map(|j| j.accepted).collect();
    assert_eq!(accepted, [32, 0, 32, 32, 0, 32], "{w:?}");
    drop(link);
    let (code, _, err) = kincal(&["emulated-arm", "faults", "--port", &fake.port, "--unplug", "7"]);
    assert_eq!(code, Some(2), "joint 7 does not exist: {err}");
    let (_, info, _) = kincal(&["info", "--port", &fake.port]);
    assert!(info.contains("reset      power-on"), "{info}");
    let (code, out, err) = kincal(&["emulated-arm", "faults", "--port", &fake.port, "--crash", "hang"]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.contains("failure injected"), "{out}");
    let (_, info, _) = kincal(&["info", "--port", &fake.port]);
    assert!(info.contains("reset      WATCHDOG: the sampling loop stopped"), "{info}");
    let (code, _, err) = kincal(&["emulated-arm", "pose", "--port", &fake.port, "--counts", "1,2,3"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("--counts: expected 6 positions"), "{err}");
}

#[test]
fn lost_answers_are_repeated_without_doing_anything_twice() {
    let fake = FakeController::start(1);
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    // The answer to one chunk is lost: the chunk is sent again with its sequence number and the
    // controller answers without appending it twice (else the read-back or the offset check fails).
    let chunk = |r: &kincal_protocol::messages::Request| {
        matches!(r, kincal_protocol::messages::Request::ParamChunk(_))
    };
    fake.fault_next(chunk, Fault::LoseReply, 1);
    let blob = kincal_e2e::signed_set(&kincal::model::ArmModel::suta_nominal(), 6);
    let done = link.upload(&blob).unwrap();
    assert!(!done.commit_reply_lost);
    assert_eq!(link.read_params(false, 4096).unwrap(), blob);
    // A lost commit answer: the repeat is answered from the controller's memory of it.
    let commit = |r: &kincal_protocol::messages::Request| {
        matches!(r, kincal_protocol::messages::Request::ParamCommit(_))
    };
    fake.fault_next(commit, Fault::LoseReply, 1);
    let blob = kincal_e2e::signed_set(&kincal::model::ArmModel::suta_nominal(), 7);
    assert!(link.upload(&blob).unwrap().commit_reply_lost);
    assert_eq!(link.info().unwrap().param_version, 7);
}

/// A TCP proxy in front of the controller at `upstream` that forwards every frame and cuts the
/// link at the answer to the first `ParamCommit`: right after passing it to the host
/// (`pass_answer`), or instead of passing it. Frames are read with the protocol crate's decoder.
fn cut_at_commit_answer(upstream: &str, pass_answer: bool) -> String {
    use kincal_protocol::framing::Decoder;
    use kincal_protocol::messages::{DeviceFrame, HostFrame, Request};
    use std::io::{Read, Write};
    use std::net::{Shutdown, TcpListener, TcpStream};
    use std::sync::{Arc, Mutex};
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = format!("tcp:{}", listener.local_addr().unwrap());
    let upstream = upstream.strip_prefix("tcp:").unwrap().to_string();
    std::thread::spawn(move || {
        let Ok((host, _)) = listener.accept() else { return };
        let device = TcpStream::connect(&upstream).unwrap();
        let commit: Arc<Mutex<Option<u16>>> = Arc::default();
        let (mut from_host, mut to_device, seen) =
            (host.try_clone().unwrap(), device.try_clone().unwrap(), commit.clone());
        std::thread::spawn(move || {
            let (mut decoder, mut buf) = (Decoder::new(), [0u8; 512]);
            while let Ok(n @ 1..) = from_host.read(&mut buf) {
                for &b in &buf[..n] {
                    if let Some(Ok(HostFrame { seq, request: Request::ParamCommit(_) })) = decoder.push(b) {
                        seen.lock().unwrap().get_or_insert(seq);
                    }
                }
                if to_device.write_all(&buf[..n]).is_err() {
                    break;
                }
            }
        });
        let (mut from_device, mut to_host) = (device.try_clone().unwrap(), host.try_clone().unwrap());
        let (mut decoder, mut frame, mut buf) = (Decoder::new(), Vec::new(), [0u8; 512]);
        while let Ok(n @ 1..) = from_device.read(&mut buf) {
            for &b in &buf[..n] {
                frame.push(b);
                let Some(decoded) = decoder.push::<DeviceFrame>(b) else { continue };
                let answers_commit = matches!(decoded, Ok(DeviceFrame::Response { seq, .. }) if Some(seq) == *commit.lock().unwrap());
                if answers_commit {
                    if pass_answer {
                        let _ = to_host.write_all(&frame);
                    }
                    let _ = host.shutdown(Shutdown::Both);
                    let _ = device.shutdown(Shutdown::Both);
                    return;
                }
                if to_host.write_all(&frame).is_err() {
                    return;
                }
                frame.clear();
            }
        }
    });
    port
}

#[test]
fn a_confirmed_commit_is_success_even_when_the_link_is_cut_right_after_it() {
    let (fake, dir, key, model) = upload_fixture("cut");
    let (key, model) = (key.as_str(), model.as_str());
    let (code, _, err) = kincal(&["upload", "--key", key, "--port", &fake.port, model, "--version", "75"]);
    assert_eq!(code, Some(0), "{err}");
    // The commit's Ack reaches the host, then the link is cut: the follow-up read-back fails.
    let proxy = cut_at_commit_answer(&fake.port, true);
    let (code, out, err) = kincal(&["upload", "--key", key, "--port", &proxy, model, "--version", "76"]);
    assert_eq!(code, Some(0), "committed is exit 0: {err}");
    assert!(out.contains("confirmed the commit of parameters version 76"), "{out}");
    assert!(err.contains("warning") && err.contains("reading back") && err.contains("kincal info"), "{err}");
    let mut link = Link::open(&fake.port).unwrap();
    link.hello().unwrap();
    assert_eq!(link.info().unwrap().param_version, 76, "what the exit status says is stored");
    drop(link);
    // The commit's answer never arrives and the controller cannot be asked: neither 0 nor 1.
    let proxy = cut_at_commit_answer(&fake.port, false);
    let (code, out, err) = kincal(&["upload", "--key", key, "--port", &proxy, model, "--version", "77"]);
    assert_eq!(code, Some(3), "unknown outcome: {out} {err}");
    assert!(err.contains("could not be asked") && !out.contains("uploaded"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_touch_with_the_angles_of_another_landmark_is_warned_about_at_the_touch() {
    let fake = FakeController::start(2);
    let dir = scratch("same-pose");
    let (artefact, artefact_path) = artefact_file(&dir);
    // Landmarks 0 and 1 at one pose (the arm not moved), the third elsewhere.
    let pose = |k: usize| {
        if k < 2 {
            [1000, 2000, 3000, 4000, 5000, 6000]
        } else {
            [9000, 2000, 3000, 4000, 5000, 6000]
        }
    };
    let steps: Vec<serde_json::Value> = artefact.landmarks[..3]
        .iter()
        .enumerate()
        .map(|(k, l)| serde_json::json!({"landmark": l.id, "repeat": 1, "pose_counts": pose(k)}))
        .collect();
    let script = dir.join("script.json");
    std::fs::write(&script, serde_json::json!({ "steps": steps }).to_string()).unwrap();
    let order = artefact.landmarks[..3].iter().map(|l| l.id.as_str()).collect::<Vec<_>>().join(",");
    let out = dir.join("sessions");
    let mut args = record_args(&fake.port, artefact_path.to_str().unwrap(), out.to_str().unwrap(), "96");
    args.extend(["--script", script.to_str().unwrap(), "--order", &order]);
    let (code, _, err) = kincal(&args);
    assert_eq!(code, Some(0), "{err}");
    let (first, second, third) =
        (&artefact.landmarks[0].id, &artefact.landmarks[1].id, &artefact.landmarks[2].id);
    let warning = format!("warning: {second} has the same six angles as {first} (repeat 1)");
    assert!(err.contains(&warning), "{err}");
    assert_eq!(err.matches("same six angles").count(), 1, "only the touch that repeats a pose: {err}");
    assert!(!err.contains(&format!("warning: {third}")), "{err}");
    assert_eq!(measured(&out.join("C_A.json"), &artefact).len(), 3, "a script stores what it measured");
    std::fs::remove_dir_all(&dir).ok();
}

fn faults_unplugging(unplugged: u8) -> kincal_protocol::messages::Request {
    kincal_protocol::messages::Request::SimFaults(SimFaults { unplugged, ..SimFaults::default() })
}

/// A joint unplugged while `kincal stream --pose` runs: the CLI names the joint, never prints a
/// position for those poses, the CSV marks the rows (valid 0, the joint, no position); plugged
/// back, the poses are valid again.
#[test]
fn an_unplugged_joint_mid_stream_is_named_and_marked_and_valid_again_when_plugged_back() {
    let fake = FakeController::start(1);
    let dir = scratch("unplug");
    let model = dir.join("model.toml");
    model_of_the_fake_arm().save(&model).unwrap();
    let key_file = kincal_e2e::station_key_file(&dir);
    let key = key_file.to_str().unwrap();
    let (code, _, err) = kincal(&["upload", "--key", key, "--port", &fake.port, model.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    let csv = dir.join("pose.csv");
    let child = Command::new(kincal_bin())
        .args(["stream", "--port", &fake.port, "--pose", "--seconds", "2.5", "--csv", csv.to_str().unwrap()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(900));
    fake.meddle_arm(faults_unplugging(0b100));
    std::thread::sleep(Duration::from_millis(600));
    fake.meddle_arm(faults_unplugging(0));
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("pose INVALID: joint 3 not read this tick"), "{stdout}");
    assert!(stdout.contains("pose valid again"), "{stdout}");
    assert!(stdout.contains("poses INVALID (joints 3 not read"), "{stdout}");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("seq,tick,valid,stale_joints,stale_ticks,x_mm,y_mm,z_mm,zx,zy,zz,xx,xy,xz,t_s,host_s")
    );
    // valid, stale joints and whether a position is written, row by row; runs of equal rows.
    let mut runs: Vec<(String, String, bool, usize)> = Vec::new();
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        assert_eq!(cells.len(), 16, "{line}");
        let row = (cells[2].to_string(), cells[3].to_string(), !cells[5].is_empty());
        match runs.last_mut() {
            Some(r) if (r.0.as_str(), r.1.as_str(), r.2) == (row.0.as_str(), row.1.as_str(), row.2) => {
                r.3 += 1
            }
            _ => runs.push((row.0, row.1, row.2, 1)),
        }
    }
    let shape: Vec<(&str, &str, bool)> = runs.iter().map(|r| (r.0.as_str(), r.1.as_str(), r.2)).collect();
    assert_eq!(shape, [("1", "", true), ("0", "3", false), ("1", "", true)], "{runs:?}");
    assert!(runs[1].3 > 200, "about 0.6 s of invalid poses at 768 Hz: {runs:?}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A stream that stops is an alarm line on the host, not a silent wait; its return is told.
#[test]
fn a_stalled_stream_raises_an_alarm() {
    let fake = FakeController::start(1);
    let (code, _, err) = kincal(&["stream", "--port", &fake.port, "--pose", "--seconds", "1"]);
    assert_eq!(code, Some(1), "no parameters, no pose stream: {err}");
    assert!(err.contains("holds no parameters"), "{err}");
    let child = Command::new(kincal_bin())
        .args(["stream", "--port", &fake.port, "--raw", "--seconds", "1.5"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(700));
    fake.stall(Duration::from_millis(300));
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{stdout}");
    assert!(stdout.contains("ALARM: no stream frame for over 16 ticks"), "{stdout}");
    assert!(stdout.contains("stream resumed after"), "{stdout}");
}
