//! Wild tracker samples: a marker swap, a reflection or a glitch puts a sample metres or tens of
//! degrees away from its neighbours. Within each unbroken segment, a sample is rejected when it
//! lies more than [`WILD_MM`] from the component-wise median of its neighbours (up to
//! [`WINDOW`] on each side) or its rotation is more than [`WILD_DEG`] (median) from theirs.
//! Samples with fewer than two neighbours in their segment cannot be checked and are dropped.

use super::recording::TargetStream;
use crate::numerics::stats::median;
use nalgebra::Vector3;

/// Largest distance from the neighbours' median position, mm.
pub const WILD_MM: f64 = 25.0;
/// Largest median rotation angle to the neighbours, degrees.
pub const WILD_DEG: f64 = 20.0;
/// Neighbours on each side.
pub const WINDOW: usize = 3;

/// The stream without its wild samples, and how many were removed.
pub fn reject_wild(s: &TargetStream) -> (TargetStream, usize) {
    let mut keep = Vec::with_capacity(s.t_s.len());
    for seg in s.segments() {
        for i in seg.clone() {
            let lo = i.saturating_sub(WINDOW).max(seg.start);
            let hi = (i + WINDOW + 1).min(seg.end);
            let neighbours: Vec<usize> = (lo..hi).filter(|&j| j != i).collect();
            if neighbours.len() < 2 {
                continue;
            }
            let med =
                Vector3::from_fn(|k, _| median(neighbours.iter().map(|&j| s.position_mm[j][k]).collect()));
            let angle = median(neighbours.iter().map(|&j| s.rotation[i].angle_to(&s.rotation[j])).collect());
            if (s.position_mm[i] - med).norm() <= WILD_MM && angle.to_degrees() <= WILD_DEG {
                keep.push(i);
            }
        }
    }
    let removed = s.t_s.len() - keep.len();
    (s.subset(&keep), removed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    #[test]
    fn wild_samples_go_and_fast_motion_stays() {
        // 60 Hz, 400 mm/s and 180°/s: fast but smooth; two wild samples.
        let mut s = TargetStream::default();
        for k in 0..300 {
            let t = k as f64 / 60.0;
            s.t_s.push(t);
            s.position_mm.push(Vector3::new(100.0 * (4.0 * t).sin(), 50.0 * t, 0.0));
            s.rotation.push(UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::PI * t));
        }
        s.position_mm[40].x += 10_000.0;
        s.rotation[200] = UnitQuaternion::from_euler_angles(1.0, 0.5, 0.0) * s.rotation[200];
        let (clean, removed) = reject_wild(&s);
        assert_eq!(removed, 2);
        assert!(!clean.t_s.contains(&s.t_s[40]) && !clean.t_s.contains(&s.t_s[200]));
    }
}
