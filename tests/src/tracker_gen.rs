//! An independent laser-tracker / optical-tracker data generator for serial arms (issue 18).
//!
//! Written from `shared/notes/tracker-calibration.md`, the DH / Hayati / URDF definitions and the
//! joint compliance of `shared/notes/references.md` (Δθ = c·τ_gravity(q)), and sharing no code with kincal's host library: its own
//! rigid transforms, classic DH with Hayati β, URDF joints, rotations, quaternions, inverse
//! kinematics (damped least squares), Horn's absolute orientation, noise and CSV writer.
//!
//! The measurement of one point is `X = B_s · F(q; truth) · t + noise` (position, mm, in the
//! instrument frame) and, for 6-DoF probes, `R_meas = R(B_s) · R(F) · R_t` as a unit quaternion
//! (scalar first). `B_s` is the instrument ← robot base of session `s`. Traits of real data are
//! switched on in [`TrackerOptions`], each documented with its formula and physical cause.
//!
//! A session is written as one CSV file: a tag line (`# kincal-tracker/1`, [`FOLDER_TAG`]), then
//! `pose,q1_deg,…,qN_deg,x_mm,y_mm,z_mm[,qw,qx,qy,qz][,sigma_mm|u95_mm][,time_s,temp_C]`.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The tag written as the first line of every session CSV (`# TAG`): change it here only.
pub const FOLDER_TAG: &str = "kincal-tracker/1";

/// A vector in mm (or a unit direction).
pub type Vec3 = [f64; 3];
/// A rotation matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn v_add(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn v_sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn v_scale(a: Vec3, s: f64) -> Vec3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

fn v_dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn v_cross(a: Vec3, b: Vec3) -> Vec3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// Euclidean length.
pub fn v_norm(a: Vec3) -> f64 {
    v_dot(a, a).sqrt()
}

fn m_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    c
}

fn m_vec(a: &Mat3, v: Vec3) -> Vec3 {
    [v_dot(a[0], v), v_dot(a[1], v), v_dot(a[2], v)]
}

fn m_t(a: &Mat3) -> Mat3 {
    [[a[0][0], a[1][0], a[2][0]], [a[0][1], a[1][1], a[2][1]], [a[0][2], a[1][2], a[2][2]]]
}

/// Rotation by `angle_rad` about the unit `axis` (Rodrigues).
pub fn axis_angle(axis: Vec3, angle_rad: f64) -> Mat3 {
    let n = v_norm(axis);
    let [x, y, z] = v_scale(axis, 1.0 / n);
    let (s, c) = angle_rad.sin_cos();
    let k = 1.0 - c;
    [
        [c + x * x * k, x * y * k - z * s, x * z * k + y * s],
        [y * x * k + z * s, c + y * y * k, y * z * k - x * s],
        [z * x * k - y * s, z * y * k + x * s, c + z * z * k],
    ]
}

/// Rotation by a rotation vector (axis · angle, rad); identity for a zero vector.
pub fn rotation_vector(w: Vec3) -> Mat3 {
    let angle = v_norm(w);
    if angle < 1e-300 {
        IDENTITY
    } else {
        axis_angle(w, angle)
    }
}

/// The rotation vector (axis · angle, rad) of a rotation matrix, via its quaternion.
pub fn rotation_vector_of(m: &Mat3) -> Vec3 {
    let [w, x, y, z] = quaternion_of(m);
    let s = (x * x + y * y + z * z).sqrt();
    if s < 1e-300 {
        return [0.0; 3];
    }
    let angle = 2.0 * s.atan2(w);
    [x / s * angle, y / s * angle, z / s * angle]
}

/// URDF's fixed-axis roll-pitch-yaw: `R = Rz(yaw) · Ry(pitch) · Rx(roll)`, radians.
pub fn rpy_matrix(rpy_rad: Vec3) -> Mat3 {
    let [r, p, y] = rpy_rad;
    m_mul(
        &axis_angle([0.0, 0.0, 1.0], y),
        &m_mul(&axis_angle([0.0, 1.0, 0.0], p), &axis_angle([1.0, 0.0, 0.0], r)),
    )
}

/// The roll-pitch-yaw (rad) of a rotation, inverse of [`rpy_matrix`]; at pitch ±90° the roll is 0.
pub fn rpy_of(m: &Mat3) -> Vec3 {
    let cos_pitch = m[0][0].hypot(m[1][0]);
    let pitch = (-m[2][0]).atan2(cos_pitch);
    if cos_pitch < 1e-9 {
        // Gimbal lock: only yaw − roll (or yaw + roll) is defined; put it all in yaw.
        return [0.0, pitch, (-m[0][1]).atan2(m[1][1])];
    }
    [m[2][1].atan2(m[2][2]), pitch, m[1][0].atan2(m[0][0])]
}

/// Unit quaternion `[w, x, y, z]` (scalar first, w ≥ 0) of a rotation matrix (Shepperd).
pub fn quaternion_of(m: &Mat3) -> [f64; 4] {
    let trace = m[0][0] + m[1][1] + m[2][2];
    let diag = [m[0][0], m[1][1], m[2][2]];
    let q = if trace >= diag[0].max(diag[1]).max(diag[2]) {
        let s = (1.0 + trace).sqrt() * 2.0;
        [s / 4.0, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    } else if diag[0] >= diag[1] && diag[0] >= diag[2] {
        let s = (1.0 + diag[0] - diag[1] - diag[2]).sqrt() * 2.0;
        [(m[2][1] - m[1][2]) / s, s / 4.0, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s]
    } else if diag[1] >= diag[2] {
        let s = (1.0 + diag[1] - diag[0] - diag[2]).sqrt() * 2.0;
        [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, s / 4.0, (m[1][2] + m[2][1]) / s]
    } else {
        let s = (1.0 + diag[2] - diag[0] - diag[1]).sqrt() * 2.0;
        [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, s / 4.0]
    };
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    q.map(|v| v * sign / n)
}

/// The rotation matrix of a quaternion `[w, x, y, z]` (normalised first).
pub fn quaternion_matrix(q: [f64; 4]) -> Mat3 {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// A rigid transform: `p ↦ rotation · p + translation_mm`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Rotation (this frame's axes as columns, in the parent frame).
    pub rotation: Mat3,
    /// Origin of this frame in the parent frame, mm.
    pub translation_mm: Vec3,
}

impl Pose {
    /// The identity transform.
    pub const IDENTITY: Pose = Pose { rotation: IDENTITY, translation_mm: [0.0; 3] };

    /// A pure rotation.
    pub fn rotation(rotation: Mat3) -> Pose {
        Pose { rotation, translation_mm: [0.0; 3] }
    }

    /// A URDF `<origin>`: translation (mm) then fixed-axis rpy (deg).
    pub fn from_xyz_rpy(xyz_mm: Vec3, rpy_deg: Vec3) -> Pose {
        Pose { rotation: rpy_matrix(rpy_deg.map(f64::to_radians)), translation_mm: xyz_mm }
    }

    /// `self · other`.
    pub fn then(&self, other: &Pose) -> Pose {
        Pose {
            rotation: m_mul(&self.rotation, &other.rotation),
            translation_mm: v_add(m_vec(&self.rotation, other.translation_mm), self.translation_mm),
        }
    }

    /// The transform of a point.
    pub fn apply(&self, p_mm: Vec3) -> Vec3 {
        v_add(m_vec(&self.rotation, p_mm), self.translation_mm)
    }

    /// The inverse transform (e.g. robot base ← instrument from a base B_s).
    pub fn inverse(&self) -> Pose {
        let rt = m_t(&self.rotation);
        Pose { rotation: rt, translation_mm: v_scale(m_vec(&rt, self.translation_mm), -1.0) }
    }
}

/// One classic DH row with Hayati's β: `Rz(θ) · Tz(d) · Tx(a) · Rx(α) · Ry(β)`, θ = q + offset.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DhRow {
    /// Joint zero: θ = q + theta_offset_deg.
    pub theta_offset_deg: f64,
    /// DH d, along the joint axis, mm.
    pub d_mm: f64,
    /// DH a, along the common normal, mm.
    pub a_mm: f64,
    /// DH α, twist about the common normal, deg.
    pub alpha_deg: f64,
    /// Hayati β about the new y axis, deg (for nearly parallel consecutive axes).
    pub beta_deg: f64,
}

