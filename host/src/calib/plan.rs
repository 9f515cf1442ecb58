//! What to measure next: artefact placements that separate two rival explanations, or that pin
//! down the weakest parameters, chosen from placements the arm can reach.
//!
//! **Linearised model of a placement.** Each touch's tool point p(β) moves with the parameters
//! by J = ∂p/∂β (3 rows per touch). A placement (one repeat) also has an unknown rigid pose: its
//! six columns N (translation, rotation about the touches' centroid) are projected out,
//! X = (I − N N⁺) J, so only what the artefact's certified geometry can see remains. Noise is σ
//! per axis per touch (the repeatability floor). Every parameter has a prior std of its
//! half-range (its bounds), so parameters the data cannot see keep a finite, honest variance.
//!
//! **Separating rivals A and B** (linearised T-optimal design). With δ̂_A fitted on the data
//! so far (least squares of the touch residuals on [X_M X_A]), A predicts the signal
//! s_A = X_A·δ̂_A. The separability
//! λ_AB = min_γ ‖s_A − [X_M X_B]·γ‖² (+ the prior on γ)
//! is what B cannot mimic if A is the cause, in σ² once divided by σ². With A, B swapped,
//! λ_BA. Placements are added greedily, each maximising (λ_AB + λ_BA)/σ² on the old and new
//! data together (the expected separation with either rival the cause; the minimum of the two
//! chases the rival whose fitted size is smallest, which matters least, and averaging λ over the
//! phase of the fitted parameters separated less in `kincal bench --plan`): the normal equations G = ΣXᵀX, b = ΣXᵀs, c = Σsᵀs are sums over
//! placements, so a candidate adds its rows' terms and λ = c − bᵀG⁻¹b (a rank-3n update).
//!
//! **Weak parameters** (D-optimal design). The information of the calibration data
//! F = ΣXᵀX/σ² + prior; a candidate placement gains log det(I + X F⁻¹ Xᵀ/σ²)
//! = log det(F + XᵀX/σ²) − log det F. Greedy, F updated after each pick. The weakest parameter
//! is the one whose one-std error moves the touches most after the rigid registration
//! (std × RMS of its projected column), in mm.
//!
//! Candidates: artefact placements on a grid over the arm's table (origins, heights 0 / 110 /
//! 220 mm, yaws), each landmark posed by the inverse kinematics of [`crate::simulate`] on the
//! calibrated arm (random configuration per touch, seeded), kept when at least
//! [`MIN_TOUCHES`] landmarks are reachable with every joint above the table.

use crate::calib::diagnose::diagnose;
use crate::calib::fit::{calibrate, CalibError, Fit};
use crate::calib::setup::SolveOptions;
use crate::data::{Artefact, Joints, Observation, Observations, Session, SESSION_FORMAT};
use crate::model::effects::{default_half_range, Effect};
use crate::model::kinematics::{tool_pose, tool_pose_with_jacobian, ColumnMap};
use crate::model::{ArmModel, ParamId};
use crate::simulate::{touch_encoders, Placement, SimulatedData, SimulationOptions};
use nalgebra::{DMatrix, DVector, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Fewest reachable landmarks for a candidate placement.
pub const MIN_TOUCHES: usize = 6;
/// Separability (in σ²) below which two rivals count as equivalent on the data (the review's
/// rule of thumb: a χ²₁ noncentrality of 13 gives a 5 %-level test about 95 % power).
pub const SEPARABLE_SIGMA2: f64 = 13.0;

/// Why a plan could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// A rival is not an effect of the library.
    #[error("--rivals: \"{0}\" is not an effect (e.g. compliance:3, harmonic:3:3, eccentricity:5)")]
    UnknownEffect(String),
    /// A rival is already in the model.
    #[error("--rivals: {0} is already in the model: a rival must be an effect the model lacks")]
    AlreadyIn(String),
    /// Two rivals are needed.
    #[error("--rivals takes two different effects, A,B (got {0})")]
    NotAPair(usize),
    /// No candidate placement is reachable.
    #[error(
        "no candidate placement of the artefact is reachable by this arm (at least {MIN_TOUCHES} landmarks)"
    )]
    NothingReachable,
    /// The noise level is not a positive number.
    #[error("the touch noise must be a positive number of mm, got {0}")]
    BadNoise(f64),
}

/// A candidate placement of the artefact and the touches the arm would make there.
#[derive(Clone, Debug)]
pub struct CandidatePlacement {
    /// Where the artefact goes.
    pub placement: Placement,
    /// (landmark index, encoder angles deg) per reachable landmark.
    pub touches: Vec<(usize, Joints)>,
}

