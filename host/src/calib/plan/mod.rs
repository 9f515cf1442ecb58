//! What to measure next: artefact placements, or sessions of arm poses for an instrument, that
//! separate two rival explanations or pin down the weakest parameters.
//!
//! **Linearised model of a block.** Each measurement's tool point p(β) moves with the parameters
//! by J = ∂p/∂β (3 rows per touch or point). A block (an artefact placement's repeat, or an
//! instrument session) also has an unknown rigid frame: its six columns N (translation, rotation
//! about the points' centroid) are projected out, X = (I − N N⁺) J, so only what the artefact's
//! certified geometry or the instrument's frame-free shape can see remains. Noise is σ per axis
//! (the repeatability floor of touches, or the instrument's floor). Every parameter has a prior std of its
//! half-range (its bounds), so parameters the data cannot see keep a finite, honest variance.
//!
//! **Separating rivals A and B** (linearised T-optimal design). With δ̂_A fitted on the data
//! so far (least squares of the touch residuals on [X_M X_A]), A predicts the signal
//! s_A = X_A·δ̂_A. The separability
//! λ_AB = min_γ ‖s_A − [X_M X_B]·γ‖² (+ the prior on γ)
//! is what B cannot mimic if A is the cause, in σ² once divided by σ². With A, B swapped,
//! λ_BA. Placements are added greedily, each maximising (λ_AB + λ_BA)/σ² on the old and new
//! data together (the expected separation with either rival the cause; the minimum of the two
//! chases the rival whose fitted size is smallest, which matters least, and averaging λ over the
//! phase of the fitted parameters separated less in `kincal bench --plan`): the normal equations G = ΣXᵀX, b = ΣXᵀs, c = Σsᵀs are sums over
//! placements, so a candidate adds its rows' terms and λ = c − bᵀG⁻¹b (a rank-3n update).
//!
//! **Weak parameters** (D-optimal design). The information of the calibration data
//! F = ΣXᵀX/σ² + prior; a candidate placement gains log det(I + X F⁻¹ Xᵀ/σ²)
//! = log det(F + XᵀX/σ²) − log det F. Greedy, F updated after each pick. The weakest parameter
//! is the one whose one-std error moves the touches most after the rigid registration
//! (std × RMS of its projected column), in mm.
//!
//! Candidates ([`candidates`]): for an artefact, placements on a grid over the arm's table
//! (origins, heights 0 / 110 / 220 mm, yaws), each landmark posed by the inverse kinematics of
//! [`crate::simulate`] on the calibrated arm (random configuration per touch, seeded), kept when
//! at least [`candidates::MIN_TOUCHES`] landmarks are reachable with every joint above the table;
//! for an instrument, new sessions of arm poses drawn (seeded) within the joint ranges the data
//! already visit, so each pose is one the arm and the instrument's line of sight allowed.

pub mod candidates;
mod design;
pub mod trial;

pub use candidates::{candidate_placements, candidate_sessions, Candidate, Place, MIN_TOUCHES};
pub use trial::{measure, rival_trial, separation, weak_trial, RivalOutcome, TrialOptions, TrialOutcome};

use crate::data::{Artefact, Joints, Observations};
use crate::model::effects::Effect;
use crate::model::ArmModel;
use nalgebra::DVector;

/// Separability (in σ²) below which two rivals count as equivalent on the data (the review's
/// rule of thumb: a χ²₁ noncentrality of 13 gives a 5 %-level test about 95 % power).
pub const SEPARABLE_SIGMA2: f64 = 13.0;

/// Why a plan could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// A rival is not an effect of the library.
    #[error("--rivals: \"{0}\" is not an effect (e.g. compliance:3, harmonic:3:3, eccentricity:5)")]
    UnknownEffect(String),
    /// A rival is already in the model.
    #[error("--rivals: {0} is already in the model: a rival must be an effect the model lacks")]
    AlreadyIn(String),
    /// Two rivals are needed.
    #[error("--rivals takes two different effects, A,B (got {0})")]
    NotAPair(usize),
    /// No candidate is reachable.
    #[error(
        "no candidate placement of the artefact is reachable by this arm (at least {MIN_TOUCHES} landmarks), nor \
         any session of poses within the joint ranges the data visit"
    )]
    NothingReachable,
    /// The noise level is not a positive number.
    #[error("the measurement noise must be a positive number of mm, got {0}")]
    BadNoise(f64),
}

