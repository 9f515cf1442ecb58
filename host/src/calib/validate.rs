//! Validation: what a model leaves on held-out observations, each block's own unknowns refitted.
//!
//! * Artefact touches: pairwise distance errors (frame-free), per landmark, per placement, and
//!   repeatability per landmark (ISO 9283 style).
//! * Instrument points: each held-out session's frame refitted in closed form (Horn), the point
//!   errors and the frame-free pairwise-distance errors; with the session's own tool offset
//!   refitted too when its tool floats; orientation errors of a 6-DoF probe.

use crate::calib::error_stats::{AngleStats, ErrorStats};
use crate::calib::fit::Fit;
use crate::calib::layout::Layout;
use crate::calib::nuisance::frame::{rotation_vector, Frame};
use crate::calib::nuisance::tool::{
    flange_rotation, model_points, positions, with_offset, FloatedTool, ModelPoses, PoseSource,
};
use crate::calib::problem::Problem;
use crate::data::{Observation, Observations};
use crate::model::kinematics::Chain;
use crate::model::ArmModel;
use crate::numerics::solver::{self, Loss, Residuals, SolverOptions};
use nalgebra::{Matrix3, Vector3};

/// Error of one measured distance.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PairError {
    /// Placement index in the dataset.
    pub placement: usize,
    /// Landmark indices (artefact order).
    pub landmarks: (usize, usize),
    /// Touch indices in the dataset.
    pub touches: (usize, usize),
    /// Measured minus certified distance, mm.
    pub error_mm: f64,
}

/// Repeatability of one landmark: spread of repeated touches about their barycentre.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Repeatability {
    /// Landmark id.
    pub landmark: String,
    /// Touches that had a repeat partner.
    pub touches: usize,
    /// RMS distance of touches from their placement's barycentre, mm.
    pub rms_mm: f64,
    /// ISO 9283 positional repeatability RP = mean(l) + 3·std(l), mm.
    pub rp_mm: f64,
}

/// Named group statistics.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct GroupStats {
    /// Landmark id or placement name.
    pub name: String,
    /// Errors of the distances involving this group.
    pub stats: ErrorStats,
}

/// All validation figures of one model on one dataset.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Validation {
    /// Over all pairs.
    pub overall: ErrorStats,
    /// Per landmark (pairs involving it).
    pub per_landmark: Vec<GroupStats>,
    /// Per placement.
    pub per_placement: Vec<GroupStats>,
    /// Repeatability per landmark.
    pub repeatability: Vec<Repeatability>,
    /// Every pair error.
    #[serde(skip)]
    pub errors: Vec<PairError>,
}

/// Distance errors of `model` on `data`.
pub fn distance_errors(model: &ArmModel, data: &Observations) -> Vec<PairError> {
    let pairs = data.landmark_pairs();
    if pairs.is_empty() {
        // No touch of a landmark (instrument sessions alone): no pose to compute.
        return Vec::new();
    }
    let p = positions(model, data);
    pairs
        .into_iter()
        .map(|(a, b)| {
            let (ta, tb) = (&data.obs[a], &data.obs[b]);
            let (la, lb) = (ta.landmark().unwrap_or(0), tb.landmark().unwrap_or(0));
            PairError {
                placement: ta.group,
                landmarks: (la, lb),
                touches: (a, b),
                error_mm: (p[a] - p[b]).norm() - data.landmark_distance_mm(la, lb),
            }
        })
        .collect()
}

/// Each touch's residual after a rigid fit of the artefact to the touched positions of its
/// placement (all its repeats together; placements with at least `min_touches` touches): the
/// tool point less the fitted landmark, in the arm's base frame, mm.
pub fn placement_residuals(
    model: &ArmModel,
    data: &Observations,
    min_touches: usize,
) -> Vec<Option<Vector3<f64>>> {
    let p = positions(model, data);
    let mut out = vec![None; data.obs.len()];
    for placement in 0..data.groups.len() {
        let idx: Vec<usize> = (0..data.obs.len())
            .filter(|&k| data.obs[k].group == placement && data.obs[k].landmark().is_some())
            .collect();
        if idx.len() < min_touches {
            continue;
        }
        let q: Vec<Vector3<f64>> =
            idx.iter().map(|&k| Vector3::from(data.landmarks[data.obs[k].touched()].xyz_mm)).collect();
        let pm: Vec<Vector3<f64>> = idx.iter().map(|&k| p[k]).collect();
        for (&k, r) in idx.iter().zip(Frame::residuals(&q, &pm)) {
            out[k] = Some(r);
        }
    }
    out
}

