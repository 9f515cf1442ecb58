//! Test harness around the independent tracker generator: the generated arm as a kincal model
//! (every DH value free) and the generated sessions written and read back as calibration and
//! held-out folders. Only kincal's reader and model file loader are used, no forward code.

use crate::tracker_gen::TrackerData as Generated;
use kincal::calib::validate::validate_session;
use kincal::data::tracker::load_dir;
use kincal::data::{load_folder, Observations, Purpose};
use kincal::model::{ArmModel, ParamId};
use std::path::{Path, PathBuf};

/// A fresh scratch folder for one test. The folders of earlier runs of the same test whose
/// process has ended are removed first (a folder shared by a file's tests, held in a static,
/// outlives its process: nothing drops it).
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    let stem = format!("kincal-{prefix}-{name}-");
    remove_stale(&stem);
    let dir = std::env::temp_dir().join(format!("{stem}{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

/// Remove the temporary folders `stem` + a process id whose process no longer runs (Linux's
/// `/proc` tells; elsewhere nothing is removed).
fn remove_stale(stem: &str) {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let pid = name.to_str().and_then(|n| n.strip_prefix(stem)).and_then(|p| p.parse::<u32>().ok());
        let ended = pid.is_some_and(|p| {
            cfg!(target_os = "linux") && p != std::process::id() && !Path::new(&format!("/proc/{p}")).exists()
        });
        if ended {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// The generator's nominal arm as a kincal model with every DH value free (the identifiability
/// step picks what the data can move), saved as `dir/nominal.toml`.
pub fn nominal_model(generated: &Generated, dir: &Path) -> ArmModel {
    let text = generated.options.arm.kincal_model_toml().expect("a DH arm");
    let path = dir.join("nominal.toml");
    std::fs::write(&path, &text).expect("model written");
    let mut model = ArmModel::load(&path).expect("the generator's model loads");
    model.free.clear();
    model.free_every_dh_value(5.0, 10.0);
    // Hayati β on the rows whose next axis is nominally parallel, as the generator draws it.
    let last = model.joints.len() - 1;
    for j in 0..last {
        if model.joints[j].alpha_deg.abs() < 1e-9 {
            let beta = model.joints[j].axis_deg;
            model.free_param(ParamId::Axis(j), beta - 5.0, beta + 5.0);
        }
    }
    model.save(&path).expect("model saved");
    model
}

/// Write the generated sessions into `dir/cal` (the indices `cal`) and `dir/val` and read them
/// back.
pub fn split(generated: &Generated, dir: &Path, cal: &[usize]) -> (Observations, Observations) {
    let all = dir.join("all");
    generated.write(&all).expect("sessions written");
    let (c, v) = (dir.join("cal"), dir.join("val"));
    std::fs::create_dir_all(&c).expect("cal folder");
    std::fs::create_dir_all(&v).expect("val folder");
    for (s, session) in generated.sessions.iter().enumerate() {
        let name = format!("{}.csv", session.plan.name);
        let to = if cal.contains(&s) { &c } else { &v };
        std::fs::rename(all.join(&name), to.join(&name)).expect("session moved");
    }
    (load_dir(&c).expect("calibration sessions"), load_dir(&v).expect("validation sessions"))
}

/// Pooled held-out RMS of `model` over the sessions of `val`, each session's base refitted, mm.
pub fn held_out_rms(model: &ArmModel, val: &Observations) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for b in 0..val.blocks.len() {
        let v = validate_session(model, val, b, [0.0; 3]);
        sum += v.rms_mm * v.rms_mm * v.points as f64;
        n += v.points;
    }
    (sum / n as f64).sqrt()
}

/// The sessions `S1.csv … Sn.csv` in `data/sessions` split into `dir/cal` (all but the last)
/// and `dir/val` (the last, held out), read and bound to `model`.
pub fn split_last_held_out(data: &Path, dir: &Path, model: &ArmModel) -> (Observations, Observations) {
    let (cal, val) = (dir.join("cal"), dir.join("val"));
    let source = data.join("sessions");
    let n = std::fs::read_dir(&source).expect("sessions").count();
    for (folder, sessions) in [(&cal, 1..n), (&val, n..n + 1)] {
        std::fs::create_dir_all(folder).expect("folder");
        for s in sessions {
            let name = format!("S{s}.csv");
            std::fs::copy(source.join(&name), folder.join(&name)).expect("session copied");
        }
    }
    let read = |folder: &Path, purpose| {
        let mut data = load_folder(folder, None, purpose).expect("kincal-tracker/2 sessions read");
        data.bind(model).expect("the sessions' joints and tips are the model's");
        data
    };
    (read(&cal, Purpose::Calibration), read(&val, Purpose::Validation))
}
