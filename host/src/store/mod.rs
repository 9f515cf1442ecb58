//! The folders and files kincal writes and reads back ([`run_folder`], with the formats of
//! earlier versions in [`legacy`]), and the rules that keep the user's own files safe.
//!
//! Rules (stated in the README):
//! - An output folder is written under a hidden staging name beside it and renamed into place only
//!   when every file is complete; on any error, a full disk included, the staging folder is removed
//!   and nothing is left behind.
//! - An existing output folder is replaced only when kincal wrote it: it carries the marker file
//!   [`MARKER`], or every entry in it is a file kincal writes into that kind of folder. A folder
//!   holding anything else (the user's files, input data) is refused, never emptied; so are `.`,
//!   `..`, a path that is a file, and a folder that contains one of the run's inputs.
//! - Single files (`diagnosis.json` inside a RUN, the compare page) are written atomically; an
//!   existing file is replaced only when kincal wrote it.

use crate::calib::diagnose::auto::AutoLoop;
use crate::calib::diagnose::Diagnosis;
use crate::calib::run::Run;
use crate::calib::study::StudyRow;
use crate::files::{write_atomic, FileError};
use crate::haptic::pipeline::HapticSummary;
use crate::report;

pub mod certificate;
pub mod legacy;
pub mod run_folder;

pub use run_folder::RunFolder;
use std::path::{Path, PathBuf};

/// Marker file kincal puts in every folder it writes; its text is the folder's kind.
pub const MARKER: &str = ".kincal-output";
/// Format tag of `study.json`.
pub const STUDY_FORMAT: &str = "kincal-study/1";
/// Format tag of `diagnosis.json` (every kind of held-out data; `measure` says which).
pub const DIAGNOSIS_FORMAT: &str = "kincal-diagnosis/2";
/// Format tag of a dynamic validation's `dynamic.json`.
pub const DYNAMIC_FORMAT: &str = "kincal-dynamic/1";
/// Format tag of a haptic calibration's `summary.json`.
pub const HAPTIC_FORMAT: &str = "kincal-haptic/1";
/// Format tag of the auto loop's `auto.json` (every kind of held-out data).
pub const AUTO_FORMAT: &str = "kincal-auto/2";
/// The calibration certificate `kincal certificate RUN` writes into the RUN folder.
pub const CERTIFICATE_FILE: &str = "certificate.html";
/// Format tag of a plan (`kincal plan --out FILE`).
pub const PLAN_FORMAT: &str = "kincal-plan/1";
/// Header of a plan's pose list (`kincal plan --csv FILE`), before a column per joint
/// (`j1_deg`, …): an artefact placement's origin and yaw, or a session's name with them empty.
pub const PLAN_CSV_HEADER: &str = "purpose,placement,origin_x_mm,origin_y_mm,origin_z_mm,yaw_deg,landmark";

/// Why an output could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The file system refused (disk full, permissions, …); nothing was left behind.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// Writing there would delete or overwrite something kincal did not write.
    #[error("{path}: {reason}; nothing was written. Choose a new folder (or remove it yourself).")]
    Refused {
        /// The output path.
        path: PathBuf,
        /// What is in the way.
        reason: String,
    },
    /// A model file could not be written into the folder.
    #[error(transparent)]
    File(#[from] FileError),
}

/// The kinds of folder kincal writes, with the files each may hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FolderKind {
    /// A calibration RUN (`kincal calibrate`), later also holding the diagnosis files.
    Run,
    /// A dataset-size study (`kincal study`).
    Study,
    /// A haptic calibration (`kincal haptic calibrate`).
    Haptic,
    /// The steps of `kincal diagnose --auto`, in RUN/auto.
    Auto,
    /// Simulated data (`kincal simulate`): artefact, truth and the session folders.
    Simulation,
    /// A simulated haptic recording (`kincal haptic simulate`).
    HapticRecording,
    /// A dynamic validation (`kincal dynamic`).
    Dynamic,
}

