//! The whole loop on a controller with an emulated arm: record calibration and validation
//! placements (the arm posed by inverse kinematics of a "true" arm at every landmark, which
//! carries a hidden physical effect the nominal model lacks), calibrate, diagnose (name the
//! missing effect), add it and calibrate again (the validation error falls to the floor),
//! upload, stream the calibrated pose and measure its error against the truth — nominal vs
//! calibrated.
//!
//! Absolute pose error includes what no artefact touch can observe (rotation about and shift
//! along the base axis, the tool length with a vertical tool): the pose error is therefore taken
//! after a rigid registration of the streamed tool points to the true ones, as a navigation
//! system registers the tracker to the patient.

use crate::calib::diagnose::auto::{auto_loop, AutoLoop, Stop};
use crate::calib::diagnose::{diagnose, DiagnoseError};
use crate::calib::run::{run, Run, RunError};
use crate::calib::setup::SolveOptions;
use crate::calib::summary::RunInputs;
use crate::controller::link::{Link, LinkError};
use crate::controller::record::{record, Guide, Plan, Quality, RecordError, Step, Verdict};
use crate::controller::signing::StationKey;
use crate::data::Artefact;
use crate::model::{ArmModel, ParamId};
use crate::numerics::geometry::absolute_orientation;
use crate::simulate::{
    calibration_placements, perturbed_truth, reference_tool_frame, suta_artefact, touch_encoders,
    validation_placements, Placement, SimulationOptions,
};
use kincal_protocol::biss::{counts_to_deg, deg_to_counts};
use kincal_protocol::messages::{PoseReport, SimFaults, SimSetPose, StreamPose};
use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Settings of the loop.
#[derive(Clone, Debug)]
pub struct LoopOptions {
    /// Seed of the true arm, the artefact and the noise.
    pub seed: u64,
    /// Window per touch, ticks (1536 = 2 s as on the real arm; fewer to go faster).
    pub window_ticks: u16,
    /// Repeats of every landmark per placement.
    pub repeats: u32,
    /// Seating noise of the tip, mm (standard deviation per axis).
    pub seating_noise_mm: f64,
    /// Emulated encoder noise, counts (standard deviation).
    pub encoder_noise_counts: u16,
    /// Calibration placements used (of the thesis' five).
    pub calibration_placements: usize,
    /// The physical effect the emulated arm has and the nominal model lacks: parameter deltas
    /// added to the true arm ([`DEMO_HIDDEN`] by default).
    pub hidden: Vec<(ParamId, f64)>,
    /// Where data and the run go.
    pub out: PathBuf,
    /// Days the uploaded calibration stays valid, from its validation (`None`: no period).
    pub valid_days: Option<u32>,
}

/// The demo arm's hidden effect: joint 2 sags under gravity by 0.3°/m of lever (compliance of
/// the shoulder), which the thesis' 13-parameter model does not have.
pub const DEMO_HIDDEN: (ParamId, f64) = (ParamId::Compliance(1), 0.3);

/// Effects the demo's diagnose → add loop may add at most.
pub const MAX_ADDED: usize = 3;

impl Default for LoopOptions {
    fn default() -> Self {
        LoopOptions {
            seed: 1,
            window_ticks: 96,
            repeats: 3,
            seating_noise_mm: 0.1,
            encoder_noise_counts: 3,
            calibration_placements: 5,
            hidden: vec![DEMO_HIDDEN],
            out: PathBuf::from("runs/loop"),
            valid_days: Some(365),
        }
    }
}

