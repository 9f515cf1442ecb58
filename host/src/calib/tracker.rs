//! Calibration from tracker sessions: the arm's free parameters, the tool point, and one
//! instrument ← robot base per session, over one parameter vector.
//!
//! The measured point of row i in session s is X_i = B_s · F(q_i; θ) · t, with B_s = (R_s, t_s)
//! the session's base, F the chain and t the tool point (`tcp.*`). Each session's base starts at
//! its closed form for the nominal arm (Horn's absolute orientation of the model points onto the
//! measured ones) and is then estimated jointly with θ as a small rotation ω_s (mrad, left of the
//! starting rotation) and a shift t_s (mm): R_s = exp(ω_s)·R⁰_s. The residual block of a point is
//! X_i − X_i,measured (mm, three rows); a base touches only its own session's rows. No m × n
//! Jacobian is formed: each row's derivatives over its own columns (the arm's, its session's
//! base, floated tool and drift, the probe rotation's) are added into JᵀJ and Jᵀr as the row is
//! evaluated, in fixed blocks summed in order (the same sums on any thread count). The cost per
//! point is O(own columns²), flat in the number of points, and the memory is O(n²).
//!
//! Identifiability sees the bases: the base columns are projected out of the arm columns (what
//! a base can reproduce, the data cannot attribute to the arm), and the base set is chosen by
//! pivoted QR on what remains. It works on one small matrix per session, the R factor of the
//! session's rows (own columns | arm | probe rotation) folded block by block by QR: R has the
//! same column inner products as the rows, so the projections, norms, singular values and the
//! pivoted QR are those of the full Jacobian, without squaring its condition number. What drops out is said in words: a parameter a base absorbs (the
//! first joint's offset and d, a rotation about and a shift along the base axis), and the tool
//! point when the orientation is constant within the sessions (then it and each base's
//! translation are one thing, and the tool stays at its nominal value: every figure is the same
//! for any split between them, because each base absorbs the rest).

use crate::calib::identify::{self, Combination};
use crate::calib::tracker_drift::{drift_slots, DriftSlot, DriftSpec, SessionDrift};
use crate::data::Observations;
use crate::model::kinematics::{tool_pose, tool_pose_with_jacobian, ColumnMap, PoseDerivative, ToolPose};
use crate::model::{ArmModel, ParamId};
use crate::numerics::geometry::absolute_orientation;
use crate::numerics::solver::{self, Loss, Residuals, SolverOptions};
use crate::numerics::stats::rms;
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};
use rayon::prelude::*;

/// One measured row of a tracker session.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerPoint {
    /// Joint angles, degrees, one per joint.
    pub q_deg: Vec<f64>,
    /// The tool point in the instrument frame, mm.
    pub point_mm: Vector3<f64>,
    /// The probe's orientation in the instrument frame, for 6-DoF probes.
    pub orientation: Option<nalgebra::UnitQuaternion<f64>>,
    /// The instrument's stated standard uncertainty of the point, mm.
    pub sigma_mm: Option<f64>,
    /// Time of the measurement, s.
    pub time_s: Option<f64>,
    /// Temperature, °C.
    pub temp_c: Option<f64>,
    /// Pose id: rows with the same id are repeats.
    pub pose: Option<String>,
    /// Line in the file, 1-based.
    pub line: usize,
}

/// One instrument placement: the rows of one CSV file.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerSession {
    /// File name without `.csv`.
    pub name: String,
    /// The file.
    pub path: std::path::PathBuf,
    /// Rows in file order.
    pub points: Vec<TrackerPoint>,
}

/// The tracker sessions of one set of observations.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerData {
    /// Joint count of every row.
    pub joints: usize,
    /// Sessions, by file name.
    pub sessions: Vec<TrackerSession>,
    /// Columns ignored and other things worth a look, one sentence each.
    pub warnings: Vec<String>,
}

impl TrackerData {
    /// The instrument sessions of `data` (its artefact touches left out).
    pub fn of(data: &Observations) -> TrackerData {
        let sessions = data
            .groups
            .iter()
            .enumerate()
            .filter(|(_, g)| g.kind == crate::data::Kind::Tracker)
            .map(|(g, group)| TrackerSession {
                name: group.name.clone(),
                path: group.source.clone(),
                points: data
                    .obs
                    .iter()
                    .filter(|o| o.group == g)
                    .filter_map(|o| {
                        Some(TrackerPoint {
                            q_deg: o.q_deg.to_vec(),
                            point_mm: o.point_mm()?,
                            orientation: o.orientation(),
                            sigma_mm: o.sigma_mm,
                            time_s: o.time_s,
                            temp_c: o.temp_c,
                            pose: o.pose.clone(),
                            line: o.line,
                        })
                    })
                    .collect(),
            })
            .collect();
        TrackerData { joints: data.joints, sessions, warnings: data.warnings.clone() }
    }

    /// Rows in all sessions.
    pub fn point_count(&self) -> usize {
        self.sessions.iter().map(|s| s.points.len()).sum()
    }
}

/// Spread of the tool orientation within a session, degrees, below which the session is said
/// to hold the orientation constant.
pub const CONSTANT_ORIENTATION_DEG: f64 = 1.0;
/// Half-range of the tool point when the model does not free it, mm.
pub const TOOL_HALF_RANGE_MM: f64 = 500.0;
/// Unknowns of one session's base: a rotation (mrad) and a shift (mm).
pub const BASE_UNKNOWNS: usize = 6;
/// Most Gauss–Newton passes, each re-centring the bases at their closed form.
const PASSES: usize = 3;
/// Orientation σ of a 6-DoF probe per axis, degrees, when `--orientation-sigma-deg` is not given
/// (a laser tracker's 6-DoF probe states 0.005–0.02°).
pub const DEFAULT_ORIENTATION_SIGMA_DEG: f64 = 0.01;
/// Position σ per axis, mm, that weighs orientations against points when no point states its
/// uncertainty (`sigma_mm` / `u95_mm`).
pub const DEFAULT_POSITION_SIGMA_MM: f64 = 0.025;

/// Why a tracker calibration could not run.
#[derive(Debug, thiserror::Error)]
pub enum TrackerError {
    /// The sessions' joint count differs from the model's.
    #[error("the tracker sessions have {data} joint columns (q1_deg …), the model has {model} joints")]
    JointCount {
        /// Joints in the data.
        data: usize,
        /// Joints of the model.
        model: usize,
    },
    /// A session has too few points to place its base.
    #[error(
        "{path}: session \"{session}\" has {points} points: at least 3 not on one line are needed to place its base"
    )]
    TooFewPoints {
        /// The session's file.
        path: String,
        /// The session.
        session: String,
        /// Its points.
        points: usize,
    },
    /// More unknowns than residuals.
    #[error("{residuals} measured coordinates cannot determine {unknowns} unknowns: measure more points")]
    TooFewResiduals {
        /// Residual rows.
        residuals: usize,
        /// Unknowns (arm, tool, bases).
        unknowns: usize,
    },
    /// A session named by `--float-tool` or `--drift-session` is not in the data.
    #[error("--float-tool / --drift-session {0}: no calibration session of that name")]
    UnknownSession(String),
    /// `--drift-session` names a session twice.
    #[error("--drift-session {0}: the session is named twice (one drift kind per session)")]
    DriftTwice(String),
    /// A drifting session lacks the column its drift kind drifts against.
    #[error("--drift-session {session}:{kind}: {path}:{line} has no {column} (the drift is against {column}, on every row)")]
    DriftColumn {
        /// The session.
        session: String,
        /// The drift kind.
        kind: &'static str,
        /// The missing column.
        column: &'static str,
        /// The session's file.
        path: String,
        /// The first row without it.
        line: usize,
    },
    /// The model gives non-finite points.
    #[error("the model gives non-finite tool positions on these joint angles: check the model's numbers")]
    NonFinite,
}