impl DhRow {
    /// The row's fixed part after the joint rotation: `Tz(d) · Tx(a) · Rx(α) · Ry(β)`.
    fn fixed(&self) -> Pose {
        Pose {
            rotation: m_mul(
                &axis_angle([1.0, 0.0, 0.0], self.alpha_deg.to_radians()),
                &axis_angle([0.0, 1.0, 0.0], self.beta_deg.to_radians()),
            ),
            translation_mm: [self.a_mm, 0.0, self.d_mm],
        }
    }
}

/// One URDF revolute joint: `origin(xyz, rpy) · rotation about axis by q`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UrdfJoint {
    /// Origin translation in the parent link, mm.
    pub xyz_mm: Vec3,
    /// Origin fixed-axis roll, pitch, yaw, deg.
    pub rpy_deg: Vec3,
    /// Rotation axis in the joint frame (unit).
    pub axis: Vec3,
}

/// The chain of joints, in one of two conventions.
#[derive(Clone, Debug, PartialEq)]
pub enum Chain {
    /// Classic DH rows with Hayati β; the flange is frame N.
    ClassicDh(Vec<DhRow>),
    /// URDF joints, then a fixed `flange` origin (xyz mm, rpy deg) from the last joint's child.
    Urdf { joints: Vec<UrdfJoint>, flange_xyz_mm: Vec3, flange_rpy_deg: Vec3 },
}

/// A serial arm of revolute joints, its tool and its workspace.
#[derive(Clone, Debug, PartialEq)]
pub struct Arm {
    /// Human name.
    pub name: String,
    /// The joints.
    pub chain: Chain,
    /// Joint limits (lower, upper), deg, on q (the controller's reading).
    pub limits_deg: Vec<(f64, f64)>,
    /// Tool point t (reflector, target or probe origin) in the flange frame, mm.
    pub tool_mm: Vec3,
    /// Tool (probe) orientation R_t on the flange as fixed-axis roll, pitch, yaw, deg.
    pub tool_rpy_deg: Vec3,
    /// Sampled poses keep the tool point above this height in the base frame, mm.
    pub min_z_mm: f64,
    /// Sampled poses keep the tool point this far from the base's z axis, mm.
    pub min_radius_mm: f64,
}

/// Where the joints and the flange are for one configuration (base frame).
#[derive(Clone, Debug)]
pub struct Frames {
    /// For each joint: a point on its axis, mm.
    pub axis_origin_mm: Vec<Vec3>,
    /// For each joint: its axis direction (unit).
    pub axis_dir: Vec<Vec3>,
    /// The flange (last link) frame.
    pub flange: Pose,
}

impl Arm {
    /// A KUKA-iiwa-14-like 7R arm, classic DH (mm, deg): 360/420/400/126 mm, spherical shoulder
    /// and wrist, every a = 0. A tracker target on a bracket.
    pub fn iiwa7() -> Arm {
        let row =
            |d_mm, alpha_deg| DhRow { theta_offset_deg: 0.0, d_mm, a_mm: 0.0, alpha_deg, beta_deg: 0.0 };
        Arm {
            name: "7R iiwa-like".into(),
            chain: Chain::ClassicDh(vec![
                row(360.0, -90.0),
                row(0.0, 90.0),
                row(420.0, 90.0),
                row(0.0, -90.0),
                row(400.0, -90.0),
                row(0.0, 90.0),
                row(126.0, 0.0),
            ]),
            limits_deg: vec![
                (-170.0, 170.0),
                (-120.0, 120.0),
                (-170.0, 170.0),
                (-120.0, 120.0),
                (-170.0, 170.0),
                (-120.0, 120.0),
                (-175.0, 175.0),
            ],
            tool_mm: [40.0, -25.0, 120.0],
            tool_rpy_deg: [5.0, -10.0, 30.0],
            min_z_mm: 150.0,
            min_radius_mm: 300.0,
        }
    }

    /// A 6R industrial arm (Motoman-MA1400-like sizes), classic DH with joints 2 and 3 parallel
    /// (row 2 has α = 0, so its d is replaced by Hayati's β). A 6-DoF probe on the flange.
    pub fn industrial6() -> Arm {
        let row = |theta_offset_deg, d_mm, a_mm, alpha_deg| DhRow {
            theta_offset_deg,
            d_mm,
            a_mm,
            alpha_deg,
            beta_deg: 0.0,
        };
        Arm {
            name: "6R industrial".into(),
            chain: Chain::ClassicDh(vec![
                row(0.0, 450.0, 150.0, -90.0),
                row(-90.0, 0.0, 614.0, 0.0),
                row(0.0, 0.0, 200.0, -90.0),
                row(0.0, 640.0, 0.0, 90.0),
                row(0.0, 0.0, 0.0, -90.0),
                row(0.0, 100.0, 0.0, 0.0),
            ]),
            limits_deg: vec![
                (-170.0, 170.0),
                (-90.0, 150.0),
                (-80.0, 90.0),
                (-150.0, 150.0),
                (-120.0, 120.0),
                (-200.0, 200.0),
            ],
            tool_mm: [60.0, -30.0, 180.0],
            tool_rpy_deg: [0.0, 15.0, -40.0],
            min_z_mm: -300.0,
            min_radius_mm: 450.0,
        }
    }

    /// A 12R hyper-redundant arm (the most joints kincal takes), classic DH: twelve modules of
    /// alternating ±90° twist with d and a both non-zero on most rows (no two consecutive axes
    /// parallel), about 1.6 m of reach. A tracker target on a bracket.
    pub fn serial12() -> Arm {
        let d_mm = [320.0, 40.0, 180.0, 35.0, 170.0, 30.0, 160.0, 25.0, 150.0, 20.0, 140.0, 90.0];
        let a_mm = [20.0, 110.0, 15.0, 100.0, 15.0, 95.0, 10.0, 90.0, 10.0, 80.0, 5.0, 0.0];
        let rows = (0..12)
            .map(|j| DhRow {
                theta_offset_deg: 0.0,
                d_mm: d_mm[j],
                a_mm: a_mm[j],
                alpha_deg: if j == 11 {
                    0.0
                } else if j % 2 == 0 {
                    -90.0
                } else {
                    90.0
                },
                beta_deg: 0.0,
            })
            .collect();
        Arm {
            name: "12R serial".into(),
            chain: Chain::ClassicDh(rows),
            limits_deg: vec![(-150.0, 150.0); 12],
            tool_mm: [30.0, -20.0, 80.0],
            tool_rpy_deg: [0.0, 0.0, 0.0],
            min_z_mm: 0.0,
            min_radius_mm: 200.0,
        }
    }

    /// A 2R arm: a vertical turntable axis and a horizontal shoulder, classic DH (the fewest
    /// joints that still leave arm parameters a base cannot absorb).
    pub fn shoulder2() -> Arm {
        let row =
            |d_mm, a_mm, alpha_deg| DhRow { theta_offset_deg: 0.0, d_mm, a_mm, alpha_deg, beta_deg: 0.0 };
        Arm {
            name: "2R shoulder".into(),
            chain: Chain::ClassicDh(vec![row(400.0, 80.0, -90.0), row(60.0, 600.0, 0.0)]),
            limits_deg: vec![(-170.0, 170.0), (-120.0, 120.0)],
            tool_mm: [50.0, -30.0, 40.0],
            tool_rpy_deg: [0.0, 0.0, 0.0],
            min_z_mm: -1000.0,
            min_radius_mm: 100.0,
        }
    }

