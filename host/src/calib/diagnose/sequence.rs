//! What is significant and what is named, for every kind of held-out data.
//!
//! *The fixed sequence.* Candidates — arm effects and data errors together — are tested in the
//! order the calibration data give them ([`super::evidence`]), each at [`FAMILY_ALPHA`] on the
//! held-out units, stopping at the first that fails; the order comes from data the test never
//! sees, so the family-wise error is controlled. A candidate must also lower the held-out RMS by
//! [`SIGNIFICANT_GAIN`].
//!
//! *Equivalents.* Candidates whose refits change the held-out errors the same way (correlation
//! of the changes ≥ [`EQUIVALENT_CORRELATION`]) are reported together: these data cannot tell
//! them apart at all.
//!
//! *Rivals.* "Helps" is not "is the cause": a proxy correlated with the true effect helps too.
//! The significant arm effect of lowest held-out RMS, A, is compared with every other significant
//! one B, and with every B of lower held-out RMS whose own held-out test passes although the fixed
//! sequence stopped before it, that it does not beat on the held-out units (paired test of
//! ln(MSE_B / MSE_A)): A + B is refitted (warm), and per unit e_B|A = ln(MSE_A / MSE_A+B) and
//! e_A|B = ln(MSE_B / MSE_A+B) are tested. Only A adds: A is the cause and B a proxy; only B adds:
//! B is the cause; both add: both are missing; neither adds: "A or B: these data cannot tell them
//! apart". These pairwise tests explain what the significant candidates are; they add no claim.
//!
//! *Naming.* The leader, the rivals it cannot be told from, and the significant candidates
//! equivalent to it that it does not beat on the held-out units are named. A significant data error whose held-out RMS is within [`DATA_ERROR_EXPLAINS`] of the
//! named arm effect's (or with no arm effect significant) is named instead: fix the data first.

use super::evidence::{Evidence, Refitted};
use super::units::{PartMse, Units};
use super::Candidate;

/// Family-wise false-alarm rate of the significance test over all candidates.
pub const FAMILY_ALPHA: f64 = 0.05;
/// Correlation of two candidates' changes to the held-out errors above which they are reported
/// as exactly equivalent.
pub const EQUIVALENT_CORRELATION: f64 = 0.98;
/// Relative drop of held-out RMS a candidate must reach to be called significant.
pub const SIGNIFICANT_GAIN: f64 = 0.02;
/// A data error is named instead of an arm effect when its held-out RMS is within this factor
/// of the named arm effect's.
pub const DATA_ERROR_EXPLAINS: f64 = 1.05;
/// Most rivals of the leading candidate tested against it.
const MAX_RIVALS: usize = 3;

/// How two significant candidates relate (see the module doc).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum RivalVerdict {
    /// Only `cause` adds to the other: the other is a proxy.
    Proxy {
        /// The effect that explains what the other does.
        cause: String,
        /// The effect that helps only through it.
        proxy: String,
    },
    /// Each adds to the other: both are missing.
    Both,
    /// Neither adds to the other: these data cannot tell them apart.
    CannotTell,
}

/// The leading candidate `a` against a rival `b`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Rival {
    /// The leading candidate.
    pub a: String,
    /// The rival.
    pub b: String,
    /// Held-out RMS with both refitted, mm.
    pub both_rms_mm: f64,
    /// Held-out p of adding `a` to `b`.
    pub a_adds_p: f64,
    /// Held-out p of adding `b` to `a`.
    pub b_adds_p: f64,
    /// min(λ_AB, λ_BA): how far the calibration data separate the two, in noise variances
    /// (below about 13 they are alike on these data), when computed.
    pub separability: Option<f64>,
    /// The verdict.
    pub verdict: RivalVerdict,
}