impl FolderKind {
    fn name(self) -> &'static str {
        match self {
            FolderKind::Run => "run",
            FolderKind::Study => "study",
            FolderKind::Haptic => "haptic",
            FolderKind::Auto => "auto",
            FolderKind::Simulation => "simulation",
            FolderKind::HapticRecording => "haptic-recording",
            FolderKind::Dynamic => "dynamic",
        }
    }

    /// Sub-folders kincal writes into this kind of folder, with the files each may hold.
    fn subfolders(self) -> Vec<(&'static str, Vec<String>)> {
        let names = |places: Vec<crate::simulate::Placement>| -> Vec<String> {
            places.into_iter().map(|p| format!("{}.json", p.name)).collect()
        };
        match self {
            FolderKind::Simulation => vec![
                ("cal", names(crate::simulate::calibration_placements())),
                ("val", names(crate::simulate::validation_placements())),
            ],
            FolderKind::HapticRecording => ["delay", "gimbal", "reference", "joints", "landmarks", "verify"]
                .into_iter()
                .map(|step| (step, ["device.csv", "hip.csv", "t1.csv", "t2.csv"].map(String::from).to_vec()))
                .collect(),
            _ => Vec::new(),
        }
    }

    /// Whether its files look the same whether kincal or a person made them (session files, a
    /// recording): such a folder is replaced only when it carries kincal's marker.
    fn needs_marker(self) -> bool {
        matches!(self, FolderKind::Simulation | FolderKind::HapticRecording)
    }

    /// Whether an entry of this name (a folder when `is_dir`) is one kincal writes here.
    fn writes(self, name: &str, is_dir: bool) -> bool {
        match (self, is_dir) {
            (FolderKind::Run, true) => name == "auto",
            (FolderKind::Auto, false) => {
                self.files().contains(&name)
                    || name
                        .strip_prefix("step-")
                        .and_then(|n| n.strip_suffix(".toml"))
                        .is_some_and(|k| k.chars().all(|c| c.is_ascii_digit()))
            }
            (_, false) => self.files().contains(&name),
            (_, true) => false,
        }
    }

    fn files(self) -> &'static [&'static str] {
        match self {
            FolderKind::Run => &[
                "model.toml",
                "nominal.toml",
                "summary.json",
                "residuals.json",
                "report.html",
                "diagnosis.json",
                "diagnosis.html",
                CERTIFICATE_FILE,
                crate::trace::UPLOADS_FILE,
            ],
            FolderKind::Study => &["study.json", "report.html"],
            FolderKind::Haptic => &["summary.json", "report.html"],
            FolderKind::Auto => &["auto.json", "report.html"],
            FolderKind::Simulation => &["artefact.json", "truth.toml"],
            FolderKind::HapticRecording => &["recording.json"],
            FolderKind::Dynamic => &["dynamic.json", "report.html"],
        }
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutputError + '_ {
    move |source| OutputError::Io { path: path.to_owned(), source }
}

fn refused(path: &Path, reason: impl Into<String>) -> OutputError {
    OutputError::Refused { path: path.to_owned(), reason: reason.into() }
}

/// Check that `dir` may become (or be replaced by) a kincal folder of `kind`, and that none of
/// `inputs` lies inside it. Returns whether it exists with content.
pub fn check_output_folder(dir: &Path, kind: FolderKind, inputs: &[&Path]) -> Result<bool, OutputError> {
    if dir.as_os_str().is_empty() || dir.file_name().is_none() {
        return Err(refused(dir, "is not a folder name kincal can create (`.`, `..` or a root)"));
    }
    let absolute = |p: &Path| std::fs::canonicalize(p).ok();
    if let Some(out) = absolute(dir) {
        for input in inputs {
            if absolute(input).is_some_and(|i| i.starts_with(&out)) {
                return Err(refused(dir, format!("contains the input {}", input.display())));
            }
        }
    }
    let meta = match std::fs::symlink_metadata(dir) {
        Ok(meta) => meta,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(io(dir)(e)),
    };
    if !meta.is_dir() {
        return Err(refused(dir, "exists and is not a folder"));
    }
    if kind == FolderKind::Run {
        refuse_uploaded_run(dir)?;
    }
    let mut foreign = Vec::new();
    let mut any = false;
    let mut marked = false;
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let entry = entry.map_err(io(dir))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        any = true;
        if name == MARKER {
            marked = true;
            let text = std::fs::read_to_string(entry.path()).unwrap_or_default();
            if text.trim() != kind.name() {
                return Err(refused(
                    dir,
                    format!("is a kincal {} folder, not a {} folder", text.trim(), kind.name()),
                ));
            }
        } else if let Some((_, allowed)) = kind.subfolders().into_iter().find(|(sub, _)| *sub == name) {
            foreign.extend(foreign_in_subfolder(&entry.path(), &name, &allowed)?);
        } else if !kind.writes(&name, entry.path().is_dir()) {
            foreign.push(name);
        }
    }
    if !foreign.is_empty() {
        foreign.sort();
        let shown: Vec<&str> = foreign.iter().take(5).map(String::as_str).collect();
        return Err(refused(
            dir,
            format!(
                "holds files kincal did not write ({}{})",
                shown.join(", "),
                if foreign.len() > 5 { ", …" } else { "" }
            ),
        ));
    }
    if any && !marked && kind.needs_marker() {
        // Session files carry the same names whether simulated or recorded: without kincal's
        // marker the data may be the user's own, so it is never replaced.
        return Err(refused(dir, "holds data kincal did not write (no .kincal-output marker)"));
    }
    Ok(any)
}

