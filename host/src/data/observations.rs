//! The one shape of every measurement: observations in blocks.
//!
//! An observation is the arm's joint angles (any count, 1 to [`MAX_TREE_JOINTS`]: a chain's or a whole tree's) and what the tool
//! was at: a certified landmark of an artefact, or a point (with an optional orientation)
//! measured by an instrument in its own frame. Observations come in *blocks* that share
//! unknowns: an artefact placement × repeat (the artefact sat still; distances between its
//! touches are frame-free) or an instrument session (one unknown instrument ← robot frame).
//! Blocks belong to *groups*, what a user names: a placement with its repeats, or a session.
//!
//! Readers turn each file format into [`Observations`] (artefact sessions in [`crate::data`],
//! tracker CSVs in [`crate::data::tracker`]); nothing downstream knows the format. One
//! [`Observations`] may hold both kinds (artefact placements and tracker sessions of one arm).

use crate::data::encoders::EncoderCache;
use crate::data::{Encoders, Landmark};
use crate::model::kinematics::{Tips, ToolPose};
use crate::model::MAX_TREE_JOINTS;
use nalgebra::{UnitQuaternion, Vector3};
use std::collections::HashMap;
use std::path::PathBuf;

/// Joint angles of one observation, degrees: 1 to [`MAX_TREE_JOINTS`] values stored inline (no
/// allocation, `Copy`); reads as a slice.
#[derive(Clone, Copy)]
pub struct Joints {
    len: u8,
    deg: [f64; MAX_TREE_JOINTS],
}

impl Joints {
    /// The angles of `values`; `None` when there are none or more than [`MAX_TREE_JOINTS`].
    pub fn new(values: &[f64]) -> Option<Joints> {
        if values.is_empty() || values.len() > MAX_TREE_JOINTS {
            return None;
        }
        let mut deg = [0.0; MAX_TREE_JOINTS];
        deg[..values.len()].copy_from_slice(values);
        Some(Joints { len: values.len() as u8, deg })
    }

    /// Each angle through `f`.
    pub fn map(&self, f: impl Fn(f64) -> f64) -> Joints {
        let mut out = *self;
        out.iter_mut().for_each(|v| *v = f(*v));
        out
    }
}

impl std::ops::Deref for Joints {
    type Target = [f64];
    fn deref(&self) -> &[f64] {
        &self.deg[..self.len as usize]
    }
}

impl std::ops::DerefMut for Joints {
    fn deref_mut(&mut self) -> &mut [f64] {
        &mut self.deg[..self.len as usize]
    }
}

impl PartialEq for Joints {
    fn eq(&self, other: &Joints) -> bool {
        **self == **other
    }
}

impl std::fmt::Debug for Joints {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        (**self).fmt(f)
    }
}

impl serde::Serialize for Joints {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        (**self).serialize(s)
    }
}

impl<'de> serde::Deserialize<'de> for Joints {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Joints, D::Error> {
        let values = Vec::<f64>::deserialize(d)?;
        Joints::new(&values).ok_or_else(|| {
            serde::de::Error::custom(format!(
                "expected 1 to {MAX_TREE_JOINTS} angles, found {}",
                values.len()
            ))
        })
    }
}

/// What the tool of one observation was at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Target {
    /// A certified landmark of the artefact (index into [`Observations::landmarks`]).
    Landmark(usize),
    /// A point measured by an instrument in its own frame, mm, with the probe's orientation in
    /// that frame for 6-DoF probes.
    Point {
        /// The measured point, mm.
        xyz_mm: Vector3<f64>,
        /// The probe's measured orientation.
        orientation: Option<UnitQuaternion<f64>>,
    },
    /// A point measured by an instrument whose frame is not kept from point to point: only the
    /// distances between the points of one session are measurements ([`Kind::PointDistances`]).
    Unframed {
        /// The measured point, mm.
        xyz_mm: Vector3<f64>,
    },
}

