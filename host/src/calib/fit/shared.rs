//! The normal equations of a fit's solution, session by session, shared by the refits that start
//! there (the outlier metrics' leave-one-session-out refits, the data-error scoring's refits).
//!
//! Every row of a tracker session reads the arm's columns and its own session's unknowns (its
//! frame, its group's floated tool, its drift, the probe's rotation) and no other, so the normal
//! equations JᵀWJ and JᵀWr of any set of sessions at one point are the sum of each session's
//! own. A refit from the fit's solution ([`super::warm_start`]) evaluates its first normal
//! equations exactly there, with the same parametrisation (frames' rotations centred at the
//! solution): they are assembled from the sessions' sums, taken once. A session whose tool the
//! refit floats (and the sums do not) has its sums extended by the offset's columns, which are the
//! tool point's own (see [`SessionSum::with_floated_tool`]); any other session whose unknowns
//! differ in the refit is evaluated again, alone. The sums are the same rows summed in another
//! order; the refit goes on as before from there (exact, not a one-step approximation).

use super::*;
use crate::numerics::solver::KnownStart;
use nalgebra::{DMatrix, DVector};

/// An unknown a session's rows read, named independently of the layout's column order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Key {
    Arm(ParamId),
    Frame(usize),
    Tool(usize),
    Probe(usize),
    Drift(usize),
}

/// Block `b`'s unknowns in `layout` (its group `g`), with their columns.
pub(super) fn keys(layout: &Layout, b: usize, g: usize) -> Vec<(Key, usize)> {
    let mut out: Vec<(Key, usize)> =
        layout.arm.iter().enumerate().map(|(c, &id)| (Key::Arm(id), c)).collect();
    let mut run = |first: Option<usize>, width: usize, key: fn(usize) -> Key| {
        if let Some(c) = first {
            out.extend((0..width).map(|k| (key(k), c + k)));
        }
    };
    run(layout.frame_column(b), FRAME_UNKNOWNS, Key::Frame);
    run(layout.tool_column(g), 3, Key::Tool);
    run(layout.rotation_column(), 3, Key::Probe);
    let drift = layout.drift(b);
    run(drift.map(|d| d.0), drift.map_or(0, |d| d.1.kind.unknowns()), Key::Drift);
    out
}

/// The source lines of block `b`'s points.
fn session_lines(data: &Observations, b: usize) -> Vec<usize> {
    data.blocks[b].members.iter().map(|&k| data.obs[k].line).collect()
}

/// One session's normal equations over its own unknowns, and its cost.
struct SessionSum {
    name: String,
    /// The source lines of the session's points: sums of other data (points left out) are not
    /// taken for these.
    lines: Vec<usize>,
    /// Whether the session's rows include measured orientations (which a refit floating its
    /// tool leaves out).
    orientations: bool,
    /// The arm's scale s = 1 + scale_ppm·10⁻⁶ the rows were taken at.
    scale: f64,
    keys: Vec<Key>,
    h: DMatrix<f64>,
    g: DVector<f64>,
    cost: f64,
}

impl SessionSum {
    /// Block `b` of `pieces` alone at `fit`'s solution, over the arm's `arm` columns; `None` when
    /// its evaluation is not finite.
    fn of(pieces: &Pieces, b: usize, fit: &Fit, arm: &[ParamId]) -> Option<SessionSum> {
        let mut sub = None;
        let (alone, own) = pieces.block_alone(b, &mut sub);
        SessionSum::on(pieces, b, &alone, own, fit, arm)
    }

