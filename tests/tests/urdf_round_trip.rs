//! Must show, URDF round trip: a URDF of the generator's nominal 7R arm → `kincal model
//! from-urdf` → calibration on tracker sessions of a URDF-joint true arm (`tracker_gen`, no
//! forward code shared with kincal) → `kincal model to-urdf`; the written URDF's forward
//! kinematics, by the independent Python peer `bench/urdf_fk_peer.py`, equals the calibrated
//! model's to 1 µm, and the held-out RMS is within 1.10 × the generator's true floor. With every
//! origin freed, the directions the data cannot see (what the bases and adjacent origins absorb)
//! do not drift, and moving the nominal along them changes no calibrated figure.

use kincal::calib::fit::{calibrate, Fit};
use kincal::calib::setup::SolveOptions;
use kincal::data::tracker::load_dir;
use kincal::data::Observations;
use kincal::model::kinematics::tool_pose;
use kincal::model::urdf::{calibrated_urdf, model_from_urdf};
use kincal::model::ArmModel;
use kincal_e2e::tracker_gen::{
    axis_angle, generate, rpy_matrix, rpy_of, Mat3, TrackerData as Generated, TrackerOptions as GenOptions,
};
use kincal_e2e::tracker_setup::held_out_rms;
use std::path::PathBuf;
use std::process::Command;

/// The 7R generator arm with URDF joints and hidden errors (`seed`): its nominal URDF in
/// `DIR/robot.urdf`, the model from-urdf makes of it, three sessions to calibrate and two held out.
fn urdf_arm(name: &str, seed: u64) -> (PathBuf, Generated, ArmModel, Observations, Observations) {
    let dir = std::env::temp_dir().join(format!("kincal-urdf-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut options = GenOptions::iiwa_five_sessions(seed);
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
    (dir, generated, nominal, cal, val)
}

#[test]
fn urdf_to_model_to_calibration_to_urdf_keeps_the_forward_kinematics() {
    let (dir, generated, nominal, cal, val) = urdf_arm("round", 3);
    let urdf = dir.join("robot.urdf");
    let fit = calibrate(&nominal, &cal, &SolveOptions::default()).expect("calibrates");
    let rms = held_out_rms(&fit.model, &val);
    let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
    println!("held-out {rms:.4} mm, true floor {floor:.4} mm ({:.3}×)", rms / floor);
    assert!(rms <= 1.10 * floor, "held-out {rms} mm vs floor {floor} mm");

    let written = dir.join("calibrated.urdf");
    let out = calibrated_urdf(&urdf, &fit.model, &dir.join("model.toml"), None, None).unwrap();
    assert!(out.read_back_mm < 1e-6, "kincal's own read-back: {} mm", out.read_back_mm);
    std::fs::write(&written, out.text).unwrap();
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

fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()))
}

/// Every fixed parameter of `fit` sits at its value in `nominal`.
fn fixed_stay_at_nominal(fit: &Fit, nominal: &ArmModel) {
    for name in &fit.identifiability().fixed {
        let e = fit.estimates.iter().find(|e| &e.param == name).expect("an estimate row");
        let id = nominal.free.iter().map(|f| f.id).find(|id| &id.to_string() == name);
        let at = id.map_or(e.nominal, |id| nominal.get(id));
        assert!(e.value == at && e.std.is_none(), "{name} held at {at}, estimated {e:?}");
    }
}

