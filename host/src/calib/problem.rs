//! The calibration problem (Ceres' Problem): the terms of every block over one parameter vector
//! ([`crate::calib::layout`]), as the residuals the solver minimises.
//!
//! Each evaluation turns the unknowns into values once, computes the tool pose of every
//! observation a term reads once (with its derivatives over the arm's columns when a Jacobian is
//! wanted; the encoder angles' sines and cosines kept from the problem's making), and lets every
//! term read them. The solver gets no m × n Jacobian: each term's
//! derivatives over its own columns (the arm's, its block's frame, tool and drift, the probe
//! rotation's) are added into JᵀWJ and JᵀWr as it is evaluated, in fixed blocks of terms summed in
//! order (the same sums on any thread count); the cost per observation is O(own columns²), flat in
//! the number of observations, and the memory beyond the poses is O(n²).
//!
//! Identifiability sees the block unknowns ([`Problem::group_factors`]): the rows of each group
//! folded block by block by QR into a small R factor over [its own columns | the arm's | the
//! probe rotation's], from which the own columns are projected out of the arm's (what a frame
//! or a floated tool can reproduce, the data cannot attribute to the arm).

use crate::calib::layout::{Layout, State};
use crate::calib::terms::{ArmPositions, Poses, Term, TermInput, TermJacobian};
use crate::data::encoders::pairs;
use crate::data::{Encoders, Observations};
use crate::model::kinematics::{encoder_sin_cos, Flange, PoseDerivative, Tips, ToolPose};
use crate::model::{ArmModel, ParamId};
use crate::numerics::normal::{add_and_clear, add_rows_gram, GramBuffers, NormalSums, RowTarget, TermRows};
use crate::numerics::qr::{r_factor_of_stacked, r_factor_overwriting};
use crate::numerics::solver::{symmetric, Loss, Residuals};
use nalgebra::{DMatrix, DVector, Matrix3};
use rayon::prelude::*;
use std::borrow::Cow;
use std::ops::Range;
use std::sync::{Mutex, OnceLock};

/// A run of terms: the first one's index, the terms, their residual rows.
type Run<'t, 'r> = (usize, &'t [Box<dyn Term>], &'r mut [f64]);

/// Fewest observations whose poses one thread computes (a pose with its Jacobian takes a
/// fraction of a µs: fewer are not worth waking a thread for).
const MIN_POSES_PER_TASK: usize = 256;
/// Fewest terms one thread evaluates (a term takes tens of ns).
const MIN_TERMS_PER_TASK: usize = 4096;

/// Most blocks the terms of the normal equations are summed in (each holds an n × n sum).
const MAX_BLOCKS: usize = 16;
/// Fewest terms of a block.
const MIN_BLOCK_TERMS: usize = 64;
/// Terms whose poses with their derivatives are computed together in a block of the normal
/// equations (25 arm columns of 72 bytes each: 57 kB for 32 point terms, which stay in cache).
const POSES_AT_ONCE: usize = 32;
/// Terms of a group folded into its factor by one QR.
const FOLD_TERMS: usize = 128;

/// A chunk's buffers of pose derivatives and poses (those of [`Poses`]).
type ChunkBuffers = (Vec<PoseDerivative>, Vec<Option<ToolPose>>);

/// What every problem of the same terms of the same observations shares, whatever its layout and
/// values: each term's first residual row, which observations the terms read and whether they
/// are all positions (taken once), and the buffers evaluations leave for the next (of any of
/// these problems: a caller making many, a solve's passes and a refit's, keeps one index).
pub struct TermIndex {
    offsets: Vec<usize>,
    rows: usize,
    read: Vec<bool>,
    /// The observations from the first to the last one a term reads.
    read_span: Range<usize>,
    positions_only: bool,
    /// The pose-derivative and pose buffers of chunks evaluated, for the next chunks: a solve's
    /// evaluations allocate and zero none (each pose writes its own columns; the entries of
    /// observations a chunk does not read are never read; the poses are set to `None` first).
    spare: Mutex<Vec<ChunkBuffers>>,
    /// Which observations a chunk reads, a buffer per chunk evaluated at once.
    spare_wanted: Mutex<Vec<Vec<bool>>>,
    /// The normal sums of chunks evaluated, for the next chunks (their batches' buffers).
    spare_sums: Mutex<Vec<NormalSums>>,
    /// Zeroed sums (n × n and n) for the next chunks' normal sums to start on: each chunk's sums
    /// are zeroed as they are added into the totals, instead of allocated zeroed again.
    spare_zeroed: Mutex<Vec<(Vec<f64>, Vec<f64>)>>,
}

impl TermIndex {
    /// The index of `terms` of `data`.
    pub fn of(data: &Observations, terms: &[Box<dyn Term>]) -> TermIndex {
        let mut offsets = Vec::with_capacity(terms.len());
        let mut rows = 0;
        for t in terms {
            offsets.push(rows);
            rows += t.rows();
        }
        let read = observations_read(data, terms);
        let read_span = read.iter().position(|&r| r).map_or(0..0, |first| {
            let last = read.iter().rposition(|&r| r).unwrap_or(first);
            first..last + 1
        });
        TermIndex {
            offsets,
            rows,
            read,
            read_span,
            positions_only: terms.iter().all(|t| t.is_position()),
            spare: Mutex::new(Vec::new()),
            spare_wanted: Mutex::new(Vec::new()),
            spare_sums: Mutex::new(Vec::new()),
            spare_zeroed: Mutex::new(Vec::new()),
        }
    }
}

/// A problem's term index: its own, or one kept by its caller.
enum Index<'a> {
    Own(TermIndex),
    Kept(&'a TermIndex),
}

impl std::ops::Deref for Index<'_> {
    type Target = TermIndex;

    fn deref(&self) -> &TermIndex {
        match self {
            Index::Own(index) => index,
            Index::Kept(index) => index,
        }
    }
}

/// What a caller that makes many problems of the same terms keeps for them: the encoder angles'
/// sines and cosines of [`encoder_table`] and the [`TermIndex`] of those terms and observations.
pub struct KeptForTerms<'a> {
    /// `data.joints` sines and cosines per row.
    pub sin_cos: &'a [(f64, f64)],
    /// Observation `k`'s row, when not row `k` (a selection of a table's rows, read where they
    /// are: `Encoders::by_index`).
    pub rows: Option<&'a [usize]>,
    /// The terms' index.
    pub index: &'a TermIndex,
}

impl<'a> KeptForTerms<'a> {
    /// The rows of `encoders` (which hold the observations' angles: [`Encoders::for_data`]) and
    /// the terms' `index`.
    pub(crate) fn of(encoders: &'a Encoders, index: &'a TermIndex) -> KeptForTerms<'a> {
        let (sin_cos, rows) = encoders.by_index();
        KeptForTerms { sin_cos, rows, index }
    }
}

/// The terms of some observations over one parameter vector.
pub struct Problem<'a> {
    /// Where each unknown sits.
    pub layout: Layout,
    model: &'a ArmModel,
    data: &'a Observations,
    terms: &'a [Box<dyn Term>],
    index: Index<'a>,
    /// Per observation read, the sine and cosine of each encoder angle (`joints` per row).
    sin_cos: Cow<'a, [(f64, f64)]>,
    /// Observation `k`'s row of `sin_cos`, when not row `k` ([`KeptForTerms::rows`]).
    rows: Option<&'a [usize]>,
    joints: usize,
    frame_start: Vec<Matrix3<f64>>,
    probe_start: Option<Matrix3<f64>>,
    /// Per observation, its pose's frame at the flange (those of observations no term reads at
    /// their default), taken at the first normal equations or group factors when every chain starts
    /// its poses there for the columns ([`Tips::start_at_flange`]; `None` inside otherwise):
    /// the unknowns then move the tool point and the scale alone, so every evaluation's flanges
    /// are the same. Kept with the arm's columns they were taken for: a layout changed since
    /// then takes the whole pass.
    flanges: OnceLock<Option<(Vec<ParamId>, Vec<Flange>)>>,
}

