//! Issue 31, gravity as real robots have it: a humanoid upper body (torso of four joints, two
//! 7-joint arms, a head; `tests/data/humanoid/upper_body.urdf`) measured with a marker on each
//! hand, simulated by the independent pinocchio generator `tests/gen/humanoid.py` (joint and
//! lateral compliance under the whole tree's link masses, deflections at their fixed point; no
//! code shared with kincal). kincal reads the URDF as a branched model with its mass table
//! (`kincal model from-urdf --tip left_marker,right_marker --masses`), the sessions in
//! `kincal-tracker/2`, and its loop must name the compliance under the link masses first, then
//! the lateral compliance (which refines it: the diagnosis's hierarchy, though the data alone
//! favour the lateral one), and end within 1.10× the floor held out with every fitted compliance
//! within 3 of its standard deviations of the truth. Lateral compliance alone still reaches the
//! floor through `sag` (which ends at zero); where the data cannot tell the two apart they are
//! stated as rivals. With the tip-mass model only, the diagnosis says the sag is not explained by
//! a tip mass alone. The calibrated origins are written back into the URDF, and pinocchio reads
//! the written file and agrees with kincal's model.

use kincal::calib::diagnose::auto::{auto_loop, AutoLoop, Stop};
use kincal::calib::diagnose::{diagnose, held_out_rms_mm};
use kincal::calib::setup::{Change, Setup};
use kincal::calib::validate::validate_session;
use kincal::data::{load_folder, Purpose};
use kincal::model::effects::Effect;
use kincal::model::kinematics::Chain;
use kincal::model::{ArmModel, ParamId};
use kincal_e2e::kincal_bin;
use kincal_e2e::tracker_setup::{scratch, split_last_held_out};
use std::path::{Path, PathBuf};
use std::process::Command;

const URDF: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/data/humanoid/upper_body.urdf");
const GENERATOR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/gen/humanoid.py");
const TIPS: &str = "left_marker,right_marker";
/// Sessions, the last one held out (unless a test asks for fewer).
const SESSIONS: usize = 4;

/// The generator's data (seed 1, link masses, 240 poses), written once for the tests of this
/// file: the folder and its truth.json.
fn generated() -> &'static (PathBuf, serde_json::Value) {
    static DATA: std::sync::OnceLock<(PathBuf, serde_json::Value)> = std::sync::OnceLock::new();
    DATA.get_or_init(|| {
        let dir = scratch("humanoid", "data");
        let truth = generate(&dir, &["--poses", "240", "--repeats", "12"]);
        (dir.join("data"), truth)
    })
}

/// Run the generator (seed 1, [`SESSIONS`] sessions, and `options`) into `dir/data`; its
/// truth.json.
fn generate(dir: &Path, options: &[&str]) -> serde_json::Value {
    let data = dir.join("data");
    let out = Command::new("python3")
        .args([GENERATOR, "--seed", "1", "--sessions", &SESSIONS.to_string()])
        .args(options)
        .arg("--out")
        .arg(&data)
        .output()
        .expect("python3 runs (scripts/setup.sh installs it with pinocchio)");
    assert!(out.status.success(), "the generator failed: {}", String::from_utf8_lossy(&out.stderr));
    println!("{}", String::from_utf8_lossy(&out.stdout));
    let text = std::fs::read_to_string(data.join("truth.json")).expect("truth.json");
    serde_json::from_str(&text).expect("truth.json is JSON")
}

/// `kincal model from-urdf` of the two hands' chains, with the mass table when `masses`.
fn model(dir: &Path, masses: bool) -> PathBuf {
    let path = dir.join(if masses { "masses.toml" } else { "tip-mass.toml" });
    let mut cmd = Command::new(kincal_bin());
    cmd.args(["model", "from-urdf", URDF, "--base", "base_link", "--tip", TIPS, "--out"]).arg(&path);
    if masses {
        cmd.arg("--masses");
    }
    let out = cmd.output().expect("kincal runs");
    assert!(out.status.success(), "from-urdf: {}", String::from_utf8_lossy(&out.stderr));
    println!("{}", String::from_utf8_lossy(&out.stdout));
    path
}