/// URDF with every origin freed (7 joints × (xyz, rpy, offset) + the tool): the directions the
/// data cannot see stay where the nominal puts them, and moving the nominal along them changes no
/// calibrated figure. Three moves along null directions: joint 1's whole origin (4, −3, 5) mm and
/// (1, −0.5, 2)° (each session's base absorbs it), joint 4's origin turned 1.5° about joint 4's own
/// axis (its offset absorbs it) and joint 6's origin 5 mm along joint 6's axis with joint 7's
/// origin 5 mm back (the adjacent origins absorb each other). The fixed values stay at the nominal
/// (either one), the identifiability sentences name each of them, and the calibrated forward
/// kinematics (base-free: the distances between tool points) and held-out figures are unchanged.
#[test]
fn every_origin_freed_the_null_directions_stay_at_the_nominal_and_move_no_figure() {
    let (dir, generated, nominal, cal, val) = urdf_arm("null", 5);
    assert_eq!(nominal.free.len(), 49, "every origin value and offset free");
    let mut moved = nominal.clone();
    let joint = &mut moved.joints[0];
    for k in 0..3 {
        joint.origin_xyz_mm[k] += [4.0, -3.0, 5.0][k];
        joint.origin_rpy_deg[k] += [1.0, -0.5, 2.0][k];
    }
    let fourth = &moved.joints[3];
    let turned = mul(
        &rpy_matrix(fourth.origin_rpy_deg.map(f64::to_radians)),
        &axis_angle(fourth.axis, 1.5_f64.to_radians()),
    );
    moved.joints[3].origin_rpy_deg = rpy_of(&turned).map(f64::to_degrees);
    let r6 = rpy_matrix(moved.joints[5].origin_rpy_deg.map(f64::to_radians));
    let axis6 = moved.joints[5].axis;
    for k in 0..3 {
        let along_parent: f64 = (0..3).map(|m| r6[k][m] * axis6[m]).sum();
        moved.joints[5].origin_xyz_mm[k] += 5.0 * along_parent;
        moved.joints[6].origin_xyz_mm[k] -= 5.0 * axis6[k];
    }
    let fits: Vec<Fit> = [&nominal, &moved]
        .iter()
        .map(|m| calibrate(m, &cal, &SolveOptions::default()).expect("calibrates"))
        .collect();
    fixed_stay_at_nominal(&fits[0], &nominal);
    fixed_stay_at_nominal(&fits[1], &moved);
    for fit in &fits {
        let ident = &fit.identifiability();
        println!("{} estimated, {} fixed: {:?}", ident.estimated.len(), ident.fixed.len(), ident.fixed);
        for name in &ident.fixed {
            assert!(ident.statements.iter().any(|s| s.starts_with(&format!("{name} "))), "{name}: {ident:?}");
        }
        for name in [
            "origin_x:1",
            "origin_y:1",
            "origin_z:1",
            "origin_rx:1",
            "origin_ry:1",
            "origin_rz:1",
            "offset:1",
        ] {
            let said = format!("{name} is absorbed by the session bases");
            assert!(ident.statements.iter().any(|s| s.starts_with(&said)), "{said}: {:?}", ident.statements);
        }
        // One of joint 4's turn about its axis (offset or origin angles) and one of joint 6's
        // and 7's shifts along joint 6's axis are held.
        assert!(
            ident
                .fixed
                .iter()
                .any(|p| p.ends_with(":4") && (p.starts_with("origin_r") || p.starts_with("offset"))),
            "{:?}",
            ident.fixed
        );
        assert!(
            ident.fixed.iter().any(|p| p.starts_with("origin_") && (p.ends_with(":6") || p.ends_with(":7"))),
            "{:?}",
            ident.fixed
        );
    }
    // Base-free forward kinematics: distances between the calibrated tool points at the held-out
    // readings.
    let points = |m: &ArmModel| -> Vec<[f64; 3]> {
        val.obs.iter().map(|p| tool_pose(m, &p.q_deg).position_mm.into()).collect()
    };
    let (a, b) = (points(&fits[0].model), points(&fits[1].model));
    let distance = |p: &[f64; 3], q: &[f64; 3]| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f64>().sqrt();
    let mut worst_mm: f64 = 0.0;
    for i in 0..a.len() {
        for j in i + 1..a.len() {
            worst_mm = worst_mm.max((distance(&a[i], &a[j]) - distance(&b[i], &b[j])).abs());
        }
    }
    let rms = [held_out_rms(&fits[0].model, &val), held_out_rms(&fits[1].model, &val)];
    let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
    println!(
        "tool-point distances differ by at most {worst_mm:.2e} mm; held-out {rms:?} mm, floor {floor:.4} mm"
    );
    assert!(
        worst_mm < 1e-3,
        "moving the nominal along null directions moved the calibrated arm by {worst_mm} mm"
    );
    assert!((rms[0] - rms[1]).abs() < 1e-4 && rms[1] <= 1.10 * floor, "{rms:?} vs floor {floor}");
    std::fs::remove_dir_all(&dir).ok();
}