/// A RUN whose model was uploaded is never replaced: a controller holds a set that names its
/// hash, and its certificate and upload record would be lost.
fn refuse_uploaded_run(dir: &Path) -> Result<(), OutputError> {
    if !dir.join(crate::trace::UPLOADS_FILE).exists() {
        return Ok(());
    }
    let arms = match crate::trace::read_uploads(dir) {
        Ok(uploads) => {
            let mut arms: Vec<String> = uploads.into_iter().map(|u| u.arm.id).collect();
            arms.dedup();
            format!("arm {}", arms.join(", arm "))
        }
        Err(_) => "a controller".into(),
    };
    Err(refused(
        dir,
        format!(
            "its model was uploaded to {arms} ({}): the stored set names this RUN's hash, so the RUN is kept",
            crate::trace::UPLOADS_FILE
        ),
    ))
}

/// Entries of a sub-folder kincal writes (`cal/` of simulated data) that are not among `allowed`.
fn foreign_in_subfolder(dir: &Path, name: &str, allowed: &[String]) -> Result<Vec<String>, OutputError> {
    if !std::fs::symlink_metadata(dir).map_err(io(dir))?.is_dir() {
        return Ok(vec![name.to_string()]);
    }
    let mut foreign = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io(dir))? {
        let entry = entry.map_err(io(dir))?;
        let file = entry.file_name().to_string_lossy().into_owned();
        if !(allowed.contains(&file) && entry.path().is_file()) {
            foreign.push(format!("{name}/{file}"));
        }
    }
    Ok(foreign)
}

/// A staging folder beside the target; removed on drop unless moved into place.
struct Staged {
    path: PathBuf,
    committed: bool,
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

/// Write the folder `dir` of `kind` through `fill`, which writes into the staging path it gets.
pub fn write_folder(
    dir: &Path,
    kind: FolderKind,
    inputs: &[&Path],
    fill: impl FnOnce(&Path) -> Result<(), OutputError>,
) -> Result<(), OutputError> {
    let existing = check_output_folder(dir, kind, inputs)?;
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(io(parent))?;
    let name = dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let mut staged =
        Staged { path: parent.join(format!(".{name}.partial-{}", std::process::id())), committed: false };
    if staged.path.exists() {
        std::fs::remove_dir_all(&staged.path).map_err(io(&staged.path))?;
    }
    std::fs::create_dir(&staged.path).map_err(io(&staged.path))?;
    fill(&staged.path)?;
    let marker = staged.path.join(MARKER);
    std::fs::write(&marker, kind.name()).map_err(io(&marker))?;
    sync_files(&staged.path)?;
    sync_dir(&staged.path);
    if existing || dir.exists() {
        let old = parent.join(format!(".{name}.old-{}", std::process::id()));
        std::fs::rename(dir, &old).map_err(io(dir))?;
        if let Err(e) = std::fs::rename(&staged.path, dir) {
            let _ = std::fs::rename(&old, dir);
            return Err(io(dir)(e));
        }
        staged.committed = true;
        std::fs::remove_dir_all(&old).map_err(io(&old))?;
    } else {
        std::fs::rename(&staged.path, dir).map_err(io(dir))?;
        staged.committed = true;
    }
    Ok(())
}

/// Flush a folder's entries to disk (best effort: not every file system supports it).
fn sync_dir(dir: &Path) {
    if let Ok(f) = std::fs::File::open(dir) {
        let _ = f.sync_all();
    }
}

/// Write one file into a folder being filled. No temporary name and no sync of its own: the
/// staging folder is invisible under the final name until [`write_folder`] has synced every file
/// in it (all at once, so the disk waits are shared) and renamed it; a full disk shows there.
fn put(dir: &Path, name: &str, bytes: &[u8]) -> Result<(), OutputError> {
    let path = dir.join(name);
    std::fs::write(&path, bytes).map_err(io(&path))
}

/// Flush every file of a staged folder to disk, in parallel (each `fsync` waits for the disk;
/// side by side the waits overlap), naming the first file that fails.
fn sync_files(dir: &Path) -> Result<(), OutputError> {
    use rayon::prelude::*;
    let files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io(dir))?
        .filter_map(|e| e.ok())
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .map(|e| e.path())
        .collect();
    files
        .par_iter()
        .try_for_each(|path| std::fs::File::open(path).and_then(|f| f.sync_all()).map_err(io(path)))
}

