//! The host ↔ controller loop on the emulated controller (QEMU): record, calibrate, upload,
//! stream; an upload cut off midway; a recording killed midway. QEMU is killed by its guard.

use kincal::controller::demo::{run_loop, LoopOptions};
use kincal::controller::emulator::Emulator;
use kincal::controller::link::Link;
use kincal::data::{Artefact, Session};
use kincal_e2e::emulated_firmware;
use kincal_e2e::kincal_bin;
use kincal_protocol::messages::{ParamBegin, ParamChunk, PARAM_CHUNK};
use kincal_protocol::params::BLOB_CRC;
use std::path::PathBuf;
use std::process::Command;
use std::sync::Mutex;
use std::time::{Duration, Instant};

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn elf() -> PathBuf {
    emulated_firmware()
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-loop-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn the_whole_loop_brings_the_streamed_pose_to_the_noise_floor() {
    let _g = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (_emulator, mut link) = Emulator::start(&elf()).unwrap();
    link.hello().unwrap();
    let dir = scratch("whole");
    let options = LoopOptions {
        seed: 3,
        window_ticks: 16,
        repeats: 2,
        calibration_placements: 5,
        out: dir.clone(),
        ..LoopOptions::default()
    };
    let r =
        run_loop(&mut link, &kincal::model::ArmModel::suta_nominal(), &options, &mut |s| eprintln!("  {s}"))
            .unwrap();
    eprintln!("{r:#?}");
    assert!(r.touches >= 200, "{} touches", r.touches);
    // The hidden compliance of joint 2 shows as a gap, is named, added, and the error falls.
    assert!(
        r.steps[0].validation_rms_mm > 1.5 * r.truth_validation_rms_mm,
        "the hidden effect must show before it is added: {:?} vs floor {}",
        r.steps[0],
        r.truth_validation_rms_mm
    );
    assert_eq!(r.added.first().map(String::as_str), Some("compliance:2"), "{:?}", r.steps);
    assert!(
        r.calibrated_validation_rms_mm <= 1.15 * r.truth_validation_rms_mm,
        "validation {} vs noise floor {}",
        r.calibrated_validation_rms_mm,
        r.truth_validation_rms_mm
    );
    assert!(
        r.nominal_pose_rms_mm > 20.0 * r.calibrated_pose_rms_mm,
        "nominal {} vs calibrated {}",
        r.nominal_pose_rms_mm,
        r.calibrated_pose_rms_mm
    );
    assert!(
        (r.calibrated_pose_rms_mm - r.host_calibrated_pose_rms_mm).abs() < 0.01,
        "controller {} vs host {}",
        r.calibrated_pose_rms_mm,
        r.host_calibrated_pose_rms_mm
    );
    assert!(r.calibrated_pose_rms_mm < 0.15, "calibrated pose error {} mm", r.calibrated_pose_rms_mm);
    assert!(r.floor_pose_rms_mm < 0.01, "floor {}", r.floor_pose_rms_mm);
    assert!(dir.join("run/summary.json").exists() && dir.join("data/cal/A_O.json").exists());
    // The uploaded RUN belongs to the emulated arm: its model names it, the stored set carries
    // its hash and a year's validity (recorded in RUN/uploads.json), and its certificate says
    // calibrated.
    let run = &r.uploaded_run;
    assert_eq!(run, &dir.join("run-added"));
    let model = kincal::model::ArmModel::load(&run.join("model.toml")).unwrap();
    assert_eq!(model.arm.map(|a| a.id), Some("emulated-arm".to_string()));
    let uploads = kincal::trace::read_uploads(run).unwrap();
    let hash = kincal::trace::hex(&kincal::trace::run_sha256(run).unwrap());
    assert_eq!(uploads.len(), 1, "{uploads:?}");
    assert_eq!((uploads[0].arm.id.as_str(), uploads[0].run_sha256.as_str()), ("emulated-arm", hash.as_str()));
    let year = uploads[0].valid_until_unix_s.unwrap() - uploads[0].validated_at_unix_s;
    assert_eq!(year, 365 * 86_400);
    let info = link.info().unwrap();
    assert_eq!(
        info.param_trace.run_sha256,
        kincal::trace::run_sha256(run).unwrap(),
        "the stored set names the RUN"
    );
    let certificate = kincal::api::certificate(run, None, 0).unwrap();
    let reference = certificate.summary.provenance.artefact_certificate.as_deref();
    assert_eq!(
        reference,
        Some("none: simulated by kincal demo, seed 3"),
        "the reference says it is simulated"
    );
    let verdict = certificate.verdict();
    assert_eq!((verdict.class, verdict.headline.as_str()), ("pass", "CALIBRATED"), "{}", verdict.sentence);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_upload_cut_off_midway_keeps_the_old_parameters_and_a_retry_succeeds() {
    let _g = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (_emulator, port) = Emulator::start_server(&elf()).unwrap();
    let mut link = Link::open(&port).unwrap();
    link.hello().unwrap();
    let old = kincal_e2e::signed_set(&kincal::model::ArmModel::suta_nominal(), 1);
    let started = Instant::now();
    link.upload(&old).unwrap();
    eprintln!("upload of {} bytes: {:.0} ms", old.len(), started.elapsed().as_secs_f64() * 1e3);
    let mut model = kincal::model::ArmModel::suta_nominal();
    model.joints[3].offset_deg += 0.4;
    let new = kincal_e2e::signed_set(&model, 2);
    link.call(ParamBegin { len: new.len() as u16, crc: BLOB_CRC.checksum(&new) }).unwrap();
    for (k, chunk) in new.chunks(PARAM_CHUNK).take(4).enumerate() {
        link.call(ParamChunk {
            offset: (k * PARAM_CHUNK) as u16,
            data: heapless::Vec::from_slice(chunk).unwrap(),
        })
        .unwrap();
    }
    drop(link); // the host goes away halfway through
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut link = loop {
        match Link::open(&port).and_then(|mut l| l.hello().map(|_| l)) {
            Ok(l) => break l,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(100)),
            Err(e) => panic!("reconnect: {e}"),
        }
    };
    assert_eq!(link.info().unwrap().param_version, 1, "the old parameters stay active");
    assert_eq!(link.read_params(false, 4096).unwrap(), old);
    link.upload(&new).unwrap();
    assert_eq!(link.info().unwrap().param_version, 2);
    // Round-trip latency of a request.
    let t = Instant::now();
    for _ in 0..50 {
        link.info().unwrap();
    }
    eprintln!("request round trip: {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / 50.0);
}

#[test]
fn a_recording_killed_midway_resumes_on_the_emulated_controller() {
    let _g = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let (_emulator, port) = Emulator::start_server(&elf()).unwrap();
    let dir = scratch("record");
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(2);
    let artefact: Artefact = kincal::simulate::suta_artefact(&mut rng);
    let artefact_path = dir.join("artefact.json");
    artefact.save(&artefact_path).unwrap();
    let steps: Vec<serde_json::Value> = artefact
        .landmarks
        .iter()
        .enumerate()
        .map(|(k, l)| serde_json::json!({"landmark": l.id, "pose_counts": [k * 5000 + 7, 1, 2, 3, 4, 5]}))
        .collect();
    let script = dir.join("script.json");
    std::fs::write(&script, serde_json::json!({ "steps": steps }).to_string()).unwrap();
    let out = dir.join("sessions");
    let session = out.join("V_A.json");
    let args: Vec<String> = [
        "record",
        "--port",
        &port,
        "--artefact",
        artefact_path.to_str().unwrap(),
        "--placement",
        "V_A",
        "--purpose",
        "validation",
        "--out",
        out.to_str().unwrap(),
        "--repeats",
        "1",
        "--window-ticks",
        "192",
        "--script",
        script.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let count = || Session::load(&session, &artefact).map(|s| s.measurements.len()).unwrap_or(0);
    let mut child = Command::new(kincal_bin()).args(&args).spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(60);
    while count() < 3 {
        assert!(Instant::now() < deadline, "no progress");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap();
    let _ = child.wait();
    let before = Session::load(&session, &artefact).unwrap().measurements;
    std::thread::sleep(Duration::from_millis(300));
    let done = Command::new(kincal_bin()).args(&args).output().unwrap();
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    let after = Session::load(&session, &artefact).unwrap().measurements;
    assert_eq!(&after[..before.len()], &before[..]);
    let mut ids: Vec<&str> = after.iter().map(|m| m.landmark.as_str()).collect();
    assert_eq!(ids.len(), 15, "{ids:?}");
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 15, "no landmark twice");
    for m in &after {
        let k = artefact.index_of(&m.landmark).unwrap() as f64;
        assert!((m.joints_deg[0] - (k * 5000.0 + 7.0) * 360.0 / 4_194_304.0).abs() < 1e-3, "{m:?}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