/// Why the loop stopped.
#[derive(Debug, thiserror::Error)]
pub enum LoopError {
    /// Talking to the controller failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// Recording failed.
    #[error(transparent)]
    Record(#[from] RecordError),
    /// Calibration failed.
    #[error(transparent)]
    Run(#[from] RunError),
    /// The RUN folder could not be written.
    #[error(transparent)]
    Output(#[from] crate::store::OutputError),
    /// A parameter set is outside what the controller accepts.
    #[error(transparent)]
    Params(#[from] crate::controller::device::DeviceParamsError),
    /// The diagnose → add loop could not recalibrate.
    #[error("diagnose → add: {0}")]
    Added(#[from] DiagnoseError),
    /// The demo's station key could not be made or read.
    #[error(transparent)]
    Key(#[from] crate::controller::signing::KeyFileError),
    /// Writing the inputs failed.
    #[error("{0}")]
    Files(String),
}

/// One step of diagnose → add: what was added and where the validation error is.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MissionStep {
    /// What was applied at this step (`None` for the model as given).
    pub added: Option<String>,
    /// Validation distance RMS of this step's calibrated model, mm.
    pub validation_rms_mm: f64,
    /// Validation RMS expected from repeatability for this model (the estimated floor), mm.
    pub expected_floor_mm: Option<f64>,
    /// Held-out p-value of the effect added.
    pub p_value: Option<f64>,
}

/// Calibrate → diagnose → add → calibrate again, as the user runs it.
pub struct Mission {
    /// The run of the model as given (`OUT/run`).
    pub first: Run,
    /// The diagnose → add loop from it (`OUT/run/auto`); its steps in [`Mission::steps`].
    pub auto: AutoLoop,
    /// The run with the added effects (`OUT/run-added`), or the first run when none was added.
    pub last: Option<Run>,
    /// Every step, the model as given first.
    pub steps: Vec<MissionStep>,
    /// Changes applied, in order.
    pub added: Vec<String>,
}

impl Mission {
    /// The run whose model goes to the controller: with the added effects when there are any.
    pub fn final_run(&self) -> &Run {
        self.last.as_ref().unwrap_or(&self.first)
    }
}

/// Calibrate `inputs`, diagnose the run and add what it names until the validation error is at
/// the floor (at most [`MAX_ADDED`] effects), then calibrate again with those effects as
/// `kincal calibrate … --add EFFECT` would: `out/run` (with `run/auto` and `run/diagnosis.*`)
/// and `out/run-added`.
pub fn calibrate_diagnose_add(
    inputs: &RunInputs,
    options: &SolveOptions,
    out: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<Mission, LoopError> {
    progress("calibrating the model as given");
    let first = run(inputs, options, 0, true)?;
    crate::store::write_run(&first, &out.join("run"))?;
    progress("diagnosing, adding what the diagnosis names, recalibrating");
    let (cal, val) = inputs.read_folders()?;
    let cal = inputs.exclude(cal, val)?.0;
    let setup = inputs.setup(options);
    let val = &first.validation_data;
    let auto = auto_loop(&setup, &first.calibration.model, &cal, val, MAX_ADDED)?;
    crate::store::write_auto(&auto, &out.join("run"))?;
    let first_diagnosis = diagnose(&setup, &first.calibration.model, &cal, val)?;
    crate::store::write_diagnosis(&first_diagnosis, &out.join("run"), Some(inputs))?;
    let steps = auto
        .steps
        .iter()
        .map(|s| MissionStep {
            added: s.applied.clone(),
            validation_rms_mm: s.held_out_rms_mm,
            expected_floor_mm: s.expected_rms_mm,
            p_value: s.p_value,
        })
        .collect();
    let added: Vec<String> = auto.steps.iter().filter_map(|s| s.applied.clone()).collect();
    let last = if added.is_empty() {
        None
    } else {
        progress(&format!("calibrating with {} added", added.join(", ")));
        let last = run(&inputs.with_changes(&auto.setup), options, 0, true)?;
        crate::store::write_run(&last, &out.join("run-added"))?;
        Some(last)
    };
    Ok(Mission { first, auto, last, steps, added })
}

/// Why the diagnose → add loop stopped, in words.
pub fn stop_words(stop: &Stop) -> String {
    match stop {
        Stop::AtFloor => "at the noise floor".into(),
        Stop::CannotTell => {
            "nothing significant, and these data cannot tell whether anything is missing".into()
        }
        Stop::NothingSignificant => "nothing more is significant".into(),
        Stop::DataError(name) => format!("a data error must be fixed first ({name})"),
        Stop::StepLimit => format!("step limit ({MAX_ADDED} effects)"),
    }
}

/// The demo's own station key, `OUT/station.key`: made on the first run, reused after.
pub fn demo_station_key(out: &std::path::Path) -> Result<StationKey, LoopError> {
    let path = out.join("station.key");
    if path.exists() {
        return Ok(StationKey::load(&path)?.key);
    }
    std::fs::create_dir_all(out).map_err(|e| LoopError::Files(format!("{}: {e}", out.display())))?;
    Ok(StationKey::create(&path)?)
}

/// Drop the upload records (`uploads.json`) of an earlier demo's runs in `out`: the sets they
/// record were stored on an emulated controller that ended with that demo, so no controller holds
/// them and the new demo may replace those runs (a RUN whose set a controller may hold is never
/// replaced; [`crate::store::check_output_folder`]).
pub fn forget_emulated_uploads(out: &Path) -> Result<(), LoopError> {
    for run in ["run", "run-added"] {
        let path = out.join(run).join(crate::trace::UPLOADS_FILE);
        match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(LoopError::Files(format!("{}: {e}", path.display())))
            }
            _ => {}
        }
    }
    Ok(())
}

/// The demo's true arm for `seed`: `nominal` off by the simulation's perturbation, with the
/// demo's hidden effect ([`DEMO_HIDDEN`]).
pub fn demo_truth(nominal: &ArmModel, seed: u64) -> ArmModel {
    true_arm(nominal, seed, &[DEMO_HIDDEN], &mut ChaCha8Rng::seed_from_u64(seed))
}

/// `nominal` off by the simulation's perturbation (drawn from `rng`), plus the `hidden` deltas.
fn true_arm(nominal: &ArmModel, seed: u64, hidden: &[(ParamId, f64)], rng: &mut ChaCha8Rng) -> ArmModel {
    let sim = SimulationOptions { seed, ..SimulationOptions::default() };
    let mut truth = perturbed_truth(nominal, &sim, rng);
    for (id, delta) in hidden {
        truth.set(*id, truth.get(*id) + delta);
    }
    truth
}

/// Sign `model` with `key` as the next parameter version for the controller on `link`, with
/// `trace` (its RUN's hash, validation date and validity) when given, and upload it; returns the
/// signed set.
pub fn upload_model(
    link: &mut Link,
    model: &ArmModel,
    key: &StationKey,
    trace: Option<&kincal_protocol::signed::SetTrace>,
) -> Result<Vec<u8>, LoopError> {
    let info = link.info()?;
    let version = info.param_version + 1;
    let set = match trace {
        Some(trace) => {
            crate::controller::device::traced_parameter_set(model, version, &info.arm_id, key, trace)?
        }
        None => crate::controller::device::signed_parameter_set(model, version, &info.arm_id, key)?,
    };
    link.upload(&set)?;
    Ok(set)
}

/// What the loop measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct LoopReport {
    /// Touches recorded (calibration + validation).
    pub touches: usize,
    /// Validation distance RMS of the nominal model, mm.
    pub nominal_validation_rms_mm: f64,
    /// Validation distance RMS of the calibrated model (with the effects the diagnosis
    /// added), mm.
    pub calibrated_validation_rms_mm: f64,
    /// The hidden effect of the emulated arm (parameter = delta).
    pub hidden: Vec<String>,
    /// Calibrate → diagnose → add, step by step (the model as given first).
    pub steps: Vec<MissionStep>,
    /// Effects the diagnosis named and the loop added, in order.
    pub added: Vec<String>,
    /// Why the diagnose → add loop stopped.
    pub stop: String,
    /// The diagnosis of the model as given, in words (names the missing effect).
    pub diagnosis: Vec<String>,
    /// Validation distance RMS of the true arm on the same recorded data: the noise floor, mm.
    pub truth_validation_rms_mm: f64,
    /// Pose error the host predicts for the calibrated model at the same touches, mm.
    pub host_calibrated_pose_rms_mm: f64,
    /// Pose error streamed by the controller with the nominal parameters (RMS after rigid
    /// registration to the true tool points), mm.
    pub nominal_pose_rms_mm: f64,
    /// The same with the calibrated parameters, mm.
    pub calibrated_pose_rms_mm: f64,
    /// The same with the true arm's parameters uploaded: what encoder noise and the controller's
    /// arithmetic alone leave (the floor), mm.
    pub floor_pose_rms_mm: f64,
    /// Poses compared.
    pub poses: usize,
    /// Time to upload one parameter set, s.
    pub upload_seconds: f64,
    /// The RUN whose model was uploaded last (its hash signed with it, the upload recorded in it).
    pub uploaded_run: PathBuf,
    /// Wall time of the whole loop, s.
    pub seconds: f64,
}

fn counts_of(enc_deg: &[f64; 6]) -> [u32; 6] {
    enc_deg.map(deg_to_counts)
}

fn degrees_of(counts: &[u32; 6]) -> [f64; 6] {
    counts.map(|c| counts_to_deg(c as f64))
}

/// Poses the emulated arm by inverse kinematics of the true arm, with seating noise.
struct PosingGuide<'a> {
    truth: &'a ArmModel,
    artefact: &'a Artefact,
    place: Placement,
    rng: &'a mut ChaCha8Rng,
    seat: Normal<f64>,
}

impl Guide for PosingGuide<'_> {
    fn approach(&mut self, link: &mut Link, landmark: &str, _repeat: u32) -> Result<Step, RecordError> {
        let Some(l) = self.artefact.landmarks.iter().find(|l| l.id == landmark) else {
            return Ok(Step::Skip);
        };
        let noise =
            Vector3::new(self.seat.sample(self.rng), self.seat.sample(self.rng), self.seat.sample(self.rng));
        let Some(enc) = touch_encoders(self.truth, &self.place, l, noise, self.rng) else {
            return Ok(Step::Skip);
        };
        link.call(SimSetPose { counts: counts_of(&enc) })?;
        Ok(Step::Measure)
    }

    fn accept(&mut self, _landmark: &str, _m: &crate::data::Measurement, _q: &Quality) -> Verdict {
        Verdict::Accept
    }
}

/// Average the controller's streamed tool point over `frames` pose frames at `counts`.
fn streamed_point(link: &mut Link, counts: [u32; 6], frames: usize) -> Result<Vector3<f64>, LinkError> {
    link.call(SimSetPose { counts })?;
    link.call(StreamPose { divider: 1 })?;
    link.clear_streams();
    let mut sum = Vector3::zeros();
    let mut n = 0;
    let deadline = Instant::now() + Duration::from_secs(5);
    while n < frames && Instant::now() < deadline {
        if let Some((_, p)) = link.next_on::<PoseReport>(Duration::from_millis(100))? {
            if !p.valid {
                continue; // a joint's frame was rejected this tick: no position
            }
            sum += Vector3::new(p.position_mm[0] as f64, p.position_mm[1] as f64, p.position_mm[2] as f64);
            n += 1;
        }
    }
    link.call(StreamPose { divider: 0 })?;
    if n == 0 {
        return Err(LinkError::Timeout(Duration::from_secs(5), "pose frames"));
    }
    Ok(sum / n as f64)
}

fn registered_rms(measured: &[Vector3<f64>], truth: &[Vector3<f64>]) -> f64 {
    let (r, t) = absolute_orientation(measured, truth);
    let sum: f64 = measured.iter().zip(truth).map(|(m, q)| (r * m + t - q).norm_squared()).sum();
    (sum / measured.len().max(1) as f64).sqrt()
}

/// The demo's data folder resumes an interrupted demo (recording never measures a landmark
/// twice), so it must hold this demo's data and nothing else: an existing folder is used only
/// when its `demo.json` names the same seed; a new one gets that stamp.
fn claim_data_folder(data: &std::path::Path, seed: u64) -> Result<(), LoopError> {
    let stamp = data.join("demo.json");
    let occupied = std::fs::read_dir(data).map(|mut d| d.next().is_some()).unwrap_or(false);
    if occupied {
        let found = std::fs::read_to_string(&stamp)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["seed"].as_u64());
        if found != Some(seed) {
            let what = found.map_or("files that are not a kincal demo's".to_string(), |s| {
                format!("the demo data of seed {s}")
            });
            return Err(LoopError::Files(format!(
                "{}: holds {what}, not this demo's (seed {seed}); choose another --out or remove the folder",
                data.display()
            )));
        }
    }
    std::fs::create_dir_all(data).map_err(|e| LoopError::Files(format!("{}: {e}", data.display())))?;
    let text = serde_json::json!({ "format": "kincal-demo/1", "seed": seed }).to_string();
    crate::files::write_atomic(&stamp, text.as_bytes())
        .map_err(|e| LoopError::Files(format!("{}: {e}", stamp.display())))
}