/// JSON of a value that serialises by construction (plain structs of numbers and strings).
fn json<T: serde::Serialize>(value: &T) -> String {
    serde_json::to_string_pretty(value).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
}

/// A value written with its format tag in front.
#[derive(serde::Serialize)]
struct Tagged<'a, T: serde::Serialize> {
    format: &'a str,
    #[serde(flatten)]
    body: &'a T,
}

/// `study.json`: the dataset-size study's rows.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StudyFile {
    /// Always [`STUDY_FORMAT`].
    pub format: String,
    /// One row per number of placements.
    pub rows: Vec<StudyRow>,
}

/// The JSON `kincal calibrate --json` prints and `summary.json` holds.
pub fn run_json(run: &Run) -> String {
    json(&run.summary)
}

/// Write RUN/ (model.toml, nominal.toml, summary.json, residuals.json, report.html) as one folder.
pub fn write_run(run: &Run, dir: &Path) -> Result<(), OutputError> {
    let i = &run.summary.inputs;
    let mut inputs = vec![&*i.model, &*i.calibration, &*i.validation];
    inputs.extend(i.artefact.as_deref());
    write_folder(dir, FolderKind::Run, &inputs, |staged| {
        run.calibration.model.save(&staged.join("model.toml"))?;
        run.nominal.save(&staged.join("nominal.toml"))?;
        put(staged, "residuals.json", json(&run.stored_residuals()).as_bytes())?;
        put(staged, "summary.json", run_json(run).as_bytes())?;
        put_run_report(staged, run, dir)
    })
}

/// Write `report.html` of `run` (in `dir`) into `staged` as the page is made, a session's plots at
/// a time: the whole page is megabytes.
fn put_run_report(staged: &Path, run: &Run, dir: &Path) -> Result<(), OutputError> {
    use std::io::Write;
    let path = staged.join("report.html");
    let mut file = std::fs::File::create(&path).map_err(io(&path))?;
    let mut page = String::new();
    report::run::run_report_in_parts(run, dir, &mut page, |text| {
        file.write_all(text.as_bytes())?;
        text.clear();
        Ok(())
    })
    .map_err(io(&path))
}

/// The JSON of a study, as `study.json` holds it.
pub fn study_json(rows: &[StudyRow]) -> String {
    json(&StudyFile { format: STUDY_FORMAT.to_string(), rows: rows.to_vec() })
}

/// Write a study folder (study.json, report.html).
pub fn write_study(rows: &[StudyRow], dir: &Path, inputs: &[&Path]) -> Result<(), OutputError> {
    write_folder(dir, FolderKind::Study, inputs, |staged| {
        put(staged, "study.json", study_json(rows).as_bytes())?;
        put(staged, "report.html", report::study::study_report(rows).as_bytes())
    })
}

/// The JSON of a diagnosis, as `diagnosis.json` holds it.
pub fn diagnosis_json(diagnosis: &Diagnosis) -> String {
    json(&Tagged { format: DIAGNOSIS_FORMAT, body: diagnosis })
}

