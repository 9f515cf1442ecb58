//! Forward kinematics of the arm model and its exact Jacobian.
//!
//! The chain is a product of elementary transforms E_1 … E_M (rotations about and translations
//! along x, y, z). For an elementary op m whose value depends on a parameter q, the derivative of
//! the tool point is dp/dq = R_{<m} · (∂E_m/∂v · v_{>m}) · ∂v/∂q, where R_{<m} is the rotation of
//! the ops before m and v_{>m} is the tool point expressed in the frame after op m. For a rotation
//! about axis a that is a × (E_m v_{>m}); for a translation along a it is a. One forward pass for
//! the prefix rotations and one backward pass for the tool point give every column exactly.
//!
//! A URDF joint origin's calibrated turn is one op exp(ω) after its fixed nominal orientation
//! R(rpy). Moving ω by δ turns the frame by exp(J_l(ω)·δ)·exp(ω) (J_l the left Jacobian of
//! SO(3)), so its columns are those of rotations about the axes J_l(ω)·e_k: at ω = 0 the three
//! frame axes themselves, whatever the nominal orientation (no gimbal lock).
//!
//! The joint rotation θ_j = φ_j + δθ_j + Δθ_ecc(φ_j) + c_j·λ_j (see [`crate::model::effects`]) depends on
//! several parameters; its op carries each with ∂θ/∂q. The gravity lever λ_j is itself a
//! function of the geometry; that second-order dependence (c·∂λ/∂q) is left out of the Jacobian,
//! which is exact whenever the compliances are zero.

use super::params::PARAM_SLOTS;
use super::{ArmModel, Convention, ParamId, MAX_JOINTS};
use crate::model::effects::{compliance, eccentricity, harmonic};
use nalgebra::{Matrix3, Rotation3, Vector3};

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
    /// Any unit direction (a URDF joint axis).
    Unit(Vector3<f64>),
}

impl Axis {
    fn unit(self) -> Vector3<f64> {
        match self {
            Axis::X => Vector3::x(),
            Axis::Y => Vector3::y(),
            Axis::Z => Vector3::z(),
            Axis::Unit(u) => u,
        }
    }
}

#[derive(Clone, Copy)]
enum OpKind {
    /// A rotation by the op's value (rad) about an axis.
    Rotate(Axis),
    /// A translation by the op's value (mm) along an axis.
    Translate(Axis),
    /// A fixed rotation (a URDF origin's nominal roll-pitch-yaw).
    Orient(Matrix3<f64>),
    /// A rotation by the rotation vector ω (rad): exp([ω]×).
    Turn(Vector3<f64>),
}

/// Parameters a joint angle depends on: offset, four eccentricity terms, four higher
/// harmonic terms, compliance.
const ANGLE_DEPS: usize = 10;

/// ∂θ_j/∂q (rad per parameter unit) for the parameters θ_j depends on.
type AnglePartials = [(ParamId, f64); ANGLE_DEPS];

/// What an op's value depends on.
#[derive(Clone, Copy)]
enum Dep {
    /// One parameter, with dvalue/dparam.
    Param(ParamId, f64),
    /// Joint j's angle (see [`AnglePartials`]).
    JointAngle(usize),
    /// Joint j's origin turn ω: `origin_rx:j`, `origin_ry:j`, `origin_rz:j`.
    OriginTurn(usize),
    /// Nothing: a constant of the model.
    Fixed,
}

/// One elementary transform.
#[derive(Clone, Copy)]
struct Op {
    kind: OpKind,
    value: f64,
    dep: Dep,
}

impl Op {
    fn rotation(&self) -> Matrix3<f64> {
        match self.kind {
            OpKind::Translate(_) => Matrix3::identity(),
            OpKind::Orient(r) => r,
            OpKind::Turn(w) => Rotation3::new(w).into_inner(),
            OpKind::Rotate(axis) => {
                let (s, c) = self.value.sin_cos();
                match axis {
                    Axis::X => Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c),
                    Axis::Y => Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c),
                    Axis::Z => Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
                    // Rodrigues: I + sin θ K + (1 − cos θ) K².
                    Axis::Unit(u) => {
                        let k = u.cross_matrix();
                        Matrix3::identity() + k * s + k * k * (1.0 - c)
                    }
                }
            }
        }
    }
}

