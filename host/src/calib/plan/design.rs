//! The linearised design: each block's rows with its rigid frame projected out, the rivals'
//! separability (T-optimal) and the information of the parameters (D-optimal), greedy over the
//! candidates.

use super::candidates::Candidate;
use super::{suggestion, PlanOptions, RivalPlan, WeakPlan};
use crate::calib::nuisance::frame::Frame;
use crate::data::{Joints, Observation, Observations};
use crate::model::effects::{default_half_range, Effect};
use crate::model::kinematics::{tool_pose, tool_pose_with_jacobian, ColumnMap};
use crate::model::{ArmModel, ParamId};
use nalgebra::{DMatrix, DVector, Vector3};
use rayon::prelude::*;

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

/// What an observation was at, in its block's frame: a certified landmark's position, or the
/// point the instrument measured.
fn target_mm(data: &Observations, o: &Observation) -> Option<Vector3<f64>> {
    match o.landmark() {
        Some(l) => Some(Vector3::from(data.landmarks[l].xyz_mm)),
        None => o.point_mm(),
    }
}

/// Residuals (3 per observation) of `model` after a rigid fit of each block's targets (the
/// artefact's landmarks, or the instrument's points) to the tool points.
pub(super) fn rigid_residuals(
    model: &ArmModel,
    data: &Observations,
    block: &[&Observation],
) -> Option<DVector<f64>> {
    if block.len() < 3 {
        return None;
    }
    let p: Vec<Vector3<f64>> = block.iter().map(|t| tool_pose(model, &t.q_deg).position_mm).collect();
    let q: Vec<Vector3<f64>> = block.iter().map(|t| target_mm(data, t)).collect::<Option<_>>()?;
    let residuals = Frame::residuals(&q, &p);
    Some(DVector::from_iterator(3 * p.len(), residuals.iter().flat_map(|e| [e.x, e.y, e.z])))
}

/// Touches of `data` grouped by (placement, repeat): one rigid block each.
pub(super) fn blocks(data: &Observations) -> Vec<Vec<&Observation>> {
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

#[allow(clippy::too_many_arguments)]
pub(super) fn plan_rivals(
    calibrated: &ArmModel,
    cal: &Observations,
    val: &Observations,
    a: Effect,
    b: Effect,
    candidates: &[Candidate],
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
        .flat_map(|data| blocks(data).into_iter().map(move |b| (data, b)))
        .filter_map(|(data, block)| {
            let r = rigid_residuals(calibrated, data, &block)?;
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
            let encs: Vec<Joints> = c.poses.iter().map(|t| t.2).collect();
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
            suggestion(&candidates[k], merit, Some((miss_ab, miss_ba)))
        })
        .collect();
    RivalPlan {
        rivals: (ra.effect.to_string(), rb.effect.to_string()),
        before_sigma2: before,
        after_sigma2: (ab.residual().0 / sigma2, ba.residual().0 / sigma2),
        placements,
    }
}

pub(super) fn plan_weak(
    calibrated: &ArmModel,
    cal: &Observations,
    candidates: &[Candidate],
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
            let encs: Vec<Joints> = c.poses.iter().map(|t| t.2).collect();
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
            .map(|(&k, &gain)| suggestion(&candidates[k], gain, None))
            .collect(),
    }
}