/// Which reader made a group: what the user measured with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Touches of a certified artefact (`suta-session/1`).
    Artefact,
    /// Points of an instrument (`kincal-tracker/1`).
    Tracker,
    /// Frame-free distances between an instrument's points (`kincal-point-distances/1`).
    PointDistances,
}

impl Kind {
    /// The word in messages and in summary.json.
    pub fn word(self) -> &'static str {
        match self {
            Kind::Artefact => "artefact",
            Kind::Tracker => "tracker",
            Kind::PointDistances => "point-distances",
        }
    }
}

/// The kinds a set of observations holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DataKind {
    /// Artefact placements only.
    Artefact,
    /// Tracker sessions only.
    Tracker,
    /// Both.
    Mixed,
}

impl DataKind {
    /// The word in messages and in summary.json.
    pub fn word(self) -> &'static str {
        match self {
            DataKind::Artefact => "artefact",
            DataKind::Tracker => "tracker",
            DataKind::Mixed => "mixed",
        }
    }
}

/// A placement of the artefact (with its repeats) or an instrument session: what a file holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Group {
    /// Placement name or session name (the file name without `.csv`).
    pub name: String,
    /// The file it was read from.
    pub source: PathBuf,
    /// Which reader made it.
    pub kind: Kind,
    /// The arm it was measured on, when its file names one.
    pub arm: Option<crate::trace::ArmIdentity>,
}

/// Observations that share unknowns: a placement × repeat, or a session.
#[derive(Clone, Debug, PartialEq)]
pub struct Block {
    /// Its group.
    pub group: usize,
    /// Repeat number within the placement (1 for a session).
    pub repeat: u32,
    /// Its observations (indices into [`Observations::obs`]), in file order.
    pub members: Vec<usize>,
}

/// One measurement: joint angles and what the tool was at.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    /// Its block (index into [`Observations::blocks`]).
    pub block: usize,
    /// Its group (index into [`Observations::groups`]).
    pub group: usize,
    /// Repeat number within the placement (1 for a session).
    pub repeat: u32,
    /// Joint angles as the controller reports them, degrees (raw encoder angles in [0, 360) for
    /// artefact sessions).
    pub q_deg: Joints,
    /// Standard error of each averaged joint angle, degrees, when the file reports it. Boxed: few
    /// files report it, and inline it was a third of every observation that the refits copy.
    pub q_sigma_deg: Option<Box<Joints>>,
    /// What the tool was at.
    pub target: Target,
    /// The instrument's stated standard uncertainty of the point per axis, mm.
    pub sigma_mm: Option<f64>,
    /// Time of the measurement, s.
    pub time_s: Option<f64>,
    /// Temperature, °C.
    pub temp_c: Option<f64>,
    /// Pose id: observations of one group with the same id are repeats of one arm pose.
    pub pose: Option<String>,
    /// Line in the file (tracker CSV), or the 1-based measurement number (artefact session).
    pub line: usize,
    /// The tip the tool point belongs to: an index into a branched model's tips (see
    /// [`crate::model::Tree`]), 0 for a single chain.
    pub tip: usize,
}

impl Observation {
    /// An artefact touch of `landmark` in `group` at `q_deg` (block set by
    /// [`Observations::rebuild_blocks`]); `line` is its 1-based measurement number.
    pub fn touch(group: usize, landmark: usize, repeat: u32, q_deg: Joints, line: usize) -> Observation {
        Observation {
            block: 0,
            group,
            repeat,
            q_deg,
            q_sigma_deg: None,
            target: Target::Landmark(landmark),
            sigma_mm: None,
            time_s: None,
            temp_c: None,
            pose: None,
            line,
            tip: 0,
        }
    }

    /// An instrument's point `xyz_mm` (and a probe's `orientation`) of `group` at `q_deg`, with
    /// its stated `sigma_mm` (block set by [`Observations::rebuild_blocks`]); `line` is its line.
    pub fn point(
        group: usize,
        q_deg: Joints,
        xyz_mm: Vector3<f64>,
        orientation: Option<UnitQuaternion<f64>>,
        sigma_mm: Option<f64>,
        line: usize,
    ) -> Observation {
        Observation {
            target: Target::Point { xyz_mm, orientation },
            sigma_mm,
            ..Observation::touch(group, 0, 1, q_deg, line)
        }
    }

