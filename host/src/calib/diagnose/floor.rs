//! How far from done: the floor of the held-out data, the gap to it, and for instrument points a
//! floor-free check, the one part of the verdict each kind defines.
//!
//! * **Distances** ([`crate::calib::floor::noise_floor`]): the floor from repeated touches of a
//!   landmark in one placement and configuration, the expected held-out RMS of this model from it,
//!   and the test of the gap on ln(M/E) with an equivalence test for "at the floor".
//! * **Points** ([`crate::calib::floor::point_floor`]): the floor from repeated poses, else the
//!   stated σ, else unknown (then the model is never said to explain the data); the model explains
//!   the data within [`crate::calib::floor::EXPLAINS_WITHIN`] of it and misses beyond [`crate::calib::floor::GAP_Z`]
//!   standard errors ([`point_gap`]). Whatever the floor, the *neighbour bound*
//!   U = √(½ · mean |r_i − r_nn(i)|²), with r the held-out residuals (frame refitted) and nn(i)
//!   the nearest other point of the same session in joint space (degrees), bounds from above the
//!   noise (3-D RMS) plus the part of the model error that differs between neighbours:
//!   U² = σ²₃ + ½·mean |f(q_i) − f(q_nn(i))|² for residuals r = f(q) + noise. A held-out RMS
//!   beyond [`NEIGHBOUR_MARGIN`] × U therefore shows a model error that changes slowly over the
//!   joint space, beyond the noise: the model is called incomplete without any stated σ. A
//!   held-out RMS below it says nothing (neighbours too far apart for a smooth error to agree).

use super::words::mm;
use crate::calib::fit::Fit;
use crate::calib::floor::{gap, point_floor, point_gap, Gap, NoiseFloor};
use crate::calib::setup::Setup;
use crate::calib::validate::{session_offset_mm, session_residuals};
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::stats::{median, rms};
use nalgebra::Vector3;

/// Held-out RMS beyond this many neighbour bounds: the model is incomplete (model-free check).
pub const NEIGHBOUR_MARGIN: f64 = 1.5;
/// Fewest held-out points of a session for its neighbour bound.
pub const MIN_NEIGHBOUR_POINTS: usize = 20;

/// The neighbour bound of one held-out session's residuals (see the module doc).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct NeighbourBound {
    /// The held-out session.
    pub session: String,
    /// Its points.
    pub points: usize,
    /// Its held-out RMS, mm.
    pub rms_mm: f64,
    /// U = √(½ · mean |r_i − r_nn(i)|²), mm: at least the noise's 3-D RMS.
    pub bound_mm: f64,
    /// Median joint-space distance to the nearest neighbour, degrees.
    pub median_distance_deg: f64,
    /// Held-out RMS beyond [`NEIGHBOUR_MARGIN`] × U.
    pub incomplete: bool,
}

/// The floor of the held-out data and the verdict of the calibrated model against it.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Floor {
    /// Where the floor comes from: `repeated touches`, `repeated poses`, `stated uncertainty`,
    /// or `unknown`.
    pub source: String,
    /// Held-out RMS of a perfect model, mm (unknown without repeats or a stated σ).
    pub floor_mm: Option<f64>,
    /// The held-out RMS against what this model should leave (none when the floor is unknown).
    pub gap: Option<Gap>,
    /// The floor of distances from repeated touches, in full.
    pub distances: Option<NoiseFloor>,
    /// The neighbour bound of each held-out session with enough points.
    pub neighbours: Vec<NeighbourBound>,
}

/// The neighbour bound of each held-out session with enough points, from its residuals.
fn neighbour_bounds(val: &Observations, residuals: &[Vec<Vector3<f64>>]) -> Vec<NeighbourBound> {
    let mut out = Vec::new();
    for (b, r) in val.sessions().into_iter().zip(residuals) {
        let q: Vec<&[f64]> = val.blocks[b].members.iter().map(|&k| &val.obs[k].q_deg[..]).collect();
        if q.len() < MIN_NEIGHBOUR_POINTS {
            continue;
        }
        let mut squares = Vec::new();
        let mut distances = Vec::new();
        for i in 0..q.len() {
            let nearest = (0..q.len())
                .filter(|&j| j != i)
                .map(|j| (j, q[i].iter().zip(q[j]).map(|(a, b)| (a - b).powi(2)).sum::<f64>()))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((j, d2)) = nearest {
                squares.push((r[i] - r[j]).norm_squared());
                distances.push(d2.sqrt());
            }
        }
        let bound_mm = (squares.iter().sum::<f64>() / (2.0 * squares.len() as f64)).sqrt();
        let rms_mm = rms(&r.iter().map(|v| v.norm()).collect::<Vec<_>>());
        out.push(NeighbourBound {
            session: val.block_name(b),
            points: q.len(),
            rms_mm,
            bound_mm,
            median_distance_deg: median(distances),
            incomplete: rms_mm > NEIGHBOUR_MARGIN * bound_mm,
        });
    }
    out
}

