//! Forward kinematics of the arm model and its exact Jacobian.
//!
//! The chain is a product of elementary transforms E_1 … E_M (rotations about and translations
//! along x, y, z). For an elementary op m whose value depends on a parameter q, the derivative of
//! the tool point is dp/dq = R_{<m} · (∂E_m/∂v · v_{>m}) · ∂v/∂q, where R_{<m} is the rotation of
//! the ops before m and v_{>m} is the tool point expressed in the frame after op m. For a rotation
//! about axis a that is a × (E_m v_{>m}); for a translation along a it is a. One forward pass for
//! the prefix rotations and one backward pass for the tool point give every column exactly.

use super::params::PARAM_SLOTS;
use super::{ArmModel, Convention, ParamId, JOINTS};
use nalgebra::{Matrix3, Vector3};

const DEG: f64 = std::f64::consts::PI / 180.0;

/// Pose of the tool in the base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolPose {
    /// Tool centre point, millimetres.
    pub position_mm: Vector3<f64>,
    /// Tool x axis (unit).
    pub x_axis: Vector3<f64>,
    /// Tool z axis (unit), pointing from the flange to the tip.
    pub z_axis: Vector3<f64>,
}

/// Derivatives of one [`ToolPose`] with respect to one parameter:
/// `[dp_x, dp_y, dp_z, dx_x, dx_y, dx_z, dz_x, dz_y, dz_z]` (mm or 1 per parameter unit).
pub type PoseDerivative = [f64; 9];

/// Maps each parameter to its Jacobian column, if it is one of the columns wanted.
#[derive(Clone, Debug)]
pub struct ColumnMap {
    slots: [Option<usize>; PARAM_SLOTS],
    len: usize,
}

impl ColumnMap {
    /// Columns for `params`, in that order.
    pub fn new(params: &[ParamId]) -> ColumnMap {
        let mut slots = [None; PARAM_SLOTS];
        for (c, p) in params.iter().enumerate() {
            slots[p.dense_index()] = Some(c);
        }
        ColumnMap { slots, len: params.len() }
    }

    /// Number of columns.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no column is wanted.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn column(&self, id: ParamId) -> Option<usize> {
        self.slots[id.dense_index()]
    }
}

#[derive(Clone, Copy)]
enum Axis {
    X,
    Y,
    Z,
}

impl Axis {
    fn unit(self) -> Vector3<f64> {
        match self {
            Axis::X => Vector3::x(),
            Axis::Y => Vector3::y(),
            Axis::Z => Vector3::z(),
        }
    }
}

#[derive(Clone, Copy)]
enum OpKind {
    Rotate(Axis),
    Translate(Axis),
}

/// One elementary transform; `param` is the parameter its value moves with and dvalue/dparam.
#[derive(Clone, Copy)]
struct Op {
    kind: OpKind,
    value: f64,
    param: Option<(ParamId, f64)>,
}

impl Op {
    fn rotation(&self) -> Matrix3<f64> {
        match self.kind {
            OpKind::Translate(_) => Matrix3::identity(),
            OpKind::Rotate(axis) => {
                let (s, c) = self.value.sin_cos();
                match axis {
                    Axis::X => Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
                    Axis::Y => Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
                    Axis::Z => Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
                }
            }
        }
    }
}

const OPS_PER_JOINT: usize = 5;
const OPS: usize = JOINTS * OPS_PER_JOINT + 3;

fn rot(axis: Axis, value_deg: f64, id: ParamId) -> Op {
    Op { kind: OpKind::Rotate(axis), value: value_deg * DEG, param: Some((id, DEG)) }
}

fn shift(axis: Axis, value_mm: f64, id: ParamId) -> Op {
    Op { kind: OpKind::Translate(axis), value: value_mm, param: Some((id, 1.0)) }
}