    /// The landmark touched, for an artefact touch.
    pub fn landmark(&self) -> Option<usize> {
        match self.target {
            Target::Landmark(l) => Some(l),
            Target::Point { .. } | Target::Unframed { .. } => None,
        }
    }

    /// The landmark of an artefact touch, for analyses that read artefact touches only (their
    /// observations are [`Target::Landmark`]); 0 for an instrument's point.
    pub fn touched(&self) -> usize {
        self.landmark().unwrap_or(0)
    }

    /// The measured point, for an instrument's observation.
    pub fn point_mm(&self) -> Option<Vector3<f64>> {
        match self.target {
            Target::Point { xyz_mm, .. } => Some(xyz_mm),
            Target::Landmark(_) | Target::Unframed { .. } => None,
        }
    }

    /// The measured point of a frame-free instrument's observation (distances only).
    pub fn unframed_mm(&self) -> Option<Vector3<f64>> {
        match self.target {
            Target::Unframed { xyz_mm } => Some(xyz_mm),
            Target::Landmark(_) | Target::Point { .. } => None,
        }
    }

    /// The measured orientation, for a 6-DoF probe's observation.
    pub fn orientation(&self) -> Option<UnitQuaternion<f64>> {
        match self.target {
            Target::Point { orientation, .. } => orientation,
            Target::Landmark(_) | Target::Unframed { .. } => None,
        }
    }
}

/// Measurements of one arm, in blocks: what every reader makes and everything downstream reads.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Observations {
    /// Joint count of every observation.
    pub joints: usize,
    /// The artefact's certified landmarks (empty without artefact sessions).
    pub landmarks: Vec<Landmark>,
    /// Placements and sessions, in reading order.
    pub groups: Vec<Group>,
    /// Blocks, in the order their first observation comes.
    pub blocks: Vec<Block>,
    /// Every observation, in file order, group after group.
    pub obs: Vec<Observation>,
    /// Columns ignored and other things worth a look, one sentence each.
    pub warnings: Vec<String>,
    /// The names a `kincal-tracker/2` file gives its joint columns and tips, until
    /// [`Observations::bind`] puts the angles in the model's joint order.
    pub names: Option<ColumnNames>,
    /// The encoder angles' sines and cosines, built at the first [`Observations::encoders`].
    encoders: EncoderCache,
}

/// Joint columns and tips named in the files (`kincal-tracker/2`), not yet bound to a model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColumnNames {
    /// The joint each angle of an observation belongs to, in the files' column order.
    pub joints: Vec<String>,
    /// The tips, in the order first met: an observation's `tip` indexes this list.
    pub tips: Vec<String>,
    /// The file the names were read from (for messages).
    pub source: PathBuf,
}

/// An observation's names that the model does not have.
#[derive(Debug, thiserror::Error)]
pub enum BindError {
    /// The model records no joint names.
    #[error("{file}: the sessions name their joint columns (kincal-tracker/2); the model records no joint names: make it with `kincal model from-urdf`")]
    Unnamed {
        /// The session file.
        file: String,
    },
    /// A model joint has no column.
    #[error("{file}: no column `{joint}_deg` (or `_rad`) for the model's joint {joint}")]
    MissingJoint {
        /// The session file.
        file: String,
        /// The joint's name.
        joint: String,
    },
    /// A column names no joint of the model.
    #[error("{file}: column `{joint}_deg`: the model has no joint {joint} (its joints: {known})")]
    UnknownJoint {
        /// The session file.
        file: String,
        /// The column's joint.
        joint: String,
        /// The model's joints.
        known: String,
    },
    /// A tip the model does not have.
    #[error("{file}: column `tip`: the model has no tip {tip} (its tips: {known})")]
    UnknownTip {
        /// The session file.
        file: String,
        /// The tip's name.
        tip: String,
        /// The model's tips.
        known: String,
    },
}

