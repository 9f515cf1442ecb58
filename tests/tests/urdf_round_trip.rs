//! Must show, URDF round trip: a URDF of the generator's nominal 7R arm → `kincal model
//! from-urdf` → calibration on tracker sessions of a URDF-joint true arm (`tracker_gen`, no
//! forward code shared with kincal) → `kincal model to-urdf`; the written URDF's forward
//! kinematics, by the independent Python peer `bench/urdf_fk_peer.py`, equals the calibrated
//! model's to 1 µm, and the held-out RMS is within 1.10 × the generator's true floor.

use kincal::calib::tracker::{calibrate_tracker, validate_session, TrackerOptions};
use kincal::data::tracker::load_dir;
use kincal::model::kinematics::tool_pose;
use kincal::model::urdf::{calibrated_urdf, model_from_urdf};
use kincal_e2e::tracker_gen::{generate, TrackerOptions as GenOptions};
use std::process::Command;

#[test]
fn urdf_to_model_to_calibration_to_urdf_keeps_the_forward_kinematics() {
    let dir = std::env::temp_dir().join(format!("kincal-urdf-round-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut options = GenOptions::iiwa_five_sessions(3);
    options.arm = options.arm.to_urdf_chain();
    let generated = generate(&options);
    let urdf = dir.join("robot.urdf");
    options.arm.write_urdf(&urdf, "iiwa7").unwrap();
    let nominal = model_from_urdf(&urdf, "base_link", "tool0").expect("the URDF reads");
    let all = dir.join("all");
    generated.write(&all).unwrap();
    let (cal_dir, val_dir) = (dir.join("cal"), dir.join("val"));
    std::fs::create_dir_all(&cal_dir).unwrap();
    std::fs::create_dir_all(&val_dir).unwrap();
    for (s, session) in generated.sessions.iter().enumerate() {
        let name = format!("{}.csv", session.plan.name);
        std::fs::rename(all.join(&name), if s < 3 { cal_dir.join(&name) } else { val_dir.join(&name) })
            .unwrap();
    }
    let (cal, val) = (load_dir(&cal_dir).unwrap(), load_dir(&val_dir).unwrap());
    let fit = calibrate_tracker(&nominal, &cal, &TrackerOptions::default()).expect("calibrates");
    let (mut sum, mut n) = (0.0, 0usize);
    for s in &val.sessions {
        let v = validate_session(&fit.model, s, [0.0; 3]);
        sum += v.rms_mm * v.rms_mm * v.points as f64;
        n += v.points;
    }
    let rms = (sum / n as f64).sqrt();
    let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
    println!("held-out {rms:.4} mm, true floor {floor:.4} mm ({:.3}×)", rms / floor);
    assert!(rms <= 1.10 * floor, "held-out {rms} mm vs floor {floor} mm");

    let written = dir.join("calibrated.urdf");
    std::fs::write(&written, calibrated_urdf(&urdf, "base_link", "tool0", &fit.model).unwrap()).unwrap();
    let mut model = fit.model.clone();
    model.tcp_mm = [0.0; 3];
    let peer = concat!(env!("CARGO_MANIFEST_DIR"), "/../bench/urdf_fk_peer.py");
    let mut worst_mm: f64 = 0.0;
    for q in [
        [10.0, -20.0, 30.0, -40.0, 50.0, -60.0, 70.0],
        [0.0; 7],
        [-90.0, 45.0, 5.0, 80.0, -30.0, 20.0, -100.0],
    ] {
        let list: Vec<String> = q.iter().map(|v| v.to_string()).collect();
        let out = Command::new("python3")
            .args([
                peer,
                written.to_str().unwrap(),
                "--base",
                "base_link",
                "--tip",
                "link_7",
                &format!("--q={}", list.join(",")),
            ])
            .output()
            .expect("python3 runs (it is required for this test)");
        assert!(out.status.success(), "peer failed: {}", String::from_utf8_lossy(&out.stderr));
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("peer prints JSON");
        let p: Vec<f64> =
            json["position_mm"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        let mine = tool_pose(&model, &q).position_mm;
        let d = ((p[0] - mine.x).powi(2) + (p[1] - mine.y).powi(2) + (p[2] - mine.z).powi(2)).sqrt();
        worst_mm = worst_mm.max(d);
    }
    println!("written URDF vs calibrated model: {:.3e} mm", worst_mm);
    assert!(worst_mm < 1e-3, "the written URDF is {worst_mm} mm from the calibrated model");
    std::fs::remove_dir_all(&dir).ok();
}
