//! Forward kinematics of the arm model and its exact Jacobian.
//!
//! The chain is a product of elementary transforms E_1 … E_M (rotations about and translations
//! along x, y, z). One pass from the base carries the frame (R, o) through them; for op m, before
//! it is applied, w_m = R·a is its axis in the base frame and o_m its origin. The tool point
//! p = o_M (plus the tool offset ops) moves with op m's value as
//! - a rotation about a: dp = w_m × (p − o_m), and the tool axes dx = w_m × x, dz = w_m × z;
//! - a translation along a: dp = w_m, the axes not at all.
//!
//! Since w_m × (p − o_m) = w_m × p − w_m × o_m is linear in the final p, each column gathers W =
//! Σ w_m·∂v_m/∂q and V = Σ (translation w_m or −w_m × o_m)·∂v_m/∂q during the one pass, and
//! becomes dp = W × p + V, dx = W × x, dz = W × z once p, x and z are known: every column exact,
//! no backward pass, no stored prefix.
//!
//! A URDF joint origin's calibrated turn is one rotation exp(ω) after its fixed nominal
//! orientation R(rpy), applied as one fixed op R(rpy)·exp(ω). Moving ω by δ turns the frame by
//! exp(J_l(ω)·δ)·exp(ω) (J_l the left Jacobian of SO(3)), so its columns are those of rotations
//! about the axes R(rpy)·J_l(ω)·e_k: at ω = 0 the three frame axes themselves, whatever the
//! nominal orientation (no gimbal lock).
//!
//! A [`Chain`] holds what does not change from one pose to the next (the ops of one model, the
//! fixed rotations' sines and cosines): build it once per model and evaluate it per pose
//! (pinocchio's model/data split); [`tool_pose`] and [`tool_pose_with_jacobian`] build one per call.
//! A caller that evaluates the same poses again and again (a solver's iterations) keeps each
//! encoder angle's sine and cosine ([`encoder_sin_cos`]) and hands them in: the joint rotation
//! then takes them by angle addition with the chain's offset, sin(φ + δθ) = sin φ cos δθ +
//! cos φ sin δθ, and no sine or cosine is left per pose (while no encoder harmonic or compliance
//! makes θ a function of φ beyond the offset).
//!
//! The joint rotation θ_j = φ_j + δθ_j + Δθ_ecc(φ_j) + c_j·λ_j (see [`crate::model::effects`]) depends on
//! several parameters; its op carries each with ∂θ/∂q. The gravity lever λ_j is itself a
//! function of the geometry; that second-order dependence (c·∂λ/∂q) is left out of the Jacobian,
//! which is exact whenever the compliances are zero.

use super::params::PARAM_SLOTS;
use super::tree::{self, Loads};
use super::{ArmModel, Convention, ParamId, MAX_BODIES, MAX_TREE_JOINTS};
use crate::model::effects::{bend, compliance, eccentricity, harmonic, mass, sag};
use crate::numerics::geometry::left_jacobian;
use lanes::{lane, Lanes, Poses, Width};
use nalgebra::{Matrix3, Rotation3, Vector3};

mod dh;
mod lanes;

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

/// One pose's frame at the chain's flange, before the tool shift: its origin (mm) and its x, y,
/// z axes, in the base frame. A caller evaluating the same poses again at values that move only
/// the tool point and the scale keeps it and starts each pose there (see
/// [`Chain::starts_at_flange`]).
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Flange {
    origin_mm: [f64; 3],
    axes: [[f64; 3]; 3],
}

/// Derivatives of one [`ToolPose`] with respect to one parameter:
/// `[dp_x, dp_y, dp_z, dx_x, dx_y, dx_z, dz_x, dz_y, dz_z]` (mm or 1 per parameter unit).
pub type PoseDerivative = [f64; 9];

/// Harmonic encoder-error parameters of one joint (eccentricity and higher harmonics).
const HARMONICS: [fn(usize) -> ParamId; 8] = [
    ParamId::EccSin,
    ParamId::EccCos,
    ParamId::Ecc2Sin,
    ParamId::Ecc2Cos,
    ParamId::Harm3Sin,
    ParamId::Harm3Cos,
    ParamId::Harm4Sin,
    ParamId::Harm4Cos,
];

/// Maps each parameter to its Jacobian column, if it is one of the columns wanted.
#[derive(Clone, Debug)]
pub struct ColumnMap {
    slots: [Option<usize>; PARAM_SLOTS],
    len: usize,
    /// Some harmonic encoder-error column is wanted.
    harmonics: bool,
    /// Some compliance column is wanted.
    compliance: bool,
    /// Some mass-torque compliance column (sag, bend) or mass column is wanted.
    gravity: bool,
    /// The wanted mass columns: (body, column).
    masses: Vec<(usize, usize)>,
    /// The tool axes' derivatives are wanted (not only the position's).
    axes: bool,
}

impl ColumnMap {
    /// Columns for `params`, in that order.
    pub fn new(params: &[ParamId]) -> ColumnMap {
        let mut slots = [None; PARAM_SLOTS];
        for (c, p) in params.iter().enumerate() {
            slots[p.dense_index()] = Some(c);
        }
        let any =
            |kind: fn(usize) -> ParamId| (0..MAX_TREE_JOINTS).any(|j| slots[kind(j).dense_index()].is_some());
        let masses: Vec<(usize, usize)> =
            (0..MAX_BODIES).filter_map(|b| Some((b, slots[ParamId::Mass(b).dense_index()]?))).collect();
        ColumnMap {
            slots,
            len: params.len(),
            harmonics: HARMONICS.into_iter().any(any),
            compliance: any(ParamId::Compliance),
            gravity: any(ParamId::Sag) || any(ParamId::Bend) || !masses.is_empty(),
            masses,
            axes: true,
        }
    }