/// Settings of a tracker calibration.
#[derive(Clone, Debug, Default)]
pub struct TrackerOptions {
    /// Huber threshold δ, mm; `None` for plain least squares.
    pub huber_delta_mm: Option<f64>,
    /// Sessions whose tool point gets its own offset (the probe was re-mounted there).
    pub float_tool: Vec<String>,
    /// Orientation σ of the 6-DoF probe per axis, degrees; `None`:
    /// [`DEFAULT_ORIENTATION_SIGMA_DEG`].
    pub orientation_sigma_deg: Option<f64>,
    /// Sessions whose points drift, and how (`--drift-session SESSION:KIND`, see
    /// [`crate::calib::tracker_drift`]).
    pub drift_sessions: Vec<DriftSpec>,
}

/// One session's base: instrument ← robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Base {
    /// Rotation.
    pub rotation: Matrix3<f64>,
    /// Translation, mm.
    pub translation_mm: Vector3<f64>,
}

impl Base {
    /// The base that best maps `model` points onto the session's measured points (closed form).
    pub fn fit(model: &ArmModel, points: &[TrackerPoint], tool_offset_mm: &Vector3<f64>) -> Base {
        let robot: Vec<Vector3<f64>> =
            points.iter().map(|p| model_point(model, &p.q_deg, tool_offset_mm)).collect();
        let measured: Vec<Vector3<f64>> = points.iter().map(|p| p.point_mm).collect();
        let (rotation, translation_mm) = absolute_orientation(&robot, &measured);
        Base { rotation, translation_mm }
    }

    fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation_mm
    }
}

/// The tool point in the robot frame, with a session's tool offset (in the flange frame).
fn model_point(model: &ArmModel, q_deg: &[f64], tool_offset_mm: &Vector3<f64>) -> Vector3<f64> {
    let pose = tool_pose(model, q_deg);
    pose.position_mm + flange_rotation(&pose.x_axis, &pose.z_axis) * tool_offset_mm
}

fn flange_rotation(x: &Vector3<f64>, z: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::from_columns(&[*x, z.cross(x), *z])
}

/// Axis · angle (rad) of a rotation matrix.
fn rotation_vector(m: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix(m).scaled_axis()
}

/// The joint estimation problem: arm columns, then per session ω (mrad) and t (mm), then per
/// floated session a tool offset (mm, flange frame).
struct Problem<'a> {
    model: &'a ArmModel,
    params: Vec<ParamId>,
    columns: ColumnMap,
    sessions: &'a [TrackerSession],
    start: Vec<Matrix3<f64>>,
    floated: Vec<Option<usize>>,
    rows: Vec<(usize, usize)>,
    /// Rows (session, point) with a measured orientation, after the position rows.
    oriented: Vec<(usize, usize)>,
    /// Start of the probe's orientation on the flange R⁰_t, when orientations are fitted.
    tool_rotation: Option<Matrix3<f64>>,
    /// Weight of an orientation residual: σ_position / σ_orientation, mm per rad.
    orientation_weight_mm_per_rad: f64,
    /// Per session, its drift when it drifts.
    drifting: Vec<Option<DriftSlot>>,
}

impl Problem<'_> {
    fn unknowns(&self) -> usize {
        self.drift_start() + self.drifting.iter().flatten().map(|d| d.kind.unknowns()).sum::<usize>()
    }

    fn drift_start(&self) -> usize {
        self.floated_end() + if self.tool_rotation.is_some() { 3 } else { 0 }
    }

    /// Session `s`'s drift: its first column and slot, when it drifts.
    fn drift_column(&self, s: usize) -> Option<(usize, DriftSlot)> {
        self.drifting.get(s).copied().flatten().map(|d| (self.drift_start() + d.column, d))
    }

    /// Session `s`'s drift rates (empty when it does not drift).
    fn drift_at<'x>(&self, x: &'x [f64], s: usize) -> &'x [f64] {
        self.drift_column(s).map_or(&[], |(c, d)| &x[c..c + d.kind.unknowns()])
    }

    fn floated_end(&self) -> usize {
        self.params.len() + BASE_UNKNOWNS * self.sessions.len() + 3 * self.floated.iter().flatten().count()
    }

    /// First column of the probe rotation ω_t (mrad, right of R⁰_t), when fitted.
    fn tool_rotation_column(&self) -> Option<usize> {
        self.tool_rotation.map(|_| self.floated_end())
    }

    fn tool_rotation_at(&self, x: &[f64]) -> Matrix3<f64> {
        match (self.tool_rotation, self.tool_rotation_column()) {
            (Some(start), Some(c)) => {
                start * Rotation3::new(Vector3::new(x[c], x[c + 1], x[c + 2]) * 1e-3).into_inner()
            }
            _ => Matrix3::identity(),
        }
    }

    fn base_column(&self, s: usize) -> usize {
        self.params.len() + BASE_UNKNOWNS * s
    }

    fn tool_column(&self, s: usize) -> Option<usize> {
        self.floated[s].map(|k| self.params.len() + BASE_UNKNOWNS * self.sessions.len() + 3 * k)
    }

    fn base_at(&self, x: &[f64], s: usize) -> Base {
        let c = self.base_column(s);
        let omega = Vector3::new(x[c], x[c + 1], x[c + 2]) * 1e-3;
        Base {
            rotation: Rotation3::new(omega).into_inner() * self.start[s],
            translation_mm: Vector3::new(x[c + 3], x[c + 4], x[c + 5]),
        }
    }

    fn tool_offset_at(&self, x: &[f64], s: usize) -> Vector3<f64> {
        self.tool_column(s).map_or(Vector3::zeros(), |c| Vector3::new(x[c], x[c + 1], x[c + 2]))
    }

    fn model_at(&self, x: &[f64]) -> ArmModel {
        let mut m = self.model.clone();
        for (id, v) in self.params.iter().zip(x) {
            m.set(*id, *v);
        }
        m
    }
}

/// The unknowns turned into what the residuals need: the model, and per session its base, tool
/// offset and drift rates, and the probe rotation.
struct State {
    model: ArmModel,
    bases: Vec<Base>,
    offsets: Vec<Vector3<f64>>,
    tool_rotation: Matrix3<f64>,
    drifts: Vec<Vec<f64>>,
}

/// The non-zero Jacobian columns of one residual row (three values): column `columns[k]` has
/// the derivatives `values[k]`. Reused from row to row, with the chain's derivatives.
#[derive(Clone, Default)]
struct RowJacobian {
    columns: Vec<usize>,
    values: Vec<Vector3<f64>>,
    chain: Vec<PoseDerivative>,
}

impl RowJacobian {
    fn push(&mut self, column: usize, derivative: Vector3<f64>) {
        self.columns.push(column);
        self.values.push(derivative);
    }
}