    /// Number of joints.
    pub fn joints(&self) -> usize {
        match &self.chain {
            Chain::ClassicDh(rows) => rows.len(),
            Chain::Urdf { joints, .. } => joints.len(),
        }
    }

    /// The DH rows, if this arm is in classic DH.
    pub fn dh_rows(&self) -> Option<&[DhRow]> {
        match &self.chain {
            Chain::ClassicDh(rows) => Some(rows),
            Chain::Urdf { .. } => None,
        }
    }

    /// The tool frame on the flange: translation t, rotation R_t.
    pub fn tool(&self) -> Pose {
        Pose::from_xyz_rpy(self.tool_mm, self.tool_rpy_deg)
    }

    /// Joint axes and the flange for joint readings `q_deg`.
    pub fn frames(&self, q_deg: &[f64]) -> Frames {
        assert_eq!(q_deg.len(), self.joints(), "one reading per joint");
        let mut frame = Pose::IDENTITY;
        let mut axis_origin_mm = Vec::new();
        let mut axis_dir = Vec::new();
        match &self.chain {
            Chain::ClassicDh(rows) => {
                for (row, q) in rows.iter().zip(q_deg) {
                    axis_origin_mm.push(frame.translation_mm);
                    axis_dir.push(m_vec(&frame.rotation, [0.0, 0.0, 1.0]));
                    let turn = axis_angle([0.0, 0.0, 1.0], (q + row.theta_offset_deg).to_radians());
                    frame = frame.then(&Pose::rotation(turn)).then(&row.fixed());
                }
            }
            Chain::Urdf { joints, flange_xyz_mm, flange_rpy_deg } => {
                for (joint, q) in joints.iter().zip(q_deg) {
                    frame = frame.then(&Pose::from_xyz_rpy(joint.xyz_mm, joint.rpy_deg));
                    axis_origin_mm.push(frame.translation_mm);
                    let dir = m_vec(&frame.rotation, joint.axis);
                    axis_dir.push(v_scale(dir, 1.0 / v_norm(dir)));
                    frame = frame.then(&Pose::rotation(axis_angle(joint.axis, q.to_radians())));
                }
                frame = frame.then(&Pose::from_xyz_rpy(*flange_xyz_mm, *flange_rpy_deg));
            }
        }
        Frames { axis_origin_mm, axis_dir, flange: frame }
    }

    /// The tool frame in the robot base frame, F(q) · (t, R_t).
    pub fn tool_pose(&self, q_deg: &[f64]) -> Pose {
        self.frames(q_deg).flange.then(&self.tool())
    }

    /// The same arm with URDF joints: joint j's origin is row j−1's fixed part followed by
    /// `Rz(offset_j)`, its axis z; the flange is row N's fixed part. Same forward kinematics.
    pub fn to_urdf_chain(&self) -> Arm {
        let Chain::ClassicDh(rows) = &self.chain else { return self.clone() };
        let mut before = Pose::IDENTITY;
        let mut joints = Vec::new();
        for row in rows {
            let origin =
                before.then(&Pose::rotation(axis_angle([0.0, 0.0, 1.0], row.theta_offset_deg.to_radians())));
            joints.push(UrdfJoint {
                xyz_mm: origin.translation_mm,
                rpy_deg: rpy_of(&origin.rotation).map(f64::to_degrees),
                axis: [0.0, 0.0, 1.0],
            });
            before = row.fixed();
        }
        Arm {
            chain: Chain::Urdf {
                joints,
                flange_xyz_mm: before.translation_mm,
                flange_rpy_deg: rpy_of(&before.rotation).map(f64::to_degrees),
            },
            ..self.clone()
        }
    }

    /// This arm as a URDF document (metres, radians): links `base_link`, `link_1` … `link_N`,
    /// `flange` and `tool0` (the tool frame t, R_t); joints `joint_1` … `joint_N` (revolute, with
    /// the limits), `flange_joint` and `tool_joint` (fixed). A DH arm is converted by
    /// [`Arm::to_urdf_chain`], so the URDF joint value is the reading q (offsets are in the origins).
    pub fn urdf(&self, robot_name: &str) -> String {
        let Chain::Urdf { joints, flange_xyz_mm, flange_rpy_deg } = self.to_urdf_chain().chain else {
            unreachable!("to_urdf_chain returns a URDF chain")
        };
        let origin = |xyz_mm: Vec3, rpy_deg: Vec3| {
            // `+ 0.0` writes −0 as 0.
            let xyz = xyz_mm.map(|v| v / 1000.0 + 0.0);
            let rpy = rpy_deg.map(|v| v.to_radians() + 0.0);
            format!(
                "<origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>",
                xyz[0], xyz[1], xyz[2], rpy[0], rpy[1], rpy[2]
            )
        };
        let mut s = String::new();
        let _ = writeln!(s, "<?xml version=\"1.0\"?>");
        let _ = writeln!(s, "<!-- {}: written by kincal-e2e tracker_gen -->", self.name);
        let _ = writeln!(s, "<robot name=\"{robot_name}\">");
        let _ = writeln!(s, "  <link name=\"base_link\"/>");
        let mut parent = "base_link".to_string();
        for (j, joint) in joints.iter().enumerate() {
            let child = format!("link_{}", j + 1);
            let (lo, hi) = self.limits_deg[j];
            let _ = writeln!(s, "  <link name=\"{child}\"/>");
            let _ = writeln!(s, "  <joint name=\"joint_{}\" type=\"revolute\">", j + 1);
            let _ = writeln!(s, "    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>");
            let _ = writeln!(s, "    {}", origin(joint.xyz_mm, joint.rpy_deg));
            let _ = writeln!(s, "    <axis xyz=\"{} {} {}\"/>", joint.axis[0], joint.axis[1], joint.axis[2]);
            let _ = writeln!(
                s,
                "    <limit lower=\"{}\" upper=\"{}\" effort=\"100\" velocity=\"1\"/>",
                lo.to_radians(),
                hi.to_radians()
            );
            let _ = writeln!(s, "  </joint>");
            parent = child;
        }
        for (name, child, xyz, rpy) in [
            ("flange_joint", "flange", flange_xyz_mm, flange_rpy_deg),
            ("tool_joint", "tool0", self.tool_mm, self.tool_rpy_deg),
        ] {
            let _ = writeln!(s, "  <link name=\"{child}\"/>");
            let _ = writeln!(s, "  <joint name=\"{name}\" type=\"fixed\">");
            let _ = writeln!(s, "    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>");
            let _ = writeln!(s, "    {}", origin(xyz, rpy));
            let _ = writeln!(s, "  </joint>");
            parent = child.to_string();
        }
        let _ = writeln!(s, "</robot>");
        s
    }

    /// Write [`Arm::urdf`] to `path`.
    pub fn write_urdf(&self, path: &Path, robot_name: &str) -> std::io::Result<()> {
        std::fs::write(path, self.urdf(robot_name))
    }

    /// The arm as a `kincal-arm/1` model (TOML; classic DH with β as `axis_deg`; nothing freed),
    /// or `None` for a URDF chain. The tool rotation has no place in it.
    pub fn kincal_model_toml(&self) -> Option<String> {
        let rows = self.dh_rows()?;
        let [x, y, z] = self.tool_mm;
        let mut s = format!(
            "format = \"kincal-arm/1\"\nname = \"{}\"\nconvention = \"classic\"\ntcp_mm = [{x:?}, {y:?}, {z:?}]\n",
            self.name
        );
        for row in rows {
            let _ = write!(
                s,
                "\n[[joint]]\noffset_deg = {:?}\nd_mm = {:?}\na_mm = {:?}\nalpha_deg = {:?}\naxis_deg = {:?}\n",
                row.theta_offset_deg, row.d_mm, row.a_mm, row.alpha_deg, row.beta_deg
            );
        }
        Some(s)
    }