/// Validate `model` on `data`.
pub fn validate(model: &ArmModel, data: &Observations) -> Validation {
    let errors = distance_errors(model, data);
    let all: Vec<f64> = errors.iter().map(|e| e.error_mm).collect();
    let per_landmark = data
        .landmarks
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let e: Vec<f64> = errors
                .iter()
                .filter(|e| e.landmarks.0 == i || e.landmarks.1 == i)
                .map(|e| e.error_mm)
                .collect();
            GroupStats { name: l.id.clone(), stats: ErrorStats::of(&e) }
        })
        .filter(|g| g.stats.count > 0)
        .collect();
    let per_placement = data
        .groups
        .iter()
        .enumerate()
        .map(|(p, group)| {
            let e: Vec<f64> = errors.iter().filter(|e| e.placement == p).map(|e| e.error_mm).collect();
            GroupStats { name: group.name.clone(), stats: ErrorStats::of(&e) }
        })
        .collect();
    Validation {
        overall: ErrorStats::of(&all),
        per_landmark,
        per_placement,
        repeatability: repeatability(model, data),
        errors,
    }
}

/// Repeatability per landmark from touches repeated within one placement.
pub fn repeatability(model: &ArmModel, data: &Observations) -> Vec<Repeatability> {
    let p = positions(model, data);
    // Touches grouped by (landmark, placement) once: linear in the number of touches.
    let mut groups: std::collections::BTreeMap<(usize, usize), Vec<usize>> = Default::default();
    for (k, t) in data.obs.iter().enumerate() {
        if let Some(l) = t.landmark() {
            groups.entry((l, t.group)).or_default().push(k);
        }
    }
    let mut out = Vec::new();
    for (i, l) in data.landmarks.iter().enumerate() {
        let mut spreads = Vec::new();
        for (_, idx) in groups.range((i, 0)..(i + 1, 0)) {
            if idx.len() < 2 {
                continue;
            }
            let bary = idx.iter().map(|&k| p[k]).sum::<Vector3<f64>>() / idx.len() as f64;
            spreads.extend(idx.iter().map(|&k| (p[k] - bary).norm()));
        }
        if spreads.is_empty() {
            continue;
        }
        let n = spreads.len() as f64;
        let mean = spreads.iter().sum::<f64>() / n;
        let std = (spreads.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        let rms = (spreads.iter().map(|s| s * s).sum::<f64>() / n).sqrt();
        out.push(Repeatability {
            landmark: l.id.clone(),
            touches: spreads.len(),
            rms_mm: rms,
            rp_mm: mean + 3.0 * std,
        });
    }
    out
}

/// Validation of a model on one held-out session, its frame refitted (closed form).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct SessionValidation {
    /// Session name.
    pub name: String,
    /// Points.
    pub points: usize,
    /// RMS position error, mm.
    pub rms_mm: f64,
    /// Mean position error, mm.
    pub mean_mm: f64,
    /// Standard deviation of the position error, mm.
    #[serde(default)]
    pub std_mm: f64,
    /// Largest position error, mm.
    pub max_mm: f64,
    /// RMS of the frame-free pairwise-distance error inside the session, mm.
    pub pairwise_rms_mm: f64,
    /// Pairs of points compared.
    pub pairs: usize,
}

/// The instrument points of block `b`.
fn points_of(data: &Observations, b: usize) -> impl Iterator<Item = &Observation> + '_ {
    point_members(data, b).map(|k| &data.obs[k])
}

/// The indices of [`points_of`].
fn point_members(data: &Observations, b: usize) -> impl Iterator<Item = usize> + '_ {
    data.blocks[b].members.iter().copied().filter(|&k| data.obs[k].point_mm().is_some())
}

/// Block `b`'s frame for `model` (tool offset `offset_mm` in the flange frame), closed form.
pub fn block_frame(model: &ArmModel, data: &Observations, b: usize, offset_mm: &Vector3<f64>) -> Frame {
    block_frame_of(&model_points(model, data, point_members(data, b), offset_mm), data, b)
}

/// Block `b`'s frame (closed form) for the model's points `robot` of its points in order.
fn block_frame_of(robot: &[Vector3<f64>], data: &Observations, b: usize) -> Frame {
    let measured: Vec<Vector3<f64>> = points_of(data, b).map(|p| p.point_mm().unwrap_or_default()).collect();
    Frame::fit(robot, &measured)
}

/// Position error of every calibration point at the solution, per framed block in order, mm;
/// the poses read from `poses` when they are of the fit's model on `data`.
pub fn calibration_errors(fit: &Fit, data: &Observations, poses: Option<&ModelPoses>) -> Vec<Vec<f64>> {
    calibration_residuals_mm(fit, data, poses)
        .into_iter()
        .map(|block| block.iter().map(|r| r.norm()).collect())
        .collect()
}