impl Problem<'_> {
    fn state(&self, x: &[f64]) -> State {
        let sessions = 0..self.sessions.len();
        State {
            model: self.model_at(x),
            bases: sessions.clone().map(|s| self.base_at(x, s)).collect(),
            offsets: sessions.clone().map(|s| self.tool_offset_at(x, s)).collect(),
            tool_rotation: self.tool_rotation_at(x),
            drifts: sessions.map(|s| self.drift_at(x, s).to_vec()).collect(),
        }
    }

    /// The session of residual row `i` (the points first, then the orientations).
    fn session_of(&self, i: usize) -> usize {
        let points = self.rows.len();
        if i < points {
            self.rows[i].0
        } else {
            self.oriented[i - points].0
        }
    }

    /// Residual row `i` (three values) into `r`; with `jac`, its non-zero Jacobian columns.
    fn row(&self, state: &State, i: usize, r: &mut [f64], mut jac: Option<&mut RowJacobian>) {
        if let Some(jac) = jac.as_deref_mut() {
            jac.columns.clear();
            jac.values.clear();
        }
        let points = self.rows.len();
        if i < points {
            self.point_row(state, i, r, jac)
        } else {
            self.orientation_row(state, i - points, r, jac)
        }
    }

    /// The chain's pose at `q_deg`, its derivatives into `jac.chain` when asked.
    fn chain_pose(&self, state: &State, q_deg: &[f64], jac: Option<&mut RowJacobian>) -> ToolPose {
        match jac {
            Some(jac) => {
                jac.chain.clear();
                jac.chain.resize(self.params.len(), [0.0; 9]);
                tool_pose_with_jacobian(&state.model, q_deg, &self.columns, &mut jac.chain)
            }
            None => tool_pose(&state.model, q_deg),
        }
    }

    fn point_row(&self, state: &State, i: usize, r: &mut [f64], mut jac: Option<&mut RowJacobian>) {
        let (s, k) = self.rows[i];
        let p = &self.sessions[s].points[k];
        let pose = self.chain_pose(state, &p.q_deg, jac.as_deref_mut());
        let flange = flange_rotation(&pose.x_axis, &pose.z_axis);
        let robot = pose.position_mm + flange * state.offsets[s];
        let base = &state.bases[s];
        let y = base.rotation * robot;
        let drift = self.drift_column(s).map(|(c, d)| {
            let delta = d.kind.variable(p).map_or(0.0, |v| v - d.centre);
            (c, d.kind, delta, d.kind.effect(&state.drifts[s], delta))
        });
        let (shift, growth) = drift.map_or((Vector3::zeros(), 1.0), |d| d.3);
        let e = y * growth + base.translation_mm + shift - p.point_mm;
        r.copy_from_slice(e.as_slice());
        let Some(jac) = jac else { return };
        for c in 0..self.params.len() {
            let d = jac.chain[c];
            jac.push(c, base.rotation * Vector3::new(d[0], d[1], d[2]) * growth);
        }
        let b = self.base_column(s);
        for k in 0..3 {
            jac.push(b + k, Vector3::ith(k, 1e-3).cross(&y) * growth);
        }
        for k in 0..3 {
            jac.push(b + 3 + k, Vector3::ith(k, 1.0));
        }
        if let Some(t) = self.tool_column(s) {
            let g = base.rotation * flange * growth;
            for k in 0..3 {
                jac.push(t + k, g.column(k).into_owned());
            }
        }
        if let Some((c, kind, delta, _)) = drift {
            for k in 0..kind.unknowns() {
                jac.push(c + k, kind.derivative(k, delta, &y));
            }
        }
    }

    fn orientation_row(&self, state: &State, i: usize, r: &mut [f64], mut jac: Option<&mut RowJacobian>) {
        let (s, k) = self.oriented[i];
        let p = &self.sessions[s].points[k];
        let Some(measured) = p.orientation else { return };
        let pose = self.chain_pose(state, &p.q_deg, jac.as_deref_mut());
        let flange = flange_rotation(&pose.x_axis, &pose.z_axis);
        let base = &state.bases[s];
        let predicted = base.rotation * flange * state.tool_rotation;
        let w = self.orientation_weight_mm_per_rad;
        let e = rotation_vector(&(predicted.transpose() * measured.to_rotation_matrix().into_inner())) * w;
        r.copy_from_slice(e.as_slice());
        let Some(jac) = jac else { return };
        // r ≈ r₀ − δ, δ the rotation of the prediction in its own frame.
        let to_body = predicted.transpose() * base.rotation;
        let y_axis = pose.z_axis.cross(&pose.x_axis);
        for c in 0..self.params.len() {
            let d = jac.chain[c];
            let (dx, dz) = (Vector3::new(d[3], d[4], d[5]), Vector3::new(d[6], d[7], d[8]));
            let dy = dz.cross(&pose.x_axis) + pose.z_axis.cross(&dx);
            let spin = 0.5 * (pose.x_axis.cross(&dx) + y_axis.cross(&dy) + pose.z_axis.cross(&dz));
            jac.push(c, to_body * spin * -w);
        }
        let b = self.base_column(s);
        let g = predicted.transpose() * (-1e-3 * w);
        for k in 0..3 {
            jac.push(b + k, g.column(k).into_owned());
        }
        if let Some(t) = self.tool_rotation_column() {
            for k in 0..3 {
                jac.push(t + k, Vector3::ith(k, -1e-3 * w));
            }
        }
    }
}

impl Residuals for Problem<'_> {
    fn len(&self) -> usize {
        3 * (self.rows.len() + self.oriented.len())
    }

    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
        let state = self.state(x);
        let n = self.unknowns();
        match jacobian {
            Some(dense) => r.par_chunks_mut(3).zip(dense.par_chunks_mut(3 * n)).enumerate().for_each_init(
                RowJacobian::default,
                |jac, (i, (r, dense))| {
                    self.row(&state, i, r, Some(jac));
                    dense.fill(0.0);
                    for (&c, v) in jac.columns.iter().zip(&jac.values) {
                        for a in 0..3 {
                            dense[a * n + c] = v[a];
                        }
                    }
                },
            ),
            None => r.par_chunks_mut(3).enumerate().for_each(|(i, r)| self.row(&state, i, r, None)),
        }
    }

    /// Row by row over each row's own columns (the arm's, its session's, the probe rotation's):
    /// no m × n Jacobian is formed, so the cost per point does not grow with the points. The rows
    /// are summed in fixed blocks, the blocks in order: the same sums whatever the thread count.
    fn normal_equations(&self, x: &[f64], r: &mut [f64], loss: Loss) -> (DMatrix<f64>, DVector<f64>) {
        let state = self.state(x);
        let n = self.unknowns();
        let rows = r.len() / 3;
        let block = rows.div_ceil(MAX_BLOCKS).max(MIN_BLOCK_ROWS);
        let sums: Vec<(Vec<f64>, Vec<f64>)> = r
            .par_chunks_mut(3 * block)
            .enumerate()
            .map(|(b, r)| {
                let (mut h, mut g, mut jac) = (vec![0.0; n * n], vec![0.0; n], RowJacobian::default());
                for (k, r) in r.chunks_exact_mut(3).enumerate() {
                    self.row(&state, b * block + k, r, Some(&mut jac));
                    let w = Vector3::new(loss.weight(r[0]), loss.weight(r[1]), loss.weight(r[2]));
                    for (p, (&cp, vp)) in jac.columns.iter().zip(&jac.values).enumerate() {
                        let wv = w.component_mul(vp);
                        g[cp] += wv.x * r[0] + wv.y * r[1] + wv.z * r[2];
                        for (&cq, vq) in jac.columns[p..].iter().zip(&jac.values[p..]) {
                            h[cp.min(cq) * n + cp.max(cq)] += wv.dot(vq);
                        }
                    }
                }
                (h, g)
            })
            .collect();
        let (mut upper, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        for (h_block, g_block) in sums {
            upper.iter_mut().zip(&h_block).for_each(|(a, b)| *a += b);
            g.iter_mut().zip(&g_block).for_each(|(a, b)| *a += b);
        }
        let mut h = DMatrix::from_row_slice(n, n, &upper);
        for a in 0..n {
            for b in 0..a {
                h[(a, b)] = h[(b, a)];
            }
        }
        (h, DVector::from_vec(g))
    }
}

/// Most blocks the rows of the normal equations are summed in (each holds an n × n sum).
const MAX_BLOCKS: usize = 16;
/// Fewest rows of a block.
const MIN_BLOCK_ROWS: usize = 64;

/// Position-error statistics of one set of points, mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ErrorStats {
    /// Points.
    pub points: usize,
    /// RMS of the 3-D error, mm.
    pub rms_mm: f64,
    /// Mean of the 3-D error, mm.
    pub mean_mm: f64,
    /// Largest 3-D error, mm.
    pub max_mm: f64,
}