/// Artefact placements over the arm's table, each with the touches the arm can reach there.
pub fn candidate_placements(model: &ArmModel, artefact: &Artefact, seed: u64) -> Vec<CandidatePlacement> {
    let mut grid = Vec::new();
    for (ix, x) in [362.5, 437.5, 512.5, 587.5, 662.5].into_iter().enumerate() {
        for (iy, y) in [-187.5, -87.5, 12.5, 112.5, 212.5].into_iter().enumerate() {
            for (iz, z) in [0.0, 110.0, 220.0].into_iter().enumerate() {
                for (iw, yaw) in [-30.0, 0.0, 30.0].into_iter().enumerate() {
                    let name = format!("P{ix}{iy}{iz}{iw}");
                    grid.push(Placement { name, origin_mm: [x, y, z], yaw_deg: yaw });
                }
            }
        }
    }
    grid.into_par_iter()
        .enumerate()
        .filter_map(|(k, placement)| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
            let touches: Vec<(usize, Joints)> = artefact
                .landmarks
                .iter()
                .enumerate()
                .filter_map(|(l, landmark)| {
                    touch_encoders(model, &placement, landmark, Vector3::zeros(), &mut rng)
                        .and_then(|e| Joints::new(&e))
                        .map(|e| (l, e))
                })
                .collect();
            (touches.len() >= MIN_TOUCHES).then_some(CandidatePlacement { placement, touches })
        })
        .collect()
}

/// The projected rows of one rigid block (3 per touch) for `params`, in scaled columns
/// (column × scale).
fn block_rows(model: &ArmModel, params: &[ParamId], scale: &[f64], encs: &[Joints]) -> DMatrix<f64> {
    let columns = ColumnMap::new(params);
    let n = encs.len();
    let mut j = DMatrix::zeros(3 * n, params.len());
    let mut points = Vec::with_capacity(n);
    let mut jac = vec![[0.0; 9]; params.len()];
    for (i, enc) in encs.iter().enumerate() {
        let pose = tool_pose_with_jacobian(model, enc, &columns, &mut jac);
        points.push(pose.position_mm);
        for (c, d) in jac.iter().enumerate() {
            for k in 0..3 {
                j[(3 * i + k, c)] = d[k] * scale[c];
            }
        }
    }
    project_rigid(&points, j)
}

/// Project the six rigid-motion columns (translation, rotation about the centroid) out of `j`.
fn project_rigid(points: &[Vector3<f64>], j: DMatrix<f64>) -> DMatrix<f64> {
    let n = points.len();
    let centroid = points.iter().sum::<Vector3<f64>>() / n.max(1) as f64;
    let mut nuisance = DMatrix::zeros(3 * n, 6);
    for (i, p) in points.iter().enumerate() {
        let q = (p - centroid) / 100.0;
        for k in 0..3 {
            nuisance[(3 * i + k, k)] = 1.0;
        }
        // ω × q for ω = e_x, e_y, e_z.
        let rot = [Vector3::new(0.0, -q.z, q.y), Vector3::new(q.z, 0.0, -q.x), Vector3::new(-q.y, q.x, 0.0)];
        for (c, v) in rot.iter().enumerate() {
            for k in 0..3 {
                nuisance[(3 * i + k, 3 + c)] = v[k];
            }
        }
    }
    let q = nuisance.qr().q();
    let qtj = q.transpose() * &j;
    j - q * qtj
}

/// Residuals (3 per touch) of `model` after a rigid fit of the artefact to each block's touches.
fn rigid_residuals(model: &ArmModel, artefact: &Artefact, touches: &[&Observation]) -> Option<DVector<f64>> {
    if touches.len() < 3 {
        return None;
    }
    let p: Vec<Vector3<f64>> = touches.iter().map(|t| tool_pose(model, &t.q_deg).position_mm).collect();
    let q: Vec<Vector3<f64>> =
        touches.iter().map(|t| Vector3::from(artefact.landmarks[t.touched()].xyz_mm)).collect();
    let frame = crate::calib::nuisance::frame::Frame::fit(&q, &p);
    Some(DVector::from_iterator(
        3 * p.len(),
        p.iter().zip(&q).flat_map(|(p, q)| {
            let e = p - frame.apply(q);
            [e.x, e.y, e.z]
        }),
    ))
}

/// Touches of `data` grouped by (placement, repeat): one rigid block each.
fn blocks(data: &Observations) -> Vec<Vec<&Observation>> {
    data.blocks
        .iter()
        .map(|b| b.members.iter().map(|&k| &data.obs[k]).collect::<Vec<_>>())
        .filter(|b| b.len() >= 3)
        .collect()
}

/// Scale of each parameter: its half-range (bounds of a free parameter, the library default
/// otherwise), so columns are comparable and the prior is unit.
fn scales(model: &ArmModel, params: &[ParamId]) -> Vec<f64> {
    params
        .iter()
        .map(|p| match model.free.iter().find(|f| f.id == *p) {
            Some(f) => (0.5 * (f.upper - f.lower)).max(1e-9),
            None => default_half_range(*p).max(1e-9),
        })
        .collect()
}

/// The angle range a joint passes over some touches (the shorter arc that holds them all), deg.
pub fn joint_range_deg(angles: &[f64]) -> (f64, f64) {
    let mut a: Vec<f64> = angles.iter().map(|x| x.rem_euclid(360.0)).collect();
    a.sort_by(f64::total_cmp);
    if a.is_empty() {
        return (0.0, 0.0);
    }
    // The largest gap between neighbours (with the wrap) is where the range does not go.
    let mut gap = (360.0 - a[a.len() - 1] + a[0], a.len() - 1);
    for k in 0..a.len() - 1 {
        if a[k + 1] - a[k] > gap.0 {
            gap = (a[k + 1] - a[k], k);
        }
    }
    let start = a[(gap.1 + 1) % a.len()];
    let end = a[gap.1];
    (start, if end < start { end + 360.0 } else { end })
}