impl Observations {
    /// No observation yet, of `joints` joints, on `landmarks`.
    pub fn new(joints: usize, landmarks: Vec<Landmark>) -> Observations {
        Observations { joints, landmarks, ..Observations::default() }
    }

    /// Artefact touches `(placement, landmark, repeat, joint angles)` on `landmarks`, one group per
    /// name of `placements` (for tests and for touches made in memory).
    pub fn from_touches(
        placements: &[&str],
        landmarks: Vec<Landmark>,
        touches: &[(usize, usize, u32, &[f64])],
    ) -> Observations {
        let mut data = Observations::new(touches.first().map_or(0, |t| t.3.len()), landmarks);
        for name in placements {
            data.push_group(name.to_string(), PathBuf::new(), Kind::Artefact);
        }
        for (i, &(group, landmark, repeat, q)) in touches.iter().enumerate() {
            let Some(q_deg) = Joints::new(q) else { continue };
            data.obs.push(Observation::touch(group, landmark, repeat, q_deg, i + 1));
        }
        data.rebuild_blocks();
        data
    }

    /// Add a group; returns its index.
    pub fn push_group(&mut self, name: String, source: PathBuf, kind: Kind) -> usize {
        self.groups.push(Group { name, source, kind, arm: None });
        self.groups.len() - 1
    }

    /// Recompute the blocks (and each observation's block) from the observations' group and
    /// repeat, in the order their first observation comes.
    pub fn rebuild_blocks(&mut self) {
        let mut index: HashMap<(usize, u32), usize> = HashMap::new();
        self.blocks.clear();
        // A block's observations mostly come in one run: the index is asked at a run's start.
        let mut last: Option<(usize, u32, usize)> = None;
        for (k, o) in self.obs.iter_mut().enumerate() {
            let b = match last.filter(|l| (l.0, l.1) == (o.group, o.repeat)) {
                Some(l) => l.2,
                None => *index.entry((o.group, o.repeat)).or_insert_with(|| {
                    self.blocks.push(Block { group: o.group, repeat: o.repeat, members: Vec::new() });
                    self.blocks.len() - 1
                }),
            };
            last = Some((o.group, o.repeat, b));
            self.blocks[b].members.push(k);
            o.block = b;
        }
    }

    /// The kinds held; `None` when there is no observation.
    pub fn kind(&self) -> Option<DataKind> {
        let has = |kind: Kind| self.obs.iter().any(|o| self.groups[o.group].kind == kind);
        match (has(Kind::Artefact), has(Kind::Tracker) || has(Kind::PointDistances)) {
            (true, false) => Some(DataKind::Artefact),
            (false, true) => Some(DataKind::Tracker),
            (true, true) => Some(DataKind::Mixed),
            (false, false) => None,
        }
    }

    /// The kind of observation `k`'s group.
    pub fn kind_of(&self, k: usize) -> Kind {
        self.groups[self.obs[k].group].kind
    }

    /// The sine and cosine of every encoder angle, computed at the first call and kept (by copies
    /// and selections too): what every pose of these observations reads
    /// ([`Observations::pose_on`]). A row whose observation's angles changed since is not read.
    pub fn encoders(&self) -> &Encoders {
        self.encoders.of(self)
    }

    /// [`Observations::encoders`] when already built, without building it.
    pub(crate) fn built_encoders(&self) -> Option<&Encoders> {
        self.encoders.built()
    }

    /// Observation `k`'s tool pose on its tip's chain of `tips`, its encoder angles' sines and
    /// cosines read from [`Observations::encoders`].
    pub fn pose_on(&self, tips: &Tips, k: usize) -> ToolPose {
        let o = &self.obs[k];
        self.encoders().pose(tips.tip(o.tip), k, o)
    }