/// Elementary ops per joint row: five for DH (θ, d, a, α, β), six for URDF (x, y, z, nominal
/// orientation, turn ω, θ).
fn ops_per_joint(convention: Convention) -> usize {
    match convention {
        Convention::Classic | Convention::Modified => 5,
        Convention::Urdf => 6,
    }
}
/// Most elementary ops of a chain: six per joint and three for the tool point.
const MAX_OPS: usize = MAX_JOINTS * 6 + 3;

/// The left Jacobian of SO(3) at ω (rad): exp(ω + δ) = exp(J_l(ω)·δ)·exp(ω) to first order.
/// J_l = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×², θ = |ω| (series below 1e-4 rad).
fn left_jacobian(w: &Vector3<f64>) -> Matrix3<f64> {
    let theta = w.norm();
    let k = w.cross_matrix();
    let (a, b) = if theta < 1e-4 {
        let t2 = theta * theta;
        (0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0)
    } else {
        ((1.0 - theta.cos()) / (theta * theta), (theta - theta.sin()) / (theta * theta * theta))
    };
    Matrix3::identity() + k * a + k * k * b
}

fn rot(axis: Axis, value_deg: f64, id: ParamId) -> Op {
    Op { kind: OpKind::Rotate(axis), value: value_deg * DEG, dep: Dep::Param(id, DEG) }
}

fn shift(axis: Axis, value_mm: f64, id: ParamId) -> Op {
    Op { kind: OpKind::Translate(axis), value: value_mm, dep: Dep::Param(id, 1.0) }
}

/// Joint angle θ = φ + δθ + Δθ_ecc(φ) + c·λ (degrees) and its partials. The harmonics are
/// evaluated only when `harmonics` (some eccentricity is non-zero or wanted).
fn joint_angle(
    model: &ArmModel,
    j: usize,
    enc_deg: f64,
    lever_m: f64,
    harmonics: bool,
) -> (f64, AnglePartials) {
    let joint = &model.joints[j];
    let [s1, c1, s2, c2] = if harmonics { eccentricity::partials(enc_deg) } else { [0.0; 4] };
    let [s3, c3] = if harmonics { harmonic::partials(enc_deg, 3) } else { [0.0; 2] };
    let [s4, c4] = if harmonics { harmonic::partials(enc_deg, 4) } else { [0.0; 2] };
    let ecc = joint.eccentricity_sin_deg * s1
        + joint.eccentricity_cos_deg * c1
        + joint.eccentricity2_sin_deg * s2
        + joint.eccentricity2_cos_deg * c2
        + joint.harmonic3_sin_deg * s3
        + joint.harmonic3_cos_deg * c3
        + joint.harmonic4_sin_deg * s4
        + joint.harmonic4_cos_deg * c4;
    let theta = enc_deg + joint.offset_deg + ecc + joint.compliance_deg_per_m * lever_m;
    let partials = [
        (ParamId::Offset(j), DEG),
        (ParamId::EccSin(j), DEG * s1),
        (ParamId::EccCos(j), DEG * c1),
        (ParamId::Ecc2Sin(j), DEG * s2),
        (ParamId::Ecc2Cos(j), DEG * c2),
        (ParamId::Harm3Sin(j), DEG * s3),
        (ParamId::Harm3Cos(j), DEG * c3),
        (ParamId::Harm4Sin(j), DEG * s4),
        (ParamId::Harm4Cos(j), DEG * c4),
        (ParamId::Compliance(j), DEG * lever_m),
    ];
    (theta, partials)
}

/// Index of joint j's rotation op within its row.
fn joint_op_in_row(convention: Convention) -> usize {
    match convention {
        Convention::Classic => 0,
        Convention::Modified => 3,
        Convention::Urdf => 5,
    }
}