/// The angle range a joint passes over some touches (the shorter arc that holds them all), deg.
pub fn joint_range_deg(angles: &[f64]) -> (f64, f64) {
    let mut a: Vec<f64> = angles.iter().map(|x| x.rem_euclid(360.0)).collect();
    a.sort_by(f64::total_cmp);
    if a.is_empty() {
        return (0.0, 0.0);
    }
    // The largest gap between neighbours (with the wrap) is where the range does not go.
    let mut gap = (360.0 - a[a.len() - 1] + a[0], a.len() - 1);
    for k in 0..a.len() - 1 {
        if a[k + 1] - a[k] > gap.0 {
            gap = (a[k + 1] - a[k], k);
        }
    }
    let start = a[(gap.1 + 1) % a.len()];
    let end = a[gap.1];
    (start, if end < start { end + 360.0 } else { end })
}

/// One suggested placement of the artefact, or one suggested session of poses.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SuggestedPlacement {
    /// Artefact origin in the arm's base frame, mm (none for a session of an instrument).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub origin_mm: Option<[f64; 3]>,
    /// Artefact yaw about the base z axis, deg (none for a session).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub yaw_deg: Option<f64>,
    /// The new session's name (none for an artefact placement).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub session: Option<String>,
    /// Landmarks to touch (reachable there); `pose K` for a session.
    pub landmarks: Vec<String>,
    /// (joint 1-based, from deg, to deg) each joint passes over these poses.
    pub joint_ranges_deg: Vec<(usize, f64, f64)>,
    /// Joint angles of each touch or point, deg (the pose list).
    pub poses_deg: Vec<Joints>,
    /// The figure of merit after this placement is added (λ_AB + λ_BA in σ², or the log det
    /// gain).
    pub merit: f64,
    /// For rivals: RMS per pose, mm, by which the second rival's best fit misses the first's
    /// prediction here (and the reverse).
    pub differ_mm: Option<(f64, f64)>,
    /// For rivals: per pose, mm, the larger of the two misses (where the explanations differ).
    pub touch_differ_mm: Vec<f64>,
}

impl SuggestedPlacement {
    /// The poses where the rivals differ by at least `share` of the largest difference here:
    /// their landmarks, and the range (from, to deg) each joint passes over them.
    pub fn where_rivals_differ(&self, share: f64) -> (Vec<String>, Vec<(usize, f64, f64)>) {
        let most = self.touch_differ_mm.iter().copied().fold(0.0, f64::max);
        let picked: Vec<usize> =
            (0..self.touch_differ_mm.len()).filter(|&k| self.touch_differ_mm[k] >= share * most).collect();
        let joints = self.poses_deg.first().map_or(0, |p| p.len());
        let ranges = (0..joints)
            .map(|j| {
                let (from, to) =
                    joint_range_deg(&picked.iter().map(|&k| self.poses_deg[k][j]).collect::<Vec<_>>());
                (j + 1, from, to)
            })
            .collect();
        (picked.iter().map(|&k| self.landmarks[k].clone()).collect(), ranges)
    }
}

/// Two rivals and how far apart the data put them.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RivalPlan {
    /// The two effects.
    pub rivals: (String, String),
    /// Separabilities λ_AB, λ_BA on the data so far, in σ².
    pub before_sigma2: (f64, f64),
    /// The same with the suggested placements added.
    pub after_sigma2: (f64, f64),
    /// Placements, in the order chosen.
    pub placements: Vec<SuggestedPlacement>,
}

/// The weakest parameters and what the suggested placements do to their std.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WeakPlan {
    /// (parameter, unit, std now, std with the placements, tip effect mm now) worst first.
    pub stds: Vec<(String, &'static str, f64, f64, f64)>,
    /// Placements, in the order chosen.
    pub placements: Vec<SuggestedPlacement>,
}

/// What `kincal plan` finds.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Plan {
    /// Noise per axis of a touch or point, mm.
    pub touch_std_mm: f64,
    /// Candidate placements (or sessions) the arm can reach.
    pub candidates: usize,
    /// Placements that separate the rivals, when rivals were given.
    pub rivals: Option<RivalPlan>,
    /// Placements that pin down the weak parameters.
    pub weak: WeakPlan,
}

