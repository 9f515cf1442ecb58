//! What a calibration is made of, whatever the arm's values: the terms and unknowns of the
//! observations, the starts, and the checks before any solve.

use super::*;
use crate::calib::problem::{KeptForTerms, TermIndex};
use crate::data::Encoders;
use std::cell::OnceCell;
use std::ops::Deref;
use std::sync::OnceLock;

/// The terms of some pieces: built for their observations, or a run of another pieces' terms on
/// the same observations (a block's alone, [`Pieces::block_alone`]).
pub(super) enum Terms<'a> {
    Built(Vec<Box<dyn Term>>),
    Borrowed(&'a [Box<dyn Term>]),
}

impl Deref for Terms<'_> {
    type Target = [Box<dyn Term>];

    fn deref(&self) -> &[Box<dyn Term>] {
        match self {
            Terms::Built(terms) => terms,
            Terms::Borrowed(terms) => terms,
        }
    }
}

/// What a calibration of some observations is made of, whatever the arm's values.
pub(super) struct Pieces<'a> {
    pub(super) data: &'a Observations,
    pub(super) model: ArmModel,
    pub(super) terms: Terms<'a>,
    pub(super) framed: Vec<bool>,
    pub(super) floated: Vec<bool>,
    pub(super) drift: Vec<Option<DriftSlot>>,
    pub(super) resolved: Resolved,
    /// The encoder angles' sines and cosines, once for every problem of these terms.
    pub(super) encoders: Encoders,
    /// The terms' index, once for every problem of these terms (its buffers too).
    index: IndexCell<'a>,
}

/// Where some pieces' term index is kept: their own (taken at their first problem), or that of
/// the pieces whose terms (the same, of the same observations) they borrow.
enum IndexCell<'a> {
    Own(Box<OnceLock<TermIndex>>),
    Kept(&'a OnceLock<TermIndex>),
}

impl IndexCell<'_> {
    fn cell(&self) -> &OnceLock<TermIndex> {
        match self {
            IndexCell::Own(cell) => cell,
            IndexCell::Kept(cell) => cell,
        }
    }
}

/// The terms and encoder table of some pieces, kept for other pieces of the same observations
/// and term choice ([`Pieces::new_sharing`]). The observations are borrowed for as long as they
/// are kept: they cannot change meanwhile, so the same address is the same observations.
pub(super) struct KeptTerms<'a> {
    data: &'a Observations,
    choice: TermChoice,
    terms: Terms<'a>,
    encoders: Encoders,
    index: IndexCell<'a>,
}

/// Where some pieces may take their terms and encoder table from instead of building them.
#[derive(Clone, Copy)]
pub(super) enum TermSource<'a> {
    /// Another pieces' terms ([`Pieces::keep`]).
    Kept(&'a KeptTerms<'a>),
    /// The terms of a run's calibration data ([`SharedTerms`]).
    Shared(&'a SharedTerms<'a>),
}

/// The terms and encoder table of one run's calibration data, built by the first pieces of those
/// observations that ask (its check) and borrowed by the others of the same term choice (its
/// calibrations, its session sums) instead of built again: a box per point, built once.
#[derive(Default)]
pub(crate) struct SharedTerms<'a>(OnceCell<KeptTerms<'a>>);

impl<'a> SharedTerms<'a> {
    /// The terms kept of `data` with `choice`, from `build` when none are kept yet; `None` when
    /// those kept are of other observations or another choice.
    fn of(
        &'a self,
        data: &'a Observations,
        choice: TermChoice,
        build: impl FnOnce() -> KeptTerms<'a>,
    ) -> Option<&'a KeptTerms<'a>> {
        Some(self.0.get_or_init(build)).filter(|kept| kept.holds(data, choice))
    }
}

impl SharedTerms<'_> {
    /// Whether terms are kept.
    #[cfg(test)]
    pub(super) fn is_built(&self) -> bool {
        self.0.get().is_some()
    }
}

impl KeptTerms<'_> {
    /// Whether these are the terms of `data` (the same, by address) with `choice`.
    fn holds(&self, data: &Observations, choice: TermChoice) -> bool {
        std::ptr::eq(self.data, data) && self.choice == choice
    }
}