    /// A copy without the observations for which `drop` (of their index) is true; groups stay.
    pub fn without(&self, drop: impl Fn(usize) -> bool) -> Observations {
        let kept: Vec<usize> = (0..self.obs.len()).filter(|&k| !drop(k)).collect();
        let mut out = Observations {
            obs: kept.iter().map(|&k| self.obs[k].clone()).collect(),
            blocks: Vec::new(),
            encoders: self.encoders.rows_of(&kept),
            ..self.clone_empty()
        };
        out.rebuild_blocks();
        out
    }

    /// A copy whose groups named in `groups` carry no measured orientation, or `None` when none of
    /// them carries one. A 6-DoF probe's orientation in a group whose tool floats (re-mounted,
    /// perhaps turned on its mount) is not the shared probe's: it informs only that group's own
    /// probe rotation, estimated afterwards from it.
    pub fn without_orientations_of(&self, groups: &[String]) -> Option<Observations> {
        // The names compared once per group, not once per observation.
        let named: Vec<bool> = self.groups.iter().map(|g| groups.contains(&g.name)).collect();
        if !named.contains(&true) || !self.obs.iter().any(|o| named[o.group] && o.orientation().is_some()) {
            return None;
        }
        let mut out = self.clone();
        for o in out.obs.iter_mut().filter(|o| named[o.group]) {
            if let Target::Point { orientation, .. } = &mut o.target {
                *orientation = None;
            }
        }
        Some(out)
    }

    /// A copy holding only the groups listed (by index), in that order.
    pub fn subset(&self, groups: &[usize]) -> Observations {
        let mut out = self.clone_empty();
        out.groups.clear();
        let mut kept = Vec::new();
        for &g in groups {
            let new = out.groups.len();
            out.groups.push(self.groups[g].clone());
            let members = self.group_members(g);
            out.obs.extend(members.iter().map(|&k| Observation { group: new, ..self.obs[k].clone() }));
            kept.extend(members);
        }
        out.encoders = self.encoders.rows_of(&kept);
        out.rebuild_blocks();
        out
    }

    /// A copy with the landmarks `landmarks` (a corrected certificate).
    pub fn with_landmarks(&self, landmarks: &[Landmark]) -> Observations {
        Observations { landmarks: landmarks.to_vec(), ..self.clone() }
    }

    /// A copy without the touches of one landmark.
    pub fn without_landmark(&self, landmark: usize) -> Observations {
        self.without(|k| self.obs[k].landmark() == Some(landmark))
    }

    /// The same groups and landmarks, no observation.
    fn clone_empty(&self) -> Observations {
        Observations {
            joints: self.joints,
            landmarks: self.landmarks.clone(),
            groups: self.groups.clone(),
            blocks: Vec::new(),
            obs: Vec::new(),
            warnings: self.warnings.clone(),
            names: self.names.clone(),
            encoders: EncoderCache::default(),
        }
    }

    /// Observations of group `g`, in file order (indices).
    pub fn group_members(&self, g: usize) -> Vec<usize> {
        (0..self.obs.len()).filter(|&k| self.obs[k].group == g).collect()
    }

    /// Certified distance between landmarks `a` and `b`, mm.
    pub fn landmark_distance_mm(&self, a: usize, b: usize) -> f64 {
        let (p, q) = (self.landmarks[a].xyz_mm, self.landmarks[b].xyz_mm);
        ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
    }

    /// Largest distance between two landmarks, mm (0 without an artefact).
    pub fn landmark_span_mm(&self) -> f64 {
        let n = self.landmarks.len();
        (0..n)
            .flat_map(|a| (a + 1..n).map(move |b| (a, b)))
            .fold(0.0_f64, |s, (a, b)| s.max(self.landmark_distance_mm(a, b)))
    }

    /// Index of the landmark called `id`.
    pub fn landmark_index(&self, id: &str) -> Option<usize> {
        self.landmarks.iter().position(|l| l.id == id)
    }