/// Residual of every point at the solution, per instrument session of `data` in order (empty for
/// a session `fit` has no frame of): measured − predicted (its session's fitted frame, tool offset
/// and drift), in the robot's base frame, mm; the poses read from `poses` when they are of the
/// fit's model on `data`.
pub fn calibration_residuals_mm(
    fit: &Fit,
    data: &Observations,
    poses: Option<&ModelPoses>,
) -> Vec<Vec<Vector3<f64>>> {
    (0..data.blocks.len())
        .filter(|&b| data.groups[data.blocks[b].group].kind == crate::data::Kind::Tracker)
        .map(|b| match fit.frame(&data.block_name(b)) {
            Some(frame) => residuals_with_frame(fit, data, b, &frame, data, point_members(data, b), poses),
            None => Vec::new(),
        })
        .collect()
}

/// Position errors, mm, of the points of `val`'s block `held_out` measured from calibration
/// session `session`'s instrument placement (protocol S: a held-out set of the same session), with
/// that session's calibrated frame, its floated tool and its drift; `None` when `session` is not a
/// calibration session of `cal`.
pub fn errors_in_calibration_session(
    fit: &Fit,
    cal: &Observations,
    session: &str,
    val: &Observations,
    held_out: usize,
) -> Option<Vec<f64>> {
    let b = cal.find_block(session)?;
    let frame = fit.frame(session)?;
    let residuals = residuals_with_frame(fit, cal, b, &frame, val, point_members(val, held_out), None);
    Some(residuals.iter().map(|r| r.norm()).collect())
}

/// Residuals (measured − predicted, robot base frame, mm) of the points `members` of `points`
/// with `frame` and the tool offset and drift `fit` gives block `b` of `data`; their poses read
/// from `poses` when they are of the fit's model on `points`.
fn residuals_with_frame(
    fit: &Fit,
    data: &Observations,
    b: usize,
    frame: &Frame,
    points: &Observations,
    members: impl Iterator<Item = usize>,
    poses: Option<&ModelPoses>,
) -> Vec<Vector3<f64>> {
    let offset = fit.tool_offset(&data.groups[data.blocks[b].group].name);
    let name = data.block_name(b);
    let drift = fit.drifts.iter().find(|d| d.session == name);
    PoseSource::new(&fit.model, points, poses).map(members, |k, pose| {
        let p = &points.obs[k];
        let (shift, growth) = drift.map_or((Vector3::zeros(), 1.0), |d| d.effect_at(p));
        let y = frame.rotation * with_offset(pose, &offset);
        frame.rotation.transpose()
            * (p.point_mm().unwrap_or_default() - (y * growth + frame.translation_mm + shift))
    })
}

/// Fit block `b`'s frame and its own tool offset for a fixed `model` (the tool floated there):
/// the offset with its covariance. [`validate_session`] at its offset validates with both
/// refitted.
pub fn session_tool(model: &ArmModel, data: &Observations, b: usize) -> FloatedTool {
    let group = data.blocks[b].group;
    let one = data.subset(&[group]);
    let start = block_frame(model, &one, 0, &Vector3::zeros());
    let terms = crate::calib::terms::point::terms(&one, 1.0);
    let layout = Layout::new(Vec::new(), &[true], &[true], false, &[None]);
    let problem = Problem::new(layout, model, &one, &terms, vec![start.rotation], None);
    let t = start.translation_mm;
    let x0 = [0.0, 0.0, 0.0, t.x, t.y, t.z, 0.0, 0.0, 0.0];
    let options = SolverOptions { max_iterations: 100, ..SolverOptions::default() };
    let solution = solver::solve(&problem, &x0, &[-1e9; 9], &[1e9; 9], &options);
    let mut r = vec![0.0; problem.len()];
    let (normal, _) = problem.normal_equations(&solution.x, &mut r, Loss::Linear);
    let variance = r.iter().map(|v| v * v).sum::<f64>() / (r.len() as f64 - 9.0).max(1.0);
    let cov = crate::calib::identify::covariance_of_normal(normal, variance);
    let offset = problem.state(&solution.x).tools[0];
    let block = cov.as_ref().map_or(Matrix3::zeros(), |c| c.fixed_view::<3, 3>(6, 6).into_owned());
    FloatedTool::new(data.groups[group].name.clone(), &offset, &block)
}

/// Block `b`'s tool offset (flange frame, mm) for `model`: its own fit ([`session_tool`]) when
/// `float_tool` names the block, else zero.
pub fn session_offset_mm(model: &ArmModel, data: &Observations, b: usize, float_tool: &[String]) -> [f64; 3] {
    if float_tool.contains(&data.block_name(b)) {
        session_tool(model, data, b).offset_mm
    } else {
        [0.0; 3]
    }
}

/// RMS distance, mm, of a session's points from the line through them below which they count as
/// lying on one line: the rotation of the session's base about that line is then set by this
/// spread and the noise alone (0.02 mm of noise across 1 mm turns it by about 1°).
pub const COLLINEAR_SPREAD_MM: f64 = 1.0;