impl<'a> Pieces<'a> {
    /// Check `data` against `nominal` and `options` and assemble the terms and the unknowns.
    pub(super) fn new(
        nominal: &ArmModel,
        data: &'a Observations,
        options: &SolveOptions,
        encoders: &Encoders,
    ) -> Result<Pieces<'a>, CalibError> {
        Pieces::new_sharing(nominal, data, options, encoders, None)
    }

    /// [`Pieces::new`], the terms and encoder table borrowed from `kept` when it holds those of
    /// these observations (the same, by address) and term choice, instead of built again (built
    /// and kept there first when it is a [`SharedTerms`] holding none yet).
    pub(super) fn new_sharing(
        nominal: &ArmModel,
        data: &'a Observations,
        options: &SolveOptions,
        encoders: &Encoders,
        kept: Option<TermSource<'a>>,
    ) -> Result<Pieces<'a>, CalibError> {
        if !data.obs.is_empty() && nominal.joints.len() != data.joints {
            let tracker = data.obs.iter().any(|o| o.point_mm().is_some());
            return Err(CalibError::JointCount {
                kind: if tracker { "tracker" } else { "artefact" },
                record: if tracker { "have" } else { "record" },
                data: data.joints,
                what: if tracker { "joint columns (q1_deg …)" } else { "encoder angles" },
                model: nominal.joints.len(),
            });
        }
        let framed: Vec<bool> =
            data.blocks.iter().map(|b| data.groups[b.group].kind == Kind::Tracker).collect();
        for (b, block) in data.blocks.iter().enumerate().filter(|(b, _)| framed[*b]) {
            if block.members.len() < 3 {
                let group = &data.groups[block.group];
                return Err(CalibError::TooFewPoints {
                    path: group.source.display().to_string(),
                    session: data.block_name(b),
                    points: block.members.len(),
                });
            }
        }
        for name in &options.float_tool {
            if data.find_group(name).is_none() {
                return Err(CalibError::UnknownSession(name.clone()));
            }
        }
        let floated = data.groups.iter().map(|g| options.float_tool.contains(&g.name)).collect();
        let drift = drift_slots(data, &options.drift_sessions)?;
        let mut model = nominal.clone();
        // An instrument's tool point (a reflector, a probe) is never known to the data's accuracy.
        let instrument = framed.iter().any(|f| *f) || data.obs.iter().any(|o| o.unframed_mm().is_some());
        if instrument {
            for k in 0..3 {
                if !model.free.iter().any(|f| f.id == ParamId::Tcp(k)) {
                    let v = model.tcp_mm[k];
                    model.free_param(ParamId::Tcp(k), v - TOOL_HALF_RANGE_MM, v + TOOL_HALF_RANGE_MM);
                }
            }
        }
        let mut resolved = options.resolve(data);
        if data.kind() == Some(crate::data::DataKind::Mixed) {
            let touch_std_mm = crate::calib::repeats::touch_std_mm(nominal, data);
            resolved.point_weight = options.point_weight(data, touch_std_mm);
        }
        let choice = term_choice(&resolved);
        let build = || KeptTerms {
            data,
            choice,
            terms: Terms::Built(terms::build(data, &choice)),
            encoders: encoders.for_data(data),
            index: IndexCell::Own(Box::default()),
        };
        let kept = match kept {
            Some(TermSource::Kept(kept)) => Some(kept).filter(|k| k.holds(data, choice)),
            Some(TermSource::Shared(shared)) => shared.of(data, choice, build),
            None => None,
        };
        let (terms, encoders, index) = match kept {
            Some(kept) => {
                (Terms::Borrowed(&kept.terms), kept.encoders.clone(), IndexCell::Kept(kept.index.cell()))
            }
            None => {
                let KeptTerms { terms, encoders, index, .. } = build();
                (terms, encoders, index)
            }
        };
        Ok(Pieces { data, model, terms, framed, floated, drift, resolved, encoders, index })
    }

    /// The terms and encoder table of these pieces, kept for others of the same observations.
    pub(super) fn keep(self) -> KeptTerms<'a> {
        KeptTerms {
            data: self.data,
            choice: term_choice(&self.resolved),
            terms: self.terms,
            encoders: self.encoders,
            index: self.index,
        }
    }

    /// These pieces on block `b`'s observations alone: the same model, options and unknowns
    /// (block `b`'s own, the arm's, the floated tools and the probe's, in the same columns), so
    /// that each of its terms is the term of these pieces on the same observation. Borrowed
    /// ([`Pieces::block_borrowed`]) when it can be, else on a copy of block `b`'s observations
    /// put in `sub` ([`Pieces::block_copied`]). Returns the pieces and block `b`'s index in their
    /// observations.
    pub(super) fn block_alone<'s>(
        &'s self,
        b: usize,
        sub: &'s mut Option<Observations>,
    ) -> (Pieces<'s>, usize) {
        match self.block_borrowed(b) {
            Some(alone) => (alone, b),
            None => (self.block_copied(b, sub.insert(self.data.without(|k| self.data.obs[k].block != b))), 0),
        }
    }

    /// [`Pieces::block_alone`] on these observations, block `b`'s terms borrowed, when they are
    /// one run of these terms (a tracker session without orientations): every other block has
    /// no unknowns and no terms.
    pub(super) fn block_borrowed(&self, b: usize) -> Option<Pieces<'_>> {
        let run = self.run_of(b)?;
        let blocks = self.data.blocks.len();
        let mut framed = vec![false; blocks];
        framed[b] = self.framed[b];
        let mut drift = vec![None; blocks];
        drift[b] = self.drift[b].map(|d| DriftSlot { column: 0, ..d });
        Some(Pieces {
            data: self.data,
            model: self.model.clone(),
            terms: Terms::Borrowed(&self.terms[run]),
            framed,
            floated: self.floated.clone(),
            drift,
            resolved: self.resolved,
            encoders: self.encoders.clone(),
            index: IndexCell::Own(Box::default()),
        })
    }

    /// [`Pieces::block_alone`] on `sub`, block `b`'s observations alone (`data.without` every
    /// other block, which keeps the groups): its terms built there.
    pub(super) fn block_copied<'s>(&self, b: usize, sub: &'s Observations) -> Pieces<'s> {
        let terms = Terms::Built(terms::build(sub, &term_choice(&self.resolved)));
        // The encoder table's rows of block b's observations: sub's terms read no other.
        let rows: Vec<usize> = (0..self.data.obs.len()).filter(|&k| self.data.obs[k].block == b).collect();
        let encoders = self.encoders.rows_of(&rows);
        debug_assert_eq!(encoders.table().len(), sub.obs.len() * self.data.joints);
        Pieces {
            data: sub,
            model: self.model.clone(),
            terms,
            framed: vec![self.framed[b]; sub.blocks.len()],
            floated: self.floated.clone(),
            drift: vec![self.drift[b].map(|d| DriftSlot { column: 0, ..d }); sub.blocks.len()],
            resolved: self.resolved,
            encoders,
            index: IndexCell::Own(Box::default()),
        }
    }

    /// The terms of block `b`, when they are one run of these terms.
    fn run_of(&self, b: usize) -> Option<std::ops::Range<usize>> {
        let first = self.terms.iter().position(|t| t.block() == b).unwrap_or(self.terms.len());
        let end = first + self.terms[first..].iter().take_while(|t| t.block() == b).count();
        let run = first..end;
        self.terms[end..].iter().all(|t| t.block() != b).then_some(run)
    }

    /// Whether any block or group has unknowns of its own (frames, floated tools, drifts).
    pub(super) fn blocked(&self) -> bool {
        self.framed.iter().chain(&self.floated).any(|f| *f) || self.drift.iter().any(Option::is_some)
    }

    pub(super) fn layout(&self, arm: Vec<ParamId>) -> Layout {
        let rotation = self.resolved.orientation_weight_mm_per_rad.is_some();
        Layout::new(arm, &self.framed, &self.floated, rotation, &self.drift)
    }

    /// The problem over `arm` around `model`, frames starting at `frames`, the probe at `probe`.
    pub(super) fn problem<'p>(
        &'p self,
        arm: Vec<ParamId>,
        model: &'p ArmModel,
        frames: &[Frame],
        probe: Option<Matrix3<f64>>,
    ) -> Problem<'p> {
        let index = self.index.cell().get_or_init(|| TermIndex::of(self.data, &self.terms));
        Problem::with_kept(
            self.layout(arm),
            model,
            self.data,
            &self.terms,
            frames.iter().map(|f| f.rotation).collect(),
            probe.filter(|_| self.resolved.orientation_weight_mm_per_rad.is_some()),
            Some(KeptForTerms::of(&self.encoders, index)),
        )
    }

    /// Each block's frame at its closed form for `model` (tool offsets zero), the identity for a
    /// block without one.
    pub(super) fn closed_form_frames(&self, model: &ArmModel) -> Vec<Frame> {
        let data = self.data;
        let zero = Vector3::zeros();
        (0..data.blocks.len())
            .map(|b| {
                if !self.framed[b] {
                    return Frame::identity();
                }
                let members = &data.blocks[b].members;
                let robot = model_points(model, data, members.iter().copied(), &zero);
                let measured: Vec<Vector3<f64>> =
                    members.iter().map(|&k| data.obs[k].point_mm().unwrap_or_default()).collect();
                Frame::fit(&robot, &measured)
            })
            .collect()
    }

    /// The unknowns at `model`'s values with `frames` (rotations re-centred), the groups' tool
    /// offsets `tools`, the probe at its start and the drifts `drifts`.
    pub(super) fn x_of(
        &self,
        problem: &Problem,
        model: &ArmModel,
        frames: &[Frame],
        tools: &[Vector3<f64>],
        drifts: &[Vec<f64>],
    ) -> Vec<f64> {
        let layout = &problem.layout;
        let mut x: Vec<f64> = layout.arm.iter().map(|id| model.get(*id)).collect();
        x.resize(layout.unknowns(), 0.0);
        for (b, f) in frames.iter().enumerate() {
            if let Some(c) = layout.frame_column(b) {
                x[c..c + 3].copy_from_slice(&[0.0; 3]);
                x[c + 3..c + FRAME_UNKNOWNS].copy_from_slice(f.translation_mm.as_slice());
            }
        }
        for (g, t) in tools.iter().enumerate() {
            if let Some(c) = layout.tool_column(g) {
                x[c..c + 3].copy_from_slice(t.as_slice());
            }
        }
        for (b, d) in drifts.iter().enumerate() {
            if let Some((c, slot)) = layout.drift(b) {
                for k in 0..slot.kind.unknowns() {
                    x[c + k] = d.get(k).copied().unwrap_or(0.0);
                }
            }
        }
        x
    }

    pub(super) fn bounds(&self, params: &[ParamId], unknowns: usize) -> (Vec<f64>, Vec<f64>) {
        let bound = |id: &ParamId| self.model.free.iter().find(|f| f.id == *id);
        let mut lower: Vec<f64> =
            params.iter().map(|id| bound(id).map_or(f64::NEG_INFINITY, |f| f.lower)).collect();
        let mut upper: Vec<f64> =
            params.iter().map(|id| bound(id).map_or(f64::INFINITY, |f| f.upper)).collect();
        lower.resize(unknowns, -1e9);
        upper.resize(unknowns, 1e9);
        (lower, upper)
    }

    pub(super) fn range(&self, id: ParamId) -> f64 {
        self.model.free.iter().find(|f| f.id == id).map_or(1.0, |f| (f.upper - f.lower).max(1e-9))
    }

    pub(super) fn distance_rows(&self) -> usize {
        self.terms.iter().filter(|t| t.rows() == 1 && t.is_position()).count()
    }
}