impl<'a> Problem<'a> {
    /// The problem of `terms` over `layout`; parameters not in `layout.arm` keep their values in
    /// `model`; each block's frame starts at `frame_start[b]`, the probe at `probe_start`.
    pub fn new(
        layout: Layout,
        model: &'a ArmModel,
        data: &'a Observations,
        terms: &'a [Box<dyn Term>],
        frame_start: Vec<Matrix3<f64>>,
        probe_start: Option<Matrix3<f64>>,
    ) -> Problem<'a> {
        Problem::with_kept(layout, model, data, terms, frame_start, probe_start, None)
    }

    /// As [`Problem::new`], with the encoder table and term index `kept` by a caller that makes
    /// many problems of the same `data` and `terms` (made here when none are kept).
    pub fn with_kept(
        mut layout: Layout,
        model: &'a ArmModel,
        data: &'a Observations,
        terms: &'a [Box<dyn Term>],
        frame_start: Vec<Matrix3<f64>>,
        probe_start: Option<Matrix3<f64>>,
        kept: Option<KeptForTerms<'a>>,
    ) -> Problem<'a> {
        let (sin_cos, rows, index) = match kept {
            Some(kept) => {
                debug_assert_eq!(kept.index.offsets.len(), terms.len());
                (Cow::Borrowed(kept.sin_cos), kept.rows, Index::Kept(kept.index))
            }
            None => (Cow::Owned(encoder_table(data, terms)), None, Index::Own(TermIndex::of(data, terms))),
        };
        // Terms of positions alone read no derivative of the tool's axes.
        if index.positions_only {
            layout.columns = layout.columns.positions_only();
        }
        let joints = data.joints;
        Problem {
            layout,
            model,
            data,
            terms,
            index,
            sin_cos,
            rows,
            joints,
            frame_start,
            probe_start,
            flanges: OnceLock::new(),
        }
    }

    /// The problem taking the whole pass for every pose, its flanges never kept (the plain path
    /// the flanges' must equal).
    #[cfg(test)]
    fn with_whole_passes(self) -> Self {
        Problem { flanges: OnceLock::from(None), ..self }
    }

    /// Observation `k`'s encoder sines and cosines.
    fn sin_cos(&self, k: usize) -> &[(f64, f64)] {
        let r = self.rows.map_or(k, |rows| rows[k]);
        &self.sin_cos[r * self.joints..(r + 1) * self.joints]
    }

    /// The observations the terms read.
    pub fn data(&self) -> &'a Observations {
        self.data
    }

    /// The terms.
    pub fn terms(&self) -> &[Box<dyn Term>] {
        self.terms
    }

    /// First residual row of each term.
    pub fn offsets(&self) -> &[usize] {
        &self.index.offsets
    }

    /// The values at `x`.
    pub fn state(&self, x: &[f64]) -> State {
        self.layout.state(self.model, x, &self.frame_start, self.probe_start.as_ref())
    }

    /// Each block's start rotation.
    pub fn frame_start(&self) -> &[Matrix3<f64>] {
        &self.frame_start
    }

    /// The probe rotation's start.
    pub fn probe_start(&self) -> Option<&Matrix3<f64>> {
        self.probe_start.as_ref()
    }

    /// The tool pose of every observation a term reads, with its derivatives when `jacobian`.
    pub fn poses(&self, state: &State, jacobian: bool) -> Poses {
        let arm = self.layout.arm.len();
        let columns = &self.layout.columns;
        let data = self.data;
        let kinematics = Tips::new(&state.model);
        let mut chain = if jacobian { vec![[0.0; 9]; data.obs.len() * arm] } else { Vec::new() };
        let pose = if jacobian && arm > 0 {
            chain
                .par_chunks_mut(arm)
                .enumerate()
                .with_min_len(MIN_POSES_PER_TASK)
                .map(|(k, d)| {
                    self.index.read[k].then(|| {
                        kinematics.tip(data.obs[k].tip).pose_with_sin_cos_and_jacobian(
                            &data.obs[k].q_deg,
                            self.sin_cos(k),
                            columns,
                            d,
                        )
                    })
                })
                .collect()
        } else if jacobian {
            (0..data.obs.len())
                .into_par_iter()
                .with_min_len(MIN_POSES_PER_TASK)
                .map(|k| {
                    self.index.read[k].then(|| {
                        kinematics.tip(data.obs[k].tip).pose_with_sin_cos_and_jacobian(
                            &data.obs[k].q_deg,
                            self.sin_cos(k),
                            columns,
                            &mut [],
                        )
                    })
                })
                .collect()
        } else {
            let mut pose = vec![None; data.obs.len()];
            pose.par_chunks_mut(MIN_POSES_PER_TASK)
                .enumerate()
                .for_each(|(chunk, out)| self.poses_into(&kinematics, chunk * MIN_POSES_PER_TASK, out));
            pose
        };
        Poses { first: 0, pose, chain, arm, jacobian }
    }

    /// The tool pose of each observation a term reads among `out.len()` from `first` into `out`,
    /// two observations of one tip at a time (the same poses, to the bit, as one at a time).
    fn poses_into(&self, kinematics: &Tips, first: usize, out: &mut [Option<ToolPose>]) {
        let obs = &self.data.obs;
        let read = (first..first + out.len()).filter(|&k| self.index.read[k]);
        for (a, second) in pairs(read, |a, b| obs[a].tip == obs[b].tip) {
            let chain = kinematics.tip(obs[a].tip);
            match second {
                Some(b) => {
                    let [pa, pb] = chain.pose_pair_with_sin_cos(
                        [&obs[a].q_deg, &obs[b].q_deg],
                        [self.sin_cos(a), self.sin_cos(b)],
                    );
                    (out[a - first], out[b - first]) = (Some(pa), Some(pb));
                }
                None => out[a - first] = Some(chain.pose_with_sin_cos(&obs[a].q_deg, self.sin_cos(a))),
            }
        }
    }

    /// The tool poses with their derivatives of the observations `terms` read, on the chains
    /// `kinematics` of the state's model (computed on this thread, held only for them: the
    /// memory of a chunk, not of every observation).
    fn chunk_poses(&self, kinematics: &Tips, terms: &[Box<dyn Term>]) -> Poses {
        if terms.len() == self.terms.len() && !self.index.read_span.is_empty() {
            // Every term (the dense problem's one chunk): the observations read are known from
            // the problem's making, not looked up term by term at each evaluation.
            return self.wanted_poses(
                kinematics,
                self.index.read_span.start,
                &self.index.read[self.index.read_span.clone()],
            );
        }
        self.chunk_poses_on(kinematics, &terms.iter().map(|t| t.as_ref()).collect::<Vec<_>>())
    }

    /// As [`Problem::chunk_poses`] for terms given by reference, on the chains of `state`.
    fn chunk_poses_of(&self, state: &State, terms: &[&dyn Term]) -> Poses {
        self.chunk_poses_on(&Tips::new(&state.model), terms)
    }

    /// As [`Problem::chunk_poses`] for terms given by reference.
    fn chunk_poses_on(&self, kinematics: &Tips, terms: &[&dyn Term]) -> Poses {
        let read = || terms.iter().flat_map(|t| t.observations().iter().copied());
        let (first, last) = read().fold((usize::MAX, 0), |(a, b), k| (a.min(k), b.max(k)));
        if first > last {
            return Poses {
                first: 0,
                pose: Vec::new(),
                chain: Vec::new(),
                arm: self.layout.arm.len(),
                jacobian: true,
            };
        }
        let mut wanted =
            self.index.spare_wanted.lock().ok().and_then(|mut spare| spare.pop()).unwrap_or_default();
        wanted.clear();
        wanted.resize(last + 1 - first, false);
        read().for_each(|k| wanted[k - first] = true);
        let poses = self.wanted_poses(kinematics, first, &wanted);
        if let Ok(mut spare) = self.index.spare_wanted.lock() {
            spare.push(wanted);
        }
        poses
    }

    /// The tool poses with their derivatives of the observations `first + k` for which
    /// `wanted[k]` (at least one), on the chains `kinematics` (from their flanges when the
    /// problem keeps them).
    fn wanted_poses(&self, kinematics: &Tips, first: usize, wanted: &[bool]) -> Poses {
        let arm = self.layout.arm.len();
        let last = first + wanted.len() - 1;
        let (mut chain, mut pose) =
            self.index.spare.lock().ok().and_then(|mut spare| spare.pop()).unwrap_or_default();
        chain.resize(wanted.len() * arm, [0.0; 9]);
        pose.clear();
        pose.resize(wanted.len(), None);
        let columns = &self.layout.columns;
        let flanges = self.flanges(kinematics);
        let single = |k: usize, chain: &mut [PoseDerivative]| {
            let (q, tip) = (&self.data.obs[k].q_deg, self.data.obs[k].tip);
            let d = &mut chain[(k - first) * arm..(k - first + 1) * arm];
            let chain = kinematics.tip(tip);
            Some(match flanges {
                Some(flanges) => chain.pose_from_flange(&flanges[k], columns, d),
                None => chain.pose_with_sin_cos_and_jacobian(q, self.sin_cos(k), columns, d),
            })
        };
        // Two observations of one tip at a time: their poses are carried through the chain
        // together.
        let obs = &self.data.obs;
        let read = (first..=last).filter(|k| wanted[k - first]);
        for (a, second) in pairs(read, |a, b| obs[a].tip == obs[b].tip) {
            let Some(b) = second else {
                pose[a - first] = single(a, &mut chain);
                continue;
            };
            let (oa, ob) = (&obs[a], &obs[b]);
            let (before, after) = chain.split_at_mut((b - first) * arm);
            let jacobian = [&mut before[(a - first) * arm..][..arm], &mut after[..arm]];
            let tip = kinematics.tip(oa.tip);
            let [pa, pb] = match flanges {
                Some(flanges) => tip.pose_pair_from_flanges([&flanges[a], &flanges[b]], columns, jacobian),
                None => tip.pose_pair_with_sin_cos_and_jacobian(
                    [&oa.q_deg, &ob.q_deg],
                    [self.sin_cos(a), self.sin_cos(b)],
                    columns,
                    jacobian,
                ),
            };
            (pose[a - first], pose[b - first]) = (Some(pa), Some(pb));
        }
        Poses { first, pose, chain, arm, jacobian: true }
    }

    /// The flanges the problem keeps (see its field), taken on `kinematics` (the chains of any
    /// state: the parameters they read before the tool do not change) at the first call, in one
    /// pass on the calling thread: taken in parallel, the thread taking them could steal a task
    /// of the same evaluation that waits for them, and so wait for itself.
    /// A layout whose arm columns are not those the flanges were taken for (changed since) gets
    /// none: one comparison per call, not the columns' check.
    fn flanges(&self, kinematics: &Tips) -> Option<&[Flange]> {
        let take = || {
            if !kinematics.start_at_flange(&self.layout.columns) {
                return None;
            }
            let obs = &self.data.obs;
            let mut flanges = vec![Flange::default(); obs.len()];
            let read = self.index.read_span.clone().filter(|&k| self.index.read[k]);
            for (a, second) in pairs(read, |a, b| obs[a].tip == obs[b].tip) {
                let chain = kinematics.tip(obs[a].tip);
                match second {
                    Some(b) => {
                        [flanges[a], flanges[b]] = chain.flange_pair(
                            [&obs[a].q_deg, &obs[b].q_deg],
                            [self.sin_cos(a), self.sin_cos(b)],
                        )?;
                    }
                    None => flanges[a] = chain.flange(&obs[a].q_deg, self.sin_cos(a))?,
                }
            }
            Some((self.layout.arm.clone(), flanges))
        };
        let (arm, flanges) = self.flanges.get_or_init(take).as_ref()?;
        (*arm == self.layout.arm).then_some(flanges.as_slice())
    }

    /// Keep the buffers of `poses` (of [`Problem::chunk_poses_of`]) for the next chunk.
    fn recycle(&self, poses: Poses) {
        if let Ok(mut spare) = self.index.spare.lock() {
            spare.push((poses.chain, poses.pose));
        }
    }

    /// The terms in runs of `len` (the last one shorter), each with its first term's index and
    /// its residual rows split off `r` (the rows of every term, as written by
    /// [`Residuals::evaluate`]).
    fn runs<'r>(&self, len: usize, r: &'r mut [f64]) -> Vec<Run<'a, 'r>> {
        let mut rest = r;
        let mut out = Vec::with_capacity(self.terms.len().div_ceil(len));
        for (k, terms) in self.terms.chunks(len).enumerate() {
            let first = k * len;
            let end = self.index.offsets.get(first + terms.len()).copied().unwrap_or(self.index.rows);
            let (mine, after) = rest.split_at_mut(end - self.index.offsets[first]);
            out.push((first, terms, mine));
            rest = after;
        }
        out
    }

    /// The residual rows of each term from term `first` on, split off `r` (theirs, in order)
    /// by the offsets kept (no call per term to ask its rows); as many as `r` holds.
    fn term_rows<'s, 'r: 's>(
        &'s self,
        first: usize,
        r: &'r mut [f64],
    ) -> impl Iterator<Item = &'r mut [f64]> + 's {
        let mut rest = r;
        let ends = self.index.offsets[first + 1..].iter().copied().chain([self.index.rows]);
        self.index.offsets[first..].iter().zip(ends).map_while(move |(&start, end)| {
            let (mine, after) = std::mem::take(&mut rest).split_at_mut_checked(end - start)?;
            rest = after;
            Some(mine)
        })
    }
}