/// Why block `b`'s points do not determine its base's rotation: they lie on one line, about which
/// the base can turn freely; `None` when they determine it. A session's orientation error, its
/// base refitted from its points, is then arbitrary and is not scored.
pub fn undetermined_rotation(data: &Observations, b: usize) -> Option<String> {
    let points: Vec<Vector3<f64>> = points_of(data, b).map(|p| p.point_mm().unwrap_or_default()).collect();
    let n = points.len().max(1) as f64;
    let centre = points.iter().sum::<Vector3<f64>>() / n;
    let scatter = points.iter().map(|p| (p - centre) * (p - centre).transpose()).sum::<Matrix3<f64>>() / n;
    let mut variances: Vec<f64> = scatter.symmetric_eigenvalues().iter().map(|v| v.max(0.0)).collect();
    variances.sort_by(|a, b| b.total_cmp(a));
    let (along, across) = (variances[0].sqrt(), (variances[1] + variances[2]).sqrt());
    (across < COLLINEAR_SPREAD_MM).then(|| {
        format!(
            "session {}: its points lie on one line (RMS {across:.3} mm across it, {along:.0} mm along it), so the \
             rotation of its base about that line is not determined and no orientation error is scored",
            data.block_name(b)
        )
    })
}

/// Block `b`'s own probe rotation R_t,S (flange ← probe), its frame refitted from the positions
/// with the tool offset `tool_offset_mm`: the chordal mean of R_Fᵀ·R_Sᵀ·R_meas over its oriented
/// points. A probe turned on its mount in that session is R_t,S = Q·R_t, Q its turn in the flange
/// frame. `None` without orientations.
pub fn session_probe_rotation(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    tool_offset_mm: [f64; 3],
) -> Option<Matrix3<f64>> {
    let one = data.subset(&[data.blocks[b].group]);
    let frames: Vec<Frame> =
        (0..one.blocks.len()).map(|k| block_frame(model, &one, k, &Vector3::from(tool_offset_mm))).collect();
    crate::calib::nuisance::tool::start_probe_rotation(model, &one, &frames)
}

/// Orientation errors of `model` with the probe rotation `probe` on block `b`, its frame
/// refitted from the positions (closed form); `None` when the block has no orientations.
pub fn validate_orientations(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    tool_offset_mm: [f64; 3],
    probe: &Matrix3<f64>,
) -> Option<AngleStats> {
    angle_stats(&orientation_errors_deg(model, data, b, tool_offset_mm, probe))
}

/// The statistics of the orientation errors `errors_deg` of a block's points (those it has);
/// `None` when it has none.
pub fn angle_stats(errors_deg: &[Option<f64>]) -> Option<AngleStats> {
    let angles_deg: Vec<f64> = errors_deg.iter().flatten().copied().collect();
    (!angles_deg.is_empty()).then(|| AngleStats::of(&angles_deg))
}

/// The orientation error (angle of R_predᵀ·R_meas, degrees) of every point of block `b`, its
/// frame refitted from the positions (closed form); `None` for a row without an orientation.
pub fn orientation_errors_deg(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    tool_offset_mm: [f64; 3],
    probe: &Matrix3<f64>,
) -> Vec<Option<f64>> {
    let frame = block_frame(model, data, b, &Vector3::from(tool_offset_mm));
    orientation_errors_in_frame_deg(model, data, b, &frame, probe)
}

/// [`orientation_errors_deg`] with block `b`'s frame `frame` already refitted (a
/// [`SessionFit`]'s).
pub fn orientation_errors_in_frame_deg(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    frame: &Frame,
    probe: &Matrix3<f64>,
) -> Vec<Option<f64>> {
    let chain = Chain::new(model);
    point_members(data, b)
        .map(|k| {
            let p = &data.obs[k];
            let measured = p.orientation()?.to_rotation_matrix().into_inner();
            let pose = data.encoders().pose(&chain, k, p);
            let predicted = frame.rotation * flange_rotation(&pose) * probe;
            Some(rotation_vector(&(predicted.transpose() * measured)).norm().to_degrees())
        })
        .collect()
}

/// The residual of every point of block `b` for `model`, its frame refitted (closed form):
/// measured − predicted, rotated into the robot's base frame so that sessions compare, mm. Its
/// lengths are the errors [`validate_session`] summarises.
pub fn session_residuals_mm(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    tool_offset_mm: [f64; 3],
) -> Vec<Vector3<f64>> {
    SessionFit::of(model, data, b, tool_offset_mm).residuals_mm()
}