/// The terms `resolved` asks for.
fn term_choice(resolved: &Resolved) -> TermChoice {
    TermChoice {
        relative_orientation_lever_mm: resolved.relative_lever_mm,
        orientation_weight_mm_per_rad: resolved.orientation_weight_mm_per_rad,
        point_weight: resolved.point_weight,
    }
}

pub(super) fn jacobian_at(problem: &Problem, x: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let m = problem.len();
    let mut r = vec![0.0; m];
    let mut jac = vec![0.0; m * x.len()];
    problem.evaluate(x, &mut r, Some(&mut jac));
    (r, jac)
}

/// Solve from the nominal values (start 0) or from random points inside the bounds (starts 1..),
/// keeping the lowest cost (the earliest start on a tie) inside the bounds (lower, upper), scanned from `incumbent` (a start
/// solved before, with its number) when given: the start kept, its number, and each start's
/// outcome. Random start k is the same point whichever starts are run; the starts run in
/// parallel on every core.
pub(super) fn solve_from_starts(
    problem: &Problem,
    x_nominal: &[f64],
    (lower, upper): (&[f64], &[f64]),
    options: &SolverOptions,
    seed: u64,
    starts: std::ops::RangeInclusive<usize>,
    incumbent: Option<(usize, solver::Solution)>,
) -> (usize, solver::Solution, Vec<StartOutcome>) {
    let points = start_points(x_nominal, lower, upper, seed, starts);
    let solved: Vec<(StartOutcome, solver::Solution)> = points
        .par_iter()
        .map(|(start, x0)| {
            let s = solver::solve(problem, x0, lower, upper, options);
            let outcome = StartOutcome {
                start: *start,
                initial_cost: initial_cost(problem, x0, lower, upper, &s, options.loss),
                final_cost: s.cost,
                iterations: s.iterations,
                stop: s.stop,
            };
            (outcome, s)
        })
        .collect();
    let mut outcomes = Vec::new();
    let mut best = incumbent;
    for (outcome, s) in solved {
        if best.as_ref().is_none_or(|(_, b)| beats(s.cost, b.cost, options.ftol)) {
            best = Some((outcome.start, s));
        }
        outcomes.push(outcome);
    }
    let (start, best) = best.unwrap_or_else(|| (0, solver::solve(problem, x_nominal, lower, upper, options)));
    (start, best, outcomes)
}

