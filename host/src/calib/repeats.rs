//! Repeated touches: touches of the same landmark in the same placement and arm configuration
//! differ only by seating and encoder noise, since the arm's systematic errors are the same at
//! nearly the same pose. Their scatter about the group mean, pooled over every group, is the
//! covariance of one touch: the repeatability the noise floor ([`crate::calib::floor`]) is
//! built on, and the weight of artefact touches beside instrument points in a mixed fit.

use crate::calib::nuisance::tool::positions;
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::stats::chi2_quantile;
use nalgebra::{Matrix3, Vector3};

/// A (placement, landmark) group of repeats is left out of the floor when its scatter exceeds
/// the χ² quantile at this many standard normal deviations (one-sided p ≈ 3·10⁻⁵).
pub const GROUP_OUTLIER_Z: f64 = 4.0;

/// Joint angles (degrees, every joint) within which two touches count as the same arm
/// configuration; repeats in another configuration (elbow or wrist flipped) carry other
/// systematic errors and are not pooled as noise.
pub const SAME_CONFIGURATION_DEG: f64 = 3.0;

/// Two touches' angles are the same arm configuration: every joint within
/// [`SAME_CONFIGURATION_DEG`] (across 0°/360° too).
pub fn same_pose(a: &[f64], b: &[f64]) -> bool {
    a.iter().zip(b).all(|(a, b)| ((a - b + 180.0).rem_euclid(360.0) - 180.0).abs() < SAME_CONFIGURATION_DEG)
}

/// Split touches `idx` of one landmark in one placement into groups of the same configuration.
pub fn same_configuration(data: &Observations, idx: &[usize]) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for &k in idx {
        let close = |g: &Vec<usize>| same_pose(&data.obs[g[0]].q_deg, &data.obs[k].q_deg);
        match groups.iter_mut().find(|g| close(g)) {
            Some(g) => g.push(k),
            None => groups.push(vec![k]),
        }
    }
    groups
}

/// The repeats of a calibration and a validation dataset pooled.
#[derive(Clone, Debug)]
pub struct Repeats {
    /// Covariance of one touch about its group mean, mm².
    pub cov: Matrix3<f64>,
    /// Degrees of freedom per axis: Σ (n − 1) over the groups pooled.
    pub dof: usize,
    /// Groups pooled.
    pub groups: usize,
    /// Groups left out as inconsistent: (placement, landmark id, scatter per axis mm).
    pub inconsistent: Vec<(String, String, f64)>,
}

/// Pool the repeats of `cal` and `val` (positions from `model`): groups of one landmark, one
/// placement and one configuration, those beyond the χ² quantile at [`GROUP_OUTLIER_Z`] of the
/// pooled variance left out (three rounds). `None` when no landmark was touched twice.
pub fn pool_repeats(model: &ArmModel, cal: &Observations, val: &Observations) -> Option<Repeats> {
    struct Group {
        placement: String,
        landmark: usize,
        scatter: Matrix3<f64>,
        dof: usize,
    }
    let mut groups: Vec<Group> = Vec::new();
    for data in [cal, val] {
        let p: Vec<Vector3<f64>> = positions(model, data);
        for placement in 0..data.groups.len() {
            for landmark in 0..data.landmarks.len() {
                let idx: Vec<usize> = (0..p.len())
                    .filter(|&k| data.obs[k].group == placement && data.obs[k].landmark() == Some(landmark))
                    .collect();
                for members in same_configuration(data, &idx) {
                    if members.len() < 2 {
                        continue;
                    }
                    let mean = members.iter().map(|&k| p[k]).sum::<Vector3<f64>>() / members.len() as f64;
                    let scatter = members.iter().map(|&k| (p[k] - mean) * (p[k] - mean).transpose()).sum();
                    groups.push(Group {
                        placement: data.groups[placement].name.clone(),
                        landmark,
                        scatter,
                        dof: members.len() - 1,
                    });
                }
            }
        }
    }
    if groups.is_empty() {
        return None;
    }
    // Pool, then leave out groups beyond the χ² quantile of their own degrees of freedom, twice.
    let per_axis = |g: &Group| g.scatter.trace() / (3 * g.dof) as f64;
    let mut keep = vec![true; groups.len()];
    for _ in 0..3 {
        let (sum, n) = groups
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .fold((0.0, 0), |(s, n), (g, _)| (s + g.scatter.trace(), n + 3 * g.dof));
        if n == 0 {
            return None;
        }
        let sigma2 = sum / n as f64;
        for (g, k) in groups.iter().zip(keep.iter_mut()) {
            let nu = (3 * g.dof) as f64;
            *k = per_axis(g) <= sigma2 * chi2_quantile(nu, GROUP_OUTLIER_Z) / nu;
        }
    }
    let (mut pooled, mut dof, mut used) = (Matrix3::zeros(), 0, 0);
    let mut inconsistent = Vec::new();
    for (g, k) in groups.iter().zip(&keep) {
        if *k {
            pooled += g.scatter;
            dof += g.dof;
            used += 1;
        } else {
            inconsistent.push((
                g.placement.clone(),
                cal.landmarks[g.landmark].id.clone(),
                per_axis(g).sqrt(),
            ));
        }
    }
    if dof == 0 {
        return None;
    }
    Some(Repeats { cov: pooled / dof as f64, dof, groups: used, inconsistent })
}

/// Per-axis scatter of one touch about its group mean, mm, from the repeated touches of `data`
/// alone (see [`crate::calib::floor::NoiseFloor::touch_std_mm`]); `None` without a landmark touched twice.
pub fn touch_std_mm(model: &ArmModel, data: &Observations) -> Option<f64> {
    pool_repeats(model, data, &data.without(|_| true)).map(|r| (r.cov.trace() / 3.0).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeats_in_another_configuration_are_not_pooled() {
        let data = Observations::from_touches(
            &["A"],
            Vec::new(),
            &[
                (0, 0, 1, &[10.0, 20.0, 30.0, 40.0, 50.0, 359.5]),
                (0, 0, 1, &[10.5, 20.2, 29.8, 40.1, 50.0, 0.5]), // across 0°/360°: same configuration
                (0, 0, 1, &[10.0, 20.0, 30.0, 220.0, 310.0, 180.0]), // wrist flipped
            ],
        );
        assert_eq!(same_configuration(&data, &[0, 1, 2]), vec![vec![0, 1], vec![2]]);
    }
}
