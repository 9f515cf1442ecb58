//! Summary figures of the errors a model leaves: lengths in mm ([`ErrorStats`]) and angles in
//! degrees ([`AngleStats`]), for a calibration, a validation or a pool of sessions.

/// Statistics of errors, mm: signed distance errors, or lengths of point errors.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorStats {
    /// Root mean square error.
    pub rms_mm: f64,
    /// Mean (signed) error.
    pub mean_mm: f64,
    /// Standard deviation of the error.
    #[serde(default)]
    pub std_mm: f64,
    /// Largest absolute error.
    pub max_mm: f64,
    /// Number of errors (distances or points).
    #[serde(alias = "pairs", alias = "points")]
    pub count: usize,
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
        ErrorStats { rms_mm: rms, mean_mm: mean, std_mm: std, max_mm: max, count: n }
    }

    /// The statistics of several parts pooled (weighted by their counts); the std of the pool
    /// from the parts' means and stds.
    pub fn pooled(parts: &[ErrorStats]) -> ErrorStats {
        let count: usize = parts.iter().map(|p| p.count).sum();
        let n = count.max(1) as f64;
        let mean = parts.iter().map(|p| p.mean_mm * p.count as f64).sum::<f64>() / n;
        let second =
            parts.iter().map(|p| (p.std_mm.powi(2) + p.mean_mm.powi(2)) * p.count as f64).sum::<f64>() / n;
        ErrorStats {
            count,
            rms_mm: (parts.iter().map(|p| p.rms_mm.powi(2) * p.count as f64).sum::<f64>() / n).sqrt(),
            mean_mm: mean,
            std_mm: (second - mean * mean).max(0.0).sqrt(),
            max_mm: parts.iter().map(|p| p.max_mm).fold(0.0, f64::max),
        }
    }
}

/// Orientation-error statistics (the angle of R_predᵀ·R_meas), degrees.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AngleStats {
    /// Orientations.
    pub orientations: usize,
    /// RMS angle, degrees.
    pub rms_deg: f64,
    /// Mean angle, degrees.
    pub mean_deg: f64,
    /// Largest angle, degrees.
    pub max_deg: f64,
}

impl AngleStats {
    /// Statistics of error angles (degrees).
    pub fn of(angles_deg: &[f64]) -> AngleStats {
        let e = ErrorStats::of(angles_deg);
        AngleStats { orientations: e.count, rms_deg: e.rms_mm, mean_deg: e.mean_mm, max_deg: e.max_mm }
    }

    /// Orientation figures pooled over sessions; `None` without any.
    pub fn pooled(parts: &[AngleStats]) -> Option<AngleStats> {
        let orientations: usize = parts.iter().map(|p| p.orientations).sum();
        let n = orientations as f64;
        (orientations > 0).then(|| AngleStats {
            orientations,
            rms_deg: (parts.iter().map(|p| p.rms_deg.powi(2) * p.orientations as f64).sum::<f64>() / n)
                .sqrt(),
            mean_deg: parts.iter().map(|p| p.mean_deg * p.orientations as f64).sum::<f64>() / n,
            max_deg: parts.iter().map(|p| p.max_deg).fold(0.0, f64::max),
        })
    }
}
