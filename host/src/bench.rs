//! `kincal bench`: figures for the speed targets, printed, never asserted.
//!
//! * one calibration of a thesis-sized problem (5 placements × 15 landmarks × 3 repeats,
//!   13 parameters, 8 random restarts) on one core;
//! * the 1000-calibration dataset-size study on every core;
//! * SciPy `least_squares(method='trf', loss='huber')` on the same problem from the same start
//!   (`bench/scipy_peer.py`), with the cost and time ratio.

use crate::calibrate::{calibrate, CalibrationOptions};
use crate::data::{Artefact, Dataset};
use crate::model::{ArmModel, ParamId};
use crate::simulate::{simulate, SimulatedData, SimulationOptions};
use crate::study::{study, StudyOptions};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of `kincal bench`.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchArgs {
    /// Timed repetitions of the single calibration.
    #[arg(long, default_value_t = 20)]
    pub repeats: usize,
    /// Random subsets per placement count in the study (5 counts × 200 = 1000 calibrations).
    #[arg(long, default_value_t = 200)]
    pub study_subsets: usize,
    /// Python interpreter with SciPy for the peer run.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// Skip the SciPy peer.
    #[arg(long)]
    pub no_scipy: bool,
}

/// Why a benchmark or peer run failed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// A file could not be written or read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// The peer script failed or printed something unexpected.
    #[error("SciPy peer: {0}")]
    Peer(String),
    /// The calibration could not run.
    #[error(transparent)]
    Calibration(#[from] crate::calibrate::CalibrationError),
}

/// What the SciPy peer reports.
#[derive(Clone, Debug, serde::Deserialize)]
pub struct PeerResult {
    /// SciPy's cost ½C²Σρ((f/C)²), equal to kincal's Σρ.
    pub cost: f64,
    /// Parameters reached.
    pub x: Vec<f64>,
    /// Wall time of `least_squares`, seconds.
    pub seconds: f64,
    /// Residual evaluations.
    pub nfev: usize,
}

/// The thesis-sized simulated problem used by the benchmarks and the peer test.
pub fn thesis_sized_problem(seed: u64) -> (ArmModel, SimulatedData) {
    let nominal = ArmModel::suta_nominal();
    let data = simulate(&nominal, &SimulationOptions { seed, ..SimulationOptions::default() });
    (nominal, data)
}

/// Write the peer problem file for `params` starting at the nominal values.
pub fn write_peer_problem(
    path: &Path,
    nominal: &ArmModel,
    params: &[ParamId],
    artefact: &Artefact,
    data: &Dataset,
    huber_delta_mm: f64,
) -> Result<(), BenchError> {
    let bounds: Vec<_> = params
        .iter()
        .map(|id| {
            nominal
                .free
                .iter()
                .find(|f| f.id == *id)
                .map_or((f64::NEG_INFINITY, f64::INFINITY), |f| (f.lower, f.upper))
        })
        .collect();
    let model: serde_json::Value =
        serde_json::from_str(&nominal.to_text(true)).map_err(|e| BenchError::Peer(e.to_string()))?;
    let problem = serde_json::json!({
        "model": model,
        "landmarks_mm": artefact.landmarks.iter().map(|l| l.xyz_mm).collect::<Vec<_>>(),
        "touches": data.touches.iter().map(|t| serde_json::json!({"placement": t.placement, "landmark": t.landmark, "repeat": t.repeat, "enc_deg": t.enc_deg})).collect::<Vec<_>>(),
        "params": params.iter().map(|p| p.to_string()).collect::<Vec<_>>(),
        "x0": params.iter().map(|p| nominal.get(*p)).collect::<Vec<_>>(),
        "lower": bounds.iter().map(|b| b.0).collect::<Vec<_>>(),
        "upper": bounds.iter().map(|b| b.1).collect::<Vec<_>>(),
        "huber_delta_mm": huber_delta_mm,
    });
    std::fs::write(path, problem.to_string())
        .map_err(|source| BenchError::Io { path: path.to_owned(), source })
}

/// The peer script's path in the source tree.
pub fn peer_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/scipy_peer.py")
}

