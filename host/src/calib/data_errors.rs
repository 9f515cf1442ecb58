//! Data errors: faults of the measurement rather than of the arm, found from the same touches.
//!
//! * **A wrong certificate** (`landmark:ID`): the landmark's certified position is freed. The
//!   arm is refitted without the landmark's touches, the landmark's position in the artefact
//!   frame is estimated from every calibration block (a rigid fit of the other landmarks, then
//!   the touch mapped back), and the arm is refitted once more with that certificate. Scored on
//!   the held-out placements with the corrected certificate, like an arm effect.
//! * **A disturbed block** (the artefact knocked within one repeat): within each
//!   (placement, repeat) block the touches, in the order measured, are fitted by one rigid
//!   placement of the artefact and by two (before and after touch k). The drop of the residual
//!   sum of squares over the per-axis touch variance σ² is χ²₆ for a block that did not move; the
//!   best k is flagged when the drop exceeds the χ²₆ quantile at [`SPLIT_Z`] standard normal
//!   deviations *and* [`SPLIT_OVER_MEDIAN`] times the median block's best drop (an arm error
//!   leaves every block's residuals alike; a knock is one block's).
//! * **A mis-seated touch**: a touch that disagrees with its own repeats (same placement,
//!   landmark and arm configuration, so the arm's systematic errors are the same): its distance
//!   from the mean of the others, over σ²·(1 + 1/(n − 1)), exceeds the χ²₃ quantile at
//!   [`TOUCH_Z`]. Only the worst touch of a group is named, and none in a disturbed block.
//!
//! A flagged block or touch is scored by refitting without it.

use crate::calib::calibrate::{calibrate, Calibration, CalibrationError, CalibrationOptions};
use crate::calib::floor::same_configuration;
use crate::data::{Artefact, Dataset};
use crate::model::kinematics::tool_pose;
use crate::model::ArmModel;
use crate::numerics::geometry::absolute_orientation;
use crate::numerics::stats::{chi2_quantile, median};
use nalgebra::{Matrix3, Vector3};

/// Standard normal deviate of the χ²₆ quantile a block's split must exceed.
pub const SPLIT_Z: f64 = 4.5;
/// Standard normal deviate of the χ²₃ quantile a single touch's residual must exceed.
pub const TOUCH_Z: f64 = 4.5;
/// A flagged block must also stand out this many times over the median block.
pub const SPLIT_OVER_MEDIAN: f64 = 8.0;
/// A touch is compared with its repeats only when it has at least this many.
const MIN_REPEATS: usize = 2;
/// Touches on each side of a split (a rigid fit needs three; one more for a residual).
const MIN_SIDE: usize = 4;

/// The (placement, repeat) blocks of a dataset: touch indices in measured order.
pub fn blocks(data: &Dataset) -> Vec<((usize, u32), Vec<usize>)> {
    let mut out: Vec<((usize, u32), Vec<usize>)> = Vec::new();
    for (k, t) in data.touches.iter().enumerate() {
        let key = (t.placement, t.repeat);
        match out.iter_mut().find(|b| b.0 == key) {
            Some(b) => b.1.push(k),
            None => out.push((key, vec![k])),
        }
    }
    out
}

/// Residual vectors (touched minus fitted certified position) of `touches` after one rigid fit
/// of the artefact, mm.
fn rigid_residuals(
    artefact: &Artefact,
    data: &Dataset,
    p: &[Vector3<f64>],
    touches: &[usize],
) -> Vec<Vector3<f64>> {
    let q: Vec<Vector3<f64>> =
        touches.iter().map(|&k| Vector3::from(artefact.landmarks[data.touches[k].landmark].xyz_mm)).collect();
    let pm: Vec<Vector3<f64>> = touches.iter().map(|&k| p[k]).collect();
    let (r, t): (Matrix3<f64>, Vector3<f64>) = absolute_orientation(&q, &pm);
    pm.iter().zip(&q).map(|(pm, q)| pm - (r * q + t)).collect()
}

fn rss(residuals: &[Vector3<f64>]) -> f64 {
    residuals.iter().map(|r| r.norm_squared()).sum()
}

/// A block whose artefact seems to have moved during the repeat.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DisturbedBlock {
    /// Placement index in the dataset.
    pub placement: usize,
    /// Repeat number.
    pub repeat: u32,
    /// Touches of the block before the jump.
    pub after_touch: usize,
    /// Landmark id of the first touch after the jump.
    pub first_moved: String,
    /// Drop of the residual sum of squares by the split, in σ² (χ²₆ if nothing moved).
    pub chi2: f64,
    /// How far the second rigid placement is from the first at the artefact's touches, RMS mm.
    pub moved_mm: f64,
}

