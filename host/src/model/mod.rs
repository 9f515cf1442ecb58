//! The arm model: nominal geometry, the parameters a calibration may move, and the model file.
//!
//! Every scalar the kinematics reads is a parameter named `KIND:JOINT` (joints 1-based) or `KIND`
//! for whole-arm terms (`tcp.x`, `scale`). Angles are stored in degrees, lengths in millimetres,
//! the scale in parts per million. A parameter is *free* when the model file gives it bounds.

pub mod effects;
pub mod file;
pub mod kinematics;
pub mod params;
pub mod plausible;
pub mod tree;
pub mod urdf;

pub use params::ParamId;
pub use tree::{Body, Tip, Tree, MAX_BODIES};

use nalgebra::{Rotation3, Vector3};

/// Number of joints of the SUTA arm: the encoders the controller reads, the rows its flash holds
/// and the angles an artefact session (`suta-session/1`) records.
pub const SUTA_JOINTS: usize = 6;
/// Most revolute joints a host model's chain may have (a tree's path from the base to one tip).
pub const MAX_JOINTS: usize = 12;
/// Most revolute joints a tree model may have (several chains sharing joints, see [`Tree`]).
pub const MAX_TREE_JOINTS: usize = 24;

/// Which joint convention the joint rows follow (two Denavit–Hartenberg forms, or URDF).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Convention {
    /// Classic DH: link matrix Rz(θ)·Tz(d)·Tx(a)·Rx(α) (thesis eq. 2.1).
    Classic,
    /// Modified (Craig) DH: Rx(α)·Tx(a)·Rz(θ)·Tz(d), row i holding α_{i−1}, a_{i−1}.
    Modified,
    /// URDF joint: origin Tx·Ty·Tz·Rz(yaw)·Ry(pitch)·Rx(roll)·exp(ω), then a rotation by θ about
    /// the joint's unit `axis` (the row's d, a, α and β stay zero). roll, pitch, yaw are the
    /// nominal orientation; the calibration moves the small rotation ω (see [`Joint::origin_turn_deg`]).
    Urdf,
}

/// Geometry of one joint row. θ = encoder + `offset_deg` (+ joint-angle effects).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Joint {
    /// Encoder zero offset δθ, degrees.
    pub offset_deg: f64,
    /// Link offset along z, millimetres.
    pub d_mm: f64,
    /// Link length along x, millimetres.
    pub a_mm: f64,
    /// Link twist about x, degrees.
    pub alpha_deg: f64,
    /// Hayati misalignment about y (for near-parallel consecutive axes), degrees.
    #[serde(default)]
    pub axis_deg: f64,
    /// Eccentricity, first harmonic, sine part (see [`crate::model::effects::eccentricity`]), degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub eccentricity_sin_deg: f64,
    /// Eccentricity, first harmonic, cosine part, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub eccentricity_cos_deg: f64,
    /// Eccentricity, second harmonic, sine part, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub eccentricity2_sin_deg: f64,
    /// Eccentricity, second harmonic, cosine part, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub eccentricity2_cos_deg: f64,
    /// Third-harmonic encoder error, sine part (see [`crate::model::effects::harmonic`]), degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub harmonic3_sin_deg: f64,
    /// Third-harmonic encoder error, cosine part, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub harmonic3_cos_deg: f64,
    /// Fourth-harmonic encoder error, sine part, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub harmonic4_sin_deg: f64,
    /// Fourth-harmonic encoder error, cosine part, degrees.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub harmonic4_cos_deg: f64,
    /// Gravity compliance (see [`crate::model::effects::compliance`]), degrees per metre of lever.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub compliance_deg_per_m: f64,
    /// Joint compliance under the gravity torque of the masses beyond the joint (see
    /// [`crate::model::effects::sag`]), degrees per kN·m.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub sag_deg_per_knm: f64,
    /// Lateral compliance under the gravity moment perpendicular to the axis (see
    /// [`crate::model::effects::bend`]), degrees per kN·m.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub bend_deg_per_knm: f64,
    /// URDF joint origin translation from the previous joint's frame, millimetres.
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub origin_xyz_mm: [f64; 3],
    /// URDF joint origin fixed-axis roll, pitch, yaw (R = Rz(yaw)·Ry(pitch)·Rx(roll)), degrees:
    /// the nominal orientation, which the calibration never moves.
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub origin_rpy_deg: [f64; 3],
    /// URDF joint origin's calibrated turn: the rotation vector ω (degrees) of a rotation about
    /// the nominal origin frame's own axes, applied after roll-pitch-yaw (R = R(rpy)·exp(ω)).
    /// Roll-pitch-yaw values are gimbal-locked at pitch ±90° (UR's shoulder and wrist): roll and
    /// yaw then turn about one axis and one direction is lost. A small ω about the nominal frame
    /// moves every direction equally at any nominal, so these are the free parameters
    /// (`origin_rx:j`, `origin_ry:j`, `origin_rz:j`); `kincal model to-urdf` folds ω back into rpy.
    #[serde(default, skip_serializing_if = "is_zero3")]
    pub origin_turn_deg: [f64; 3],
    /// URDF joint axis (unit vector in the joint frame); DH rows rotate about z.
    #[serde(default = "z_axis", skip_serializing_if = "is_z_axis")]
    pub axis: [f64; 3],
}

