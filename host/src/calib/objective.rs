//! The calibration objective as residual blocks over one dataset.
//!
//! * Distance block (thesis eq. 3.1): for touches a, b of different landmarks in one placement
//!   and repeat, r = ‖p_a − p_b‖ − D_ab (mm), D_ab the certified distance.
//! * Orientation block (6-DoF objective): the asymmetric pillars hold the tool perpendicular to
//!   the base plate at a certified yaw. For the same pairs: L·(z_a − z_b) (both tool axes along
//!   the plate normal) and L·wrap(φ_ab − (ψ_b − ψ_a)), φ_ab the signed angle from tool x_a to
//!   x_b about the plate normal n = −(z_a + z_b)/‖z_a + z_b‖. L (`lever_mm`) turns radians into
//!   millimetres so both blocks share one Huber threshold.

use crate::data::{Artefact, Observation, Observations};
use crate::model::kinematics::{tool_pose, tool_pose_with_jacobian, ColumnMap, PoseDerivative, ToolPose};
use crate::model::{ArmModel, ParamId};
use crate::numerics::solver::Residuals;
use nalgebra::Vector3;

/// Which residual blocks the calibration minimises.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Objective {
    /// Pairwise distances only (the thesis).
    Distance,
    /// Distances plus relative orientation between touches of one placement.
    SixDof {
        /// Millimetres per radian of orientation error.
        lever_mm: f64,
    },
}

/// Rows per orientation pair: three for the tool-axis difference, one for yaw.
const ORIENTATION_ROWS: usize = 4;

/// Residuals of one dataset as a function of the free parameters `params`.
pub struct CalibrationProblem<'a> {
    base: &'a ArmModel,
    params: Vec<ParamId>,
    columns: ColumnMap,
    touches: &'a [Observation],
    /// (touch a, touch b, certified distance mm, certified yaw difference rad)
    pairs: Vec<(usize, usize, f64, f64)>,
    lever_mm: Option<f64>,
}

impl<'a> CalibrationProblem<'a> {
    /// Set up the problem; parameters not in `params` keep their values in `base`.
    pub fn new(
        base: &'a ArmModel,
        params: Vec<ParamId>,
        artefact: &Artefact,
        data: &'a Observations,
        objective: Objective,
    ) -> Self {
        let pairs = data
            .landmark_pairs()
            .into_iter()
            .map(|(a, b)| {
                let (la, lb) = (data.obs[a].landmark().unwrap_or(0), data.obs[b].landmark().unwrap_or(0));
                let yaw = (artefact.landmarks[lb].yaw_deg - artefact.landmarks[la].yaw_deg).to_radians();
                (a, b, artefact.distance_mm(la, lb), yaw)
            })
            .collect();
        let lever_mm = match objective {
            Objective::Distance => None,
            Objective::SixDof { lever_mm } => Some(lever_mm),
        };
        CalibrationProblem {
            base,
            columns: ColumnMap::new(&params),
            params,
            touches: &data.obs,
            pairs,
            lever_mm,
        }
    }

    /// The free parameters, in column order.
    pub fn params(&self) -> &[ParamId] {
        &self.params
    }

    /// Number of distance residuals (they come first).
    pub fn distance_rows(&self) -> usize {
        self.pairs.len()
    }

    /// The model with the free parameters set to `x`.
    pub fn model_at(&self, x: &[f64]) -> ArmModel {
        let mut model = self.base.clone();
        for (id, v) in self.params.iter().zip(x) {
            model.set(*id, *v);
        }
        model
    }
}

fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

fn column(d: &PoseDerivative, k: usize) -> Vector3<f64> {
    Vector3::new(d[3 * k], d[3 * k + 1], d[3 * k + 2])
}

impl Residuals for CalibrationProblem<'_> {
    fn len(&self) -> usize {
        self.pairs.len() * if self.lever_mm.is_some() { 1 + ORIENTATION_ROWS } else { 1 }
    }

    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
        let model = self.model_at(x);
        let n = self.params.len();
        let Some(jac) = jacobian else {
            let poses: Vec<ToolPose> = self.touches.iter().map(|t| tool_pose(&model, &t.q_deg)).collect();
            self.fill(&poses, None, r, None);
            return;
        };
        let mut derivs = vec![[0.0; 9]; self.touches.len() * n];
        let poses: Vec<ToolPose> = self
            .touches
            .iter()
            .zip(derivs.chunks_exact_mut(n.max(1)))
            .map(|(t, d)| tool_pose_with_jacobian(&model, &t.q_deg, &self.columns, &mut d[..n]))
            .collect();
        self.fill(&poses, Some(&derivs), r, Some(jac));
    }
}

