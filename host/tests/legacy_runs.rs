//! RUN folders of earlier versions stay readable: a `kincal-run/1` artefact run and a
//! `kincal-tracker-run/1` tracker run, each written by kincal 0.1 before the engine was one (the
//! files under `host/tests/legacy/`), are read as today's summary with every figure carried over,
//! and diagnosed on their data.

use kincal::api;
use kincal::calib::diagnose::Measure;
use kincal::calib::summary::RUN_FORMAT;
use kincal::data::DataKind;
use serde_json::Value;
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/legacy").join(name)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-legacy-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Copy the fixture's files (and folders) into `to`.
fn copy(from: &Path, to: &Path) {
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            std::fs::create_dir_all(&target).unwrap();
            copy(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

/// The RUN's summary.json as written, its input paths made absolute under `dir`.
fn point_inputs_at(run: &Path, dir: &Path, keys: &[&str]) -> Value {
    let path = run.join("summary.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    for key in keys {
        let rel = v["inputs"][key].as_str().unwrap().to_string();
        v["inputs"][key] = Value::String(dir.join(rel).to_str().unwrap().into());
    }
    std::fs::write(&path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    v
}

#[test]
fn an_artefact_run_of_format_1_reads_as_today_and_is_diagnosed() {
    let dir = scratch("artefact");
    let run = dir.join("run");
    std::fs::create_dir_all(&run).unwrap();
    copy(&fixture("artefact-run-1"), &run);
    // The data it was made from: `kincal simulate --seed 1` with the default options.
    let nominal = kincal::model::ArmModel::load(&run.join("nominal.toml")).unwrap();
    let sim = kincal::simulate::simulate(&nominal, &kincal::simulate::SimulationOptions::default());
    sim.write(&dir.join("data")).unwrap();
    std::fs::copy(run.join("nominal.toml"), run.join("../run-nominal.toml")).unwrap();
    let old = point_inputs_at(&run, &dir, &["artefact", "calibration", "validation"]);
    let mut v: Value = old.clone();
    v["inputs"]["model"] = Value::String(dir.join("run-nominal.toml").to_str().unwrap().into());
    std::fs::write(run.join("summary.json"), serde_json::to_string_pretty(&v).unwrap()).unwrap();

    let folder = api::load(&run).expect("a kincal-run/1 folder reads");
    assert_eq!(folder.format, "kincal-run/1");
    let s = &folder.summary;
    assert_eq!((s.format.as_str(), s.kind, s.joints), (RUN_FORMAT, DataKind::Artefact, 6));
    let d = s.validation.distances.as_ref().expect("held-out distances");
    assert_eq!(d.calibrated.rms_mm, old["validation"]["rms_mm"].as_f64().unwrap());
    assert_eq!(d.nominal.rms_mm, old["nominal_validation"]["rms_mm"].as_f64().unwrap());
    assert_eq!(d.calibrated.count as u64, old["validation"]["pairs"].as_u64().unwrap());
    assert_eq!(s.options.huber_delta_mm, old["options"]["huber_delta_mm"].as_f64());
    assert_eq!(s.options.restarts as u64, old["options"]["restarts"].as_u64().unwrap());
    assert_eq!(s.calibration.observations as u64, old["calibration"]["touches"].as_u64().unwrap());
    assert_eq!(s.identifiability.report.fixed, ["offset:1", "length:1", "tcp.z"]);
    for (e, o) in s.calibration.estimates.iter().zip(old["calibration"]["estimates"].as_array().unwrap()) {
        assert_eq!((e.param.as_str(), e.value), (o["param"].as_str().unwrap(), o["value"].as_f64().unwrap()));
    }
    // Diagnosed on its data: the held-out figure it starts from is the stored one.
    let diagnosis = api::diagnose(&folder).expect("diagnoses");
    assert_eq!(diagnosis.measure, Measure::Distances, "an artefact run is diagnosed on its distances");
    assert!((diagnosis.baseline.rms_mm - d.calibrated.rms_mm).abs() < 1e-12, "{:?}", diagnosis.baseline);
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn a_tracker_run_of_format_1_reads_as_today_and_is_diagnosed_and_compared() {
    let dir = scratch("tracker");
    copy(&fixture("tracker-run-1"), &dir);
    let run = dir.join("run");
    std::fs::create_dir_all(&run).unwrap();
    for file in ["summary.json", "model.toml", "nominal.toml"] {
        std::fs::rename(dir.join(file), run.join(file)).unwrap();
    }
    let old = point_inputs_at(&run, &dir, &["model", "calibration", "validation"]);

    let folder = api::load(&run).expect("a kincal-tracker-run/1 folder reads");
    assert_eq!(folder.format, "kincal-tracker-run/1");
    let s = &folder.summary;
    assert_eq!((s.format.as_str(), s.kind, s.joints), (RUN_FORMAT, DataKind::Tracker, 7));
    assert_eq!(s.options.huber_delta_mm, None);
    assert_eq!(s.inputs.stated_sigma_mm, Some(0.02));
    let sessions = s.held_out_sessions();
    let stored = old["validation"]["sessions"].as_array().unwrap();
    assert_eq!(sessions.len(), stored.len());
    for (f, o) in sessions.iter().zip(stored) {
        assert_eq!(f.calibrated.name, o["name"].as_str().unwrap());
        assert_eq!(f.calibrated.rms_mm, o["rms_mm"].as_f64().unwrap());
        assert_eq!(f.nominal.rms_mm, o["nominal"]["rms_mm"].as_f64().unwrap());
    }
    assert_eq!(s.calibration.rms_mm, old["fit"]["rms_mm"].as_f64().unwrap());
    assert_eq!(s.point_floor().rms_mm, old["floor"]["rms_mm"].as_f64());
    assert_eq!(
        s.verdict,
        old["verdict"].as_array().unwrap().iter().map(|v| v.as_str().unwrap()).collect::<Vec<_>>()
    );
    assert!(folder.residuals().expect("no distances, no residuals file needed").is_empty());
    // Diagnosed on its data (the data checked to be what it was made from: the same calibration
    // RMS refitted) and compared with itself.
    let d = api::diagnose(&folder).expect("diagnoses");
    assert_eq!(d.measure, Measure::Points, "a tracker run is diagnosed on its sessions");
    let overall = old["validation"]["overall"]["rms_mm"].as_f64().unwrap();
    assert!((d.baseline.rms_mm - overall).abs() < 1e-9 * overall, "{} vs {overall}", d.baseline.rms_mm);
    let c = api::compare(&run, &run).expect("compares").comparison;
    assert_eq!(c.measure, Measure::Points, "two tracker runs compare on their sessions");
    assert_eq!((c.before_rms_mm, c.after_rms_mm), (d.baseline.rms_mm, d.baseline.rms_mm));
    std::fs::remove_dir_all(dir).ok();
}
