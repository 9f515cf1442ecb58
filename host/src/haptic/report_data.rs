//! Where the held-out errors of a haptic calibration are, for the report and `summary.json`: per
//! stylus direction, per workspace region and against each joint angle — the way `diagnose` shows
//! it for the arm. A wrong joint convention or a missing effect shows as errors growing along
//! one joint's range or a common error direction (bias) in one region; a good calibration leaves
//! small errors pointing anywhere (paper §3.4).

use nalgebra::Vector3;

/// One held-out sample after calibration.
#[derive(Clone, Copy, Debug)]
pub struct HeldOutSample {
    /// Stylus direction in device coordinates (unit).
    pub direction: Vector3<f64>,
    /// Calibrated HIP position in device coordinates, mm.
    pub position_mm: Vector3<f64>,
    /// Reference minus calibrated HIP, device coordinates, mm.
    pub error_mm: Vector3<f64>,
    /// Stylus-axis error, degrees.
    pub axis_error_deg: f64,
    /// Calibrated θ1–θ3, degrees.
    pub theta_deg: [f64; 3],
}

/// Errors of the samples in one cell of a map.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Cell {
    /// What the cell is (`lon 30…60°, lat 0…30°`, `x low, y mid, z high`, `θ2 12…18°`).
    pub label: String,
    /// Samples in the cell.
    pub count: usize,
    /// RMS position error, mm.
    pub position_rms_mm: f64,
    /// Mean error vector (bias), device coordinates, mm.
    pub bias_mm: [f64; 3],
    /// RMS axis error, degrees.
    pub axis_rms_deg: f64,
}

/// The maps.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ErrorMaps {
    /// By stylus direction: longitude atan2(x, z) and latitude asin(y) in 45° × 30° cells.
    pub directions: Vec<Cell>,
    /// By workspace region: thirds of the held-out positions along x, y and z (device frame).
    pub regions: Vec<Cell>,
    /// By joint angle: θ1, θ2, θ3 each in six equal bins over its held-out range.
    pub joints: [Vec<Cell>; 3],
    /// Mean error vector over all held-out samples, mm.
    pub bias_mm: [f64; 3],
}

fn cell(label: String, samples: &[&HeldOutSample]) -> Cell {
    let n = samples.len().max(1) as f64;
    let bias: Vector3<f64> = samples.iter().map(|s| s.error_mm).sum::<Vector3<f64>>() / n;
    Cell {
        label,
        count: samples.len(),
        position_rms_mm: (samples.iter().map(|s| s.error_mm.norm_squared()).sum::<f64>() / n).sqrt(),
        bias_mm: [bias.x, bias.y, bias.z],
        axis_rms_deg: (samples.iter().map(|s| s.axis_error_deg.powi(2)).sum::<f64>() / n).sqrt(),
    }
}

/// Cells of `samples` grouped by `key` (non-empty cells only, in key order).
fn group<K: Ord + Copy>(
    samples: &[HeldOutSample],
    key: impl Fn(&HeldOutSample) -> K,
    label: impl Fn(K) -> String,
) -> Vec<Cell> {
    let mut groups: std::collections::BTreeMap<K, Vec<&HeldOutSample>> = Default::default();
    for s in samples {
        groups.entry(key(s)).or_default().push(s);
    }
    groups.into_iter().map(|(k, v)| cell(label(k), &v)).collect()
}

/// Thirds boundaries of `values`.
fn terciles(mut values: Vec<f64>) -> (f64, f64) {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n == 0 {
        return (0.0, 0.0);
    }
    (values[n / 3], values[(2 * n) / 3])
}

/// The maps of `samples`.
pub fn error_maps(samples: &[HeldOutSample]) -> ErrorMaps {
    if samples.is_empty() {
        return ErrorMaps::default();
    }
    let directions = group(
        samples,
        |s| {
            let lon = s.direction.x.atan2(s.direction.z).to_degrees();
            let lat = s.direction.y.clamp(-1.0, 1.0).asin().to_degrees();
            (((lon + 180.0) / 45.0).floor() as i32, ((lat + 90.0) / 30.0).floor() as i32)
        },
        |(a, b)| format!("lon {}…{}°, lat {}…{}°", a * 45 - 180, a * 45 - 135, b * 30 - 90, b * 30 - 60),
    );
    let bounds: [(f64, f64); 3] =
        std::array::from_fn(|k| terciles(samples.iter().map(|s| s.position_mm[k]).collect()));
    let third = |v: f64, (a, b): (f64, f64)| {
        if v < a {
            0
        } else if v < b {
            1
        } else {
            2
        }
    };
    let names = ["low", "mid", "high"];
    let regions = group(
        samples,
        |s| [0, 1, 2].map(|k| third(s.position_mm[k], bounds[k])),
        |r| format!("x {}, y {}, z {}", names[r[0]], names[r[1]], names[r[2]]),
    );
    let joints = std::array::from_fn(|j| {
        let (lo, hi) = samples.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
            (lo.min(s.theta_deg[j]), hi.max(s.theta_deg[j]))
        });
        let width = ((hi - lo) / 6.0).max(1e-9);
        group(
            samples,
            |s| (((s.theta_deg[j] - lo) / width) as usize).min(5),
            |b| format!("θ{} {:.0}…{:.0}°", j + 1, lo + b as f64 * width, lo + (b + 1) as f64 * width),
        )
    });
    let all = cell(String::new(), &samples.iter().collect::<Vec<_>>());
    ErrorMaps { directions, regions, joints, bias_mm: all.bias_mm }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bias_in_one_region_shows_in_that_cell() {
        let samples: Vec<HeldOutSample> = (0..300)
            .map(|k| {
                let x = (k % 10) as f64 * 10.0;
                HeldOutSample {
                    direction: Vector3::z(),
                    position_mm: Vector3::new(x, (k / 10 % 10) as f64, (k / 100) as f64),
                    // Only the high-x third is off, by 1 mm along y.
                    error_mm: if x >= 60.0 { Vector3::new(0.0, 1.0, 0.0) } else { Vector3::zeros() },
                    axis_error_deg: 0.1,
                    theta_deg: [x / 10.0, 0.0, 0.0],
                }
            })
            .collect();
        let maps = error_maps(&samples);
        let high: Vec<&Cell> = maps.regions.iter().filter(|c| c.label.starts_with("x high")).collect();
        assert!(!high.is_empty() && high.iter().all(|c| (c.bias_mm[1] - 1.0).abs() < 1e-12));
        assert!(maps
            .regions
            .iter()
            .filter(|c| !c.label.starts_with("x high"))
            .all(|c| c.position_rms_mm == 0.0));
        assert_eq!(maps.joints[0].len(), 6);
        assert!(maps.joints[0][5].position_rms_mm > 0.9 && maps.joints[0][0].position_rms_mm == 0.0);
        assert_eq!(maps.directions.len(), 1);
    }
}