impl ErrorStats {
    /// Statistics of error lengths.
    pub fn of(errors: &[f64]) -> ErrorStats {
        let n = errors.len();
        ErrorStats {
            points: n,
            rms_mm: rms(errors),
            mean_mm: if n > 0 { errors.iter().sum::<f64>() / n as f64 } else { 0.0 },
            max_mm: errors.iter().copied().fold(0.0, f64::max),
        }
    }
}

/// Orientation-error statistics (the angle of R_predᵀ·R_meas), degrees.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AngleStats {
    /// Orientations.
    pub orientations: usize,
    /// RMS angle, degrees.
    pub rms_deg: f64,
    /// Mean angle, degrees.
    pub mean_deg: f64,
    /// Largest angle, degrees.
    pub max_deg: f64,
}

impl AngleStats {
    /// Statistics of error angles (degrees).
    pub fn of(angles_deg: &[f64]) -> AngleStats {
        let e = ErrorStats::of(angles_deg);
        AngleStats { orientations: e.points, rms_deg: e.rms_mm, mean_deg: e.mean_mm, max_deg: e.max_mm }
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

/// The start of R_t: the chordal mean of R_Fᵀ·R_sᵀ·R_meas over the oriented points (bases from
/// the positions); `None` without orientations.
fn start_tool_rotation(
    model: &ArmModel,
    data: &TrackerData,
    bases: &[Base],
    oriented: &[(usize, usize)],
) -> Option<Matrix3<f64>> {
    if oriented.is_empty() {
        return None;
    }
    let mut sum = Matrix3::zeros();
    for &(s, k) in oriented {
        let p = &data.sessions[s].points[k];
        let measured = p.orientation?.to_rotation_matrix().into_inner();
        let pose = tool_pose(model, &p.q_deg);
        sum += flange_rotation(&pose.x_axis, &pose.z_axis).transpose()
            * bases[s].rotation.transpose()
            * measured;
    }
    let svd = sum.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * v_t).determinant().signum();
    Some(u * d * v_t)
}

/// Weight of an orientation residual, mm per rad: σ_position / σ_orientation, so that a
/// residual of one stated σ counts the same in a point's coordinate (mm) as in an orientation
/// axis. σ_position is the median stated point σ (`sigma_mm`, `u95_mm`/2), else
/// [`DEFAULT_POSITION_SIGMA_MM`]; σ_orientation is `--orientation-sigma-deg`, else
/// [`DEFAULT_ORIENTATION_SIGMA_DEG`].
pub fn orientation_weight_mm_per_rad(data: &TrackerData, options: &TrackerOptions) -> f64 {
    let mut stated: Vec<f64> =
        data.sessions.iter().flat_map(|s| s.points.iter().filter_map(|p| p.sigma_mm)).collect();
    stated.sort_by(f64::total_cmp);
    let position = stated.get(stated.len() / 2).copied().unwrap_or(DEFAULT_POSITION_SIGMA_MM);
    let orientation = options.orientation_sigma_deg.unwrap_or(DEFAULT_ORIENTATION_SIGMA_DEG).to_radians();
    position / orientation
}

/// What the data cannot separate, in words, and what the calibration therefore left out.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct TrackerIdentifiability {
    /// Free parameters estimated.
    pub estimated: Vec<String>,
    /// Free parameters held at their nominal value because the data cannot determine them.
    pub fixed: Vec<String>,
    /// Sentences a user reads: what cannot be separated, and why.
    pub statements: Vec<String>,
    /// Directions of the arm parameters (bases projected out) the data cannot determine.
    pub unidentifiable: Vec<Combination>,
    /// Directions it determines only weakly.
    pub poorly_identified: Vec<Combination>,
    /// Orientation spread of the tool within each session, degrees (session, spread).
    pub orientation_spread_deg: Vec<(String, f64)>,
}

/// One estimated value.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct TrackerEstimate {
    /// Parameter name.
    pub param: String,
    /// Unit.
    pub unit: String,
    /// Nominal value.
    pub nominal: f64,
    /// Calibrated value.
    pub value: f64,
    /// One standard deviation, when estimated.
    pub std: Option<f64>,
}

/// A session's own tool offset (the tool floated there).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct FloatedTool {
    /// The session.
    pub session: String,
    /// Offset of the tool point from the shared one, flange frame, mm.
    pub offset_mm: [f64; 3],
    /// Standard deviation of the offset's length, mm.
    pub size_std_mm: f64,
}

/// Standard deviation of |v| from the covariance block `c` of v.
fn length_std(v: &Vector3<f64>, c: &Matrix3<f64>) -> f64 {
    let n = v.norm();
    if n == 0.0 {
        return (c.trace() / 3.0).max(0.0).sqrt();
    }
    let u = v / n;
    (u.transpose() * c * u)[(0, 0)].max(0.0).sqrt()
}

fn covariance_block(cov: &Option<nalgebra::DMatrix<f64>>, at: usize) -> Matrix3<f64> {
    cov.as_ref().map_or(Matrix3::zeros(), |c| c.fixed_view::<3, 3>(at, at).into_owned())
}

/// The result of a tracker calibration.
#[derive(Clone, Debug)]
pub struct TrackerCalibration {
    /// The calibrated model.
    pub model: ArmModel,
    /// Each calibration session's base, in session order.
    pub bases: Vec<Base>,
    /// Tool offsets of the floated sessions.
    pub tool_offsets: Vec<FloatedTool>,
    /// Drift velocities of the drifting sessions.
    pub drifts: Vec<SessionDrift>,
    /// Position error on the calibration sessions.
    pub fit: ErrorStats,
    /// Orientation error on the calibration sessions (6-DoF probes).
    pub orientation_fit: Option<AngleStats>,
    /// The probe's orientation on the flange (6-DoF probes).
    pub tool_rotation: Option<ToolRotation>,
    /// Estimates of the free parameters.
    pub estimates: Vec<TrackerEstimate>,
    /// What was left out and why.
    pub identifiability: TrackerIdentifiability,
    /// Gauss–Newton iterations over all passes.
    pub iterations: usize,
}