    /// The joint angles the arm really takes at readings `q_deg` under gravity sag ([`GravitySag`]).
    fn sagged_q(&self, q_deg: &[f64], sag: Option<&GravitySag>) -> Vec<f64> {
        let Some(sag) = sag else { return q_deg.to_vec() };
        let levers = gravity_levers_m(self, q_deg, sag.down);
        q_deg.iter().zip(&levers).zip(&sag.compliance_deg_per_m).map(|((q, l), c)| q + c * l).collect()
    }
}

/// For each joint, the gravity moment about its axis of unit masses at the joint-frame origins
/// beyond it, the flange origin and the tool point (m): `Σ_k ((m_k − o_j) × ĝ) · z_j`, with ĝ
/// = `down` the unit direction of gravity in the robot base frame, on the undeflected arm.
pub fn gravity_levers_m(arm: &Arm, q_deg: &[f64], down: Vec3) -> Vec<f64> {
    let frames = arm.frames(q_deg);
    let mut masses = frames.axis_origin_mm.clone();
    masses.push(frames.flange.translation_mm);
    masses.push(frames.flange.apply(arm.tool_mm));
    (0..arm.joints())
        .map(|j| {
            let o = frames.axis_origin_mm[j];
            masses[j + 1..]
                .iter()
                .map(|m| v_dot(v_cross(v_scale(v_sub(*m, o), 1e-3), down), frames.axis_dir[j]))
                .sum()
        })
        .collect()
}

/// Sizes of the hidden errors that make the truth from the nominal arm: each value is drawn
/// uniformly in ±size. Set a size to 0 to leave that kind of parameter at nominal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HiddenErrorSizes {
    /// Joint zero offsets (encoder mounted at an arbitrary zero), deg.
    pub offset_deg: f64,
    /// DH d and a, or URDF origin xyz (machining and assembly), mm.
    pub length_mm: f64,
    /// DH α, or URDF origin rpy (axes not at their nominal angle), deg.
    pub twist_deg: f64,
    /// Hayati β on rows whose nominal α is 0 (parallel consecutive axes; their d stays nominal,
    /// as in Hayati's convention), deg.
    pub beta_deg: f64,
    /// Tool point against its CAD value, mm.
    pub tool_mm: f64,
}

impl Default for HiddenErrorSizes {
    fn default() -> Self {
        HiddenErrorSizes { offset_deg: 0.1, length_mm: 0.5, twist_deg: 0.1, beta_deg: 0.1, tool_mm: 1.0 }
    }
}

/// One hidden error, named as kincal names parameters (`offset:2`, `length:3`, `link_offset:1`,
/// `twist:4`, `axis:2`, `tcp.x`; URDF: `origin:j.x_mm` … `origin:j.yaw_deg`), joints 1-based.
#[derive(Clone, Debug, PartialEq)]
pub struct HiddenError {
    /// Parameter name.
    pub name: String,
    /// Its nominal value (mm or deg).
    pub nominal: f64,
    /// Its true value (mm or deg).
    pub truth: f64,
}

/// The true arm: the nominal arm with seeded hidden errors of the given sizes.
pub fn perturb(nominal: &Arm, sizes: &HiddenErrorSizes, seed: u64) -> (Arm, Vec<HiddenError>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut errors = Vec::new();
    let mut draw = |name: String, value: &mut f64, size: f64| {
        if size > 0.0 {
            let nominal = *value;
            *value += size * (2.0 * rng.random::<f64>() - 1.0);
            errors.push(HiddenError { name, nominal, truth: *value });
        }
    };
    let mut truth = nominal.clone();
    let n = truth.joints();
    match &mut truth.chain {
        Chain::ClassicDh(rows) => {
            for (j, row) in rows.iter_mut().enumerate() {
                let k = j + 1;
                let parallel = k < n && row.alpha_deg.abs() < 1e-9;
                draw(format!("offset:{k}"), &mut row.theta_offset_deg, sizes.offset_deg);
                if parallel {
                    draw(format!("axis:{k}"), &mut row.beta_deg, sizes.beta_deg);
                } else {
                    draw(format!("length:{k}"), &mut row.d_mm, sizes.length_mm);
                }
                draw(format!("link_offset:{k}"), &mut row.a_mm, sizes.length_mm);
                draw(format!("twist:{k}"), &mut row.alpha_deg, sizes.twist_deg);
            }
        }
        Chain::Urdf { joints, .. } => {
            for (j, joint) in joints.iter_mut().enumerate() {
                for (axis, v) in ["x_mm", "y_mm", "z_mm"].iter().zip(joint.xyz_mm.iter_mut()) {
                    draw(format!("origin:{}.{axis}", j + 1), v, sizes.length_mm);
                }
                for (axis, v) in ["roll_deg", "pitch_deg", "yaw_deg"].iter().zip(joint.rpy_deg.iter_mut()) {
                    draw(format!("origin:{}.{axis}", j + 1), v, sizes.twist_deg);
                }
            }
        }
    }
    for (axis, v) in ["tcp.x", "tcp.y", "tcp.z"].iter().zip(truth.tool_mm.iter_mut()) {
        draw(axis.to_string(), v, sizes.tool_mm);
    }
    (truth, errors)
}

/// Inverse kinematics by damped least squares (Levenberg–Marquardt damping: a step is kept only
/// when it lowers the error, else the damping grows) on this module's own kinematics: the joint
/// readings near `q_start_deg` that put the tool frame at `target` (position and orientation,
/// base frame). Orientation errors are weighted by 500 mm/rad. `None` when it does not converge
/// to 1e-9 mm and 1e-12 rad within 100 iterations or ends outside the joint limits.
pub fn inverse_kinematics(arm: &Arm, target: &Pose, q_start_deg: &[f64]) -> Option<Vec<f64>> {
    const LEVER_MM: f64 = 500.0;
    // The pose error (mm, and rad × lever) and the Jacobian columns (per rad) at `q`.
    let error_at = |q: &[f64]| -> ([f64; 6], Vec<[f64; 6]>) {
        let frames = arm.frames(q);
        let tool = frames.flange.then(&arm.tool());
        let e_p = v_sub(target.translation_mm, tool.translation_mm);
        let e_w = v_scale(rotation_vector_of(&m_mul(&target.rotation, &m_t(&tool.rotation))), LEVER_MM);
        let columns = (0..q.len())
            .map(|j| {
                let z = frames.axis_dir[j];
                let v = v_cross(z, v_sub(tool.translation_mm, frames.axis_origin_mm[j]));
                [v[0], v[1], v[2], z[0] * LEVER_MM, z[1] * LEVER_MM, z[2] * LEVER_MM]
            })
            .collect();
        ([e_p[0], e_p[1], e_p[2], e_w[0], e_w[1], e_w[2]], columns)
    };
    let size = |e: &[f64; 6]| e.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut q = q_start_deg.to_vec();
    let (mut e, mut columns) = error_at(&q);
    let mut damping = 1.0;
    for _ in 0..100 {
        if size(&[e[0], e[1], e[2], 0.0, 0.0, 0.0]) < 1e-9
            && size(&[e[3], e[4], e[5], 0.0, 0.0, 0.0]) < 1e-12 * LEVER_MM
        {
            let inside = q.iter().zip(&arm.limits_deg).all(|(v, (lo, hi))| v >= lo && v <= hi);
            return inside.then_some(q);
        }
        // (J Jᵀ + μ I) y = e, Δq = Jᵀ y.
        let mut a = [[0.0; 7]; 6];
        for r in 0..6 {
            for c in 0..6 {
                a[r][c] = columns.iter().map(|col| col[r] * col[c]).sum::<f64>()
                    + if r == c { damping } else { 0.0 };
            }
            a[r][6] = e[r];
        }
        let y = solve6(a)?;
        let trial: Vec<f64> = q
            .iter()
            .zip(&columns)
            .map(|(v, col)| v + (0..6).map(|r| col[r] * y[r]).sum::<f64>().to_degrees())
            .collect();
        let (e_trial, columns_trial) = error_at(&trial);
        if size(&e_trial) < size(&e) {
            (q, e, columns) = (trial, e_trial, columns_trial);
            damping = (damping / 4.0).max(1e-12);
        } else {
            damping *= 8.0;
            if damping > 1e12 {
                return None;
            }
        }
    }
    None
}