/// The candidate's own held-out test passes at [`FAMILY_ALPHA`] with the practical gain (and
/// the calibration data favour it): significant when the fixed sequence reaches it, else still a
/// rival of the leading candidate.
fn helps_alone(c: &Candidate, baseline_rms_mm: f64) -> bool {
    c.ranking.order.is_some_and(|o| o > 0.0)
        && c.p_value <= FAMILY_ALPHA
        && c.held_out_rms_mm <= (1.0 - SIGNIFICANT_GAIN) * baseline_rms_mm
}

/// Mark the candidates the fixed sequence reaches (`tested`) and those it finds significant.
pub fn decide(candidates: &mut [Candidate], data_errors: &mut [Candidate], baseline_rms_mm: f64) {
    let mut sequence: Vec<&mut Candidate> =
        candidates.iter_mut().chain(data_errors.iter_mut()).filter(|c| c.ranking.order.is_some()).collect();
    sequence
        .sort_by(|a, b| b.ranking.order.unwrap_or(f64::MIN).total_cmp(&a.ranking.order.unwrap_or(f64::MIN)));
    for c in sequence {
        c.tested = true;
        if !helps_alone(c, baseline_rms_mm) {
            break;
        }
        c.significant = true;
    }
}

/// Mark candidates (sorted best first, with their held-out errors) equivalent to a better-ranked
/// one when their changes to the held-out errors correlate at [`EQUIVALENT_CORRELATION`].
pub fn group_equivalents(candidates: &mut [Candidate], errors: &[&[f64]], baseline: &[f64]) {
    let change = |e: &[f64]| -> Vec<f64> { e.iter().zip(baseline).map(|(a, b)| a - b).collect() };
    let correlation = |a: &[f64], b: &[f64]| {
        let (ab, aa, bb) = a
            .iter()
            .zip(b)
            .fold((0.0, 0.0, 0.0), |(ab, aa, bb), (x, y)| (ab + x * y, aa + x * x, bb + y * y));
        if aa > 0.0 && bb > 0.0 {
            ab / (aa * bb).sqrt()
        } else {
            0.0
        }
    };
    let changes: Vec<Vec<f64>> = errors.iter().map(|e| change(e)).collect();
    let mut leaders: Vec<usize> = Vec::new();
    for i in 0..candidates.len() {
        match leaders.iter().find(|&&l| correlation(&changes[l], &changes[i]) >= EQUIVALENT_CORRELATION) {
            Some(&leader) => {
                candidates[i].equivalent_to = Some(candidates[leader].name.clone());
                let name = candidates[i].name.clone();
                candidates[leader].equivalent.push(name);
            }
            None => leaders.push(i),
        }
    }
}

/// What the rival tests need: the candidates (best held-out RMS first) with their refits and
/// held-out errors, the units, and the calibrated model's held-out RMS.
pub struct Contest<'a> {
    /// Arm-effect candidates, best first.
    pub candidates: &'a [Candidate],
    /// Their refits, in the same order.
    pub refits: &'a [Refitted],
    /// The held-out units.
    pub units: &'a Units,
    /// Held-out RMS of the calibrated model, mm.
    pub baseline_rms_mm: f64,
}

