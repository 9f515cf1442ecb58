//! The held-out test's units, the one part of the test each kind of held-out data defines.
//!
//! A model's held-out errors are one list ([`Measure::errors`]): the distance errors between
//! touches of the validation placements, or the lengths of the point errors of the held-out
//! sessions (each session's frame refitted, and its tool where it floats). A *unit* is a set of
//! them whose log mean-square ratio is one number of the test, ln(MSE_before / MSE_after), and
//! units must be independent under "no effect":
//!
//! * **a validation placement** for distances. Its repeats share poses, configurations and the
//!   systematic residual, so they are not independent: each repeat is a *part*, and the unit's
//!   number is the mean over its parts of their log ratios;
//! * **a contiguous block of poses** of a held-out session for points, at most
//!   [`UNITS_PER_SESSION`] per session of at least [`MIN_UNIT_POINTS`] points each: instrument
//!   noise is independent from point to point, and the six frame values refitted on the whole
//!   session couple its blocks only weakly.
//!
//! The units' numbers go to the sign-flip and t test of [`crate::numerics::significance`].

use crate::calib::validate::{distance_errors, held_out_session_errors};
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::significance::held_out_p;
use crate::numerics::stats::rms;

/// Most test units (contiguous pose blocks) per held-out session.
pub const UNITS_PER_SESSION: usize = 8;
/// Fewest points of a test unit of a held-out session.
pub const MIN_UNIT_POINTS: usize = 6;

/// What the held-out data measure, which fixes how a model is scored on them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Measure {
    /// Distances between the touches of one artefact placement and repeat.
    Distances,
    /// Points of instrument sessions, each session's frame refitted.
    Points,
}

impl Measure {
    /// What `val` measures: `None` when it holds neither kind, or both.
    pub fn of(val: &Observations) -> Option<Measure> {
        let touches = val.obs.iter().any(|o| o.landmark().is_some());
        let points = !val.sessions().is_empty();
        match (touches, points) {
            (true, false) => Some(Measure::Distances),
            (false, true) => Some(Measure::Points),
            _ => None,
        }
    }

    /// The word in messages.
    pub fn word(self) -> &'static str {
        match self {
            Measure::Distances => "distances",
            Measure::Points => "points",
        }
    }

    /// The held-out errors of `model` on `val`, in the order [`Measure::units`] index them:
    /// signed distance errors, or lengths of point errors (each session's frame refitted, and
    /// its tool too where its group is in `float_tool`), mm.
    pub fn errors(self, model: &ArmModel, val: &Observations, float_tool: &[String]) -> Vec<f64> {
        match self {
            Measure::Distances => distance_errors(model, val).iter().map(|e| e.error_mm).collect(),
            Measure::Points => val
                .sessions()
                .into_iter()
                .flat_map(|b| held_out_session_errors(model, val, b, float_tool))
                .collect(),
        }
    }

    /// The test units of `val` (see the module doc).
    pub fn units(self, val: &Observations) -> Units {
        match self {
            Measure::Distances => {
                // Pairs in the order of the errors; a part per (placement, repeat) block in the
                // order first met, a unit per placement in placement order.
                let mut parts: Vec<(usize, Vec<usize>)> = Vec::new();
                for (i, (a, _)) in val.landmark_pairs().into_iter().enumerate() {
                    let block = val.obs[a].block;
                    match parts.iter_mut().find(|p| p.0 == block) {
                        Some(p) => p.1.push(i),
                        None => parts.push((block, vec![i])),
                    }
                }
                let mut units: Vec<Unit> = Vec::new();
                for (block, members) in parts {
                    let group = val.blocks[block].group;
                    match units.iter_mut().find(|u| u.group == group) {
                        Some(u) => u.parts.push(members),
                        None => units.push(Unit {
                            name: val.groups[group].name.clone(),
                            group,
                            parts: vec![members],
                        }),
                    }
                }
                units.sort_by_key(|u| u.group);
                Units { units }
            }
            Measure::Points => {
                let mut units = Vec::new();
                let mut at = 0;
                for b in val.sessions() {
                    let n =
                        val.blocks[b].members.iter().filter(|&&k| val.obs[k].point_mm().is_some()).count();
                    let blocks = (n / MIN_UNIT_POINTS).clamp(1, UNITS_PER_SESSION);
                    units.extend((0..blocks).map(|k| Unit {
                        name: format!("{} #{}", val.block_name(b), k + 1),
                        group: val.blocks[b].group,
                        parts: vec![(at + k * n / blocks..at + (k + 1) * n / blocks).collect()],
                    }));
                    at += n;
                }
                Units { units }
            }
        }
    }
}