/// The elementary ops of the chain for joint angles `theta_deg`, and how many of them there are.
fn chain(model: &ArmModel, theta_deg: &[f64]) -> ([Op; MAX_OPS], usize) {
    let mut ops = [Op { kind: OpKind::Translate(Axis::X), value: 0.0, dep: Dep::JointAngle(0) }; MAX_OPS];
    let joints = model.joints.len().min(MAX_JOINTS);
    let per_joint = ops_per_joint(model.convention);
    for (j, joint) in model.joints.iter().take(joints).enumerate() {
        let row = &mut ops[j * per_joint..(j + 1) * per_joint];
        if model.convention == Convention::Urdf {
            let axis = Axis::Unit(Vector3::from(joint.axis));
            let theta = Op { kind: OpKind::Rotate(axis), value: theta_deg[j] * DEG, dep: Dep::JointAngle(j) };
            let [x, y, z] = joint.origin_xyz_mm;
            let [roll, pitch, yaw] = joint.origin_rpy_deg.map(|v| v * DEG);
            let nominal = Rotation3::from_euler_angles(roll, pitch, yaw).into_inner();
            let turn = Vector3::from(joint.origin_turn_deg) * DEG;
            row.copy_from_slice(&[
                shift(Axis::X, x, ParamId::OriginXyz(j, 0)),
                shift(Axis::Y, y, ParamId::OriginXyz(j, 1)),
                shift(Axis::Z, z, ParamId::OriginXyz(j, 2)),
                Op { kind: OpKind::Orient(nominal), value: 0.0, dep: Dep::Fixed },
                Op { kind: OpKind::Turn(turn), value: 0.0, dep: Dep::OriginTurn(j) },
                theta,
            ]);
            continue;
        }
        let theta = Op { kind: OpKind::Rotate(Axis::Z), value: theta_deg[j] * DEG, dep: Dep::JointAngle(j) };
        let d = shift(Axis::Z, joint.d_mm, ParamId::Length(j));
        let a = shift(Axis::X, joint.a_mm, ParamId::LinkOffset(j));
        let alpha = rot(Axis::X, joint.alpha_deg, ParamId::Twist(j));
        let beta = rot(Axis::Y, joint.axis_deg, ParamId::Axis(j));
        row.copy_from_slice(&match model.convention {
            Convention::Modified => [alpha, beta, a, theta, d],
            Convention::Classic | Convention::Urdf => [theta, d, a, alpha, beta],
        });
    }
    let tcp = &mut ops[joints * per_joint..];
    for (k, axis) in [Axis::X, Axis::Y, Axis::Z].into_iter().enumerate() {
        tcp[k] = shift(axis, model.tcp_mm[k], ParamId::Tcp(k));
    }
    (ops, joints * per_joint + 3)
}

/// Tool pose for raw encoder angles `enc_deg` (degrees, one per joint of the model; a missing
/// angle reads as 0).
pub fn tool_pose(model: &ArmModel, enc_deg: &[f64]) -> ToolPose {
    evaluate(model, enc_deg, None)
}

/// Tool pose and its derivatives for the parameters in `columns`, written to `jacobian`
/// (one [`PoseDerivative`] per column; `jacobian.len()` must be `columns.len()`).
pub fn tool_pose_with_jacobian(
    model: &ArmModel,
    enc_deg: &[f64],
    columns: &ColumnMap,
    jacobian: &mut [PoseDerivative],
) -> ToolPose {
    evaluate(model, enc_deg, Some((columns, jacobian)))
}