    /// [`SessionSum::of`] evaluated on `alone`, block `b` of `pieces` alone
    /// ([`Pieces::block_alone`]), where it is block `own`.
    fn on(
        pieces: &Pieces,
        b: usize,
        alone: &Pieces,
        own: usize,
        fit: &Fit,
        arm: &[ParamId],
    ) -> Option<SessionSum> {
        let data = pieces.data;
        let start = warm_start(alone, fit);
        let problem = alone.problem(arm.to_vec(), &start.model, &start.frames, start.probe);
        let x = alone.x_of(&problem, &start.model, &start.frames, &start.tools, &start.drifts);
        let mut r = vec![0.0; problem.len()];
        let (h, g) = problem.normal_equations(&x, &mut r, alone.resolved.loss);
        let cost = alone.resolved.loss.cost(&r);
        let columns = keys(&problem.layout, own, data.blocks[b].group);
        let keys = columns.iter().map(|k| k.0).collect();
        let h = DMatrix::from_fn(columns.len(), columns.len(), |i, j| h[(columns[i].1, columns[j].1)]);
        let g = DVector::from_iterator(columns.len(), columns.iter().map(|c| g[c.1]));
        let finite = h.iter().all(|v| v.is_finite()) && g.iter().all(|v| v.is_finite()) && cost.is_finite();
        let lines = session_lines(data, b);
        let orientations = data.blocks[b].members.iter().any(|&k| data.obs[k].orientation().is_some());
        let scale = 1.0 + start.model.scale_ppm * 1e-6;
        finite.then(|| SessionSum { name: data.block_name(b), lines, orientations, scale, keys, h, g, cost })
    }

    /// This sum with its session's tool floated: three more unknowns, the offset Δ (`Key::Tool`),
    /// when the tool point's own values (`tool`, arm parameters) are among its unknowns and it
    /// has no orientation rows. A point's derivative by Δ is R_s·R_F·e_k, by the tool point's
    /// own value along the same flange axis R_s·s·R_F·e_k (the chain's point scaled by its scale
    /// s), times the same drift growth and weight: the tool point's columns over s (equal to
    /// rounding: the chain carries the flange's y axis, the point term forms it as z × x). Only
    /// for a refit that starts its offset at Δ = 0, where the rows, their cost and gradient are
    /// this sum's (the caller checks it).
    fn with_floated_tool(&self, tool: [ParamId; 3]) -> Option<SessionSum> {
        if self.orientations || self.keys.iter().any(|k| matches!(k, Key::Tool(_))) {
            return None;
        }
        let at: Vec<usize> = tool
            .iter()
            .map(|&id| self.keys.iter().position(|k| *k == Key::Arm(id)))
            .collect::<Option<Vec<_>>>()?;
        let (n, wide) = (self.keys.len(), self.keys.len() + 3);
        // Column c of the floated sum: its own column, or the tool point's over s.
        let source = |c: usize| if c < n { (c, 1.0) } else { (at[c - n], 1.0 / self.scale) };
        let h = DMatrix::from_fn(wide, wide, |i, j| {
            let ((a, fa), (b, fb)) = (source(i), source(j));
            self.h[(a, b)] * fa * fb
        });
        let g = DVector::from_fn(wide, |i, _| {
            let (a, f) = source(i);
            self.g[a] * f
        });
        let keys = self.keys.iter().copied().chain((0..3).map(Key::Tool)).collect();
        Some(SessionSum { keys, h, g, name: self.name.clone(), lines: self.lines.clone(), ..*self })
    }
}

/// The normal equations of `fit`'s solution on a set of tracker sessions, session by session.
pub struct SessionSums<'f> {
    fit: &'f Fit,
    resolved: Resolved,
    sessions: Vec<SessionSum>,
    /// The terms and encoder table of the observations the sums were taken on, for the refits
    /// on them (the data-error scoring's); `None` when taken on a copy (orientations left out).
    kept: Option<KeptTerms<'f>>,
}

