//! The candidates of a plan: artefact placements the arm can reach, or new sessions of arm poses
//! for an instrument.

use super::joint_range_deg;
use crate::data::{Artefact, Joints, Observations};
use crate::model::ArmModel;
use crate::simulate::{touch_encoders, Placement};
use nalgebra::Vector3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Fewest reachable landmarks for a candidate placement.
pub const MIN_TOUCHES: usize = 6;
/// Candidate sessions drawn for an instrument.
pub const CANDIDATE_SESSIONS: usize = 200;
/// Fewest poses of a candidate session (a frame needs three points; more for a residual).
pub const MIN_SESSION_POSES: usize = 6;

/// Where a candidate's measurements are made.
#[derive(Clone, Debug)]
pub enum Place {
    /// The artefact at this placement.
    Placement(Placement),
    /// A new session of the instrument (its frame unknown), by name.
    Session(String),
}

/// A candidate placement of the artefact, or a candidate session, and the poses it takes.
#[derive(Clone, Debug)]
pub struct Candidate {
    /// Where.
    pub place: Place,
    /// (what is measured: a landmark's id or `pose K`; the landmark's index for an artefact;
    /// joint angles deg) per pose.
    pub poses: Vec<(String, Option<usize>, Joints)>,
}

/// Artefact placements over the arm's table, each with the touches the arm can reach there.
pub fn candidate_placements(model: &ArmModel, artefact: &Artefact, seed: u64) -> Vec<Candidate> {
    let mut grid = Vec::new();
    for (ix, x) in [362.5, 437.5, 512.5, 587.5, 662.5].into_iter().enumerate() {
        for (iy, y) in [-187.5, -87.5, 12.5, 112.5, 212.5].into_iter().enumerate() {
            for (iz, z) in [0.0, 110.0, 220.0].into_iter().enumerate() {
                for (iw, yaw) in [-30.0, 0.0, 30.0].into_iter().enumerate() {
                    let name = format!("P{ix}{iy}{iz}{iw}");
                    grid.push(Placement { name, origin_mm: [x, y, z], yaw_deg: yaw });
                }
            }
        }
    }
    grid.into_par_iter()
        .enumerate()
        .filter_map(|(k, placement)| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
            let poses: Vec<(String, Option<usize>, Joints)> = artefact
                .landmarks
                .iter()
                .enumerate()
                .filter_map(|(l, landmark)| {
                    touch_encoders(model, &placement, landmark, Vector3::zeros(), &mut rng)
                        .and_then(|e| Joints::new(&e))
                        .map(|e| (landmark.id.clone(), Some(l), e))
                })
                .collect();
            (poses.len() >= MIN_TOUCHES).then_some(Candidate { place: Place::Placement(placement), poses })
        })
        .collect()
}

/// New sessions of an instrument: [`CANDIDATE_SESSIONS`] sets of arm poses, each joint drawn
/// (seeded, uniformly) within the range of angles `data` already visit for it (the shorter arc
/// holding them all, written in the data's own 360° window), as many poses as the data's median
/// session (at least [`MIN_SESSION_POSES`]). The data show that the arm reaches these angles and
/// that the instrument saw the tool there; joints drawn apart may still meet other limits, which
/// the user checks before measuring.
pub fn candidate_sessions(data: &[&Observations], seed: u64) -> Vec<Candidate> {
    let observations: Vec<&Joints> = data.iter().flat_map(|d| d.obs.iter().map(|o| &o.q_deg)).collect();
    let Some(joints) = observations.first().map(|q| q.len()) else { return Vec::new() };
    let ranges: Vec<(f64, f64, f64)> = (0..joints)
        .map(|j| {
            let angles: Vec<f64> = observations.iter().map(|q| q[j]).collect();
            let (from, to) = joint_range_deg(&angles);
            (from, to, angles.iter().copied().fold(f64::INFINITY, f64::min))
        })
        .collect();
    let mut sizes: Vec<usize> =
        data.iter().flat_map(|d| d.sessions().into_iter().map(|b| d.blocks[b].members.len())).collect();
    sizes.sort_unstable();
    let poses = sizes.get(sizes.len() / 2).copied().unwrap_or(0).max(MIN_SESSION_POSES);
    (0..CANDIDATE_SESSIONS)
        .into_par_iter()
        .filter_map(|k| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1_000_003).wrapping_add(k as u64));
            let pose = |rng: &mut ChaCha8Rng| {
                let angles: Vec<f64> = ranges
                    .iter()
                    .map(|&(from, to, lowest)| {
                        let a = from + rng.random::<f64>() * (to - from);
                        lowest + (a - lowest).rem_euclid(360.0)
                    })
                    .collect();
                Joints::new(&angles)
            };
            let poses: Option<Vec<(String, Option<usize>, Joints)>> =
                (0..poses).map(|p| pose(&mut rng).map(|q| (format!("pose {}", p + 1), None, q))).collect();
            Some(Candidate { place: Place::Session(format!("plan_{}", k + 1)), poses: poses? })
        })
        .collect()
}
