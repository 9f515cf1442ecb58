//! The sine and cosine of every encoder angle of a set of observations, computed once: every pose
//! of those observations on any arm reads them ([`Chain::pose_with_sin_cos`]), so that no fit
//! iteration, validated arm or diagnosis takes the sine of the same angle again.

use super::{Observation, Observations};
use crate::model::kinematics::{encoder_sin_cos, Chain, Tips, ToolPose};
use crate::model::MAX_TREE_JOINTS;
use std::borrow::Cow;
use std::sync::{Arc, OnceLock};

/// The sine and cosine of every encoder angle of some observations (`joints` per observation,
/// (0, 1) for an angle an observation lacks). [`Observations::encoders`] builds it at its first
/// use and keeps it; the fit's problems read it ([`crate::calib::problem::encoder_table`], which
/// leaves out observations no term reads, makes the same rows), and each [`crate::calib::fit::Fit`]
/// keeps the table of its observations for its refits (pinocchio's constant model and
/// per-algorithm data). A selection of its rows (`Encoders::rows_of`: a session's, a session
/// left out) shares the rows of the table it was taken from.
#[derive(Clone)]
pub struct Encoders {
    joints: usize,
    /// Each observation's angle count and its angles' bits, `joints + 1` values per row shared.
    angles: Arc<[u64]>,
    /// `joints` sines and cosines per row shared.
    table: Arc<[(f64, f64)]>,
    /// Which rows shared this table holds, in its order.
    rows: Rows,
}

/// The rows shared that an [`Encoders`] holds.
#[derive(Clone)]
enum Rows {
    /// `count` consecutive rows from `first` on (every row of a table built, one session's).
    Run {
        /// The first row shared held (row 0).
        first: usize,
        /// How many rows are held.
        count: usize,
    },
    /// These rows shared, row `k` the `k`-th (a selection that is no run: a session left out).
    Picked(Arc<[usize]>),
}

impl std::fmt::Debug for Encoders {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Encoders {{ observations: {}, joints: {} }}", self.rows(), self.joints)
    }
}

impl Encoders {
    /// The sines and cosines of `data`'s angles.
    pub fn of(data: &Observations) -> Encoders {
        let joints = data.joints;
        let mut table = vec![(0.0, 1.0); data.obs.len() * joints];
        let mut angles = vec![0; data.obs.len() * (joints + 1)];
        for ((row, key), o) in
            table.chunks_exact_mut(joints.max(1)).zip(angles.chunks_exact_mut(joints + 1)).zip(&data.obs)
        {
            key[0] = o.q_deg.len() as u64;
            for ((sc, bits), &q) in row.iter_mut().zip(&mut key[1..]).zip(o.q_deg.iter()) {
                *sc = encoder_sin_cos(q);
                *bits = q.to_bits();
            }
        }
        let rows = Rows::Run { first: 0, count: data.obs.len() };
        Encoders { joints, angles: angles.into(), table: table.into(), rows }
    }