/// Gaussian elimination with partial pivoting on an augmented 6 × 7 system.
fn solve6(mut a: [[f64; 7]; 6]) -> Option<[f64; 6]> {
    for col in 0..6 {
        let pivot = (col..6).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[pivot][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, pivot);
        let pivot_row = a[col];
        for row in a.iter_mut().skip(col + 1) {
            let f = row[col] / pivot_row[col];
            row.iter_mut().zip(&pivot_row).skip(col).for_each(|(x, p)| *x -= f * p);
        }
    }
    let mut x = [0.0; 6];
    for row in (0..6).rev() {
        let s: f64 = (row + 1..6).map(|k| a[row][k] * x[k]).sum();
        x[row] = (a[row][6] - s) / a[row][row];
    }
    Some(x)
}

/// The rigid transform B minimising Σ |x_i − B·p_i|² (Horn's quaternion method, 1987): the
/// quaternion is the eigenvector of Horn's 4 × 4 matrix with the largest eigenvalue (Jacobi).
pub fn fit_rigid(p_mm: &[Vec3], x_mm: &[Vec3]) -> Pose {
    let n = p_mm.len().min(x_mm.len()) as f64;
    let mean = |v: &[Vec3]| v.iter().fold([0.0; 3], |a, b| v_add(a, *b)).map(|c| c / n);
    let (pc, xc) = (mean(p_mm), mean(x_mm));
    let mut s = [[0.0; 3]; 3];
    for (p, x) in p_mm.iter().zip(x_mm) {
        let (a, b) = (v_sub(*p, pc), v_sub(*x, xc));
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let mut k = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let mut v = [[0.0; 4]; 4];
    (0..4).for_each(|i| v[i][i] = 1.0);
    for _ in 0..100 {
        let off: f64 = (0..4)
            .flat_map(|i| (0..4).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| k[i][j].powi(2))
            .sum();
        if off < 1e-30 {
            break;
        }
        for p in 0..4 {
            for q in p + 1..4 {
                if k[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (k[q][q] - k[p][p]) / (2.0 * k[p][q]);
                // Jacobi rotation J (c, s in rows/columns p, q): K ← Jᵀ K J, V ← V J.
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let c = 1.0 / (t * t + 1.0).sqrt();
                let sn = t * c;
                let turn_columns = |m: &mut [[f64; 4]; 4]| {
                    for row in m.iter_mut() {
                        let (a, b) = (row[p], row[q]);
                        row[p] = c * a - sn * b;
                        row[q] = sn * a + c * b;
                    }
                };
                turn_columns(&mut k);
                turn_columns(&mut v);
                let (kp, kq) = (k[p], k[q]);
                k[p] = std::array::from_fn(|r| c * kp[r] - sn * kq[r]);
                k[q] = std::array::from_fn(|r| sn * kp[r] + c * kq[r]);
            }
        }
    }
    let best = (0..4).max_by(|&a, &b| k[a][a].total_cmp(&k[b][b])).unwrap_or(0);
    let rotation = quaternion_matrix([v[0][best], v[1][best], v[2][best], v[3][best]]);
    Pose { rotation, translation_mm: v_sub(xc, m_vec(&rotation, pc)) }
}

/// Residual statistics of points, 3-D distances, mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Floor {
    /// Points.
    pub points: usize,
    /// √(mean |r|²).
    pub rms_mm: f64,
    /// mean |r|.
    pub mean_mm: f64,
    /// max |r|.
    pub max_mm: f64,
}

impl Floor {
    /// The statistics of `distances_mm` (all zero for none).
    fn of(distances_mm: &[f64]) -> Floor {
        let n = distances_mm.len().max(1) as f64;
        Floor {
            points: distances_mm.len(),
            rms_mm: (distances_mm.iter().map(|d| d * d).sum::<f64>() / n).sqrt(),
            mean_mm: distances_mm.iter().sum::<f64>() / n,
            max_mm: distances_mm.iter().fold(0.0, |m: f64, d| m.max(*d)),
        }
    }
}

/// Gravity sag (joint compliance, SUTA thesis): the weight of the links beyond joint j twists it
/// by `δθ_j = c_j · L_j(q)` (deg), with `L_j` the gravity lever of [`gravity_levers_m`] (m) and
/// `c_j` in deg/m; the deflected angle `q_j + δθ_j` is what the arm really takes while the
/// controller reports `q_j`.
#[derive(Clone, Debug, PartialEq)]
pub struct GravitySag {
    /// c_j per joint, deg/m.
    pub compliance_deg_per_m: Vec<f64>,
    /// ĝ, the unit direction of gravity in the robot base frame: `[0, 0, −1]` for a robot on
    /// the floor, `[0, 0, 1]` hanging from the ceiling, horizontal on a wall.
    pub down: Vec3,
}

impl GravitySag {
    /// Compliances `c_j` (deg/m) of a robot standing on the floor.
    pub fn floor_mounted(compliance_deg_per_m: Vec<f64>) -> GravitySag {
        GravitySag { compliance_deg_per_m, down: [0.0, 0.0, -1.0] }
    }
}

/// A periodic encoder error (a cyclic error of a joint's encoder or of its gearing): when the
/// controller reports `q_j` the joint really stands at `q_j + sin_deg·sin(n·q_j) + cos_deg·cos(n·q_j)`,
/// n cycles per revolution of the reported angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EncoderHarmonic {
    /// The joint, 1-based.
    pub joint: usize,
    /// Cycles per revolution, n ≥ 1.
    pub order: u32,
    /// Amplitude of the sine term, deg.
    pub sin_deg: f64,
    /// Amplitude of the cosine term, deg.
    pub cos_deg: f64,
}

impl EncoderHarmonic {
    /// The angles the joints really take at readings `q_deg`.
    fn applied(&self, q_deg: &[f64]) -> Vec<f64> {
        let mut out = q_deg.to_vec();
        if let Some(q) = out.get_mut(self.joint.wrapping_sub(1)) {
            let phase = f64::from(self.order) * q.to_radians();
            *q += self.sin_deg * phase.sin() + self.cos_deg * phase.cos();
        }
        out
    }
}

/// Slow thermal drift: a steel arm grows with temperature, so every length of the arm and tool
/// scales by `1 + k·(T(t) − T_ref)`; the measured point becomes `(1 + k·ΔT) · F(q)·t` in the base
/// frame. Over a session T rises by `rise_c`: linearly, `T(t) = T_ref + rise_c · t / D` (an
/// overnight warm-up), or as a room warming towards a new level with time constant τ,
/// `T(t) = T_ref + rise_c · (1 − e^(−t/τ)) / (1 − e^(−D/τ))` (D the session's duration).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThermalDrift {
    /// k, 1/°C (12e-6: 12 µm per °C per metre of steel).
    pub expansion_per_c: f64,
    /// T_ref: the temperature at which the truth holds and each session starts, °C.
    pub start_c: f64,
    /// Rise of T over a session, °C.
    pub rise_c: f64,
    /// Only this session (0-based) warms; the others stay at T_ref. `None`: every session.
    pub session: Option<usize>,
    /// τ of an exponential warm-up, s; `None`: a linear rise.
    pub time_constant_s: Option<f64>,
}

impl ThermalDrift {
    /// Temperature rise at `time_s` into session `s` of `duration_s`, °C.
    pub fn rise_at(&self, s: usize, time_s: f64, duration_s: f64) -> f64 {
        if self.session.is_some_and(|only| only != s) {
            return 0.0;
        }
        match self.time_constant_s {
            Some(tau) => self.rise_c * (1.0 - (-time_s / tau).exp()) / (1.0 - (-duration_s / tau).exp()),
            None => self.rise_c * time_s / duration_s,
        }
    }
}