    /// The same columns for the position alone: the axes' derivatives are left at zero (for
    /// residuals that read positions only).
    pub fn positions_only(self) -> ColumnMap {
        ColumnMap { axes: false, ..self }
    }

    /// Number of columns.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no column is wanted.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn column(&self, slot: usize) -> Option<usize> {
        self.slots[slot]
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

#[derive(Clone, Copy)]
enum OpKind {
    /// A rotation by the op's value (rad) about an axis.
    Rotate(Axis),
    /// A translation by the op's value (mm) along an axis.
    Translate(Axis),
    /// A fixed rotation: a URDF origin's nominal roll-pitch-yaw and its calibrated turn,
    /// R(rpy)·exp([ω]×).
    Orient(Matrix3<f64>),
}

/// What an op's value depends on.
#[derive(Clone, Copy)]
enum Dep {
    /// One parameter (its dense index), with dvalue/dparam.
    Param(usize, f64),
    /// Joint j's angle (see [`Chain::joint_angle`]).
    JointAngle(usize),
    /// Joint j's lateral turn under its gravity moment (see [`bend`]): a rotation about the
    /// moment's direction, set per pose.
    Bend(usize),
    /// Joint j's origin turn ω (`origin_rx:j`, `origin_ry:j`, `origin_rz:j`): the columns of
    /// R(rpy)·J_l(ω) are the axes, in the frame before the op, the frame turns about per radian.
    OriginTurn(usize, Matrix3<f64>),
}

/// One elementary transform; a rotation carries its angle's sine and cosine.
#[derive(Clone, Copy)]
struct Op {
    kind: OpKind,
    value: f64,
    sin_cos: (f64, f64),
    dep: Dep,
}

fn rot(axis: Axis, value_deg: f64, id: ParamId) -> Op {
    let value = value_deg * DEG;
    Op { kind: OpKind::Rotate(axis), value, sin_cos: value.sin_cos(), dep: Dep::Param(id.dense_index(), DEG) }
}

fn shift(axis: Axis, value_mm: f64, id: ParamId) -> Op {
    Op {
        kind: OpKind::Translate(axis),
        value: value_mm,
        sin_cos: (0.0, 1.0),
        dep: Dep::Param(id.dense_index(), 1.0),
    }
}

/// A frame carried from the base: its axes (the columns of R) and origin.
struct Frame {
    axes: [Vector3<f64>; 3],
    origin: Vector3<f64>,
}

impl Frame {
    fn base() -> Frame {
        Frame { axes: [Vector3::x(), Vector3::y(), Vector3::z()], origin: Vector3::zeros() }
    }

    /// R·a.
    fn direction(&self, axis: Axis) -> Vector3<f64> {
        match axis {
            Axis::X => self.axes[0],
            Axis::Y => self.axes[1],
            Axis::Z => self.axes[2],
            Axis::Unit(u) => self.axes[0] * u.x + self.axes[1] * u.y + self.axes[2] * u.z,
        }
    }

    /// Apply `op`; its direction in the base frame before it (R·a).
    #[inline]
    fn apply(&mut self, op: &Op) -> Vector3<f64> {
        match op.kind {
            OpKind::Translate(axis) => {
                let t = self.direction(axis);
                self.origin += t * op.value;
                t
            }
            OpKind::Rotate(axis) => {
                let w = self.direction(axis);
                let (s, c) = op.sin_cos;
                let [x, y, z] = self.axes;
                // R·Rx, R·Ry, R·Rz column by column; any axis by Rodrigues' I + sin θ K + (1 − cos θ) K².
                match axis {
                    Axis::X => self.axes = [x, y * c + z * s, z * c - y * s],
                    Axis::Y => self.axes = [x * c - z * s, y, x * s + z * c],
                    Axis::Z => self.axes = [x * c + y * s, y * c - x * s, z],
                    Axis::Unit(u) => self.rotate_about(&u, s, c),
                }
                w
            }
            OpKind::Orient(m) => {
                self.turn(&m);
                Vector3::zeros()
            }
        }
    }

    /// R·m.
    fn turn(&mut self, m: &Matrix3<f64>) {
        let [x, y, z] = self.axes;
        self.axes = [0, 1, 2].map(|i| x * m[(0, i)] + y * m[(1, i)] + z * m[(2, i)]);
    }

    /// R·(I + sin θ K + (1 − cos θ) K²), K the cross matrix of the unit axis `u` (Rodrigues).
    #[inline(never)]
    fn rotate_about(&mut self, u: &Vector3<f64>, s: f64, c: f64) {
        let k = u.cross_matrix();
        let m: Matrix3<f64> = Matrix3::identity() + k * s + k * k * (1.0 - c);
        self.turn(&m);
    }
}

/// Elementary ops per joint row: five for DH (θ, d, a, α, β) and for URDF (x, y, z, the
/// origin's orientation, θ).
const OPS_PER_JOINT: usize = 5;

/// Parameters a joint angle depends on: offset, four eccentricity terms, four higher
/// harmonic terms, compliance, sag.
const ANGLE_DEPS: usize = 11;

/// The chain of one model's tip: its elementary ops with the fixed rotations' sines and cosines,
/// built once and evaluated at any joint angles (of the whole tree: a tip's chain reads the
/// angles of the joints on its path, and the gravity loads read them all).
pub struct Chain<'m> {
    model: &'m ArmModel,
    ops: Vec<Op>,
    /// The op index at which each joint row of the path ends, base first.
    row_ends: Vec<usize>,
    /// The joints of the path, base first.
    path: Vec<usize>,
    /// Some harmonic encoder error is non-zero.
    harmonics: bool,
    /// Some compliance is non-zero.
    compliant: bool,
    /// Some mass-torque compliance (sag, bend) is non-zero on a model with masses.
    loaded: bool,
    /// Per body of the mass table, the joints that carry it (bit j, see [`tree::Tree::carriers`]).
    carriers: Vec<u32>,
    scale: f64,
    /// Per joint, the sine and cosine of its offset δθ.
    offset_sin_cos: [(f64, f64); MAX_TREE_JOINTS],
    /// The rows of a DH chain, for its kernel ([`dh`]); `None` for a URDF model.
    dh: Option<Vec<dh::Row>>,
    /// The tool point's shifts along x, y, z: value (mm) and dense slot.
    tool: [(f64, usize); 3],
}

