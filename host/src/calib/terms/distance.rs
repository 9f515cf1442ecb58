//! Distance between two touches of one block (thesis eq. 3.1): for touches a, b of different
//! landmarks in one placement and repeat, r = ‖p_a − p_b‖ − D_ab (mm), D_ab the certified
//! distance. Frame-free: the artefact's placement never enters. With the tool floated in the
//! placement (`--float-tool`), p = p_flange + R_F·Δ; the arm's columns leave out ∂(R_F·Δ)/∂θ
//! (second order for an offset of millimetres; the residuals themselves are exact).

use super::{ArmPositions, Term, TermInput, TermJacobian};
use crate::calib::nuisance::tool::flange_rotation;
use crate::data::Observations;
use crate::model::kinematics::PoseDerivative;
use nalgebra::Vector3;
use wide::f64x2;

/// ‖p_a − p_b‖ − D_ab.
pub struct Distance {
    obs: [usize; 2],
    block: usize,
    group: usize,
    distance_mm: f64,
}

impl Distance {
    /// The distance between the tool points of observations `a` and `b` of one block against
    /// `distance_mm` (certified, or measured by a frame-free instrument).
    pub fn new(data: &Observations, a: usize, b: usize, distance_mm: f64) -> Distance {
        Distance { obs: [a, b], block: data.obs[a].block, group: data.obs[a].group, distance_mm }
    }
}

/// The distance terms of `pairs` (touch indices of one block).
pub fn terms(data: &Observations, pairs: &[(usize, usize)]) -> Vec<Box<dyn Term>> {
    pairs
        .iter()
        .map(|&(a, b)| {
            let (la, lb) = (data.obs[a].touched(), data.obs[b].touched());
            Box::new(Distance::new(data, a, b, data.landmark_distance_mm(la, lb))) as Box<dyn Term>
        })
        .collect()
}

impl Term for Distance {
    fn rows(&self) -> usize {
        1
    }

    fn block(&self) -> usize {
        self.block
    }

    fn observations(&self) -> &[usize] {
        &self.obs
    }

    fn evaluate(&self, at: &TermInput<'_>, r: &mut [f64], jac: Option<&mut TermJacobian>) {
        let tool = at.layout.tool_column(self.group);
        let Some(j) = jac else {
            // No direction without derivatives: the length alone.
            r[0] = self.difference(at, tool.is_some()).norm() - self.distance_mm;
            return;
        };
        let (residual, u) = self.residual_and_direction(at, tool.is_some());
        r[0] = residual;
        let [a, b] = self.obs;
        let (Some(da), Some(db)) = (at.poses.chain(a), at.poses.chain(b)) else { return };
        j.columns.extend(0..at.poses.arm);
        j.values.extend(da.iter().zip(db).map(|(a, b)| arm_derivative(&u, a, b)));
        if let Some(t) = tool {
            let (pa, pb) = (at.poses.of(a), at.poses.of(b));
            let g = (flange_rotation(pa) - flange_rotation(pb)).transpose() * u;
            for k in 0..3 {
                j.push(t + k, &[g[k]]);
            }
        }
    }

    fn evaluate_into_row(
        &self,
        at: &TermInput<'_>,
        positions: &ArmPositions,
        r: &mut f64,
        row: &mut [f64],
    ) -> bool {
        if at.layout.tool_column(self.group).is_some() || row.len() != positions.arm() {
            return false;
        }
        let u;
        (*r, u) = self.residual_and_direction(at, false);
        let [a, b] = self.obs;
        arm_row(&u, positions.of_observation(a), positions.of_observation(b), row);
        true
    }
}

impl Distance {
    /// The residual ‖p_a − p_b‖ − D_ab and the unit vector u from p_b to p_a, the tool points
    /// carrying the group's offset when its tool floats (`floated`).
    fn residual_and_direction(&self, at: &TermInput<'_>, floated: bool) -> (f64, Vector3<f64>) {
        let diff = self.difference(at, floated);
        let length = diff.norm();
        (length - self.distance_mm, diff / length.max(1e-12))
    }

    /// p_a − p_b, the tool points carrying the group's offset when its tool floats (`floated`).
    fn difference(&self, at: &TermInput<'_>, floated: bool) -> Vector3<f64> {
        let [a, b] = self.obs;
        let (pa, pb) = (at.poses.of(a), at.poses.of(b));
        if floated {
            let offset = &at.state.tools[self.group];
            (pa.position_mm + flange_rotation(pa) * offset) - (pb.position_mm + flange_rotation(pb) * offset)
        } else {
            pa.position_mm - pb.position_mm
        }
    }
}

/// The row's derivative by one arm column: u·(∂p_a/∂c − ∂p_b/∂c), u the unit vector from b to a.
fn arm_derivative(u: &Vector3<f64>, a: &PoseDerivative, b: &PoseDerivative) -> f64 {
    u.x * (a[0] - b[0]) + u.y * (a[1] - b[1]) + u.z * (a[2] - b[2])
}

