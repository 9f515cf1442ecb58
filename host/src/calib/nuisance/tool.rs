//! The tool point and the probe on the flange.
//!
//! **A re-mounted tool.** A probe or reflector taken off and put back sits a little elsewhere on
//! the flange: in that group (placement or session) the tool point is t + Δ, Δ in the flange
//! frame (mm), an unknown of the group (`--float-tool`). With the orientation varying inside the
//! group, Δ cannot be absorbed by the group's frame; a calibration that shares t bends the arm
//! parameters to spread it.
//!
//! **The 6-DoF probe's rotation.** A probe that reports its orientation adds R_t, the probe on
//! the flange (flange ← probe), shared by every session: R_meas = R_s·R_F(q)·R_t. It is an
//! unknown of three values, a small rotation ω_t (mrad) right of its start R⁰_t (the chordal
//! mean of R_Fᵀ·R_sᵀ·R_meas over the oriented observations).

use crate::calib::nuisance::frame::Frame;
use crate::data::Observations;
use crate::model::kinematics::{Tips, ToolPose};
use crate::model::ArmModel;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// Unknowns of a floated tool: its offset in the flange frame (mm).
pub const TOOL_UNKNOWNS: usize = 3;

/// The flange's rotation (its x, y, z axes as columns) from a tool pose.
pub fn flange_rotation(pose: &ToolPose) -> Matrix3<f64> {
    let (x, z) = (&pose.x_axis, &pose.z_axis);
    Matrix3::from_columns(&[*x, z.cross(x), *z])
}

/// The tool point of `pose` with the offset `offset_mm` (flange frame), mm.
pub fn with_offset(pose: &ToolPose, offset_mm: &Vector3<f64>) -> Vector3<f64> {
    pose.position_mm + flange_rotation(pose) * offset_mm
}

/// The tool point in the robot frame of each observation `members` of `data` (on its tip's
/// chain), with an offset (flange frame), mm.
pub fn model_points(
    model: &ArmModel,
    data: &Observations,
    members: impl IntoIterator<Item = usize>,
    offset_mm: &Vector3<f64>,
) -> Vec<Vector3<f64>> {
    PoseSource::Posed(Tips::new(model), data).map(members.into_iter(), |_, pose| with_offset(pose, offset_mm))
}

/// The tool pose of every observation of `data` on a model, taken once for the several figures a
/// run reads from them (the calibration residuals, the outlier rows, the data-error scoring).
pub struct ModelPoses<'a> {
    model: &'a ArmModel,
    data: &'a Observations,
    poses: Vec<ToolPose>,
}

impl<'a> ModelPoses<'a> {
    /// Every observation of `data` on `model` (on its tip's chain).
    pub fn of(model: &'a ArmModel, data: &'a Observations) -> ModelPoses<'a> {
        let poses = data.encoders().poses_on(&Tips::new(model), &data.obs, 0..data.obs.len());
        ModelPoses { model, data, poses }
    }

    /// The poses, when they are those of `model` on `data` (the very values, not equal copies).
    fn of_model(&self, model: &ArmModel, data: &Observations) -> Option<&[ToolPose]> {
        (std::ptr::eq(self.model, model) && std::ptr::eq(self.data, data)).then_some(self.poses.as_slice())
    }
}

/// The tool pose of any observation of one data set on one model: read from poses taken once
/// ([`ModelPoses`]) when they are of that very model and data, else posed.
pub enum PoseSource<'a> {
    /// The poses of every observation, taken once.
    Taken(&'a [ToolPose]),
    /// The model's chains and the data, posed on demand.
    Posed(Tips<'a>, &'a Observations),
}

impl<'a> PoseSource<'a> {
    /// The poses of `model` on `data`: from `taken` when it holds that very model's on that very
    /// data, else posed.
    pub fn new(model: &'a ArmModel, data: &'a Observations, taken: Option<&'a ModelPoses>) -> PoseSource<'a> {
        match taken.and_then(|t| t.of_model(model, data)) {
            Some(poses) => PoseSource::Taken(poses),
            None => PoseSource::Posed(Tips::new(model), data),
        }
    }

    /// `f` of each observation `k` of `members` and its tool pose, in order (the source decided
    /// once, outside the loop; posed two at a time, [`crate::data::Encoders::for_each_pose`]).
    pub fn map<T>(
        &self,
        members: impl Iterator<Item = usize>,
        mut f: impl FnMut(usize, &ToolPose) -> T,
    ) -> Vec<T> {
        match self {
            PoseSource::Taken(poses) => members.map(|k| f(k, &poses[k])).collect(),
            PoseSource::Posed(tips, data) => {
                let mut out = Vec::with_capacity(members.size_hint().0);
                data.encoders().for_each_pose(tips, &data.obs, members, |k, pose| out.push(f(k, pose)));
                out
            }
        }
    }
}

/// The tool position of every observation of `data` (the model's own tool), mm.
pub fn positions(model: &ArmModel, data: &Observations) -> Vec<Vector3<f64>> {
    model_points(model, data, 0..data.obs.len(), &Vector3::zeros())
}

/// The probe rotation at its unknowns `x` (mrad) right of its start.
pub fn probe_rotation_at(start: &Matrix3<f64>, x: &[f64]) -> Matrix3<f64> {
    start * Rotation3::new(Vector3::new(x[0], x[1], x[2]) * 1e-3).into_inner()
}

/// A floated offset's component with a larger standard deviation than this, mm, is not determined
/// by the data (a re-mount is measured to better than a millimetre or not at all): distances
/// between touches of one placement hardly see the tool moved along its own axis, for example.
pub const FLOATED_DETERMINED_MM: f64 = 1.0;

/// A group's own tool offset (the tool floated there).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FloatedTool {
    /// The group (placement or session).
    pub session: String,
    /// Offset of the tool point from the shared one, flange frame, mm.
    pub offset_mm: [f64; 3],
    /// Standard deviation of the offset's length, mm.
    pub size_std_mm: f64,
    /// Standard deviation of each component, flange frame, mm.
    #[serde(default)]
    pub std_mm: [f64; 3],
}