/// The elementary ops of the chain for encoder angles `enc_deg`.
fn chain(model: &ArmModel, enc_deg: &[f64; JOINTS]) -> [Op; OPS] {
    let mut ops = [Op { kind: OpKind::Translate(Axis::X), value: 0.0, param: None }; OPS];
    for (j, joint) in model.joints.iter().enumerate() {
        let theta = rot(Axis::Z, enc_deg[j] + joint.offset_deg, ParamId::Offset(j));
        let d = shift(Axis::Z, joint.d_mm, ParamId::Length(j));
        let a = shift(Axis::X, joint.a_mm, ParamId::LinkOffset(j));
        let alpha = rot(Axis::X, joint.alpha_deg, ParamId::Twist(j));
        let beta = rot(Axis::Y, joint.axis_deg, ParamId::Axis(j));
        let row = match model.convention {
            Convention::Classic => [theta, d, a, alpha, beta],
            Convention::Modified => [alpha, beta, a, theta, d],
        };
        ops[j * OPS_PER_JOINT..(j + 1) * OPS_PER_JOINT].copy_from_slice(&row);
    }
    let tcp = &mut ops[JOINTS * OPS_PER_JOINT..];
    for (k, axis) in [Axis::X, Axis::Y, Axis::Z].into_iter().enumerate() {
        tcp[k] = shift(axis, model.tcp_mm[k], ParamId::Tcp(k));
    }
    ops
}

/// Tool pose for raw encoder angles `enc_deg` (degrees).
pub fn tool_pose(model: &ArmModel, enc_deg: &[f64; JOINTS]) -> ToolPose {
    evaluate(model, enc_deg, None)
}

/// Tool pose and its derivatives for the parameters in `columns`, written to `jacobian`
/// (one [`PoseDerivative`] per column; `jacobian.len()` must be `columns.len()`).
pub fn tool_pose_with_jacobian(
    model: &ArmModel,
    enc_deg: &[f64; JOINTS],
    columns: &ColumnMap,
    jacobian: &mut [PoseDerivative],
) -> ToolPose {
    evaluate(model, enc_deg, Some((columns, jacobian)))
}

