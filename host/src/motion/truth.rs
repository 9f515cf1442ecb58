//! A dynamic validation against a known truth (the emulator, the tests): the true path error of
//! every sample the validation compared, RMS per [`Category`], beside what it measured.
//!
//! The true error of tracker sample k is the true tool point at the instant it was taken against
//! the point the arm reported for that instant, after the best rigid registration over every
//! compared sample, as the validation registers the tracker.

use super::{Category, Dynamic, ErrorStat};
use nalgebra::Vector3;

/// One category: measured and true.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct TruthRow {
    /// The category.
    pub category: Category,
    /// What the validation measured.
    pub measured: ErrorStat,
    /// The true RMS error of the same samples, mm.
    pub truth_rms_mm: f64,
    /// The truth lies within the measured figure's 95 % uncertainty (or below its bound).
    pub agrees: bool,
}

/// The true tool point and the arm's reported point at one instant, both in the arm's base
/// frame, mm.
type PointPair = (Vector3<f64>, Vector3<f64>);

/// The true error by category; `points(k)` gives, for tracker sample k, the true tool point and
/// the arm's reported point at the instant it was taken (both in the arm's base frame, mm), or
/// None where the arm reported none (that sample is left out).
pub fn against_truth(d: &Dynamic, points: &dyn Fn(usize) -> Option<PointPair>) -> Vec<TruthRow> {
    let known: Vec<(&super::PathSample, PointPair)> =
        d.series.iter().filter_map(|s| points(s.index).map(|p| (s, p))).collect();
    let (from, to): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = known.iter().map(|(_, p)| *p).unzip();
    let (r, t) = crate::numerics::geometry::absolute_orientation(&from, &to);
    let squared: Vec<f64> = from.iter().zip(&to).map(|(q, p)| (r * q + t - p).norm_squared()).collect();
    d.categories
        .iter()
        .map(|(category, measured)| {
            let e: Vec<f64> =
                known.iter().zip(&squared).filter(|((s, _), _)| category.holds(s)).map(|(_, e)| *e).collect();
            let truth = (e.iter().sum::<f64>() / e.len().max(1) as f64).sqrt();
            let agrees = match (measured.rms_mm, measured.u95_mm, measured.below_mm) {
                (Some(rms), Some(u), _) => (rms - truth).abs() <= u,
                (_, _, Some(bound)) => truth <= bound,
                _ => false,
            };
            TruthRow { category: *category, measured: measured.clone(), truth_rms_mm: truth, agrees }
        })
        .collect()
}