impl SessionValidation {
    /// The point-error statistics.
    pub fn stats(&self) -> ErrorStats {
        ErrorStats {
            count: self.points,
            rms_mm: self.rms_mm,
            mean_mm: self.mean_mm,
            std_mm: self.std_mm,
            max_mm: self.max_mm,
        }
    }
}

/// Most points of a session whose pairwise distances are compared (evenly spaced beyond).
pub const MAX_PAIRWISE_POINTS: usize = 2000;

/// Block `b`'s closed-form fit for a model: the model's points of its points, its frame and the
/// position error of every point with it. Every figure of a session for one model and tool offset
/// (its validation, its residuals, its orientation errors) is read from one of these, so that its
/// points are posed and its frame fitted once.
pub struct SessionFit<'a> {
    /// The data and the block fitted.
    data: &'a Observations,
    b: usize,
    /// The model's tool points of the block's points, in file order, robot frame, mm.
    robot: Vec<Vector3<f64>>,
    /// The refitted frame (robot → instrument).
    frame: Frame,
    /// Predicted − measured of every point, in file order, in the instrument's frame, mm.
    residuals: Vec<Vector3<f64>>,
}

impl<'a> SessionFit<'a> {
    /// Block `b` of `data` for `model` with the tool offset `tool_offset_mm` (flange frame).
    pub fn of(
        model: &ArmModel,
        data: &'a Observations,
        b: usize,
        tool_offset_mm: [f64; 3],
    ) -> SessionFit<'a> {
        SessionFit::with_poses(model, data, b, tool_offset_mm, None)
    }

    /// [`SessionFit::of`], the poses read from `poses` when they are of `model` on `data`.
    pub fn with_poses(
        model: &ArmModel,
        data: &'a Observations,
        b: usize,
        tool_offset_mm: [f64; 3],
        poses: Option<&ModelPoses>,
    ) -> SessionFit<'a> {
        let (offset, poses) = (&Vector3::from(tool_offset_mm), PoseSource::new(model, data, poses));
        let robot = poses.map(point_members(data, b), |_, pose| with_offset(pose, offset));
        let frame = block_frame_of(&robot, data, b);
        let residuals = points_of(data, b)
            .zip(&robot)
            .map(|(p, y)| frame.apply(y) - p.point_mm().unwrap_or_default())
            .collect();
        SessionFit { data, b, robot, frame, residuals }
    }

    /// The refitted frame (robot → instrument).
    pub fn frame(&self) -> &Frame {
        &self.frame
    }

    /// Position error of every point, in file order, in the instrument's frame, mm.
    pub fn residuals(&self) -> &[Vector3<f64>] {
        &self.residuals
    }

    /// Lengths of the residuals, mm.
    pub fn errors(&self) -> Vec<f64> {
        self.residuals.iter().map(|r| r.norm()).collect()
    }

    /// Measured − predicted of every point, rotated into the robot's base frame so that sessions
    /// compare, mm.
    pub fn residuals_mm(&self) -> Vec<Vector3<f64>> {
        self.residuals.iter().map(|r| self.frame.rotation.transpose() * -r).collect()
    }

    /// The error statistics and the pairwise figure of the block.
    pub fn validation(&self) -> SessionValidation {
        let (data, b) = (self.data, self.b);
        let stats = ErrorStats::of(&self.errors());
        let points: Vec<Vector3<f64>> =
            points_of(data, b).map(|p| p.point_mm().unwrap_or_default()).collect();
        let (sum, pairs) = pairwise_square_sum(&self.robot, &points);
        SessionValidation {
            name: data.block_name(b),
            points: stats.count,
            rms_mm: stats.rms_mm,
            mean_mm: stats.mean_mm,
            std_mm: stats.std_mm,
            max_mm: stats.max_mm,
            pairwise_rms_mm: if pairs > 0 { (sum / pairs as f64).sqrt() } else { 0.0 },
            pairs,
        }
    }
}

/// Every instrument session of one data set for one model, each tool that floats refitted
/// first ([`session_offset_mm`]): taken once for the figures read from them (a run's held-out
/// validation and its data-error scoring's held-out errors).
pub struct SessionFits<'a> {
    model: &'a ArmModel,
    data: &'a Observations,
    float_tool: &'a [String],
    /// Each session with its tool offset (its own where it floats, flange frame, mm) and its fit.
    fits: Vec<(usize, [f64; 3], SessionFit<'a>)>,
}