/// Gravity levers λ_j (m) of every joint on the arm without compliance deflection.
fn gravity_levers(model: &ArmModel, theta_deg: &[f64]) -> [f64; MAX_JOINTS] {
    let (ops, count) = chain(model, theta_deg);
    let per_joint = ops_per_joint(model.convention);
    let joints = (count - 3) / per_joint;
    // Pose (rotation, origin) before each op, and the tool point after all.
    let mut rotation = Matrix3::identity();
    let mut origin = Vector3::zeros();
    let mut before = [(Matrix3::identity(), Vector3::zeros()); MAX_OPS + 1];
    for (m, op) in ops[..count].iter().enumerate() {
        before[m] = (rotation, origin);
        match op.kind {
            OpKind::Translate(axis) => origin += rotation * axis.unit() * op.value,
            OpKind::Rotate(_) | OpKind::Orient(_) | OpKind::Turn(_) => rotation *= op.rotation(),
        }
    }
    before[count] = (rotation, origin);
    let row_end = |j: usize| before[(j + 1) * per_joint].1;
    let tool = before[count].1;
    let at = joint_op_in_row(model.convention);
    std::array::from_fn(|j| {
        if j >= joints {
            return 0.0;
        }
        let (r, o) = before[j * per_joint + at];
        let masses: Vec<Vector3<f64>> = (j..joints).map(row_end).chain([tool]).collect();
        let axis = if model.convention == Convention::Urdf {
            Vector3::from(model.joints[j].axis)
        } else {
            Vector3::z()
        };
        compliance::gravity_lever_m(&o, &(r * axis), &masses)
    })
}