fn is_zero3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| *x == 0.0)
}

fn z_axis() -> [f64; 3] {
    [0.0, 0.0, 1.0]
}

fn is_z_axis(v: &[f64; 3]) -> bool {
    *v == z_axis()
}

impl Default for Joint {
    fn default() -> Joint {
        Joint {
            offset_deg: 0.0,
            d_mm: 0.0,
            a_mm: 0.0,
            alpha_deg: 0.0,
            axis_deg: 0.0,
            eccentricity_sin_deg: 0.0,
            eccentricity_cos_deg: 0.0,
            eccentricity2_sin_deg: 0.0,
            eccentricity2_cos_deg: 0.0,
            harmonic3_sin_deg: 0.0,
            harmonic3_cos_deg: 0.0,
            harmonic4_sin_deg: 0.0,
            harmonic4_cos_deg: 0.0,
            compliance_deg_per_m: 0.0,
            sag_deg_per_knm: 0.0,
            bend_deg_per_knm: 0.0,
            origin_xyz_mm: [0.0; 3],
            origin_rpy_deg: [0.0; 3],
            origin_turn_deg: [0.0; 3],
            axis: z_axis(),
        }
    }
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Joint {
    /// The URDF origin's rotation R(rpy)·exp(ω): the nominal roll-pitch-yaw turned by the
    /// calibrated rotation vector [`Joint::origin_turn_deg`].
    pub fn origin_rotation(&self) -> Rotation3<f64> {
        let [roll, pitch, yaw] = self.origin_rpy_deg.map(f64::to_radians);
        Rotation3::from_euler_angles(roll, pitch, yaw)
            * Rotation3::new(Vector3::from(self.origin_turn_deg.map(f64::to_radians)))
    }

    /// The field a per-joint parameter lives in (whole-arm parameters map to `offset_deg`,
    /// never asked for by [`ArmModel`]).
    fn slot(&mut self, id: ParamId) -> &mut f64 {
        match id {
            ParamId::Length(_) => &mut self.d_mm,
            ParamId::LinkOffset(_) => &mut self.a_mm,
            ParamId::Twist(_) => &mut self.alpha_deg,
            ParamId::Axis(_) => &mut self.axis_deg,
            ParamId::EccSin(_) => &mut self.eccentricity_sin_deg,
            ParamId::EccCos(_) => &mut self.eccentricity_cos_deg,
            ParamId::Ecc2Sin(_) => &mut self.eccentricity2_sin_deg,
            ParamId::Ecc2Cos(_) => &mut self.eccentricity2_cos_deg,
            ParamId::Compliance(_) => &mut self.compliance_deg_per_m,
            ParamId::Sag(_) => &mut self.sag_deg_per_knm,
            ParamId::Bend(_) => &mut self.bend_deg_per_knm,
            ParamId::Harm3Sin(_) => &mut self.harmonic3_sin_deg,
            ParamId::Harm3Cos(_) => &mut self.harmonic3_cos_deg,
            ParamId::Harm4Sin(_) => &mut self.harmonic4_sin_deg,
            ParamId::Harm4Cos(_) => &mut self.harmonic4_cos_deg,
            ParamId::OriginXyz(_, k) => &mut self.origin_xyz_mm[k],
            ParamId::OriginTurn(_, k) => &mut self.origin_turn_deg[k],
            ParamId::Offset(_)
            | ParamId::Tcp(_)
            | ParamId::TipTcp(..)
            | ParamId::Scale
            | ParamId::Mass(_) => &mut self.offset_deg,
        }
    }
}

/// A parameter the solver may move, with its bounds in the parameter's own unit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FreeParam {
    /// Which parameter.
    pub id: ParamId,
    /// Lower bound (deg, mm or ppm).
    pub lower: f64,
    /// Upper bound (deg, mm or ppm).
    pub upper: f64,
}