/// Largest angle, degrees, between the tool orientation at any point of `session` and at its
/// first point (the model's flange orientation).
pub fn orientation_spread_deg(model: &ArmModel, session: &TrackerSession) -> f64 {
    let rotations: Vec<Matrix3<f64>> = session
        .points
        .iter()
        .map(|p| {
            let pose = tool_pose(model, &p.q_deg);
            flange_rotation(&pose.x_axis, &pose.z_axis)
        })
        .collect();
    let Some(first) = rotations.first() else { return 0.0 };
    rotations
        .iter()
        .map(|r| {
            let c = (((first.transpose() * r).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
            c.acos().to_degrees()
        })
        .fold(0.0, f64::max)
}

/// Points of a session folded into its factor by one QR.
const FOLD_POINTS: usize = 128;

/// A session's rows of the Jacobian in a small matrix: the R factor of its columns [its own
/// (base, floated tool, drift) | the arm's | the probe rotation's], folded block by block by QR.
/// R has the column geometry of those rows (every inner product of two columns), so what is
/// computed from it (projections, norms, singular values, pivoted QR) is what the m rows give,
/// without an m × n matrix.
struct SessionFactor {
    r: DMatrix<f64>,
    own: usize,
}

/// Each session's factor at `x`; `None` when a residual or a derivative is not finite.
fn session_factors(problem: &Problem, x: &[f64]) -> Option<Vec<SessionFactor>> {
    let state = problem.state(x);
    let (n, a) = (problem.unknowns(), problem.params.len());
    let rotation: Vec<usize> =
        problem.tool_rotation_column().map(|t| vec![t, t + 1, t + 2]).unwrap_or_default();
    let rows = problem.rows.len() + problem.oriented.len();
    (0..problem.sessions.len())
        .map(|s| {
            let mut own: Vec<usize> = (0..BASE_UNKNOWNS).map(|k| problem.base_column(s) + k).collect();
            own.extend(problem.tool_column(s).map(|t| [t, t + 1, t + 2]).into_iter().flatten());
            own.extend(problem.drift_column(s).map(|(c, d)| c..c + d.kind.unknowns()).into_iter().flatten());
            let mut local = vec![None; n];
            for (l, &c) in own.iter().chain(&(0..a).collect::<Vec<_>>()).chain(&rotation).enumerate() {
                local[c] = Some(l);
            }
            let width = own.len() + a + rotation.len();
            let mine: Vec<usize> = (0..rows).filter(|&i| problem.session_of(i) == s).collect();
            let blocks: Vec<Option<DMatrix<f64>>> = mine
                .par_chunks(FOLD_POINTS)
                .map_init(RowJacobian::default, |jac, chunk| {
                    let mut block = DMatrix::zeros(3 * chunk.len(), width);
                    let mut finite = true;
                    for (k, &i) in chunk.iter().enumerate() {
                        let mut r = [0.0; 3];
                        problem.row(&state, i, &mut r, Some(jac));
                        finite &= r.iter().all(|v| v.is_finite());
                        for (&c, v) in jac.columns.iter().zip(&jac.values) {
                            finite &= v.iter().all(|v| v.is_finite());
                            if let Some(l) = local[c] {
                                block.view_mut((3 * k, l), (3, 1)).copy_from(v);
                            }
                        }
                    }
                    finite.then(|| block.qr().r())
                })
                .collect();
            // Folded in order: the same factor whatever the thread count.
            let r = blocks
                .into_iter()
                .try_fold(DMatrix::zeros(0, width), |top, bottom| Some(fold(top, bottom?)))?;
            Some(SessionFactor { r, own: own.len() })
        })
        .collect()
}

/// The R factor of two factors stacked.
fn fold(top: DMatrix<f64>, bottom: DMatrix<f64>) -> DMatrix<f64> {
    if top.nrows() == 0 {
        return bottom;
    }
    if bottom.nrows() == 0 {
        return top;
    }
    let mut stacked = DMatrix::zeros(top.nrows() + bottom.nrows(), top.ncols());
    stacked.rows_mut(0, top.nrows()).copy_from(&top);
    stacked.rows_mut(top.nrows(), bottom.nrows()).copy_from(&bottom);
    stacked.qr().r()
}

/// `m` with the directions of `basis`'s columns above `1e-12` of its largest singular value
/// projected out of each column.
fn project_out(m: &mut DMatrix<f64>, basis: &DMatrix<f64>) {
    let q = basis.clone().svd(true, false);
    let Some(u) = q.u else { return };
    let top = q.singular_values.iter().copied().fold(0.0, f64::max);
    for k in (0..q.singular_values.len()).filter(|&k| q.singular_values[k] > 1e-12 * top) {
        let uk = u.column(k);
        for c in 0..m.ncols() {
            let dot = uk.dot(&m.column(c));
            m.column_mut(c).axpy(-dot, &uk, 1.0);
        }
    }
}

/// Row-major copy of a matrix.
fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    m.transpose().as_slice().to_vec()
}

/// The arm columns (raw, and with every session's own columns projected out per session, then
/// the probe rotation's over all sessions), row-major with the arm's columns, from the session
/// factors: the column geometry of the full Jacobian's arm columns.
fn projected_arm_columns(problem: &Problem, factors: &[SessionFactor]) -> (Vec<f64>, Vec<f64>) {
    let a = problem.params.len();
    let t = if problem.tool_rotation.is_some() { 3 } else { 0 };
    let rows: usize = factors.iter().map(|f| f.r.nrows()).sum();
    let (mut raw, mut projected, mut rotation) =
        (DMatrix::zeros(rows, a), DMatrix::zeros(rows, a), DMatrix::zeros(rows, t));
    let mut at = 0;
    for f in factors {
        let m = f.r.nrows();
        let own = f.r.columns(0, f.own).into_owned();
        let mut rest = f.r.columns(f.own, a + t).into_owned();
        raw.rows_mut(at, m).copy_from(&rest.columns(0, a));
        project_out(&mut rest, &own);
        projected.rows_mut(at, m).copy_from(&rest.columns(0, a));
        rotation.rows_mut(at, m).copy_from(&rest.columns(a, t));
        at += m;
    }
    if t > 0 {
        project_out(&mut projected, &rotation);
    }
    (row_major(&raw), row_major(&projected))
}

/// The rows and weights of a calibration, shared by the problems of its passes.
struct Layout {
    floated: Vec<Option<usize>>,
    rows: Vec<(usize, usize)>,
    oriented: Vec<(usize, usize)>,
    weight: f64,
    drifting: Vec<Option<DriftSlot>>,
}

impl Layout {
    fn problem<'a>(
        &self,
        params: Vec<ParamId>,
        model: &'a ArmModel,
        data: &'a TrackerData,
        bases: &[Base],
        tool_rotation: Option<Matrix3<f64>>,
    ) -> Problem<'a> {
        Problem {
            model,
            columns: ColumnMap::new(&params),
            params,
            sessions: &data.sessions,
            start: bases.iter().map(|b| b.rotation).collect(),
            floated: self.floated.clone(),
            rows: self.rows.clone(),
            oriented: self.oriented.clone(),
            tool_rotation,
            orientation_weight_mm_per_rad: self.weight,
            drifting: self.drifting.clone(),
        }
    }
}