/// One suggested placement.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SuggestedPlacement {
    /// Artefact origin in the arm's base frame, mm.
    pub origin_mm: [f64; 3],
    /// Artefact yaw about the base z axis, deg.
    pub yaw_deg: f64,
    /// Landmarks to touch (reachable there).
    pub landmarks: Vec<String>,
    /// (joint 1-based, from deg, to deg) each joint passes over these touches.
    pub joint_ranges_deg: Vec<(usize, f64, f64)>,
    /// Encoder angles of each touch, deg (the pose list).
    pub poses_deg: Vec<Joints>,
    /// The figure of merit after this placement is added (λ_AB + λ_BA in σ², or the log det
    /// gain).
    pub merit: f64,
    /// For rivals: RMS per touch, mm, by which the second rival's best fit misses the first's
    /// prediction here (and the reverse).
    pub differ_mm: Option<(f64, f64)>,
    /// For rivals: per touch, mm, the larger of the two misses (where the explanations differ).
    pub touch_differ_mm: Vec<f64>,
}

impl SuggestedPlacement {
    /// The touches where the rivals differ by at least `share` of the largest difference here:
    /// their landmarks, and the range (from, to deg) each joint passes over them.
    pub fn where_rivals_differ(&self, share: f64) -> (Vec<String>, Vec<(usize, f64, f64)>) {
        let most = self.touch_differ_mm.iter().copied().fold(0.0, f64::max);
        let picked: Vec<usize> =
            (0..self.touch_differ_mm.len()).filter(|&k| self.touch_differ_mm[k] >= share * most).collect();
        let joints = self.poses_deg.first().map_or(0, |p| p.len());
        let ranges = (0..joints)
            .map(|j| {
                let (from, to) =
                    joint_range_deg(&picked.iter().map(|&k| self.poses_deg[k][j]).collect::<Vec<_>>());
                (j + 1, from, to)
            })
            .collect();
        (picked.iter().map(|&k| self.landmarks[k].clone()).collect(), ranges)
    }
}

/// Two rivals and how far apart the data put them.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RivalPlan {
    /// The two effects.
    pub rivals: (String, String),
    /// Separabilities λ_AB, λ_BA on the data so far, in σ².
    pub before_sigma2: (f64, f64),
    /// The same with the suggested placements added.
    pub after_sigma2: (f64, f64),
    /// Placements, in the order chosen.
    pub placements: Vec<SuggestedPlacement>,
}

/// The weakest parameters and what the suggested placements do to their std.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WeakPlan {
    /// (parameter, unit, std now, std with the placements, tip effect mm now) worst first.
    pub stds: Vec<(String, &'static str, f64, f64, f64)>,
    /// Placements, in the order chosen.
    pub placements: Vec<SuggestedPlacement>,
}

/// What `kincal plan` finds.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Plan {
    /// Touch noise per axis used, mm.
    pub touch_std_mm: f64,
    /// Candidate placements the arm can reach.
    pub candidates: usize,
    /// Placements that separate the rivals, when rivals were given.
    pub rivals: Option<RivalPlan>,
    /// Placements that pin down the weak parameters.
    pub weak: WeakPlan,
}

/// Settings of a plan.
#[derive(Clone, Debug)]
pub struct PlanOptions {
    /// Placements to suggest.
    pub count: usize,
    /// Seed of the candidate touches' arm configurations.
    pub seed: u64,
    /// Touch noise per axis, mm (from the repeatability floor).
    pub touch_std_mm: f64,
}

/// Normal equations of a least-squares problem with a unit prior, accumulated over blocks.
#[derive(Clone)]
struct Normal {
    g: DMatrix<f64>,
    b: DVector<f64>,
    c: f64,
}

impl Normal {
    fn new(n: usize, prior: f64) -> Normal {
        Normal { g: DMatrix::identity(n, n) * prior, b: DVector::zeros(n), c: 0.0 }
    }
    fn add(&mut self, x: &DMatrix<f64>, s: &DVector<f64>) {
        self.g += x.transpose() * x;
        self.b += x.transpose() * s;
        self.c += s.norm_squared();
    }
    /// min_γ ‖s − Xγ‖² + prior‖γ‖², and γ.
    fn residual(&self) -> (f64, DVector<f64>) {
        match self.g.clone().cholesky() {
            Some(ch) => {
                let gamma = ch.solve(&self.b);
                ((self.c - self.b.dot(&gamma)).max(0.0), gamma)
            }
            None => (self.c, DVector::zeros(self.b.len())),
        }
    }
}

/// Columns of one rival's explanation: the model's free parameters then the rival's.
struct Rival {
    effect: Effect,
    params: Vec<ParamId>,
}

