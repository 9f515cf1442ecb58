//! Validation metrics: pairwise distance errors of a model on a dataset, per landmark, per
//! placement, and repeatability per landmark (ISO 9283 style).

use crate::data::{Artefact, Observations};
use crate::model::kinematics::tool_pose;
use crate::model::ArmModel;
use nalgebra::Vector3;

/// Error of one measured distance.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PairError {
    /// Placement index in the dataset.
    pub placement: usize,
    /// Landmark indices (artefact order).
    pub landmarks: (usize, usize),
    /// Touch indices in the dataset.
    pub touches: (usize, usize),
    /// Measured minus certified distance, mm.
    pub error_mm: f64,
}

/// Summary statistics of distance errors, mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorStats {
    /// Root mean square error.
    pub rms_mm: f64,
    /// Mean (signed) error.
    pub mean_mm: f64,
    /// Standard deviation of the error.
    pub std_mm: f64,
    /// Largest absolute error.
    pub max_mm: f64,
    /// Number of distances.
    pub pairs: usize,
}

impl ErrorStats {
    /// Statistics of `errors` (mm).
    pub fn of(errors: &[f64]) -> ErrorStats {
        let n = errors.len();
        if n == 0 {
            return ErrorStats::default();
        }
        let mean = errors.iter().sum::<f64>() / n as f64;
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
        let std = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
        let max = errors.iter().fold(0.0_f64, |a, e| a.max(e.abs()));
        ErrorStats { rms_mm: rms, mean_mm: mean, std_mm: std, max_mm: max, pairs: n }
    }
}

/// Repeatability of one landmark: spread of repeated touches about their barycentre.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Repeatability {
    /// Landmark id.
    pub landmark: String,
    /// Touches that had a repeat partner.
    pub touches: usize,
    /// RMS distance of touches from their placement's barycentre, mm.
    pub rms_mm: f64,
    /// ISO 9283 positional repeatability RP = mean(l) + 3·std(l), mm.
    pub rp_mm: f64,
}

/// Named group statistics.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct GroupStats {
    /// Landmark id or placement name.
    pub name: String,
    /// Errors of the distances involving this group.
    pub stats: ErrorStats,
}

/// All validation figures of one model on one dataset.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Validation {
    /// Over all pairs.
    pub overall: ErrorStats,
    /// Per landmark (pairs involving it).
    pub per_landmark: Vec<GroupStats>,
    /// Per placement.
    pub per_placement: Vec<GroupStats>,
    /// Repeatability per landmark.
    pub repeatability: Vec<Repeatability>,
    /// Every pair error.
    #[serde(skip)]
    pub errors: Vec<PairError>,
}

/// Tool positions of every observation, mm.
pub fn positions(model: &ArmModel, data: &Observations) -> Vec<Vector3<f64>> {
    data.obs.iter().map(|t| tool_pose(model, &t.q_deg).position_mm).collect()
}

/// Distance errors of `model` on `data`.
pub fn distance_errors(model: &ArmModel, artefact: &Artefact, data: &Observations) -> Vec<PairError> {
    let p = positions(model, data);
    data.landmark_pairs()
        .into_iter()
        .map(|(a, b)| {
            let (ta, tb) = (&data.obs[a], &data.obs[b]);
            let (la, lb) = (ta.landmark().unwrap_or(0), tb.landmark().unwrap_or(0));
            PairError {
                placement: ta.group,
                landmarks: (la, lb),
                touches: (a, b),
                error_mm: (p[a] - p[b]).norm() - artefact.distance_mm(la, lb),
            }
        })
        .collect()
}

/// Validate `model` on `data`.
pub fn validate(model: &ArmModel, artefact: &Artefact, data: &Observations) -> Validation {
    let errors = distance_errors(model, artefact, data);
    let all: Vec<f64> = errors.iter().map(|e| e.error_mm).collect();
    let per_landmark = artefact
        .landmarks
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let e: Vec<f64> = errors
                .iter()
                .filter(|e| e.landmarks.0 == i || e.landmarks.1 == i)
                .map(|e| e.error_mm)
                .collect();
            GroupStats { name: l.id.clone(), stats: ErrorStats::of(&e) }
        })
        .filter(|g| g.stats.pairs > 0)
        .collect();
    let per_placement = data
        .groups
        .iter()
        .enumerate()
        .map(|(p, group)| {
            let e: Vec<f64> = errors.iter().filter(|e| e.placement == p).map(|e| e.error_mm).collect();
            GroupStats { name: group.name.clone(), stats: ErrorStats::of(&e) }
        })
        .collect();
    Validation {
        overall: ErrorStats::of(&all),
        per_landmark,
        per_placement,
        repeatability: repeatability(model, artefact, data),
        errors,
    }
}

/// Repeatability per landmark from touches repeated within one placement.
pub fn repeatability(model: &ArmModel, artefact: &Artefact, data: &Observations) -> Vec<Repeatability> {
    let p = positions(model, data);
    // Touches grouped by (landmark, placement) once: linear in the number of touches.
    let mut groups: std::collections::BTreeMap<(usize, usize), Vec<usize>> = Default::default();
    for (k, t) in data.obs.iter().enumerate() {
        if let Some(l) = t.landmark() {
            groups.entry((l, t.group)).or_default().push(k);
        }
    }
    let mut out = Vec::new();
    for (i, l) in artefact.landmarks.iter().enumerate() {
        let mut spreads = Vec::new();
        for (_, idx) in groups.range((i, 0)..(i + 1, 0)) {
            if idx.len() < 2 {
                continue;
            }
            let bary = idx.iter().map(|&k| p[k]).sum::<Vector3<f64>>() / idx.len() as f64;
            spreads.extend(idx.iter().map(|&k| (p[k] - bary).norm()));
        }
        if spreads.is_empty() {
            continue;
        }
        let n = spreads.len() as f64;
        let mean = spreads.iter().sum::<f64>() / n;
        let std = (spreads.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        let rms = (spreads.iter().map(|s| s * s).sum::<f64>() / n).sqrt();
        out.push(Repeatability {
            landmark: l.id.clone(),
            touches: spreads.len(),
            rms_mm: rms,
            rp_mm: mean + 3.0 * std,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_known_errors() {
        let s = ErrorStats::of(&[1.0, -1.0, 3.0, -3.0]);
        assert!((s.rms_mm - 5.0_f64.sqrt()).abs() < 1e-12);
        assert_eq!((s.mean_mm, s.max_mm, s.pairs), (0.0, 3.0, 4));
        assert_eq!(ErrorStats::of(&[]).pairs, 0);
    }
}