/// A tool re-mounted in one session (a probe taken off and put back): in `session` the tool point
/// sits `size_mm` (0.5–1 mm) from where the other sessions have it, in a seeded random direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ToolRemount {
    /// Session index (0-based).
    pub session: usize,
    /// Distance of the displaced tool point, mm.
    pub size_mm: f64,
}

/// A 6-DoF probe put back turned on its mount in one session: its rotation on the flange and its
/// point turn about the flange z axis, `R_t,S = Rz(θ)·R_t`, `t_S = Rz(θ)·t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ProbeTurn {
    /// Session index (0-based).
    pub session: usize,
    /// The turn θ about the flange z axis, degrees.
    pub angle_deg: f64,
}

/// Instrument drift within one session (the tracker's stand or the floor under it settling): the
/// robot base slides linearly in the instrument frame, `X = B_s · p + v · t`, with |v| =
/// `mm_per_hour` / 3600 s in a seeded random direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstrumentDrift {
    /// Session index (0-based).
    pub session: usize,
    /// Drift speed, mm/h.
    pub mm_per_hour: f64,
}

/// Single bad points (a beam broken and caught again on the wrong spot of the reflector, a probe
/// bumped): `count` measurements drawn at random over all sessions get a gross error of
/// `size_mm` in a random direction, `X = B_s · p + e_i + noise`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BadPoints {
    /// How many measurements.
    pub count: usize,
    /// Size of each error, mm.
    pub size_mm: f64,
}

/// The stated uncertainty column written per point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UncertaintyColumn {
    /// No column.
    None,
    /// `sigma_mm`: the instrument's σ per axis.
    SigmaMm,
    /// `u95_mm`: the expanded uncertainty, 2σ (k = 2).
    U95Mm,
}

/// A mistake in the exported file, for tests of the reader's plausibility checks: the values are
/// written wrongly under the right header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportMistake {
    /// A correct file.
    None,
    /// Positions (and `sigma_mm`/`u95_mm`) in metres under the `_mm` columns.
    MetresUnderMm,
    /// Joint readings in radians under the `_deg` columns.
    RadiansUnderDeg,
    /// The quaternion scalar last (`qx, qy, qz, qw`) under `qw, qx, qy, qz`.
    ScalarLastQuaternion,
}

/// One session (one placement of the instrument).
#[derive(Clone, Debug, PartialEq)]
pub struct SessionPlan {
    /// File name without `.csv`.
    pub name: String,
    /// Distinct poses (each measured `repeats` times).
    pub poses: usize,
    /// A position grid at one fixed tool orientation (IK on the true arm), spaced
    /// `grid_spacing_mm`; otherwise random joint configurations.
    pub constant_orientation: bool,
    /// The poses' joint angles given (deg, e.g. a plan's); empty: drawn as above.
    pub joints_deg: Vec<Vec<f64>>,
}

/// Everything the generator does; presets in [`TrackerOptions::iiwa_five_sessions`] and
/// [`TrackerOptions::industrial_6dof`], traits switched on by the fields.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerOptions {
    /// Seed of everything random.
    pub seed: u64,
    /// The nominal arm.
    pub arm: Arm,
    /// Hidden errors that make the true arm.
    pub hidden: HiddenErrorSizes,
    /// The sessions.
    pub sessions: Vec<SessionPlan>,
    /// Instrument noise σ per axis, mm (0.01–0.05 for a laser tracker).
    pub noise_sigma_mm: f64,
    /// Orientation columns `qw,qx,qy,qz` with this noise σ per axis (deg); `None`: positions only.
    pub orientation_sigma_deg: Option<f64>,
    /// The stated uncertainty column.
    pub uncertainty: UncertaintyColumn,
    /// Each pose measured this many times in a row (the `pose` column repeats): a floor.
    pub repeats: usize,
    /// Tool re-mounted in one session.
    pub tool_remount: Option<ToolRemount>,
    /// A 6-DoF probe turned on its mount in one session.
    pub probe_turn: Option<ProbeTurn>,
    /// Thermal drift within each session; also writes `time_s` and `temp_C`.
    pub thermal: Option<ThermalDrift>,
    /// Write `time_s` and `temp_C` even without thermal drift (`temp_C` is then 20 °C).
    pub time_columns: bool,
    /// Instrument drift in one session.
    pub instrument_drift: Option<InstrumentDrift>,
    /// Single bad points.
    pub bad_points: Option<BadPoints>,
    /// Gravity sag.
    pub gravity_sag: Option<GravitySag>,
    /// A periodic encoder error on one joint.
    pub encoder_harmonic: Option<EncoderHarmonic>,
    /// Low coverage of a joint: joint (1-based) sampled only within ± half this span (deg)
    /// around the middle of its range.
    pub low_coverage: Option<(usize, f64)>,
    /// Time between measurements, s.
    pub seconds_per_point: f64,
    /// Spacing of constant-orientation grids, mm.
    pub grid_spacing_mm: f64,
    /// The tag line of every CSV.
    pub tag: String,
    /// A mistake in the written files (the truth and the rows stay right).
    pub export_mistake: ExportMistake,
}

impl TrackerOptions {
    /// The 7R arm, five random-pose sessions of 60 poses, σ = 0.02 mm, positions only, the
    /// default hidden errors, `sigma_mm` column, no other trait.
    pub fn iiwa_five_sessions(seed: u64) -> TrackerOptions {
        TrackerOptions {
            seed,
            arm: Arm::iiwa7(),
            hidden: HiddenErrorSizes::default(),
            sessions: (1..=5)
                .map(|k| SessionPlan {
                    name: format!("session_{k}"),
                    poses: 60,
                    constant_orientation: false,
                    joints_deg: Vec::new(),
                })
                .collect(),
            noise_sigma_mm: 0.02,
            orientation_sigma_deg: None,
            uncertainty: UncertaintyColumn::SigmaMm,
            repeats: 1,
            tool_remount: None,
            probe_turn: None,
            thermal: None,
            time_columns: false,
            instrument_drift: None,
            bad_points: None,
            gravity_sag: None,
            encoder_harmonic: None,
            low_coverage: None,
            seconds_per_point: 15.0,
            grid_spacing_mm: 100.0,
            tag: FOLDER_TAG.into(),
            export_mistake: ExportMistake::None,
        }
    }

    /// The 6R industrial arm with a 6-DoF probe (orientation σ 0.005°), four sessions, `u95_mm`.
    pub fn industrial_6dof(seed: u64) -> TrackerOptions {
        TrackerOptions {
            arm: Arm::industrial6(),
            sessions: (1..=4)
                .map(|k| SessionPlan {
                    name: format!("day_{k}"),
                    poses: 50,
                    constant_orientation: false,
                    joints_deg: Vec::new(),
                })
                .collect(),
            orientation_sigma_deg: Some(0.005),
            uncertainty: UncertaintyColumn::U95Mm,
            ..TrackerOptions::iiwa_five_sessions(seed)
        }
    }

    /// Few placements: keep only the first `count` sessions.
    pub fn few_placements(mut self, count: usize) -> TrackerOptions {
        self.sessions.truncate(count.max(1));
        self
    }
}

/// One measured row.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// Pose index within the session (repeats share it).
    pub pose: usize,
    /// Joint readings as the controller reports them, deg.
    pub q_deg: Vec<f64>,
    /// Measured point in the instrument frame, mm.
    pub x_mm: Vec3,
    /// The same without noise and bad-point error (instrument drift included), mm.
    pub exact_mm: Vec3,
    /// Measured orientation `[qw, qx, qy, qz]`, if the probe is 6-DoF.
    pub quaternion: Option<[f64; 4]>,
    /// The same without noise.
    pub exact_rotation: Mat3,
    /// Time since the session started, s.
    pub time_s: f64,
    /// Arm temperature, °C.
    pub temp_c: f64,
    /// The tool pose in the robot base frame without noise (sag, drift and re-mount included).
    pub tool_in_base: Pose,
}