/// Which observations `terms` read.
fn observations_read(data: &Observations, terms: &[Box<dyn Term>]) -> Vec<bool> {
    let mut read = vec![false; data.obs.len()];
    for t in terms {
        for &k in t.observations() {
            read[k] = true;
        }
    }
    read
}

/// The sine and cosine of each encoder angle of every observation `terms` read (`data.joints`
/// per observation; (0, 1) for one no term reads).
pub fn encoder_table(data: &Observations, terms: &[Box<dyn Term>]) -> Vec<(f64, f64)> {
    let read = observations_read(data, terms);
    let joints = data.joints;
    let mut sin_cos = vec![(0.0, 1.0); data.obs.len() * joints];
    for (k, o) in data.obs.iter().enumerate().filter(|(k, _)| read[*k]) {
        for (sc, &q) in sin_cos[k * joints..(k + 1) * joints].iter_mut().zip(o.q_deg.iter()) {
            *sc = encoder_sin_cos(q);
        }
    }
    sin_cos
}

impl Residuals for Problem<'_> {
    fn len(&self) -> usize {
        self.index.rows
    }

    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
        let state = self.state(x);
        let poses = self.poses(&state, jacobian.is_some());
        let input = TermInput { state: &state, layout: &self.layout, data: self.data, poses: &poses };
        let n = self.layout.unknowns();
        match jacobian {
            Some(dense) => {
                let mut rows = Vec::with_capacity(self.terms.len());
                let mut rest = dense;
                for t in self.terms {
                    let (mine, after) = rest.split_at_mut(t.rows() * n);
                    rows.push(mine);
                    rest = after;
                }
                let slices: Vec<&mut [f64]> = self.term_rows(0, r).collect();
                self.terms.par_iter().zip(slices).zip(rows).with_min_len(MIN_TERMS_PER_TASK).for_each_init(
                    TermJacobian::default,
                    |jac, ((t, r), dense)| {
                        jac.reset(t.rows());
                        t.evaluate(&input, r, Some(jac));
                        dense.fill(0.0);
                        for (p, &c) in jac.columns.iter().enumerate() {
                            for (a, v) in jac.column(p).iter().enumerate() {
                                dense[a * n + c] = *v;
                            }
                        }
                    },
                );
            }
            None => self.runs(MIN_TERMS_PER_TASK, r).into_par_iter().for_each(|(first, terms, r)| {
                for (t, r) in terms.iter().zip(self.term_rows(first, r)) {
                    t.evaluate(&input, r, None);
                }
            }),
        }
    }

    /// Term by term over each term's own columns, in fixed blocks summed in order (see the
    /// module doc). Without block unknowns every term reads every column: its rows are laid out
    /// densely as they come (`DenseRows`), and the blocks are larger (a block computes the
    /// poses of each observation its terms read, so the pairs of one placement split over two
    /// blocks would compute its touches' poses twice).
    fn normal_equations(&self, x: &[f64], r: &mut [f64], loss: Loss) -> (DMatrix<f64>, DVector<f64>) {
        let n = self.layout.unknowns();
        let state = self.state(x);
        let dense = !self.layout.has_block_unknowns();
        let least = if dense { MIN_TERMS_PER_TASK } else { MIN_BLOCK_TERMS };
        let block = self.terms.len().div_ceil(MAX_BLOCKS).max(least);
        let kinematics = Tips::new(&state.model);
        let sums: Vec<(Vec<f64>, Vec<f64>)> = self
            .runs(block, r)
            .into_par_iter()
            .map(|(first, terms, r)| {
                if dense {
                    let poses = self.chunk_poses(&kinematics, terms);
                    let input =
                        TermInput { state: &state, layout: &self.layout, data: self.data, poses: &poses };
                    let mut rows = DenseRows::new(n, &poses);
                    rows.add_terms(terms, &self.index.offsets[first..], &input, r, loss);
                    self.recycle(poses);
                    return (rows.h, rows.g);
                }
                let mut jac = TermJacobian::default();
                let mut rs = self.term_rows(first, r);
                let spare = self.index.spare_sums.lock().ok().and_then(|mut spare| spare.pop());
                let mut sums = spare.filter(|s| s.columns() == n).unwrap_or_else(|| NormalSums::new(n));
                let mut w = Vec::new();
                // The poses of a few terms at a time: their derivatives are read while in cache.
                for part in terms.chunks(POSES_AT_ONCE) {
                    let poses = self.chunk_poses(&kinematics, part);
                    let input =
                        TermInput { state: &state, layout: &self.layout, data: self.data, poses: &poses };
                    for (t, r) in part.iter().zip(rs.by_ref()) {
                        // A point writes its rows straight into the batch; any other term
                        // through its Jacobian.
                        let direct = t.evaluate_into_rows(&input, r, &mut sums);
                        if !direct {
                            jac.reset(t.rows());
                            t.evaluate(&input, r, Some(&mut jac));
                        }
                        w.clear();
                        w.extend(r.iter().map(|&v| loss.weight(v)));
                        if direct {
                            sums.close(r, &w);
                        } else {
                            sums.add(&jac.columns, &jac.values, r, &w);
                        }
                    }
                    self.recycle(poses);
                }
                let zeroed = self.index.spare_zeroed.lock().ok().and_then(|mut spare| spare.pop());
                let out = sums.finish_on(zeroed);
                if let Ok(mut spare) = self.index.spare_sums.lock() {
                    spare.push(sums);
                }
                out
            })
            .collect();
        let (mut upper, mut g) = (vec![0.0; n * n], vec![0.0; n]);
        let mut zeroed = Vec::with_capacity(sums.len());
        for (mut h_block, mut g_block) in sums {
            add_and_clear(&mut upper, &mut h_block);
            add_and_clear(&mut g, &mut g_block);
            zeroed.push((h_block, g_block));
        }
        if let Ok(mut spare) = self.index.spare_zeroed.lock() {
            spare.append(&mut zeroed);
        }
        (symmetric(n, &upper), DVector::from_vec(g))
    }
}

/// Rows a [`DenseRows`] batch holds before their Gram matrix is added (the `matrixmultiply`
/// crate's depth of one pass for `f64`: one batch is one pass over its packed panels).
const DENSE_BATCH_ROWS: usize = 256;

/// JᵀWJ (upper triangle, n × n row-major) and JᵀWr of terms whose rows read every one of n
/// columns, their rows written into a dense batch (a distance's in place, another term's copied
/// from its Jacobian): no m × n Jacobian, no per-row column lookup.
struct DenseRows {
    n: usize,
    h: Vec<f64>,
    g: Vec<f64>,
    /// The batch's rows (row-major, as many as the batch has), kept at the largest size reached
    /// and not zeroed for each row: a row written in place is written whole, one copied from a
    /// Jacobian is zeroed first.
    rows: Vec<f64>,
    /// The batch's weights.
    w: Vec<f64>,
    buffers: GramBuffers,
    /// The position derivatives of the terms' poses as their rows read them.
    positions: Option<ArmPositions>,
}

impl DenseRows {
    /// Empty sums over n columns, for terms reading `poses`.
    fn new(n: usize, poses: &Poses) -> DenseRows {
        let batch = DENSE_BATCH_ROWS + 8;
        DenseRows {
            n,
            positions: ArmPositions::of(poses),
            h: vec![0.0; n * n],
            g: vec![0.0; n],
            rows: vec![0.0; batch * n],
            w: Vec::with_capacity(batch),
            buffers: GramBuffers::default(),
        }
    }

