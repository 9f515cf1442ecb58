//! Data errors of artefact placements: faults of the measurement rather than of the arm, found
//! from the same touches.
//!
//! * **A wrong certificate** (`landmark:ID`): the landmark's certified position is freed. The
//!   arm is refitted without the landmark's touches, the landmark's position in the artefact
//!   frame is estimated from every calibration block (a rigid fit of the other landmarks, then
//!   the touch mapped back), and the arm is refitted once more with that certificate. Scored on
//!   the held-out placements with the corrected certificate, like an arm effect.
//! * **A disturbed block** (the artefact knocked within one repeat): each touch of a
//!   (placement, repeat) block is paired with its *twin* in another repeat of the placement —
//!   the same landmark touched in the same arm configuration — so the arm's pose-dependent
//!   errors cancel between the two. The twins' positions are mapped onto the block's touches,
//!   in the order measured, by one rigid motion and by two (before and after touch k). The drop
//!   of the residual sum of squares over 2σ² (σ² the per-axis touch variance; a difference of two
//!   touches has twice it) is χ²₆ for a block that did not move. The best k over the splits and
//!   the other repeats is flagged when the drop exceeds the χ²₆ quantile at [`SPLIT_Z`] standard
//!   normal deviations, a level that stays below 10⁻³ after the hundreds of splits looked at
//!   (a Bonferroni bound on the change-point maximum). Touches without a twin are left out, so
//!   repeats taken in other configurations neither trip nor hide the test: a compliance error
//!   that differs between configurations is never read as the artefact moving.
//! * **A mis-seated touch**: a touch that disagrees with its own repeats (same placement,
//!   landmark and arm configuration, so the arm's systematic errors are the same): its distance
//!   from the mean of the others, over σ²·(1 + 1/(n − 1)), exceeds the χ²₃ quantile at
//!   [`TOUCH_Z`]. Only the worst touch of a group is named, and none in a disturbed block.
//!
//! A flagged block or touch is scored by refitting without it.

use crate::calib::error::CalibError;
use crate::calib::fit::{calibrate, solve_warm, Fit};
use crate::calib::nuisance::frame::Frame;
use crate::calib::repeats::{same_configuration, same_pose};
use crate::calib::setup::SolveOptions;
use crate::data::{Landmark, Observations};
use crate::model::{ArmModel, ParamId};
use crate::numerics::stats::{chi2_quantile, f_upper_tail, normal_upper_tail};
use nalgebra::Vector3;

/// Standard normal deviate of the χ²₆ quantile a block's split must exceed.
pub const SPLIT_Z: f64 = 4.5;
/// Standard normal deviate of the χ²₃ quantile a single touch's residual must exceed.
pub const TOUCH_Z: f64 = 4.5;
/// A touch is compared with its repeats only when it has at least this many.
const MIN_REPEATS: usize = 2;
/// Touches on each side of a split (a rigid fit needs three; one more for a residual).
const MIN_SIDE: usize = 4;

/// The (placement, repeat) blocks of a dataset: touch indices in measured order.
pub fn blocks(data: &Observations) -> Vec<((usize, u32), Vec<usize>)> {
    data.blocks.iter().map(|b| ((b.group, b.repeat), b.members.clone())).collect()
}