impl<'m> Chain<'m> {
    /// The chain of `model` (of its first tip, for a tree).
    pub fn new(model: &'m ArmModel) -> Chain<'m> {
        Chain::for_tip(model, 0)
    }

    /// The chain of `model`'s tip `tip` (0-based; a chain has tip 0 only).
    pub fn for_tip(model: &'m ArmModel, tip: usize) -> Chain<'m> {
        let joints = model.joints.len().min(MAX_TREE_JOINTS);
        let path = model.tree.path(joints, tip);
        let masses = model.convention == Convention::Urdf && !model.tree.bodies.is_empty();
        let mut ops = Vec::with_capacity(path.len() * (OPS_PER_JOINT + 1) + 3);
        let mut row_ends = Vec::with_capacity(path.len());
        for &j in &path {
            let joint = &model.joints[j];
            let theta_axis = match model.convention {
                Convention::Urdf => Axis::Unit(Vector3::from(joint.axis)),
                Convention::Classic | Convention::Modified => Axis::Z,
            };
            let theta = Op {
                kind: OpKind::Rotate(theta_axis),
                value: 0.0,
                sin_cos: (0.0, 1.0),
                dep: Dep::JointAngle(j),
            };
            if model.convention == Convention::Urdf {
                let [x, y, z] = joint.origin_xyz_mm;
                let [roll, pitch, yaw] = joint.origin_rpy_deg.map(|v| v * DEG);
                let nominal = Rotation3::from_euler_angles(roll, pitch, yaw).into_inner();
                let turn = Vector3::from(joint.origin_turn_deg) * DEG;
                let orient = Op {
                    kind: OpKind::Orient(nominal * Rotation3::new(turn).into_inner()),
                    value: 0.0,
                    sin_cos: (0.0, 1.0),
                    dep: Dep::OriginTurn(j, nominal * left_jacobian(&turn)),
                };
                ops.extend([
                    shift(Axis::X, x, ParamId::OriginXyz(j, 0)),
                    shift(Axis::Y, y, ParamId::OriginXyz(j, 1)),
                    shift(Axis::Z, z, ParamId::OriginXyz(j, 2)),
                    orient,
                    theta,
                ]);
                if masses {
                    ops.push(Op {
                        kind: OpKind::Rotate(Axis::Z),
                        value: 0.0,
                        sin_cos: (0.0, 1.0),
                        dep: Dep::Bend(j),
                    });
                }
                row_ends.push(ops.len() - 1);
                continue;
            }
            let d = shift(Axis::Z, joint.d_mm, ParamId::Length(j));
            let a = shift(Axis::X, joint.a_mm, ParamId::LinkOffset(j));
            let alpha = rot(Axis::X, joint.alpha_deg, ParamId::Twist(j));
            let beta = rot(Axis::Y, joint.axis_deg, ParamId::Axis(j));
            ops.extend(match model.convention {
                Convention::Modified => [alpha, beta, a, theta, d],
                Convention::Classic | Convention::Urdf => [theta, d, a, alpha, beta],
            });
            row_ends.push(ops.len() - 1);
        }
        let mut tool = [(0.0, 0); 3];
        for (k, axis) in [Axis::X, Axis::Y, Axis::Z].into_iter().enumerate() {
            let (value, id) = match model.tree.tips.get(tip).filter(|_| tip > 0) {
                Some(t) => (t.tcp_mm[k], ParamId::TipTcp(tip, k)),
                None => (model.tcp_mm[k], ParamId::Tcp(k)),
            };
            tool[k] = (value, id.dense_index());
            ops.push(shift(axis, value, id));
        }
        let joint_rows = &model.joints[..joints];
        let mut offset_sin_cos = [(0.0, 1.0); MAX_TREE_JOINTS];
        for (sc, joint) in offset_sin_cos.iter_mut().zip(joint_rows) {
            *sc = (joint.offset_deg * DEG).sin_cos();
        }
        Chain {
            offset_sin_cos,
            dh: dh::rows(model, &path),
            tool,
            model,
            ops,
            row_ends,
            path,
            loaded: masses
                && joint_rows.iter().any(|j| j.sag_deg_per_knm != 0.0 || j.bend_deg_per_knm != 0.0),
            carriers: (0..model.tree.bodies.len()).map(|b| model.tree.carriers(b, joints)).collect(),
            harmonics: joint_rows.iter().any(|j| {
                j.eccentricity_sin_deg != 0.0
                    || j.eccentricity_cos_deg != 0.0
                    || j.eccentricity2_sin_deg != 0.0
                    || j.eccentricity2_cos_deg != 0.0
                    || j.harmonic3_sin_deg != 0.0
                    || j.harmonic3_cos_deg != 0.0
                    || j.harmonic4_sin_deg != 0.0
                    || j.harmonic4_cos_deg != 0.0
            }),
            compliant: joint_rows.iter().any(|j| j.compliance_deg_per_m != 0.0),
            scale: 1.0 + model.scale_ppm * 1e-6,
        }
    }

    /// Tool pose for raw encoder angles `enc_deg` (degrees, one per joint; a missing angle reads
    /// as 0).
    pub fn pose(&self, enc_deg: &[f64]) -> ToolPose {
        self.evaluate(enc_deg, None, None)
    }

    /// As [`Chain::pose`] with each encoder angle's sine and cosine given (see the module doc).
    pub fn pose_with_sin_cos(&self, enc_deg: &[f64], enc_sin_cos: &[(f64, f64)]) -> ToolPose {
        self.evaluate(enc_deg, Some(enc_sin_cos), None)
    }

    /// As [`Chain::pose_with_jacobian`] with each encoder angle's sine and cosine given (see the
    /// module doc).
    pub fn pose_with_sin_cos_and_jacobian(
        &self,
        enc_deg: &[f64],
        enc_sin_cos: &[(f64, f64)],
        columns: &ColumnMap,
        jacobian: &mut [PoseDerivative],
    ) -> ToolPose {
        self.evaluate(enc_deg, Some(enc_sin_cos), Some((columns, jacobian)))
    }

    /// Tool pose and its derivatives for the parameters in `columns`, written to `jacobian` (one
    /// [`PoseDerivative`] per column; `jacobian.len()` must be `columns.len()`).
    pub fn pose_with_jacobian(
        &self,
        enc_deg: &[f64],
        columns: &ColumnMap,
        jacobian: &mut [PoseDerivative],
    ) -> ToolPose {
        self.evaluate(enc_deg, None, Some((columns, jacobian)))
    }

    /// Joint angle θ = φ + δθ + Δθ_ecc(φ) + c·λ + s·τ/1000 (degrees) and its partials ∂θ/∂q
    /// (rad per parameter unit, parameters by dense index), how many. The harmonics are
    /// evaluated (and their partials given) only when `harmonics`, the compliance's partial only
    /// when `compliance`, the sag's only when `torque_nm` is given.
    fn joint_angle(
        &self,
        j: usize,
        enc_deg: f64,
        lever_m: f64,
        torque_nm: Option<f64>,
        harmonics: bool,
        compliance: bool,
    ) -> (f64, [(usize, f64); ANGLE_DEPS], usize) {
        let joint = &self.model.joints[j];
        let mut partials = [(0, 0.0); ANGLE_DEPS];
        partials[0] = (ParamId::Offset(j).dense_index(), DEG);
        let mut count = 1;
        let mut ecc = 0.0;
        if harmonics {
            let [s1, c1, s2, c2] = eccentricity::partials(enc_deg);
            let [s3, c3] = harmonic::partials(enc_deg, 3);
            let [s4, c4] = harmonic::partials(enc_deg, 4);
            ecc = joint.eccentricity_sin_deg * s1
                + joint.eccentricity_cos_deg * c1
                + joint.eccentricity2_sin_deg * s2
                + joint.eccentricity2_cos_deg * c2
                + joint.harmonic3_sin_deg * s3
                + joint.harmonic3_cos_deg * c3
                + joint.harmonic4_sin_deg * s4
                + joint.harmonic4_cos_deg * c4;
            for (kind, v) in HARMONICS.into_iter().zip([s1, c1, s2, c2, s3, c3, s4, c4]) {
                partials[count] = (kind(j).dense_index(), DEG * v);
                count += 1;
            }
        }
        if compliance {
            partials[count] = (ParamId::Compliance(j).dense_index(), DEG * lever_m);
            count += 1;
        }
        let mut theta = enc_deg + joint.offset_deg + ecc + joint.compliance_deg_per_m * lever_m;
        if let Some(torque) = torque_nm {
            partials[count] = (ParamId::Sag(j).dense_index(), DEG * sag::partial(torque));
            count += 1;
            theta += joint.sag_deg_per_knm * sag::partial(torque);
        }
        (theta, partials, count)
    }

    /// True when joint j carries body `b` of the mass table.
    fn carries(&self, b: usize, j: usize) -> bool {
        self.carriers.get(b).is_some_and(|bits| j < 32 && bits & (1 << j) != 0)
    }

    /// Op `op` with joint j's angle θ_j (degrees) set.
    fn with_angle(op: &Op, theta_deg: f64) -> Op {
        let value = theta_deg * DEG;
        Op { value, sin_cos: value.sin_cos(), ..*op }
    }

    /// Gravity levers λ_j (m) of every joint of the path on the arm without compliance
    /// deflection, by tree joint.
    fn gravity_levers(&self, enc: impl Fn(usize) -> f64, harmonics: bool) -> [f64; MAX_TREE_JOINTS] {
        let rows = self.path.len();
        // Per row: its axis' point and direction (before its θ op) and the origin at its end.
        let mut axes = Vec::with_capacity(rows);
        let mut masses = Vec::with_capacity(rows + 1);
        let mut frame = Frame::base();
        for (m, op) in self.ops.iter().enumerate() {
            match op.dep {
                Dep::JointAngle(j) => {
                    let OpKind::Rotate(axis) = op.kind else { unreachable!("a joint angle is a rotation") };
                    axes.push((frame.origin, frame.direction(axis)));
                    let (theta, ..) = self.joint_angle(j, enc(j), 0.0, None, harmonics, false);
                    frame.apply(&Self::with_angle(op, theta));
                }
                Dep::Param(..) | Dep::OriginTurn(..) => {
                    frame.apply(op);
                }
                Dep::Bend(_) => {}
            }
            if self.row_ends.contains(&m) {
                masses.push(frame.origin);
            }
        }
        masses.push(frame.origin);
        let mut levers = [0.0; MAX_TREE_JOINTS];
        for (row, &j) in self.path.iter().enumerate() {
            levers[j] = compliance::gravity_lever_m(&axes[row].0, &axes[row].1, &masses[row..]);
        }
        levers
    }

    /// The rows of the DH kernel when this chain takes it for `columns`: a DH chain whose
    /// angles read their offsets alone.
    fn kernel(&self, columns: Option<&ColumnMap>) -> Option<&[dh::Row]> {
        let harmonics = self.harmonics || columns.is_some_and(|c| c.harmonics);
        let compliance = self.compliant || columns.is_some_and(|c| c.compliance);
        self.dh.as_deref().filter(|_| !harmonics && !compliance)
    }

    /// The pose and the wanted columns: by the DH kernel when the chain takes it, else by the
    /// general pass over the ops.
    fn evaluate(
        &self,
        enc_deg: &[f64],
        enc_sin_cos: Option<&[(f64, f64)]>,
        wanted: Option<(&ColumnMap, &mut [PoseDerivative])>,
    ) -> ToolPose {
        match self.kernel(wanted.as_ref().map(|(c, _)| *c)) {
            Some(rows) => {
                let (columns, jac) = wanted.map_or((None, None), |(c, j)| (Some(c), Some(j)));
                let mut jacs = jac.map(|j| [j]);
                let enc = [(enc_deg, enc_sin_cos.unwrap_or_default())];
                let frame = self.dh_columns(rows, enc, columns.zip(jacs.as_mut()));
                let [pose] = self.finish(frame, columns.zip(jacs.as_mut()));
                pose
            }
            None => self.general_pass(enc_deg, enc_sin_cos, wanted),
        }
    }

    /// As [`Chain::pose_with_sin_cos_and_jacobian`] for two poses: carried through the chain
    /// together (two to an SSE2 register) when the chain takes the DH kernel, else one after
    /// the other; to the bit what two calls give.
    pub fn pose_pair_with_sin_cos_and_jacobian(
        &self,
        enc_deg: [&[f64]; 2],
        enc_sin_cos: [&[(f64, f64)]; 2],
        columns: &ColumnMap,
        jacobian: [&mut [PoseDerivative]; 2],
    ) -> [ToolPose; 2] {
        let mut jacs = jacobian;
        let Some(rows) = self.kernel(Some(columns)) else {
            let [first, second] = jacs;
            return [
                self.evaluate(enc_deg[0], Some(enc_sin_cos[0]), Some((columns, first))),
                self.evaluate(enc_deg[1], Some(enc_sin_cos[1]), Some((columns, second))),
            ];
        };
        let frame =
            self.dh_columns(rows, [0, 1].map(|i| (enc_deg[i], enc_sin_cos[i])), Some((columns, &mut jacs)));
        self.finish(frame, Some((columns, &mut jacs)))
    }

    /// As [`Chain::pose_with_sin_cos`] for two poses: carried through the chain together (two to
    /// an SSE2 register) when the chain takes the DH kernel, else one after the other; to the bit
    /// what two calls give.
    pub fn pose_pair_with_sin_cos(
        &self,
        enc_deg: [&[f64]; 2],
        enc_sin_cos: [&[(f64, f64)]; 2],
    ) -> [ToolPose; 2] {
        match self.kernel(None) {
            Some(rows) => {
                self.finish(self.dh_columns(rows, [0, 1].map(|i| (enc_deg[i], enc_sin_cos[i])), None), None)
            }
            None => [0, 1].map(|i| self.general_pass(enc_deg[i], Some(enc_sin_cos[i]), None)),
        }
    }

    /// True when the poses with `columns` may start at their flanges: the chain takes the DH
    /// kernel and every wanted column is its tool point's or the scale's, which move nothing
    /// before the tool shift. The flanges of one such chain then serve every chain of its model
    /// at other values of those parameters alone. Off the kernel (a URDF chain, a compliance,
    /// an encoder harmonic) the whole pass is taken.
    pub(crate) fn starts_at_flange(&self, columns: &ColumnMap) -> bool {
        let after_flange =
            |slot: usize| slot == ParamId::Scale.dense_index() || self.tool.iter().any(|&(_, s)| s == slot);
        self.kernel(Some(columns)).is_some()
            && columns.slots.iter().enumerate().all(|(slot, c)| c.is_none() || after_flange(slot))
    }

    /// The frames at the flange of two poses, as [`Chain::pose_pair_with_sin_cos`] carries them
    /// before the tool shift; `None` off the DH kernel.
    pub(crate) fn flange_pair(
        &self,
        enc_deg: [&[f64]; 2],
        enc_sin_cos: [&[(f64, f64)]; 2],
    ) -> Option<[Flange; 2]> {
        let rows = self.kernel(None)?;
        Some(self.dh_flanges(rows, [0, 1].map(|i| (enc_deg[i], enc_sin_cos[i]))))
    }

    /// As [`Chain::flange_pair`] for one pose.
    pub(crate) fn flange(&self, enc_deg: &[f64], enc_sin_cos: &[(f64, f64)]) -> Option<Flange> {
        let rows = self.kernel(None)?;
        let [flange] = self.dh_flanges(rows, [(enc_deg, enc_sin_cos)]);
        Some(flange)
    }

    /// As [`Chain::pose_pair_with_sin_cos_and_jacobian`] from the two poses' flanges (of
    /// [`Chain::flange_pair`] on a chain of this model at any values of `columns`' parameters),
    /// when the chain [starts at the flange](Chain::starts_at_flange) for `columns`: the tool
    /// shift alone, to the bit what the whole pass gives.
    pub(crate) fn pose_pair_from_flanges(
        &self,
        flanges: [&Flange; 2],
        columns: &ColumnMap,
        jacobian: [&mut [PoseDerivative]; 2],
    ) -> [ToolPose; 2] {
        self.poses_at_flanges(flanges, columns, jacobian)
    }

    /// As [`Chain::pose_pair_from_flanges`] for one pose.
    pub(crate) fn pose_from_flange(
        &self,
        flange: &Flange,
        columns: &ColumnMap,
        jacobian: &mut [PoseDerivative],
    ) -> ToolPose {
        let [pose] = self.poses_at_flanges([flange], columns, [jacobian]);
        pose
    }

    /// The poses and columns of [`Chain::pose_pair_from_flanges`] for `N` poses.
    fn poses_at_flanges<const N: usize>(
        &self,
        flanges: [&Flange; N],
        columns: &ColumnMap,
        mut jacs: [&mut [PoseDerivative]; N],
    ) -> [ToolPose; N]
    where
        Poses<N>: Width,
    {
        debug_assert!(
            self.starts_at_flange(columns),
            "a pose starts at its flange only when nothing before moves"
        );
        let frame = self.dh_tool_columns(flanges, Some((columns, &mut jacs)));
        self.finish(frame, Some((columns, &mut jacs)))
    }

    /// The pose and the wanted columns by one pass over the chain's ops (see the module doc).
    fn general_pass(
        &self,
        enc_deg: &[f64],
        enc_sin_cos: Option<&[(f64, f64)]>,
        mut wanted: Option<(&ColumnMap, &mut [PoseDerivative])>,
    ) -> ToolPose {
        let harmonics = self.harmonics || wanted.as_ref().is_some_and(|(c, _)| c.harmonics);
        let compliance = self.compliant || wanted.as_ref().is_some_and(|(c, _)| c.compliance);
        let enc = |j: usize| enc_deg.get(j).copied().unwrap_or(0.0);
        let levers = if compliance { self.gravity_levers(enc, harmonics) } else { [0.0; MAX_TREE_JOINTS] };
        let loads: Option<Loads> = (self.loaded || wanted.as_ref().is_some_and(|(c, _)| c.gravity))
            .then(|| tree::loads(self.model, enc))
            .flatten();
        if let Some((_, jac)) = wanted.as_mut() {
            jac.iter_mut().for_each(|col| *col = [0.0; 9]);
        }
        // Each wanted column gathers V (in 0..3) and W (in 3..6), see the module doc.
        let mut frame = Frame::base();
        for op in &self.ops {
            let origin = frame.origin;
            match op.dep {
                Dep::Param(slot, dv) => {
                    let column = wanted.as_ref().and_then(|(columns, _)| columns.column(slot));
                    // A rotation or shift by zero that no column asks for leaves the frame as is.
                    if op.value == 0.0 && column.is_none() {
                        continue;
                    }
                    let dir = frame.apply(op);
                    if let (Some(c), Some((_, jac))) = (column, wanted.as_mut()) {
                        gather(&mut jac[c], op, &dir, &origin, dv);
                    }
                }
                Dep::OriginTurn(j, axes) => {
                    if let Some((columns, jac)) = wanted.as_mut() {
                        for k in 0..3 {
                            if let Some(c) = columns.column(ParamId::OriginTurn(j, k).dense_index()) {
                                let dir = frame.direction(Axis::Unit(axes.column(k).into_owned()));
                                gather_rotation(&mut jac[c], &dir, &origin, DEG);
                            }
                        }
                    }
                    frame.apply(op);
                }
                Dep::Bend(j) => {
                    if let (Some((columns, jac)), Some(loads)) = (wanted.as_mut(), loads.as_ref()) {
                        let compliance = self.model.joints[j].bend_deg_per_knm;
                        for &(b, c) in columns.masses.iter().filter(|(b, _)| self.carries(*b, j)) {
                            let (_, lateral) = loads.per_kg(&self.model.tree.bodies[b], j);
                            let turn = mass::bend_partial(compliance, &lateral);
                            if let Some(u) = turn.try_normalize(0.0) {
                                gather_rotation(
                                    &mut jac[c],
                                    &frame.direction(Axis::Unit(u)),
                                    &origin,
                                    DEG * turn.norm(),
                                );
                            }
                        }
                    }
                    let Some((axis, dv)) =
                        loads.as_ref().and_then(|l| bend::direction_and_partial(&l.lateral_nm[j]))
                    else {
                        continue;
                    };
                    let turn = Op {
                        kind: OpKind::Rotate(Axis::Unit(axis)),
                        dep: Dep::Param(ParamId::Bend(j).dense_index(), DEG * dv),
                        ..Self::with_angle(op, self.model.joints[j].bend_deg_per_knm * dv)
                    };
                    let dir = frame.apply(&turn);
                    if let Some((columns, jac)) = wanted.as_mut() {
                        if let Some(c) = columns.column(ParamId::Bend(j).dense_index()) {
                            gather(&mut jac[c], &turn, &dir, &origin, DEG * dv);
                        }
                    }
                }
                Dep::JointAngle(j) => {
                    // The encoder's sine and cosine kept and θ = φ + δθ: angle addition, and the
                    // offset is the only parameter θ reads.
                    if let Some(&(s, c)) = enc_sin_cos
                        .and_then(|sc| sc.get(j))
                        .filter(|_| !harmonics && !compliance && loads.is_none())
                    {
                        let (so, co) = self.offset_sin_cos[j];
                        let dir = frame.apply(&Op { sin_cos: (s * co + c * so, c * co - s * so), ..*op });
                        if let Some((columns, jac)) = wanted.as_mut() {
                            if let Some(c) = columns.column(ParamId::Offset(j).dense_index()) {
                                gather(&mut jac[c], op, &dir, &origin, DEG);
                            }
                        }
                        continue;
                    }
                    let torque = loads.as_ref().map(|l| l.torque_nm[j]);
                    let (theta, partials, count) =
                        self.joint_angle(j, enc(j), levers[j], torque, harmonics, compliance);
                    let dir = frame.apply(&Self::with_angle(op, theta));
                    if let Some((columns, jac)) = wanted.as_mut() {
                        for &(slot, dv) in &partials[..count] {
                            if let Some(c) = columns.column(slot) {
                                gather(&mut jac[c], op, &dir, &origin, dv);
                            }
                        }
                        let compliance = self.model.joints[j].sag_deg_per_knm;
                        for &(b, c) in columns.masses.iter().filter(|(b, _)| self.carries(*b, j)) {
                            let Some(loads) = loads.as_ref() else { break };
                            let (torque, _) = loads.per_kg(&self.model.tree.bodies[b], j);
                            gather(
                                &mut jac[c],
                                op,
                                &dir,
                                &origin,
                                DEG * mass::angle_partial(compliance, torque),
                            );
                        }
                    }
                }
            }
        }
        let [x_axis, _, z_axis] = frame.axes;
        let frame = [frame.origin, x_axis, z_axis].map(|v| [v.x, v.y, v.z].map(Lanes::<1>::splat));
        let (columns, mut jac) = wanted.map_or((None, None), |(c, j)| (Some(c), Some([j])));
        let [pose] = self.finish(frame, columns.zip(jac.as_mut()));
        pose
    }

    /// The poses at `N` poses' tool points (before the scale) and x and z axes `frame`, each
    /// wanted column turned from its V and W (laid out as [`lanes::gathered`] says) into the
    /// derivatives of the point and the axes.
    #[inline(always)]
    fn finish<const N: usize>(
        &self,
        [point, x_axis, z_axis]: dh::TipFrame<N>,
        wanted: Option<(&ColumnMap, &mut [&mut [PoseDerivative]; N])>,
    ) -> [ToolPose; N]
    where
        Poses<N>: Width,
    {
        if let Some((columns, jacs)) = wanted {
            let scale = Lanes::splat(self.scale);
            // V and W of a column (one per pose); dp = (W × p + V)·scale.
            let moved = |cols: &[&mut PoseDerivative]| {
                let mut entries = [[0.0; 6]; N];
                for (e, col) in entries.iter_mut().zip(cols) {
                    e.copy_from_slice(&col[..6]);
                }
                let vw = lanes::ungathered(&entries);
                let w = [vw[3], vw[4], vw[5]];
                (w, lanes::scaled(&lanes::sum(&lanes::cross(&w, &point), &[vw[0], vw[1], vw[2]]), scale))
            };
            // One loop per case, none with a branch per column.
            if columns.axes {
                Poses::<N>::each_column(jacs, |cols| {
                    let (w, dp) = moved(cols);
                    let (dx, dz) = (lanes::cross(&w, &x_axis), lanes::cross(&w, &z_axis));
                    for (i, col) in cols.iter_mut().enumerate() {
                        let [p, x, z] = [dp, dx, dz];
                        **col = [p[0], p[1], p[2], x[0], x[1], x[2], z[0], z[1], z[2]].map(|v| v.lane(i));
                    }
                });
            } else {
                Poses::<N>::each_column(jacs, |cols| {
                    let (_, dp) = moved(cols);
                    for (i, col) in cols.iter_mut().enumerate() {
                        **col = [dp[0].lane(i), dp[1].lane(i), dp[2].lane(i), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                    }
                });
            }
            if let Some(c) = columns.column(ParamId::Scale.dense_index()) {
                for (i, jac) in jacs.iter_mut().enumerate() {
                    for k in 0..3 {
                        jac[c][k] += point[k].lane(i) * 1e-6;
                    }
                }
            }
        }
        std::array::from_fn(|i| ToolPose {
            position_mm: lane(&point, i) * self.scale,
            x_axis: lane(&x_axis, i),
            z_axis: lane(&z_axis, i),
        })
    }
}

/// The chains of every tip of a model (one for a single chain): an observation is evaluated on
/// the chain of the tip it names.
pub struct Tips<'m>(Vec<Chain<'m>>);

impl<'m> Tips<'m> {
    /// The chains of `model`'s tips.
    pub fn new(model: &'m ArmModel) -> Tips<'m> {
        Tips((0..model.tree.tip_count()).map(|t| Chain::for_tip(model, t)).collect())
    }

    /// True when every tip's chain [starts at the flange](Chain::starts_at_flange) for `columns`.
    pub(crate) fn start_at_flange(&self, columns: &ColumnMap) -> bool {
        self.0.iter().all(|chain| chain.starts_at_flange(columns))
    }

    /// The chain of tip `tip` (the first one for a tip the model does not have).
    pub fn tip(&self, tip: usize) -> &Chain<'m> {
        self.0.get(tip).unwrap_or(&self.0[0])
    }
}

/// Add op `op`'s share to a column gathering V (0..3) and W (3..6) (see the module doc): its
/// direction `dir` and origin `origin` in the base frame, ∂value/∂parameter `dv`.
#[inline(always)]
fn gather(col: &mut PoseDerivative, op: &Op, dir: &Vector3<f64>, origin: &Vector3<f64>, dv: f64) {
    match op.kind {
        OpKind::Translate(_) => {
            for k in 0..3 {
                col[k] += dir[k] * dv;
            }
        }
        OpKind::Rotate(_) | OpKind::Orient(_) => gather_rotation(col, dir, origin, dv),
    }
}

/// Add a rotation's share to a column (see [`gather`]): about `dir` through `origin`.
#[inline(always)]
fn gather_rotation(col: &mut PoseDerivative, dir: &Vector3<f64>, origin: &Vector3<f64>, dv: f64) {
    let v = dir.cross(origin);
    for k in 0..3 {
        col[k] -= v[k] * dv;
        col[3 + k] += dir[k] * dv;
    }
}

/// The sine and cosine of an encoder angle (degrees), as [`Chain::pose_with_sin_cos`] takes them.
pub fn encoder_sin_cos(enc_deg: f64) -> (f64, f64) {
    (enc_deg * DEG).sin_cos()
}

/// Tool pose for raw encoder angles `enc_deg` (degrees, one per joint of the model; a missing
/// angle reads as 0).
pub fn tool_pose(model: &ArmModel, enc_deg: &[f64]) -> ToolPose {
    Chain::new(model).pose(enc_deg)
}

/// Tool pose and its derivatives for the parameters in `columns`, written to `jacobian`
/// (one [`PoseDerivative`] per column; `jacobian.len()` must be `columns.len()`).
pub fn tool_pose_with_jacobian(
    model: &ArmModel,
    enc_deg: &[f64],
    columns: &ColumnMap,
    jacobian: &mut [PoseDerivative],
) -> ToolPose {
    Chain::new(model).pose_with_jacobian(enc_deg, columns, jacobian)
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

    /// A URDF arm of three joints (a vertical axis, then a horizontal one, then one along the
    /// upper link) carrying an upper link of 5 kg and a hand of 3 kg: no compliance set.
    fn three_joint_arm_with_masses() -> ArmModel {
        let mut model = ArmModel::suta_nominal();
        model.convention = Convention::Urdf;
        model.free.clear();
        model.joints = vec![
            crate::model::Joint { origin_xyz_mm: [0.0, 0.0, 300.0], ..Default::default() },
            crate::model::Joint {
                origin_xyz_mm: [0.0, 80.0, 200.0],
                axis: [0.0, 1.0, 0.0],
                ..Default::default()
            },
            crate::model::Joint {
                origin_xyz_mm: [400.0, 0.0, 0.0],
                axis: [1.0, 0.0, 0.0],
                ..Default::default()
            },
        ];
        model.tcp_mm = [300.0, 20.0, -50.0];
        model.tree.bodies = vec![
            crate::model::Body { name: "upper".into(), joint: 1, mass_kg: 5.0, com_mm: [200.0, 0.0, 10.0] },
            crate::model::Body { name: "hand".into(), joint: 2, mass_kg: 3.0, com_mm: [150.0, 30.0, -20.0] },
        ];
        model
    }

    /// A URDF arm of three joints with a mass table: the sag and bend columns are exact where
    /// the compliances are zero (the loads' own change is of their order), within 1 % at a
    /// humanoid's compliances; a sag turns the tool down.
    #[test]
    fn sag_and_bend_columns_match_central_differences() {
        let model = three_joint_arm_with_masses();
        let enc = [20.0, -15.0, 40.0];
        let params: Vec<ParamId> = (0..3).flat_map(|j| [ParamId::Sag(j), ParamId::Bend(j)]).collect();
        let rigid = tool_pose(&model, &enc).position_mm;
        for (values, tolerance) in [(0.0, 1e-6), (8.0, 1e-2)] {
            let mut m = model.clone();
            params.iter().for_each(|p| m.set(*p, values));
            let mut jac = vec![[0.0; 9]; params.len()];
            let pose = tool_pose_with_jacobian(&m, &enc, &ColumnMap::new(&params), &mut jac);
            if values > 0.0 {
                assert!(pose.position_mm.z < rigid.z, "the arm sags: {} vs {}", pose.position_mm.z, rigid.z);
            }
            for (c, &id) in params.iter().enumerate() {
                let h = 1e-4;
                let (mut plus, mut minus) = (m.clone(), m.clone());
                plus.set(id, values + h);
                minus.set(id, values - h);
                let fd =
                    (tool_pose(&plus, &enc).position_mm - tool_pose(&minus, &enc).position_mm) / (2.0 * h);
                let column = Vector3::new(jac[c][0], jac[c][1], jac[c][2]);
                assert!(
                    (column - fd).norm() <= tolerance * fd.norm().max(1e-3),
                    "{id} at {values}: {column} vs {fd}"
                );
            }
        }
    }

    /// The mass columns on the arm above (compliances of a humanoid's size) match central
    /// differences within 1 % (the loads' own change is left out, as for sag and bend); at zero
    /// compliance they are zero; and scaling every mass up and every compliance down together is
    /// a direction the Jacobian does not see (Σ m_b·∂/∂m_b = Σ s_j·∂/∂s_j + Σ b_j·∂/∂b_j).
    #[test]
    fn mass_columns_match_central_differences_and_trade_against_the_compliances() {
        let mut model = three_joint_arm_with_masses();
        let enc = [20.0, -15.0, 40.0];
        let masses = [ParamId::Mass(0), ParamId::Mass(1)];
        let compliances: Vec<ParamId> = (0..3).flat_map(|j| [ParamId::Sag(j), ParamId::Bend(j)]).collect();
        let params: Vec<ParamId> = masses.iter().chain(&compliances).copied().collect();
        let mut jac = vec![[0.0; 9]; params.len()];
        tool_pose_with_jacobian(&model, &enc, &ColumnMap::new(&params), &mut jac);
        assert!(jac[..2].iter().flatten().all(|v| *v == 0.0), "no compliance: no mass moves the tool");
        compliances.iter().enumerate().for_each(|(k, p)| model.set(*p, 6.0 + k as f64));
        tool_pose_with_jacobian(&model, &enc, &ColumnMap::new(&params), &mut jac);
        for (c, &id) in masses.iter().enumerate() {
            let (h, v) = (1e-4, model.get(id));
            let (mut plus, mut minus) = (model.clone(), model.clone());
            plus.set(id, v + h);
            minus.set(id, v - h);
            let fd = (tool_pose(&plus, &enc).position_mm - tool_pose(&minus, &enc).position_mm) / (2.0 * h);
            let column = Vector3::new(jac[c][0], jac[c][1], jac[c][2]);
            assert!(fd.norm() > 1e-3 && (column - fd).norm() <= 1e-2 * fd.norm(), "{id}: {column} vs {fd}");
        }
        let trade: Vec<f64> = (0..9)
            .map(|k| {
                params
                    .iter()
                    .enumerate()
                    .map(|(c, p)| {
                        let sign = if matches!(p, ParamId::Mass(_)) { 1.0 } else { -1.0 };
                        sign * model.get(*p) * jac[c][k]
                    })
                    .sum()
            })
            .collect();
        let size = (0..2)
            .map(|c| model.get(masses[c]) * Vector3::new(jac[c][0], jac[c][1], jac[c][2]).norm())
            .sum::<f64>();
        assert!(trade.iter().all(|v| v.abs() <= 1e-12 * size.max(1.0)), "{trade:?} vs {size}");
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