/// One generated session.
#[derive(Clone, Debug, PartialEq)]
pub struct Session {
    /// Its plan.
    pub plan: SessionPlan,
    /// Its rows.
    pub rows: Vec<Row>,
}

/// What the generator used: compare recovered parameters with it.
#[derive(Clone, Debug, PartialEq)]
pub struct Truth {
    /// The nominal arm (the fit's start).
    pub nominal: Arm,
    /// The true arm.
    pub truth: Arm,
    /// Every hidden error, named as kincal names parameters.
    pub hidden_errors: Vec<HiddenError>,
    /// Instrument ← robot base per session.
    pub bases: Vec<Pose>,
    /// Session with the re-mounted tool and the displacement of its tool point (flange frame, mm).
    pub tool_remount: Option<(usize, Vec3)>,
    /// Instrument noise σ per axis, mm.
    pub noise_sigma_mm: f64,
    /// Orientation noise σ per axis, deg.
    pub orientation_sigma_deg: Option<f64>,
    /// Thermal drift used.
    pub thermal: Option<ThermalDrift>,
    /// Session with instrument drift and its velocity in the instrument frame, mm/s.
    pub instrument_drift: Option<(usize, Vec3)>,
    /// Bad points: (session, row, error added in the instrument frame, mm).
    pub bad_points: Vec<(usize, usize, Vec3)>,
    /// Gravity sag used.
    pub gravity_sag: Option<GravitySag>,
    /// Periodic encoder error used.
    pub encoder_harmonic: Option<EncoderHarmonic>,
}

/// A generated data set.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerData {
    /// The options it came from.
    pub options: TrackerOptions,
    /// The truth.
    pub truth: Truth,
    /// The sessions.
    pub sessions: Vec<Session>,
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1 = rng.random::<f64>().max(1e-300);
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn random_direction(rng: &mut ChaCha8Rng) -> Vec3 {
    let v = [gauss(rng), gauss(rng), gauss(rng)];
    v_scale(v, 1.0 / v_norm(v))
}

/// Round to 1e-6 so the written reading is the value the measurement was computed from.
fn round6(v: f64) -> f64 {
    (v * 1e6).round() / 1e6
}

/// Random readings inside the limits (and the low-coverage span) whose tool point lies in the
/// reachable workspace (above `min_z_mm`, outside `min_radius_mm`).
fn random_q(arm: &Arm, low_coverage: Option<(usize, f64)>, rng: &mut ChaCha8Rng) -> Vec<f64> {
    for _ in 0..100_000 {
        let q: Vec<f64> = arm
            .limits_deg
            .iter()
            .enumerate()
            .map(|(j, &(lo, hi))| {
                let (lo, hi) = match low_coverage {
                    Some((joint, span)) if joint == j + 1 => {
                        let mid = 0.5 * (lo + hi);
                        (mid - 0.5 * span, mid + 0.5 * span)
                    }
                    _ => (lo, hi),
                };
                round6(lo + (hi - lo) * rng.random::<f64>())
            })
            .collect();
        let p = arm.tool_pose(&q).translation_mm;
        if p[2] > arm.min_z_mm && p[0].hypot(p[1]) > arm.min_radius_mm {
            return q;
        }
    }
    panic!("{}: no reading of 100 000 puts the tool above min_z_mm and outside min_radius_mm", arm.name)
}

/// A grid of `count` tool positions at one orientation, solved by IK on `arm`: the cells of a
/// cubic grid of side ⌈∛count⌉ + 1 nearest to a random reachable start's tool point, skipping
/// cells IK cannot reach inside the limits; a new start when too many are out of reach.
fn constant_orientation_q(arm: &Arm, count: usize, spacing_mm: f64, rng: &mut ChaCha8Rng) -> Vec<Vec<f64>> {
    let side = (count as f64).cbrt().ceil() as i64 + 1;
    let mut cells: Vec<Vec3> = (0..side * side * side)
        .map(|c| {
            [c / (side * side), (c / side) % side, c % side]
                .map(|v| (v as f64 - 0.5 * (side - 1) as f64) * spacing_mm)
        })
        .collect();
    cells.sort_by(|a, b| v_norm(*a).total_cmp(&v_norm(*b)));
    for _ in 0..200 {
        let start = random_q(arm, None, rng);
        let center = arm.tool_pose(&start);
        let mut out: Vec<Vec<f64>> = Vec::new();
        let mut missed = 0;
        for offset in &cells {
            if out.len() == count || missed > cells.len() - count {
                break;
            }
            let target = Pose { translation_mm: v_add(center.translation_mm, *offset), ..center };
            let solved = out
                .last()
                .and_then(|q_prev| inverse_kinematics(arm, &target, q_prev))
                .or_else(|| inverse_kinematics(arm, &target, &start));
            match solved {
                Some(q) => out.push(q),
                None => missed += 1,
            }
        }
        if out.len() == count {
            return out;
        }
    }
    panic!(
        "{}: no start of 200 reaches {count} cells of a grid spaced {spacing_mm} mm at one orientation; ask \
         for fewer poses or a smaller grid_spacing_mm",
        arm.name
    )
}