/// Calibrate the free parameters of `nominal` (and its tool point) on tracker sessions.
pub fn calibrate_tracker(
    nominal: &ArmModel,
    data: &TrackerData,
    options: &TrackerOptions,
) -> Result<TrackerCalibration, TrackerError> {
    if data.joints != nominal.joints.len() {
        return Err(TrackerError::JointCount { data: data.joints, model: nominal.joints.len() });
    }
    for s in &data.sessions {
        if s.points.len() < 3 {
            return Err(TrackerError::TooFewPoints {
                path: s.path.display().to_string(),
                session: s.name.clone(),
                points: s.points.len(),
            });
        }
    }
    for name in &options.float_tool {
        if !data.sessions.iter().any(|s| &s.name == name) {
            return Err(TrackerError::UnknownSession(name.clone()));
        }
    }
    let mut model = nominal.clone();
    for k in 0..3 {
        if !model.free.iter().any(|f| f.id == ParamId::Tcp(k)) {
            let v = model.tcp_mm[k];
            model.free_param(ParamId::Tcp(k), v - TOOL_HALF_RANGE_MM, v + TOOL_HALF_RANGE_MM);
        }
    }
    let all: Vec<ParamId> = model.free.iter().map(|f| f.id).collect();
    let range_of =
        |id: ParamId| model.free.iter().find(|f| f.id == id).map_or(1.0, |f| (f.upper - f.lower).max(1e-9));
    // Per session, its index among the named sessions (their own columns), if named.
    let numbered = |names: &[String]| -> Vec<Option<usize>> {
        let mut next = 0;
        data.sessions
            .iter()
            .map(|s| {
                names.contains(&s.name).then(|| {
                    next += 1;
                    next - 1
                })
            })
            .collect()
    };
    let floated = numbered(&options.float_tool);
    let rows: Vec<(usize, usize)> = data
        .sessions
        .iter()
        .enumerate()
        .flat_map(|(s, ss)| (0..ss.points.len()).map(move |k| (s, k)))
        .collect();
    let oriented: Vec<(usize, usize)> =
        rows.iter().copied().filter(|&(s, k)| data.sessions[s].points[k].orientation.is_some()).collect();
    let zero = Vector3::zeros();
    let start_bases: Vec<Base> = data.sessions.iter().map(|s| Base::fit(&model, &s.points, &zero)).collect();
    let mut tool_rotation = start_tool_rotation(&model, data, &start_bases, &oriented);
    let weight = orientation_weight_mm_per_rad(data, options);
    let drifting = drift_slots(data, &options.drift_sessions)?;
    let layout = Layout { floated: floated.clone(), rows: rows.clone(), oriented, weight, drifting };
    let x_of = |problem: &Problem,
                model: &ArmModel,
                bases: &[Base],
                offsets: &[Vector3<f64>],
                drifts: &[Vec<f64>]| {
        let mut x: Vec<f64> = problem.params.iter().map(|id| model.get(*id)).collect();
        for b in bases {
            x.extend([0.0, 0.0, 0.0, b.translation_mm.x, b.translation_mm.y, b.translation_mm.z]);
        }
        for (s, f) in floated.iter().enumerate() {
            if f.is_some() {
                x.extend(offsets[s].iter());
            }
        }
        if problem.tool_rotation.is_some() {
            x.extend([0.0; 3]);
        }
        for (s, drift) in drifts.iter().enumerate() {
            if let Some((_, d)) = problem.drift_column(s) {
                x.extend((0..d.kind.unknowns()).map(|k| drift.get(k).copied().unwrap_or(0.0)));
            }
        }
        x
    };
    // Identifiability at the nominal values, bases at their closed form.
    let full = layout.problem(all.clone(), &model, data, &start_bases, tool_rotation);
    let unknowns = full.unknowns();
    if full.len() < unknowns {
        return Err(TrackerError::TooFewResiduals { residuals: full.len(), unknowns });
    }
    let offsets0 = vec![Vector3::zeros(); data.sessions.len()];
    let x0 = x_of(&full, &model, &start_bases, &offsets0, &vec![Vec::new(); data.sessions.len()]);
    let factors = session_factors(&full, &x0).ok_or(TrackerError::NonFinite)?;
    let (raw, projected) = projected_arm_columns(&full, &factors);
    let ranges: Vec<f64> = all.iter().map(|&id| range_of(id)).collect();
    let (kept, _) = identify::base_columns(&projected, all.len(), &ranges);
    let analysis = identify::analyse(&projected, &all, &ranges);
    let spreads: Vec<(String, f64)> =
        data.sessions.iter().map(|s| (s.name.clone(), orientation_spread_deg(&model, s))).collect();
    // No session turns the tool: its point is the bases' translation, whatever a small model
    // error makes the Jacobian say; it stays at its nominal value.
    let tool_turns = spreads.iter().any(|s| s.1 >= CONSTANT_ORIENTATION_DEG);
    let is_tool = |c: &usize| matches!(all[*c], ParamId::Tcp(_));
    let estimated: Vec<ParamId> =
        kept.iter().filter(|c| tool_turns || !is_tool(c)).map(|&c| all[c]).collect();
    let fixed: Vec<ParamId> =
        (0..all.len()).filter(|c| !estimated.contains(&all[*c])).map(|c| all[c]).collect();
    let statements = explain(&all, &raw, &projected, &full, &fixed, &spreads, &ranges);
    // Solve; re-centre the bases at their closed form between passes.
    let loss = options.huber_delta_mm.map_or(Loss::Linear, Loss::Huber);
    let solver_options =
        SolverOptions { loss, max_iterations: 100, ftol: 1e-10, xtol: 1e-10, ..SolverOptions::default() };
    let mut current = model.clone();
    let mut bases = start_bases;
    let mut offsets = offsets0.clone();
    let mut drifts = vec![Vec::new(); data.sessions.len()];
    let mut iterations = 0;
    let mut last_cost = f64::INFINITY;
    for _ in 0..PASSES {
        let problem = layout.problem(estimated.clone(), &current, data, &bases, tool_rotation);
        let n = problem.unknowns();
        let x0 = x_of(&problem, &current, &bases, &offsets, &drifts);
        let mut lower: Vec<f64> = estimated
            .iter()
            .map(|id| model.free.iter().find(|f| f.id == *id).map_or(f64::NEG_INFINITY, |f| f.lower))
            .collect();
        let mut upper: Vec<f64> = estimated
            .iter()
            .map(|id| model.free.iter().find(|f| f.id == *id).map_or(f64::INFINITY, |f| f.upper))
            .collect();
        lower.resize(n, -1e9);
        upper.resize(n, 1e9);
        let solution = solver::solve(&problem, &x0, &lower, &upper, &solver_options);
        iterations += solution.iterations;
        let solved = problem.model_at(&solution.x);
        offsets = (0..data.sessions.len()).map(|s| problem.tool_offset_at(&solution.x, s)).collect();
        bases = (0..data.sessions.len()).map(|s| problem.base_at(&solution.x, s)).collect();
        tool_rotation = tool_rotation.map(|_| problem.tool_rotation_at(&solution.x));
        drifts = (0..data.sessions.len()).map(|s| problem.drift_at(&solution.x, s).to_vec()).collect();
        current = solved;
        let converged = (last_cost - solution.cost).abs() <= 1e-9 * solution.cost.max(1e-12);
        last_cost = solution.cost;
        if converged {
            break;
        }
    }
    // Uncertainty at the solution (bases and floated tools marginalised).
    let problem = layout.problem(estimated.clone(), &current, data, &bases, tool_rotation);
    let x = x_of(&problem, &current, &bases, &offsets, &drifts);
    let mut r = vec![0.0; problem.len()];
    let (normal, _) = problem.normal_equations(&x, &mut r, Loss::Linear);
    let n = problem.unknowns();
    let dof = (r.len() as f64 - n as f64).max(1.0);
    let variance = r.iter().map(|v| v * v).sum::<f64>() / dof;
    let cov = identify::covariance_of_normal(normal, variance);
    let (position_rows, orientation_rows) = r.split_at(3 * problem.rows.len());
    let errors: Vec<f64> =
        position_rows.chunks_exact(3).map(|e| Vector3::new(e[0], e[1], e[2]).norm()).collect();
    let angles_deg: Vec<f64> = orientation_rows
        .chunks_exact(3)
        .map(|e| (Vector3::new(e[0], e[1], e[2]).norm() / weight).to_degrees())
        .collect();
    let tool_rotation = problem.tool_rotation_column().zip(tool_rotation).map(|(c, rotation)| ToolRotation {
        rotation_vector_deg: rotation_vector(&rotation).map(f64::to_degrees).into(),
        std_deg: cov
            .as_ref()
            .map(|m| [0, 1, 2].map(|k| (m[(c + k, c + k)].max(0.0).sqrt() * 1e-3).to_degrees())),
    });
    let estimates = all
        .iter()
        .map(|&id| {
            let k = estimated.iter().position(|e| *e == id);
            TrackerEstimate {
                param: id.to_string(),
                unit: id.unit().into(),
                nominal: nominal.get(id),
                value: current.get(id),
                std: k.and_then(|k| cov.as_ref().map(|c| c[(k, k)].max(0.0).sqrt())),
            }
        })
        .collect();
    // A floated session's tool offset with the deviation of its length.
    let own = |column: &dyn Fn(usize) -> Option<usize>,
               values: &[Vector3<f64>]|
     -> Vec<(String, Vector3<f64>, f64)> {
        data.sessions
            .iter()
            .enumerate()
            .filter_map(|(s, session)| {
                let c = column(s)?;
                Some((session.name.clone(), values[s], length_std(&values[s], &covariance_block(&cov, c))))
            })
            .collect()
    };
    let tool_offsets = own(&|s| problem.tool_column(s), &offsets)
        .into_iter()
        .map(|(session, v, std)| FloatedTool { session, offset_mm: v.into(), size_std_mm: std })
        .collect();
    let drifts = data
        .sessions
        .iter()
        .enumerate()
        .filter_map(|(s, session)| {
            let (c, d) = problem.drift_column(s)?;
            let rate = drifts[s].clone();
            let rate_std = if d.kind.is_scale() {
                cov.as_ref().map_or(0.0, |m| m[(c, c)].max(0.0).sqrt())
            } else {
                length_std(&Vector3::from_column_slice(&rate), &covariance_block(&cov, c))
            };
            Some(SessionDrift {
                session: session.name.clone(),
                kind: d.kind,
                rate,
                rate_std,
                unit: d.kind.unit().into(),
                centre: d.centre,
            })
        })
        .collect();
    Ok(TrackerCalibration {
        model: current,
        bases,
        tool_offsets,
        drifts,
        fit: ErrorStats::of(&errors),
        orientation_fit: tool_rotation.as_ref().map(|_| AngleStats::of(&angles_deg)),
        tool_rotation,
        estimates,
        identifiability: TrackerIdentifiability {
            estimated: estimated.iter().map(|p| p.to_string()).collect(),
            fixed: fixed.iter().map(|p| p.to_string()).collect(),
            statements,
            unidentifiable: analysis.unidentifiable,
            poorly_identified: analysis.poorly_identified,
            orientation_spread_deg: spreads,
        },
        iterations,
    })
}