fn evaluate(
    model: &ArmModel,
    enc_deg: &[f64; JOINTS],
    mut wanted: Option<(&ColumnMap, &mut [PoseDerivative])>,
) -> ToolPose {
    let ops = chain(model, enc_deg);
    let rotations: [Matrix3<f64>; OPS] = std::array::from_fn(|m| ops[m].rotation());
    // prefix[m] = rotation of ops 0..m (exclusive).
    let mut prefix = [Matrix3::identity(); OPS + 1];
    for m in 0..OPS {
        prefix[m + 1] = prefix[m] * rotations[m];
    }
    let scale = 1.0 + model.scale_ppm * 1e-6;
    if let Some((_, jac)) = wanted.as_mut() {
        jac.iter_mut().for_each(|col| *col = [0.0; 9]);
    }
    // Walk back from the tool: point and axes expressed in the frame before op m.
    let mut point = Vector3::zeros();
    let mut x_axis = Vector3::x();
    let mut z_axis = Vector3::z();
    for m in (0..OPS).rev() {
        let op = &ops[m];
        match op.kind {
            OpKind::Translate(axis) => point += axis.unit() * op.value,
            OpKind::Rotate(_) => {
                point = rotations[m] * point;
                x_axis = rotations[m] * x_axis;
                z_axis = rotations[m] * z_axis;
            }
        }
        let Some((columns, jac)) = wanted.as_mut() else { continue };
        let Some((id, dvalue)) = op.param else { continue };
        let Some(c) = columns.column(id) else { continue };
        let (dp, dx, dz) = match op.kind {
            OpKind::Translate(axis) => (axis.unit(), Vector3::zeros(), Vector3::zeros()),
            OpKind::Rotate(axis) => {
                let a = axis.unit();
                (a.cross(&point), a.cross(&x_axis), a.cross(&z_axis))
            }
        };
        let r = &prefix[m];
        let (dp, dx, dz) = (r * dp * (scale * dvalue), r * dx * dvalue, r * dz * dvalue);
        let col = &mut jac[c];
        for k in 0..3 {
            col[k] += dp[k];
            col[3 + k] += dx[k];
            col[6 + k] += dz[k];
        }
    }
    if let Some((columns, jac)) = wanted {
        if let Some(c) = columns.column(ParamId::Scale) {
            for k in 0..3 {
                jac[c][k] += point[k] * 1e-6;
            }
        }
    }
    ToolPose { position_mm: point * scale, x_axis, z_axis }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::ParamId;

    /// Independent forward path: 4×4 homogeneous matrices multiplied row by row.
    fn fk_by_matrices(model: &ArmModel, enc: &[f64; 6]) -> nalgebra::Vector4<f64> {
        use nalgebra::Matrix4;
        let rz = |t: f64| Matrix4::new(t.cos(), -t.sin(), 0., 0., t.sin(), t.cos(), 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.);
        let rx = |t: f64| Matrix4::new(1., 0., 0., 0., 0., t.cos(), -t.sin(), 0., 0., t.sin(), t.cos(), 0., 0., 0., 0., 1.);
        let tr = |x: f64, y: f64, z: f64| Matrix4::new(1., 0., 0., x, 0., 1., 0., y, 0., 0., 1., z, 0., 0., 0., 1.);
        let mut t = Matrix4::identity();
        for (j, row) in model.joints.iter().enumerate() {
            t = t * rz((enc[j] + row.offset_deg).to_radians()) * tr(0., 0., row.d_mm) * tr(row.a_mm, 0., 0.) * rx(row.alpha_deg.to_radians());
        }
        t * nalgebra::Vector4::new(model.tcp_mm[0], model.tcp_mm[1], model.tcp_mm[2], 1.0)
    }

    #[test]
    fn matches_plain_matrix_product_for_the_thesis_model() {
        let model = ArmModel::suta_nominal();
        let enc = [10.0, 200.0, 33.0, 300.0, 45.0, 123.0];
        let p = tool_pose(&model, &enc).position_mm;
        let q = fk_by_matrices(&model, &enc);
        assert!((p - q.xyz()).norm() < 1e-9, "{p} vs {q}");
    }

    #[test]
    fn jacobian_matches_central_differences_for_every_parameter() {
        for convention in [Convention::Classic, Convention::Modified] {
            let mut model = ArmModel::suta_nominal();
            model.convention = convention;
            model.joints[2].a_mm = 3.0;
            model.joints[3].axis_deg = 0.7;
            model.tcp_mm = [4.0, -2.0, 253.0];
            model.scale_ppm = 150.0;
            let params = ParamId::all();
            let columns = ColumnMap::new(&params);
            let mut jac = vec![[0.0; 9]; params.len()];
            let enc = [31.0, 170.0, 80.0, 250.0, 10.0, 95.0];
            tool_pose_with_jacobian(&model, &enc, &columns, &mut jac);
            for (c, &id) in params.iter().enumerate() {
                let h = 1e-5;
                let mut plus = model.clone();
                plus.set(id, model.get(id) + h);
                let mut minus = model.clone();
                minus.set(id, model.get(id) - h);
                let (a, b) = (tool_pose(&plus, &enc), tool_pose(&minus, &enc));
                let fd = [(a.position_mm - b.position_mm) / (2.0 * h), (a.x_axis - b.x_axis) / (2.0 * h), (a.z_axis - b.z_axis) / (2.0 * h)];
                for k in 0..9 {
                    let expect = fd[k / 3][k % 3];
                    assert!((jac[c][k] - expect).abs() < 1e-5 * (1.0 + expect.abs()), "{convention:?} {id} [{k}]: {} vs {}", jac[c][k], expect);
                }
            }
        }
    }
}
