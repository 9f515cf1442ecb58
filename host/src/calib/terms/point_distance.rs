//! Frame-free distances between the points an instrument measured in one session
//! ([`crate::data::point_distances`]): for two points a, b of a session,
//! r = ‖p_a − p_b‖ − ‖X_a − X_b‖ (mm), p the tool points the model predicts and X the measured
//! ones, one row per pair of the session's points. The instrument's frame cancels, so the term
//! has no unknown of its block: it is the distance between two touches
//! ([`super::distance::Distance`]) with the measured distance in place of the certified one.

use super::distance::Distance;
use super::Term;
use crate::data::Observations;

/// One distance term per pair of points of every frame-free session, in file order.
pub fn terms(data: &Observations) -> Vec<Box<dyn Term>> {
    let mut out: Vec<Box<dyn Term>> = Vec::new();
    for block in &data.blocks {
        let points: Vec<(usize, nalgebra::Vector3<f64>)> =
            block.members.iter().filter_map(|&k| Some((k, data.obs[k].unframed_mm()?))).collect();
        for (i, &(a, xa)) in points.iter().enumerate() {
            for &(b, xb) in &points[i + 1..] {
                out.push(Box::new(Distance::new(data, a, b, (xa - xb).norm())));
            }
        }
    }
    out
}