impl Floor {
    /// The floor of held-out distances, `rms_mm` the calibrated model's held-out RMS.
    pub fn of_distances(floor: Option<NoiseFloor>, rms_mm: f64, val: &Observations) -> Floor {
        Floor {
            source: if floor.is_some() { "repeated touches" } else { "unknown" }.into(),
            floor_mm: floor.as_ref().map(|f| f.distance_rms_mm),
            gap: floor.as_ref().map(|f| gap(f, rms_mm, val)),
            distances: floor,
            neighbours: Vec::new(),
        }
    }

    /// The floor of held-out points for `model`, calibrated as `fit` (its degrees of freedom) of
    /// `setup`.
    pub fn of_points(setup: &Setup, fit: &Fit, model: &ArmModel, val: &Observations) -> Floor {
        let floor = point_floor(val, setup.stated_sigma_mm);
        let residuals: Vec<Vec<Vector3<f64>>> = val
            .sessions()
            .into_iter()
            .map(|b| {
                let offset = session_offset_mm(model, val, b, &setup.float_tool);
                session_residuals(model, val, b, offset)
            })
            .collect();
        let rms_mm = rms(&residuals.iter().flatten().map(|r| r.norm()).collect::<Vec<_>>());
        Floor {
            gap: point_gap(&floor, rms_mm, fit, val),
            source: floor.source,
            floor_mm: floor.rms_mm,
            distances: None,
            neighbours: neighbour_bounds(val, &residuals),
        }
    }

    /// The held-out RMS a complete model would leave, mm.
    pub fn expected_mm(&self) -> Option<f64> {
        self.gap.as_ref().map(|g| g.expected_mm)
    }

    /// The model explains the held-out data: at the floor.
    pub fn explains(&self) -> bool {
        self.gap.as_ref().is_some_and(|g| g.at_floor)
    }

    /// The model is shown incomplete: a gap beyond noise, or the neighbour check.
    pub fn incomplete(&self) -> bool {
        self.gap.as_ref().is_some_and(|g| g.significant) || self.neighbours.iter().any(|n| n.incomplete)
    }

    /// The verdict's first line.
    pub fn verdict(&self, rms_mm: f64, count: usize, what: &str) -> String {
        let Some(g) = &self.gap else {
            return if self.distances.is_none() && self.neighbours.is_empty() && what == "pairs" {
                format!(
                    "validation RMS of the calibrated model: {rms_mm:.3} mm over {count} pairs; no landmark was touched twice in a placement, so the noise floor is unknown and the model cannot be called explained"
                )
            } else {
                format!(
                    "{} mm held out; the floor is unknown (no repeated poses, no stated uncertainty): the model cannot be called explained",
                    mm(rms_mm)
                )
            };
        };
        if self.distances.is_some() {
            return g.sentence();
        }
        let f = self.floor_mm.unwrap_or(g.expected_mm);
        if g.at_floor {
            format!(
                "the model explains the held-out data: {} mm against a floor of {} mm ({})",
                mm(rms_mm),
                mm(f),
                self.source
            )
        } else if g.significant {
            format!(
                "{} mm held out, floor {} mm ({}): the model misses about {} mm ({:.1} standard errors above what the fitted parameters and the noise leave)",
                mm(rms_mm),
                mm(f),
                self.source,
                mm(g.missing_mm),
                g.z
            )
        } else {
            format!(
                "{} mm held out, floor {} mm ({}): {:.2}× the floor, within what the fitted parameters and the sampling of {count} held-out points allow ({:.1} standard errors): cannot tell; more held-out points would tell",
                mm(rms_mm),
                mm(f),
                self.source,
                rms_mm / f,
                g.z
            )
        }
    }

    /// A line per neighbour bound.
    pub fn neighbour_lines(&self) -> Vec<String> {
        self.neighbours
            .iter()
            .map(|n| {
                let line = format!(
                    "neighbour check of {} (no floor needed): residuals of the nearest poses in joint space (median {:.1}° apart) differ by {} mm (RMS/√2), an upper bound on noise plus small-scale error",
                    n.session, n.median_distance_deg, mm(n.bound_mm)
                );
                if n.incomplete {
                    format!(
                        "{line}; {} mm held out there is {:.2}× that: the model is incomplete (an error that varies slowly over the joint space is left)",
                        mm(n.rms_mm),
                        n.rms_mm / n.bound_mm
                    )
                } else {
                    format!(
                        "{line}; {} mm held out there is {:.2}× that, within {NEIGHBOUR_MARGIN}×: this check cannot tell",
                        mm(n.rms_mm),
                        n.rms_mm / n.bound_mm
                    )
                }
            })
            .collect()
    }
}