    /// Pairs of touches of different landmarks in one block (thesis eq. 3.1), as
    /// `(touch_a, touch_b)` indices, `a` before `b`, in the order of `a` then `b`.
    pub fn landmark_pairs(&self) -> Vec<(usize, usize)> {
        let mut pairs = Vec::new();
        for (a, oa) in self.obs.iter().enumerate() {
            let Some(la) = oa.landmark() else { continue };
            let members = &self.blocks[oa.block].members;
            let after = members.partition_point(|&b| b <= a);
            pairs.extend(
                members[after..]
                    .iter()
                    .filter(|&&b| self.obs[b].landmark().is_some_and(|lb| lb != la))
                    .map(|&b| (a, b)),
            );
        }
        pairs
    }

    /// How many pairs [`Observations::landmark_pairs`] returns, counted without forming them.
    pub fn pair_count(&self) -> usize {
        let pairs = |k: usize| k * k.saturating_sub(1) / 2;
        self.blocks
            .iter()
            .map(|b| {
                let mut by_landmark: HashMap<usize, usize> = HashMap::new();
                for l in b.members.iter().filter_map(|&k| self.obs[k].landmark()) {
                    *by_landmark.entry(l).or_default() += 1;
                }
                pairs(by_landmark.values().sum()) - by_landmark.values().map(|&c| pairs(c)).sum::<usize>()
            })
            .sum()
    }

    /// Observations that are instrument points.
    pub fn point_count(&self) -> usize {
        self.obs.iter().filter(|o| o.point_mm().is_some()).count()
    }

    /// The canonical name of observation `k` on the command line (`--exclude-point`):
    /// `SESSION:LINE` for an instrument's point, `PLACEMENT/REPEAT/LANDMARK` for a touch.
    pub fn point_name(&self, k: usize) -> String {
        let o = &self.obs[k];
        let group = &self.groups[o.group].name;
        match o.target {
            Target::Landmark(l) => format!("{group}/{}/{}", o.repeat, self.landmarks[l].id),
            Target::Point { .. } | Target::Unframed { .. } => format!("{group}:{}", o.line),
        }
    }

    /// The observations named `name` (see [`Observations::point_name`]).
    pub fn find_point(&self, name: &str) -> Vec<usize> {
        (0..self.obs.len()).filter(|&k| self.point_name(k) == name).collect()
    }

    /// The instrument sessions (blocks of tracker groups), in order.
    pub fn sessions(&self) -> Vec<usize> {
        (0..self.blocks.len()).filter(|&b| self.groups[self.blocks[b].group].kind == Kind::Tracker).collect()
    }

    /// The canonical name of block `b` (`--exclude-block`): `PLACEMENT/REPEAT`, or the session.
    pub fn block_name(&self, b: usize) -> String {
        let block = &self.blocks[b];
        let group = &self.groups[block.group];
        match group.kind {
            Kind::Artefact => format!("{}/{}", group.name, block.repeat),
            Kind::Tracker | Kind::PointDistances => group.name.clone(),
        }
    }

    /// The block called `name` (see [`Observations::block_name`]).
    pub fn find_block(&self, name: &str) -> Option<usize> {
        (0..self.blocks.len()).find(|&b| self.block_name(b) == name)
    }

    /// The group called `name`.
    pub fn find_group(&self, name: &str) -> Option<usize> {
        self.groups.iter().position(|g| g.name == name)
    }

    /// The one arm every group of `self` and `others` was measured on (see
    /// [`crate::trace::one_arm`]): `None` when none names one; refused, naming files and arms,
    /// for groups of two arms or of a named and an unnamed arm.
    pub fn one_arm(
        &self,
        others: &[&Observations],
    ) -> Result<Option<crate::trace::ArmIdentity>, crate::trace::MixedArms> {
        let groups: Vec<_> = std::iter::once(self)
            .chain(others.iter().copied())
            .flat_map(|d| d.groups.iter().map(|g| (g.source.clone(), g.arm.clone())))
            .collect();
        crate::trace::one_arm(&groups)
    }