/// Write `diagnosis.html` and `diagnosis.json` into an existing RUN folder, both or neither; the
/// page spells the next command out from the RUN's `inputs` when given.
pub fn write_diagnosis(
    diagnosis: &Diagnosis,
    run_dir: &Path,
    inputs: Option<&crate::calib::summary::RunInputs>,
) -> Result<(), OutputError> {
    put_together(
        run_dir,
        &[
            ("diagnosis.html", report::diagnosis::diagnosis_report(diagnosis, run_dir, inputs)),
            ("diagnosis.json", diagnosis_json(diagnosis)),
        ],
    )
}

/// Write several files into `dir` so that a failure (a full disk) leaves the old ones, not a mix:
/// every file is first written and synced under a temporary name, then all are renamed.
fn put_together(dir: &Path, files: &[(&str, String)]) -> Result<(), OutputError> {
    let temporary = |name: &str| dir.join(format!(".{name}.tmp-new-{}", std::process::id()));
    for (k, (name, text)) in files.iter().enumerate() {
        if let Err(e) = write_atomic(&temporary(name), text.as_bytes()) {
            for (done, _) in &files[..k] {
                let _ = std::fs::remove_file(temporary(done));
            }
            return Err(io(&dir.join(name))(e));
        }
    }
    for (name, _) in files {
        std::fs::rename(temporary(name), dir.join(name)).map_err(io(&dir.join(name)))?;
    }
    Ok(())
}

/// The JSON of a plan, as `kincal plan --out` writes it.
pub fn plan_json(plan: &crate::calib::plan::Plan) -> String {
    json(&Tagged { format: PLAN_FORMAT, body: plan })
}

/// The pose list of a plan: one row per suggested touch (rivals first, then weak parameters).
pub fn plan_csv(plan: &crate::calib::plan::Plan) -> String {
    let rivals = plan.rivals.iter().flat_map(|r| r.placements.iter().map(|p| ("rivals", p)));
    let weak = plan.weak.placements.iter().map(|p| ("weak", p));
    let all: Vec<(&str, &crate::calib::plan::SuggestedPlacement)> = rivals.chain(weak).collect();
    let joints = all.iter().flat_map(|(_, p)| p.poses_deg.first()).map(|q| q.len()).max().unwrap_or(0);
    let columns: Vec<String> = (1..=joints).map(|j| format!("j{j}_deg")).collect();
    let mut out = format!("{PLAN_CSV_HEADER},{}\n", columns.join(","));
    for (k, (purpose, p)) in all.into_iter().enumerate() {
        let place = match (p.origin_mm, p.yaw_deg) {
            (Some(o), Some(yaw)) => format!("N{},{:.1},{:.1},{:.1},{yaw:.1}", k + 1, o[0], o[1], o[2]),
            _ => format!("{},,,,", p.session.as_deref().unwrap_or("N")),
        };
        for (landmark, pose) in p.landmarks.iter().zip(&p.poses_deg) {
            let angles: Vec<String> = pose.iter().map(|a| format!("{a:.4}")).collect();
            out.push_str(&format!("{purpose},{place},{landmark},{}\n", angles.join(",")));
        }
    }
    out
}

/// Whether a single-file result may go to `path`: a new file, or one holding `own` near its
/// start (one kincal wrote before). Anything else there is refused, never lost.
pub fn check_own_file(path: &Path, own: &str) -> Result<(), OutputError> {
    if path.is_dir() {
        return Err(refused(path, "is a folder"));
    }
    if path.exists() {
        let head = std::fs::read(path).map_err(io(path))?;
        if !String::from_utf8_lossy(&head[..head.len().min(4096)]).contains(own) {
            return Err(refused(path, format!("exists and is not a file kincal wrote ({own})")));
        }
    }
    Ok(())
}

/// Write a single-file result (a plan's JSON or CSV) to `path` after [`check_own_file`].
pub fn write_own_file(path: &Path, text: &str, own: &str) -> Result<(), OutputError> {
    check_own_file(path, own)?;
    write_atomic(path, text.as_bytes()).map_err(io(path))
}

/// The JSON of an auto loop, as `auto.json` holds it.
pub fn auto_json(run: &AutoLoop) -> String {
    json(&Tagged { format: AUTO_FORMAT, body: run })
}

