//! Relative orientation of two touches of one block (the 6-DoF objective on an artefact): the
//! asymmetric pillars hold the tool perpendicular to the base plate at a certified yaw. For the
//! pairs of the distance terms: L·(z_a − z_b) (both tool axes along the plate normal) and
//! L·wrap(φ_ab − (ψ_b − ψ_a)), φ_ab the signed angle from tool x_a to x_b about the plate normal
//! n = −(z_a + z_b)/‖z_a + z_b‖. L (`lever_mm`) turns radians into millimetres so both kinds of
//! rows share one Huber threshold.

use super::{column, Term, TermInput, TermJacobian};
use crate::data::Observations;

/// Rows per pair: three for the tool-axis difference, one for yaw.
pub const ROWS: usize = 4;

/// L·(z_a − z_b) and L·wrap(φ_ab − Δψ).
pub struct RelativeOrientation {
    obs: [usize; 2],
    block: usize,
    yaw_rad: f64,
    lever_mm: f64,
}

/// The relative-orientation terms of `pairs` (touch indices of one block), weighed by `lever_mm`.
pub fn terms(data: &Observations, pairs: &[(usize, usize)], lever_mm: f64) -> Vec<Box<dyn Term>> {
    pairs
        .iter()
        .map(|&(a, b)| {
            let (la, lb) = (data.obs[a].touched(), data.obs[b].touched());
            let yaw_rad = (data.landmarks[lb].yaw_deg - data.landmarks[la].yaw_deg).to_radians();
            Box::new(RelativeOrientation { obs: [a, b], block: data.obs[a].block, yaw_rad, lever_mm })
                as Box<dyn Term>
        })
        .collect()
}

fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

impl Term for RelativeOrientation {
    fn rows(&self) -> usize {
        ROWS
    }

    fn block(&self) -> usize {
        self.block
    }

    fn observations(&self) -> &[usize] {
        &self.obs
    }

    fn is_position(&self) -> bool {
        false
    }

    fn evaluate(&self, at: &TermInput<'_>, r: &mut [f64], jac: Option<&mut TermJacobian>) {
        let [a, b] = self.obs;
        let lever = self.lever_mm;
        let (pa, pb) = (at.poses.of(a), at.poses.of(b));
        let axis_diff = pa.z_axis - pb.z_axis;
        let sum = pa.z_axis + pb.z_axis;
        let sum_norm = sum.norm().max(1e-12);
        let n_hat = sum / sum_norm;
        let normal = -n_hat;
        let cross = pa.x_axis.cross(&pb.x_axis);
        let (c, s) = (pa.x_axis.dot(&pb.x_axis), normal.dot(&cross));
        for i in 0..3 {
            r[i] = lever * axis_diff[i];
        }
        r[3] = lever * wrap_pi(s.atan2(c) - self.yaw_rad);
        let Some(j) = jac else { return };
        let (Some(da), Some(db)) = (at.poses.chain(a), at.poses.chain(b)) else { return };
        for col in 0..at.poses.arm {
            let (da, db) = (&da[col], &db[col]);
            let (dxa, dxb, dza, dzb) = (column(da, 1), column(db, 1), column(da, 2), column(db, 2));
            let dsum = dza + dzb;
            let dnormal = -(dsum - n_hat * n_hat.dot(&dsum)) / sum_norm;
            let dc = dxa.dot(&pb.x_axis) + pa.x_axis.dot(&dxb);
            let dcross = dxa.cross(&pb.x_axis) + pa.x_axis.cross(&dxb);
            let ds = dnormal.dot(&cross) + normal.dot(&dcross);
            j.push(
                col,
                &[
                    lever * (dza[0] - dzb[0]),
                    lever * (dza[1] - dzb[1]),
                    lever * (dza[2] - dzb[2]),
                    lever * (c * ds - s * dc) / (c * c + s * s).max(1e-300),
                ],
            );
        }
    }
}