/// A touch of a block against its reference: (position in the block, touch, reference position
/// mm) — a twin's touched position or the certified landmark.
type Reference = (usize, usize, Vector3<f64>);

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
    data: &Observations,
    sigma2_mm2: f64,
) -> (Vec<DisturbedBlock>, Vec<MisSeatedTouch>) {
    let p: Vec<Vector3<f64>> = crate::calib::nuisance::tool::positions(model, data);
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
    let all_blocks = blocks(data);
    let split_limit = chi2_quantile(6.0, SPLIT_Z);
    for ((placement, repeat), touches) in &all_blocks {
        // (position in the block, touch, reference position) in measured order: the twins in
        // each other repeat, else the certified landmarks.
        let mut references: Vec<(Vec<Reference>, bool)> = all_blocks
            .iter()
            .filter(|(k, _)| k.0 == *placement && k.1 != *repeat)
            .map(|(_, others)| {
                let matched = touches
                    .iter()
                    .enumerate()
                    .filter_map(|(i, &k)| {
                        others
                            .iter()
                            .find(|&&o| {
                                data.obs[o].landmark() == data.obs[k].landmark()
                                    && same_pose(&data.obs[k].q_deg, &data.obs[o].q_deg)
                            })
                            .map(|&o| (i, k, p[o]))
                    })
                    .collect::<Vec<_>>();
                (matched, true)
            })
            .filter(|(m, _)| m.len() >= 2 * MIN_SIDE)
            .collect();
        if references.is_empty() {
            let certified = touches
                .iter()
                .enumerate()
                .map(|(i, &k)| (i, k, Vector3::from(data.landmarks[data.obs[k].touched()].xyz_mm)))
                .collect::<Vec<_>>();
            if certified.len() >= 2 * MIN_SIDE {
                references.push((certified, false));
            }
        }
        let mut best: Option<(DisturbedBlock, bool)> = None;
        for (matched, twins) in references {
            let q: Vec<Vector3<f64>> = matched.iter().map(|m| m.2).collect();
            let pm: Vec<Vector3<f64>> = matched.iter().map(|m| p[m.1]).collect();
            let rss_of = |range: std::ops::Range<usize>| {
                let frame = Frame::fit(&q[range.clone()], &pm[range.clone()]);
                q[range.clone()]
                    .iter()
                    .zip(&pm[range])
                    .map(|(q, pm)| (pm - frame.apply(q)).norm_squared())
                    .sum::<f64>()
            };
            let rss0 = rss_of(0..matched.len());
            let splits = (MIN_SIDE..=matched.len() - MIN_SIDE).map(|i| {
                let rest = rss_of(0..i) + rss_of(i..matched.len());
                (i, rss0 - rest, rest)
            });
            let Some((i, drop, rest)) = splits.max_by(|a, b| a.1.total_cmp(&b.1)) else { continue };
            // Twins: differences of two touches, variance 2σ² per axis, χ²₆. Certified
            // positions: the arm's own errors stay in the residual, so the drop is judged
            // against what is left after the split (F with 6 and 3n − 12 degrees of freedom).
            let (chi2, exceeds) = if twins {
                let chi2 = drop / (2.0 * sigma2_mm2);
                (chi2, chi2 > split_limit)
            } else {
                let dof = (3 * matched.len()).saturating_sub(12).max(1) as f64;
                let f = (drop / 6.0) / (rest / dof).max(1e-300);
                (drop / sigma2_mm2, f_upper_tail(f, 6.0, dof) < normal_upper_tail(SPLIT_Z))
            };
            if best.as_ref().is_some_and(|b| b.0.chi2 >= chi2) {
                continue;
            }
            // How far apart the two rigid motions put the later touches.
            let (before, after) = (Frame::fit(&q[..i], &pm[..i]), Frame::fit(&q[i..], &pm[i..]));
            let moved =
                (q[i..].iter().map(|q| (before.apply(q) - after.apply(q)).norm_squared()).sum::<f64>()
                    / (matched.len() - i) as f64)
                    .sqrt();
            let (position, first, _) = matched[i];
            best = Some((
                DisturbedBlock {
                    placement: *placement,
                    repeat: *repeat,
                    after_touch: position,
                    first_moved: data.landmarks[data.obs[first].touched()].id.clone(),
                    chi2,
                    moved_mm: moved,
                },
                exceeds,
            ));
        }
        splits.extend(best.filter(|b| b.1).map(|b| b.0));
    }
    let touch_limit = chi2_quantile(3.0, TOUCH_Z);
    splits.sort_by(|a, b| b.chi2.total_cmp(&a.chi2));
    // A touch inside a disturbed block is explained by the block.
    singles.retain(|s| {
        let t = &data.obs[s.touch];
        s.chi2 > touch_limit && !splits.iter().any(|b| b.placement == t.group && b.repeat == t.repeat)
    });
    singles.sort_by(|a, b| b.chi2.total_cmp(&a.chi2));
    (splits, singles)
}

