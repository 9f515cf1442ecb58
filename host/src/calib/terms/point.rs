//! A point measured by an instrument: X_i = B_s · F(q_i; θ) · t, with B_s = (R_s, t_s) the
//! session's frame (instrument ← robot) and t the tool point (with the session's own offset Δ_s
//! when its tool floats: t + Δ_s in the flange frame). With a drift (`--drift-session`), the
//! session's points creep: X = g · R_s·p + t_s + v, the growth g and shift v linear in the row's
//! time or temperature ([`crate::calib::nuisance::drift`]). The residual is the predicted minus
//! the measured point, mm, three rows. The arm's columns leave out ∂(R_F·Δ_s)/∂θ: a re-mount's
//! offset is millimetres, so the term is second order (the residuals themselves are exact).

use super::{Derivatives3, Term, TermInput, TermJacobian};
use crate::calib::nuisance::drift::DriftKind;
use crate::calib::nuisance::frame::FRAME_UNKNOWNS;
use crate::calib::nuisance::tool::{flange_rotation, TOOL_UNKNOWNS};
use crate::data::Observations;
use crate::model::kinematics::PoseDerivative;
use crate::numerics::normal::RowTarget;
use nalgebra::{Matrix3, Vector3};

/// B_s · F(q) · (t + Δ_s) (+ drift) − X, times the weight of instrument rows in mixed data.
pub struct Point {
    obs: [usize; 1],
    block: usize,
    group: usize,
    weight: f64,
}

/// The point terms of every instrument observation, in file order, each row times `weight`.
pub fn terms(data: &Observations, weight: f64) -> Vec<Box<dyn Term>> {
    (0..data.obs.len())
        .filter(|&k| data.obs[k].point_mm().is_some())
        .map(|k| {
            let (block, group) = (data.obs[k].block, data.obs[k].group);
            Box::new(Point { obs: [k], block, group, weight }) as Box<dyn Term>
        })
        .collect()
}

impl Term for Point {
    fn rows(&self) -> usize {
        3
    }

    fn block(&self) -> usize {
        self.block
    }

    fn observations(&self) -> &[usize] {
        &self.obs
    }

    fn weight(&self) -> f64 {
        self.weight
    }

    fn evaluate(&self, at: &TermInput<'_>, r: &mut [f64], jac: Option<&mut TermJacobian>) {
        let point = self.residuals(at, r);
        let Some(jac) = jac else {
            self.weigh(r, None);
            return;
        };
        let Some(chain) = at.poses.chain(self.obs[0]) else {
            self.weigh(r, None);
            return;
        };
        self.derivatives(at, &point, chain, jac);
        self.weigh(r, Some(jac));
    }

    fn evaluate_into_rows(&self, at: &TermInput<'_>, r: &mut [f64], target: &mut dyn RowTarget) -> bool {
        let Some(chain) = at.poses.chain(self.obs[0]) else { return false };
        let point = self.residuals(at, r);
        let (s, layout) = (self.block, at.layout);
        let spans = [
            0..chain.len(),
            layout.frame_column(s).map_or(0..0, |b| b..b + FRAME_UNKNOWNS),
            layout.tool_column(self.group).map_or(0..0, |t| t..t + TOOL_UNKNOWNS),
            point.drift.map_or(0..0, |d| d.column..d.column + d.kind.unknowns()),
        ];
        let mut rows = target.rows(3, &spans);
        self.derivatives(at, &point, chain, &mut rows);
        self.weigh(r, None);
        if self.weight != 1.0 {
            rows.scale(self.weight);
        }
        true
    }
}

/// What a point's derivatives read of its residual's computation.
struct Evaluated {
    /// A floated tool's first column and the flange's rotation.
    tool: Option<(usize, Matrix3<f64>)>,
    /// The point in the instrument's axes before the frame's shift and the drift (R_s·p).
    y: Vector3<f64>,
    /// The drift's growth (1 without a drift).
    growth: f64,
    drift: Option<DriftAt>,
}

/// A drifting session's unknowns at one point.
#[derive(Clone, Copy)]
struct DriftAt {
    column: usize,
    kind: DriftKind,
    /// The point's time or temperature from the drift's centre.
    delta: f64,
}

impl Point {
    /// Its residuals (before the weight) into `r`, and what its derivatives read.
    fn residuals(&self, at: &TermInput<'_>, r: &mut [f64]) -> Evaluated {
        let (k, s) = (self.obs[0], self.block);
        let p = &at.data.obs[k];
        let pose = at.poses.of(k);
        // A tool that does not float has no offset (zero): the flange's point, with no product
        // by zeros and no flange rotation, which only a floated tool's columns read.
        let tool = at.layout.tool_column(self.group).map(|column| (column, flange_rotation(pose)));
        let robot = match &tool {
            Some((_, flange)) => pose.position_mm + flange * at.state.tools[self.group],
            None => pose.position_mm,
        };
        let base = &at.state.frames[s];
        let y = base.rotation * robot;
        let drift = at.layout.drift(s).map(|(column, d)| {
            let delta = d.kind.variable(p).map_or(0.0, |v| v - d.centre);
            (DriftAt { column, kind: d.kind, delta }, d.kind.effect(&at.state.drifts[s], delta))
        });
        let measured = p.point_mm().unwrap_or_default();
        // Without a drift, no product by a growth of 1 nor sum with a zero shift.
        let (e, growth) = match drift {
            Some((_, (shift, growth))) => (y * growth + base.translation_mm + shift - measured, growth),
            None => (y + base.translation_mm - measured, 1.0),
        };
        r.copy_from_slice(e.as_slice());
        Evaluated { tool, y, growth, drift: drift.map(|d| d.0) }
    }

    /// Its derivatives (before the weight) by the arm's columns (`chain`), its frame's, its
    /// tool's and its drift's, in that order, into `out`.
    fn derivatives(
        &self,
        at: &TermInput<'_>,
        point: &Evaluated,
        chain: &[PoseDerivative],
        out: &mut impl Derivatives3,
    ) {
        let s = self.block;
        let (base, y, growth) = (&at.state.frames[s], &point.y, point.growth);
        out.put_arm(chain, &base.rotation, growth);
        if let Some(b) = at.layout.frame_column(s) {
            let turns = &at.state.frame_turns[s];
            for k in 0..3 {
                out.put(b + k, turns.column(k).cross(y) * growth);
            }
            for k in 0..3 {
                out.put(b + 3 + k, Vector3::ith(k, 1.0));
            }
        }
        if let Some((t, flange)) = &point.tool {
            let (t, g) = (*t, base.rotation * flange * growth);
            for k in 0..3 {
                out.put(t + k, g.column(k).into_owned());
            }
        }
        if let Some(d) = point.drift {
            for k in 0..d.kind.unknowns() {
                out.put(d.column + k, d.kind.derivative(k, d.delta, y));
            }
        }
    }

    /// The rows (and derivatives) times the weight; nothing to do at weight 1 (one kind alone).
    fn weigh(&self, r: &mut [f64], jac: Option<&mut TermJacobian>) {
        if self.weight == 1.0 {
            return;
        }
        r.iter_mut().for_each(|v| *v *= self.weight);
        if let Some(jac) = jac {
            jac.values.iter_mut().for_each(|v| *v *= self.weight);
        }
    }
}