/// Rows of a block for the union of parameters, split into the model part and each rival's.
struct BlockRows {
    model: DMatrix<f64>,
    a: DMatrix<f64>,
    b: DMatrix<f64>,
}

fn split_rows(
    model: &ArmModel,
    union: &[ParamId],
    scale: &[f64],
    m: usize,
    ra: &Rival,
    rb: &Rival,
    encs: &[Joints],
) -> BlockRows {
    let x = block_rows(model, union, scale, encs);
    let pick = |ids: &[ParamId]| {
        let cols: Vec<usize> = ids.iter().filter_map(|p| union.iter().position(|u| u == p)).collect();
        x.select_columns(cols.iter())
    };
    BlockRows { model: x.columns(0, m).into_owned(), a: pick(&ra.params), b: pick(&rb.params) }
}

fn hcat(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(a.nrows(), a.ncols() + b.ncols());
    out.columns_mut(0, a.ncols()).copy_from(a);
    out.columns_mut(a.ncols(), b.ncols()).copy_from(b);
    out
}

/// Plan placements: to separate `rivals` (when given) and to pin down the weak parameters.
/// `cal` is what the model was calibrated on; `val` is held-out data (used for the rivals).
pub fn plan(
    calibrated: &ArmModel,
    artefact: &Artefact,
    cal: &Observations,
    val: &Observations,
    rivals: Option<(&str, &str)>,
    options: &PlanOptions,
) -> Result<Plan, PlanError> {
    if !(options.touch_std_mm.is_finite() && options.touch_std_mm > 0.0) {
        return Err(PlanError::BadNoise(options.touch_std_mm));
    }
    let rivals = rivals
        .map(|(a, b)| {
            let parse = |name: &str| {
                let e = Effect::parse(name).ok_or_else(|| PlanError::UnknownEffect(name.to_string()))?;
                if e.is_in(calibrated) {
                    return Err(PlanError::AlreadyIn(name.to_string()));
                }
                Ok(e)
            };
            let (a, b) = (parse(a)?, parse(b)?);
            if a == b {
                return Err(PlanError::NotAPair(1));
            }
            Ok((a, b))
        })
        .transpose()?;
    let candidates = candidate_placements(calibrated, artefact, options.seed);
    if candidates.is_empty() {
        return Err(PlanError::NothingReachable);
    }
    let rivals = rivals.map(|(a, b)| plan_rivals(calibrated, artefact, cal, val, a, b, &candidates, options));
    let weak = plan_weak(calibrated, artefact, cal, &candidates, options);
    Ok(Plan { touch_std_mm: options.touch_std_mm, candidates: candidates.len(), rivals, weak })
}

/// RMS over touches of a 3-rows-per-touch vector, mm.
fn rms_per_touch(v: &DVector<f64>) -> f64 {
    (v.norm_squared() / (v.len() / 3).max(1) as f64).sqrt()
}

fn suggestion(
    c: &CandidatePlacement,
    artefact: &Artefact,
    merit: f64,
    differ: Option<(DVector<f64>, DVector<f64>)>,
) -> SuggestedPlacement {
    let encs: Vec<Joints> = c.touches.iter().map(|t| t.1).collect();
    SuggestedPlacement {
        origin_mm: c.placement.origin_mm,
        yaw_deg: c.placement.yaw_deg,
        landmarks: c.touches.iter().map(|t| artefact.landmarks[t.0].id.clone()).collect(),
        joint_ranges_deg: (0..encs.first().map_or(0, |e| e.len()))
            .map(|j| {
                let (from, to) = joint_range_deg(&encs.iter().map(|e| e[j]).collect::<Vec<_>>());
                (j + 1, from, to)
            })
            .collect(),
        poses_deg: encs,
        merit,
        differ_mm: differ.as_ref().map(|(ab, ba)| (rms_per_touch(ab), rms_per_touch(ba))),
        touch_differ_mm: differ.map_or_else(Vec::new, |(ab, ba)| {
            (0..ab.len() / 3).map(|k| ab.rows(3 * k, 3).norm().max(ba.rows(3 * k, 3).norm())).collect()
        }),
    }
}