/// A touch far off its block's rigid fit.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MisSeatedTouch {
    /// Touch index in the dataset.
    pub touch: usize,
    /// Its residual in σ² (χ²₃ for a good touch).
    pub chi2: f64,
    /// Its residual, mm.
    pub residual_mm: f64,
}

/// Blocks of `data` that look disturbed and touches that look mis-seated, for positions from
/// `model` and a per-axis touch variance `sigma2_mm2`.
pub fn suspicious(
    model: &ArmModel,
    artefact: &Artefact,
    data: &Dataset,
    sigma2_mm2: f64,
) -> (Vec<DisturbedBlock>, Vec<MisSeatedTouch>) {
    let p: Vec<Vector3<f64>> =
        data.touches.iter().map(|t| tool_pose(model, &t.enc_deg).position_mm).collect();
    let mut splits = Vec::new();
    let mut singles = Vec::new();
    for group in repeat_groups(data) {
        if group.len() < MIN_REPEATS + 1 {
            continue;
        }
        let n = group.len() as f64;
        let worst = group
            .iter()
            .map(|&k| {
                let others =
                    group.iter().filter(|&&o| o != k).map(|&o| p[o]).sum::<Vector3<f64>>() / (n - 1.0);
                let r = p[k] - others;
                MisSeatedTouch {
                    touch: k,
                    chi2: r.norm_squared() / (sigma2_mm2 * n / (n - 1.0)),
                    residual_mm: r.norm(),
                }
            })
            .max_by(|a, b| a.chi2.total_cmp(&b.chi2));
        singles.extend(worst);
    }
    for ((placement, repeat), touches) in blocks(data) {
        if touches.len() < 2 * MIN_SIDE {
            continue;
        }
        let rss0 = rss(&rigid_residuals(artefact, data, &p, &touches));
        let best = (MIN_SIDE..=touches.len() - MIN_SIDE)
            .map(|k| {
                let split = rss(&rigid_residuals(artefact, data, &p, &touches[..k]))
                    + rss(&rigid_residuals(artefact, data, &p, &touches[k..]));
                (k, (rss0 - split) / sigma2_mm2)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((k, chi2)) = best {
            // How far apart the two placements are: the later touches' fit moved by the first's.
            let later = &touches[k..];
            let alone = rigid_residuals(artefact, data, &p, later);
            let with_first = {
                let q: Vec<Vector3<f64>> = touches[..k]
                    .iter()
                    .map(|&i| Vector3::from(artefact.landmarks[data.touches[i].landmark].xyz_mm))
                    .collect();
                let pm: Vec<Vector3<f64>> = touches[..k].iter().map(|&i| p[i]).collect();
                let (r, t) = absolute_orientation(&q, &pm);
                later
                    .iter()
                    .map(|&i| {
                        p[i] - (r * Vector3::from(artefact.landmarks[data.touches[i].landmark].xyz_mm) + t)
                    })
                    .collect::<Vec<_>>()
            };
            let moved = (with_first.iter().zip(&alone).map(|(a, b)| (a - b).norm_squared()).sum::<f64>()
                / later.len() as f64)
                .sqrt();
            splits.push(DisturbedBlock {
                placement,
                repeat,
                after_touch: k,
                first_moved: artefact.landmarks[data.touches[touches[k]].landmark].id.clone(),
                chi2,
                moved_mm: moved,
            });
        }
    }
    let split_median = median(splits.iter().map(|s| s.chi2).collect());
    let split_limit = chi2_quantile(6.0, SPLIT_Z).max(SPLIT_OVER_MEDIAN * split_median);
    let touch_limit = chi2_quantile(3.0, TOUCH_Z);
    splits.retain(|s| s.chi2 > split_limit);
    splits.sort_by(|a, b| b.chi2.total_cmp(&a.chi2));
    // A touch inside a disturbed block is explained by the block.
    singles.retain(|s| {
        let t = &data.touches[s.touch];
        s.chi2 > touch_limit && !splits.iter().any(|b| b.placement == t.placement && b.repeat == t.repeat)
    });
    singles.sort_by(|a, b| b.chi2.total_cmp(&a.chi2));
    (splits, singles)
}

/// Where landmark `landmark` really is in the artefact frame, from its touches in `data`
/// (positions from `model`), each mapped back through a rigid fit of the other landmarks of its
/// block; `None` when no block has it and three others.
pub fn locate_landmark(
    model: &ArmModel,
    artefact: &Artefact,
    data: &Dataset,
    landmark: usize,
) -> Option<[f64; 3]> {
    let p: Vec<Vector3<f64>> =
        data.touches.iter().map(|t| tool_pose(model, &t.enc_deg).position_mm).collect();
    let mut sum = Vector3::zeros();
    let mut n = 0usize;
    for (_, touches) in blocks(data) {
        let (this, others): (Vec<usize>, Vec<usize>) =
            touches.iter().partition(|&&k| data.touches[k].landmark == landmark);
        if this.is_empty() || others.len() < 3 {
            continue;
        }
        let q: Vec<Vector3<f64>> = others
            .iter()
            .map(|&k| Vector3::from(artefact.landmarks[data.touches[k].landmark].xyz_mm))
            .collect();
        let pm: Vec<Vector3<f64>> = others.iter().map(|&k| p[k]).collect();
        let (r, t) = absolute_orientation(&q, &pm);
        for &k in &this {
            sum += r.transpose() * (p[k] - t);
            n += 1;
        }
    }
    (n > 0).then(|| {
        let m = sum / n as f64;
        [m.x, m.y, m.z]
    })
}

/// Calibrate with landmark `landmark`'s certified position freed: fit the arm without it,
/// locate it, refit with the located position. Returns the fit and the corrected artefact.
pub fn calibrate_with_landmark_freed(
    start: &ArmModel,
    artefact: &Artefact,
    cal: &Dataset,
    landmark: usize,
    options: &CalibrationOptions,
) -> Result<(Calibration, Artefact), CalibrationError> {
    let without = calibrate(start, artefact, &cal.without_landmark(landmark), options)?;
    let mut corrected = artefact.clone();
    if let Some(xyz) = locate_landmark(&without.model, artefact, cal, landmark) {
        corrected.landmarks[landmark].xyz_mm = xyz;
    }
    let fit = calibrate(&without.model, &corrected, cal, &CalibrationOptions { restarts: 0, ..*options })?;
    Ok((fit, corrected))
}

/// Touches of the same landmark, placement and arm configuration (see
/// [`crate::calib::floor::same_configuration`]).
fn repeat_groups(data: &Dataset) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    for placement in 0..data.placements.len() {
        let mut landmarks: Vec<usize> =
            data.touches.iter().filter(|t| t.placement == placement).map(|t| t.landmark).collect();
        landmarks.sort_unstable();
        landmarks.dedup();
        for l in landmarks {
            let idx: Vec<usize> = (0..data.touches.len())
                .filter(|&k| data.touches[k].placement == placement && data.touches[k].landmark == l)
                .collect();
            out.extend(same_configuration(data, &idx));
        }
    }
    out
}

/// A copy of `data` without the touches for which `drop` is true.
pub fn without(data: &Dataset, drop: impl Fn(usize) -> bool) -> Dataset {
    Dataset {
        placements: data.placements.clone(),
        touches: data.touches.iter().enumerate().filter(|(k, _)| !drop(*k)).map(|(_, t)| t.clone()).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Landmark, Touch, ARTEFACT_FORMAT};

    #[test]
    fn blocks_keep_the_measured_order() {
        let t = |placement, repeat| Touch {
            placement,
            landmark: 0,
            repeat,
            enc_deg: [0.0; 6],
            enc_sigma_deg: None,
        };
        let data = Dataset {
            placements: vec!["A".into(), "B".into()],
            touches: vec![t(0, 1), t(1, 1), t(0, 1), t(0, 2)],
        };
        assert_eq!(blocks(&data), vec![((0, 1), vec![0, 2]), ((1, 1), vec![1]), ((0, 2), vec![3])]);
        assert_eq!(without(&data, |k| k == 1).touches.len(), 3);
    }

    #[test]
    fn a_landmark_is_located_through_the_others() {
        // Four touches; the artefact frame is the base frame, so the certificates of the first
        // three are their touched positions, and landmark 3's certificate is 2 mm off along x.
        let model = ArmModel::suta_nominal();
        let enc = [
            [0.0, 200.0, 100.0, 30.0, 40.0, 50.0],
            [10.0, 210.0, 90.0, 20.0, 50.0, 40.0],
            [350.0, 190.0, 95.0, 25.0, 45.0, 55.0],
            [5.0, 205.0, 105.0, 35.0, 35.0, 45.0],
        ];
        let p: Vec<Vector3<f64>> = enc.iter().map(|e| tool_pose(&model, e).position_mm).collect();
        let artefact = Artefact {
            format: ARTEFACT_FORMAT.into(),
            landmarks: (0..4)
                .map(|i| {
                    let q = if i < 3 { p[i] } else { p[3] + Vector3::new(2.0, 0.0, 0.0) };
                    Landmark { id: format!("L{i}"), xyz_mm: [q.x, q.y, q.z], yaw_deg: 0.0 }
                })
                .collect(),
        };
        let data = Dataset {
            placements: vec!["A".into()],
            touches: (0..4)
                .map(|l| Touch { placement: 0, landmark: l, repeat: 1, enc_deg: enc[l], enc_sigma_deg: None })
                .collect(),
        };
        let found = locate_landmark(&model, &artefact, &data, 3).expect("located");
        assert!((Vector3::from(found) - p[3]).norm() < 1e-6, "{found:?} vs {:?}", p[3]);
    }
}
