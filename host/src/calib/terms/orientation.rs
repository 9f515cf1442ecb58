//! A 6-DoF probe's measured orientation: R_meas = R(B_s)·R(F(q))·R_t, with R_t the probe's
//! orientation on the flange, shared by all sessions. The residual is the rotation vector of
//! R_predᵀ·R_meas (rad) times σ_position/σ_orientation (mm/rad), so that a residual of one stated
//! σ weighs the same in an orientation axis as in a point's coordinate.

use super::{Term, TermInput, TermJacobian};
use crate::calib::nuisance::frame::rotation_vector;
use crate::calib::nuisance::tool::flange_rotation;
use crate::data::Observations;
use nalgebra::Vector3;

/// The rotation vector of R_predᵀ·R_meas, weighed.
pub struct Orientation {
    obs: [usize; 1],
    block: usize,
    weight_mm_per_rad: f64,
}

/// The orientation terms of every observation with a measured orientation, in file order.
pub fn terms(data: &Observations, weight_mm_per_rad: f64) -> Vec<Box<dyn Term>> {
    (0..data.obs.len())
        .filter(|&k| data.obs[k].orientation().is_some())
        .map(|k| {
            Box::new(Orientation { obs: [k], block: data.obs[k].block, weight_mm_per_rad }) as Box<dyn Term>
        })
        .collect()
}

impl Term for Orientation {
    fn rows(&self) -> usize {
        3
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

    fn weight(&self) -> f64 {
        self.weight_mm_per_rad
    }

    fn evaluate(&self, at: &TermInput<'_>, r: &mut [f64], jac: Option<&mut TermJacobian>) {
        let (k, s) = (self.obs[0], self.block);
        let Some(measured) = at.data.obs[k].orientation() else { return };
        let pose = at.poses.of(k);
        let flange = flange_rotation(pose);
        let base = &at.state.frames[s];
        let predicted = base.rotation * flange * at.state.probe;
        let w = self.weight_mm_per_rad;
        let e = rotation_vector(&(predicted.transpose() * measured.to_rotation_matrix().into_inner())) * w;
        r.copy_from_slice(e.as_slice());
        let Some(jac) = jac else { return };
        let Some(chain) = at.poses.chain(k) else { return };
        // r ≈ r₀ − δ, δ the rotation of the prediction in its own frame.
        let to_body = predicted.transpose() * base.rotation;
        let y_axis = pose.z_axis.cross(&pose.x_axis);
        for (c, d) in chain.iter().enumerate() {
            let (dx, dz) = (Vector3::new(d[3], d[4], d[5]), Vector3::new(d[6], d[7], d[8]));
            let dy = dz.cross(&pose.x_axis) + pose.z_axis.cross(&dx);
            let spin = 0.5 * (pose.x_axis.cross(&dx) + y_axis.cross(&dy) + pose.z_axis.cross(&dz));
            jac.push3(c, to_body * spin * -w);
        }
        if let Some(b) = at.layout.frame_column(s) {
            let g = predicted.transpose() * at.state.frame_turns[s] * -w;
            for k in 0..3 {
                jac.push3(b + k, g.column(k).into_owned());
            }
        }
        if let Some(t) = at.layout.rotation_column() {
            for k in 0..3 {
                jac.push3(t + k, at.state.probe_turn.column(k) * -w);
            }
        }
    }
}