/// Write RUN/auto: each step's model (`step-K.toml`), `auto.json` and the error-by-step page.
pub fn write_auto(run: &AutoLoop, run_dir: &Path) -> Result<(), OutputError> {
    write_folder(&run_dir.join("auto"), FolderKind::Auto, &[], |staged| {
        for (k, model) in run.steps.iter().enumerate().filter_map(|(k, s)| Some((k, s.model.as_ref()?))) {
            model.save(&staged.join(format!("step-{k}.toml")))?;
        }
        put(staged, "auto.json", auto_json(run).as_bytes())?;
        put(staged, "report.html", report::auto::auto_report(run, run_dir).as_bytes())
    })
}

/// The JSON of a haptic calibration, as its `summary.json` holds it.
pub fn haptic_json(summary: &HapticSummary) -> String {
    json(&Tagged { format: HAPTIC_FORMAT, body: summary })
}

/// Write a haptic calibration folder (summary.json, report.html).
pub fn write_haptic(summary: &HapticSummary, dir: &Path, recording: &Path) -> Result<(), OutputError> {
    write_folder(dir, FolderKind::Haptic, &[recording], |staged| {
        put(staged, "summary.json", haptic_json(summary).as_bytes())?;
        put(staged, "report.html", report::haptic::haptic_report(summary, dir).as_bytes())
    })
}

/// The JSON of a dynamic validation, as its `dynamic.json` holds it (with the true error by
/// category when it is known).
pub fn dynamic_json(d: &crate::motion::Dynamic, truth: Option<&[crate::motion::truth::TruthRow]>) -> String {
    #[derive(serde::Serialize)]
    struct WithTruth<'a> {
        #[serde(flatten)]
        result: &'a crate::motion::Dynamic,
        #[serde(skip_serializing_if = "Option::is_none")]
        truth: Option<&'a [crate::motion::truth::TruthRow]>,
    }
    json(&Tagged { format: DYNAMIC_FORMAT, body: &WithTruth { result: d, truth } })
}

/// Write a dynamic validation folder (dynamic.json, report.html) from the recordings `arm` and
/// `tracker`.
pub fn write_dynamic(
    d: &crate::motion::Dynamic,
    truth: Option<&[crate::motion::truth::TruthRow]>,
    dir: &Path,
    arm: &Path,
    tracker: &Path,
) -> Result<(), OutputError> {
    let (arm_name, tracker_name) = (arm.display().to_string(), tracker.display().to_string());
    let inputs = report::dynamic::PageInputs { arm: &arm_name, tracker: &tracker_name };
    write_folder(dir, FolderKind::Dynamic, &[arm, tracker], |staged| {
        put(staged, "dynamic.json", dynamic_json(d, truth).as_bytes())?;
        put(staged, "report.html", report::dynamic::dynamic_report(d, &inputs, truth).as_bytes())
    })
}

