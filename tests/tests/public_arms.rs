//! Must show (issue 27), the part that does not wait on the calibration engine: the public URDFs
//! of real arms (`tests/data/urdf/`, as published, meshes stripped) read by kincal and by
//! pinocchio (`bench/pinocchio_peer.py`, `pip install pin`, installed by `scripts/setup.sh`).
//!
//! 1. kincal's forward kinematics of each chain equals pinocchio's to 1e-9 mm (the tip) and 1e-12
//!    (the last joint's frame axes) at 24 readings spread over the joint limits.
//! 2. After a calibration on tracker sessions that pinocchio generated from a perturbed arm, the
//!    URDF `kincal model to-urdf` writes, read by pinocchio, is kincal's calibrated model to 1 µm,
//!    and only the chain's `<origin>` lines differ from the published file (on the ROS 2 file,
//!    its `<ros2_control>` block is untouched).

use kincal::model::kinematics::tool_pose;
use kincal::model::urdf::model_from_urdf;
use kincal::model::ArmModel;
use kincal_e2e::kincal_bin;
use std::path::{Path, PathBuf};
use std::process::Command;

/// One public arm: its name, URDF and chain.
struct Arm {
    name: String,
    urdf: PathBuf,
    base: String,
    tip: String,
}

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/urdf")
}

/// The arms of `tests/data/urdf/arms.csv`.
fn arms() -> Vec<Arm> {
    let text = std::fs::read_to_string(data().join("arms.csv")).unwrap();
    let arms: Vec<Arm> = text
        .lines()
        .filter(|l| !l.starts_with('#'))
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            Arm { name: f[0].into(), urdf: data().join(f[1]), base: f[2].into(), tip: f[3].into() }
        })
        .collect();
    assert!(arms.len() >= 8, "at least eight public arms");
    arms
}

fn peer() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/pinocchio_peer.py")
}