/// Whether a later start's cost `candidate` beats the best so far, `best`: lower by more than
/// the solver's function tolerance, `ftol`·best. Starts that reach one minimum end with costs
/// apart by rounding, and which of them counts as lowest must not turn on it: the earliest start
/// wins a tie. A finite cost beats a best that is not.
pub(crate) fn beats(candidate: f64, best: f64, ftol: f64) -> bool {
    candidate.is_finite() && (!best.is_finite() || candidate < best - ftol * best.abs())
}

/// The cost at `x0`: the solve's own first evaluation when `x0` lies inside the bounds (the
/// solver starts at `x0` clamped), else an evaluation at `x0`.
pub(super) fn initial_cost(
    problem: &Problem,
    x0: &[f64],
    lower: &[f64],
    upper: &[f64],
    solution: &solver::Solution,
    loss: Loss,
) -> f64 {
    let inside = x0.iter().zip(lower.iter().zip(upper)).all(|(v, (l, u))| l <= v && v <= u);
    if inside {
        return solution.initial_cost;
    }
    let mut r0 = vec![0.0; problem.len()];
    problem.evaluate(x0, &mut r0, None);
    loss.cost(&r0)
}

/// The start points `starts`: 0 the nominal values, k ≥ 1 the k-th seeded random point inside the
/// bounds (the same whichever starts are run).
pub(super) fn start_points(
    x_nominal: &[f64],
    lower: &[f64],
    upper: &[f64],
    seed: u64,
    starts: std::ops::RangeInclusive<usize>,
) -> Vec<(usize, Vec<f64>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..=*starts.end())
        .map(|start| {
            let x0: Vec<f64> = if start == 0 {
                x_nominal.to_vec()
            } else {
                lower.iter().zip(upper).map(|(l, u)| l + (u - l) * rng.random::<f64>()).collect()
            };
            (start, x0)
        })
        .filter(|(start, _)| starts.contains(start))
        .collect()
}