/// Run the loop on `link` (greeted) with `nominal` as the model to calibrate.
pub fn run_loop(
    link: &mut Link,
    nominal: &ArmModel,
    options: &LoopOptions,
    progress: &mut dyn FnMut(&str),
) -> Result<LoopReport, LoopError> {
    let started = Instant::now();
    let files = |e: &dyn std::fmt::Display| LoopError::Files(e.to_string());
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let truth = true_arm(nominal, options.seed, &options.hidden, &mut rng);
    // A simulated artefact has no calibration lab's certificate; its reference says so.
    let artefact = Artefact {
        certificate: Some(format!("none: simulated by kincal demo, seed {}", options.seed)),
        ..suta_artefact(&mut rng)
    };
    let data = options.out.join("data");
    claim_data_folder(&data, options.seed)?;
    artefact.save(&data.join("artefact.json")).map_err(|e| files(&e))?;
    truth.save(&data.join("truth.toml")).map_err(|e| files(&e))?;
    nominal.save(&data.join("nominal.toml")).map_err(|e| files(&e))?;
    link.call(SimFaults { noise_counts: options.encoder_noise_counts, ..SimFaults::default() })?;
    let seat = Normal::new(0.0, options.seating_noise_mm.max(0.0)).map_err(|e| files(&e))?;
    let order: Vec<String> = artefact.landmarks.iter().map(|l| l.id.clone()).collect();
    let mut touches = 0;
    let groups = [
        (
            "calibration",
            "cal",
            calibration_placements().into_iter().take(options.calibration_placements).collect::<Vec<_>>(),
        ),
        ("validation", "val", validation_placements()),
    ];
    for (purpose, folder, places) in groups {
        for place in places {
            progress(&format!(
                "recording {purpose} placement {} ({} landmarks × {} repeats)",
                place.name,
                order.len(),
                options.repeats
            ));
            let plan = Plan {
                placement: place.name.clone(),
                purpose: purpose.into(),
                order: order.clone(),
                repeats: options.repeats,
                window_ticks: options.window_ticks,
                out: data.join(folder),
            };
            let mut guide = PosingGuide { truth: &truth, artefact: &artefact, place, rng: &mut rng, seat };
            let done = record(link, &artefact, &plan, &mut guide)?;
            touches += done.measured + done.resumed;
        }
    }
    let inputs = RunInputs::new(
        data.join("nominal.toml"),
        Some(data.join("artefact.json")),
        data.join("cal"),
        data.join("val"),
    );
    let calibration = SolveOptions { seed: options.seed, ..SolveOptions::default() };
    let mission = calibrate_diagnose_add(&inputs, &calibration, &options.out, progress)?;
    let result = mission.final_run();
    // Pose check at one noise-free touch of every landmark of every validation placement.
    let mut check_counts = Vec::new();
    for place in validation_placements() {
        for l in &artefact.landmarks {
            if let Some(enc) = touch_encoders(&truth, &place, l, Vector3::zeros(), &mut rng) {
                check_counts.push(counts_of(&enc));
            }
        }
    }
    let truth_points: Vec<Vector3<f64>> = check_counts
        .iter()
        .map(|c| reference_tool_frame(&truth, &degrees_of(c)).0.fixed_view::<3, 1>(0, 3).into_owned())
        .collect();
    let key = demo_station_key(&options.out)?;
    // Each set is signed for the connected arm; the calibrated one carries its RUN's hash and
    // date, and the RUN records the upload, as `kincal upload RUN/model.toml` does.
    let mut pose_rms = |model: &ArmModel,
                        label: &str,
                        run: Option<&Path>,
                        link: &mut Link|
     -> Result<(f64, f64), LoopError> {
        progress(&format!(
            "uploading the {label} parameters and streaming the pose at {} validation touches",
            check_counts.len()
        ));
        let t = Instant::now();
        let origin = match run {
            Some(run) => crate::trace::run_origin(&run.join("model.toml")).map_err(|e| files(&e))?,
            None => None,
        };
        let trace = match &origin {
            Some(origin) => Some(
                crate::controller::traceability::upload_trace(
                    Path::new(""),
                    Some(origin),
                    options.valid_days,
                    crate::controller::traceability::unix_now(),
                )
                .map_err(|e| files(&e))?,
            ),
            None => None,
        };
        let set = upload_model(link, model, &key, trace.as_ref())?;
        let upload = t.elapsed().as_secs_f64();
        if let Some(origin) = &origin {
            let arm = crate::controller::record::connected_arm(link)?;
            if let Some(record) = crate::controller::traceability::upload_record(&arm, &set) {
                crate::trace::record_upload(&origin.run, &record).map_err(|e| files(&e))?;
            }
        }
        let points =
            check_counts.iter().map(|c| streamed_point(link, *c, 8)).collect::<Result<Vec<_>, _>>()?;
        Ok((registered_rms(&points, &truth_points), upload))
    };
    let (nominal_pose, _) = pose_rms(nominal, "nominal", None, link)?;
    let (floor_pose, _) = pose_rms(&truth, "true arm's", None, link)?;
    let final_run = options.out.join(if mission.last.is_some() { "run-added" } else { "run" });
    let (calibrated_pose, upload_seconds) =
        pose_rms(&result.calibration.model, "calibrated", Some(&final_run), link)?;
    let host_points: Vec<Vector3<f64>> = check_counts
        .iter()
        .map(|c| crate::model::kinematics::tool_pose(&result.calibration.model, &degrees_of(c)).position_mm)
        .collect();
    let truth_validation = crate::calib::validate::validate(&truth, &result.validation_data).overall.rms_mm;
    Ok(LoopReport {
        hidden: options.hidden.iter().map(|(id, d)| format!("{id} = {d:+}")).collect(),
        steps: mission.steps.clone(),
        added: mission.added.clone(),
        stop: stop_words(&mission.auto.stop),
        diagnosis: mission.auto.steps.first().map(|s| s.summary.clone()).unwrap_or_default(),
        truth_validation_rms_mm: truth_validation,
        host_calibrated_pose_rms_mm: registered_rms(&host_points, &truth_points),
        touches,
        nominal_validation_rms_mm: mission.first.summary.nominal_held_out_rms_mm(),
        calibrated_validation_rms_mm: result.summary.held_out_rms_mm(),
        nominal_pose_rms_mm: nominal_pose,
        calibrated_pose_rms_mm: calibrated_pose,
        floor_pose_rms_mm: floor_pose,
        poses: check_counts.len(),
        upload_seconds,
        uploaded_run: final_run,
        seconds: started.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::claim_data_folder;

    #[test]
    fn the_data_folder_resumes_only_the_same_demo() {
        let dir = std::env::temp_dir().join(format!("kincal-demo-claim-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let data = dir.join("data");
        claim_data_folder(&data, 1).expect("a new folder is claimed");
        claim_data_folder(&data, 1).expect("the same demo resumes");
        let other = claim_data_folder(&data, 2).unwrap_err().to_string();
        assert!(other.contains("seed 1") && other.contains("seed 2"), "{other}");
        let mine = dir.join("mine");
        std::fs::create_dir_all(&mine).unwrap();
        std::fs::write(mine.join("notes.txt"), b"mine").unwrap();
        let refused = claim_data_folder(&mine, 1).unwrap_err().to_string();
        assert!(refused.contains("not a kincal demo"), "{refused}");
        assert_eq!(std::fs::read(mine.join("notes.txt")).unwrap(), b"mine");
        std::fs::remove_dir_all(&dir).ok();
    }
}