fn run(command: &mut Command) -> String {
    let out = command.output().expect("the command runs (python3 with pinocchio: scripts/setup.sh)");
    assert!(
        out.status.success(),
        "{command:?}: {}\n{}",
        String::from_utf8_lossy(&out.stderr),
        String::from_utf8_lossy(&out.stdout)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Pinocchio's pose of `tip` (mm) and of the chain's last joint frame at each reading.
fn pinocchio_fk(urdf: &Path, arm: &Arm, poses: &[Vec<f64>], dir: &Path) -> Vec<([f64; 3], [[f64; 3]; 3])> {
    let file = dir.join("poses.json");
    std::fs::write(&file, serde_json::to_string(poses).unwrap()).unwrap();
    let out = run(Command::new("python3").arg(peer()).arg("fk").arg(urdf).args([
        "--base",
        &arm.base,
        "--tip",
        &arm.tip,
        "--q-file",
        file.to_str().unwrap(),
    ]));
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    let number = |v: &serde_json::Value| v.as_f64().unwrap();
    json["poses"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let pos = p["position_mm"].as_array().unwrap();
            let rot = p["rotation"].as_array().unwrap();
            (
                std::array::from_fn(|k| number(&pos[k])),
                std::array::from_fn(|r| std::array::from_fn(|c| number(&rot[r][c]))),
            )
        })
        .collect()
}

/// 24 readings spread over the model's joint limits (±180° for a continuous joint).
fn readings(model: &ArmModel) -> Vec<Vec<f64>> {
    model.urdf.as_ref().expect("a model from-urdf records its chain").spread_readings(24)
}

/// The largest differences between kincal's `model` and pinocchio's reading of `urdf`: the tip
/// position (mm) and the last joint frame's x and z axes.
fn worst_difference(model: &ArmModel, urdf: &Path, arm: &Arm, dir: &Path) -> (f64, f64) {
    let qs = readings(model);
    let theirs = pinocchio_fk(urdf, arm, &qs, dir);
    let (mut position, mut axes): (f64, f64) = (0.0, 0.0);
    let mut frame = model.clone();
    frame.tcp_mm = [0.0; 3];
    for (q, (p, r)) in qs.iter().zip(&theirs) {
        let mine = tool_pose(model, q).position_mm;
        position = position.max((0..3).map(|k| (mine[k] - p[k]).powi(2)).sum::<f64>().sqrt());
        let axes_of = tool_pose(&frame, q);
        for (k, row) in r.iter().enumerate() {
            axes = axes.max((axes_of.x_axis[k] - row[0]).abs()).max((axes_of.z_axis[k] - row[2]).abs());
        }
    }
    (position, axes)
}

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-public-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn kincal_forward_kinematics_of_every_public_arm_is_pinocchios() {
    let dir = temp("fk");
    for arm in arms() {
        let model = model_from_urdf(&arm.urdf, &arm.base, &arm.tip).unwrap();
        let (position, axes) = worst_difference(&model, &arm.urdf, &arm, &dir);
        println!("{:<22} {} joints: tip {position:.1e} mm, axes {axes:.1e}", arm.name, model.joints.len());
        assert!(position < 1e-9, "{}: tip {position} mm from pinocchio's", arm.name);
        assert!(axes < 1e-12, "{}: last frame axes {axes} from pinocchio's", arm.name);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_urdf_written_after_a_calibration_is_the_calibrated_arm_for_pinocchio() {
    let root = temp("round");
    for (k, arm) in arms().iter().enumerate() {
        let dir = root.join(format!("arm{k}"));
        let chain = ["--base", arm.base.as_str(), "--tip", arm.tip.as_str()];
        run(Command::new("python3").arg(peer()).arg("sessions").arg(&arm.urdf).args(chain).args([
            "--seed",
            "7",
            "--tool",
            "off",
            "--out",
            dir.to_str().unwrap(),
        ]));
        let kincal = |args: &[&str]| run(Command::new(kincal_bin()).args(args).current_dir(&dir));
        let urdf = arm.urdf.to_str().unwrap();
        kincal(&[&["model", "from-urdf", urdf, "--out", "model.toml"], &chain[..]].concat());
        kincal(&[
            "calibrate",
            "--model",
            "model.toml",
            "--data",
            "cal",
            "--validate",
            "val",
            "--out",
            "run",
            "--restarts",
            "1",
        ]);
        let said =
            kincal(&["model", "to-urdf", "run/model.toml", "--urdf", urdf, "--out", "calibrated.urdf"]);
        assert!(said.contains("joint origins calibrated") && said.contains("read back"), "{said}");
        let nominal = ArmModel::load(&dir.join("model.toml")).unwrap();
        let mut calibrated = ArmModel::load(&dir.join("run/model.toml")).unwrap();
        // The URDF's tip stays the published one; the calibrated tool point (the probe) stays in
        // the model.
        calibrated.tcp_mm = nominal.tcp_mm;
        let moved = readings(&calibrated)
            .iter()
            .map(|q| (tool_pose(&calibrated, q).position_mm - tool_pose(&nominal, q).position_mm).norm())
            .fold(0.0, f64::max);
        let (position, axes) = worst_difference(&calibrated, &dir.join("calibrated.urdf"), arm, &dir);
        println!(
            "{:<22} calibration moved the tip by up to {moved:.3} mm; written URDF vs model: {position:.1e} mm, axes {axes:.1e}",
            arm.name
        );
        assert!(moved > 0.1, "{}: the calibration changed nothing worth writing ({moved} mm)", arm.name);
        assert!(position < 1e-3, "{}: the written URDF is {position} mm from the calibrated model", arm.name);
        assert!(axes < 1e-6, "{}: the written URDF's axes are {axes} from the model's", arm.name);
        let (before, after) = (
            std::fs::read_to_string(&arm.urdf).unwrap(),
            std::fs::read_to_string(dir.join("calibrated.urdf")).unwrap(),
        );
        // Apart from kincal's note of what it wrote, the same lines.
        let note = kincal::files::WRITTEN_BY;
        assert_eq!(after.matches(note).count(), 1, "{}: one note", arm.name);
        let after: String = after.lines().filter(|l| !l.contains(note)).map(|l| format!("{l}\n")).collect();
        let changed: Vec<&str> =
            before.lines().zip(after.lines()).filter(|(a, b)| a != b).map(|(_, b)| b.trim()).collect();
        assert_eq!(before.lines().count(), after.lines().count(), "{}: lines added or lost", arm.name);
        assert_eq!(
            changed.len(),
            nominal.joints.len(),
            "{}: one <origin> per joint changes: {changed:?}",
            arm.name
        );
        assert!(changed.iter().all(|l| l.starts_with("<origin ")), "{}: {changed:?}", arm.name);
        if let Some(start) = before.find("<ros2_control") {
            let end = before.find("</ros2_control>").unwrap();
            assert!(after.contains(&before[start..end]), "{}: the <ros2_control> block changed", arm.name);
        }
    }
    std::fs::remove_dir_all(&root).ok();
}