/// The true compliance of `param` in kincal's unit (deg/(kN·m)) from truth.json.
fn truth_of(truth: &serde_json::Value, param: ParamId) -> f64 {
    let (key, j) = match param {
        ParamId::Sag(j) => ("c_rad_per_Nm", j),
        ParamId::Bend(j) => ("k_rad_per_Nm", j),
        _ => unreachable!("a compliance"),
    };
    truth["joints"][j][key].as_f64().expect("a compliance in truth.json").to_degrees() * 1000.0
}

/// kincal's gravity loads are the generator's: the true URDF with its masses and the true
/// compliances leave only the instrument's noise at the markers (each session's base refitted).
#[test]
fn the_true_robot_in_kincal_leaves_only_the_noise() {
    let (data, truth) = generated();
    let dir = scratch("humanoid", "truth");
    let out = Command::new(kincal_bin())
        .args(["model", "from-urdf"])
        .arg(data.join("truth.urdf"))
        .args(["--base", "base_link", "--tip", TIPS, "--masses", "--out"])
        .arg(dir.join("truth.toml"))
        .output()
        .expect("kincal runs");
    assert!(out.status.success(), "from-urdf: {}", String::from_utf8_lossy(&out.stderr));
    let mut model = ArmModel::load(&dir.join("truth.toml")).expect("the model loads");
    for j in 0..model.joints.len() {
        for id in [ParamId::Sag(j), ParamId::Bend(j)] {
            model.set(id, truth_of(truth, id));
        }
    }
    let mut all = load_folder(&data.join("sessions"), None, Purpose::Validation).expect("sessions");
    all.bind(&model).expect("bound");
    let (mut sum, mut n) = (0.0, 0);
    for b in 0..all.blocks.len() {
        let v = validate_session(&model, &all, b, [0.0; 3]);
        sum += v.rms_mm * v.rms_mm * v.points as f64;
        n += v.points;
    }
    let rms = (sum / n as f64).sqrt();
    let floor = truth["stages"]["geometry+joint+lateral"]["rms_mm"].as_f64().expect("floor");
    println!(
        "the true robot in kincal: {rms:.4} mm RMS at the markers, the generator's noise alone {floor:.4} mm"
    );
    assert!(rms <= 1.02 * floor, "kincal's true robot leaves {rms} mm, the noise {floor} mm");
    std::fs::remove_dir_all(&dir).ok();
}

/// Some line of a diagnosis's `summary` starts with `start`.
fn says(summary: &[String], start: &str) -> bool {
    summary.iter().any(|l| l.starts_with(start))
}

/// The loop from the geometric calibration of `nominal` on the generated `data` (split in `dir`):
/// its steps printed, and the last step refitted (its estimates with their deviations).
fn run_loop(data: &Path, dir: &Path, nominal: &ArmModel) -> (AutoLoop, kincal::calib::fit::Fit) {
    let (cal, val) = split_last_held_out(data, dir, nominal);
    let setup = Setup::default();
    let geometry = setup.calibrate(nominal, &cal).expect("calibrates").model;
    let auto = auto_loop(&setup, &geometry, &cal, &val, 3).expect("the loop runs");
    for s in &auto.steps {
        let free = s.model.as_ref().map(|m| m.free.len()).unwrap_or_default();
        println!(
            "step {:?}: held out {:.3} mm, floor {:?} mm, named {:?} ({free} free)",
            s.applied, s.held_out_rms_mm, s.floor_mm, s.named
        );
    }
    for (k, s) in auto.steps.iter().enumerate() {
        println!("step {k} summary:\n  {}", s.summary.join("\n  "));
    }
    let last = auto.steps.last().and_then(|s| s.model.clone()).expect("the last step's model");
    let fit = auto.setup.calibrate(&last, &cal).expect("the last step refits");
    (auto, fit)
}