    /// Evaluate `terms` at `input` into their residual rows `r` (theirs in order, the first
    /// term's first row `offsets[0]`, each term's first row in `offsets`) and add their rows
    /// weighed by `loss`: a one-row term writes its row straight into the batch when it can
    /// ([`Term::evaluate_into_row`]), any other through a [`TermJacobian`]. A batch's residuals
    /// are read where the terms wrote them in `r` (no copy per row), its weights taken when it
    /// is summed.
    fn add_terms(
        &mut self,
        terms: &[Box<dyn Term>],
        offsets: &[usize],
        input: &TermInput,
        r: &mut [f64],
        loss: Loss,
    ) {
        let (n, base) = (self.n, offsets.first().copied().unwrap_or(0));
        let mut jac = TermJacobian::default();
        // The batch's first row in `r`.
        let mut batch = 0;
        let ends = offsets.get(1..).unwrap_or_default().iter().map(|&o| o - base).chain([r.len()]);
        for ((t, &first), end) in terms.iter().zip(offsets).zip(ends) {
            let start = first - base;
            if !self.write_row(t.as_ref(), input, &mut r[start..end], start - batch) {
                jac.reset(end - start);
                t.evaluate(input, &mut r[start..end], Some(&mut jac));
                let rows = batch_rows(&mut self.rows, n, start - batch, end - start);
                rows.fill(0.0);
                for (p, &c) in jac.columns.iter().enumerate() {
                    for (a, v) in jac.column(p).iter().enumerate() {
                        rows[a * n + c] = *v;
                    }
                }
            }
            if end - batch >= DENSE_BATCH_ROWS {
                self.flush(&r[batch..end], loss);
                batch = end;
            }
        }
        self.flush(&r[batch..], loss);
    }

    /// A one-row term's residual into `r` and its row straight into row `at` of the batch
    /// ([`Term::evaluate_into_row`]); `false` when it has more rows or no such path.
    fn write_row(&mut self, t: &dyn Term, input: &TermInput, r: &mut [f64], at: usize) -> bool {
        let ([residual], Some(positions)) = (r, &self.positions) else { return false };
        // The batch holds more rows than a batch starts at: no growing for one row.
        let Some(row) = self.rows.get_mut(at * self.n..(at + 1) * self.n) else { return false };
        if cfg!(debug_assertions) {
            // A column the term leaves unwritten poisons the sums instead of reading an earlier
            // row.
            row.fill(f64::NAN);
        }
        t.evaluate_into_row(input, positions, residual, row)
    }

    /// Add the batch's rows, their residuals `r` weighed by `loss`, into the sums.
    fn flush(&mut self, r: &[f64], loss: Loss) {
        self.w.clear();
        self.w.extend(r.iter().map(|&v| loss.weight(v)));
        let rows = (&self.rows[..r.len() * self.n], self.n, self.n);
        add_rows_gram(&mut self.h, &mut self.g, rows, &self.w, r, &mut self.buffers);
    }
}

/// Rows `first..first + count` of a batch of rows of `n` columns (row-major), grown to hold them.
fn batch_rows(rows: &mut Vec<f64>, n: usize, first: usize, count: usize) -> &mut [f64] {
    let span = first * n..(first + count) * n;
    if rows.len() < span.end {
        rows.resize(span.end, 0.0);
    }
    &mut rows[span]
}

/// A group's rows of the Jacobian in a small matrix: the R factor of its columns [its own |
/// the arm's | the probe rotation's], folded block by block by QR. R has the column geometry of
/// those rows (every inner product of two columns), so what is computed from it (projections,
/// norms, singular values, pivoted QR) is what the m rows give, without an m × n matrix.
pub struct GroupFactor {
    /// The R factor.
    pub r: DMatrix<f64>,
    /// Its own columns (the first ones).
    pub own: usize,
    /// The problem's column of each of R's columns.
    pub columns: Vec<usize>,
    /// Jᵀr over the group's columns (in R's order), the rows unweighted.
    pub gradient: DVector<f64>,
    /// Σ ½r² over the group's residuals.
    pub half_squares: f64,
    /// The largest |r| of the group's residuals.
    pub largest_residual: f64,
}

impl Problem<'_> {
    /// Each group's factor at `x` (groups without terms left out); `None` when a residual or a
    /// derivative is not finite.
    pub fn group_factors(&self, x: &[f64]) -> Option<Vec<GroupFactor>> {
        let state = self.state(x);
        let (n, a) = (self.layout.unknowns(), self.layout.arm.len());
        let rotation: Vec<usize> =
            self.layout.rotation_column().map(|t| vec![t, t + 1, t + 2]).unwrap_or_default();
        let mut by_group: Vec<Vec<usize>> = vec![Vec::new(); self.data.groups.len()];
        // The buffers of chunks done, for the next chunks of any group (a group is often one
        // chunk).
        let spare: Mutex<Vec<FactorBuffers>> = Mutex::new(Vec::new());
        for (i, t) in self.terms.iter().enumerate() {
            by_group[self.data.blocks[t.block()].group].push(i);
        }
        by_group
            .iter()
            .enumerate()
            .filter(|(_, mine)| !mine.is_empty())
            .map(|(g, mine)| {
                let blocks: Vec<usize> =
                    (0..self.data.blocks.len()).filter(|&b| self.data.blocks[b].group == g).collect();
                let own = self.layout.own_columns(g, &blocks);
                let columns: Vec<usize> =
                    own.iter().copied().chain(0..a).chain(rotation.iter().copied()).collect();
                // Per column, its place in the group's rows (none: `usize::MAX`).
                let mut local = vec![usize::MAX; n];
                for (l, &c) in columns.iter().enumerate() {
                    local[c] = l;
                }
                let width = columns.len();
                let folded: Vec<Option<ChunkFactor>> = mine
                    .par_chunks(FOLD_TERMS)
                    .map(|chunk| {
                        let mut buffers =
                            spare.lock().ok().and_then(|mut spare| spare.pop()).unwrap_or_default();
                        let chosen: Vec<&dyn Term> = chunk.iter().map(|&i| self.terms[i].as_ref()).collect();
                        let poses = self.chunk_poses_of(&state, &chosen);
                        let input =
                            TermInput { state: &state, layout: &self.layout, data: self.data, poses: &poses };
                        let rows: usize = chunk.iter().map(|&i| self.terms[i].rows()).sum();
                        let FactorBuffers { jac, values, columns, r } = &mut buffers;
                        // Zero already (each chunk's factor leaves its rows so): grown, not cleared.
                        if values.len() < rows * width {
                            values.resize(rows * width, 0.0);
                        }
                        let mut block = FactorRows {
                            values: &mut values[..rows * width],
                            width,
                            local: &local,
                            at: 0,
                            finite: true,
                        };
                        r.clear();
                        r.resize(rows, 0.0);
                        let mut at = 0;
                        for &i in chunk {
                            let t = &self.terms[i];
                            let mine = &mut r[at..at + t.rows()];
                            at += t.rows();
                            // A point writes its rows in place; any other term through its Jacobian.
                            if !t.evaluate_into_rows(&input, mine, &mut block) {
                                jac.reset(t.rows());
                                t.evaluate(&input, mine, Some(jac));
                                block.add(jac);
                            }
                        }
                        self.recycle(poses);
                        let factor = block.factor(r, columns);
                        if let Ok(mut spare) = spare.lock() {
                            spare.push(buffers);
                        }
                        factor
                    })
                    .collect();
                // Folded in order: the same factor whatever the thread count.
                let folded = folded
                    .into_iter()
                    .try_fold(ChunkFactor::empty(width), |top, bottom| Some(top.fold(bottom?)))?;
                Some(GroupFactor {
                    r: folded.r,
                    own: own.len(),
                    columns,
                    gradient: folded.gradient,
                    half_squares: folded.half_squares,
                    largest_residual: folded.largest_residual,
                })
            })
            .collect()
    }
}

/// A chunk's buffers for its factor, left for the next chunk.
#[derive(Default)]
struct FactorBuffers {
    jac: TermJacobian,
    /// Room for a chunk's rows, all zero between chunks.
    values: Vec<f64>,
    /// The rows column-major, overwritten by their QR.
    columns: Vec<f64>,
    /// A chunk's residuals.
    r: Vec<f64>,
}

/// A group's Jacobian rows for its factor, row-major over the group's columns: a term writes
/// its rows in place ([`Term::evaluate_into_rows`]) or has them copied from its Jacobian.
struct FactorRows<'l> {
    /// Zero before the first term writes.
    values: &'l mut [f64],
    width: usize,
    /// Per column of the problem, its place in a row (`usize::MAX`: not the group's).
    local: &'l [usize],
    /// Rows written.
    at: usize,
    /// No derivative copied from a Jacobian (of the group's columns or not) is infinite or NaN.
    finite: bool,
}

impl FactorRows<'_> {
    /// The next term's rows from its Jacobian `jac` (columns that are not the group's left out).
    fn add(&mut self, jac: &TermJacobian) {
        let rows = &mut self.values[self.at * self.width..(self.at + jac.rows) * self.width];
        for (p, &c) in jac.columns.iter().enumerate() {
            let column = jac.column(p);
            self.finite &= column.iter().all(|v| v.is_finite());
            if let Some(l) = Some(self.local[c]).filter(|&l| l < self.width) {
                for (k, &v) in column.iter().enumerate() {
                    rows[k * self.width + l] = v;
                }
            }
        }
        self.at += jac.rows;
    }

    /// The factor of the rows with their residuals `r` (`columns` its buffer); `None` when a
    /// value, a derivative copied or a residual is not finite. The rows are left zero either
    /// way, for the next chunk to write into without clearing them.
    fn factor(self, r: &[f64], columns: &mut Vec<f64>) -> Option<ChunkFactor> {
        let width = self.width;
        let mut gradient = DVector::zeros(width);
        columns.resize(r.len() * width, 0.0);
        take_transposed(self.values, r, columns, gradient.as_mut_slice());
        // With finite residuals, a value that is not finite leaves its column's sum not finite
        // (NaN, or ±∞ that no later product brings back): a finite gradient proves every value
        // finite, and only one that overflowed has the values read again.
        let finite = self.finite
            && r.iter().all(|v| v.is_finite())
            && (gradient.as_slice().iter().all(|g| g.is_finite()) || all_finite(columns));
        finite.then(|| {
            let mut rows = DMatrix::from_vec(r.len(), width, std::mem::take(columns));
            let factor = r_factor_overwriting(&mut rows);
            *columns = rows.data.into();
            ChunkFactor {
                r: factor,
                gradient,
                half_squares: r.iter().map(|v| 0.5 * v * v).sum(),
                largest_residual: r.iter().fold(0.0, |m, v| v.abs().max(m)),
            }
        })
    }
}