#[allow(clippy::too_many_arguments)]
fn plan_rivals(
    calibrated: &ArmModel,
    artefact: &Artefact,
    cal: &Observations,
    val: &Observations,
    a: Effect,
    b: Effect,
    candidates: &[CandidatePlacement],
    options: &PlanOptions,
) -> RivalPlan {
    let sigma2 = options.touch_std_mm.powi(2);
    let model_params: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
    let m = model_params.len();
    let ra = Rival { effect: a, params: a.params() };
    let rb = Rival { effect: b, params: b.params() };
    let mut union = model_params.clone();
    for p in ra.params.iter().chain(&rb.params) {
        if !union.contains(p) {
            union.push(*p);
        }
    }
    let scale = scales(calibrated, &union);
    // Old data: cal and val blocks with their residuals.
    let old: Vec<(BlockRows, DVector<f64>)> = [cal, val]
        .into_iter()
        .flat_map(blocks)
        .filter_map(|block| {
            let r = rigid_residuals(calibrated, artefact, &block)?;
            let encs: Vec<Joints> = block.iter().map(|t| t.q_deg).collect();
            Some((split_rows(calibrated, &union, &scale, m, &ra, &rb, &encs), r))
        })
        .collect();
    // δ̂ of each rival: least squares of the residuals on [X_M X_rival], prior σ² per column.
    let fitted = |rival_rows: &dyn Fn(&BlockRows) -> &DMatrix<f64>| -> DVector<f64> {
        let k = rival_rows(&old[0].0).ncols();
        let mut n = Normal::new(m + k, sigma2);
        for (rows, r) in &old {
            n.add(&hcat(&rows.model, rival_rows(rows)), r);
        }
        let (_, gamma) = n.residual();
        gamma.rows(m, k).into_owned()
    };
    let delta_a = fitted(&|r| &r.a);
    let delta_b = fitted(&|r| &r.b);
    // λ_AB: A's signal against [M B]; λ_BA: B's signal against [M A].
    let mut ab = Normal::new(m + rb.params.len(), sigma2);
    let mut ba = Normal::new(m + ra.params.len(), sigma2);
    let add = |ab: &mut Normal, ba: &mut Normal, rows: &BlockRows| {
        ab.add(&hcat(&rows.model, &rows.b), &(&rows.a * &delta_a));
        ba.add(&hcat(&rows.model, &rows.a), &(&rows.b * &delta_b));
    };
    for (rows, _) in &old {
        add(&mut ab, &mut ba, rows);
    }
    let before = (ab.residual().0 / sigma2, ba.residual().0 / sigma2);
    let candidate_rows: Vec<BlockRows> = candidates
        .par_iter()
        .map(|c| {
            let encs: Vec<Joints> = c.touches.iter().map(|t| t.1).collect();
            split_rows(calibrated, &union, &scale, m, &ra, &rb, &encs)
        })
        .collect();
    let mut chosen: Vec<usize> = Vec::new();
    let mut merits = Vec::new();
    for _ in 0..options.count.min(candidates.len()) {
        let best = (0..candidates.len())
            .into_par_iter()
            .filter(|k| !chosen.contains(k))
            .map(|k| {
                let (mut ab, mut ba) = (ab.clone(), ba.clone());
                add(&mut ab, &mut ba, &candidate_rows[k]);
                (k, (ab.residual().0 + ba.residual().0) / sigma2)
            })
            .max_by(|x, y| x.1.total_cmp(&y.1));
        let Some((k, merit)) = best else { break };
        add(&mut ab, &mut ba, &candidate_rows[k]);
        chosen.push(k);
        merits.push(merit);
    }
    let (gamma_ab, gamma_ba) = (ab.residual().1, ba.residual().1);
    let placements = chosen
        .iter()
        .zip(&merits)
        .map(|(&k, &merit)| {
            let rows = &candidate_rows[k];
            let miss_ab = &rows.a * &delta_a - hcat(&rows.model, &rows.b) * &gamma_ab;
            let miss_ba = &rows.b * &delta_b - hcat(&rows.model, &rows.a) * &gamma_ba;
            suggestion(&candidates[k], artefact, merit, Some((miss_ab, miss_ba)))
        })
        .collect();
    RivalPlan {
        rivals: (ra.effect.to_string(), rb.effect.to_string()),
        before_sigma2: before,
        after_sigma2: (ab.residual().0 / sigma2, ba.residual().0 / sigma2),
        placements,
    }
}