/// A kinematic arm model: geometry plus the set of free parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct ArmModel {
    /// Free text naming the arm.
    pub name: String,
    /// DH convention of the joint rows.
    pub convention: Convention,
    /// Joint rows, base to tip (1 to [`MAX_JOINTS`]); in a tree, in topological order (a joint
    /// after its parent; 1 to [`MAX_TREE_JOINTS`]).
    pub joints: Vec<Joint>,
    /// Tool centre point in the last frame, millimetres (in a tree, the first tip's point).
    pub tcp_mm: [f64; 3],
    /// Length scale error, parts per million (thermal expansion, artefact scale).
    pub scale_ppm: f64,
    /// Parameters the calibration may move, in file order.
    pub free: Vec<FreeParam>,
    /// The URDF chain the model was made from (`kincal model from-urdf`), if any: `to-urdf`
    /// writes the model into that chain only.
    pub urdf: Option<urdf::UrdfSource>,
    /// The arm this model is of (calibrated from its sessions); `None` for a nominal, simulated
    /// or hand-written model.
    pub arm: Option<crate::trace::ArmIdentity>,
    /// The joints' parents and the named tips of a branched robot, and the masses gravity pulls
    /// on (empty for a single chain without a mass table).
    pub tree: Tree,
}

impl ArmModel {
    /// The value of one parameter, in its unit.
    pub fn get(&self, id: ParamId) -> f64 {
        match id {
            ParamId::Tcp(k) => self.tcp_mm[k],
            ParamId::TipTcp(t, k) => self.tree.tips.get(t).map_or(0.0, |tip| tip.tcp_mm[k]),
            ParamId::Scale => self.scale_ppm,
            ParamId::Mass(b) => self.tree.bodies.get(b).map_or(0.0, |body| body.mass_kg),
            _ => match self.joints.get(id.joint().unwrap_or(0)) {
                Some(joint) => *joint.clone().slot(id),
                None => 0.0,
            },
        }
    }

    /// Set one parameter, in its unit (a joint the model does not have holds nothing).
    pub fn set(&mut self, id: ParamId, value: f64) {
        if let Some(slot) = self.slot(id) {
            *slot = value;
        }
    }

    fn slot(&mut self, id: ParamId) -> Option<&mut f64> {
        match id {
            ParamId::Tcp(k) => Some(&mut self.tcp_mm[k]),
            ParamId::TipTcp(t, k) => {
                self.tree.tips.get_mut(t).filter(|_| t > 0).map(|tip| &mut tip.tcp_mm[k])
            }
            ParamId::Scale => Some(&mut self.scale_ppm),
            ParamId::Mass(b) => self.tree.bodies.get_mut(b).map(|body| &mut body.mass_kg),
            _ => self.joints.get_mut(id.joint().unwrap_or(0)).map(|j| j.slot(id)),
        }
    }