/// One unit of the held-out test.
#[derive(Clone, Debug)]
pub struct Unit {
    /// The placement, or the session and the block's number.
    pub name: String,
    /// Its group in the held-out data.
    pub group: usize,
    /// Its parts (each a list of indices into the held-out errors): the repeats of a placement,
    /// or the one block of poses.
    pub parts: Vec<Vec<usize>>,
}

/// The units of one held-out data set.
#[derive(Clone, Debug)]
pub struct Units {
    /// In test order.
    pub units: Vec<Unit>,
}

/// Mean square error of every part of every unit.
#[derive(Clone, Debug, PartialEq)]
pub struct PartMse(Vec<Vec<f64>>);

/// A candidate's held-out figures against a reference (the calibrated model, or another
/// candidate).
#[derive(Clone, Debug)]
pub struct Score {
    /// Held-out RMS with the candidate, mm.
    pub rms_mm: f64,
    /// Parts whose error fell, and parts compared.
    pub parts_improved: (usize, usize),
    /// Units whose number is positive, and units compared.
    pub units_improved: (usize, usize),
    /// Mean over the parts of ln(MSE_before / MSE_after).
    pub mean_log_ratio: f64,
    /// Held-out p over the units' numbers.
    pub p_value: f64,
}

impl Units {
    /// How many.
    pub fn len(&self) -> usize {
        self.units.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.units.is_empty()
    }

    /// Mean square of `errors` over every part.
    pub fn mse(&self, errors: &[f64]) -> PartMse {
        PartMse(
            self.units
                .iter()
                .map(|u| {
                    u.parts
                        .iter()
                        .map(|p| {
                            p.iter().map(|&i| errors[i] * errors[i]).sum::<f64>() / p.len().max(1) as f64
                        })
                        .collect()
                })
                .collect(),
        )
    }

    /// Per unit, its parts' ln(MSE_before / MSE_after): positive where `after` is better.
    fn part_ratios(&self, before: &PartMse, after: &PartMse) -> Vec<Vec<f64>> {
        before
            .0
            .iter()
            .zip(&after.0)
            .map(|(b, a)| b.iter().zip(a).map(|(b, a)| (b.max(1e-300) / a.max(1e-300)).ln()).collect())
            .collect()
    }

    /// Each unit's number: the mean of its parts' log ratios.
    pub fn numbers(&self, before: &PartMse, after: &PartMse) -> Vec<f64> {
        self.part_ratios(before, after)
            .iter()
            .map(|r| r.iter().sum::<f64>() / r.len().max(1) as f64)
            .collect()
    }

    /// The held-out figures of `errors` against `before`.
    pub fn score(&self, before: &PartMse, errors: &[f64]) -> Score {
        let after = self.mse(errors);
        let ratios = self.part_ratios(before, &after);
        let parts: Vec<f64> = ratios.iter().flatten().copied().collect();
        let numbers = self.numbers(before, &after);
        Score {
            rms_mm: rms(errors),
            parts_improved: (parts.iter().filter(|r| **r > 0.0).count(), parts.len()),
            units_improved: (numbers.iter().filter(|r| **r > 0.0).count(), numbers.len()),
            mean_log_ratio: parts.iter().sum::<f64>() / parts.len().max(1) as f64,
            p_value: held_out_p(&numbers),
        }
    }

    /// Held-out p that `after` beats `before` (both errors of the same held-out data).
    pub fn p_better(&self, before: &[f64], after: &[f64]) -> f64 {
        held_out_p(&self.numbers(&self.mse(before), &self.mse(after)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_unit_is_the_mean_of_its_parts() {
        let units = Units {
            units: vec![
                Unit { name: "A".into(), group: 0, parts: vec![vec![0, 1], vec![2]] },
                Unit { name: "B".into(), group: 1, parts: vec![vec![3]] },
            ],
        };
        let before = units.mse(&[1.0, 1.0, 2.0, 1.0]);
        let score = units.score(&before, &[0.5, 0.5, 2.0, 2.0]);
        let numbers = units.numbers(&before, &units.mse(&[0.5, 0.5, 2.0, 2.0]));
        assert!((numbers[0] - 0.5 * 4f64.ln()).abs() < 1e-15 && (numbers[1] + 4f64.ln()).abs() < 1e-15);
        assert_eq!((score.parts_improved, score.units_improved), ((1, 3), (1, 2)));
    }
}