fn plan_weak(
    calibrated: &ArmModel,
    artefact: &Artefact,
    cal: &Observations,
    candidates: &[CandidatePlacement],
    options: &PlanOptions,
) -> WeakPlan {
    let sigma2 = options.touch_std_mm.powi(2);
    let params: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
    let scale = scales(calibrated, &params);
    let n = params.len();
    // Information in scaled units, with the unit prior.
    let mut f = DMatrix::<f64>::identity(n, n);
    let mut column_ss = vec![0.0; n];
    let mut rows_total = 0usize;
    for block in blocks(cal) {
        let encs: Vec<Joints> = block.iter().map(|t| t.q_deg).collect();
        let x = block_rows(calibrated, &params, &scale, &encs);
        f += x.transpose() * &x / sigma2;
        for (c, ss) in column_ss.iter_mut().enumerate() {
            *ss += x.column(c).norm_squared();
        }
        rows_total += encs.len();
    }
    let stds = |f: &DMatrix<f64>| -> Vec<f64> {
        match f.clone().cholesky() {
            Some(ch) => {
                let inv = ch.inverse();
                (0..n).map(|k| inv[(k, k)].max(0.0).sqrt() * scale[k]).collect()
            }
            None => scale.clone(),
        }
    };
    let before = stds(&f);
    let candidate_info: Vec<DMatrix<f64>> = candidates
        .par_iter()
        .map(|c| {
            let encs: Vec<Joints> = c.touches.iter().map(|t| t.1).collect();
            let x = block_rows(calibrated, &params, &scale, &encs);
            x.transpose() * &x / sigma2
        })
        .collect();
    let log_det = |m: &DMatrix<f64>| {
        m.clone().cholesky().map_or(f64::NEG_INFINITY, |ch| 2.0 * ch.l().diagonal().map(f64::ln).sum())
    };
    let mut chosen: Vec<usize> = Vec::new();
    let mut merits = Vec::new();
    for _ in 0..options.count.min(candidates.len()) {
        let now = log_det(&f);
        let best = (0..candidates.len())
            .into_par_iter()
            .filter(|k| !chosen.contains(k))
            .map(|k| (k, log_det(&(&f + &candidate_info[k])) - now))
            .max_by(|x, y| x.1.total_cmp(&y.1));
        let Some((k, gain)) = best else { break };
        f += &candidate_info[k];
        chosen.push(k);
        merits.push(gain);
    }
    let after = stds(&f);
    let rows = rows_total.max(1) as f64;
    let mut table: Vec<(String, &'static str, f64, f64, f64)> = (0..n)
        .map(|k| {
            // Tip effect: one std times the RMS (per touch) of the projected column, unscaled.
            let tip = before[k] * (column_ss[k] / rows).sqrt() / scale[k];
            (params[k].to_string(), params[k].unit(), before[k], after[k], tip)
        })
        .collect();
    table.sort_by(|a, b| b.4.total_cmp(&a.4));
    WeakPlan {
        stds: table,
        placements: chosen
            .iter()
            .zip(&merits)
            .map(|(&k, &gain)| suggestion(&candidates[k], artefact, gain, None))
            .collect(),
    }
}

/// Measure placements with a (simulated) true arm: every planned touch `repeats` times, posed by
/// the true arm's inverse kinematics started from the planned configuration, with the seating
/// and encoder noise of `sim`. One session per placement, named `name_prefix` + its number.
pub fn measure(
    truth: &ArmModel,
    artefact: &Artefact,
    placements: &[&CandidatePlacement],
    sim: &SimulationOptions,
    name_prefix: &str,
    rng: &mut ChaCha8Rng,
) -> Vec<Session> {
    use rand_distr::{Distribution, Normal};
    let seat = Normal::new(0.0, sim.seating_noise_mm.max(0.0)).ok();
    let enc_noise = Normal::new(0.0, sim.encoder_noise_deg.max(0.0)).ok();
    placements
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let mut measurements = Vec::new();
            for repeat in 1..=sim.repeats {
                for (l, planned) in &c.touches {
                    let draw = |rng: &mut ChaCha8Rng| seat.map_or(0.0, |n| n.sample(rng));
                    let noise = Vector3::new(draw(rng), draw(rng), draw(rng));
                    let landmark = &artefact.landmarks[*l];
                    let Ok(near) = <[f64; crate::model::SUTA_JOINTS]>::try_from(&planned[..]) else {
                        continue;
                    };
                    let Some(enc) = crate::simulate::touch_encoders_from(
                        truth,
                        &c.placement,
                        landmark,
                        noise,
                        &near,
                        rng,
                    ) else {
                        continue;
                    };
                    measurements.push(crate::data::Measurement {
                        landmark: landmark.id.clone(),
                        repeat,
                        joints_deg: enc
                            .iter()
                            .map(|v| (v + enc_noise.map_or(0.0, |n| n.sample(rng))).rem_euclid(360.0))
                            .collect(),
                        std_deg: None,
                        samples: None,
                        rejected: None,
                        at_unix_s: None,
                    });
                }
            }
            Session {
                format: SESSION_FORMAT.into(),
                placement: format!("{name_prefix}{}", k + 1),
                purpose: "calibration".into(),
                measurements,
                arm: None,
            }
        })
        .collect()
}

/// Sum of squared touch residuals after a rigid fit per (placement, repeat), in σ².
fn rigid_ssr(model: &ArmModel, artefact: &Artefact, data: &Observations, sigma2: f64) -> f64 {
    blocks(data)
        .iter()
        .filter_map(|b| rigid_residuals(model, artefact, b))
        .map(|r| r.norm_squared())
        .sum::<f64>()
        / sigma2
}

/// How clearly `data` tell rival `a` (the true one) from `b`: each is added to `calibrated`
/// and refitted on `data` (warm start, no restarts); the result is (SSR_b − SSR_a)/σ² of the
/// touch residuals after a rigid fit per block. Above [`SEPARABLE_SIGMA2`] the data prefer `a`
/// clearly.
pub fn separation(
    calibrated: &ArmModel,
    artefact: &Artefact,
    data: &Observations,
    a: Effect,
    b: Effect,
    touch_std_mm: f64,
) -> Result<f64, CalibError> {
    let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
    let ssr = |e: Effect| -> Result<f64, CalibError> {
        let mut model = calibrated.clone();
        e.add_to(&mut model);
        let fit = calibrate(&model, data, &options)?;
        Ok(rigid_ssr(&fit.model, artefact, data, touch_std_mm.powi(2)))
    };
    Ok(ssr(b)? - ssr(a)?)
}