/// The row's derivatives by every arm column ([`arm_derivative`] of each, the same operations in
/// the same order) from the pairs of columns of the two touches' position derivatives (of
/// [`ArmPositions`]), two columns per `f64x2`: one packed subtract, multiply or add serves both
/// (no fused multiply-add: the values are those of one column alone, to the bit).
fn arm_row(u: &Vector3<f64>, a: &[[f64; 6]], b: &[[f64; 6]], row: &mut [f64]) {
    let [ux, uy, uz] = [u.x, u.y, u.z].map(f64x2::splat);
    let values = |a: &[f64; 6], b: &[f64; 6]| {
        let axis = |k: usize| f64x2::new([a[k], a[k + 1]]) - f64x2::new([b[k], b[k + 1]]);
        ux * axis(0) + uy * axis(2) + uz * axis(4)
    };
    let (whole, last) = row.as_chunks_mut::<2>();
    for ((out, a), b) in whole.iter_mut().zip(a).zip(b) {
        *out = values(a, b).to_array();
    }
    // An odd column count: the last column is its pair's first lane.
    if let ([last], Some(a), Some(b)) = (last, a.get(whole.len()), b.get(whole.len())) {
        *last = values(a, b).as_array()[0];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::layout::Layout;
    use crate::calib::problem::Problem;
    use crate::calib::terms::{build, Poses, TermChoice};
    use crate::model::ArmModel;
    use nalgebra::Matrix3;

    /// A row read from the laid-out position derivatives is [`arm_derivative`] of each column
    /// to the bit, for odd and even column counts, with derivatives that are not finite (a
    /// NaN, an infinity) among them.
    #[test]
    fn a_row_from_the_laid_out_positions_is_each_columns_derivative() {
        let mut next = crate::calib::terms::uniform_signed(0x9e37_79b9_7f4a_7c15_u64);
        let same = |a: f64, b: f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        for arm in [1, 2, 13, 14, 25] {
            let observations = 5;
            let mut chain: Vec<PoseDerivative> =
                (0..observations * arm).map(|_| std::array::from_fn(|_| next() * 1e3)).collect();
            chain[arm][0] = f64::NAN;
            chain[2 * arm + arm - 1][2] = f64::INFINITY;
            let poses = Poses { first: 7, pose: vec![None; observations], chain, arm, jacobian: true };
            let positions = ArmPositions::of(&poses).expect("derivatives");
            let mut row = vec![0.0; arm];
            for (a, b) in [(7, 8), (9, 7), (10, 11), (11, 9)] {
                let u = Vector3::new(next(), next(), next()).normalize();
                arm_row(&u, positions.of_observation(a), positions.of_observation(b), &mut row);
                let (da, db) = (poses.chain(a).expect("jacobian"), poses.chain(b).expect("jacobian"));
                for (c, v) in row.iter().enumerate() {
                    let plain = arm_derivative(&u, &da[c], &db[c]);
                    assert!(same(*v, plain), "{arm} columns, pair {a} {b}, column {c}: {v} {plain}");
                }
            }
        }
    }

    /// The residual alone (no direction computed) is the one evaluated with the Jacobian, to the
    /// bit, with the tool fixed or floated.
    #[test]
    fn the_residual_alone_is_the_one_with_the_jacobian() {
        let nominal = ArmModel::suta_nominal();
        let options = crate::simulate::SimulationOptions { seed: 3, ..Default::default() };
        let sim = crate::simulate::simulate(&nominal, &options);
        let data = Observations::from_sessions(&sim.calibration, &sim.artefact);
        let choice = TermChoice {
            relative_orientation_lever_mm: None,
            orientation_weight_mm_per_rad: None,
            point_weight: 1.0,
        };
        let terms = build(&data, &choice);
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        for floated in [false, true] {
            let tools = vec![floated; data.groups.len()];
            let layout =
                Layout::new(params.clone(), &vec![false; blocks], &tools, false, &vec![None; blocks]);
            let problem =
                Problem::new(layout, &nominal, &data, &terms, vec![Matrix3::identity(); blocks], None);
            let mut x: Vec<f64> = params.iter().map(|id| nominal.get(*id) + 1e-3).collect();
            x.resize(problem.layout.unknowns(), 0.5);
            let state = problem.state(&x);
            let poses = problem.poses(&state, true);
            let at = TermInput { state: &state, layout: &problem.layout, data: &data, poses: &poses };
            let mut jac = TermJacobian::default();
            assert!(terms.len() > 100);
            for t in &terms {
                let (mut alone, mut with_jacobian) = ([0.0], [0.0]);
                t.evaluate(&at, &mut alone, None);
                jac.reset(1);
                t.evaluate(&at, &mut with_jacobian, Some(&mut jac));
                assert_eq!(alone, with_jacobian, "floated {floated}");
            }
        }
    }
}