impl<'a> SessionFits<'a> {
    /// Every session of `data` for `model`, the tools `float_tool` names refitted.
    pub fn of(model: &'a ArmModel, data: &'a Observations, float_tool: &'a [String]) -> SessionFits<'a> {
        let fits = (data.sessions().into_iter())
            .map(|b| {
                let offset_mm = session_offset_mm(model, data, b, float_tool);
                (b, offset_mm, SessionFit::of(model, data, b, offset_mm))
            })
            .collect();
        SessionFits { model, data, float_tool, fits }
    }

    /// Each session, its tool offset and its fit, in order.
    pub fn fits(&self) -> &[(usize, [f64; 3], SessionFit<'a>)] {
        &self.fits
    }

    /// The errors of `model` on each session of `data` in order, the tools `float_tool` names
    /// refitted ([`held_out_session_errors`]): `taken`'s when it is of that very model and data
    /// with the same tools floated, else taken here.
    pub fn errors(
        taken: Option<&SessionFits>,
        model: &ArmModel,
        data: &Observations,
        float_tool: &[String],
    ) -> Vec<(usize, Vec<f64>)> {
        let same = |t: &&SessionFits| {
            std::ptr::eq(t.model, model) && std::ptr::eq(t.data, data) && t.float_tool == float_tool
        };
        match taken.filter(same) {
            Some(taken) => taken.fits.iter().map(|(b, _, fit)| (*b, fit.errors())).collect(),
            None => data
                .sessions()
                .into_iter()
                .map(|b| (b, held_out_session_errors(model, data, b, float_tool)))
                .collect(),
        }
    }
}

/// Position error of every point of block `b` for `model`, its frame refitted (closed form), in
/// file order, in the instrument's frame, mm.
pub fn session_residuals(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    tool_offset_mm: [f64; 3],
) -> Vec<Vector3<f64>> {
    SessionFit::of(model, data, b, tool_offset_mm).residuals
}

/// [`session_errors`] of held-out session `b` of `val`, its tool refitted too
/// ([`session_tool`]) when `float_tool` names it.
pub fn held_out_session_errors(
    model: &ArmModel,
    val: &Observations,
    b: usize,
    float_tool: &[String],
) -> Vec<f64> {
    session_errors(model, val, b, session_offset_mm(model, val, b, float_tool))
}

/// Lengths of [`session_residuals`], mm.
pub fn session_errors(model: &ArmModel, data: &Observations, b: usize, tool_offset_mm: [f64; 3]) -> Vec<f64> {
    SessionFit::of(model, data, b, tool_offset_mm).errors()
}

/// Errors of `model` on block `b` with its frame refitted (closed form), and the pairwise figures.
pub fn validate_session(
    model: &ArmModel,
    data: &Observations,
    b: usize,
    tool_offset_mm: [f64; 3],
) -> SessionValidation {
    SessionFit::of(model, data, b, tool_offset_mm).validation()
}

/// Points' coordinates as three arrays, so that a loop over many points reads each coordinate
/// contiguously (and vectorises).
struct Coordinates {
    x: Vec<f64>,
    y: Vec<f64>,
    z: Vec<f64>,
}

impl Coordinates {
    /// The coordinates of `points[i]` for each `i` of `picked`, in that order.
    fn of(points: &[Vector3<f64>], picked: impl Iterator<Item = usize> + Clone) -> Coordinates {
        let axis = |j: usize| picked.clone().map(|i| points[i][j]).collect();
        Coordinates { x: axis(0), y: axis(1), z: axis(2) }
    }

    /// Point `a`'s distance to each point after it, into `out` (as long as the points after it).
    /// The sum of squares in `Vector3::norm`'s order, so each distance is its norm to the bit.
    fn distances_after(&self, a: usize, out: &mut [f64]) {
        let n = out.len();
        let (x, y, z) = (&self.x[a + 1..][..n], &self.y[a + 1..][..n], &self.z[a + 1..][..n]);
        let (xa, ya, za) = (self.x[a], self.y[a], self.z[a]);
        for i in 0..n {
            let (dx, dy, dz) = (xa - x[i], ya - y[i], za - z[i]);
            out[i] = (dx * dx + dy * dy + dz * dz).sqrt();
        }
    }
}

/// The frame-free pairwise figure of a session: Σ (|yₐ − y_c| − |pₐ − p_c|)² over the pairs
/// a < c of its points (`robot` the model's, `measured` the instrument's, in order; at most
/// [`MAX_PAIRWISE_POINTS`] of them, evenly spaced), and the number of pairs. Each row of pairs'
/// squares is taken into a buffer, a loop that vectorises, then added in the pairs' order: the
/// sum of the plain pair-by-pair loop, to the bit.
fn pairwise_square_sum(robot: &[Vector3<f64>], measured: &[Vector3<f64>]) -> (f64, usize) {
    let step = measured.len().div_ceil(MAX_PAIRWISE_POINTS).max(1);
    let picked = (0..measured.len()).step_by(step);
    let (robot, measured) = (Coordinates::of(robot, picked.clone()), Coordinates::of(measured, picked));
    let n = measured.x.len();
    let (mut model_mm, mut measured_mm) = (vec![0.0; n], vec![0.0; n]);
    let mut sum = 0.0;
    for a in 0..n {
        let (model_mm, measured_mm) = (&mut model_mm[..n - a - 1], &mut measured_mm[..n - a - 1]);
        robot.distances_after(a, model_mm);
        measured.distances_after(a, measured_mm);
        for (m, d) in model_mm.iter_mut().zip(measured_mm.iter()) {
            let e = *m - d;
            *m = e * e;
        }
        for square in model_mm.iter() {
            sum += square;
        }
    }
    (sum, n * n.saturating_sub(1) / 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_of_known_errors() {
        let s = ErrorStats::of(&[1.0, -1.0, 3.0, -3.0]);
        assert!((s.rms_mm - 5.0_f64.sqrt()).abs() < 1e-12);
        assert_eq!((s.mean_mm, s.max_mm, s.count), (0.0, 3.0, 4));
        assert_eq!(ErrorStats::of(&[]).count, 0);
    }

    /// The pairwise figure of the plain loop: every pair's vectors' norms, one pair at a time.
    fn plain_pairwise(robot: &[Vector3<f64>], measured: &[Vector3<f64>]) -> (f64, usize) {
        let step = measured.len().div_ceil(MAX_PAIRWISE_POINTS).max(1);
        let picked: Vec<usize> = (0..measured.len()).step_by(step).collect();
        let (mut sum, mut pairs) = (0.0, 0);
        for (k, &a) in picked.iter().enumerate() {
            for &c in &picked[k + 1..] {
                let e = (robot[a] - robot[c]).norm() - (measured[a] - measured[c]).norm();
                sum += e * e;
                pairs += 1;
            }
        }
        (sum, pairs)
    }

    /// Scattered points of a session, the measured ones the model's moved by a little noise.
    fn session_points(n: usize) -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
        let at = |i: usize, j: usize| ((i * 3 + j) as f64 * 0.7351).sin() * 900.0 + j as f64 * 130.0;
        let robot: Vec<Vector3<f64>> = (0..n).map(|i| Vector3::new(at(i, 0), at(i, 1), at(i, 2))).collect();
        let noise = |i: usize, j: usize| ((i * 5 + j) as f64 * 1.913).cos() * 0.03;
        let measured = robot
            .iter()
            .enumerate()
            .map(|(i, p)| p + Vector3::new(noise(i, 0), noise(i, 1), noise(i, 2)))
            .collect();
        (robot, measured)
    }

    /// A session's figures read from one closed-form fit are those computed each on its own: the
    /// frame [`block_frame`] fits (the one the orientation errors read), the errors, the residuals
    /// in the base frame, and the statistics with the plain loop's pairwise figure.
    #[test]
    fn a_session_fit_gives_each_figure_computed_alone() {
        use crate::calib::bench_problem;
        let nominal = bench_problem::arm();
        let data = bench_problem::sessions(&bench_problem::truth(&nominal), 2, 60, 7);
        for (b, offset_mm) in [(0, [0.0; 3]), (1, [0.4, -0.3, 1.1])] {
            let offset = Vector3::from(offset_mm);
            let fit = SessionFit::of(&nominal, &data, b, offset_mm);
            assert_eq!(*fit.frame(), block_frame(&nominal, &data, b, &offset));
            let robot = model_points(&nominal, &data, point_members(&data, b), &offset);
            let measured: Vec<Vector3<f64>> =
                points_of(&data, b).map(|p| p.point_mm().unwrap_or_default()).collect();
            let frame = Frame::fit(&robot, &measured);
            let residuals: Vec<Vector3<f64>> =
                robot.iter().zip(&measured).map(|(y, p)| frame.apply(y) - p).collect();
            let errors: Vec<f64> = residuals.iter().map(|r| r.norm()).collect();
            assert_eq!(fit.residuals(), residuals.as_slice());
            assert_eq!(fit.errors(), errors);
            let in_base: Vec<Vector3<f64>> =
                residuals.iter().map(|r| frame.rotation.transpose() * -r).collect();
            assert_eq!(fit.residuals_mm(), in_base);
            let (v, stats) = (fit.validation(), ErrorStats::of(&errors));
            let (sum, pairs) = plain_pairwise(&robot, &measured);
            assert_eq!(
                (v.points, v.rms_mm, v.mean_mm, v.std_mm, v.max_mm, v.pairs, v.pairwise_rms_mm),
                (
                    60,
                    stats.rms_mm,
                    stats.mean_mm,
                    stats.std_mm,
                    stats.max_mm,
                    pairs,
                    (sum / pairs as f64).sqrt()
                )
            );
            assert!(v.rms_mm > 0.1, "the nominal arm misses the truth's points: {v:?}");
        }
    }

    /// Figures read from a fit's poses taken once ([`ModelPoses`]) are those computed from the model,
    /// to the bit: a session's fit, its orientation spread, the calibration residuals. The poses
    /// are read only for the very model and data they were taken of: another model (or a copy of
    /// the data) is posed again, and its figures are its own.
    #[test]
    fn figures_from_shared_poses_are_those_of_the_model() {
        use crate::calib::bench_problem;
        use crate::calib::nuisance::tool::{orientation_spread_deg, orientation_spread_with};
        let nominal = bench_problem::arm();
        let data = bench_problem::sessions(&bench_problem::truth(&nominal), 2, 60, 11);
        let options = crate::calib::setup::SolveOptions::default();
        let fit = crate::calib::fit::calibrate(&nominal, &data, &options).expect("fit");
        let shared = ModelPoses::of(&fit.model, &data);
        assert!(matches!(PoseSource::new(&fit.model, &data, Some(&shared)), PoseSource::Taken(_)));
        let copy = data.clone();
        for (model, data) in [(&nominal, &data), (&fit.model, &copy)] {
            assert!(matches!(PoseSource::new(model, data, Some(&shared)), PoseSource::Posed(..)));
        }
        let offset_mm = [0.2, 0.0, -0.7];
        for b in 0..2 {
            for model in [&fit.model, &nominal] {
                let (alone, read) = (
                    SessionFit::of(model, &data, b, offset_mm),
                    SessionFit::with_poses(model, &data, b, offset_mm, Some(&shared)),
                );
                assert_eq!((alone.frame(), alone.residuals()), (read.frame(), read.residuals()));
                let spread = orientation_spread_deg(model, &data, b);
                assert_eq!(spread, orientation_spread_with(model, &data, b, Some(&shared)));
            }
            // The two models' figures differ: reading the fit's poses for the nominal arm would fail.
            let (fitted, nominal_fit) = (
                SessionFit::of(&fit.model, &data, b, offset_mm),
                SessionFit::of(&nominal, &data, b, offset_mm),
            );
            assert!(fitted.residuals() != nominal_fit.residuals());
        }
        let residuals = calibration_residuals_mm(&fit, &data, None);
        assert_eq!(residuals.iter().map(Vec::len).collect::<Vec<_>>(), [60, 60]);
        assert_eq!(residuals, calibration_residuals_mm(&fit, &data, Some(&shared)));
        let other = ModelPoses::of(&nominal, &data);
        assert_eq!(residuals, calibration_residuals_mm(&fit, &data, Some(&other)));
    }

    /// A held-out validation's session fits give the data-error scoring its errors, those of
    /// [`held_out_session_errors`] to the bit (a floated tool refitted); they are read only for the
    /// very model and data with the same tools floated: otherwise the errors are taken again.
    #[test]
    fn held_out_errors_from_session_fits_are_those_taken_again() {
        use crate::calib::bench_problem;
        let nominal = bench_problem::arm();
        let truth = bench_problem::truth(&nominal);
        let data = bench_problem::sessions(&truth, 2, 60, 5);
        let (none, one) = (Vec::new(), vec![data.block_name(1)]);
        let fits = SessionFits::of(&nominal, &data, &one);
        assert_eq!(fits.fits()[0].1, [0.0; 3]);
        assert!(fits.fits()[1].1 != [0.0; 3], "the floated tool is refitted");
        let again =
            |model: &ArmModel, data: &Observations, float_tool: &[String]| -> Vec<(usize, Vec<f64>)> {
                data.sessions()
                    .into_iter()
                    .map(|b| (b, held_out_session_errors(model, data, b, float_tool)))
                    .collect()
            };
        let copy = data.clone();
        for (model, data, float_tool) in [
            (&nominal, &data, &one),
            (&truth, &data, &one),
            (&nominal, &copy, &one),
            (&nominal, &data, &none),
        ] {
            let read = SessionFits::errors(Some(&fits), model, data, float_tool);
            assert_eq!(read, again(model, data, float_tool));
        }
        // The other model's and the other tools' errors differ from these fits': reading them there fails.
        let own = again(&nominal, &data, &one);
        assert!(own != again(&truth, &data, &one) && own != again(&nominal, &data, &none));
    }

    /// The row-buffered pairwise sum is the plain loop's to the bit, with and without points
    /// left out by the cap on their number, and for no pair at all.
    #[test]
    fn pairwise_sum_is_the_plain_loops() {
        for n in [0, 1, 2, 3, 17, 250, MAX_PAIRWISE_POINTS + 7] {
            let (robot, measured) = session_points(n);
            let (fast, plain) = (pairwise_square_sum(&robot, &measured), plain_pairwise(&robot, &measured));
            assert_eq!((fast.0.to_bits(), fast.1), (plain.0.to_bits(), plain.1), "{n} points");
            assert!(n < 3 || fast.0 > 0.0, "the noise leaves a figure");
        }
    }
}