impl FloatedTool {
    /// The offset `offset` of group `session` with its covariance `cov` (flange frame, mm²).
    pub fn new(session: String, offset: &Vector3<f64>, cov: &Matrix3<f64>) -> FloatedTool {
        FloatedTool {
            session,
            offset_mm: (*offset).into(),
            size_std_mm: length_std(offset, cov),
            std_mm: [0, 1, 2].map(|k| cov[(k, k)].max(0.0).sqrt()),
        }
    }

    /// Whether component `k` is determined by the data (σ within [`FLOATED_DETERMINED_MM`]).
    pub fn determined(&self, k: usize) -> bool {
        self.std_mm[k] <= FLOATED_DETERMINED_MM
    }
}

/// The 6-DoF probe's orientation R_t on the flange (flange ← probe), shared by all sessions.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ToolRotation {
    /// R_t as a rotation vector (axis · angle), degrees.
    pub rotation_vector_deg: [f64; 3],
    /// One standard deviation of a small rotation of R_t about each of the probe's own axes,
    /// degrees (`None` when the normal matrix is singular).
    pub std_deg: Option<[f64; 3]>,
}

impl ToolRotation {
    /// R_t as a matrix.
    pub fn rotation(&self) -> Matrix3<f64> {
        Rotation3::new(Vector3::from(self.rotation_vector_deg.map(f64::to_radians))).into_inner()
    }
}

/// Standard deviation of |v| from the covariance block `c` of v.
pub fn length_std(v: &Vector3<f64>, c: &Matrix3<f64>) -> f64 {
    let n = v.norm();
    if n == 0.0 {
        return (c.trace() / 3.0).max(0.0).sqrt();
    }
    let u = v / n;
    (u.transpose() * c * u)[(0, 0)].max(0.0).sqrt()
}

/// The start of R_t: the chordal mean of R_Fᵀ·R_sᵀ·R_meas over the oriented observations (frames
/// `frames` per block, from the positions); `None` without orientations.
pub fn start_probe_rotation(model: &ArmModel, data: &Observations, frames: &[Frame]) -> Option<Matrix3<f64>> {
    let mut sum = Matrix3::zeros();
    let mut any = false;
    let tips = Tips::new(model);
    for (k, o) in data.obs.iter().enumerate() {
        let Some(measured) = o.orientation() else { continue };
        let pose = data.pose_on(&tips, k);
        sum += flange_rotation(&pose).transpose()
            * frames[o.block].rotation.transpose()
            * measured.to_rotation_matrix().into_inner();
        any = true;
    }
    if !any {
        return None;
    }
    let svd = sum.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * v_t).determinant().signum();
    Some(u * d * v_t)
}

/// Spread of the tool orientation within a session, degrees, below which the session is said
/// to hold the orientation constant.
pub const CONSTANT_ORIENTATION_DEG: f64 = 1.0;

/// Largest angle, degrees, between the tool orientation at any observation of block `b` and at
/// its first (the model's flange orientation).
pub fn orientation_spread_deg(model: &ArmModel, data: &Observations, b: usize) -> f64 {
    orientation_spread_with(model, data, b, None)
}

/// [`orientation_spread_deg`], the poses read from `taken` when they are of `model` on `data`.
pub fn orientation_spread_with(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    taken: Option<&ModelPoses>,
) -> f64 {
    let poses = PoseSource::new(model, data, taken);
    spread_deg(poses.map(data.blocks[b].members.iter().copied(), |_, pose| flange_rotation(pose)).into_iter())
}

/// Largest angle, degrees, between any of `rotations` and the first.
fn spread_deg(rotations: impl Iterator<Item = Matrix3<f64>>) -> f64 {
    let rotations: Vec<Matrix3<f64>> = rotations.collect();
    let Some(first) = rotations.first() else { return 0.0 };
    rotations
        .iter()
        .map(|r| {
            let c = (((first.transpose() * r).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
            c.acos().to_degrees()
        })
        .fold(0.0, f64::max)
}