/// Generate a data set (deterministic in `options.seed`).
///
/// # Panics
/// When the options ask for the impossible: a workspace no reading reaches, or a
/// constant-orientation grid too large for the arm (the message says which).
pub fn generate(options: &TrackerOptions) -> TrackerData {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let (truth_arm, hidden_errors) = perturb(&options.arm, &options.hidden, rng.random::<u64>());
    // The instrument: 1.5–2.5 m from the robot, any heading, slightly tilted; each further
    // session moves it by 5–10° about a random axis and 0.3–1 m.
    let first = Pose {
        rotation: m_mul(
            &axis_angle([0.0, 0.0, 1.0], std::f64::consts::TAU * rng.random::<f64>()),
            &rotation_vector([0.02 * gauss(&mut rng), 0.02 * gauss(&mut rng), 0.0]),
        ),
        translation_mm: v_scale(random_direction(&mut rng), 1500.0 + 1000.0 * rng.random::<f64>()),
    };
    let bases: Vec<Pose> = (0..options.sessions.len())
        .map(|s| {
            if s == 0 {
                return first;
            }
            let turn = rotation_vector(v_scale(
                random_direction(&mut rng),
                (5.0 + 5.0 * rng.random::<f64>()).to_radians(),
            ));
            let shift = v_scale(random_direction(&mut rng), 300.0 + 700.0 * rng.random::<f64>());
            Pose {
                rotation: m_mul(&turn, &first.rotation),
                translation_mm: v_add(first.translation_mm, shift),
            }
        })
        .collect();
    // Each trait draws from its own stream, so switching one on leaves the rest of the data as it was.
    let stream = |k: u64| ChaCha8Rng::seed_from_u64(options.seed ^ k.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    let tool_remount =
        options.tool_remount.map(|r| (r.session, v_scale(random_direction(&mut stream(1)), r.size_mm)));
    let instrument_drift = options
        .instrument_drift
        .map(|d| (d.session, v_scale(random_direction(&mut stream(2)), d.mm_per_hour / 3600.0)));
    let mut orientation_rng = stream(3);
    let mut sessions = Vec::new();
    for (s, plan) in options.sessions.iter().enumerate() {
        let mut arm = truth_arm.clone();
        if let Some((session, offset)) = tool_remount {
            if session == s {
                arm.tool_mm = v_add(arm.tool_mm, offset);
            }
        }
        if let Some(turn) = options.probe_turn.filter(|t| t.session == s) {
            let rz = axis_angle([0.0, 0.0, 1.0], turn.angle_deg.to_radians());
            let rpy = arm.tool_rpy_deg.map(f64::to_radians);
            arm.tool_mm = m_vec(&rz, arm.tool_mm);
            arm.tool_rpy_deg = rpy_of(&m_mul(&rz, &rpy_matrix(rpy))).map(f64::to_degrees);
        }
        let qs: Vec<Vec<f64>> = if !plan.joints_deg.is_empty() {
            plan.joints_deg.clone()
        } else if plan.constant_orientation {
            constant_orientation_q(&arm, plan.poses, options.grid_spacing_mm, &mut rng)
                .into_iter()
                .map(|q| q.into_iter().map(round6).collect())
                .collect()
        } else {
            (0..plan.poses).map(|_| random_q(&options.arm, options.low_coverage, &mut rng)).collect()
        };
        let measurements = qs.len() * options.repeats.max(1);
        let duration_s = options.seconds_per_point * measurements as f64;
        let mut rows = Vec::new();
        for (pose, q) in qs.iter().enumerate() {
            for _ in 0..options.repeats.max(1) {
                let time_s = options.seconds_per_point * rows.len() as f64;
                let (scale, temp_c) = match options.thermal {
                    Some(t) => {
                        let delta_c = t.rise_at(s, time_s, duration_s);
                        (1.0 + t.expansion_per_c * delta_c, t.start_c + delta_c)
                    }
                    None => (1.0, 20.0),
                };
                let mut deflected = arm.sagged_q(q, options.gravity_sag.as_ref());
                if let Some(h) = &options.encoder_harmonic {
                    deflected = h.applied(&deflected);
                }
                let tool = arm.tool_pose(&deflected);
                let tool_in_base = Pose { translation_mm: v_scale(tool.translation_mm, scale), ..tool };
                let mut measured = bases[s].then(&tool_in_base);
                if let Some((_, velocity)) = instrument_drift.filter(|(session, _)| *session == s) {
                    measured.translation_mm = v_add(measured.translation_mm, v_scale(velocity, time_s));
                }
                let noise = [0; 3].map(|_| options.noise_sigma_mm * gauss(&mut rng));
                let quaternion = options.orientation_sigma_deg.map(|sigma_deg| {
                    let w = [0; 3].map(|_| sigma_deg.to_radians() * gauss(&mut orientation_rng));
                    quaternion_of(&m_mul(&rotation_vector(w), &measured.rotation))
                });
                rows.push(Row {
                    pose,
                    q_deg: q.clone(),
                    x_mm: v_add(measured.translation_mm, noise),
                    exact_mm: measured.translation_mm,
                    quaternion,
                    exact_rotation: measured.rotation,
                    time_s,
                    temp_c,
                    tool_in_base,
                });
            }
        }
        sessions.push(Session { plan: plan.clone(), rows });
    }
    let mut bad_points = Vec::new();
    if let Some(bad) = options.bad_points {
        let mut bad_rng = stream(4);
        let all: Vec<(usize, usize)> = sessions
            .iter()
            .enumerate()
            .flat_map(|(s, session)| (0..session.rows.len()).map(move |k| (s, k)))
            .collect();
        while bad_points.len() < bad.count.min(all.len()) {
            let (s, k) = all[(bad_rng.random::<f64>() * all.len() as f64) as usize % all.len()];
            if bad_points.iter().any(|&(bs, bk, _)| (bs, bk) == (s, k)) {
                continue;
            }
            let error = v_scale(random_direction(&mut bad_rng), bad.size_mm);
            sessions[s].rows[k].x_mm = v_add(sessions[s].rows[k].x_mm, error);
            bad_points.push((s, k, error));
        }
    }
    TrackerData {
        options: options.clone(),
        truth: Truth {
            nominal: options.arm.clone(),
            truth: truth_arm,
            hidden_errors,
            bases,
            tool_remount,
            noise_sigma_mm: options.noise_sigma_mm,
            orientation_sigma_deg: options.orientation_sigma_deg,
            thermal: options.thermal,
            instrument_drift,
            bad_points,
            gravity_sag: options.gravity_sag.clone(),
            encoder_harmonic: options.encoder_harmonic,
        },
        sessions,
    }
}

impl TrackerData {
    /// The CSV text of session `s`: the tag line, the header, one row per measurement.
    pub fn csv(&self, s: usize) -> String {
        let o = &self.options;
        let session = &self.sessions[s];
        let n = o.arm.joints();
        let mut out = format!("# {}\n", o.tag);
        let mut header: Vec<String> = vec!["pose".into()];
        header.extend((1..=n).map(|j| format!("q{j}_deg")));
        header.extend(["x_mm", "y_mm", "z_mm"].map(String::from));
        if o.orientation_sigma_deg.is_some() {
            header.extend(["qw", "qx", "qy", "qz"].map(String::from));
        }
        match o.uncertainty {
            UncertaintyColumn::None => {}
            UncertaintyColumn::SigmaMm => header.push("sigma_mm".into()),
            UncertaintyColumn::U95Mm => header.push("u95_mm".into()),
        }
        if o.thermal.is_some() || o.time_columns {
            header.extend(["time_s", "temp_C"].map(String::from));
        }
        let _ = writeln!(out, "{}", header.join(","));
        let length = |mm: f64| match o.export_mistake {
            ExportMistake::MetresUnderMm => format!("{:.9}", mm / 1000.0),
            _ => format!("{mm:.6}"),
        };
        for row in &session.rows {
            let mut fields: Vec<String> = vec![(row.pose + 1).to_string()];
            fields.extend(row.q_deg.iter().map(|v| match o.export_mistake {
                ExportMistake::RadiansUnderDeg => format!("{:.9}", v.to_radians()),
                _ => format!("{v:.6}"),
            }));
            fields.extend(row.x_mm.iter().map(|v| length(*v)));
            if let Some([w, x, y, z]) = row.quaternion {
                let written = match o.export_mistake {
                    ExportMistake::ScalarLastQuaternion => [x, y, z, w],
                    _ => [w, x, y, z],
                };
                fields.extend(written.iter().map(|v| format!("{v:.9}")));
            }
            match o.uncertainty {
                UncertaintyColumn::None => {}
                UncertaintyColumn::SigmaMm => fields.push(length(o.noise_sigma_mm)),
                UncertaintyColumn::U95Mm => fields.push(length(2.0 * o.noise_sigma_mm)),
            }
            if o.thermal.is_some() || o.time_columns {
                fields.push(format!("{:.3}", row.time_s));
                fields.push(format!("{:.4}", row.temp_c));
            }
            let _ = writeln!(out, "{}", fields.join(","));
        }
        out
    }

    /// Write every session as `DIR/NAME.csv` (the folder is created); returns the paths.
    pub fn write(&self, dir: &Path) -> std::io::Result<Vec<PathBuf>> {
        std::fs::create_dir_all(dir)?;
        (0..self.sessions.len())
            .map(|s| {
                let path = dir.join(format!("{}.csv", self.sessions[s].plan.name));
                std::fs::write(&path, self.csv(s))?;
                Ok(path)
            })
            .collect()
    }

    /// The noise floor of held-out sessions: the 3-D residuals the TRUE model (every trait that
    /// is switched on included, noise excluded) leaves on the measured points of each listed
    /// session after its base is refitted (Horn), pooled. Bad points stay in: no model explains
    /// them. The figure for "held-out RMS ≤ 1.10 × floor" tests; about σ·√3 for positions.
    pub fn true_floor_mm(&self, sessions: &[usize]) -> Floor {
        let mut distances = Vec::new();
        for &s in sessions {
            let rows = &self.sessions[s].rows;
            let p: Vec<Vec3> = rows.iter().map(|r| r.tool_in_base.translation_mm).collect();
            let drift = |r: &Row| match self.truth.instrument_drift {
                Some((session, velocity)) if session == s => v_scale(velocity, r.time_s),
                _ => [0.0; 3],
            };
            let x: Vec<Vec3> = rows.iter().map(|r| v_sub(r.x_mm, drift(r))).collect();
            let base = fit_rigid(&p, &x);
            distances.extend(p.iter().zip(&x).map(|(p, x)| v_norm(v_sub(*x, base.apply(*p)))));
        }
        Floor::of(&distances)
    }
}