/// Outcome of one seed of the plan check.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TrialOutcome {
    /// Figure on the data so far.
    pub before: f64,
    /// Figure with the planned placements measured.
    pub planned: f64,
    /// Figure with as many random candidate placements measured, one value per random draw.
    pub random: Vec<f64>,
}

/// The simulated old data of a trial: the first `placements` calibration sessions of `sim`.
fn old_sessions(sim: &SimulatedData, placements: usize) -> Vec<Session> {
    sim.calibration.iter().take(placements).cloned().collect()
}

/// `count` random candidates (seeded), for the comparison with the plan.
fn random_pick<'a>(
    candidates: &'a [CandidatePlacement],
    count: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<&'a CandidatePlacement> {
    let mut picked: Vec<usize> = Vec::new();
    while picked.len() < count.min(candidates.len()) {
        let k = rng.random_range(0..candidates.len());
        if !picked.contains(&k) {
            picked.push(k);
        }
    }
    picked.into_iter().map(|k| &candidates[k]).collect()
}

/// Settings of a plan check on simulated data.
#[derive(Clone, Debug)]
pub struct TrialOptions {
    /// Seed of the simulated arm, its data and the random placements.
    pub seed: u64,
    /// Calibration placements of the data so far (of the simulator's five).
    pub placements: usize,
    /// Placements planned (and drawn at random).
    pub count: usize,
    /// Random designs compared with the plan.
    pub random_draws: usize,
}

/// The candidates a plan chose, by their placement.
fn chosen<'a>(
    candidates: &'a [CandidatePlacement],
    suggested: &[SuggestedPlacement],
) -> Vec<&'a CandidatePlacement> {
    suggested
        .iter()
        .filter_map(|p| {
            candidates
                .iter()
                .find(|c| c.placement.origin_mm == p.origin_mm && c.placement.yaw_deg == p.yaw_deg)
        })
        .collect()
}

/// A simulated arm, its sessions and the data so far, for a plan check.
struct Trial {
    sim: SimulatedData,
    sim_options: SimulationOptions,
    old: Vec<Session>,
    cal: Observations,
}

impl Trial {
    /// Simulate the arm of `trial.seed` with `hidden`; the data so far are its first
    /// `trial.placements` calibration placements.
    fn new(nominal: &ArmModel, hidden: &[(ParamId, f64)], trial: &TrialOptions) -> Trial {
        let sim_options =
            SimulationOptions { seed: trial.seed, hidden: hidden.to_vec(), ..SimulationOptions::default() };
        let sim = crate::simulate::simulate(nominal, &sim_options);
        let old = old_sessions(&sim, trial.placements);
        let cal = Observations::from_sessions(&old, &sim.artefact);
        Trial { sim, sim_options, old, cal }
    }

    /// `figure` of the data so far plus the `suggested` placements measured on the true arm, and
    /// of the data so far plus `trial.random_draws` random designs of as many placements.
    fn planned_and_random(
        &self,
        candidates: &[CandidatePlacement],
        suggested: &[SuggestedPlacement],
        trial: &TrialOptions,
        figure: impl Fn(&Observations) -> Result<f64, CalibError>,
    ) -> Result<(f64, Vec<f64>), CalibError> {
        let mut rng = ChaCha8Rng::seed_from_u64(trial.seed ^ 0x9e37_79b9);
        let score = |design: &[&CandidatePlacement], rng: &mut ChaCha8Rng| {
            let mut sessions = self.old.clone();
            sessions.extend(measure(
                &self.sim.truth,
                &self.sim.artefact,
                design,
                &self.sim_options,
                "N",
                rng,
            ));
            figure(&Observations::from_sessions(&sessions, &self.sim.artefact))
        };
        let with_plan = score(&chosen(candidates, suggested), &mut rng)?;
        let mut random = Vec::new();
        for _ in 0..trial.random_draws {
            let design = random_pick(candidates, trial.count, &mut rng);
            random.push(score(&design, &mut rng)?);
        }
        Ok((with_plan, random))
    }
}

/// Outcome of one seed of the rivals check.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RivalOutcome {
    /// What the diagnosis names on the data so far.
    pub named_before: Vec<String>,
    /// What it names with the planned placements measured.
    pub named_planned: Vec<String>,
    /// What it names with each random design measured.
    pub named_random: Vec<Vec<String>>,
    /// [`separation`] of the true rival from the other on every measured touch (σ²).
    pub separation: TrialOutcome,
}

impl RivalOutcome {
    /// Whether `named` is the true rival `a` alone.
    pub fn alone(named: &[String], a: Effect) -> bool {
        named.len() == 1 && named[0] == a.to_string()
    }
}

