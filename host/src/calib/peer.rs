//! The SciPy peer: the same calibration problem written to a file that `bench/scipy_peer.py`
//! solves with `least_squares(method='trf', loss='huber')` and its own numpy kinematics, so that
//! kincal's solver can be compared with an independent one (test `scipy_peer`, `kincal bench`).

use crate::data::Observations;
use crate::model::{ArmModel, ParamId};
use crate::simulate::{simulate, SimulatedData, SimulationOptions};
use std::path::{Path, PathBuf};

/// Why the peer problem could not be written or solved.
#[derive(Debug, thiserror::Error)]
pub enum PeerError {
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
    Calibration(#[from] crate::calib::error::CalibError),
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
    data: &Observations,
    huber_delta_mm: f64,
) -> Result<(), PeerError> {
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
        serde_json::from_str(&nominal.to_text(true)).map_err(|e| PeerError::Peer(e.to_string()))?;
    let problem = serde_json::json!({
        "model": model,
        "landmarks_mm": data.landmarks.iter().map(|l| l.xyz_mm).collect::<Vec<_>>(),
        "touches": data.obs.iter().map(|t| serde_json::json!({"placement": t.group, "landmark": t.touched(), "repeat": t.repeat, "enc_deg": t.q_deg})).collect::<Vec<_>>(),
        "params": params.iter().map(|p| p.to_string()).collect::<Vec<_>>(),
        "x0": params.iter().map(|p| nominal.get(*p)).collect::<Vec<_>>(),
        "lower": bounds.iter().map(|b| b.0).collect::<Vec<_>>(),
        "upper": bounds.iter().map(|b| b.1).collect::<Vec<_>>(),
        "huber_delta_mm": huber_delta_mm,
    });
    std::fs::write(path, problem.to_string())
        .map_err(|source| PeerError::Io { path: path.to_owned(), source })
}

/// The peer script's path in the source tree.
pub fn peer_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/scipy_peer.py")
}

/// Run the SciPy peer on a problem file.
pub fn run_peer(python: &str, problem: &Path) -> Result<PeerResult, PeerError> {
    let output = std::process::Command::new(python)
        .arg(peer_script())
        .arg(problem)
        .output()
        .map_err(|e| PeerError::Peer(format!("could not start {python}: {e}")))?;
    if !output.status.success() {
        return Err(PeerError::Peer(format!(
            "{} failed: {}",
            peer_script().display(),
            String::from_utf8_lossy(&output.stderr).trim()
        )));
    }
    serde_json::from_slice(&output.stdout).map_err(|e| {
        PeerError::Peer(format!("unexpected output ({e}): {}", String::from_utf8_lossy(&output.stdout)))
    })
}