/// The dense Jacobian at the nominal values after the checks of a problem without frames.
pub(super) fn check_dense<'p>(
    pieces: &'p Pieces,
    all: &[ParamId],
) -> Result<(Problem<'p>, Vec<f64>), CalibError> {
    if all.is_empty() {
        return Err(CalibError::NothingFree);
    }
    let full =
        pieces.problem(all.to_vec(), &pieces.model, &vec![Frame::identity(); pieces.data.blocks.len()], None);
    let unknowns = full.layout.unknowns();
    let pairs = pieces.distance_rows();
    if pairs < all.len() {
        return Err(CalibError::TooFewPairs { pairs, params: all.len() });
    }
    if full.len() < unknowns {
        return Err(CalibError::TooFewResiduals { residuals: full.len(), unknowns });
    }
    let mut x0 = pieces.model.free_values();
    x0.resize(unknowns, 0.0);
    let (r0, jac) = jacobian_at(&full, &x0);
    if !r0.iter().chain(&jac).all(|v| v.is_finite()) {
        return Err(CalibError::NonFinite);
    }
    // Over its whole range, no free parameter moves any residual by a measurable amount.
    let ranges: Vec<f64> = all.iter().map(|&id| pieces.range(id)).collect();
    let n = unknowns;
    if jac.iter().enumerate().all(|(k, v)| k % n >= all.len() || (v * ranges[k % n]).abs() < NEGLIGIBLE_MM) {
        return Err(CalibError::NothingIdentifiable);
    }
    Ok((full, jac))
}

/// The group factors at `x0` after the checks of a problem with frames.
pub(super) fn check_framed(
    full: &Problem,
    x0: &[f64],
) -> Result<Vec<crate::calib::problem::GroupFactor>, CalibError> {
    check_rows(full)?;
    full.group_factors(x0).ok_or(CalibError::NonFinite)
}

/// The checks of [`check_framed`] on the residuals alone (no derivatives, no factors): enough
/// residuals for the unknowns, all finite at `x0`.
pub(super) fn check_residuals(full: &Problem, x0: &[f64]) -> Result<(), CalibError> {
    check_rows(full)?;
    let mut r = vec![0.0; full.len()];
    full.evaluate(x0, &mut r, None);
    match r.iter().all(|v| v.is_finite()) {
        true => Ok(()),
        false => Err(CalibError::NonFinite),
    }
}

/// At least as many residuals as unknowns.
pub(super) fn check_rows(full: &Problem) -> Result<(), CalibError> {
    let unknowns = full.layout.unknowns();
    match full.len() < unknowns {
        true => Err(CalibError::TooFewResiduals { residuals: full.len(), unknowns }),
        false => Ok(()),
    }
}