/// Sentences on what the data cannot separate; `raw` and `projected` are the arm columns
/// before and after the bases are projected out (row-major, `all.len()` columns).
fn explain(
    all: &[ParamId],
    raw: &[f64],
    projected: &[f64],
    problem: &Problem,
    fixed: &[ParamId],
    spreads: &[(String, f64)],
    ranges: &[f64],
) -> Vec<String> {
    let a = all.len();
    let probe_turns = problem.tool_rotation.is_some();
    let norm = |m: &[f64], stride: usize, c: usize| {
        m.chunks_exact(stride).map(|row| row[c] * row[c]).sum::<f64>().sqrt()
    };
    let mut out = Vec::new();
    let constant: Vec<&str> =
        spreads.iter().filter(|s| s.1 < CONSTANT_ORIENTATION_DEG).map(|s| s.0.as_str()).collect();
    let tool_fixed: Vec<String> =
        fixed.iter().filter(|p| matches!(p, ParamId::Tcp(_))).map(|p| p.to_string()).collect();
    if !constant.is_empty() {
        out.push(format!(
            "the tool orientation is constant (within {CONSTANT_ORIENTATION_DEG}°) in session{} {}: there, the \
             tool point and the base translation are one thing{}",
            if constant.len() == 1 { "" } else { "s" },
            constant.join(", "),
            if probe_turns {
                " (the probe's orientations do not separate them: R_s·R_F·t is one constant vector there)"
            } else {
                ""
            }
        ));
    }
    if !tool_fixed.is_empty() {
        out.push(format!(
            "{} cannot be separated from the session bases' translations (no session turns the tool): held at \
             the nominal value; no figure depends on this split, each session's base absorbs it",
            tool_fixed.join(", ")
        ));
    }
    let largest = (0..a).map(|c| norm(raw, a, c) * ranges[c]).fold(0.0, f64::max).max(1e-300);
    for p in fixed.iter().filter(|p| !matches!(p, ParamId::Tcp(_))) {
        let Some(c) = all.iter().position(|q| q == p) else { continue };
        let (raw, rest) = (norm(raw, a, c) * ranges[c], norm(projected, a, c) * ranges[c]);
        out.push(if raw < identify::ZERO_COLUMN_BELOW * largest {
            format!("{p} moves no measured point: held at its nominal value")
        } else if rest < identify::UNIDENTIFIABLE_BELOW * largest && probe_turns {
            format!(
                "{p} is absorbed by the session bases and the probe's orientation on the flange (a base rotation or \
                 shift, or a turn of the probe with the tool point, reproduces it): held at its nominal value"
            )
        } else if rest < identify::UNIDENTIFIABLE_BELOW * largest {
            format!("{p} is absorbed by the session bases (a base rotation or shift reproduces it): held at its nominal value")
        } else {
            format!("{p} cannot be separated from the other free parameters on this data: held at its nominal value")
        });
    }
    out
}

/// Validation of a model on one held-out session, its base refitted (closed form).
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
    /// Largest position error, mm.
    pub max_mm: f64,
    /// RMS of the base-free pairwise-distance error inside the session, mm.
    pub pairwise_rms_mm: f64,
    /// Pairs of points compared.
    pub pairs: usize,
}

/// Position error of every calibration point at the solution, per session in file order, mm.
pub fn calibration_errors(fit: &TrackerCalibration, data: &TrackerData) -> Vec<Vec<f64>> {
    calibration_residuals_mm(fit, data)
        .into_iter()
        .map(|session| session.iter().map(|r| r.norm()).collect())
        .collect()
}

/// Residual of every calibration point at the solution, per session in file order: measured −
/// predicted (its session's fitted base, tool offset and drift), in the robot's base frame, mm.
pub fn calibration_residuals_mm(fit: &TrackerCalibration, data: &TrackerData) -> Vec<Vec<Vector3<f64>>> {
    data.sessions
        .iter()
        .zip(&fit.bases)
        .map(|(s, base)| residuals_with_base(fit, &s.name, base, &s.points))
        .collect()
}

/// Position errors, mm, of `points` measured from calibration session `session`'s instrument
/// placement (protocol S: a held-out set of the same session), with that session's calibrated
/// base, its floated tool and its drift; `None` when `session` is not a calibration session.
pub fn errors_in_calibration_session(
    fit: &TrackerCalibration,
    data: &TrackerData,
    session: &str,
    points: &[TrackerPoint],
) -> Option<Vec<f64>> {
    let s = data.sessions.iter().position(|s| s.name == session)?;
    Some(residuals_with_base(fit, session, fit.bases.get(s)?, points).iter().map(|r| r.norm()).collect())
}

/// Residuals (measured − predicted, robot base frame, mm) of `points` with `base` and the tool
/// offset and drift `fit` gives session `name`.
fn residuals_with_base(
    fit: &TrackerCalibration,
    name: &str,
    base: &Base,
    points: &[TrackerPoint],
) -> Vec<Vector3<f64>> {
    let offset = fit
        .tool_offsets
        .iter()
        .find(|t| t.session == name)
        .map_or(Vector3::zeros(), |t| Vector3::from(t.offset_mm));
    let drift = fit.drifts.iter().find(|d| d.session == name);
    points
        .iter()
        .map(|p| {
            let (shift, growth) = drift.map_or((Vector3::zeros(), 1.0), |d| d.effect_at(p));
            let y = base.rotation * model_point(&fit.model, &p.q_deg, &offset);
            base.rotation.transpose() * (p.point_mm - (y * growth + base.translation_mm + shift))
        })
        .collect()
}

/// Fit `session`'s base and its own tool offset for a fixed `model` (the tool floated there),
/// and validate with both refitted.
pub fn fit_session_with_tool(model: &ArmModel, session: &TrackerSession) -> (FloatedTool, SessionValidation) {
    let sessions = std::slice::from_ref(session);
    let start = Base::fit(model, &session.points, &Vector3::zeros());
    let problem = Problem {
        model,
        params: Vec::new(),
        columns: ColumnMap::new(&[]),
        sessions,
        start: vec![start.rotation],
        floated: vec![Some(0)],
        rows: (0..session.points.len()).map(|k| (0, k)).collect(),
        oriented: Vec::new(),
        tool_rotation: None,
        orientation_weight_mm_per_rad: 0.0,
        drifting: vec![None],
    };
    let t = start.translation_mm;
    let x0 = [0.0, 0.0, 0.0, t.x, t.y, t.z, 0.0, 0.0, 0.0];
    let options = SolverOptions { max_iterations: 100, ..SolverOptions::default() };
    let solution = solver::solve(&problem, &x0, &[-1e9; 9], &[1e9; 9], &options);
    let mut r = vec![0.0; problem.len()];
    let (normal, _) = problem.normal_equations(&solution.x, &mut r, Loss::Linear);
    let variance = r.iter().map(|v| v * v).sum::<f64>() / (r.len() as f64 - 9.0).max(1.0);
    let cov = identify::covariance_of_normal(normal, variance);
    let offset = problem.tool_offset_at(&solution.x, 0);
    let tool = FloatedTool {
        session: session.name.clone(),
        offset_mm: offset.into(),
        size_std_mm: length_std(&offset, &covariance_block(&cov, 6)),
    };
    (tool, validate_session(model, session, offset.into()))
}