/// The rows `values` (row-major, as many as `r` has residuals) into `out` column-major, each
/// value replaced by zero, and Jᵀr summed row after row into `gradient` (one value per
/// column): one pass, two rows by two columns at a time, which the compiler keeps in vector
/// instructions (two values loaded, multiplied, summed, zeroed and stored in one each).
fn take_transposed(values: &mut [f64], r: &[f64], out: &mut [f64], gradient: &mut [f64]) {
    let (m, width) = (r.len(), gradient.len());
    if out.is_empty() {
        return;
    }
    let mut row_pairs = values.chunks_exact_mut(2 * width);
    for ((pair, ri), i) in (&mut row_pairs).zip(r.as_chunks::<2>().0).zip((0..m).step_by(2)) {
        let (top, bottom) = pair.split_at_mut(width);
        let ((top, top_last), (bottom, bottom_last)) =
            (top.as_chunks_mut::<2>(), bottom.as_chunks_mut::<2>());
        let (sums, sum_last) = gradient.as_chunks_mut::<2>();
        let mut columns = out.chunks_exact_mut(2 * m);
        // Everything read into locals before the stores: nothing is read again after one.
        let [r0, r1] = *ri;
        for (((t, b), g), two) in top.iter_mut().zip(bottom).zip(sums).zip(&mut columns) {
            let ([t0, t1], [b0, b1]) = (std::mem::take(t), std::mem::take(b));
            *g = [g[0] + t0 * r0 + b0 * r1, g[1] + t1 * r0 + b1 * r1];
            let (left, right) = two.split_at_mut(m);
            left[i..i + 2].copy_from_slice(&[t0, b0]);
            right[i..i + 2].copy_from_slice(&[t1, b1]);
        }
        // An odd column.
        if let ([t], [b], [g]) = (top_last, bottom_last, sum_last) {
            let (t, b) = (std::mem::take(t), std::mem::take(b));
            *g = *g + t * r0 + b * r1;
            columns.into_remainder()[i..i + 2].copy_from_slice(&[t, b]);
        }
    }
    // An odd row.
    let last = row_pairs.into_remainder();
    for ((v, g), column) in last.iter_mut().zip(gradient).zip(out.chunks_exact_mut(m)) {
        *g += *v * r[m - 1];
        column[m - 1] = std::mem::take(v);
    }
}

/// Every value is finite. Read eight values at a time without stopping inside a chunk, which
/// the compiler turns into vector comparisons (stopping at the first one not finite took three
/// times the instructions).
fn all_finite(values: &[f64]) -> bool {
    let (chunks, tail) = values.as_chunks::<8>();
    let chunk_finite = |c: &[f64; 8]| c.iter().fold(true, |all, v| all & v.is_finite());
    chunks.iter().all(chunk_finite) && tail.iter().all(|v| v.is_finite())
}

impl RowTarget for FactorRows<'_> {
    fn rows<'a>(&'a mut self, rows: usize, columns: &'a [Range<usize>]) -> TermRows<'a> {
        let span = self.at * self.width..(self.at + rows) * self.width;
        self.at += rows;
        TermRows::new(&mut self.values[span], self.width, self.local, columns)
    }
}

/// A chunk of a group's rows reduced: their R factor, Jᵀr, Σ ½r² and largest |r|.
struct ChunkFactor {
    r: DMatrix<f64>,
    gradient: DVector<f64>,
    half_squares: f64,
    largest_residual: f64,
}

impl ChunkFactor {
    /// No rows, over `width` columns.
    fn empty(width: usize) -> ChunkFactor {
        ChunkFactor {
            r: DMatrix::zeros(0, width),
            gradient: DVector::zeros(width),
            half_squares: 0.0,
            largest_residual: 0.0,
        }
    }

    /// This chunk's rows and then `bottom`'s.
    fn fold(self, bottom: ChunkFactor) -> ChunkFactor {
        ChunkFactor {
            r: fold(self.r, bottom.r),
            gradient: self.gradient + bottom.gradient,
            half_squares: self.half_squares + bottom.half_squares,
            largest_residual: self.largest_residual.max(bottom.largest_residual),
        }
    }
}

/// The R factor of two factors stacked.
fn fold(top: DMatrix<f64>, bottom: DMatrix<f64>) -> DMatrix<f64> {
    if top.nrows() == 0 {
        return bottom;
    }
    if bottom.nrows() == 0 {
        return top;
    }
    r_factor_of_stacked(top, bottom)
}