/// The loop added `sag`, then `bend`, the first step saying why `sag` comes first, and ended at
/// the floor of the held-out session (within 1.10×).
fn assert_sag_then_bend_to_the_floor(auto: &AutoLoop, truth: &serde_json::Value) {
    let applied: Vec<&str> = auto.steps.iter().filter_map(|s| s.applied.as_deref()).collect();
    assert_eq!(applied, ["sag", "bend"], "{:?}", auto.steps[0].summary);
    let hierarchy = "bend is offered once sag is in the model: lateral compliance refines joint compliance";
    assert!(says(&auto.steps[0].summary, hierarchy), "{:?}", auto.steps[0].summary);
    let floor = truth["stages"]["geometry+joint+lateral"]["rms_mm"].as_f64().expect("floor");
    let end = auto.steps.last().expect("steps").held_out_rms_mm;
    assert_eq!(auto.stop, Stop::AtFloor, "{:?}", auto.last.summary);
    assert!(end <= 1.10 * floor, "held out {end:.3} mm against the floor {floor:.3} mm");
}

/// The compliances `fit` determines, each within 3 of its standard deviations of the truth; how
/// many; their z-scores printed with their largest and RMS.
fn within_three_sigma(fit: &kincal::calib::fit::Fit, truth: &serde_json::Value) -> usize {
    let mut z = Vec::new();
    for e in &fit.estimates {
        let Some(id) = ParamId::parse(&e.param).filter(|p| p.is_load_compliance()) else { continue };
        let Some(std) = e.std else { continue };
        let t = truth_of(truth, id);
        let deviations = (e.value - t) / std;
        println!("{id}: {:.3} ± {std:.3} deg/(kN·m), truth {t:.3} ({deviations:+.1} σ)", e.value);
        assert!(deviations.abs() <= 3.0, "{id}: {} ± {std} vs truth {t}", e.value);
        z.push(deviations);
    }
    let rms = (z.iter().map(|v| v * v).sum::<f64>() / z.len().max(1) as f64).sqrt();
    println!(
        "{} compliances determined: largest |z| {:.2}, RMS z {rms:.2}",
        z.len(),
        z.iter().fold(0.0f64, |m, v| m.max(v.abs()))
    );
    z.len()
}

/// The loop names joint compliance under the link masses (`sag`) first, then lateral compliance
/// (`bend`), and reaches the floor; every determined compliance lies within 3σ of the truth.
#[test]
fn the_loop_names_sag_then_bend_and_reaches_the_floor_on_a_humanoid() {
    let dir = scratch("humanoid", "links");
    let truth = &generated().1;
    let nominal = ArmModel::load(&model(&dir, true)).expect("the model loads");
    assert_eq!((nominal.joints.len(), nominal.tree.tips.len()), (18, 2));
    let carried: f64 = nominal.tree.bodies.iter().map(|b| b.mass_kg).sum();
    let urdf_total: f64 =
        truth["bodies"].as_array().expect("bodies").iter().map(|b| b["mass_kg"].as_f64().unwrap()).sum();
    assert!(
        (carried - urdf_total).abs() < 1e-9,
        "kincal carries {carried} kg, the URDF has {urdf_total} kg beyond the base"
    );
    let (auto, fit) = run_loop(&generated().0, &dir, &nominal);
    assert_sag_then_bend_to_the_floor(&auto, truth);
    // (A loop that refitted warm only, from the solution with `bend` alone, once settled at a
    // cost 0.45 % higher with sag:17 at −2.8 ± 3.0 against 7.8 true; the loop keeps the better
    // of two starts, see `auto_loop`.)
    round_trip(&dir, &fit.model);
    let checked = within_three_sigma(&fit, truth);
    assert!(checked >= 30, "only {checked} compliances estimated");
    std::fs::remove_dir_all(&dir).ok();
}

