//! A point measured by an instrument: X_i = B_s · F(q_i; θ) · t, with B_s = (R_s, t_s) the
//! session's frame (instrument ← robot) and t the tool point (with the session's own offset Δ_s
//! when its tool floats: t + Δ_s in the flange frame). With a drift (`--drift-session`), the
//! session's points creep: X = g · R_s·p + t_s + v, the growth g and shift v linear in the row's
//! time or temperature ([`crate::calib::nuisance::drift`]). The residual is the predicted minus
//! the measured point, mm, three rows. The arm's columns leave out ∂(R_F·Δ_s)/∂θ: a re-mount's
//! offset is millimetres, so the term is second order (the residuals themselves are exact).

use super::{Term, TermInput, TermJacobian};
use crate::calib::nuisance::tool::flange_rotation;
use crate::data::Observations;
use nalgebra::Vector3;

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
        let (k, s) = (self.obs[0], self.block);
        let p = &at.data.obs[k];
        let pose = at.poses.of(k);
        let flange = flange_rotation(pose);
        let robot = pose.position_mm + flange * at.state.tools[self.group];
        let base = &at.state.frames[s];
        let y = base.rotation * robot;
        let drift = at.layout.drift(s).map(|(c, d)| {
            let delta = d.kind.variable(p).map_or(0.0, |v| v - d.centre);
            (c, d.kind, delta, d.kind.effect(&at.state.drifts[s], delta))
        });
        let (shift, growth) = drift.map_or((Vector3::zeros(), 1.0), |d| d.3);
        let e = y * growth + base.translation_mm + shift - p.point_mm().unwrap_or_default();
        r.copy_from_slice(e.as_slice());
        let Some(jac) = jac else {
            self.weigh(r, None);
            return;
        };
        let Some(chain) = at.poses.chain(k) else {
            self.weigh(r, None);
            return;
        };
        jac.push3_from(0, chain.iter().map(|d| base.rotation * Vector3::new(d[0], d[1], d[2]) * growth));
        if let Some(b) = at.layout.frame_column(s) {
            let turns = &at.state.frame_turns[s];
            for k in 0..3 {
                jac.push3(b + k, turns.column(k).cross(&y) * growth);
            }
            for k in 0..3 {
                jac.push3(b + 3 + k, Vector3::ith(k, 1.0));
            }
        }
        if let Some(t) = at.layout.tool_column(self.group) {
            let g = base.rotation * flange * growth;
            for k in 0..3 {
                jac.push3(t + k, g.column(k).into_owned());
            }
        }
        if let Some((c, kind, delta, _)) = drift {
            for k in 0..kind.unknowns() {
                jac.push3(c + k, kind.derivative(k, delta, &y));
            }
        }
        self.weigh(r, Some(jac));
    }
}

impl Point {
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