    /// Every row, `joints` per observation, in the observations' order: borrowed when the rows
    /// are one run of the rows shared, else copied.
    pub fn table(&self) -> Cow<'_, [(f64, f64)]> {
        match self.by_index() {
            (rows, None) => Cow::Borrowed(rows),
            (rows, Some(picked)) => {
                let joints = self.joints;
                Cow::Owned(
                    picked.iter().flat_map(|&r| &rows[r * joints..(r + 1) * joints]).copied().collect(),
                )
            }
        }
    }

    /// Every row as a problem reads them by index ([`crate::calib::problem::KeptForTerms`]):
    /// row `k` is `joints` values from `joints * r` on of the rows returned, where `r` is the
    /// `k`-th index returned when there are indices, else `k`.
    pub(crate) fn by_index(&self) -> (&[(f64, f64)], Option<&[usize]>) {
        match &self.rows {
            Rows::Run { first, count } => {
                (&self.table[first * self.joints..(first + count) * self.joints], None)
            }
            Rows::Picked(picked) => (&self.table, Some(picked)),
        }
    }

    /// How many observations the table holds.
    fn rows(&self) -> usize {
        match &self.rows {
            Rows::Run { count, .. } => *count,
            Rows::Picked(picked) => picked.len(),
        }
    }

    /// The row shared that holds row `i`.
    #[inline]
    fn shared(&self, i: usize) -> usize {
        match &self.rows {
            Rows::Run { first, .. } => first + i,
            Rows::Picked(picked) => picked[i],
        }
    }

    /// Whether row `i` holds observation `o`'s angles (bit for bit).
    #[inline]
    fn holds(&self, i: usize, o: &Observation) -> bool {
        let (width, r) = (self.joints + 1, self.shared(i));
        let key = &self.angles[r * width..(r + 1) * width];
        key[0] == o.q_deg.len() as u64 && o.q_deg.iter().zip(&key[1..]).all(|(q, b)| q.to_bits() == *b)
    }

    /// Whether row k holds observation k's angles for every observation of `data`, and no row
    /// more (a table a problem may read by index).
    fn holds_all(&self, data: &Observations) -> bool {
        self.joints == data.joints
            && self.rows() == data.obs.len()
            && data.obs.iter().enumerate().all(|(k, o)| self.holds(k, o))
    }

    /// `f` of observation `o`'s sines and cosines: row `k` when it holds `o`'s angles, else
    /// [`encoder_sin_cos`] of each angle taken here (the same values), whatever the table holds.
    pub fn with_row<R>(&self, k: usize, o: &Observation, f: impl FnOnce(&[(f64, f64)]) -> R) -> R {
        f(self.row(k, o, &mut None))
    }

    /// Observation `o`'s sines and cosines as [`Encoders::with_row`] hands them over: row `k`, or
    /// those of its angles written to `own` (set up only then: most poses read the table).
    fn row<'r>(
        &'r self,
        k: usize,
        o: &Observation,
        own: &'r mut Option<[(f64, f64); MAX_TREE_JOINTS]>,
    ) -> &'r [(f64, f64)] {
        if k < self.rows() && self.holds(k, o) {
            let r = self.shared(k);
            return &self.table[r * self.joints..(r + 1) * self.joints];
        }
        let own = own.insert([(0.0, 1.0); MAX_TREE_JOINTS]);
        for (sc, &q) in own.iter_mut().zip(o.q_deg.iter()) {
            *sc = encoder_sin_cos(q);
        }
        &own[..o.q_deg.len()]
    }

    /// Observation `o` (row `k`)'s tool pose on `chain` (its tip's): [`Chain::pose_with_sin_cos`]
    /// of its row ([`Encoders::with_row`]).
    pub fn pose(&self, chain: &Chain, k: usize, o: &Observation) -> ToolPose {
        self.with_row(k, o, |sin_cos| chain.pose_with_sin_cos(&o.q_deg, sin_cos))
    }

    /// `f` of each observation `k` of `members` (indices into `obs`, whose row k this table's
    /// row k is meant to be) and its tool pose on its tip's chain of `tips`, in `members`' order:
    /// [`Encoders::pose`] to the bit, taken two at a time where consecutive members share a
    /// chain ([`Chain::pose_pair_with_sin_cos`]).
    pub fn for_each_pose(
        &self,
        tips: &Tips,
        obs: &[Observation],
        members: impl IntoIterator<Item = usize>,
        mut f: impl FnMut(usize, &ToolPose),
    ) {
        let same_chain = |a: usize, b: usize| {
            let (ta, tb) = (obs[a].tip, obs[b].tip);
            ta == tb || std::ptr::eq(tips.tip(ta), tips.tip(tb))
        };
        let mut own = [None, None];
        for (a, second) in pairs(members.into_iter(), same_chain) {
            let [own_a, own_b] = &mut own;
            let oa = &obs[a];
            let rows_a = self.row(a, oa, own_a);
            let chain = tips.tip(oa.tip);
            match second {
                Some(b) => {
                    let ob = &obs[b];
                    let [pa, pb] = chain
                        .pose_pair_with_sin_cos([&oa.q_deg, &ob.q_deg], [rows_a, self.row(b, ob, own_b)]);
                    f(a, &pa);
                    f(b, &pb);
                }
                None => f(a, &chain.pose_with_sin_cos(&oa.q_deg, rows_a)),
            }
        }
    }

    /// The tool pose of each observation `members` of `obs` on its tip's chain of `tips`, in
    /// order ([`Encoders::for_each_pose`]).
    pub fn poses_on(
        &self,
        tips: &Tips,
        obs: &[Observation],
        members: impl ExactSizeIterator<Item = usize>,
    ) -> Vec<ToolPose> {
        let mut poses = Vec::with_capacity(members.len());
        self.for_each_pose(tips, obs, members, |_, pose| poses.push(*pose));
        poses
    }

    /// The table of `data`: its own when built and every row still holds its observation's
    /// angles (a selection of observations whose table was
    /// built takes its rows, [`Observations::without`]), else taken from this one when `data`'s
    /// observations are these or some of them in the same order (another selection of the same
    /// observations: a session or a few points left out, the orientations dropped), else built
    /// for `data`. A row depends on its angles alone, so a row whose angles are bit for bit those
    /// of an observation is its row, whichever table holds it.
    pub fn for_data(&self, data: &Observations) -> Encoders {
        if let Some(own) = data.built_encoders().filter(|own| own.holds_all(data)) {
            return own.clone();
        }
        if data.joints != self.joints {
            return Encoders::of(data);
        }
        let rows = self.rows();
        let mut taken = Vec::with_capacity(data.obs.len());
        let mut i = 0;
        for o in &data.obs {
            while i < rows && !self.holds(i, o) {
                i += 1;
            }
            if i == rows {
                return Encoders::of(data);
            }
            taken.push(i);
            i += 1;
        }
        if taken.len() == rows {
            return self.clone();
        }
        self.rows_of(&taken)
    }

    /// The table of rows `taken`, in that order, sharing these rows (one run of them when
    /// `taken` are consecutive); every row taken is one of this table's (a run past its end
    /// would read the shared rows after it).
    pub(crate) fn rows_of(&self, taken: &[usize]) -> Encoders {
        debug_assert!(taken.iter().all(|&i| i < self.rows()), "a row past the table's end");
        let consecutive = taken.windows(2).all(|w| w[1] == w[0] + 1);
        let rows = match (&self.rows, taken.first()) {
            (Rows::Run { first, .. }, Some(&i)) if consecutive => {
                Rows::Run { first: first + i, count: taken.len() }
            }
            (_, None) => Rows::Run { first: 0, count: 0 },
            _ => Rows::Picked(taken.iter().map(|&i| self.shared(i)).collect()),
        };
        Encoders { rows, ..self.clone() }
    }

    /// Each row's angle count and its angles' bits, `joints + 1` values per row, in order.
    #[cfg(test)]
    fn angles(&self) -> Vec<u64> {
        let width = self.joints + 1;
        (0..self.rows())
            .flat_map(|i| &self.angles[self.shared(i) * width..(self.shared(i) + 1) * width])
            .copied()
            .collect()
    }
}