/// Lateral compliance alone (no joint compliance in the generator): the hierarchy does not block
/// it. A unit-level check of the loop's first step, to keep the file's time (a second loop of 240
/// poses would double it, and with 120 or 160 poses the loop, in the same order, stops 1.1× above
/// the floor): the diagnosis names `sag` (significant by itself: it imitates part of the bending)
/// although the data favour `bend`, and says why; the model with both, as the loop would add them,
/// reaches the floor, and the `sag` it holds is zero within 3σ on every joint.
#[test]
fn lateral_compliance_alone_is_reached_after_sag_which_ends_at_zero() {
    let dir = scratch("humanoid", "lateral");
    let truth = generate(&dir, &["--poses", "240", "--repeats", "12", "--joint-compliance-scale", "0"]);
    let nominal = ArmModel::load(&model(&dir, true)).expect("the model loads");
    let (cal, val) = split_last_held_out(&dir.join("data"), &dir, &nominal);
    let setup = Setup::default();
    let geometry = setup.calibrate(&nominal, &cal).expect("calibrates").model;
    let d = diagnose(&setup, &geometry, &cal, &val).expect("diagnoses");
    println!("{}", d.summary.join("\n"));
    assert_eq!(d.named, ["sag"], "{:?}", d.summary);
    let hierarchy = "bend is offered once sag is in the model: lateral compliance refines joint compliance";
    assert!(says(&d.summary, hierarchy), "{:?}", d.summary);
    let (sag, bend) = (d.candidate("sag").expect("sag scored"), d.candidate("bend").expect("bend scored"));
    assert!(bend.significant && bend.held_out_rms_mm < sag.held_out_rms_mm, "the data alone would name bend");
    let mut both = setup.clone();
    let mut start = geometry.clone();
    for effect in ["sag", "bend"] {
        let change = Change::Effect(Effect::parse(effect).expect("an effect"));
        (both, start) = both.apply(&change, &start);
    }
    let fit = both.calibrate(&start, &cal).expect("calibrates with sag and bend");
    let end = held_out_rms_mm(&both, &fit.model, &val).expect("held out");
    let floor = truth["stages"]["geometry+joint+lateral"]["rms_mm"].as_f64().expect("floor");
    println!("geometry {:.3} mm, with sag {:.3} mm (bend alone {:.3} mm), with both {end:.3} mm held out; noise {floor:.3} mm", d.baseline.rms_mm, sag.held_out_rms_mm, bend.held_out_rms_mm);
    assert!(end <= 1.10 * floor, "held out {end:.3} mm against the floor {floor:.3} mm");
    let checked = within_three_sigma(&fit, &truth);
    let sags = fit.estimates.iter().filter(|e| e.param.starts_with("sag:") && e.std.is_some()).count();
    assert!(sags >= 10 && checked >= 25, "{sags} sag and {checked} compliances estimated");
    std::fs::remove_dir_all(&dir).ok();
}

/// Where the data truly cannot tell joint from lateral compliance (a sag of 0.3× the usual on
/// every joint, no bending, 60 poses over one calibration and one held-out session, a 1 mm
/// instrument), the diagnosis states `sag` and `bend` as rivals, says why they look alike, and
/// claims neither over the other.
#[test]
fn sag_and_bend_the_data_cannot_tell_apart_are_stated_as_rivals() {
    let dir = scratch("humanoid", "rivals");
    let options = ["--poses", "60", "--sessions", "2", "--repeats", "6", "--sigma-mm", "1.0"];
    generate(&dir, &[&options[..], &["--joint-compliance-scale", "0.3", "--lateral-scale", "0"]].concat());
    let nominal = ArmModel::load(&model(&dir, true)).expect("the model loads");
    let (cal, val) = split_last_held_out(&dir.join("data"), &dir, &nominal);
    let setup = Setup::default();
    let calibrated = setup.calibrate(&nominal, &cal).expect("calibrates").model;
    let d = diagnose(&setup, &calibrated, &cal, &val).expect("diagnoses");
    println!("{}", d.summary.join("\n"));
    let mut named = d.named.clone();
    named.sort();
    assert_eq!(named, ["bend", "sag"], "{:?}", d.summary);
    assert!(
        says(&d.summary, "missing effect: sag or bend: these data cannot tell them apart"),
        "{:?}",
        d.summary
    );
    assert!(says(&d.summary, "sag and bend are rivals: joint compliance"), "{:?}", d.summary);
    // Neither is claimed alone.
    assert!(!says(&d.summary, "missing effect: sag —") && !says(&d.summary, "missing effect: bend —"));
    std::fs::remove_dir_all(&dir).ok();
}