    /// Number of revolute joints.
    pub fn joint_count(&self) -> usize {
        self.joints.len()
    }

    /// Every parameter this model holds, in a stable order (DH rows hold no URDF origin, URDF
    /// joints no d, a, α, β).
    pub fn params(&self) -> Vec<ParamId> {
        ParamId::all()
            .into_iter()
            .filter(|id| id.joint().is_none_or(|j| j < self.joints.len()))
            .filter(|id| id.is_urdf_geometry() == (self.convention == Convention::Urdf) || !id.is_geometry())
            .filter(|id| match id {
                ParamId::TipTcp(t, _) => *t < self.tree.tips.len(),
                ParamId::Sag(_) | ParamId::Bend(_) => !self.tree.bodies.is_empty(),
                ParamId::Mass(b) => *b < self.tree.bodies.len(),
                _ => true,
            })
            .collect()
    }

    /// Values of the free parameters, in `free` order.
    pub fn free_values(&self) -> Vec<f64> {
        self.free.iter().map(|f| self.get(f.id)).collect()
    }

    /// Copy of the model with the free parameters set to `values` (in `free` order).
    pub fn with_free_values(&self, values: &[f64]) -> ArmModel {
        let mut out = self.clone();
        for (f, &v) in self.free.iter().zip(values) {
            out.set(f.id, v);
        }
        out
    }

    /// Make `id` free with bounds, or update its bounds if it is free already.
    pub fn free_param(&mut self, id: ParamId, lower: f64, upper: f64) {
        match self.free.iter_mut().find(|f| f.id == id) {
            Some(f) => {
                f.lower = lower;
                f.upper = upper;
            }
            None => self.free.push(FreeParam { id, lower, upper }),
        }
    }

    /// Free every DH value of every joint (offset, d, a, α) within ± `angle_deg` / ± `length_mm`
    /// of its current value; the identifiability step keeps what the data can move.
    pub fn free_every_dh_value(&mut self, angle_deg: f64, length_mm: f64) {
        for j in 0..self.joints.len() {
            let row = self.joints[j];
            self.free_param(ParamId::Offset(j), row.offset_deg - angle_deg, row.offset_deg + angle_deg);
            self.free_param(ParamId::Length(j), row.d_mm - length_mm, row.d_mm + length_mm);
            self.free_param(ParamId::LinkOffset(j), row.a_mm - length_mm, row.a_mm + length_mm);
            self.free_param(ParamId::Twist(j), row.alpha_deg - angle_deg, row.alpha_deg + angle_deg);
        }
    }

    /// The parameter's name in this model: a body's mass by the body's name (`mass:payload`),
    /// every other parameter as [`ParamId`] writes it.
    pub fn param_name(&self, id: ParamId) -> String {
        match id {
            ParamId::Mass(b) => match self.tree.bodies.get(b) {
                Some(body) => format!("mass:{}", body.name),
                None => id.to_string(),
            },
            _ => id.to_string(),
        }
    }

    /// The parameter named `name` in this model ([`ArmModel::param_name`]'s names, and every
    /// name [`ParamId::parse`] reads).
    pub fn parse_param(&self, name: &str) -> Option<ParamId> {
        match name.strip_prefix("mass:").and_then(|body| self.tree.body_index(body)) {
            Some(b) => Some(ParamId::Mass(b)),
            None => ParamId::parse(name),
        }
    }

    /// Remove `id` from the free set (it keeps its current value).
    pub fn fix_param(&mut self, id: ParamId) {
        self.free.retain(|f| f.id != id);
    }

    /// The thesis Table 3.2 nominal SUTA model with its 13 calibrated parameters free
    /// (six encoder offsets ±10°, six lengths d ±10 mm, TCP length ±10 mm): the file
    /// `examples/suta/model.toml`, built into kincal ([`file::SUTA_MODEL_TOML`]), so every
    /// command that defaults to it works from any folder.
    pub fn suta_nominal() -> ArmModel {
        file::suta_model()
    }
}
