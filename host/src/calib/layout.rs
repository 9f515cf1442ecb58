//! Where each unknown sits in the one parameter vector (Ceres' parameter blocks), and the
//! unknowns turned into values.
//!
//! Columns, in order: the arm's free parameters | each framed block's frame (6: ω mrad, t mm) |
//! each floated group's tool offset (3, mm) | the probe's rotation (3, mrad) | each drifting
//! block's rates (1 or 3, in the order the drifts were named). A block's own unknowns (its frame,
//! its group's tool, its drift) touch only its own terms, which is what lets the problem fold the
//! rows block by block and eliminate them.

use crate::calib::nuisance::drift::DriftSlot;
use crate::calib::nuisance::frame::{Frame, FRAME_UNKNOWNS};
use crate::calib::nuisance::tool::{probe_rotation_at, TOOL_UNKNOWNS};
use crate::model::kinematics::ColumnMap;
use crate::model::{ArmModel, ParamId};
use crate::numerics::geometry::left_jacobian;
use nalgebra::{Matrix3, Vector3};

/// The columns of every unknown.
#[derive(Clone, Debug)]
pub struct Layout {
    /// The arm's free parameters, in column order (the first columns).
    pub arm: Vec<ParamId>,
    /// Their columns for the kinematics.
    pub columns: ColumnMap,
    frame: Vec<Option<usize>>,
    tool: Vec<Option<usize>>,
    rotation: Option<usize>,
    drift: Vec<Option<(usize, DriftSlot)>>,
    unknowns: usize,
}

impl Layout {
    /// Columns for `arm`, a frame for each block with `framed[b]`, a tool offset for each group
    /// with `floated[g]`, the probe rotation when `rotation`, and the drifts `drift` (per block).
    pub fn new(
        arm: Vec<ParamId>,
        framed: &[bool],
        floated: &[bool],
        rotation: bool,
        drift: &[Option<DriftSlot>],
    ) -> Layout {
        let mut next = arm.len();
        let mut take = |width: usize| {
            next += width;
            next - width
        };
        let frame = framed.iter().map(|&f| f.then(|| take(FRAME_UNKNOWNS))).collect();
        let tool = floated.iter().map(|&f| f.then(|| take(TOOL_UNKNOWNS))).collect();
        let rotation = rotation.then(|| take(3));
        let first = next;
        let drift: Vec<Option<(usize, DriftSlot)>> =
            drift.iter().map(|d| d.map(|d| (first + d.column, d))).collect();
        let width: usize = drift.iter().flatten().map(|d| d.1.kind.unknowns()).sum();
        Layout { columns: ColumnMap::new(&arm), arm, frame, tool, rotation, drift, unknowns: first + width }
    }

    /// Every unknown.
    pub fn unknowns(&self) -> usize {
        self.unknowns
    }

    /// Whether any unknown belongs to a block or group (not only the arm's).
    pub fn has_block_unknowns(&self) -> bool {
        self.unknowns > self.arm.len()
    }

    /// First column of block `b`'s frame.
    pub fn frame_column(&self, b: usize) -> Option<usize> {
        self.frame.get(b).copied().flatten()
    }

    /// First column of group `g`'s floated tool.
    pub fn tool_column(&self, g: usize) -> Option<usize> {
        self.tool.get(g).copied().flatten()
    }

    /// First column of the probe's rotation.
    pub fn rotation_column(&self) -> Option<usize> {
        self.rotation
    }

    /// Block `b`'s drift: its first column and slot.
    pub fn drift(&self, b: usize) -> Option<(usize, DriftSlot)> {
        self.drift.get(b).copied().flatten()
    }

    /// Columns of the unknowns that belong to group `g` (its blocks' frames, its tool, its
    /// blocks' drifts), given its blocks.
    pub fn own_columns(&self, g: usize, blocks: &[usize]) -> Vec<usize> {
        let mut own: Vec<usize> = Vec::new();
        for &b in blocks {
            own.extend(self.frame_column(b).map(|c| c..c + FRAME_UNKNOWNS).into_iter().flatten());
        }
        own.extend(self.tool_column(g).map(|c| c..c + TOOL_UNKNOWNS).into_iter().flatten());
        for &b in blocks {
            own.extend(self.drift(b).map(|(c, d)| c..c + d.kind.unknowns()).into_iter().flatten());
        }
        own
    }
}

/// The unknowns turned into what the terms read.
pub struct State {
    /// The model with the arm's columns set.
    pub model: ArmModel,
    /// Per block, its frame (the identity for a block without one).
    pub frames: Vec<Frame>,
    /// Per block, how its frame's rotation turns per unit of its unknowns (mrad): a change δω
    /// turns it by `frame_turns[b]·δω` rad, J_l(ω)·10⁻³ ([`left_jacobian`]).
    pub frame_turns: Vec<Matrix3<f64>>,
    /// Per group, its tool offset in the flange frame (zero unless floated), mm.
    pub tools: Vec<Vector3<f64>>,
    /// The probe's rotation on the flange (the identity without one).
    pub probe: Matrix3<f64>,
    /// How the probe's rotation turns, in its own frame, per unit of its unknowns (mrad):
    /// J_r(ψ)·10⁻³ = J_l(ψ)ᵀ·10⁻³.
    pub probe_turn: Matrix3<f64>,
    /// Per block, its drift rates (empty unless drifting).
    pub drifts: Vec<Vec<f64>>,
}

impl Layout {
    /// The values at `x`: `model` with the arm's columns set, each frame from its start rotation
    /// `frame_start[b]`, the probe from `probe_start`.
    pub fn state(
        &self,
        model: &ArmModel,
        x: &[f64],
        frame_start: &[Matrix3<f64>],
        probe_start: Option<&Matrix3<f64>>,
    ) -> State {
        let mut m = model.clone();
        for (id, v) in self.arm.iter().zip(x) {
            m.set(*id, *v);
        }
        let turn = |c: Option<usize>| {
            c.map_or(Matrix3::identity(), |c| left_jacobian(&(Vector3::new(x[c], x[c + 1], x[c + 2]) * 1e-3)))
                * 1e-3
        };
        State {
            frame_turns: (0..self.frame.len()).map(|b| turn(self.frame_column(b))).collect(),
            probe_turn: turn(self.rotation).transpose(),
            model: m,
            frames: (0..self.frame.len())
                .map(|b| match self.frame_column(b) {
                    Some(c) => Frame::at(&frame_start[b], &x[c..c + FRAME_UNKNOWNS]),
                    None => Frame::identity(),
                })
                .collect(),
            tools: (0..self.tool.len())
                .map(|g| {
                    self.tool_column(g).map_or(Vector3::zeros(), |c| Vector3::new(x[c], x[c + 1], x[c + 2]))
                })
                .collect(),
            probe: match (probe_start, self.rotation) {
                (Some(start), Some(c)) => probe_rotation_at(start, &x[c..c + 3]),
                _ => Matrix3::identity(),
            },
            drifts: (0..self.drift.len())
                .map(|b| self.drift(b).map_or(Vec::new(), |(c, d)| x[c..c + d.kind.unknowns()].to_vec()))
                .collect(),
        }
    }
}