fn evaluate(
    model: &ArmModel,
    enc_deg: &[f64],
    mut wanted: Option<(&ColumnMap, &mut [PoseDerivative])>,
) -> ToolPose {
    let wants = |kind: fn(usize) -> ParamId| {
        wanted.as_ref().is_some_and(|(c, _)| (0..model.joints.len()).any(|j| c.column(kind(j)).is_some()))
    };
    let harmonics = [
        ParamId::EccSin,
        ParamId::EccCos,
        ParamId::Ecc2Sin,
        ParamId::Ecc2Cos,
        ParamId::Harm3Sin,
        ParamId::Harm3Cos,
        ParamId::Harm4Sin,
        ParamId::Harm4Cos,
    ]
    .into_iter()
    .any(wants)
        || model.joints.iter().any(|j| {
            j.eccentricity_sin_deg != 0.0
                || j.eccentricity_cos_deg != 0.0
                || j.eccentricity2_sin_deg != 0.0
                || j.eccentricity2_cos_deg != 0.0
                || j.harmonic3_sin_deg != 0.0
                || j.harmonic3_cos_deg != 0.0
                || j.harmonic4_sin_deg != 0.0
                || j.harmonic4_cos_deg != 0.0
        });
    let joints = model.joints.len().min(MAX_JOINTS);
    let enc = |j: usize| enc_deg.get(j).copied().unwrap_or(0.0);
    let rigid: [(f64, AnglePartials); MAX_JOINTS] = std::array::from_fn(|j| {
        if j < joints {
            joint_angle(model, j, enc(j), 0.0, harmonics)
        } else {
            (0.0, [(ParamId::Offset(j), 0.0); ANGLE_DEPS])
        }
    });
    let angles = if wants(ParamId::Compliance) || model.joints.iter().any(|j| j.compliance_deg_per_m != 0.0) {
        let levers = gravity_levers(model, &rigid.map(|a| a.0));
        std::array::from_fn(|j| {
            if j < joints {
                joint_angle(model, j, enc(j), levers[j], harmonics)
            } else {
                rigid[j]
            }
        })
    } else {
        rigid
    };
    let (ops, count) = chain(model, &angles.map(|a| a.0));
    let rotations: [Matrix3<f64>; MAX_OPS] =
        std::array::from_fn(|m| if m < count { ops[m].rotation() } else { Matrix3::identity() });
    // prefix[m] = rotation of ops 0..m (exclusive).
    let mut prefix = [Matrix3::identity(); MAX_OPS + 1];
    for m in 0..count {
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
    for m in (0..count).rev() {
        let op = &ops[m];
        match op.kind {
            OpKind::Translate(axis) => point += axis.unit() * op.value,
            OpKind::Rotate(_) | OpKind::Orient(_) | OpKind::Turn(_) => {
                point = rotations[m] * point;
                x_axis = rotations[m] * x_axis;
                z_axis = rotations[m] * z_axis;
            }
        }
        let Some((columns, jac)) = wanted.as_mut() else { continue };
        // The pose's derivative per unit motion of this op: a translation along `a` or a rotation
        // about `a` (both in the frame before op m), mapped to the base frame.
        let motion = |a: Vector3<f64>, rotate: bool| {
            let (dp, dx, dz) = if rotate {
                (a.cross(&point), a.cross(&x_axis), a.cross(&z_axis))
            } else {
                (a, Vector3::zeros(), Vector3::zeros())
            };
            let r = &prefix[m];
            (r * dp * scale, r * dx, r * dz)
        };
        let add = |col: &mut PoseDerivative,
                   (dp, dx, dz): (Vector3<f64>, Vector3<f64>, Vector3<f64>),
                   dvalue: f64| {
            for k in 0..3 {
                col[k] += dp[k] * dvalue;
                col[3 + k] += dx[k] * dvalue;
                col[6 + k] += dz[k] * dvalue;
            }
        };
        let single;
        let deps: &[(ParamId, f64)] = match op.dep {
            Dep::Fixed => continue,
            Dep::OriginTurn(j) => {
                if let OpKind::Turn(w) = op.kind {
                    let jl = left_jacobian(&w);
                    for k in 0..3 {
                        if let Some(c) = columns.column(ParamId::OriginTurn(j, k)) {
                            add(&mut jac[c], motion(jl.column(k).into_owned(), true), DEG);
                        }
                    }
                }
                continue;
            }
            Dep::Param(id, d) => {
                single = [(id, d)];
                &single
            }
            Dep::JointAngle(j) => &angles[j].1,
        };
        // Computed once per op, for every parameter the op's value depends on.
        let mut unit_derivative = None;
        for (id, dvalue) in deps {
            let Some(c) = columns.column(*id) else { continue };
            let derivative = *unit_derivative.get_or_insert_with(|| match op.kind {
                OpKind::Translate(axis) => motion(axis.unit(), false),
                OpKind::Rotate(axis) => motion(axis.unit(), true),
                OpKind::Orient(_) | OpKind::Turn(_) => (Vector3::zeros(), Vector3::zeros(), Vector3::zeros()),
            });
            add(&mut jac[c], derivative, *dvalue);
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
    fn fk_by_matrices(model: &ArmModel, enc: &[f64]) -> nalgebra::Vector4<f64> {
        use nalgebra::Matrix4;
        let rz = |t: f64| {
            Matrix4::new(t.cos(), -t.sin(), 0., 0., t.sin(), t.cos(), 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.)
        };
        let rx = |t: f64| {
            Matrix4::new(1., 0., 0., 0., 0., t.cos(), -t.sin(), 0., 0., t.sin(), t.cos(), 0., 0., 0., 0., 1.)
        };
        let tr = |x: f64, y: f64, z: f64| {
            Matrix4::new(1., 0., 0., x, 0., 1., 0., y, 0., 0., 1., z, 0., 0., 0., 1.)
        };
        let mut t = Matrix4::identity();
        for (j, row) in model.joints.iter().enumerate() {
            t = t
                * rz((enc[j] + row.offset_deg).to_radians())
                * tr(0., 0., row.d_mm)
                * tr(row.a_mm, 0., 0.)
                * rx(row.alpha_deg.to_radians());
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
    fn any_joint_count_matches_the_plain_matrix_product() {
        for joints in [1, 7, crate::model::MAX_JOINTS] {
            let mut model = ArmModel::suta_nominal();
            model.joints = (0..joints)
                .map(|j| crate::model::Joint {
                    offset_deg: 7.0 * j as f64,
                    d_mm: 50.0 + 10.0 * j as f64,
                    a_mm: 20.0 - 3.0 * j as f64,
                    alpha_deg: if j % 2 == 0 { 90.0 } else { -80.0 },
                    ..Default::default()
                })
                .collect();
            let enc: Vec<f64> = (0..joints).map(|j| 13.0 + 29.0 * j as f64).collect();
            let p = tool_pose(&model, &enc).position_mm;
            let q = fk_by_matrices(&model, &enc);
            assert!((p - q.xyz()).norm() < 1e-9, "{joints} joints: {p} vs {q}");
        }
    }

    #[test]
    fn compliance_bends_joints_down_and_its_column_is_exact() {
        let mut model = ArmModel::suta_nominal();
        let enc = [31.0, 170.0, 80.0, 250.0, 10.0, 95.0];
        let rigid = tool_pose(&model, &enc).position_mm;
        model.joints[1].compliance_deg_per_m = 0.5;
        let bent = tool_pose(&model, &enc).position_mm;
        assert!(bent.z < rigid.z, "gravity pulls the tool down: {} vs {}", bent.z, rigid.z);
        // Joint 1 has a vertical axis: gravity exerts no torque about it.
        let mut vertical = ArmModel::suta_nominal();
        vertical.joints[0].compliance_deg_per_m = 5.0;
        assert!((tool_pose(&vertical, &enc).position_mm - rigid).norm() < 1e-9);
        let params = [ParamId::Compliance(1), ParamId::Compliance(3)];
        let mut jac = vec![[0.0; 9]; 2];
        tool_pose_with_jacobian(&model, &enc, &ColumnMap::new(&params), &mut jac);
        for (c, &id) in params.iter().enumerate() {
            let h = 1e-5;
            let (mut plus, mut minus) = (model.clone(), model.clone());
            plus.set(id, model.get(id) + h);
            minus.set(id, model.get(id) - h);
            let fd = (tool_pose(&plus, &enc).position_mm - tool_pose(&minus, &enc).position_mm) / (2.0 * h);
            for k in 0..3 {
                assert!(
                    (jac[c][k] - fd[k]).abs() < 1e-5 * (1.0 + fd[k].abs()),
                    "{id}[{k}]: {} vs {}",
                    jac[c][k],
                    fd[k]
                );
            }
        }
    }

    #[test]
    fn jacobian_matches_central_differences_for_every_parameter() {
        for convention in [Convention::Classic, Convention::Modified, Convention::Urdf] {
            let mut model = ArmModel::suta_nominal();
            model.convention = convention;
            model.joints[2].a_mm = 3.0;
            model.joints[3].axis_deg = 0.7;
            if convention == Convention::Urdf {
                for (j, joint) in model.joints.iter_mut().enumerate() {
                    let s = j as f64;
                    joint.origin_xyz_mm = [10.0 * s, -20.0 + s, joint.d_mm];
                    joint.origin_rpy_deg = [joint.alpha_deg, 7.0 * s, -3.0 * s];
                    // A calibrated turn away from zero: its columns use J_l(ω), not the identity.
                    joint.origin_turn_deg = [2.0 - s, 0.5 * s, 9.0 - 3.0 * s];
                    let n = (1.0 + 0.04 * s * s).sqrt();
                    joint.axis = [0.2 * s / n, 0.0, 1.0 / n];
                    (joint.d_mm, joint.a_mm, joint.alpha_deg, joint.axis_deg) = (0.0, 0.0, 0.0, 0.0);
                }
            }
            model.tcp_mm = [4.0, -2.0, 253.0];
            model.scale_ppm = 150.0;
            model.joints[1].eccentricity_sin_deg = 0.3;
            model.joints[4].eccentricity_cos_deg = -0.2;
            model.joints[2].eccentricity2_sin_deg = 0.1;
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
                let fd = [
                    (a.position_mm - b.position_mm) / (2.0 * h),
                    (a.x_axis - b.x_axis) / (2.0 * h),
                    (a.z_axis - b.z_axis) / (2.0 * h),
                ];
                for k in 0..9 {
                    let expect = fd[k / 3][k % 3];
                    assert!(
                        (jac[c][k] - expect).abs() < 1e-5 * (1.0 + expect.abs()),
                        "{convention:?} {id} [{k}]: {} vs {}",
                        jac[c][k],
                        expect
                    );
                }
            }
        }
    }

    /// UR's shoulder and wrist origins sit at pitch ±90°, where roll and yaw turn about one axis.
    /// The origin's turn ω about its own frame moves the tool frame in three independent
    /// directions there (and at pitch 0, and at UR's rounded 1.570796325 rad): the tool frame's
    /// angular velocities per degree of the three turns have rank 3, all singular values one
    /// degree (no direction weaker than another).
    /// Roll-pitch-yaw as parameters would lose one: their derivatives' rotation axes at pitch 90°
    /// are parallel, as the last assertion shows.
    #[test]
    fn an_origin_at_pitch_90_degrees_loses_no_rotation_direction() {
        let mut model = ArmModel::suta_nominal();
        model.convention = Convention::Urdf;
        model.joints.truncate(3);
        model.free.clear();
        for joint in &mut model.joints {
            (joint.d_mm, joint.alpha_deg, joint.offset_deg) = (0.0, 0.0, 0.0);
        }
        model.joints[0].origin_xyz_mm = [0.0, 0.0, 89.159];
        model.joints[1].origin_xyz_mm = [0.0, 135.85, 0.0];
        model.joints[1].axis = [0.0, 1.0, 0.0];
        model.joints[2].origin_xyz_mm = [0.0, -119.7, 425.0];
        model.joints[2].axis = [0.0, 1.0, 0.0];
        model.tcp_mm = [0.0, 0.0, 392.25];
        let turns: Vec<ParamId> = (0..3).map(|k| ParamId::OriginTurn(1, k)).collect();
        for pitch_deg in [90.0, -90.0, 1.570796325_f64.to_degrees(), 0.0] {
            model.joints[1].origin_rpy_deg = [0.0, pitch_deg, 0.0];
            for enc in [[0.0, 0.0, 0.0], [30.0, -60.0, 45.0]] {
                let mut jac = vec![[0.0; 9]; 3];
                let pose = tool_pose_with_jacobian(&model, &enc, &ColumnMap::new(&turns), &mut jac);
                // The tool frame's angular velocity per degree of each turn: w = x × dx − (y·dz) x.
                let (x, z) = (pose.x_axis, pose.z_axis);
                let y = z.cross(&x);
                let w = Matrix3::from_fn(|r, c| {
                    let (dx, dz) =
                        (Vector3::from_fn(|k, _| jac[c][3 + k]), Vector3::from_fn(|k, _| jac[c][6 + k]));
                    (x.cross(&dx) - x * y.dot(&dz))[r]
                });
                let sv = w.singular_values();
                for s in sv.iter() {
                    assert!(
                        (s - DEG).abs() < 1e-9,
                        "pitch {pitch_deg}: singular values {sv}, expected 3 × {DEG}"
                    );
                }
            }
        }
        // Roll-pitch-yaw at pitch 90°: ∂R/∂roll and ∂R/∂yaw turn about the same axis.
        let rpy = |r: f64, p: f64, y: f64| Rotation3::from_euler_angles(r, p, y).into_inner();
        let h = 1e-7;
        let axis_of = |d: Matrix3<f64>| {
            let w = d * rpy(0.0, std::f64::consts::FRAC_PI_2, 0.0).transpose();
            Vector3::new(w[(2, 1)], w[(0, 2)], w[(1, 0)]).normalize()
        };
        let half = std::f64::consts::FRAC_PI_2;
        let d_roll = (rpy(h, half, 0.0) - rpy(-h, half, 0.0)) / (2.0 * h);
        let d_yaw = (rpy(0.0, half, h) - rpy(0.0, half, -h)) / (2.0 * h);
        assert!(
            axis_of(d_roll).cross(&axis_of(d_yaw)).norm() < 1e-6,
            "roll and yaw are one direction at pitch 90°"
        );
    }
}