/// Test the leading significant arm effect against its rivals; returns the rivals and the
/// effects named (see the module doc): empty when no arm effect is significant.
pub fn rivals(x: &Contest, evidence: &dyn Evidence) -> (Vec<Rival>, Vec<String>) {
    let candidates = x.candidates;
    let Some(lead) = candidates.iter().position(|c| c.significant) else { return (Vec::new(), Vec::new()) };
    let a = &candidates[lead];
    let mse: Vec<PartMse> = x.refits.iter().map(|r| x.units.mse(&r.errors)).collect();
    let contenders: Vec<usize> = candidates
        .iter()
        .enumerate()
        .filter(|(k, c)| {
            *k != lead
                && (c.significant || (*k < lead && helps_alone(c, x.baseline_rms_mm)))
                && c.equivalent_to.is_none()
                && !a.equivalent.contains(&c.name)
        })
        // A beats B unless the paired test of ln(MSE_B / MSE_A) says so.
        .filter(|(k, _)| x.units.p_better(&x.refits[*k].errors, &x.refits[lead].errors) > FAMILY_ALPHA)
        .map(|(k, _)| k)
        .take(MAX_RIVALS)
        .collect();
    use rayon::prelude::*;
    let tested: Vec<Rival> = contenders
        .par_iter()
        .filter_map(|&k| {
            let b = &candidates[k];
            let both = evidence.both(&x.refits[lead], &x.refits[k])?;
            let b_adds = x.units.score(&mse[lead], &both);
            let a_adds = x.units.score(&mse[k], &both);
            let gain = |p: f64, after: f64, single: f64| {
                p <= FAMILY_ALPHA && after <= (1.0 - SIGNIFICANT_GAIN) * single
            };
            let a_helps = gain(a_adds.p_value, a_adds.rms_mm, b.held_out_rms_mm);
            let b_helps = gain(b_adds.p_value, b_adds.rms_mm, a.held_out_rms_mm);
            let verdict = match (a_helps, b_helps) {
                (true, false) => RivalVerdict::Proxy { cause: a.name.clone(), proxy: b.name.clone() },
                (false, true) => RivalVerdict::Proxy { cause: b.name.clone(), proxy: a.name.clone() },
                (true, true) => RivalVerdict::Both,
                (false, false) => RivalVerdict::CannotTell,
            };
            Some(Rival {
                a: a.name.clone(),
                b: b.name.clone(),
                both_rms_mm: b_adds.rms_mm,
                a_adds_p: a_adds.p_value,
                b_adds_p: b_adds.p_value,
                separability: evidence.separability(&x.refits[lead], &x.refits[k]),
                verdict,
            })
        })
        .collect();
    // A rival that explains what the leader does (and more) leads instead: of several, the one
    // with the strongest calibration evidence (data the held-out tests never saw).
    let evidence_of =
        |name: &str| candidates.iter().find(|c| c.name == name).map_or(f64::MIN, |c| c.ranking.calibration_z);
    let leader = tested
        .iter()
        .filter_map(|r| match &r.verdict {
            RivalVerdict::Proxy { cause, .. } if *cause == r.b => Some(cause.clone()),
            _ => None,
        })
        .max_by(|x, y| evidence_of(x).total_cmp(&evidence_of(y)))
        .unwrap_or_else(|| a.name.clone());
    let tied: Vec<String> =
        tested.iter().filter(|r| r.verdict == RivalVerdict::CannotTell).map(|r| r.b.clone()).collect();
    let mut named = vec![leader.clone()];
    named.extend(tied.into_iter().filter(|t| *t != leader));
    // A significant candidate whose refit changes the held-out errors as the leader's does, and
    // which the leader does not beat on the held-out units, cannot be told from it: named with it.
    let index = |name: &str| candidates.iter().position(|c| c.name == name);
    if let Some(l) = index(&leader) {
        let equivalent: Vec<String> = candidates[l]
            .equivalent
            .iter()
            .filter(|e| !named.contains(e))
            .filter(|e| {
                index(e).is_some_and(|k| {
                    candidates[k].significant
                        && x.units.p_better(&x.refits[k].errors, &x.refits[l].errors) > FAMILY_ALPHA
                })
            })
            .cloned()
            .collect();
        named.extend(equivalent);
    }
    (tested, named)
}

/// The data error named instead of the arm effects `named` (see the module doc): the significant
/// one of lowest held-out RMS, when it is within [`DATA_ERROR_EXPLAINS`] of the first named
/// effect's or none is named.
pub fn named_data_error<'a>(
    data_errors: &'a [Candidate],
    candidates: &[Candidate],
    named: &[String],
) -> Option<&'a Candidate> {
    let best_arm = named.first().and_then(|n| candidates.iter().find(|c| c.name == *n));
    data_errors
        .iter()
        .find(|c| c.significant)
        .filter(|d| best_arm.is_none_or(|a| d.held_out_rms_mm <= DATA_ERROR_EXPLAINS * a.held_out_rms_mm))
}