/// pinocchio's placement (mm) of the joints named in argv[2] at the readings (deg) of argv[3]
/// (a JSON object joint → angle), for the URDF argv[1]: one JSON list of [x, y, z] per joint.
const PINOCCHIO_FK: &str = r#"
import json, sys
import numpy as np
import pinocchio as pin
model = pin.buildModelFromUrdf(sys.argv[1])
data = model.createData()
readings = json.loads(sys.argv[3])
q = np.array([np.radians(readings[model.names[i]]) for i in range(1, model.njoints)])
pin.forwardKinematics(model, data, q)
print(json.dumps([list(data.oMi[model.getJointId(n)].translation * 1000.0) for n in sys.argv[2].split(",")]))
"#;

/// The calibrated origins written back into the URDF (`kincal model to-urdf`; the compliances
/// stay in the model file), and pinocchio reads the written file: each hand's last joint sits
/// where kincal's rigid model puts it.
fn round_trip(dir: &Path, calibrated: &ArmModel) {
    let (model_path, written) = (dir.join("calibrated.toml"), dir.join("calibrated.urdf"));
    calibrated.save(&model_path).expect("model saved");
    let out = Command::new(kincal_bin())
        .args(["model", "to-urdf"])
        .arg(&model_path)
        .args(["--urdf", URDF, "--out"])
        .arg(&written)
        .output()
        .expect("kincal runs");
    assert!(out.status.success(), "to-urdf: {}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&written).expect("written URDF");
    assert!(text.contains("have no URDF element"), "the note names the compliances kept in the model");
    let source = calibrated.urdf.as_ref().expect("a URDF model");
    let mut rigid = calibrated.clone();
    rigid.tree.bodies.clear();
    rigid.tcp_mm = [0.0; 3];
    rigid.tree.tips.iter_mut().for_each(|t| t.tcp_mm = [0.0; 3]);
    let last: Vec<&str> = rigid.tree.tips.iter().map(|t| source.joint[t.joint].name.as_str()).collect();
    let mut worst: f64 = 0.0;
    for q in source.spread_readings(4) {
        let readings: serde_json::Map<String, serde_json::Value> =
            source.joint.iter().zip(&q).map(|(j, v)| (j.name.clone(), (*v).into())).collect();
        let out = Command::new("python3")
            .args(["-c", PINOCCHIO_FK])
            .arg(&written)
            .arg(last.join(","))
            .arg(serde_json::Value::Object(readings).to_string())
            .output()
            .expect("python3 runs");
        assert!(out.status.success(), "pinocchio: {}", String::from_utf8_lossy(&out.stderr));
        let points: Vec<[f64; 3]> = serde_json::from_slice(&out.stdout).expect("pinocchio prints JSON");
        for (t, p) in points.iter().enumerate() {
            let mine = Chain::for_tip(&rigid, t).pose(&q).position_mm;
            let d = (0..3).map(|k| (mine[k] - p[k]).powi(2)).sum::<f64>().sqrt();
            worst = worst.max(d);
        }
    }
    println!("the written URDF in pinocchio vs kincal's calibrated model: {worst:.2e} mm");
    assert!(worst < 1e-3, "pinocchio puts the hands {worst} mm from kincal's model");
}

/// With the tip-mass model only (no mass table, `compliance:J` on every joint: a unit mass at the
/// tool point), the model stays above the floor and the diagnosis says the sag is not explained
/// by a tip mass alone.
#[test]
fn the_tip_mass_model_alone_leaves_a_sag_it_cannot_explain() {
    let dir = scratch("humanoid", "tip-mass");
    let mut nominal = ArmModel::load(&model(&dir, false)).expect("the model loads");
    assert!(nominal.tree.bodies.is_empty());
    for j in 1..nominal.joints.len() {
        Effect::parse(&format!("compliance:{}", j + 1)).expect("an effect").add_to(&mut nominal);
    }
    let (cal, val) = split_last_held_out(&generated().0, &dir, &nominal);
    let setup = Setup::default();
    let calibrated = setup.calibrate(&nominal, &cal).expect("calibrates").model;
    let d = diagnose(&setup, &calibrated, &cal, &val).expect("diagnoses");
    println!("{}", d.summary.join("\n"));
    assert!(d.incomplete, "the tip-mass model misses the floor");
    assert!(says(&d.summary, "the sag is not explained by a tip mass alone"), "{:?}", d.summary);
    std::fs::remove_dir_all(&dir).ok();
}