impl<'f> SessionSums<'f> {
    /// Each session of `data` at `fit`'s solution, with `options`. `model` is the model the
    /// refits are called with (its effects, free parameters, bounds and fixed values); its free
    /// parameters take the fit's values, as in the refits' warm start. `None` when a block of
    /// `data` is not a session with a frame (artefact touches, whose distances are shared by no
    /// session's unknowns alone), or when a sum is not finite.
    pub fn of(
        model: &ArmModel,
        fit: &'f Fit,
        data: &'f Observations,
        options: &SolveOptions,
    ) -> Option<SessionSums<'f>> {
        SessionSums::of_sharing(model, fit, data, options, None)
    }

    /// [`SessionSums::of`], the terms of `data` from `terms` when given (a run's, see
    /// [`SharedTerms`]).
    pub(crate) fn of_sharing(
        model: &ArmModel,
        fit: &'f Fit,
        data: &'f Observations,
        options: &SolveOptions,
        terms: Option<&'f SharedTerms<'f>>,
    ) -> Option<SessionSums<'f>> {
        if let Some(own) = data.without_orientations_of(&options.float_tool) {
            let (resolved, sessions) =
                SessionSums::sums(&Pieces::new(model, &own, options, &fit.encoders).ok()?, fit)?;
            return Some(SessionSums { fit, resolved, sessions, kept: None });
        }
        let source = terms.map(TermSource::Shared);
        let pieces = Pieces::new_sharing(model, data, options, &fit.encoders, source).ok()?;
        let (resolved, sessions) = SessionSums::sums(&pieces, fit)?;
        Some(SessionSums { fit, resolved, sessions, kept: Some(pieces.keep()) })
    }

    /// The options as resolved and each session's sum of `pieces` at `fit`'s solution (see
    /// [`SessionSums::of`]).
    fn sums(pieces: &Pieces, fit: &Fit) -> Option<(Resolved, Vec<SessionSum>)> {
        let data = pieces.data;
        // Without the fit's probe rotation, a session alone would start its probe elsewhere.
        let probe_unknown =
            pieces.resolved.orientation_weight_mm_per_rad.is_some() && fit.tool_rotation.is_none();
        if data.blocks.is_empty() || !pieces.framed.iter().all(|f| *f) || probe_unknown {
            return None;
        }
        let sessions = (0..data.blocks.len())
            .into_par_iter()
            .map(|b| SessionSum::of(pieces, b, fit, &fit.estimated))
            .collect::<Option<Vec<_>>>()?;
        Some((pieces.resolved, sessions))
    }

    /// The terms and encoder table of the observations these sums were taken on.
    pub(super) fn kept(&self) -> Option<&KeptTerms<'f>> {
        self.kept.as_ref()
    }

    /// The fit these sums are of.
    pub fn fit(&self) -> &'f Fit {
        self.fit
    }

    /// The normal matrix, gradient and cost of `problem` (of `pieces`, at `warm_start(pieces,
    /// fit)`), from the sums: each block's by its session's name when its unknowns are the same,
    /// else that block evaluated alone. `None` when `pieces` is not all framed sessions or
    /// resolves its options otherwise than the sums.
    pub(super) fn normal_at_start(&self, pieces: &Pieces, problem: &Problem) -> Option<KnownStart> {
        let data = pieces.data;
        if data.blocks.is_empty() || !pieces.framed.iter().all(|f| *f) || pieces.resolved != self.resolved {
            return None;
        }
        let n = problem.layout.unknowns();
        let (mut h, mut g, mut cost) = (DMatrix::zeros(n, n), DVector::zeros(n), 0.0);
        for b in 0..data.blocks.len() {
            let columns = keys(&problem.layout, b, data.blocks[b].group);
            let name = data.block_name(b);
            let lines = session_lines(data, b);
            let same = |s: &&SessionSum| {
                s.name == name
                    && s.lines == lines
                    && s.keys.len() == columns.len()
                    && columns.iter().all(|c| s.keys.contains(&c.0))
            };
            let fresh;
            let sum = match self.sessions.iter().find(same) {
                Some(sum) => sum,
                None => {
                    let floated = self.floated_tool(pieces, b, &lines, &columns);
                    fresh = match floated {
                        Some(sum) => sum,
                        None => SessionSum::of(pieces, b, self.fit, &problem.layout.arm)?,
                    };
                    &fresh
                }
            };
            let at: Vec<usize> = sum
                .keys
                .iter()
                .map(|k| columns.iter().find(|c| c.0 == *k).map(|c| c.1))
                .collect::<Option<Vec<_>>>()?;
            cost += sum.cost;
            for (i, &ci) in at.iter().enumerate() {
                g[ci] += sum.g[i];
                for (j, &cj) in at.iter().enumerate() {
                    h[(ci, cj)] += sum.h[(i, j)];
                }
            }
        }
        Some(KnownStart { normal: h, gradient: g, cost })
    }

    /// Block `b`'s sum (its source `lines`, its unknowns `columns`) from its session's kept one
    /// when they differ by its tool floated alone ([`SessionSum::with_floated_tool`]) and the
    /// refit starts the offset at zero (the fit did not float that tool).
    fn floated_tool(
        &self,
        pieces: &Pieces,
        b: usize,
        lines: &[usize],
        columns: &[(Key, usize)],
    ) -> Option<SessionSum> {
        let data = pieces.data;
        let name = data.block_name(b);
        let kept = self.sessions.iter().find(|s| s.name == name && s.lines == lines)?;
        let members = &data.blocks[b].members;
        let tip = data.obs[*members.first()?].tip;
        if members.iter().any(|&k| data.obs[k].tip != tip) {
            return None;
        }
        if self.fit.tool_offset(&data.groups[data.blocks[b].group].name) != Vector3::zeros() {
            return None;
        }
        let tool = std::array::from_fn(|k| if tip > 0 { ParamId::TipTcp(tip, k) } else { ParamId::Tcp(k) });
        let sum = kept.with_floated_tool(tool)?;
        let same = sum.keys.len() == columns.len() && columns.iter().all(|c| sum.keys.contains(&c.0));
        same.then_some(sum)
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::{arm, arm_and_truth, sessions};
    use super::*;
    use crate::calib::nuisance::drift::{DriftKind, DriftSpec};

    /// Largest entry difference of two matrices over the largest entry of the first.
    fn relative_gap(a: &DMatrix<f64>, b: &DMatrix<f64>) -> f64 {
        (a - b).abs().max() / a.abs().max()
    }

    /// The normal equations, gradient and cost assembled from `sums` for `pieces` equal those of
    /// its own evaluation at the warm start of `fit` (1e-12); the gradient is not zero. Returns
    /// the problem's probe-rotation column.
    fn assert_assembled_is_evaluated(
        sums: &SessionSums,
        pieces: &Pieces,
        fit: &Fit,
        label: &str,
    ) -> Option<usize> {
        let start = warm_start(pieces, fit);
        let problem = pieces.problem(fit.estimated.clone(), &start.model, &start.frames, start.probe);
        let x = pieces.x_of(&problem, &start.model, &start.frames, &start.tools, &start.drifts);
        let mut r = vec![0.0; problem.len()];
        let (own, own_g) = problem.normal_equations(&x, &mut r, pieces.resolved.loss);
        let known = sums.normal_at_start(pieces, &problem).expect("assembled");
        let own_cost = pieces.resolved.loss.cost(&r);
        assert!((known.cost - own_cost).abs() <= 1e-12 * own_cost, "{label}: {} vs {own_cost}", known.cost);
        let gap = relative_gap(&own, &known.normal);
        assert!(gap < 1e-12, "{label}: {gap:e}");
        assert!(own_g.abs().max() > 0.0, "{label}");
        assert!((&own_g - &known.gradient).abs().max() <= 1e-12 * own_g.abs().max(), "{label}");
        problem.layout.rotation_column()
    }

    /// Three sessions of 40 points of an arm 1.5 mm and 0.2° from `arm()`, each point moved by a
    /// fixed pattern of up to 0.05 mm (noise, so that leaving a session out moves the fit).
    fn noisy_sessions(probe: Option<Matrix3<f64>>) -> (ArmModel, Observations) {
        let (nominal, truth) = arm_and_truth();
        let mut data = sessions(&truth, probe);
        for (k, o) in data.obs.iter_mut().enumerate() {
            if let crate::data::Target::Point { xyz_mm, .. } = &mut o.target {
                let f = k as f64;
                *xyz_mm += 0.05 * Vector3::new((1.3 * f).sin(), (0.7 * f).cos(), (2.1 * f).sin());
            }
        }
        (nominal, data)
    }

    /// The first normal equations assembled from the sums are those the refit evaluates itself
    /// (one session left out; one session's tool floated, whose block is evaluated again: the
    /// tool point is not estimated, so its columns are not in the sums), and
    /// the refits that start from them reach the same solution as those that do not.
    #[test]
    fn refits_from_session_sums_are_the_refits() {
        let (nominal, cal) = noisy_sessions(None);
        let options = SolveOptions::default();
        let fit = calibrate(&nominal, &cal, &options).expect("fit");
        let sums = SessionSums::of(&fit.model, &fit, &cal, &options).expect("sums");
        // Leave a session out.
        for b in [0, 2] {
            let without = cal.without(|k| cal.obs[k].block == b);
            let pieces = Pieces::new(&fit.model, &without, &options, &fit.encoders).expect("pieces");
            assert_assembled_is_evaluated(&sums, &pieces, &fit, &format!("session {b} left out"));
            let plain = refit(&fit, &without, &options).expect("refit");
            let shared = refit_with(&sums, &without, &options).expect("refit with sums");
            let moved = fit.estimated.iter().any(|id| (plain.get(*id) - fit.model.get(*id)).abs() > 1e-6);
            assert!(moved, "leaving session {b} out moves the fit");
            for id in &fit.estimated {
                let (a, s) = (plain.get(*id), shared.get(*id));
                assert!((a - s).abs() <= 1e-9 * a.abs().max(1.0), "{id}: {a} vs {s}");
            }
        }
        // Float one session's tool: its block's unknowns differ from the sums'.
        let name = cal.block_name(1);
        let floated = SolveOptions { float_tool: vec![name.clone()], ..options.clone() };
        let sums = SessionSums::of(&nominal, &fit, &cal, &options).expect("sums");
        let pieces = Pieces::new(&nominal, &cal, &floated, &fit.encoders).expect("pieces");
        let start = warm_start(&pieces, &fit);
        let arm: Vec<ParamId> =
            pieces.model.free.iter().map(|f| f.id).filter(|id| fit.estimated.contains(id)).collect();
        let problem = pieces.problem(arm, &start.model, &start.frames, start.probe);
        let x = pieces.x_of(&problem, &start.model, &start.frames, &start.tools, &start.drifts);
        let mut r = vec![0.0; problem.len()];
        let (own, _) = problem.normal_equations(&x, &mut r, Loss::Linear);
        let h = sums.normal_at_start(&pieces, &problem).expect("assembled").normal;
        assert_eq!(own.nrows(), fit.estimated.len() + 3 * FRAME_UNKNOWNS + 3);
        assert!(relative_gap(&own, &h) < 1e-12, "floated tool: {:e}", relative_gap(&own, &h));
        let plain = recalibrate(&nominal, &cal, &floated, &fit).expect("refit");
        let shared = recalibrate_with(&nominal, &cal, &floated, &sums).expect("refit with sums");
        assert!((plain.cost - shared.cost).abs() <= 1e-12 * plain.cost);
        let (a, s) = (&plain.tool_offsets[0], &shared.tool_offsets[0]);
        assert_eq!(a.session, name);
        for k in 0..3 {
            assert!((a.offset_mm[k] - s.offset_mm[k]).abs() <= 1e-9 * a.offset_mm[k].abs().max(1e-3));
        }
        assert!((a.size_std_mm - s.size_std_mm).abs() <= 1e-9 * a.size_std_mm);
    }

    /// A session's sums with its tool floated are taken from its kept sums (the tool point's
    /// columns over the arm's scale, here 150 ppm from 1), not evaluated again, and are those
    /// of its own evaluation.
    #[test]
    fn a_floated_tool_is_summed_from_the_tool_points_columns() {
        let (mut nominal, cal) = noisy_sessions(None);
        nominal.scale_ppm = 150.0;
        for k in 0..3 {
            nominal.free_param(ParamId::Tcp(k), nominal.tcp_mm[k] - 20.0, nominal.tcp_mm[k] + 20.0);
        }
        nominal.free_param(ParamId::Scale, -500.0, 500.0);
        let options = SolveOptions::default();
        let fit = calibrate(&nominal, &cal, &options).expect("fit");
        assert!((0..3).all(|k| fit.estimated.contains(&ParamId::Tcp(k))), "{:?}", fit.estimated);
        assert!(fit.model.scale_ppm.abs() > 1.0);
        let sums = SessionSums::of(&nominal, &fit, &cal, &options).expect("sums");
        let b = 1;
        let floated = SolveOptions { float_tool: vec![cal.block_name(b)], ..options.clone() };
        let pieces = Pieces::new(&nominal, &cal, &floated, &fit.encoders).expect("pieces");
        let start = warm_start(&pieces, &fit);
        let problem = pieces.problem(fit.estimated.clone(), &start.model, &start.frames, start.probe);
        let columns = keys(&problem.layout, b, cal.blocks[b].group);
        assert!(columns.iter().any(|c| matches!(c.0, Key::Tool(_))));
        let derived = sums.floated_tool(&pieces, b, &session_lines(&cal, b), &columns);
        assert!(derived.is_some(), "the floated session is summed from its kept sums");
        assert_assembled_is_evaluated(&sums, &pieces, &fit, "floated tool");
    }

    /// A fit that floated a session's tool starts its refits there with that offset, not zero:
    /// the session's kept sums (taken without the offset) are not extended but evaluated again,
    /// and the assembled start is the refit's own.
    #[test]
    fn a_tool_floated_by_the_fit_is_evaluated_again() {
        let (mut nominal, cal) = noisy_sessions(None);
        for k in 0..3 {
            nominal.free_param(ParamId::Tcp(k), nominal.tcp_mm[k] - 20.0, nominal.tcp_mm[k] + 20.0);
        }
        let b = 1;
        let floated = SolveOptions { float_tool: vec![cal.block_name(b)], ..SolveOptions::default() };
        let fit = calibrate(&nominal, &cal, &floated).expect("fit");
        assert!(fit.tool_offset(&cal.block_name(b)).norm() > 0.0);
        let sums = SessionSums::of(&nominal, &fit, &cal, &SolveOptions::default()).expect("sums");
        let pieces = Pieces::new(&nominal, &cal, &floated, &fit.encoders).expect("pieces");
        let start = warm_start(&pieces, &fit);
        let problem = pieces.problem(fit.estimated.clone(), &start.model, &start.frames, start.probe);
        let columns = keys(&problem.layout, b, cal.blocks[b].group);
        assert!(sums.floated_tool(&pieces, b, &session_lines(&cal, b), &columns).is_none());
        // The refit floats what the fit floated: it starts at the fit's minimum, where the
        // gradient is rounding (compared on the normal matrix's scale).
        let x = pieces.x_of(&problem, &start.model, &start.frames, &start.tools, &start.drifts);
        let mut r = vec![0.0; problem.len()];
        let (own, own_g) = problem.normal_equations(&x, &mut r, pieces.resolved.loss);
        let known = sums.normal_at_start(&pieces, &problem).expect("assembled");
        let own_cost = pieces.resolved.loss.cost(&r);
        assert!((known.cost - own_cost).abs() <= 1e-12 * own_cost, "{} vs {own_cost}", known.cost);
        assert!(relative_gap(&own, &known.normal) < 1e-12);
        assert!((&own_g - &known.gradient).abs().max() <= 1e-12 * own.abs().max());
    }

    /// Sums taken on other data are not taken for a session whose points differ (points left
    /// out of it): that session is evaluated again, and the normal equations are the refit's own.
    #[test]
    fn a_session_with_points_left_out_is_evaluated_again() {
        let (_, cal) = noisy_sessions(None);
        let options = SolveOptions::default();
        let fit = calibrate(&arm(), &cal, &options).expect("fit");
        let sums = SessionSums::of(&fit.model, &fit, &cal, &options).expect("sums");
        let first: Vec<usize> = cal.blocks[0].members[..3].to_vec();
        let fewer = cal.without(|k| first.contains(&k));
        let pieces = Pieces::new(&fit.model, &fewer, &options, &fit.encoders).expect("pieces");
        assert_assembled_is_evaluated(&sums, &pieces, &fit, "three points left out");
    }

    /// With a 6-DoF probe, whose rotation every session's rows read, the assembled normal
    /// equations are the refit's own too (the sessions with the probe's orientations, one left
    /// out).
    #[test]
    fn a_probe_rotation_is_summed_over_the_sessions() {
        let probe = nalgebra::Rotation3::from_euler_angles(0.2, -0.1, 0.4).into_inner();
        let (nominal, data) = noisy_sessions(Some(probe));
        let options = SolveOptions { orientation_sigma_deg: Some(0.05), ..SolveOptions::default() };
        let mut fit = calibrate(&nominal, &data, &options).expect("fit");
        // Away from the minimum, so that the residuals and the gradient are not zero.
        fit.model.joints[2].d_mm += 0.3;
        let sums = SessionSums::of(&fit.model, &fit, &data, &options).expect("sums");
        let without = data.without(|k| data.obs[k].block == 1);
        let pieces = Pieces::new(&fit.model, &without, &options, &fit.encoders).expect("pieces");
        let rotation = assert_assembled_is_evaluated(&sums, &pieces, &fit, "probe, session 1 left out");
        assert!(rotation.is_some());
    }

    /// A session's terms borrowed on the whole data give the sums of its observations copied
    /// alone, to the bit (with a drift, a floated tool, the arm's scale free); a session whose
    /// terms are not one run (its orientations after every point) is not borrowed.
    #[test]
    fn a_borrowed_session_sums_as_its_copy() {
        let (mut nominal, mut cal) = noisy_sessions(None);
        nominal.free_param(ParamId::Scale, -500.0, 500.0);
        for (k, o) in cal.obs.iter_mut().enumerate() {
            o.time_s = Some(60.0 * k as f64);
        }
        let drift = DriftSpec { session: cal.block_name(2), kind: DriftKind::OffsetTime };
        let floated = SolveOptions {
            float_tool: vec![cal.block_name(1)],
            drift_sessions: vec![drift],
            ..SolveOptions::default()
        };
        let fit = calibrate(&nominal, &cal, &floated).expect("fit");
        let pieces = Pieces::new(&nominal, &cal, &floated, &fit.encoders).expect("pieces");
        for b in 0..cal.blocks.len() {
            let borrowed = pieces.block_borrowed(b).expect("one run");
            let sub = cal.without(|k| cal.obs[k].block != b);
            let copied = pieces.block_copied(b, &sub);
            let ours = SessionSum::on(&pieces, b, &borrowed, b, &fit, &fit.estimated).expect("borrowed");
            let theirs = SessionSum::on(&pieces, b, &copied, 0, &fit, &fit.estimated).expect("copied");
            assert_eq!(ours.keys, theirs.keys, "session {b}");
            let bits = |m: &[f64]| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(ours.h.as_slice()), bits(theirs.h.as_slice()), "session {b}");
            assert_eq!(bits(ours.g.as_slice()), bits(theirs.g.as_slice()), "session {b}");
            assert_eq!(ours.cost.to_bits(), theirs.cost.to_bits(), "session {b}");
            assert!(ours.g.abs().max() > 0.0 && ours.keys.len() > fit.estimated.len(), "session {b}");
        }
        let probe = nalgebra::Rotation3::from_euler_angles(0.2, -0.1, 0.4).into_inner();
        let (nominal, data) = noisy_sessions(Some(probe));
        let options = SolveOptions { orientation_sigma_deg: Some(0.05), ..SolveOptions::default() };
        let pieces = Pieces::new(&nominal, &data, &options, data.encoders()).expect("pieces");
        assert!(pieces.block_borrowed(1).is_none());
    }

    /// Sums taken on a run's terms (built by its check, borrowed here) are those taken on terms
    /// of their own, to the bit.
    #[test]
    fn sums_on_a_runs_terms_are_the_sums_on_their_own() {
        let (nominal, cal) = noisy_sessions(None);
        let options = SolveOptions::default();
        let fit = calibrate(&nominal, &cal, &options).expect("fit");
        let terms = SharedTerms::default();
        let start = ToolFirstFit::default();
        check_data_sharing(&nominal, &cal, &fit.encoders, &options, &start, Some(&terms)).expect("checked");
        assert!(terms.is_built());
        let shared = SessionSums::of_sharing(&nominal, &fit, &cal, &options, Some(&terms)).expect("sums");
        let own = SessionSums::of(&nominal, &fit, &cal, &options).expect("sums");
        assert_eq!(shared.sessions.len(), cal.blocks.len());
        let bits = |m: &[f64]| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        for (a, b) in shared.sessions.iter().zip(&own.sessions) {
            assert_eq!((&a.name, &a.keys, a.cost.to_bits()), (&b.name, &b.keys, b.cost.to_bits()));
            assert_eq!(bits(a.h.as_slice()), bits(b.h.as_slice()), "{}", a.name);
            assert_eq!(bits(a.g.as_slice()), bits(b.g.as_slice()), "{}", a.name);
        }
    }

    /// The sums keep the terms of the observations they were taken on: a refit of those same
    /// observations borrows them, one of a copy (equal, at another address) builds its own, and
    /// both refits are the same to the bit.
    #[test]
    fn refits_of_the_summed_observations_borrow_their_terms() {
        let (nominal, cal) = noisy_sessions(None);
        let options = SolveOptions::default();
        let fit = calibrate(&nominal, &cal, &options).expect("fit");
        let sums = SessionSums::of(&nominal, &fit, &cal, &options).expect("sums");
        let floated = SolveOptions { float_tool: vec![cal.block_name(1)], ..options.clone() };
        let copy = cal.clone();
        let kept = sums.kept().map(TermSource::Kept);
        let same = Pieces::new_sharing(&nominal, &cal, &floated, &fit.encoders, kept).expect("pieces");
        let other = Pieces::new_sharing(&nominal, &copy, &floated, &fit.encoders, kept).expect("pieces");
        assert!(matches!(same.terms, Terms::Borrowed(_)));
        assert!(matches!(other.terms, Terms::Built(_)));
        let shared = recalibrate_with(&nominal, &cal, &floated, &sums).expect("refit");
        let built = recalibrate_with(&nominal, &copy, &floated, &sums).expect("refit");
        assert_eq!(shared.cost.to_bits(), built.cost.to_bits());
        assert!(shared.tool_offsets[0].offset_mm.iter().any(|v| *v != 0.0));
        assert_eq!(
            shared.tool_offsets[0].offset_mm.map(f64::to_bits),
            built.tool_offsets[0].offset_mm.map(f64::to_bits)
        );
        for id in &fit.estimated {
            assert_eq!(shared.model.get(*id).to_bits(), built.model.get(*id).to_bits(), "{id}");
        }
    }

    /// Artefact touches share their distances across blocks: no session sums.
    #[test]
    fn artefact_data_has_no_session_sums() {
        let nominal = ArmModel::suta_nominal();
        let sim = crate::simulate::simulate(&nominal, &crate::simulate::SimulationOptions::default());
        let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
        let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
        let fit = calibrate(&nominal, &cal, &options).expect("fit");
        assert!(SessionSums::of(&fit.model, &fit, &cal, &options).is_none());
    }
}