/// Orientation errors of `model` with the probe rotation `tool_rotation` on `session`, its base
/// refitted from the positions (closed form); `None` when the session has no orientations.
pub fn validate_orientations(
    model: &ArmModel,
    session: &TrackerSession,
    tool_offset_mm: [f64; 3],
    tool_rotation: &Matrix3<f64>,
) -> Option<AngleStats> {
    let angles_deg: Vec<f64> =
        orientation_errors_deg(model, session, tool_offset_mm, tool_rotation).into_iter().flatten().collect();
    (!angles_deg.is_empty()).then(|| AngleStats::of(&angles_deg))
}

/// The orientation error (angle of R_predᵀ·R_meas, degrees) of every point of `session`, its
/// base refitted from the positions (closed form); `None` for a row without an orientation.
pub fn orientation_errors_deg(
    model: &ArmModel,
    session: &TrackerSession,
    tool_offset_mm: [f64; 3],
    tool_rotation: &Matrix3<f64>,
) -> Vec<Option<f64>> {
    let base = Base::fit(model, &session.points, &Vector3::from(tool_offset_mm));
    session
        .points
        .iter()
        .map(|p| {
            let measured = p.orientation?.to_rotation_matrix().into_inner();
            let pose = tool_pose(model, &p.q_deg);
            let predicted = base.rotation * flange_rotation(&pose.x_axis, &pose.z_axis) * tool_rotation;
            Some(rotation_vector(&(predicted.transpose() * measured)).norm().to_degrees())
        })
        .collect()
}

/// The residual of every point of `session` for `model`, its base refitted (closed form):
/// measured − predicted, rotated into the robot's base frame so that sessions compare, mm. Its
/// lengths are the errors [`validate_session`] summarises.
pub fn session_residuals_mm(
    model: &ArmModel,
    session: &TrackerSession,
    tool_offset_mm: [f64; 3],
) -> Vec<Vector3<f64>> {
    let tool_offset_mm = &Vector3::from(tool_offset_mm);
    let base = Base::fit(model, &session.points, tool_offset_mm);
    session
        .points
        .iter()
        .map(|p| {
            base.rotation.transpose()
                * (p.point_mm - base.apply(&model_point(model, &p.q_deg, tool_offset_mm)))
        })
        .collect()
}

/// Most points of a session whose pairwise distances are compared (evenly spaced beyond).
pub const MAX_PAIRWISE_POINTS: usize = 2000;

/// Position error of every point of `session` for `model`, its base refitted (closed form), in
/// file order, mm.
pub fn session_residuals(
    model: &ArmModel,
    session: &TrackerSession,
    tool_offset_mm: [f64; 3],
) -> Vec<Vector3<f64>> {
    let offset = &Vector3::from(tool_offset_mm);
    let base = Base::fit(model, &session.points, offset);
    session.points.iter().map(|p| base.apply(&model_point(model, &p.q_deg, offset)) - p.point_mm).collect()
}

/// Lengths of [`session_residuals`], mm.
pub fn session_errors(model: &ArmModel, session: &TrackerSession, tool_offset_mm: [f64; 3]) -> Vec<f64> {
    session_residuals(model, session, tool_offset_mm).iter().map(|r| r.norm()).collect()
}

/// Errors of `model` on `session` with the base refitted (closed form), and the pairwise figures.
pub fn validate_session(
    model: &ArmModel,
    session: &TrackerSession,
    tool_offset_mm: [f64; 3],
) -> SessionValidation {
    let offset = &Vector3::from(tool_offset_mm);
    let robot: Vec<Vector3<f64>> =
        session.points.iter().map(|p| model_point(model, &p.q_deg, offset)).collect();
    let errors = session_errors(model, session, tool_offset_mm);
    let stats = ErrorStats::of(&errors);
    let step = session.points.len().div_ceil(MAX_PAIRWISE_POINTS).max(1);
    let picked: Vec<usize> = (0..session.points.len()).step_by(step).collect();
    let mut sum = 0.0;
    let mut pairs = 0usize;
    for (k, &a) in picked.iter().enumerate() {
        for &b in &picked[k + 1..] {
            let e = (robot[a] - robot[b]).norm()
                - (session.points[a].point_mm - session.points[b].point_mm).norm();
            sum += e * e;
            pairs += 1;
        }
    }
    SessionValidation {
        name: session.name.clone(),
        points: stats.points,
        rms_mm: stats.rms_mm,
        mean_mm: stats.mean_mm,
        max_mm: stats.max_mm,
        pairwise_rms_mm: if pairs > 0 { (sum / pairs as f64).sqrt() } else { 0.0 },
        pairs,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Joint;

    /// A 7-joint arm with lengths and twists free (consistency of the solver with its own
    /// kinematics only; accuracy is tested on the independent generator in `tests/`).
    fn arm() -> ArmModel {
        let alpha = [-90.0, 90.0, -90.0, 90.0, -90.0, 90.0, 0.0];
        let d = [340.0, 0.0, 400.0, 0.0, 400.0, 0.0, 126.0];
        let mut model = ArmModel::suta_nominal();
        model.joints =
            (0..7).map(|j| Joint { d_mm: d[j], alpha_deg: alpha[j], ..Joint::default() }).collect();
        model.tcp_mm = [10.0, 20.0, 80.0];
        model.free.clear();
        for (j, dj) in d.iter().enumerate() {
            model.free_param(ParamId::Offset(j), -5.0, 5.0);
            model.free_param(ParamId::Length(j), dj - 10.0, dj + 10.0);
        }
        model
    }

    fn sessions(truth: &ArmModel) -> TrackerData {
        let mut sessions = Vec::new();
        for s in 0..3 {
            let base = Base {
                rotation: Rotation3::from_euler_angles(0.1 * s as f64, -0.05, 0.3 * s as f64).into_inner(),
                translation_mm: Vector3::new(2000.0, -500.0 * s as f64, 300.0),
            };
            let points = (0..40)
                .map(|i| {
                    let f = (i + 40 * s) as f64;
                    let q: Vec<f64> = (0..7).map(|j| 60.0 * (0.37 * f * (j + 1) as f64).sin()).collect();
                    TrackerPoint {
                        point_mm: base.apply(&tool_pose(truth, &q).position_mm),
                        q_deg: q,
                        orientation: None,
                        sigma_mm: None,
                        time_s: None,
                        temp_c: None,
                        pose: None,
                        line: i + 3,
                    }
                })
                .collect();
            sessions.push(TrackerSession { name: format!("s{s}"), path: "s.csv".into(), points });
        }
        TrackerData { joints: 7, sessions, warnings: vec![] }
    }

    #[test]
    fn noise_free_points_of_its_own_kinematics_are_fitted_exactly() {
        let nominal = arm();
        let mut truth = nominal.clone();
        truth.joints[2].d_mm += 1.5;
        truth.joints[3].offset_deg += 0.2;
        truth.tcp_mm[2] += 2.0;
        let data = sessions(&truth);
        let fit = calibrate_tracker(&nominal, &data, &TrackerOptions::default()).unwrap();
        assert!(fit.fit.rms_mm < 1e-6, "{:?}", fit.fit);
        let ident = &fit.identifiability;
        assert!(ident.fixed.contains(&"offset:1".to_string()), "{ident:?}");
        assert!(
            ident.statements.iter().any(|s| s.contains("offset:1 is absorbed by the session bases")),
            "{ident:?}"
        );
        let v = validate_session(&fit.model, &data.sessions[1], [0.0; 3]);
        assert!(v.rms_mm < 1e-6 && v.pairwise_rms_mm < 1e-6, "{v:?}");
    }
}