/// Run the SciPy peer on a problem file.
pub fn run_peer(python: &str, problem: &Path) -> Result<PeerResult, BenchError> {
    let output = std::process::Command::new(python)
        .arg(peer_script())
        .arg(problem)
        .output()
        .map_err(|e| BenchError::Peer(format!("could not start {python}: {e}")))?;
    if !output.status.success() {
        return Err(BenchError::Peer(format!(
            "{} failed: {}",
            peer_script().display(),
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    serde_json::from_slice(&output.stdout).map_err(|e| {
        BenchError::Peer(format!("unexpected output ({e}): {}", String::from_utf8_lossy(&output.stdout)))
    })
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Run every benchmark and print the figures.
pub fn run_benchmarks(args: &BenchArgs) -> Result<(), BenchError> {
    let (nominal, sim) = thesis_sized_problem(1);
    let cal = Dataset::from_sessions(&sim.calibration, &sim.artefact);
    let val = Dataset::from_sessions(&sim.validation, &sim.artefact);
    let options = CalibrationOptions::default();
    println!("thesis-sized problem: {} placements, {} touches, {} pairs, {} free parameters, {} restarts + nominal start", cal.placements.len(), cal.touches.len(), cal.touch_pairs().len(), nominal.free.len(), options.restarts);
    let mut times = Vec::new();
    let mut fit = None;
    for _ in 0..args.repeats.max(1) {
        let t = Instant::now();
        fit = Some(calibrate(&nominal, &sim.artefact, &cal, &options)?);
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let single_ms = median(times.clone());
    println!("one calibration (one core):        median {single_ms:.1} ms, min {:.1} ms over {} runs  (target <= 50 ms)", times.iter().cloned().fold(f64::INFINITY, f64::min), times.len());
    let study_options = StudyOptions {
        subsets: args.study_subsets,
        seed: 1,
        calibration: CalibrationOptions { restarts: 0, ..options },
        progress: false,
    };
    let t = Instant::now();
    let rows = study(&nominal, &sim.artefact, &cal, &val, &study_options);
    let study_s = t.elapsed().as_secs_f64();
    let count: usize = rows.iter().map(|r| r.calibrations + r.failed).sum();
    println!(
        "study: {count} calibrations on {} threads: {study_s:.2} s  (target <= 10 s on 2 cores)",
        rayon::current_num_threads()
    );
    let hidden = SimulationOptions {
        seed: 1,
        hidden: vec![(ParamId::EccSin(4), 0.2), (ParamId::EccCos(4), -0.1)],
        ..SimulationOptions::default()
    };
    let sim_hidden = simulate(&nominal, &hidden);
    let (cal_h, val_h) = (
        Dataset::from_sessions(&sim_hidden.calibration, &sim_hidden.artefact),
        Dataset::from_sessions(&sim_hidden.validation, &sim_hidden.artefact),
    );
    let fit_h = calibrate(&nominal, &sim_hidden.artefact, &cal_h, &options)?;
    let t = Instant::now();
    let diagnosis = crate::diagnose::diagnose(&fit_h.model, &sim_hidden.artefact, &cal_h, &val_h, &options);
    println!("diagnose, whole library ({} candidates scored, {} not identifiable), {} threads: {:.2} s  (target <= 2 s on 2 cores)", diagnosis.candidates.len(), diagnosis.not_identifiable.len(), rayon::current_num_threads(), t.elapsed().as_secs_f64());
    // Haptic: a 5-minute recording (100 s of fixed steps + 200 s of free motion).
    let (recording, _) =
        crate::haptic::simulate::simulate_recording(&crate::haptic::simulate::HapticSimOptions {
            joints_seconds: 200.0,
            ..Default::default()
        });
    let t = Instant::now();
    match crate::haptic::pipeline::calibrate_recording(&recording) {
        Ok(h) => println!("haptic pipeline on a 5-minute recording: {:.2} s  (target <= 1 s); delay {:.2} ms, position {:.3} mm, orientation {:.3} deg", t.elapsed().as_secs_f64(), h.delay_ms, h.position_mm.after, h.orientation_deg.after),
        Err(e) => println!("haptic pipeline failed: {e}"),
    }
    if args.no_scipy {
        return Ok(());
    }
    let single = calibrate(&nominal, &sim.artefact, &cal, &CalibrationOptions { restarts: 0, ..options })?;
    let t = Instant::now();
    let reps = 10;
    for _ in 0..reps {
        calibrate(&nominal, &sim.artefact, &cal, &CalibrationOptions { restarts: 0, ..options })?;
    }
    let single_start_ms = t.elapsed().as_secs_f64() * 1e3 / reps as f64;
    let dir = std::env::temp_dir().join(format!("kincal-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|source| BenchError::Io { path: dir.clone(), source })?;
    let problem = dir.join("problem.json");
    write_peer_problem(&problem, &nominal, &single.estimated, &sim.artefact, &cal, options.huber_delta_mm)?;
    let peer = run_peer(&args.python, &problem)?;
    std::fs::remove_dir_all(&dir).ok();
    println!(
        "SciPy least_squares(trf, huber), one start: {:.1} ms, {} evaluations, cost {:.9}",
        peer.seconds * 1e3,
        peer.nfev,
        peer.cost
    );
    println!("kincal, same start and parameters:       {single_start_ms:.2} ms, cost {:.9}", single.cost);
    println!(
        "speed-up {:.0}x (target >= 300x); cost ratio kincal/SciPy {:.9}",
        peer.seconds * 1e3 / single_start_ms,
        single.cost / peer.cost
    );
    if let Some(fit) = fit {
        println!("kincal with restarts: cost {:.9}; full 8-restart calibration is {:.0}x faster than one SciPy start", fit.cost, peer.seconds * 1e3 / single_ms);
    }
    Ok(())
}