/// `members` in order, two at a time where `same` holds of the first and the next (else one).
pub(crate) fn pairs(
    mut members: impl Iterator<Item = usize>,
    same: impl Fn(usize, usize) -> bool,
) -> impl Iterator<Item = (usize, Option<usize>)> {
    // By hand rather than `Peekable::next_if`, which the compiler leaves as a call per member
    // on the kinematics' hot loop.
    let mut next = members.next();
    std::iter::from_fn(move || {
        let first = next.take()?;
        next = members.next();
        match next {
            Some(second) if same(first, second) => {
                next = members.next();
                Some((first, Some(second)))
            }
            _ => Some((first, None)),
        }
    })
}

/// The [`Encoders`] of a set of observations, built at its first use. It is no part of their
/// value (equal observations are equal whatever their caches hold), and a row that no longer holds
/// its observation's angles (the observations changed since) is not read.
#[derive(Clone, Default)]
pub(super) struct EncoderCache(OnceLock<Encoders>);

impl EncoderCache {
    /// The table of `data`, whose cache this is.
    pub(super) fn of(&self, data: &Observations) -> &Encoders {
        self.0.get_or_init(|| Encoders::of(data))
    }

    /// The table when built.
    pub(super) fn built(&self) -> Option<&Encoders> {
        self.0.get()
    }

    /// The cache of a selection of these observations (`kept`, in order): their rows when this
    /// table is built (a row no longer holding its observation's angles is no more read there
    /// than here), else empty.
    pub(super) fn rows_of(&self, kept: &[usize]) -> EncoderCache {
        match self.0.get().filter(|e| kept.iter().all(|&k| k < e.rows())) {
            Some(encoders) => EncoderCache(OnceLock::from(encoders.rows_of(kept))),
            None => EncoderCache::default(),
        }
    }
}

impl PartialEq for EncoderCache {
    fn eq(&self, _: &EncoderCache) -> bool {
        true
    }
}