    /// Per joint, the readings the observations of `self` and `others` visited: the shortest arc
    /// of the circle holding them all, `(from_deg in [0, 360), span_deg)`; empty without
    /// observations.
    pub fn joint_arcs(&self, others: &[&Observations]) -> Vec<(f64, f64)> {
        let all: Vec<&Observation> =
            std::iter::once(self).chain(others.iter().copied()).flat_map(|d| &d.obs).collect();
        let joints = all.iter().map(|o| o.q_deg.len()).max().unwrap_or(0);
        (0..joints)
            .map(|j| {
                let mut angles: Vec<f64> =
                    all.iter().filter_map(|o| o.q_deg.get(j)).map(|a| a.rem_euclid(360.0)).collect();
                angles.sort_by(f64::total_cmp);
                // The arc is the circle less its largest gap between neighbouring readings.
                let n = angles.len();
                let (gap, after) = (0..n)
                    .map(|k| {
                        let next = if k + 1 < n { angles[k + 1] } else { angles[0] + 360.0 };
                        (next - angles[k], (k + 1) % n)
                    })
                    .fold((f64::NEG_INFINITY, 0), |best, g| if g.0 > best.0 { g } else { best });
                (angles[after], 360.0 - gap)
            })
            .collect()
    }

    /// Put each observation's angles in `model`'s joint order and its tip in the model's tip
    /// numbering, when the files named their joint columns and tips (`kincal-tracker/2`); the
    /// names are then used up. Observations without names are left as they are.
    pub fn bind(&mut self, model: &crate::model::ArmModel) -> Result<(), BindError> {
        let Some(names) = self.names.take() else { return Ok(()) };
        let file = names.source.display().to_string();
        let Some(urdf) = model.urdf.as_ref() else { return Err(BindError::Unnamed { file }) };
        let model_joints: Vec<&str> = urdf.joint.iter().map(|j| j.name.as_str()).collect();
        for joint in &names.joints {
            if !model_joints.contains(&joint.as_str()) {
                let known = model_joints.join(", ");
                return Err(BindError::UnknownJoint { file, joint: joint.clone(), known });
            }
        }
        let mut order = Vec::with_capacity(model_joints.len());
        for joint in &model_joints {
            match names.joints.iter().position(|n| n == joint) {
                Some(c) => order.push(c),
                None => return Err(BindError::MissingJoint { file, joint: joint.to_string() }),
            }
        }
        let model_tips: Vec<String> = match model.tree.is_branched() {
            true => model.tree.tips.iter().map(|t| t.name.clone()).collect(),
            false => vec![urdf.tip.clone()],
        };
        let mut tips = Vec::with_capacity(names.tips.len());
        for tip in &names.tips {
            match model_tips.iter().position(|t| t == tip) {
                Some(t) => tips.push(t),
                None => {
                    return Err(BindError::UnknownTip {
                        file,
                        tip: tip.clone(),
                        known: model_tips.join(", "),
                    })
                }
            }
        }
        for o in &mut self.obs {
            let q: Vec<f64> = order.iter().map(|&c| o.q_deg.get(c).copied().unwrap_or(0.0)).collect();
            o.q_deg = Joints::new(&q).unwrap_or(o.q_deg);
            o.tip = tips.get(o.tip).copied().unwrap_or(0);
        }
        self.joints = model_joints.len();
        Ok(())
    }

