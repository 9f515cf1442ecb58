//! Per-landmark outlier diagnostics (thesis appendix F), each metric with the thesis threshold:
//!
//! * error contribution: Σ_{pairs ∋ i} e² / (2 Σ_pairs e²) · 100 %, flagged above 1.5 × 100/L %;
//! * Cook's distance D_i = Δβᵀ JᵀJ Δβ / (p · MSE), Δβ the change of the estimates when landmark
//!   i is left out, flagged above 4/L;
//! * leave-one-landmark-out impact (RMS_full − RMS_without_i)/RMS_full · 100 % on the validation
//!   data (calibration data if none), flagged above 5 %;
//! * systematic bias: RMS of the landmark's residual after a rigid fit of the artefact to the
//!   measured positions of each placement, flagged above 1.0 mm.
//!
//! A landmark is flagged when at least two metrics exceed their thresholds.

use crate::calib::fit::{dense_jacobian, refit, Fit};
use crate::calib::nuisance::frame::Frame;
use crate::calib::setup::SolveOptions;
use crate::calib::validate::{distance_errors, positions, ErrorStats};
use crate::data::Observations;
use crate::model::ArmModel;
use nalgebra::Vector3;
use rayon::prelude::*;

/// Leave-one-out impact (percent) above which a landmark is suspicious.
pub const LOO_IMPACT_PCT: f64 = 5.0;
/// Systematic bias (mm) above which a landmark is suspicious.
pub const BIAS_MM: f64 = 1.0;

/// The four metrics of one landmark.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LandmarkOutlier {
    /// Landmark id.
    pub landmark: String,
    /// Share of the squared calibration error, percent.
    pub contribution_pct: f64,
    /// Cook's distance of leaving the landmark out.
    pub cooks_distance: f64,
    /// Validation RMS improvement when the landmark is left out, percent.
    pub loo_impact_pct: f64,
    /// Residual after a rigid fit of the artefact per placement, RMS, mm.
    pub bias_mm: f64,
    /// Metrics beyond their thresholds.
    pub exceeded: Vec<String>,
    /// At least two metrics exceeded.
    pub flagged: bool,
}

/// Per-landmark RMS residual after a rigid fit of the artefact in every placement, mm.
pub fn landmark_bias(model: &ArmModel, data: &Observations) -> Vec<f64> {
    let p = positions(model, data);
    let mut sum = vec![0.0; data.landmarks.len()];
    let mut count = vec![0usize; data.landmarks.len()];
    for placement in 0..data.groups.len() {
        let idx: Vec<usize> = (0..data.obs.len()).filter(|&k| data.obs[k].group == placement).collect();
        if idx.len() < 3 {
            continue;
        }
        let q: Vec<Vector3<f64>> =
            idx.iter().map(|&k| Vector3::from(data.landmarks[data.obs[k].touched()].xyz_mm)).collect();
        let pm: Vec<Vector3<f64>> = idx.iter().map(|&k| p[k]).collect();
        let frame = Frame::fit(&q, &pm);
        for (i, &k) in idx.iter().enumerate() {
            let l = data.obs[k].touched();
            sum[l] += (frame.apply(&q[i]) - pm[i]).norm_squared();
            count[l] += 1;
        }
    }
    sum.iter().zip(&count).map(|(s, &c)| if c > 0 { (s / c as f64).sqrt() } else { 0.0 }).collect()
}

/// Run the four metrics for every landmark touched in `cal`.
pub fn landmark_outliers(
    fit: &Fit,
    cal: &Observations,
    val: Option<&Observations>,
    options: &SolveOptions,
) -> Vec<LandmarkOutlier> {
    let errors = distance_errors(&fit.model, cal);
    let total: f64 = errors.iter().map(|e| e.error_mm.powi(2)).sum::<f64>().max(1e-300);
    let touched: Vec<usize> =
        (0..cal.landmarks.len()).filter(|&l| cal.obs.iter().any(|t| t.landmark() == Some(l))).collect();
    let count = touched.len().max(1) as f64;
    let rms_on = |model: &ArmModel| {
        let data = val.unwrap_or(cal);
        ErrorStats::of(&distance_errors(model, data).iter().map(|e| e.error_mm).collect::<Vec<_>>()).rms_mm
    };
    let full_rms = rms_on(&fit.model).max(1e-300);
    // Cook's distance needs JᵀJ and the MSE of the full fit over the estimated parameters.
    let (r, jac) = dense_jacobian(&fit.model, &fit.estimated, cal, None);
    let (m, p) = (r.len(), fit.estimated.len());
    let mse = r[..m].iter().map(|v| v * v).sum::<f64>() / (m as f64 - p as f64).max(1.0);
    let (jtj, _) = crate::numerics::solver::normal_equations(&jac[..m * p], &r[..m], &vec![1.0; m], p);
    let bias = landmark_bias(&fit.model, cal);
    // Refits without one landmark start from the full fit, on its base set.
    touched
        .par_iter()
        .map(|&l| {
            let contribution_pct = 100.0
                * errors
                    .iter()
                    .filter(|e| e.landmarks.0 == l || e.landmarks.1 == l)
                    .map(|e| e.error_mm.powi(2))
                    .sum::<f64>()
                / (2.0 * total);
            let (cooks_distance, loo_impact_pct) = match refit(fit, &cal.without_landmark(l), options) {
                Ok(model) => {
                    let delta = nalgebra::DVector::from_iterator(
                        p,
                        fit.estimated.iter().map(|&id| model.get(id) - fit.model.get(id)),
                    );
                    let cook = delta.dot(&(&jtj * &delta)) / (p as f64 * mse.max(1e-300));
                    (cook, 100.0 * (full_rms - rms_on(&model)) / full_rms)
                }
                Err(_) => (f64::NAN, f64::NAN),
            };
            let mut exceeded = Vec::new();
            if contribution_pct > 1.5 * 100.0 / count {
                exceeded.push("contribution");
            }
            if cooks_distance > 4.0 / count {
                exceeded.push("cooks_distance");
            }
            if loo_impact_pct > LOO_IMPACT_PCT {
                exceeded.push("leave_one_out");
            }
            if bias[l] > BIAS_MM {
                exceeded.push("bias");
            }
            LandmarkOutlier {
                landmark: cal.landmarks[l].id.clone(),
                contribution_pct,
                cooks_distance,
                loo_impact_pct,
                bias_mm: bias[l],
                flagged: exceeded.len() >= 2,
                exceeded: exceeded.into_iter().map(String::from).collect(),
            }
        })
        .collect()
}