/// Settings of a plan.
#[derive(Clone, Debug)]
pub struct PlanOptions {
    /// Placements (or sessions) to suggest.
    pub count: usize,
    /// Seed of the candidates' arm configurations.
    pub seed: u64,
    /// Noise per axis of a touch or point, mm (from the floor).
    pub touch_std_mm: f64,
}

/// Plan placements of `artefact` (or, without one, sessions of poses for the instrument): to
/// separate `rivals` (when given) and to pin down the weak parameters. `cal` is what the model
/// was calibrated on; `val` is held-out data (used for the rivals).
pub fn plan(
    calibrated: &ArmModel,
    artefact: Option<&Artefact>,
    cal: &Observations,
    val: &Observations,
    rivals: Option<(&str, &str)>,
    options: &PlanOptions,
) -> Result<Plan, PlanError> {
    if !(options.touch_std_mm.is_finite() && options.touch_std_mm > 0.0) {
        return Err(PlanError::BadNoise(options.touch_std_mm));
    }
    let rivals = rivals
        .map(|(a, b)| {
            let parse = |name: &str| {
                let e = Effect::parse(name).ok_or_else(|| PlanError::UnknownEffect(name.to_string()))?;
                if e.is_in(calibrated) {
                    return Err(PlanError::AlreadyIn(name.to_string()));
                }
                Ok(e)
            };
            let (a, b) = (parse(a)?, parse(b)?);
            if a == b {
                return Err(PlanError::NotAPair(1));
            }
            Ok((a, b))
        })
        .transpose()?;
    let candidates = match artefact {
        Some(artefact) => candidate_placements(calibrated, artefact, options.seed),
        None => candidate_sessions(&[cal, val], options.seed),
    };
    if candidates.is_empty() {
        return Err(PlanError::NothingReachable);
    }
    let rivals = rivals.map(|(a, b)| design::plan_rivals(calibrated, cal, val, a, b, &candidates, options));
    let weak = design::plan_weak(calibrated, cal, &candidates, options);
    Ok(Plan { touch_std_mm: options.touch_std_mm, candidates: candidates.len(), rivals, weak })
}

/// RMS over poses of a 3-rows-per-pose vector, mm.
fn rms_per_touch(v: &DVector<f64>) -> f64 {
    (v.norm_squared() / (v.len() / 3).max(1) as f64).sqrt()
}

/// The suggestion of candidate `c` with its merit (and, for rivals, the two misses).
fn suggestion(c: &Candidate, merit: f64, differ: Option<(DVector<f64>, DVector<f64>)>) -> SuggestedPlacement {
    let encs: Vec<Joints> = c.poses.iter().map(|t| t.2).collect();
    let (origin_mm, yaw_deg, session) = match &c.place {
        Place::Placement(p) => (Some(p.origin_mm), Some(p.yaw_deg), None),
        Place::Session(name) => (None, None, Some(name.clone())),
    };
    SuggestedPlacement {
        origin_mm,
        yaw_deg,
        session,
        landmarks: c.poses.iter().map(|t| t.0.clone()).collect(),
        joint_ranges_deg: (0..encs.first().map_or(0, |e| e.len()))
            .map(|j| {
                let (from, to) = joint_range_deg(&encs.iter().map(|e| e[j]).collect::<Vec<_>>());
                (j + 1, from, to)
            })
            .collect(),
        poses_deg: encs,
        merit,
        differ_mm: differ.as_ref().map(|(ab, ba)| (rms_per_touch(ab), rms_per_touch(ba))),
        touch_differ_mm: differ.map_or_else(Vec::new, |(ab, ba)| {
            (0..ab.len() / 3).map(|k| ab.rows(3 * k, 3).norm().max(ba.rows(3 * k, 3).norm())).collect()
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_ranges_take_the_short_way_round() {
        assert_eq!(joint_range_deg(&[120.0, 200.0, 150.0]), (120.0, 200.0));
        assert_eq!(joint_range_deg(&[350.0, 10.0, 5.0]), (350.0, 370.0));
    }
}