/// Write a single HTML page kincal made (the compare page) whose `<title>` is `title`. An existing
/// file is replaced only when it is such a page; a page inside a folder kincal writes is refused.
pub fn write_page(path: &Path, title: &str, html: &str) -> Result<(), OutputError> {
    if path.is_dir() {
        return Err(refused(path, "is a folder; give a file name such as compare.html"));
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    if parent.join(MARKER).exists() {
        return Err(refused(
            path,
            "is inside a folder kincal writes (a RUN, a study …): the page would replace its files or be lost with the folder; write it beside the folder",
        ));
    }
    if path.exists() {
        let head = std::fs::read(path).map_err(io(path))?;
        let head = String::from_utf8_lossy(&head[..head.len().min(4096)]).into_owned();
        if !(head.starts_with("<!doctype html>") && head.contains(title)) {
            return Err(refused(path, format!("exists and is not a page kincal wrote (no \"{title}\")")));
        }
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(io(parent))?;
    }
    write_atomic(path, html.as_bytes()).map_err(io(path))
}

/// Write a simulated haptic recording (recording.json and one folder per step) as one folder.
pub fn write_haptic_recording(
    recording: &crate::haptic::recording::Recording,
    dir: &Path,
) -> Result<(), OutputError> {
    write_folder(dir, FolderKind::HapticRecording, &[], |staged| {
        crate::haptic::simulate::write_recording(recording, staged).map_err(io(staged))
    })
}

/// Write simulated data (artefact.json, truth.toml, cal/, val/) as one folder.
pub fn write_simulation(sim: &crate::simulate::SimulatedData, dir: &Path) -> Result<(), OutputError> {
    write_folder(dir, FolderKind::Simulation, &[], |staged| Ok(sim.write(staged)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-output-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn files(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn a_folder_with_the_users_files_is_refused_and_left_as_it_was() {
        let dir = scratch("foreign");
        let out = dir.join("run");
        std::fs::create_dir_all(&out).unwrap();
        std::fs::write(out.join("thesis.docx"), b"years of work").unwrap();
        let result = write_folder(&out, FolderKind::Run, &[], |s| put(s, "summary.json", b"{}"));
        let message = result.unwrap_err().to_string();
        assert!(message.contains("thesis.docx"), "{message}");
        assert_eq!(files(&out), ["thesis.docx"]);
        assert_eq!(files(&dir), ["run"], "no staging folder left behind");
    }

    #[test]
    fn a_folder_kincal_wrote_is_replaced_whole() {
        let dir = scratch("replace");
        let out = dir.join("run");
        write_folder(&out, FolderKind::Run, &[], |s| put(s, "report.html", b"old")).unwrap();
        write_folder(&out, FolderKind::Run, &[], |s| put(s, "summary.json", b"new")).unwrap();
        assert_eq!(files(&out), [MARKER, "summary.json"]);
        assert_eq!(files(&dir), ["run"]);
    }

    #[test]
    fn a_failure_while_filling_leaves_nothing_and_keeps_the_old_folder() {
        let dir = scratch("fail");
        let out = dir.join("run");
        write_folder(&out, FolderKind::Run, &[], |s| put(s, "report.html", b"old")).unwrap();
        let failed = write_folder(&out, FolderKind::Run, &[], |s| {
            put(s, "summary.json", b"half")?;
            Err(OutputError::Io { path: s.to_owned(), source: std::io::Error::other("disk full") })
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read(out.join("report.html")).unwrap(), b"old");
        assert_eq!(files(&dir), ["run"]);
    }

    #[test]
    fn dot_a_file_and_a_folder_holding_an_input_are_refused() {
        let dir = scratch("refuse");
        let file = dir.join("notes.txt");
        std::fs::write(&file, b"mine").unwrap();
        for bad in [Path::new("."), Path::new(".."), file.as_path()] {
            assert!(matches!(
                write_folder(bad, FolderKind::Study, &[], |_| Ok(())),
                Err(OutputError::Refused { .. })
            ));
        }
        assert_eq!(std::fs::read(&file).unwrap(), b"mine");
        let data = dir.join("data");
        std::fs::create_dir_all(data.join("cal")).unwrap();
        let input = data.join("cal");
        let refused = write_folder(&data, FolderKind::Run, &[&input], |_| Ok(())).unwrap_err();
        assert!(refused.to_string().contains("contains the input"), "{refused}");
    }

    #[test]
    fn a_page_the_user_wrote_or_a_runs_report_is_not_overwritten() {
        const T: &str = "<title>kincal compare</title>";
        let dir = scratch("page");
        let page = dir.join("compare.html");
        std::fs::write(&page, b"<html>my notes</html>").unwrap();
        assert!(write_page(&page, T, "<!doctype html><title>kincal compare</title>").is_err());
        assert_eq!(std::fs::read(&page).unwrap(), b"<html>my notes</html>");
        std::fs::remove_file(&page).unwrap();
        write_page(&page, T, "<!doctype html><html><head><title>kincal compare</title>").unwrap();
        write_page(&page, T, "<!doctype html><html><head><title>kincal compare</title>2").unwrap();
        let run = dir.join("run");
        write_folder(&run, FolderKind::Run, &[], |s| put(s, "report.html", b"calibration")).unwrap();
        assert!(
            write_page(&run.join("report.html"), T, "<!doctype html><title>kincal compare</title>").is_err()
        );
        assert_eq!(std::fs::read(run.join("report.html")).unwrap(), b"calibration");
    }
}