/// `m` with the directions of `basis`'s columns above `1e-12` of its largest singular value
/// projected out of each column.
fn project_out(m: &mut DMatrix<f64>, basis: &DMatrix<f64>) {
    if basis.ncols() == 0 || basis.nrows() == 0 {
        return;
    }
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

/// The arm columns (raw, and with every group's own columns projected out per group, then the
/// probe rotation's over all groups), row-major with the arm's columns, from the group factors:
/// the column geometry of the full Jacobian's arm columns.
pub fn projected_arm_columns(layout: &Layout, factors: &[GroupFactor]) -> (Vec<f64>, Vec<f64>) {
    let a = layout.arm.len();
    let t = if layout.rotation_column().is_some() { 3 } else { 0 };
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::terms::{build, TermChoice};
    use crate::data::{Joints, Kind, Observation};
    use crate::model::kinematics::tool_pose;
    use crate::numerics::qr::r_factor;
    use nalgebra::{Rotation3, Vector3};

    /// Three sessions of 40 points of an arm moved from `nominal`, each seen from its own base.
    fn sessions(nominal: &ArmModel) -> Observations {
        let mut truth = nominal.clone();
        for (k, f) in nominal.free.iter().enumerate() {
            truth.set(f.id, nominal.get(f.id) + 0.1 * (k as f64 * 1.7).sin());
        }
        let joints = nominal.joints.len();
        let mut data = Observations::new(joints, Vec::new());
        for s in 0..3 {
            let group = data.push_group(format!("s{s}"), "s.csv".into(), Kind::Tracker);
            let rotation = Rotation3::from_euler_angles(0.1, -0.05, 1.2 * s as f64).into_inner();
            let shift = Vector3::new(2500.0, -300.0 * s as f64, 400.0);
            for i in 0..40 {
                let q: Vec<f64> =
                    (0..joints).map(|j| ((i * 7 + j * 3 + s) as f64 * 0.9).sin() * 100.0).collect();
                let p = rotation * tool_pose(&truth, &q).position_mm + shift;
                let q = Joints::new(&q).expect("the arm's joints fit in Joints");
                data.obs.push(Observation::point(group, q, p, None, Some(0.02), i + 3));
            }
        }
        data.rebuild_blocks();
        data
    }

    /// The terms of positions alone, unweighted.
    fn positions_only() -> TermChoice {
        TermChoice {
            relative_orientation_lever_mm: None,
            orientation_weight_mm_per_rad: None,
            point_weight: 1.0,
        }
    }

    /// A term that writes its derivatives only through its Jacobian (the default path), its
    /// columns in their order or, `reversed`, backwards (the first term in a batch then places
    /// the arm's columns there backwards).
    struct ThroughJacobian {
        term: Box<dyn Term>,
        reversed: bool,
    }

    /// `term` through its Jacobian.
    fn through(term: Box<dyn Term>) -> Box<dyn Term> {
        Box::new(ThroughJacobian { term, reversed: false })
    }

    /// `term` through its Jacobian, its columns backwards.
    fn reversed(term: Box<dyn Term>) -> Box<dyn Term> {
        Box::new(ThroughJacobian { term, reversed: true })
    }

    impl Term for ThroughJacobian {
        fn rows(&self) -> usize {
            self.term.rows()
        }
        fn block(&self) -> usize {
            self.term.block()
        }
        fn observations(&self) -> &[usize] {
            self.term.observations()
        }
        fn is_position(&self) -> bool {
            self.term.is_position()
        }
        fn evaluate(&self, at: &TermInput<'_>, r: &mut [f64], jac: Option<&mut TermJacobian>) {
            let jac = match jac {
                Some(jac) if self.reversed => jac,
                plain => return self.term.evaluate(at, r, plain),
            };
            let mut forward = TermJacobian::default();
            forward.reset(jac.rows);
            self.term.evaluate(at, r, Some(&mut forward));
            for k in (0..forward.columns.len()).rev() {
                jac.push(forward.columns[k], forward.column(k));
            }
        }
    }

    /// Without block unknowns the normal equations are those of the dense Jacobian: distances
    /// written straight into the batch's rows, every other distance through its Jacobian (the
    /// row written and then taken back), with relative orientations (four rows) between.
    #[test]
    fn the_sums_of_distances_are_the_dense_normal_equations() {
        let nominal = ArmModel::suta_nominal();
        let options = crate::simulate::SimulationOptions { seed: 1, ..Default::default() };
        let sim = crate::simulate::simulate(&nominal, &options);
        let data = Observations::from_sessions(&sim.calibration, &sim.artefact);
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        for lever_mm in [None, Some(150.0)] {
            let choice = TermChoice {
                relative_orientation_lever_mm: lever_mm,
                orientation_weight_mm_per_rad: None,
                point_weight: 1.0,
            };
            let terms: Vec<Box<dyn Term>> = build(&data, &choice)
                .into_iter()
                .enumerate()
                .map(|(k, t)| if k % 2 == 1 { through(t) } else { t })
                .collect();
            let tools = vec![false; data.groups.len()];
            let layout =
                Layout::new(params.clone(), &vec![false; blocks], &tools, false, &vec![None; blocks]);
            let frames = vec![Matrix3::identity(); blocks];
            let problem = Problem::new(layout, &nominal, &data, &terms, frames, None);
            let n = problem.layout.unknowns();
            assert!(!problem.layout.has_block_unknowns(), "the dense path");
            let x: Vec<f64> = params.iter().map(|id| nominal.get(*id) + 1e-3).collect();
            let m = problem.len();
            let (mut r, mut jac) = (vec![0.0; m], vec![0.0; m * n]);
            problem.evaluate(&x, &mut r, Some(&mut jac));
            // Huber's δ below most residuals: weights other than 1 in every batch.
            for loss in [Loss::Linear, Loss::Huber(0.01)] {
                let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
                let weighted = weights.iter().filter(|&&w| w != 1.0).count();
                assert!(loss == Loss::Linear || weighted > m / 4, "{weighted} of {m} rows weighted");
                let (hd, gd) = crate::numerics::solver::normal_equations(&jac, &r, &weights, n);
                let mut r2 = vec![0.0; m];
                let (h, g) = problem.normal_equations(&x, &mut r2, loss);
                let label = format!("lever {lever_mm:?}, {loss:?}");
                assert_eq!(r, r2, "{label}: the residuals are written as they are");
                let (dh, dg) = ((&h - &hd).norm() / hd.norm(), (&g - &gd).norm() / gd.norm());
                assert!(dh <= 1e-12 && dg <= 1e-12, "{label}: {dh:e} {dg:e}");
            }
        }
    }

    /// Distances written straight into the batch's rows (read from the laid-out position
    /// derivatives) give the sums of the same distances through their Jacobians to the bit, with
    /// relative orientations (four rows) between: the same rows in the same batch positions.
    #[test]
    fn distances_written_into_rows_give_the_sums_of_their_jacobians() {
        let nominal = ArmModel::suta_nominal();
        let options = crate::simulate::SimulationOptions { seed: 2, ..Default::default() };
        let sim = crate::simulate::simulate(&nominal, &options);
        let data = Observations::from_sessions(&sim.calibration, &sim.artefact);
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        let choice = TermChoice { relative_orientation_lever_mm: Some(150.0), ..positions_only() };
        let direct = build(&data, &choice);
        let jacobians: Vec<Box<dyn Term>> = build(&data, &choice).into_iter().map(through).collect();
        let layout = || {
            let tools = vec![false; data.groups.len()];
            Layout::new(params.clone(), &vec![false; blocks], &tools, false, &vec![None; blocks])
        };
        let frames = vec![Matrix3::identity(); blocks];
        let ours = Problem::new(layout(), &nominal, &data, &direct, frames.clone(), None);
        let theirs = Problem::new(layout(), &nominal, &data, &jacobians, frames, None);
        assert!(ours.len() > 2 * DENSE_BATCH_ROWS, "more than one batch");
        let x: Vec<f64> = params.iter().map(|id| nominal.get(*id) + 1e-3).collect();
        let mut r = vec![0.0; ours.len()];
        ours.evaluate(&x, &mut r, None);
        for loss in [Loss::Linear, Loss::Huber(median_abs(&r))] {
            assert_same_sums(&ours, &theirs, &x, loss, &format!("{loss:?}"));
        }
    }

    /// The point the framed tests evaluate at: `nominal`'s values of `params` (the first
    /// columns), each session's frame turned and shifted a little, each floated tool offset and
    /// each drift's rates set.
    fn framed_point(problem: &Problem, params: &[crate::model::ParamId], nominal: &ArmModel) -> Vec<f64> {
        let layout = &problem.layout;
        let mut x = vec![0.0; layout.unknowns()];
        for (k, id) in params.iter().enumerate() {
            x[k] = nominal.get(*id);
        }
        for b in 0..problem.data.blocks.len() {
            let c = layout.frame_column(b).expect("framed");
            x[c..c + 6].copy_from_slice(&[1e-3, -2e-3, 0.5e-3, 2500.0, -300.0 * b as f64, 400.0]);
            if let Some((c, d)) = layout.drift(b) {
                for k in 0..d.kind.unknowns() {
                    x[c + k] = 0.3 - 0.2 * k as f64;
                }
            }
        }
        for (g, c) in (0..problem.data.groups.len()).filter_map(|g| Some((g, layout.tool_column(g)?))) {
            x[c..c + 3].copy_from_slice(&[0.3, -0.2, 0.1 * g as f64]);
        }
        x
    }

    /// The frames' rotations the framed tests start at: each session's turned a little off the
    /// rotation its points were made with.
    fn start_rotations(blocks: usize) -> Vec<Matrix3<f64>> {
        (0..blocks)
            .map(|s| Rotation3::from_euler_angles(0.1, -0.05, 1.2 * s as f64 + 0.01).into_inner())
            .collect()
    }

    /// `a` and `b` have the same group factors at `x` to the bit: each R factor, gradient, sum
    /// of squares and largest residual.
    fn assert_same_factors(a: &Problem, b: &Problem, x: &[f64], label: &str) {
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let key = |f: &GroupFactor| {
            let sums = [f.half_squares, f.largest_residual];
            (bits(f.r.as_slice()), bits(f.gradient.as_slice()), bits(&sums), f.columns.clone(), f.own)
        };
        let [fa, fb] = [a, b].map(|p| p.group_factors(x).expect("finite factors"));
        assert_eq!(fa.iter().map(key).collect::<Vec<_>>(), fb.iter().map(key).collect::<Vec<_>>(), "{label}");
    }

    /// `ours` and `theirs` give the same residuals and normal equations at `x` to the bit, and
    /// sums of something.
    fn assert_same_sums(ours: &Problem, theirs: &Problem, x: &[f64], loss: Loss, label: &str) {
        let m = ours.len();
        let (mut r_ours, mut r_theirs) = (vec![0.0; m], vec![0.0; m]);
        let (h, g) = ours.normal_equations(x, &mut r_ours, loss);
        let (hj, gj) = theirs.normal_equations(x, &mut r_theirs, loss);
        assert_eq!(r_ours, r_theirs, "{label}: residuals");
        assert!(h.iter().zip(&hj).all(|(a, b)| a.to_bits() == b.to_bits()), "{label}: JᵀWJ");
        assert!(g.iter().zip(&gj).all(|(a, b)| a.to_bits() == b.to_bits()), "{label}: JᵀWr");
        assert!(hj.norm() > 0.0 && gj.norm() > 0.0, "{label}: sums of something");
    }

    /// The median of the residuals' sizes: a Huber threshold that weighs half the rows.
    fn median_abs(r: &[f64]) -> f64 {
        let mut a: Vec<f64> = r.iter().map(|v| v.abs()).collect();
        a.sort_by(f64::total_cmp);
        a[a.len() / 2]
    }

    /// [`sessions`] with a time on every point, the nominal arm's free parameters, and session
    /// drifts for up to three blocks: none, one in scale and one in offset.
    struct Timed {
        nominal: ArmModel,
        data: Observations,
        params: Vec<crate::model::ParamId>,
        blocks: usize,
        drifts: [Option<crate::calib::nuisance::drift::DriftSlot>; 3],
    }

    fn timed_sessions() -> Timed {
        use crate::calib::nuisance::drift::{DriftKind, DriftSlot};
        let nominal = ArmModel::suta_nominal();
        let mut data = sessions(&nominal);
        for (k, o) in data.obs.iter_mut().enumerate() {
            o.time_s = Some(60.0 * k as f64);
        }
        let params = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        assert!(blocks <= 3, "a drift per block");
        let drift = |column, kind| Some(DriftSlot { column, kind, centre: 0.5 });
        let drifts = [None, drift(0, DriftKind::ScaleTime), drift(1, DriftKind::OffsetTime)];
        Timed { nominal, data, params, blocks, drifts }
    }

    /// Points written straight into the batch's rows give the sums of the same points through
    /// their Jacobians to the bit (the same values in the same batch positions), and so do the
    /// groups' identifiability factors written into their rows: frames, floated tools, a session
    /// drifting in scale and one in offset, a point weight other than 1, and weights 1 and Huber
    /// weights.
    #[test]
    fn points_written_into_the_rows_give_the_sums_and_factors_of_their_jacobians() {
        let Timed { nominal, data, params, blocks, drifts } = timed_sessions();
        for point_weight in [1.0, 0.4] {
            let choice = TermChoice {
                relative_orientation_lever_mm: None,
                orientation_weight_mm_per_rad: None,
                point_weight,
            };
            let direct = build(&data, &choice);
            let through: Vec<Box<dyn Term>> = build(&data, &choice).into_iter().map(through).collect();
            let layout = || {
                let tools = vec![true; data.groups.len()];
                Layout::new(params.clone(), &vec![true; blocks], &tools, false, &drifts[..blocks])
            };
            let starts = start_rotations(blocks);
            let ours = Problem::new(layout(), &nominal, &data, &direct, starts.clone(), None);
            let theirs = Problem::new(layout(), &nominal, &data, &through, starts, None);
            let x = framed_point(&ours, &params, &nominal);
            let (mine, reference) = (ours.group_factors(&x), theirs.group_factors(&x));
            let (mine, reference) = (mine.expect("finite"), reference.expect("finite"));
            assert_eq!(mine.len(), reference.len());
            for (a, b) in mine.iter().zip(&reference) {
                assert_eq!((a.own, a.r.shape()), (b.own, b.r.shape()));
                assert!(a.r.iter().zip(&b.r).all(|(u, v)| u.to_bits() == v.to_bits()), "R factors");
                assert!(b.r.norm() > 0.0 && a.own > 0, "a factor of something, with own columns");
            }
            let m = ours.len();
            let mut r = vec![0.0; m];
            ours.evaluate(&x, &mut r, None);
            for loss in [Loss::Linear, Loss::Huber(median_abs(&r))] {
                assert_same_sums(&ours, &theirs, &x, loss, &format!("point weight {point_weight}, {loss:?}"));
            }
        }
    }

    /// The tool point's first fit (its columns, the frames) solved with each pose started at
    /// its flange is, to the bit, the fit by the whole pass: every step's residuals and sums,
    /// so the solution, its cost, residuals and normal matrix; with the scale, floated tools,
    /// drifts and a Huber loss too. A fit of a row's parameter keeps no flanges.
    #[test]
    fn the_tool_fit_from_the_flanges_is_the_fit_by_the_whole_pass() {
        use crate::model::ParamId;
        use crate::numerics::solver::{solve_from, SolverOptions};
        let Timed { nominal, data, blocks, drifts, .. } = timed_sessions();
        let terms = build(&data, &positions_only());
        let tcp = [ParamId::Tcp(0), ParamId::Tcp(1), ParamId::Tcp(2)];
        let scaled = [tcp.as_slice(), &[ParamId::Scale]].concat();
        let none = [None, None, None];
        let floated = vec![true; data.groups.len()];
        let plain = vec![false; data.groups.len()];
        let cases = [
            (tcp.to_vec(), &plain, &none, false),
            (scaled.clone(), &plain, &none, true),
            (scaled, &floated, &drifts, true),
        ];
        for (case, (params, tools, drifts, huber)) in cases.into_iter().enumerate() {
            let layout = || Layout::new(params.clone(), &vec![true; blocks], tools, false, &drifts[..blocks]);
            let starts = start_rotations(blocks);
            let problem = || Problem::new(layout(), &nominal, &data, &terms, starts.clone(), None);
            let (ours, theirs) = (problem(), problem().with_whole_passes());
            let x0 = framed_point(&ours, &params, &nominal);
            let mut r = vec![0.0; ours.len()];
            ours.evaluate(&x0, &mut r, None);
            let loss = if huber { Loss::Huber(median_abs(&r)) } else { Loss::Linear };
            let n = x0.len();
            let (lower, upper) = (vec![f64::NEG_INFINITY; n], vec![f64::INFINITY; n]);
            for trial_normal in [true, false] {
                let options = SolverOptions { loss, trial_normal, ..SolverOptions::default() };
                let [a, b] = [&ours, &theirs].map(|p| solve_from(p, &x0, &lower, &upper, &options, None));
                let label = format!("case {case}, trial normal {trial_normal}");
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&a.x), bits(&b.x), "{label}: solution");
                assert_eq!(a.cost.to_bits(), b.cost.to_bits(), "{label}: cost");
                assert_eq!(bits(&a.residuals), bits(&b.residuals), "{label}: residuals");
                assert_eq!((a.iterations, format!("{:?}", a.stop)), (b.iterations, format!("{:?}", b.stop)));
                let normal = |s: &crate::numerics::solver::Solution| {
                    s.normal_at_x.as_ref().map(|m| bits(m.as_slice()))
                };
                assert_eq!(normal(&a), normal(&b), "{label}: normal matrix");
                assert!(a.iterations > 1 && a.x[..3] != x0[..3], "{label}: a fit that moved the tool");
            }
            assert!(ours.flanges.get().is_some_and(Option::is_some), "case {case}: flanges kept");
            assert!(theirs.flanges.get().is_some_and(Option::is_none), "case {case}: none kept");
            assert_same_sums(&ours, &theirs, &x0, loss, &format!("case {case}"));
            assert_same_factors(&ours, &theirs, &x0, &format!("case {case}"));
        }
        // Without frames (the dense path, its chunks over the whole span read).
        let layout = || Layout::new(tcp.to_vec(), &vec![false; blocks], &plain, false, &none[..blocks]);
        let problem = || Problem::new(layout(), &nominal, &data, &terms, start_rotations(blocks), None);
        let (ours, theirs) = (problem(), problem().with_whole_passes());
        let values =
            |params: &[ParamId]| params.iter().map(|id| nominal.get(*id) + 0.3).collect::<Vec<f64>>();
        let x0 = values(&tcp);
        assert_same_sums(&ours, &theirs, &x0, Loss::Linear, "no frames");
        assert_same_factors(&ours, &theirs, &x0, "no frames");
        assert!(ours.flanges.get().is_some_and(Option::is_some), "no frames: flanges kept");
        // A layout changed after the flanges were kept to a row's parameter takes the whole pass.
        let mut changed = problem();
        changed.normal_equations(&x0, &mut vec![0.0; changed.len()], Loss::Linear);
        let rows = vec![ParamId::Tcp(0), ParamId::Length(2)];
        changed.layout = Layout::new(rows.clone(), &vec![false; blocks], &plain, false, &none[..blocks]);
        let whole =
            Problem::new(changed.layout.clone(), &nominal, &data, &terms, start_rotations(blocks), None);
        let x = values(&rows);
        assert_same_sums(&changed, &whole.with_whole_passes(), &x, Loss::Linear, "a changed layout");
        // A row's parameter moves the flanges: none kept.
        let params = vec![ParamId::Tcp(0), ParamId::Length(2)];
        let layout = Layout::new(params.clone(), &vec![true; blocks], &plain, false, &none[..blocks]);
        let problem = Problem::new(layout, &nominal, &data, &terms, start_rotations(blocks), None);
        let x = framed_point(&problem, &params, &nominal);
        problem.normal_equations(&x, &mut vec![0.0; problem.len()], Loss::Linear);
        assert!(problem.flanges.get().and_then(Option::as_ref).is_none(), "a row's parameter: no flanges");
    }

    /// A point of a tool that does not float (no product by its zero offset, no flange
    /// rotation) has the residuals of the same point with its tool floated at a zero offset, to
    /// the bit: sessions without a drift (no product by a growth of 1) and drifting in scale and
    /// in offset.
    #[test]
    fn a_point_of_a_fixed_tool_is_one_of_a_floated_tool_at_zero() {
        let Timed { nominal, data, params, blocks, drifts } = timed_sessions();
        let terms = build(&data, &positions_only());
        let residuals = |floated: bool| {
            let tools = vec![floated; data.groups.len()];
            let layout = Layout::new(params.clone(), &vec![true; blocks], &tools, false, &drifts[..blocks]);
            let problem = Problem::new(layout, &nominal, &data, &terms, start_rotations(blocks), None);
            let mut x = framed_point(&problem, &params, &nominal);
            for c in (0..data.groups.len()).filter_map(|g| problem.layout.tool_column(g)) {
                x[c..c + 3].fill(0.0);
            }
            let mut r = vec![0.0; problem.len()];
            problem.evaluate(&x, &mut r, None);
            r
        };
        let (fixed, floated) = (residuals(false), residuals(true));
        assert!(fixed.iter().zip(&floated).all(|(a, b)| a.to_bits() == b.to_bits()));
        assert!(fixed.iter().any(|v| *v != 0.0));
    }

    /// A chunk's factor is that of its rows read as they were written (R of the row-major
    /// matrix, Jᵀr summed row by row, to the bit), and it leaves the rows zero: rows and
    /// columns in even and odd counts, one buffer for every chunk's copy of the rows.
    #[test]
    fn a_chunk_factor_is_that_of_its_rows_and_leaves_them_zero() {
        let mut columns = Vec::new();
        for (m, width) in [(40, 7), (41, 7), (40, 8), (41, 8), (1, 3), (3, 1), (2, 2), (5, 12)] {
            let local: Vec<usize> = (0..width).collect();
            let values: Vec<f64> = (0..m * width).map(|k| (k as f64 * 0.37).sin() * 10.0).collect();
            let r: Vec<f64> = (0..m).map(|i| (i as f64 * 0.71).cos()).collect();
            let mut rows = values.clone();
            let block = FactorRows { values: &mut rows, width, local: &local, at: m, finite: true };
            let factor = block.factor(&r, &mut columns).expect("finite");
            assert!(rows.iter().all(|&v| v == 0.0), "{m} × {width}");
            let same = |a: &[f64], b: &[f64]| {
                a.len() == b.len() && a.iter().zip(b).all(|(u, v)| u.to_bits() == v.to_bits())
            };
            let reference = r_factor(DMatrix::from_row_slice(m, width, &values));
            assert!(same(factor.r.as_slice(), reference.as_slice()), "R factors, {m} × {width}");
            let gradient: Vec<f64> =
                (0..width).map(|l| (0..m).fold(0.0, |g, i| g + values[i * width + l] * r[i])).collect();
            assert!(same(factor.gradient.as_slice(), &gradient), "gradients, {m} × {width}");
            assert_eq!(factor.half_squares.to_bits(), r.iter().map(|v| 0.5 * v * v).sum::<f64>().to_bits());
            assert_eq!(factor.largest_residual, r.iter().fold(0.0, |l: f64, v| l.max(v.abs())));
        }
    }

    /// A chunk has a factor exactly when every value, copied derivative and residual is finite:
    /// wherever the value that is not lies (in a chunk of eight or in the tail), and when finite
    /// values overflow the gradient. Its rows are left zero either way.
    #[test]
    fn a_chunk_has_a_factor_exactly_when_everything_is_finite() {
        let local = [0, 1, 2];
        let (values, r): (Vec<f64>, Vec<f64>) = ((0..27).map(|k| k as f64 - 13.5).collect(), vec![0.5; 9]);
        let factor = |mut values: Vec<f64>, r: &[f64], finite| {
            let block = FactorRows { values: &mut values, width: 3, local: &local, at: 9, finite };
            let factor = block.factor(r, &mut Vec::new());
            assert!(values.iter().all(|&v| v == 0.0), "rows left zero");
            factor.is_some()
        };
        assert!(factor(values.clone(), &r, true));
        assert!(!factor(values.clone(), &r, false));
        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            for k in [0, 7, 8, 23, 24, 26] {
                let mut with_bad = values.clone();
                with_bad[k] = bad;
                assert!(!factor(with_bad, &r, true), "{bad} at {k}");
                // A zero residual on its row: the product is NaN, not zero.
                let mut zero_residual = r.clone();
                zero_residual[k / 3] = 0.0;
                let mut with_bad = values.clone();
                with_bad[k] = bad;
                assert!(!factor(with_bad, &zero_residual, true), "{bad} at {k}, zero residual");
            }
            let mut bad_residual = r.clone();
            bad_residual[4] = bad;
            assert!(!factor(values.clone(), &bad_residual, true), "residual {bad}");
        }
        assert!(factor(vec![1e300; 27], &[1e10; 9], true), "finite values, a gradient that overflows");
    }

    /// A problem's next evaluation, whose chunks take the buffers (pose derivatives, poses,
    /// observations read, zeroed sums) the chunks before left, gives the sums of a fresh
    /// problem's first to the bit (two counts of arm columns); so does a problem on a term index
    /// kept across problems of either count (their buffers left by the problems before).
    #[test]
    fn kept_chunk_buffers_give_the_first_sums() {
        let nominal = ArmModel::suta_nominal();
        let data = sessions(&nominal);
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        let choice = positions_only();
        let terms = build(&data, &choice);
        let layout = |arm: &[crate::model::ParamId]| {
            let tools = vec![true; data.groups.len()];
            Layout::new(arm.to_vec(), &vec![true; blocks], &tools, false, &vec![None; blocks])
        };
        let starts = start_rotations(blocks);
        let (index, sin_cos) = (TermIndex::of(&data, &terms), encoder_table(&data, &terms));
        for arm in [&params[..], &params[..params.len() - 3], &params[..]] {
            let kept = Problem::new(layout(arm), &nominal, &data, &terms, starts.clone(), None);
            let x = framed_point(&kept, arm, &nominal);
            let mut r = vec![0.0; kept.len()];
            kept.normal_equations(&x, &mut r, Loss::Linear);
            let fresh = Problem::new(layout(arm), &nominal, &data, &terms, starts.clone(), None);
            assert_same_sums(&kept, &fresh, &x, Loss::Linear, &format!("{} arm columns", arm.len()));
            let on_index = KeptForTerms { sin_cos: &sin_cos, rows: None, index: &index };
            let shared = Problem::with_kept(
                layout(arm),
                &nominal,
                &data,
                &terms,
                starts.clone(),
                None,
                Some(on_index),
            );
            assert_same_sums(
                &shared,
                &fresh,
                &x,
                Loss::Linear,
                &format!("{} arm columns, kept index", arm.len()),
            );
        }
    }

    /// A problem on a session left out of the others, its rows read by index out of the whole
    /// table ([`KeptForTerms::of`] a selection's [`Encoders`]), gives the sums and group factors
    /// of a problem whose table is its own, to the bit.
    #[test]
    fn rows_read_by_index_are_the_rows_of_a_table_of_their_own() {
        let nominal = ArmModel::suta_nominal();
        let data = sessions(&nominal);
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        data.encoders();
        let without = data.without(|k| data.obs[k].block == 1);
        let encoders = without.encoders();
        assert!(encoders.by_index().1.is_some(), "rows picked out of the whole table");
        let terms = build(&without, &positions_only());
        let blocks = without.blocks.len();
        let tools = vec![true; without.groups.len()];
        let layout = Layout::new(params.clone(), &vec![true; blocks], &tools, false, &vec![None; blocks]);
        let index = TermIndex::of(&without, &terms);
        let kept = Some(KeptForTerms::of(encoders, &index));
        let (starts, model) = (start_rotations(blocks), &nominal);
        let picked = Problem::with_kept(layout.clone(), model, &without, &terms, starts.clone(), None, kept);
        let own = Problem::new(layout, model, &without, &terms, starts, None);
        let x = framed_point(&picked, &params, model);
        assert_same_sums(&picked, &own, &x, Loss::Linear, "rows read by index");
        assert_same_factors(&picked, &own, &x, "rows read by index");
    }

    /// The poses of an evaluation without derivatives, taken two at a time, are each
    /// observation's pose alone to the bit, and an observation no term reads has none: terms over
    /// two points of three, a tip change that breaks a pair, chunks of the parallel split that end
    /// on an odd observation.
    #[test]
    fn poses_without_derivatives_are_the_poses_one_at_a_time() {
        let nominal = ArmModel::suta_nominal();
        let mut data = sessions(&nominal);
        let copies = data.obs.clone();
        for _ in 0..2 {
            data.obs.extend(copies.iter().cloned());
        }
        data.rebuild_blocks();
        for k in [5, 6, 255, 300] {
            data.obs[k].tip = 1;
        }
        let choice = positions_only();
        let terms: Vec<Box<dyn Term>> = build(&data, &choice)
            .into_iter()
            .enumerate()
            .filter(|(i, _)| i % 3 != 1)
            .map(|(_, t)| t)
            .collect();
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        let tools = vec![true; data.groups.len()];
        let layout = Layout::new(params.clone(), &vec![true; blocks], &tools, false, &vec![None; blocks]);
        let problem = Problem::new(layout, &nominal, &data, &terms, start_rotations(blocks), None);
        let state = problem.state(&framed_point(&problem, &params, &nominal));
        let poses = problem.poses(&state, false);
        let tips = Tips::new(&state.model);
        assert!(data.obs.len() > MIN_POSES_PER_TASK && poses.pose.len() == data.obs.len());
        for (k, o) in data.obs.iter().enumerate() {
            let alone = problem.index.read[k]
                .then(|| tips.tip(o.tip).pose_with_sin_cos(&o.q_deg, problem.sin_cos(k)));
            assert_eq!(poses.pose[k], alone, "observation {k}");
        }
        assert_eq!(poses.pose.iter().filter(|p| p.is_none()).count(), data.obs.len() / 3);
    }

    /// Points written straight into a batch whose arm columns are not in order (placed backwards
    /// by the term before) give the sums of the same points through their Jacobians to the bit:
    /// the arm's rows are written column by column there, not as one run.
    #[test]
    fn points_written_into_rows_out_of_order_give_the_sums_of_their_jacobians() {
        let nominal = ArmModel::suta_nominal();
        let data = sessions(&nominal);
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        let choice = positions_only();
        // Every other term reversed; the rest written into the rows (ours) or through their
        // Jacobians (theirs): the same columns in the same batch places.
        let mixed = |direct: bool| -> Vec<Box<dyn Term>> {
            build(&data, &choice)
                .into_iter()
                .enumerate()
                .map(|(k, t)| match (k % 2, direct) {
                    (0, _) => reversed(t),
                    (_, true) => t,
                    (_, false) => through(t),
                })
                .collect()
        };
        let (direct, through) = (mixed(true), mixed(false));
        let layout = || {
            let tools = vec![true; data.groups.len()];
            Layout::new(params.clone(), &vec![true; blocks], &tools, false, &vec![None; blocks])
        };
        let starts = start_rotations(blocks);
        let ours = Problem::new(layout(), &nominal, &data, &direct, starts.clone(), None);
        let theirs = Problem::new(layout(), &nominal, &data, &through, starts, None);
        let x = framed_point(&ours, &params, &nominal);
        assert_same_sums(&ours, &theirs, &x, Loss::Linear, "reversed batches");
    }

    /// The normal equations summed term by term are those of the dense Jacobian, on turned
    /// sessions with frames and floated tools, with every weight 1 (the batches that are their
    /// own weighted copy) and with Huber weights that differ within a point.
    #[test]
    fn the_sums_of_points_are_the_dense_normal_equations() {
        let nominal = ArmModel::suta_nominal();
        let data = sessions(&nominal);
        let terms = build(
            &data,
            &TermChoice {
                relative_orientation_lever_mm: None,
                orientation_weight_mm_per_rad: None,
                point_weight: 1.0,
            },
        );
        let params: Vec<_> = nominal.free.iter().map(|f| f.id).collect();
        let blocks = data.blocks.len();
        let layout = Layout::new(
            params.clone(),
            &vec![true; blocks],
            &vec![true; data.groups.len()],
            false,
            &vec![None; blocks],
        );
        let starts = start_rotations(blocks);
        let problem = Problem::new(layout, &nominal, &data, &terms, starts, None);
        let n = problem.layout.unknowns();
        let x = framed_point(&problem, &params, &nominal);
        let m = problem.len();
        let (mut r, mut jac) = (vec![0.0; m], vec![0.0; m * n]);
        problem.evaluate(&x, &mut r, Some(&mut jac));
        for loss in [Loss::Linear, Loss::Huber(median_abs(&r))] {
            let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
            if let Loss::Huber(_) = loss {
                let mixed = weights.chunks(3).filter(|w| w.iter().any(|&v| v != w[0])).count();
                assert!(mixed > 10, "points of unequal row weights: {mixed}");
            }
            let (hd, gd) = crate::numerics::solver::normal_equations(&jac, &r, &weights, n);
            let mut r2 = vec![0.0; m];
            let (h, g) = problem.normal_equations(&x, &mut r2, loss);
            assert_eq!(r, r2, "the residuals are written as they are");
            assert!((&h - &hd).norm() <= 1e-12 * hd.norm(), "{loss:?}: {:e}", (&h - &hd).norm() / hd.norm());
            assert!((&g - &gd).norm() <= 1e-12 * gd.norm(), "{loss:?}: {:e}", (&g - &gd).norm() / gd.norm());
        }
    }
}