/// Where landmark `landmark` really is in the artefact frame, from its touches in `data`
/// (positions from `model`), each mapped back through a rigid fit of the other landmarks of its
/// block; `None` when no block has it and three others.
pub fn locate_landmark(model: &ArmModel, data: &Observations, landmark: usize) -> Option<[f64; 3]> {
    let p: Vec<Vector3<f64>> = crate::calib::nuisance::tool::positions(model, data);
    let mut sum = Vector3::zeros();
    let mut n = 0usize;
    for (_, touches) in blocks(data) {
        let (this, others): (Vec<usize>, Vec<usize>) =
            touches.iter().partition(|&&k| data.obs[k].landmark() == Some(landmark));
        if this.is_empty() || others.len() < 3 {
            continue;
        }
        let q: Vec<Vector3<f64>> =
            others.iter().map(|&k| Vector3::from(data.landmarks[data.obs[k].touched()].xyz_mm)).collect();
        let pm: Vec<Vector3<f64>> = others.iter().map(|&k| p[k]).collect();
        let frame = Frame::fit(&q, &pm);
        for &k in &this {
            sum += frame.rotation.transpose() * (p[k] - frame.translation_mm);
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
    cal: &Observations,
    landmark: usize,
    options: &SolveOptions,
) -> Result<(Fit, Vec<Landmark>), CalibError> {
    let without = calibrate(start, &cal.without_landmark(landmark), options)?;
    let corrected = located(&without.model, cal, landmark);
    let fit = calibrate(
        &without.model,
        &cal.with_landmarks(&corrected),
        &SolveOptions { restarts: Some(0), ..options.clone() },
    )?;
    Ok((fit, corrected))
}

/// As [`calibrate_with_landmark_freed`] from a calibrated model whose identifiable parameters
/// `params` are known: both fits are warm solves (no identifiability analysis, no restarts).
pub fn refit_with_landmark_freed(
    calibrated: &ArmModel,
    params: &[ParamId],
    cal: &Observations,
    landmark: usize,
    options: &SolveOptions,
) -> Result<(ArmModel, Vec<Landmark>), CalibError> {
    let without = solve_warm(calibrated, params, &cal.without_landmark(landmark), options)?;
    let corrected = located(&without, cal, landmark);
    Ok((solve_warm(&without, params, &cal.with_landmarks(&corrected), options)?, corrected))
}

/// `artefact` with landmark `landmark` where `model` locates it (unchanged when it cannot).
fn located(model: &ArmModel, cal: &Observations, landmark: usize) -> Vec<Landmark> {
    let mut corrected = cal.landmarks.clone();
    if let Some(xyz) = locate_landmark(model, cal, landmark) {
        corrected[landmark].xyz_mm = xyz;
    }
    corrected
}

/// Touches of the same landmark, placement and arm configuration (see
/// [`crate::calib::repeats::same_configuration`]).
fn repeat_groups(data: &Observations) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    for placement in 0..data.groups.len() {
        let mut landmarks: Vec<usize> =
            data.obs.iter().filter(|t| t.group == placement).map(|t| t.touched()).collect();
        landmarks.sort_unstable();
        landmarks.dedup();
        for l in landmarks {
            let idx: Vec<usize> = (0..data.obs.len())
                .filter(|&k| data.obs[k].group == placement && data.obs[k].landmark() == Some(l))
                .collect();
            out.extend(same_configuration(data, &idx));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Artefact, Landmark, ARTEFACT_FORMAT};
    use crate::model::kinematics::tool_pose;

    #[test]
    fn blocks_keep_the_measured_order() {
        let q: &[f64] = &[0.0; 6];
        let data = Observations::from_touches(
            &["A", "B"],
            Vec::new(),
            &[(0, 0, 1, q), (1, 0, 1, q), (0, 0, 1, q), (0, 0, 2, q)],
        );
        assert_eq!(blocks(&data), vec![((0, 1), vec![0, 2]), ((1, 1), vec![1]), ((0, 2), vec![3])]);
        assert_eq!(data.without(|k| k == 1).obs.len(), 3);
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
            certificate: None,
        };
        let touches: Vec<(usize, usize, u32, &[f64])> = (0..4).map(|l| (0, l, 1, &enc[l][..])).collect();
        let data = Observations::from_touches(&["A"], artefact.landmarks.clone(), &touches);
        let found = locate_landmark(&model, &data, 3).expect("located");
        assert!((Vector3::from(found) - p[3]).norm() < 1e-6, "{found:?} vs {:?}", p[3]);
    }
}