    /// Observations and blocks of `other` after these (the same arm and joint count; landmarks
    /// from whichever has them).
    pub fn merge(mut self, other: Observations) -> Observations {
        let offset = self.groups.len();
        self.groups.extend(other.groups);
        self.obs.extend(other.obs.into_iter().map(|o| Observation { group: o.group + offset, ..o }));
        if self.landmarks.is_empty() {
            self.landmarks = other.landmarks;
        }
        self.joints = self.joints.max(other.joints);
        self.warnings.extend(other.warnings);
        self.rebuild_blocks();
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(group: usize, landmark: usize, repeat: u32) -> Observation {
        Observation::touch(group, landmark, repeat, Joints::new(&[0.0; 6]).unwrap(), 1)
    }

    #[test]
    fn joint_arcs_are_the_shortest_arcs_holding_every_reading() {
        let mut data = Observations::new(2, Vec::new());
        data.push_group("A".into(), "A.json".into(), Kind::Artefact);
        for q in [[350.0, 10.0], [20.0, 100.0], [5.0, 200.0]] {
            data.obs.push(Observation { q_deg: Joints::new(&q).unwrap(), ..touch(0, 0, 1) });
        }
        let mut other = Observations::new(2, Vec::new());
        other.obs.push(Observation { q_deg: Joints::new(&[-15.0, 150.0]).unwrap(), ..touch(0, 0, 1) });
        let arcs = data.joint_arcs(&[&other]);
        // Joint 1 wraps through 0°: from 345° (−15°) over 35°; joint 2 from 10° to 200°.
        assert!((arcs[0].0 - 345.0).abs() < 1e-9 && (arcs[0].1 - 35.0).abs() < 1e-9, "{arcs:?}");
        assert!((arcs[1].0 - 10.0).abs() < 1e-9 && (arcs[1].1 - 190.0).abs() < 1e-9, "{arcs:?}");
        assert_eq!(Observations::default().joint_arcs(&[]), []);
    }

    /// Blocks come in the order of their first observation, whatever order the observations
    /// of different blocks interleave in (runs and single observations).
    #[test]
    fn blocks_gather_interleaved_observations() {
        let mut data = Observations::new(6, Vec::new());
        data.push_group("A".into(), "A.json".into(), Kind::Artefact);
        data.push_group("B".into(), "B.json".into(), Kind::Artefact);
        let order = [(1, 2), (1, 2), (0, 1), (1, 2), (0, 2), (0, 1), (0, 1), (1, 1), (0, 2), (1, 2)];
        data.obs.extend(order.iter().map(|&(g, repeat)| touch(g, 0, repeat)));
        data.rebuild_blocks();
        let blocks: Vec<(usize, u32, Vec<usize>)> =
            data.blocks.iter().map(|b| (b.group, b.repeat, b.members.clone())).collect();
        let expected =
            vec![(1, 2, vec![0, 1, 3, 9]), (0, 1, vec![2, 5, 6]), (0, 2, vec![4, 8]), (1, 1, vec![7])];
        assert_eq!(blocks, expected);
        let of: Vec<usize> = data.obs.iter().map(|o| o.block).collect();
        assert_eq!(of, [0, 0, 1, 0, 2, 1, 1, 3, 2, 0]);
    }

    #[test]
    fn pairs_stay_within_one_block() {
        let mut data = Observations::new(6, Vec::new());
        data.push_group("A".into(), "A.json".into(), Kind::Artefact);
        data.push_group("B".into(), "B.json".into(), Kind::Artefact);
        data.obs = vec![touch(0, 0, 1), touch(0, 1, 1), touch(0, 1, 2), touch(1, 0, 1), touch(1, 1, 1)];
        data.rebuild_blocks();
        assert_eq!(data.landmark_pairs(), vec![(0, 1), (3, 4)]);
        assert_eq!(data.pair_count(), 2);
        assert_eq!(data.blocks.len(), 3);
        assert_eq!(data.subset(&[1]).landmark_pairs(), vec![(0, 1)]);
        assert_eq!(data.without(|k| k == 1).pair_count(), 1);
    }

    #[test]
    fn joints_hold_any_count_up_to_the_most() {
        let q = Joints::new(&[1.0, 2.0]).unwrap();
        assert_eq!((q.len(), q[1]), (2, 2.0));
        assert!(Joints::new(&[]).is_none() && Joints::new(&[0.0; MAX_TREE_JOINTS + 1]).is_none());
        assert_eq!(serde_json::to_string(&q).unwrap(), "[1.0,2.0]");
        assert_eq!(serde_json::from_str::<Joints>("[1.0,2.0]").unwrap(), q);
    }
}