impl std::fmt::Debug for EncoderCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0.get() {
            Some(e) => e.fmt(f),
            None => f.write_str("Encoders (not built)"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Landmark;
    use crate::model::kinematics::Tips;
    use crate::model::{ArmModel, Convention};

    /// Touches of two placements at varied angles, one of them lacking its last two angles.
    fn touches() -> Observations {
        let angles: Vec<Vec<f64>> = (0..12)
            .map(|t| {
                let count = if t == 5 { 4 } else { 6 };
                (0..count).map(|j| ((t * 7 + j) as f64 * 0.77).sin() * 170.0).collect()
            })
            .collect();
        let touches: Vec<(usize, usize, u32, &[f64])> =
            angles.iter().enumerate().map(|(t, q)| (t % 2, t % 3, 1, q.as_slice())).collect();
        let landmarks = (0..3)
            .map(|l| Landmark { id: format!("L{l}"), xyz_mm: [l as f64, 0.0, 0.0], yaw_deg: 0.0 })
            .collect();
        Observations::from_touches(&["A", "B"], landmarks, &touches)
    }

    /// The SUTA with encoder offsets and a scale, in `convention`.
    fn offset_arm(convention: Convention) -> ArmModel {
        let mut model = ArmModel::suta_nominal();
        model.convention = convention;
        for (j, joint) in model.joints.iter_mut().enumerate() {
            joint.offset_deg = 3.1 * j as f64 - 7.3;
        }
        model.scale_ppm = 80.0;
        model
    }

    /// `data`'s poses on `model` from the table and from each observation's own angles.
    fn poses(model: &ArmModel, data: &Observations) -> Vec<(ToolPose, ToolPose, ToolPose)> {
        let tips = Tips::new(model);
        (0..data.obs.len())
            .map(|k| {
                let (chain, q) = (tips.tip(data.obs[k].tip), &data.obs[k].q_deg);
                let own: Vec<(f64, f64)> = q.iter().map(|&a| encoder_sin_cos(a)).collect();
                (data.pose_on(&tips, k), chain.pose_with_sin_cos(q, &own), chain.pose(q))
            })
            .collect()
    }

    /// A pose read from the table is, bit for bit, the pose of the observation's own angles'
    /// sines and cosines; that is `Chain::pose` to rounding (θ = φ + δθ by angle addition), and
    /// to the bit without offsets or with an encoder harmonic (whose θ reads no table).
    #[test]
    fn table_poses_are_the_poses_of_the_angles() {
        let data = touches();
        assert_eq!(data.obs[5].q_deg.len(), 4, "a touch lacks angles");
        for convention in [Convention::Classic, Convention::Modified] {
            for (table, own, plain) in poses(&offset_arm(convention), &data) {
                assert_eq!(table, own);
                assert!((table.position_mm - plain.position_mm).norm() < 1e-9);
                assert!(
                    (table.x_axis - plain.x_axis).norm() < 1e-14
                        && (table.z_axis - plain.z_axis).norm() < 1e-14
                );
            }
        }
        let mut no_offsets = offset_arm(Convention::Classic);
        no_offsets.joints.iter_mut().for_each(|j| j.offset_deg = 0.0);
        let mut harmonic = offset_arm(Convention::Classic);
        harmonic.joints[1].eccentricity_sin_deg = 0.02;
        for model in [no_offsets, harmonic] {
            for (table, own, plain) in poses(&model, &data) {
                assert_eq!((table, own), (plain, plain));
            }
        }
    }

    /// Poses taken two at a time ([`Encoders::for_each_pose`], [`Encoders::poses_on`]) are
    /// [`Encoders::pose`]'s to the bit and in the members' order: DH arms with a tool point (the
    /// two-pose kernel), a URDF arm, a compliance and an encoder harmonic (the general pass);
    /// every count of members (the last of an odd count alone), a selection out of order; a NaN
    /// angle in the table, a touch lacking angles, a row no longer holding its angles (posed from
    /// its own), a touch naming a tip the model lacks (its first chain's).
    #[test]
    fn poses_two_at_a_time_are_the_poses_alone() {
        let mut data = touches();
        data.obs[4].q_deg[3] = f64::NAN;
        data.obs[9].tip = 1;
        data.encoders();
        data.obs[7].q_deg[1] += 0.5;
        let mut urdf = offset_arm(Convention::Urdf);
        for joint in &mut urdf.joints {
            joint.origin_xyz_mm = [joint.a_mm, 0.0, joint.d_mm];
        }
        let mut compliant = offset_arm(Convention::Classic);
        compliant.joints[2].compliance_deg_per_m = 0.4;
        let mut harmonic = offset_arm(Convention::Modified);
        harmonic.joints[1].eccentricity_cos_deg = -0.02;
        let selections: Vec<Vec<usize>> =
            (0..=12).map(|n| (0..n).collect()).chain([vec![11, 3, 4, 8, 7], vec![9, 2]]).collect();
        for mut model in
            [offset_arm(Convention::Classic), offset_arm(Convention::Modified), urdf, compliant, harmonic]
        {
            model.tcp_mm = [14.0, -6.0, 180.0];
            let tips = Tips::new(&model);
            let encoders = data.encoders();
            for members in &selections {
                let mut paired = Vec::new();
                encoders.for_each_pose(&tips, &data.obs, members.iter().copied(), |k, pose| {
                    paired.push((k, *pose))
                });
                let bits = |p: &ToolPose| [p.position_mm, p.x_axis, p.z_axis].map(|v| v.map(f64::to_bits));
                let alone: Vec<(usize, ToolPose)> = members
                    .iter()
                    .map(|&k| (k, encoders.pose(tips.tip(data.obs[k].tip), k, &data.obs[k])))
                    .collect();
                let label = format!("{:?} {members:?}", model.convention);
                assert_eq!(paired.len(), alone.len(), "{label}");
                for ((k, p), (m, a)) in paired.iter().zip(&alone) {
                    assert_eq!((k, bits(p)), (m, bits(a)), "{label}");
                    assert_eq!(p.position_mm.x.is_nan(), *k == 4, "{label} {k}");
                }
                let listed = encoders.poses_on(&tips, &data.obs, members.iter().copied());
                assert!(listed.iter().zip(&alone).all(|(l, (_, a))| bits(l) == bits(a)), "{label}");
                assert_eq!(listed.len(), alone.len());
            }
        }
    }

    /// Members pair up two at a time while they share a chain; one left over (an odd run, a
    /// chain change) is taken alone.
    #[test]
    fn consecutive_members_of_one_chain_pair_up() {
        let chains = [0, 0, 1, 1, 1, 0, 2, 2];
        let same = |a: usize, b: usize| chains[a] == chains[b];
        let got: Vec<_> = pairs(0..8, same).collect();
        assert_eq!(got, [(0, Some(1)), (2, Some(3)), (4, None), (5, None), (6, Some(7))]);
        let got: Vec<_> = pairs([7, 6, 0].into_iter(), same).collect();
        assert_eq!(got, [(7, Some(6)), (0, None)]);
        assert_eq!(pairs(0..0, same).count(), 0);
    }

    /// A selection of observations whose table is built reads that table (its rows not copied
    /// again); one whose table is not built takes its rows from another table, the rows its own
    /// angles give.
    #[test]
    fn a_selection_reads_its_own_table() {
        let data = touches();
        let full = data.encoders().clone();
        let selection = data.without(|k| k % 3 == 1);
        let own = selection.built_encoders().expect("a selection of a built table is built");
        assert_eq!(read_at(&full.for_data(&selection)), read_at(own));
        assert_eq!(own.table(), Encoders::of(&selection).table());
        let unbuilt = touches().without(|k| k % 4 == 2);
        assert!(unbuilt.built_encoders().is_none());
        let (taken, fresh) = (full.for_data(&unbuilt), Encoders::of(&unbuilt));
        assert_ne!(taken.table().len(), full.table().len(), "rows were left out");
        assert_eq!((taken.table(), taken.angles()), (fresh.table(), fresh.angles()));
    }

    /// Where a problem reads a table's rows ([`Encoders::by_index`]).
    fn read_at(e: &Encoders) -> (*const (f64, f64), Option<*const usize>) {
        let (rows, picked) = e.by_index();
        (rows.as_ptr(), picked.map(<[usize]>::as_ptr))
    }

    /// A selection of rows shares the table it was taken from (no row copied), one run of rows
    /// read as a slice of it, other rows by index, and reads the rows and poses of a table
    /// built for its observations, as does a selection of that selection (a run of a run, of
    /// picked rows; picked rows of either); no row at all.
    #[test]
    fn a_selection_shares_its_rows() {
        let model = offset_arm(Convention::Modified);
        let tips = Tips::new(&model);
        let data = touches();
        let full = data.encoders();
        let rows = |e: &Encoders| (e.table().to_vec(), e.angles());
        let shares =
            |e: &Encoders| Arc::ptr_eq(&e.table, &full.table) && Arc::ptr_eq(&e.angles, &full.angles);
        let by_index = |e: &Encoders| {
            let (rows, picked) = e.by_index();
            let joints = e.joints;
            (0..e.rows())
                .map(|k| picked.map_or(k, |p| p[k]))
                .flat_map(|r| rows[r * joints..(r + 1) * joints].to_vec())
                .collect::<Vec<_>>()
        };
        let check = |sub: &Observations, label: &str| {
            let own = sub.built_encoders().expect("a selection of a built table is built");
            let fresh = Encoders::of(sub);
            assert!(shares(own), "{label}");
            assert_eq!(rows(own), rows(&fresh), "{label}");
            assert_eq!(by_index(own), *fresh.table(), "{label}");
            for (k, o) in sub.obs.iter().enumerate() {
                assert_eq!(sub.pose_on(&tips, k), fresh.pose(tips.tip(o.tip), k, o), "{label} {k}");
            }
            own.clone()
        };
        // Observations 3..9 (a run) and all but 3..9 (picked).
        let run = data.without(|k| !(3..9).contains(&k));
        let own = check(&run, "a run");
        assert_eq!(read_at(&own), (full.table()[3 * data.joints..].as_ptr(), None));
        assert_eq!(own.table().as_ptr(), full.table()[3 * data.joints..].as_ptr(), "borrowed");
        for k in 0..6 {
            assert_eq!(run.pose_on(&tips, k), data.pose_on(&tips, k + 3));
        }
        let picked = data.without(|k| (3..9).contains(&k));
        assert!(read_at(&check(&picked, "picked")).1.is_some());
        for (from, name, of_a_run) in [(&run, "a run's", true), (&picked, "picked", false)] {
            for kept in [vec![1, 2, 3], vec![0, 2, 5]] {
                let sub = from.without(|k| !kept.contains(&k));
                let own = check(&sub, &format!("{name} {kept:?}"));
                let one_run = of_a_run && kept[2] - kept[0] == 2;
                assert_eq!(read_at(&own).1.is_none(), one_run, "{name} {kept:?}");
            }
        }
        let joints = data.joints;
        let out_of_order: Vec<(f64, f64)> =
            [4, 3, 5].iter().flat_map(|&r| full.table()[r * joints..(r + 1) * joints].to_vec()).collect();
        assert_eq!(*full.rows_of(&[4, 3, 5]).table(), out_of_order[..]);
        let none = full.rows_of(&[]);
        assert!(none.table().is_empty() && none.angles().is_empty() && shares(&none));
    }

    /// A row is read only while it holds its observation's angles: an angle changed after the
    /// table was built is posed from its new value; a selection of the observations takes their
    /// rows.
    #[test]
    fn a_row_is_that_of_its_angles() {
        let model = offset_arm(Convention::Classic);
        let tips = Tips::new(&model);
        let mut data = touches();
        let before = data.pose_on(&tips, 3);
        let built = data.encoders().table().as_ptr();
        data.obs[3].q_deg[2] += 1.0;
        let moved = data.pose_on(&tips, 3);
        assert_eq!(data.encoders().table().as_ptr(), built, "the table is kept");
        assert_ne!(moved, before);
        let fresh = Encoders::of(&data);
        assert_eq!(moved, fresh.pose(tips.tip(0), 3, &data.obs[3]));
        // Rows of another set of observations are not read either.
        let other = touches();
        assert_eq!(other.encoders().pose(tips.tip(0), 3, &data.obs[3]), moved);
        // A selection takes the rows of its observations, the changed one's not read there either.
        for selection in [data.without(|k| k % 3 == 1), data.subset(&[1])] {
            let fresh = Encoders::of(&selection);
            for (k, o) in selection.obs.iter().enumerate() {
                assert_eq!(selection.pose_on(&tips, k), fresh.pose(tips.tip(0), k, o));
            }
        }
        // The table a problem reads by index is never the stale one: the changed angle's row is
        // built again (and an unchanged table is the data's own).
        let given = other.encoders().for_data(&data);
        assert_eq!((given.table(), given.angles()), (fresh.table(), fresh.angles()));
        assert_eq!(other.encoders().for_data(&other).table().as_ptr(), other.encoders().table().as_ptr());
    }
}