/// Rivals check on the simulator's thesis-sized data (five calibration and five validation
/// placements, 3 repeats) of a true arm with `hidden` (effect `a`'s parameters): calibrate,
/// diagnose, plan `trial.count` placements to tell `a` from `b`, measure them on the true arm
/// (the simulator's independent forward path, 3 repeats), add them to the calibration data,
/// recalibrate and diagnose again on the same validation placements; the same with
/// `trial.random_draws` designs of as many random reachable placements. `trial.placements` is
/// not used: all ten simulated placements are the data so far.
pub fn rival_trial(
    nominal: &ArmModel,
    hidden: &[(ParamId, f64)],
    a: Effect,
    b: Effect,
    trial: &TrialOptions,
) -> Result<RivalOutcome, CalibError> {
    let sim_options =
        SimulationOptions { seed: trial.seed, hidden: hidden.to_vec(), ..SimulationOptions::default() };
    let sim = crate::simulate::simulate(nominal, &sim_options);
    let artefact = &sim.artefact;
    let cal = Observations::from_sessions(&sim.calibration, artefact);
    let val = Observations::from_sessions(&sim.validation, artefact);
    let calibration = SolveOptions { restarts: Some(2), seed: trial.seed, ..SolveOptions::default() };
    let fit = calibrate(nominal, &cal, &calibration)?;
    let sigma = sim_options.seating_noise_mm;
    let options = PlanOptions { count: trial.count, seed: trial.seed, touch_std_mm: sigma };
    let candidates = candidate_placements(&fit.model, artefact, trial.seed);
    let planned = plan_rivals(&fit.model, artefact, &cal, &val, a, b, &candidates, &options);
    // The user's next step: measure the placements, add them to the calibration data,
    // recalibrate (warm) and diagnose again on the same validation placements.
    let outcome = |design: &[&CandidatePlacement], rng: &mut ChaCha8Rng| {
        let new = measure(&sim.truth, artefact, design, &sim_options, "N", rng);
        let everything: Vec<Session> =
            sim.calibration.iter().chain(&sim.validation).chain(&new).cloned().collect();
        let separated = separation(
            &fit.model,
            artefact,
            &Observations::from_sessions(&everything, artefact),
            a,
            b,
            sigma,
        )?;
        let sessions: Vec<Session> = sim.calibration.iter().chain(&new).cloned().collect();
        let more = Observations::from_sessions(&sessions, artefact);
        let refit = calibrate(&fit.model, &more, &SolveOptions { restarts: Some(0), ..calibration.clone() })?;
        let named = diagnose(&refit.model, &more, &val, &calibration).named;
        Ok::<_, CalibError>((named, separated))
    };
    let before = diagnose(&fit.model, &cal, &val, &calibration).named;
    let so_far: Vec<Session> = sim.calibration.iter().chain(&sim.validation).cloned().collect();
    let separated_before =
        separation(&fit.model, artefact, &Observations::from_sessions(&so_far, artefact), a, b, sigma)?;
    let mut rng = ChaCha8Rng::seed_from_u64(trial.seed ^ 0x9e37_79b9);
    let (named_planned, separated_planned) = outcome(&chosen(&candidates, &planned.placements), &mut rng)?;
    let (mut named_random, mut separated_random) = (Vec::new(), Vec::new());
    for _ in 0..trial.random_draws {
        let design = random_pick(&candidates, trial.count, &mut rng);
        let (named, separated) = outcome(&design, &mut rng)?;
        named_random.push(named);
        separated_random.push(separated);
    }
    Ok(RivalOutcome {
        named_before: before,
        named_planned,
        named_random,
        separation: TrialOutcome {
            before: separated_before,
            planned: separated_planned,
            random: separated_random,
        },
    })
}

/// Weak-parameter check: plan `trial.count` placements (D-optimal) on `trial.placements`
/// calibration placements of a simulated arm, measure them, recalibrate, and compare the std of
/// the parameter the plan names weakest with that after as many random placements. Returns the
/// parameter and its stds (as the calibration reports them).
pub fn weak_trial(nominal: &ArmModel, trial: &TrialOptions) -> Result<(String, TrialOutcome), CalibError> {
    let t = Trial::new(nominal, &[], trial);
    let (artefact, cal) = (&t.sim.artefact, &t.cal);
    let calibration = SolveOptions { restarts: Some(0), seed: trial.seed, ..SolveOptions::default() };
    let fit = calibrate(nominal, cal, &calibration)?;
    let options =
        PlanOptions { count: trial.count, seed: trial.seed, touch_std_mm: t.sim_options.seating_noise_mm };
    let candidates = candidate_placements(&fit.model, artefact, trial.seed);
    let planned = plan_weak(&fit.model, artefact, cal, &candidates, &options);
    let worst = planned.stds.first().map(|s| s.0.clone()).unwrap_or_default();
    let std_of =
        |fit: &Fit| fit.estimates.iter().find(|e| e.param == worst).and_then(|e| e.std).unwrap_or(f64::NAN);
    let before = std_of(&fit);
    let (planned_std, random) = t.planned_and_random(&candidates, &planned.placements, trial, |data| {
        Ok(std_of(&calibrate(&fit.model, data, &calibration)?))
    })?;
    Ok((worst, TrialOutcome { before, planned: planned_std, random }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_ranges_take_the_short_way_round() {
        assert_eq!(joint_range_deg(&[120.0, 200.0, 150.0]), (120.0, 200.0));
        assert_eq!(joint_range_deg(&[350.0, 10.0, 5.0]), (350.0, 370.0));
    }
}