impl CalibrationProblem<'_> {
    fn fill(
        &self,
        poses: &[ToolPose],
        derivs: Option<&[PoseDerivative]>,
        r: &mut [f64],
        mut jac: Option<&mut [f64]>,
    ) {
        let n = self.params.len();
        let d_of = |touch: usize, c: usize| derivs.map(|d| &d[touch * n + c]);
        for (row, &(a, b, distance, _)) in self.pairs.iter().enumerate() {
            let diff = poses[a].position_mm - poses[b].position_mm;
            let length = diff.norm();
            r[row] = length - distance;
            if let Some(j) = jac.as_deref_mut() {
                let u = diff / length.max(1e-12);
                for c in 0..n {
                    let (da, db) = (d_of(a, c).map(|d| column(d, 0)), d_of(b, c).map(|d| column(d, 0)));
                    j[row * n + c] = u.dot(&(da.unwrap_or_default() - db.unwrap_or_default()));
                }
            }
        }
        let Some(lever) = self.lever_mm else { return };
        let base_row = self.pairs.len();
        for (k, &(a, b, _, yaw)) in self.pairs.iter().enumerate() {
            let row = base_row + k * ORIENTATION_ROWS;
            let (pa, pb) = (&poses[a], &poses[b]);
            let axis_diff = pa.z_axis - pb.z_axis;
            let sum = pa.z_axis + pb.z_axis;
            let sum_norm = sum.norm().max(1e-12);
            let n_hat = sum / sum_norm;
            let normal = -n_hat;
            let cross = pa.x_axis.cross(&pb.x_axis);
            let (c, s) = (pa.x_axis.dot(&pb.x_axis), normal.dot(&cross));
            for i in 0..3 {
                r[row + i] = lever * axis_diff[i];
            }
            r[row + 3] = lever * wrap_pi(s.atan2(c) - yaw);
            let Some(j) = jac.as_deref_mut() else { continue };
            for col in 0..n {
                let (Some(da), Some(db)) = (d_of(a, col), d_of(b, col)) else { continue };
                let (dxa, dxb, dza, dzb) = (column(da, 1), column(db, 1), column(da, 2), column(db, 2));
                for i in 0..3 {
                    j[(row + i) * n + col] = lever * (dza[i] - dzb[i]);
                }
                let dsum = dza + dzb;
                let dnormal = -(dsum - n_hat * n_hat.dot(&dsum)) / sum_norm;
                let dc = dxa.dot(&pb.x_axis) + pa.x_axis.dot(&dxb);
                let dcross = dxa.cross(&pb.x_axis) + pa.x_axis.cross(&dxb);
                let ds = dnormal.dot(&cross) + normal.dot(&dcross);
                j[(row + 3) * n + col] = lever * (c * ds - s * dc) / (c * c + s * s).max(1e-300);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{Joints, Kind, Landmark, Observation, Target};

    #[test]
    fn six_dof_jacobian_matches_central_differences() {
        let model = ArmModel::suta_nominal();
        let artefact = Artefact {
            format: crate::data::ARTEFACT_FORMAT.into(),
            landmarks: (0..3)
                .map(|i| Landmark {
                    id: format!("L{i}"),
                    xyz_mm: [10.0 * i as f64, 5.0, 20.0],
                    yaw_deg: 30.0 * i as f64,
                })
                .collect(),
        };
        let touch = |landmark, q: [f64; 6]| Observation {
            block: 0,
            group: 0,
            repeat: 1,
            q_deg: Joints::new(&q).unwrap(),
            q_sigma_deg: None,
            target: Target::Landmark(landmark),
            sigma_mm: None,
            time_s: None,
            temp_c: None,
            pose: None,
            line: 1,
        };
        let mut data = Observations::new(6, artefact.landmarks.clone());
        data.push_group("A".into(), "A.json".into(), Kind::Artefact);
        data.obs = vec![
            touch(0, [10.0, 200.0, 30.0, 300.0, 40.0, 120.0]),
            touch(1, [12.0, 205.0, 28.0, 290.0, 45.0, 100.0]),
            touch(2, [8.0, 190.0, 35.0, 310.0, 50.0, 80.0]),
        ];
        data.rebuild_blocks();
        let params: Vec<ParamId> = ParamId::all();
        let problem = CalibrationProblem::new(
            &model,
            params.clone(),
            &artefact,
            &data,
            Objective::SixDof { lever_mm: 100.0 },
        );
        let x: Vec<f64> = params.iter().map(|p| model.get(*p)).collect();
        let (m, n) = (problem.len(), x.len());
        let mut r = vec![0.0; m];
        let mut jac = vec![0.0; m * n];
        problem.evaluate(&x, &mut r, Some(&mut jac));
        for c in 0..n {
            let h = 1e-6;
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[c] += h;
            xm[c] -= h;
            let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
            problem.evaluate(&xp, &mut rp, None);
            problem.evaluate(&xm, &mut rm, None);
            for i in 0..m {
                let fd = (rp[i] - rm[i]) / (2.0 * h);
                assert!(
                    (jac[i * n + c] - fd).abs() < 1e-4 * (1.0 + fd.abs()),
                    "row {i} {}: {} vs {fd}",
                    params[c],
                    jac[i * n + c]
                );
            }
        }
    }
}
