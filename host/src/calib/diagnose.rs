//! Model diagnostics: where the calibrated model fails, which physical effect is missing.
//!
//! *Where it fails* reads the residuals of the calibrated model on the held-out placements:
//! after a rigid fit of the artefact to the touched positions of each placement, every touch
//! leaves a 3-D residual r. Projected on ∂p/∂θ_j it becomes the *apparent error of joint j*,
//! e_j = (g_j·r)/‖g_j‖² with g_j = ∂p/∂θ_j — what joint j would have to be off by to explain the
//! residual. e_j is binned against θ_j and fitted, jointly over the orders 1..=[`SPECTRUM_ORDERS`],
//! by weighted least squares (weights ‖g_j‖²): e ≈ c + Σ_n a_n sin nθ + b_n cos nθ. Fitting the
//! orders together shows aliasing over the angles actually visited: each joint reports its
//! angle coverage and the pairs of orders the visited angles cannot tell apart. The apparent
//! error is also drawn against the joint's gravity lever, and |r| against height and reach.
//!
//! *Which effect is missing.* Every library effect not yet in the model is a candidate (the
//! harmonics of orders 1–4 on every joint included). The calibration evidence and the refits use
//! at most [`SCREEN_BLOCKS`] calibration blocks, evenly spaced (all of them on data of thesis
//! size; a subsample at scale, where 150 blocks are ten times the thesis' data); the held-out
//! scores always use every validation touch, so the tests stay exact. The calibrated model's
//! Jacobian with every candidate parameter freed is evaluated once and shared:
//! * *Identifiability*: a candidate's parameters that add no rank to the identifiable base set
//!   are held at zero and named; a candidate with none left is not identifiable.
//! * *Screen*: a score (Lagrange-multiplier) test with no refit. With r the calibration
//!   residuals and J_M, J_c the model's and the candidate's columns,
//!   s = J_cᵀ(I − P_M)r and LM = sᵀ[J_cᵀ(I − P_M)J_c]⁻¹s/σ², χ²_k under no effect (computed as
//!   the drop of the Gauss–Newton objective of the augmented fit, from the shared normal
//!   matrix). It is turned into the standard normal deviate with the same upper tail, computed
//!   exactly in log space (the Wilson–Hilferty cube root, used before, favours 2-parameter
//!   effects at χ² in the hundreds), the candidate's *calibration evidence*.
//! * *Refit*: the [`REFITTED`] candidates with the strongest calibration evidence are refitted
//!   warm (nonlinear, every calibration touch, from the calibrated values), and their evidence
//!   is then the exact drop, rows × (1 − RSS_after/RSS_before), on the score test's scale; the
//!   others are scored from the shared Gauss–Newton step. Either way the held-out score is
//!   exact.
//!
//! *Significance* (the unit is the validation placement). Repeats of one placement share poses
//! and the systematic residual, so they are not independent; each placement gives one number,
//! the mean over its repeats of ln(MSE_before / MSE_after). The held-out p combines an exact
//! one-sided sign-flip (randomisation) test of their sum (every sign pattern enumerated up to
//! 20 placements) and a one-sided t test on the same numbers by a weighted Bonferroni
//! (p = min(p_flip/0.64, p_t/0.36)): the sign-flip test is exact but cannot go below 2⁻ᴾ, so with
//! five placements one placement slightly worse would hide a large, consistent gain; the t test
//! uses the sizes. Five placements all improved still pass at 0.05 (2⁻⁵/0.64 = 0.049). Candidates — arm effects and data errors together — are tested in a fixed
//! sequence ordered by their calibration evidence, each at [`FAMILY_ALPHA`], stopping at the
//! first that fails; the order comes from data the test never sees, so the family-wise error
//! is controlled. A candidate must also lower validation RMS by [`SIGNIFICANT_GAIN`]. Below
//! five validation placements the report says the test has too few units.
//!
//! *Rivals.* "Helps" is not "is the cause": a proxy correlated with the true effect helps too.
//! The best significant candidate A is compared with every other significant one B, and with
//! every B of lower validation RMS whose own held-out test passes although the fixed sequence
//! stopped before it (calibration data often rank aliased harmonics of one joint nearly alike),
//! that it does not beat in every placement: A + B is refitted (warm), and per placement
//! e_B|A = ln(MSE_A / MSE_A+B) and e_A|B = ln(MSE_B / MSE_A+B) are sign-flip tested. Only A
//! adds: A is the cause and B a proxy; only B adds: B is the cause; both add: both are missing;
//! neither adds: "A or B: these data cannot tell them apart". The separability
//! λ = min(λ_AB, λ_BA), λ_AB = ‖(I − P_\[M,B\])J_Aδ_A‖²/σ² on the calibration data (a projection
//! with no refit), says how far the calibration touches separate the two. Candidates whose
//! refits change the held-out errors the same way (correlation of the changes ≥
//! [`EQUIVALENT_CORRELATION`]) are reported as exactly equivalent.

use crate::calib::data_errors::{refit_with_landmark_freed, suspicious, DisturbedBlock, MisSeatedTouch};
use crate::calib::fit::{dense_jacobian, solve_warm};
use crate::calib::floor::{gap, noise_floor, Gap, NoiseFloor};
use crate::calib::identify;
use crate::calib::nuisance::frame::Frame;
use crate::calib::setup::SolveOptions;
use crate::calib::validate::{distance_errors, ErrorStats, PairError};
use crate::data::Observations;
use crate::model::effects::{Effect, EffectKind};
use crate::model::kinematics::{tool_pose, tool_pose_with_jacobian, ColumnMap};
use crate::model::{ArmModel, ParamId};
use crate::numerics::solver::normal_equations;
use crate::numerics::stats::one_sided_t;
use nalgebra::{DMatrix, DVector, Vector3};
use rayon::prelude::*;

/// Family-wise false-alarm rate of the significance test over all candidates.
pub const FAMILY_ALPHA: f64 = 0.05;
/// Correlation of two candidates' changes to the held-out errors above which they are reported
/// as exactly equivalent.
pub const EQUIVALENT_CORRELATION: f64 = 0.98;
/// Relative drop of validation RMS a candidate must reach to be called significant.
pub const SIGNIFICANT_GAIN: f64 = 0.02;
/// Flagged blocks and touches scored at most (each kind).
const MAX_FLAGGED: usize = 3;
/// A data error is named instead of an arm effect when its held-out RMS is within this factor
/// of the best arm effect's.
pub const DATA_ERROR_EXPLAINS: f64 = 1.05;
/// Most calibration (placement, repeat) blocks the screening (shared Jacobian, refits, calibration
/// evidence) uses; larger data are subsampled evenly. Held-out scores use every validation touch.
pub const SCREEN_BLOCKS: usize = 150;
/// Candidates refitted in full (warm, nonlinear), strongest calibration evidence first.
pub const REFITTED: usize = 10;
/// Validation placements below which the summary warns that the held-out test has few units.
const MIN_PLACEMENTS: usize = 5;
/// Most rivals of the leading candidate tested against it.
const MAX_RIVALS: usize = 3;
/// Canonical correlation between two orders' sin/cos columns over the visited angles above
/// which a joint reports them as aliased.
pub const ALIASED_ABOVE: f64 = 0.9;
/// Highest harmonic order in each joint's apparent-error spectrum.
pub const SPECTRUM_ORDERS: u32 = 4;
/// Angle bins for the residual-vs-joint-angle plots.
const ANGLE_BINS: usize = 12;

/// One order n of the apparent joint error, e ≈ a·sin nφ + b·cos nφ (+ c), fitted jointly with
/// the other orders.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Sinusoid {
    /// √(a² + b²), degrees.
    pub amplitude_deg: f64,
    /// atan2(b, a), degrees.
    pub phase_deg: f64,
    /// Constant part c, degrees.
    pub mean_deg: f64,
    /// Share of the weighted variance this order explains beyond the other orders (0–1).
    pub explained: f64,
}

/// Apparent error of one joint against its angle and its gravity lever.
#[derive(Clone, Debug, serde::Serialize)]
pub struct JointResiduals {
    /// Joint, 1-based.
    pub joint: usize,
    /// (raw encoder angle deg, apparent error deg, weight ‖g‖²) per touch.
    pub points: Vec<(f64, f64, f64)>,
    /// (bin centre deg, weighted mean apparent error deg, touches) per angle bin.
    pub bins: Vec<(f64, f64, usize)>,
    /// First harmonic of the apparent error (from the joint fit of every order).
    pub sinusoid: Sinusoid,
    /// Harmonics 1..=[`SPECTRUM_ORDERS`] of the apparent error, fitted jointly by weighted
    /// least squares: (cycles per revolution, fit).
    pub spectrum: Vec<(u32, Sinusoid)>,
    /// Angle range the touches visit: 360° less the largest gap between visited angles, deg.
    pub coverage_deg: f64,
    /// Pairs of orders the visited angles cannot tell apart, with the canonical correlation of
    /// their sin/cos columns (above [`ALIASED_ABOVE`]).
    pub aliased: Vec<(u32, u32, f64)>,
    /// (gravity lever m, apparent error deg) per touch.
    pub gravity: Vec<(f64, f64)>,
    /// Slope of apparent error against gravity lever, deg/m, weighted by ‖g_j‖² (a touch near a
    /// singularity, where joint j barely moves the tip, has a huge apparent error and no say).
    pub gravity_slope_deg_per_m: f64,
}

/// One candidate effect, scored on held-out data.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Candidate {
    /// Effect name, e.g. `eccentricity:5`.
    pub effect: String,
    /// Validation RMS with the effect added and refitted, mm.
    pub validation_rms_mm: f64,
    /// Share of the validation mean square error removed (0–1).
    pub explained: f64,
    /// Improvement beyond what noise explains (see module doc).
    pub significant: bool,
    /// Validation blocks (placement, repeat) whose error fell, and blocks compared.
    pub blocks_improved: (usize, usize),
    /// Mean log ratio ln(MSE_before / MSE_after) over the validation blocks.
    pub mean_log_ratio: f64,
    /// Held-out p-value over the validation placements' mean log ratios: a weighted Bonferroni of
    /// an exact one-sided sign-flip test and a one-sided t test, at most 1.
    pub p_value: f64,
    /// Change of BIC on the calibration data (negative favours the effect): from the refit, or
    /// from the shared Gauss–Newton step on the screening rows.
    pub delta_bic: f64,
    /// Calibration evidence as a standard normal deviate (same upper tail as the score test's
    /// χ²_k, or of the likelihood ratio or split χ² for a data error); orders the held-out
    /// tests.
    pub calibration_z: f64,
    /// Validation placements whose mean log ratio is positive, and placements compared.
    pub placements_improved: (usize, usize),
    /// Refitted in full (else scored from the shared Gauss–Newton step).
    pub refitted: bool,
    /// Fitted change of each of the effect's parameters from the calibrated model (name,
    /// change, unit).
    pub fitted: Vec<(String, f64, &'static str)>,
    /// Plain-words reason.
    pub evidence: String,
    /// Other candidates that change the held-out errors the same way: the data cannot tell
    /// them apart from this one.
    pub equivalent: Vec<String>,
    /// The better-ranked candidate this one is equivalent to, if any.
    pub equivalent_to: Option<String>,
    /// For a data error: what the user can do about it.
    pub action: Option<String>,
}

/// How two significant candidates relate (see the module doc).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
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
#[derive(Clone, Debug, serde::Serialize)]
pub struct Rival {
    /// The leading candidate.
    pub a: String,
    /// The rival.
    pub b: String,
    /// Validation RMS with both refitted, mm.
    pub both_rms_mm: f64,
    /// Held-out p of adding `a` to `b` (sign-flip over placements).
    pub a_adds_p: f64,
    /// Held-out p of adding `b` to `a`.
    pub b_adds_p: f64,
    /// min(λ_AB, λ_BA): how far the calibration touches separate the two, in noise variances
    /// (below about 13 they are alike on these data).
    pub separability: f64,
    /// The verdict.
    pub verdict: RivalVerdict,
}

/// An effect the data cannot identify next to the current model.
#[derive(Clone, Debug, serde::Serialize)]
pub struct NotIdentifiable {
    /// Effect name.
    pub effect: String,
    /// What absorbs it.
    pub reason: String,
}

/// A large held-out distance error.
#[derive(Clone, Debug, serde::Serialize)]
pub struct WorstPair {
    /// Placement name.
    pub placement: String,
    /// Landmark ids.
    pub landmarks: (String, String),
    /// Measured minus certified, mm.
    pub error_mm: f64,
}

/// Everything `kincal diagnose` finds.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Diagnosis {
    /// Calibrated model on the validation data.
    pub baseline: ErrorStats,
    /// Noise floor estimated from repeated touches (`None` without repeats).
    pub floor: Option<NoiseFloor>,
    /// Validation RMS against the floor.
    pub gap: Option<Gap>,
    /// Data errors scored like effects (`landmark:ID`, `block:P/R`, `touch:P/R/ID`), best first.
    pub data_errors: Vec<Candidate>,
    /// Calibration blocks whose artefact seems to have moved within the repeat.
    pub disturbed: Vec<DisturbedBlock>,
    /// Calibration touches far off their block's rigid fit.
    pub mis_seated: Vec<MisSeatedTouch>,
    /// Candidates, best (lowest validation RMS) first.
    pub candidates: Vec<Candidate>,
    /// The leading candidate against the other significant ones it does not clearly beat.
    pub rivals: Vec<Rival>,
    /// What the diagnosis names as missing: one effect, or several the data cannot tell apart
    /// (empty when no arm effect is significant).
    pub named: Vec<String>,
    /// Effects the data cannot identify next to the model.
    pub not_identifiable: Vec<NotIdentifiable>,
    /// Apparent joint errors.
    pub joints: Vec<JointResiduals>,
    /// (height z mm, |residual| mm) per validation touch.
    pub by_height: Vec<(f64, f64)>,
    /// (reach √(x²+y²) mm, |residual| mm) per validation touch.
    pub by_reach: Vec<(f64, f64)>,
    /// Largest validation distance errors.
    pub worst: Vec<WorstPair>,
    /// Placement RMS, mm.
    pub by_placement: Vec<(String, f64)>,
    /// Short text summary.
    pub summary: Vec<String>,
}

/// Per-touch residual vectors after a rigid fit of the artefact in each placement.
fn touch_residuals(model: &ArmModel, data: &Observations) -> Vec<Option<Vector3<f64>>> {
    let p: Vec<Vector3<f64>> = data.obs.iter().map(|t| tool_pose(model, &t.q_deg).position_mm).collect();
    let mut out = vec![None; p.len()];
    for placement in 0..data.groups.len() {
        let idx: Vec<usize> = (0..p.len()).filter(|&k| data.obs[k].group == placement).collect();
        if idx.len() < 4 {
            continue;
        }
        let q: Vec<Vector3<f64>> =
            idx.iter().map(|&k| Vector3::from(data.landmarks[data.obs[k].touched()].xyz_mm)).collect();
        let pm: Vec<Vector3<f64>> = idx.iter().map(|&k| p[k]).collect();
        let frame = Frame::fit(&q, &pm);
        for (i, &k) in idx.iter().enumerate() {
            out[k] = Some(pm[i] - frame.apply(&q[i]));
        }
    }
    out
}

/// (cycles per revolution, fit) per order.
type Spectrum = Vec<(u32, Sinusoid)>;
/// (order, order, canonical correlation) of aliased pairs.
type Aliased = Vec<(u32, u32, f64)>;

/// Sin/cos columns of orders 1..=[`SPECTRUM_ORDERS`] and a constant at angle `phi_deg`.
fn harmonic_row(phi_deg: f64) -> DVector<f64> {
    let n = 2 * SPECTRUM_ORDERS as usize + 1;
    let mut x = DVector::zeros(n);
    for k in 0..SPECTRUM_ORDERS as usize {
        let a = (k + 1) as f64 * phi_deg.to_radians();
        x[2 * k] = a.sin();
        x[2 * k + 1] = a.cos();
    }
    x[n - 1] = 1.0;
    x
}

/// Weighted least squares e ≈ c + Σ_n a_n sin nφ + b_n cos nφ over orders
/// 1..=[`SPECTRUM_ORDERS`] jointly, for points (angle deg, value deg, weight). Returns each
/// order's fit (its share: the weighted variance lost when it alone is dropped) and the
/// aliased pairs of orders.
fn fit_spectrum(points: &[(f64, f64, f64)]) -> (Spectrum, Aliased) {
    let n = 2 * SPECTRUM_ORDERS as usize + 1;
    let mut ata = DMatrix::zeros(n, n);
    let mut atb = DVector::zeros(n);
    for &(phi, e, w) in points {
        let x = harmonic_row(phi);
        ata += &x * x.transpose() * w;
        atb += x * (e * w);
    }
    let total_w: f64 = points.iter().map(|p| p.2).sum::<f64>().max(1e-300);
    let mean = points.iter().map(|p| p.1 * p.2).sum::<f64>() / total_w;
    let ss_tot: f64 = points.iter().map(|&(_, e, w)| w * (e - mean).powi(2)).sum::<f64>();
    // Least squares on a subset of columns: coefficients (zeros when singular) and the
    // weighted residual sum of squares.
    let solve = |cols: &[usize]| -> (Vec<f64>, f64) {
        let sub = DMatrix::from_fn(cols.len(), cols.len(), |a, b| ata[(cols[a], cols[b])]);
        let rhs = DVector::from_fn(cols.len(), |a, _| atb[cols[a]]);
        let coef = sub
            .clone()
            .svd(true, true)
            .solve(&rhs, 1e-10 * sub.norm().max(1e-300))
            .map(|c| c.iter().copied().collect())
            .unwrap_or_else(|_| vec![0.0; cols.len()]);
        let ss = points
            .iter()
            .map(|&(phi, e, w)| {
                let x = harmonic_row(phi);
                let fit: f64 = cols.iter().zip(&coef).map(|(&c, v)| x[c] * v).sum();
                w * (e - fit).powi(2)
            })
            .sum::<f64>();
        (coef, ss)
    };
    let all: Vec<usize> = (0..n).collect();
    let (coef, ss_all) = solve(&all);
    let spectrum = (1..=SPECTRUM_ORDERS)
        .map(|order| {
            let k = 2 * (order as usize - 1);
            let others: Vec<usize> = all.iter().copied().filter(|&c| c != k && c != k + 1).collect();
            let (_, ss_without) = solve(&others);
            let (a, b) = (coef[k], coef[k + 1]);
            let fit = Sinusoid {
                amplitude_deg: a.hypot(b),
                phase_deg: b.atan2(a).to_degrees(),
                mean_deg: coef[n - 1],
                explained: if ss_tot > 0.0 { ((ss_without - ss_all) / ss_tot).clamp(0.0, 1.0) } else { 0.0 },
            };
            (order, fit)
        })
        .collect();
    // Canonical correlation of two orders' (centred, weighted) column pairs.
    let centred = |c: usize, d: usize| ata[(c, d)] - ata[(c, n - 1)] * ata[(d, n - 1)] / total_w;
    let mut aliased = Vec::new();
    for p in 1..=SPECTRUM_ORDERS {
        for q in p + 1..=SPECTRUM_ORDERS {
            let (kp, kq) = (2 * (p as usize - 1), 2 * (q as usize - 1));
            let block = |a: usize, b: usize| {
                nalgebra::Matrix2::new(
                    centred(a, b),
                    centred(a, b + 1),
                    centred(a + 1, b),
                    centred(a + 1, b + 1),
                )
            };
            let inv_sqrt = |m: nalgebra::Matrix2<f64>| {
                let e = m.symmetric_eigen();
                let d = e.eigenvalues.map(|v| if v > 1e-12 * total_w { 1.0 / v.sqrt() } else { 0.0 });
                e.eigenvectors * nalgebra::Matrix2::from_diagonal(&d) * e.eigenvectors.transpose()
            };
            let m = inv_sqrt(block(kp, kp)) * block(kp, kq) * inv_sqrt(block(kq, kq));
            let rho = m.singular_values().max();
            if rho > ALIASED_ABOVE {
                aliased.push((p, q, rho));
            }
        }
    }
    (spectrum, aliased)
}

/// Angle range visited by `angles_deg`: 360° less the largest gap between neighbours.
fn coverage_deg(angles_deg: &[f64]) -> f64 {
    let mut a: Vec<f64> = angles_deg.iter().map(|v| v.rem_euclid(360.0)).collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    let wrap = a[0] + 360.0 - a[a.len() - 1];
    let largest = a.windows(2).map(|w| w[1] - w[0]).fold(wrap, f64::max);
    360.0 - largest
}

/// Apparent joint errors of `model` on `data`.
/// Points (x, y) of a scatter plot.
type Points = Vec<(f64, f64)>;

fn joint_residuals(model: &ArmModel, data: &Observations) -> (Vec<JointResiduals>, Points, Points) {
    let residuals = touch_residuals(model, data);
    let joints = model.joints.len();
    let offsets: Vec<ParamId> = (0..joints).map(ParamId::Offset).collect();
    let columns = ColumnMap::new(&offsets);
    let mut per_joint: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new(); joints];
    let mut gravity: Vec<Vec<(f64, f64)>> = vec![Vec::new(); joints];
    let mut gravity_weights: Vec<Vec<f64>> = vec![Vec::new(); joints];
    let (mut by_height, mut by_reach) = (Vec::new(), Vec::new());
    for (t, r) in data.obs.iter().zip(&residuals) {
        let Some(r) = r else { continue };
        let mut jac = vec![[0.0; 9]; joints];
        let pose = tool_pose_with_jacobian(model, &t.q_deg, &columns, &mut jac);
        let levers = gravity_levers(model, &t.q_deg);
        by_height.push((pose.position_mm.z, r.norm()));
        by_reach.push((pose.position_mm.xy().norm(), r.norm()));
        for j in 0..joints {
            let g = Vector3::new(jac[j][0], jac[j][1], jac[j][2]); // mm per degree
            let w = g.norm_squared();
            if w < 1e-9 {
                continue;
            }
            let e = g.dot(r) / w;
            per_joint[j].push((t.q_deg[j], e, w));
            gravity[j].push((levers[j], e));
            gravity_weights[j].push(w);
        }
    }
    let joints = (0..joints)
        .map(|j| {
            let points = std::mem::take(&mut per_joint[j]);
            let bins = (0..ANGLE_BINS)
                .map(|b| {
                    let width = 360.0 / ANGLE_BINS as f64;
                    let inside: Vec<&(f64, f64, f64)> =
                        points.iter().filter(|p| ((p.0 / width) as usize).min(ANGLE_BINS - 1) == b).collect();
                    let w: f64 = inside.iter().map(|p| p.2).sum();
                    let mean = if w > 0.0 { inside.iter().map(|p| p.1 * p.2).sum::<f64>() / w } else { 0.0 };
                    ((b as f64 + 0.5) * width, mean, inside.len())
                })
                .collect();
            let g = &gravity[j];
            let (sxx, sxy) = g
                .iter()
                .zip(&gravity_weights[j])
                .fold((0.0, 0.0), |(a, b), ((x, y), w)| (a + w * x * x, b + w * x * y));
            let (spectrum, aliased) = fit_spectrum(&points);
            JointResiduals {
                joint: j + 1,
                sinusoid: spectrum[0].1,
                coverage_deg: coverage_deg(&points.iter().map(|p| p.0).collect::<Vec<_>>()),
                aliased,
                spectrum,
                bins,
                points,
                gravity: g.clone(),
                gravity_slope_deg_per_m: if sxx > 0.0 { sxy / sxx } else { 0.0 },
            }
        })
        .collect();
    (joints, by_height, by_reach)
}

/// Gravity lever of each joint at a touch (the compliance regressor), metres.
fn gravity_levers(model: &ArmModel, enc_deg: &[f64]) -> Vec<f64> {
    // ∂p/∂compliance_j = ∂p/∂θ_j · λ_j: the ratio of the two columns gives λ_j.
    let joints = model.joints.len();
    let params: Vec<ParamId> =
        (0..joints).flat_map(|j| [ParamId::Offset(j), ParamId::Compliance(j)]).collect();
    let mut jac = vec![[0.0; 9]; params.len()];
    tool_pose_with_jacobian(model, enc_deg, &ColumnMap::new(&params), &mut jac);
    (0..joints)
        .map(|j| {
            let (dtheta, dc) = (&jac[2 * j], &jac[2 * j + 1]);
            let n: f64 = (0..3).map(|k| dtheta[k] * dtheta[k]).sum();
            if n > 1e-12 {
                (0..3).map(|k| dc[k] * dtheta[k]).sum::<f64>() / n
            } else {
                0.0
            }
        })
        .collect()
}

impl Candidate {
    /// A candidate from its held-out score and calibration evidence: not yet significant, no
    /// fitted values, no equivalents, no action.
    fn scored(
        effect: String,
        score: &Score,
        baseline_rms_mm: f64,
        delta_bic: f64,
        calibration_z: f64,
        evidence: String,
    ) -> Candidate {
        let base_ms = baseline_rms_mm.powi(2).max(1e-300);
        Candidate {
            effect,
            validation_rms_mm: score.after,
            explained: ((base_ms - score.after.powi(2)) / base_ms).clamp(0.0, 1.0),
            significant: false,
            blocks_improved: score.blocks_improved,
            mean_log_ratio: score.mean_log_ratio,
            p_value: score.p_value,
            delta_bic,
            calibration_z,
            placements_improved: score.placements_improved,
            refitted: true,
            fitted: Vec::new(),
            evidence,
            equivalent: Vec::new(),
            equivalent_to: None,
            action: None,
        }
    }
}

/// Mean square validation error per (placement, repeat) block.
fn block_mse(errors: &[PairError], data: &Observations) -> Vec<((usize, u32), f64)> {
    let mut blocks: Vec<((usize, u32), f64, usize)> = Vec::new();
    for e in errors {
        let key = (e.placement, data.obs[e.touches.0].repeat);
        match blocks.iter_mut().find(|b| b.0 == key) {
            Some(b) => {
                b.1 += e.error_mm * e.error_mm;
                b.2 += 1;
            }
            None => blocks.push((key, e.error_mm * e.error_mm, 1)),
        }
    }
    blocks.into_iter().map(|(k, s, n)| (k, s / n as f64)).collect()
}

/// Held-out figures of a refit against the baseline blocks.
struct Score {
    after: f64,
    blocks_improved: (usize, usize),
    placements_improved: (usize, usize),
    mean_log_ratio: f64,
    p_value: f64,
    /// Mean log ratio per validation placement (the test's units).
    per_placement: Vec<(usize, f64)>,
}

impl Score {
    fn of(errors: &[PairError], baseline_blocks: &[((usize, u32), f64)], val: &Observations) -> Score {
        let blocks = block_mse(errors, val);
        let ratios = log_ratios(baseline_blocks, &blocks);
        let per_placement = placement_means(&ratios);
        let units: Vec<f64> = per_placement.iter().map(|p| p.1).collect();
        Score {
            after: rms(errors),
            blocks_improved: (ratios.iter().filter(|r| r.1 > 0.0).count(), ratios.len()),
            placements_improved: (units.iter().filter(|r| **r > 0.0).count(), units.len()),
            mean_log_ratio: ratios.iter().map(|r| r.1).sum::<f64>() / ratios.len().max(1) as f64,
            p_value: held_out_p(&units),
            per_placement,
        }
    }
}

/// ln(MSE_before / MSE_after) per block present in both.
fn log_ratios(before: &[((usize, u32), f64)], after: &[((usize, u32), f64)]) -> Vec<((usize, u32), f64)> {
    before
        .iter()
        .filter_map(|(k, b)| {
            after.iter().find(|a| a.0 == *k).map(|a| (*k, (b.max(1e-300) / a.1.max(1e-300)).ln()))
        })
        .collect()
}

/// Mean of the blocks' values per placement, in placement order.
fn placement_means(blocks: &[((usize, u32), f64)]) -> Vec<(usize, f64)> {
    let mut out: Vec<(usize, f64, usize)> = Vec::new();
    for ((placement, _), v) in blocks {
        match out.iter_mut().find(|o| o.0 == *placement) {
            Some(o) => {
                o.1 += v;
                o.2 += 1;
            }
            None => out.push((*placement, *v, 1)),
        }
    }
    out.sort_by_key(|o| o.0);
    out.into_iter().map(|(p, s, n)| (p, s / n as f64)).collect()
}

/// Share of the held-out level given to the sign-flip test (the rest to the t test): a weighted
/// Bonferroni over the pair. 0.64 lets five placements all improved (p = 2⁻⁵) pass at 0.05.
const SIGN_FLIP_WEIGHT: f64 = 0.64;

/// Held-out p of the placements' mean log ratios: a weighted Bonferroni over the exact
/// sign-flip p and a one-sided t test on the same numbers, at most 1.
pub fn held_out_p(units: &[f64]) -> f64 {
    (sign_flip_p(units) / SIGN_FLIP_WEIGHT).min(one_sided_t(units).1 / (1.0 - SIGN_FLIP_WEIGHT)).min(1.0)
}

/// Placements up to which the sign-flip test enumerates every sign pattern; beyond, a seeded
/// random sample of [`SIGN_FLIP_DRAWS`] patterns.
const SIGN_FLIP_EXACT: usize = 20;
/// Random sign patterns beyond [`SIGN_FLIP_EXACT`] placements.
const SIGN_FLIP_DRAWS: usize = 200_000;

/// Exact one-sided sign-flip (randomisation) p of Σ units > 0: the share of sign patterns
/// whose sum is at least the observed one. Symmetric about zero under "no effect".
pub fn sign_flip_p(units: &[f64]) -> f64 {
    if units.is_empty() {
        return 1.0;
    }
    let observed: f64 = units.iter().sum();
    let tolerance = 1e-12 * units.iter().map(|u| u.abs()).sum::<f64>();
    let at_least = |signs: u64| {
        let sum: f64 =
            units.iter().enumerate().map(|(k, u)| if signs >> k & 1 == 1 { -u.abs() } else { u.abs() }).sum();
        sum >= observed - tolerance
    };
    if units.len() <= SIGN_FLIP_EXACT {
        let patterns = 1u64 << units.len();
        (0..patterns).filter(|&s| at_least(s)).count() as f64 / patterns as f64
    } else {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        let hits = (0..SIGN_FLIP_DRAWS).filter(|_| at_least(rng.random::<u64>())).count();
        (1 + hits) as f64 / (1 + SIGN_FLIP_DRAWS) as f64
    }
}

fn rms(errors: &[PairError]) -> f64 {
    ErrorStats::of(&errors.iter().map(|e| e.error_mm).collect::<Vec<_>>()).rms_mm
}

/// BIC of a fit with `params` parameters from its distance residuals.
fn bic(residuals: &[f64], params: usize) -> f64 {
    let m = residuals.len().max(1) as f64;
    let rss = residuals.iter().map(|r| r * r).sum::<f64>().max(1e-300);
    m * (rss / m).ln() + params as f64 * m.ln()
}

fn distance_residuals(model: &ArmModel, data: &Observations) -> Vec<f64> {
    distance_errors(model, data).iter().map(|e| e.error_mm).collect()
}

/// Plain words for a fitted effect.
fn evidence(
    effect: Effect,
    fitted: &[(String, f64, &'static str)],
    joints: &[JointResiduals],
    before: f64,
    after: f64,
) -> String {
    let gain = format!("would bring validation RMS from {before:.3} to {after:.3} mm");
    let value = |k: usize| fitted.get(k).map_or(0.0, |f| f.1);
    let j = effect.joint.map_or(0, |j| j + 1);
    match effect.kind {
        EffectKind::Eccentricity | EffectKind::Eccentricity2 | EffectKind::Harmonic3 | EffectKind::Harmonic4 => {
            let order = effect.kind.harmonic_order().unwrap_or(1);
            let n = if order == 1 { String::new() } else { order.to_string() };
            let seen = joints
                .get(j.saturating_sub(1))
                .and_then(|r| r.spectrum.iter().find(|s| s.0 == order).map(|s| s.1));
            let residual = match seen {
                Some(s) if s.explained > 0.1 => format!("the residual follows sin {n}θ{j} with {:.3}° amplitude ({:.0} % of its variance); ", s.amplitude_deg, 100.0 * s.explained),
                _ => String::new(),
            };
            let what = match order {
                1 => "encoder eccentricity".to_string(),
                2 => "second-harmonic encoder error".to_string(),
                _ => format!("{order}-per-revolution encoder error"),
            };
            format!("{residual}{what} of joint {j} (Δθ = {:.3}°·sin {n}φ {:+.3}°·cos {n}φ, amplitude {:.3}°) {gain}", value(0), value(1), value(0).hypot(value(1)))
        }
        EffectKind::Compliance => {
            let slope = joints.get(j.saturating_sub(1)).map_or(0.0, |r| r.gravity_slope_deg_per_m);
            let fitted = value(0);
            // The calibration already moved parameters that absorb part of a sag, so the apparent
            // error's slope alone can be far smaller than the fitted compliance, or of the other sign.
            let seen = if slope * fitted > 0.0 && slope.abs() >= fitted.abs() / 3.0 {
                format!("the residual grows with its gravity lever ({slope:+.3} °/m seen, {fitted:+.3} °/m fitted)")
            } else {
                format!("a deflection proportional to its gravity lever fits the residuals ({fitted:+.3} °/m fitted; the apparent error against the lever alone shows {slope:+.3} °/m, because the parameters already calibrated absorb part of the sag)")
            };
            format!("joint {j} sags under gravity: {seen}; compliance of joint {j} {gain}")
        }
        EffectKind::Twist => format!("the axis after joint {j} is twisted by {:+.3}° more than the model says; twist of joint {j} {gain}", value(0)),
        EffectKind::Axis => format!("consecutive axes at joint {j} are tilted by {:+.3}° about y; axis misalignment of joint {j} {gain}", value(0)),
        EffectKind::LinkOffset => format!("axes at joint {j} miss each other by {:+.3} mm; link offset a{j} {gain}", value(0)),
        EffectKind::Length => format!("link length d{j} is off by {:+.3} mm; {gain}", value(0)),
        EffectKind::Offset => format!("encoder {j} zero is off by {:+.3}°; {gain}", value(0)),
        EffectKind::Tcp => format!("the tool tip sits off by ({:+.3}, {:+.3}, {:+.3}) mm in the last frame; a 3-D tool offset {gain}", value(0), value(1), value(2)),
        EffectKind::Scale => format!("lengths scale by {:+.0} ppm (temperature or artefact scale); {gain}", value(0)),
    }
}

/// Standard normal deviate of a χ²_k statistic, exact in the far tail (calibration evidence
/// compares effects with different parameter counts at χ² in the hundreds).
pub fn chi2_z(x: f64, k: usize) -> f64 {
    crate::numerics::stats::chi2_normal_deviate(x, k)
}

/// `data` with at most [`SCREEN_BLOCKS`] (placement, repeat) blocks, evenly spaced.
fn screening_subset(data: &Observations) -> std::borrow::Cow<'_, Observations> {
    let blocks = crate::calib::data_errors::blocks(data);
    if blocks.len() <= SCREEN_BLOCKS {
        return std::borrow::Cow::Borrowed(data);
    }
    let keep: Vec<(usize, u32)> =
        (0..SCREEN_BLOCKS).map(|k| blocks[k * blocks.len() / SCREEN_BLOCKS].0).collect();
    std::borrow::Cow::Owned(data.without(|t| {
        let touch = &data.obs[t];
        !keep.contains(&(touch.group, touch.repeat))
    }))
}

/// The calibrated model's Jacobian with every candidate parameter freed, evaluated once on the
/// calibration data (the screening subsample at scale) and shared by every candidate.
struct Screen {
    params: Vec<ParamId>,
    ranges: Vec<f64>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    values: Vec<f64>,
    jac: Vec<f64>,
    /// JᵀWJ and JᵀWr (Huber weights at the calibrated residuals).
    gram: DMatrix<f64>,
    grad: DVector<f64>,
    /// Residual variance per row.
    sigma2: f64,
    rows: usize,
    /// Identifiable base set of the current parameters (column indices).
    base: Vec<usize>,
    /// Drop of the Gauss–Newton objective with the base set alone (≈ 0 at the optimum).
    base_drop: f64,
}

impl Screen {
    fn new(calibrated: &ArmModel, effects: &[Effect], cal: &Observations, options: &SolveOptions) -> Screen {
        let mut augmented = calibrated.clone();
        for e in effects {
            e.add_to(&mut augmented);
        }
        let params: Vec<ParamId> = augmented.free.iter().map(|f| f.id).collect();
        let ranges: Vec<f64> = augmented.free.iter().map(|f| (f.upper - f.lower).max(1e-9)).collect();
        let resolved = options.resolve(cal);
        let (r, jac) = dense_jacobian(&augmented, &params, cal, resolved.relative_lever_mm);
        let values = augmented.free_values();
        let (rows, n) = (r.len(), params.len());
        let loss = resolved.loss;
        let weights: Vec<f64> = r.iter().map(|&v| loss.weight(v)).collect();
        let (gram, grad) = normal_equations(&jac, &r, &weights, n);
        let current: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
        let lower: Vec<f64> = augmented.free.iter().map(|f| f.lower).collect();
        let upper: Vec<f64> = augmented.free.iter().map(|f| f.upper).collect();
        // A parameter the calibration left at a bound is held there (its gradient is not zero).
        let at_bound = |c: usize| (values[c] - lower[c]).min(upper[c] - values[c]) <= 1e-6 * ranges[c];
        let existing: Vec<usize> = (0..n).filter(|&c| current.contains(&params[c]) && !at_bound(c)).collect();
        let existing_ranges: Vec<f64> = existing.iter().map(|&c| ranges[c]).collect();
        let base: Vec<usize> =
            identify::base_columns(&subset_jacobian(&jac, n, &existing), existing.len(), &existing_ranges)
                .0
                .into_iter()
                .map(|k| existing[k])
                .collect();
        let rss: f64 = r.iter().zip(&weights).map(|(v, w)| w * v * v).sum();
        let mut screen = Screen {
            lower,
            upper,
            sigma2: (rss / rows.saturating_sub(base.len()).max(1) as f64).max(1e-300),
            params,
            ranges,
            values,
            jac,
            gram,
            grad,
            rows,
            base,
            base_drop: 0.0,
        };
        screen.base_drop = screen.step(&screen.base.clone()).map_or(0.0, |s| s.0);
        screen
    }

    /// Column index of a parameter.
    fn column(&self, id: ParamId) -> Option<usize> {
        self.params.iter().position(|p| *p == id)
    }

    /// Gauss–Newton step with columns `cols` free: (drop of the objective, step).
    fn step(&self, cols: &[usize]) -> Option<(f64, DVector<f64>)> {
        let g = DMatrix::from_fn(cols.len(), cols.len(), |a, b| self.gram[(cols[a], cols[b])]);
        let rhs = DVector::from_fn(cols.len(), |a, _| self.grad[cols[a]]);
        let x = g.cholesky()?.solve(&rhs);
        Some((rhs.dot(&x), -x))
    }

    /// ‖(I − P_T) J_S δ‖² / σ²: the part of the change a step `delta` on columns `s` makes to
    /// the residuals that columns `t` cannot make.
    fn unexplained(&self, s: &[usize], delta: &DVector<f64>, t: &[usize]) -> f64 {
        let gss = DMatrix::from_fn(s.len(), s.len(), |a, b| self.gram[(s[a], s[b])]);
        let gts = DMatrix::from_fn(t.len(), s.len(), |a, b| self.gram[(t[a], s[b])]);
        let gtt = DMatrix::from_fn(t.len(), t.len(), |a, b| self.gram[(t[a], t[b])]);
        let whole = delta.dot(&(&gss * delta));
        let projected = gts * delta;
        let explained = gtt.cholesky().map_or(0.0, |c| projected.dot(&c.solve(&projected)));
        (whole - explained).max(0.0) / self.sigma2
    }
}

/// A candidate screened on the shared Jacobian.
struct Screened {
    effect: Effect,
    /// Columns fitted: the base set and the candidate's identifiable parameters.
    cols: Vec<usize>,
    /// The candidate's identifiable parameters.
    added: Vec<ParamId>,
    /// Its parameters held at zero (not identifiable next to the model).
    held: Vec<ParamId>,
    /// Why they are held.
    held_reason: Vec<String>,
    lm: f64,
    z: f64,
    /// The Gauss–Newton step on `cols`.
    delta: DVector<f64>,
}

impl Screened {
    /// `calibrated` with the effect added (held parameters fixed) at the calibrated values.
    fn start(&self, calibrated: &ArmModel) -> ArmModel {
        let mut model = calibrated.clone();
        self.effect.add_to(&mut model);
        for p in &self.held {
            model.fix_param(*p);
        }
        model
    }

    /// The model after the shared Gauss–Newton step (within the bounds).
    fn one_step(&self, calibrated: &ArmModel, screen: &Screen) -> ArmModel {
        let mut model = self.start(calibrated);
        for (a, &c) in self.cols.iter().enumerate() {
            let v = (screen.values[c] + self.delta[a]).clamp(screen.lower[c], screen.upper[c]);
            model.set(screen.params[c], v);
        }
        model
    }
}

/// Identifiability and the score test of `effect` on the shared Jacobian.
fn screen_candidate(
    effect: Effect,
    screen: &Screen,
    current: &[ParamId],
) -> Result<Screened, NotIdentifiable> {
    let n = screen.params.len();
    let extra: Vec<usize> =
        effect.params().iter().filter(|p| !current.contains(p)).filter_map(|&p| screen.column(p)).collect();
    let rank = identify::added_rank(&screen.jac, n, &screen.ranges, &screen.base, &extra);
    let describe = |k: usize| {
        let r = &rank[k];
        let name = screen.params[extra[k]];
        if r.moves_nothing {
            return format!("{name} changes no distance");
        }
        let mut terms: Vec<(ParamId, f64, f64)> = screen
            .base
            .iter()
            .enumerate()
            .map(|(i, &c)| (screen.params[c], -r.like[i], r.share[i]))
            .filter(|t| t.2.abs() > 1e-3)
            .collect();
        terms.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
        let list: Vec<String> = terms
            .iter()
            .take(4)
            .map(|(p, b, _)| format!("{p} ({b:+.4} {} per {})", p.unit(), name.unit()))
            .collect();
        format!("{name}'s effect on distances is absorbed by {}", list.join(", "))
    };
    let held_idx: Vec<usize> = (0..extra.len()).filter(|&k| !rank[k].adds).collect();
    let not_identifiable = |reason: String| NotIdentifiable { effect: effect.to_string(), reason };
    if held_idx.len() == extra.len() {
        let reasons: Vec<String> = held_idx.iter().map(|&k| describe(k)).collect();
        return Err(not_identifiable(format!("not identifiable from these touches: {}", reasons.join("; "))));
    }
    let added_cols: Vec<usize> = (0..extra.len()).filter(|&k| rank[k].adds).map(|k| extra[k]).collect();
    let cols: Vec<usize> = screen.base.iter().chain(&added_cols).copied().collect();
    let (drop, delta) = screen
        .step(&cols)
        .ok_or_else(|| not_identifiable("its normal equations are singular next to the model".into()))?;
    let lm = (drop - screen.base_drop).max(0.0) / screen.sigma2;
    Ok(Screened {
        effect,
        added: added_cols.iter().map(|&c| screen.params[c]).collect(),
        held: held_idx.iter().map(|&k| screen.params[extra[k]]).collect(),
        held_reason: held_idx.iter().map(|&k| describe(k)).collect(),
        z: chi2_z(lm, added_cols.len()),
        lm,
        cols,
        delta,
    })
}

/// A candidate's model and held-out errors, kept for the rival tests.
struct Fitted {
    blocks: Vec<((usize, u32), f64)>,
    per_placement: Vec<(usize, f64)>,
}

/// Diagnose `calibrated` (whose free set and bounds are those it was calibrated with).
pub fn diagnose(
    calibrated: &ArmModel,
    cal: &Observations,
    val: &Observations,
    options: &SolveOptions,
) -> Diagnosis {
    let baseline_errors = distance_errors(calibrated, val);
    let baseline = ErrorStats::of(&baseline_errors.iter().map(|e| e.error_mm).collect::<Vec<_>>());
    let (joints, by_height, by_reach) = joint_residuals(calibrated, val);
    let current: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
    // Refits and the calibration evidence use at most SCREEN_BLOCKS blocks; the held-out
    // scores always use every validation touch.
    let fit_data = screening_subset(cal);
    let baseline_cal = distance_residuals(calibrated, &fit_data);
    let baseline_bic = bic(&baseline_cal, current.len());
    let baseline_rss: f64 = baseline_cal.iter().map(|r| r * r).sum::<f64>().max(1e-300);
    let baseline_blocks = block_mse(&baseline_errors, val);
    let effects: Vec<Effect> =
        Effect::library(calibrated.joints.len()).into_iter().filter(|e| !e.is_in(calibrated)).collect();
    let screen = Screen::new(calibrated, &effects, &fit_data, options);
    let base_params: Vec<ParamId> = screen.base.iter().map(|&c| screen.params[c]).collect();
    let floor = noise_floor(calibrated, cal, val, screen.base.len())
        .map(|f| f.with_estimate_noise(calibrated, &base_params, &fit_data, val));
    let (disturbed, mis_seated) = match &floor {
        Some(f) => suspicious(calibrated, cal, f.touch_std_mm.powi(2)),
        None => (Vec::new(), Vec::new()),
    };
    let disturbed: Vec<DisturbedBlock> = disturbed.into_iter().take(MAX_FLAGGED).collect();
    let mis_seated: Vec<MisSeatedTouch> = mis_seated.into_iter().take(MAX_FLAGGED).collect();
    let mut screened = Vec::new();
    let mut not_identifiable = Vec::new();
    for r in effects.par_iter().map(|&e| screen_candidate(e, &screen, &current)).collect::<Vec<_>>() {
        match r {
            Ok(s) => screened.push(s),
            Err(n) => not_identifiable.push(n),
        }
    }
    screened.sort_by(|a, b| b.z.total_cmp(&a.z));
    let m_screen = screen.rows.max(2) as f64;
    let scored: Vec<(Candidate, Vec<f64>, Fitted)> = screened
        .par_iter()
        .enumerate()
        .map(|(rank, c)| {
            let refit = (rank < REFITTED)
                .then(|| {
                    let params: Vec<ParamId> = base_params.iter().chain(&c.added).copied().collect();
                    solve_warm(&c.start(calibrated), &params, &fit_data, options).ok()
                })
                .flatten();
            let refitted = refit.is_some();
            let model = refit.unwrap_or_else(|| c.one_step(calibrated, &screen));
            let errors = distance_errors(&model, val);
            let score = Score::of(&errors, &baseline_blocks, val);
            let k = c.added.len();
            // A refit replaces the score test's linearised drop by the exact one, on the same
            // scale: rows × (1 − RSS_after / RSS_before).
            let (delta_bic, z) = if refitted {
                let residuals = distance_residuals(&model, &fit_data);
                let rss: f64 = residuals.iter().map(|r| r * r).sum();
                let exact = m_screen * (1.0 - rss / baseline_rss).max(0.0);
                (bic(&residuals, current.len() + k) - baseline_bic, chi2_z(exact, k))
            } else {
                let rss = screen.sigma2 * (screen.rows.saturating_sub(screen.base.len()).max(1)) as f64;
                let drop = m_screen * (1.0 - (c.lm * screen.sigma2 / rss).min(0.999_999)).ln()
                    + k as f64 * m_screen.ln();
                (drop, c.z)
            };
            let fitted: Vec<(String, f64, &'static str)> = c
                .effect
                .params()
                .iter()
                .map(|p| (p.to_string(), model.get(*p) - calibrated.get(*p), p.unit()))
                .collect();
            let mut evidence = evidence(c.effect, &fitted, &joints, baseline.rms_mm, score.after);
            if !c.held_reason.is_empty() {
                evidence.push_str(&format!(" (held at zero: {})", c.held_reason.join("; ")));
            }
            let change: Vec<f64> =
                errors.iter().zip(&baseline_errors).map(|(a, b)| a.error_mm - b.error_mm).collect();
            let candidate = Candidate {
                fitted,
                refitted,
                ..Candidate::scored(c.effect.to_string(), &score, baseline.rms_mm, delta_bic, z, evidence)
            };
            let blocks = block_mse(&errors, val);
            (candidate, change, Fitted { blocks, per_placement: score.per_placement })
        })
        .collect();
    let mut scored = scored;
    scored.sort_by(|a, b| a.0.validation_rms_mm.total_cmp(&b.0.validation_rms_mm));
    let (pairs, fits): (Vec<(Candidate, Vec<f64>)>, Vec<Fitted>) =
        scored.into_iter().map(|(c, change, f)| ((c, change), f)).unzip();
    let mut candidates = group_equivalents(pairs);
    let mut worst: Vec<&PairError> = baseline_errors.iter().collect();
    worst.sort_by(|a, b| b.error_mm.abs().total_cmp(&a.error_mm.abs()));
    let worst = worst
        .into_iter()
        .take(10)
        .map(|e| WorstPair {
            placement: val.groups[e.placement].name.clone(),
            landmarks: (val.landmarks[e.landmarks.0].id.clone(), val.landmarks[e.landmarks.1].id.clone()),
            error_mm: e.error_mm,
        })
        .collect();
    let by_placement = val
        .groups
        .iter()
        .enumerate()
        .map(|(p, group)| {
            (
                group.name.clone(),
                rms(&baseline_errors.iter().filter(|e| e.placement == p).cloned().collect::<Vec<_>>()),
            )
        })
        .collect();
    let mut data_errors = score_data_errors(
        &DataErrorInputs {
            calibrated,
            base_params: &base_params,
            cal,
            fit_data: &fit_data,
            val,
            options,
            baseline: &baseline,
            baseline_blocks: &baseline_blocks,
            baseline_bic,
        },
        &disturbed,
        &mis_seated,
    );
    let gap = floor.as_ref().map(|f| gap(f, baseline.rms_mm, val));
    decide(&mut candidates, &mut data_errors, baseline.rms_mm);
    let (rivals, named) = rivals(
        &RivalInputs {
            calibrated,
            fit_data: &fit_data,
            val,
            options,
            screen: &screen,
            base_params: &base_params,
            baseline_rms_mm: baseline.rms_mm,
        },
        &candidates,
        &fits,
        &screened,
    );
    let summary = summarise(
        &baseline,
        gap.as_ref(),
        floor.as_ref(),
        val,
        &candidates,
        &data_errors,
        &joints,
        &rivals,
        &named,
    );
    Diagnosis {
        baseline,
        floor,
        gap,
        data_errors,
        disturbed,
        mis_seated,
        candidates,
        rivals,
        named,
        not_identifiable,
        joints,
        by_height,
        by_reach,
        worst,
        by_placement,
        summary,
    }
}

/// Mark the significant candidates (arm effects and data errors together): a fixed sequence
/// ordered by calibration evidence, each tested at [`FAMILY_ALPHA`] on the held-out placements
/// with the minimum gain, stopping at the first that fails (see the module doc).
fn decide(candidates: &mut [Candidate], data_errors: &mut [Candidate], baseline_rms_mm: f64) {
    let mut sequence: Vec<&mut Candidate> = candidates.iter_mut().chain(data_errors.iter_mut()).collect();
    sequence.sort_by(|a, b| b.calibration_z.total_cmp(&a.calibration_z));
    for c in sequence {
        if !helps_alone(c, baseline_rms_mm) {
            break;
        }
        c.significant = true;
    }
}

/// The candidate's own held-out test passes at [`FAMILY_ALPHA`] with the minimum gain (and the
/// calibration data favour it): significant when the fixed sequence reaches it, else still a
/// rival of the leading candidate.
fn helps_alone(c: &Candidate, baseline_rms_mm: f64) -> bool {
    c.calibration_z > 0.0
        && c.p_value <= FAMILY_ALPHA
        && c.validation_rms_mm <= (1.0 - SIGNIFICANT_GAIN) * baseline_rms_mm
}

/// What the rival tests need.
struct RivalInputs<'a> {
    calibrated: &'a ArmModel,
    /// The calibration data the refits use (a subsample at scale).
    fit_data: &'a Observations,
    val: &'a Observations,
    options: &'a SolveOptions,
    screen: &'a Screen,
    base_params: &'a [ParamId],
    /// Validation RMS of the calibrated model, mm.
    baseline_rms_mm: f64,
}

/// Test the leading significant candidate against the other significant ones, and against those
/// with a lower validation RMS whose own held-out test passes although the fixed sequence did
/// not reach them, that it does not beat in every validation placement; returns the rivals and the effects named (see the module doc).
fn rivals(
    x: &RivalInputs,
    candidates: &[Candidate],
    fits: &[Fitted],
    screened: &[Screened],
) -> (Vec<Rival>, Vec<String>) {
    let Some(lead) = candidates.iter().position(|c| c.significant) else { return (Vec::new(), Vec::new()) };
    let a = &candidates[lead];
    let contenders: Vec<usize> = candidates
        .iter()
        .enumerate()
        .filter(|(k, c)| {
            *k != lead
                && (c.significant || (*k < lead && helps_alone(c, x.baseline_rms_mm)))
                && c.equivalent_to.is_none()
                && !a.equivalent.contains(&c.effect)
        })
        .filter(|(k, _)| {
            // ln(MSE_B / MSE_A) per placement: A beats B unless the sign-flip test says otherwise.
            let diff: Vec<f64> = fits[lead]
                .per_placement
                .iter()
                .filter_map(|(p, va)| fits[*k].per_placement.iter().find(|q| q.0 == *p).map(|q| va - q.1))
                .collect();
            held_out_p(&diff) > FAMILY_ALPHA
        })
        .map(|(k, _)| k)
        .take(MAX_RIVALS)
        .collect();
    let find = |name: &str| screened.iter().find(|s| s.effect.to_string() == name);
    let tested: Vec<Rival> = contenders
        .par_iter()
        .filter_map(|&k| {
            let b = &candidates[k];
            let (sa, sb) = (find(&a.effect)?, find(&b.effect)?);
            let mut start = sa.start(x.calibrated);
            for p in sb.effect.params() {
                if !sb.held.contains(&p) && !start.free.iter().any(|f| f.id == p) {
                    let h = crate::model::effects::default_half_range(p);
                    let v = start.get(p);
                    start.free_param(p, v - h, v + h);
                }
            }
            let params: Vec<ParamId> =
                x.base_params.iter().chain(&sa.added).chain(&sb.added).copied().collect();
            let both = solve_warm(&start, &params, x.fit_data, x.options).ok()?;
            let errors = distance_errors(&both, x.val);
            let b_adds = Score::of(&errors, &fits[lead].blocks, x.val);
            let a_adds = Score::of(&errors, &fits[k].blocks, x.val);
            let gain = |score: &Score, single: f64| {
                score.p_value <= FAMILY_ALPHA && score.after <= (1.0 - SIGNIFICANT_GAIN) * single
            };
            let (a_helps, b_helps) = (gain(&a_adds, b.validation_rms_mm), gain(&b_adds, a.validation_rms_mm));
            let verdict = match (a_helps, b_helps) {
                (true, false) => RivalVerdict::Proxy { cause: a.effect.clone(), proxy: b.effect.clone() },
                (false, true) => RivalVerdict::Proxy { cause: b.effect.clone(), proxy: a.effect.clone() },
                (true, true) => RivalVerdict::Both,
                (false, false) => RivalVerdict::CannotTell,
            };
            let separability = x
                .screen
                .unexplained(&sa.cols, &sa.delta, &sb.cols)
                .min(x.screen.unexplained(&sb.cols, &sb.delta, &sa.cols));
            Some(Rival {
                a: a.effect.clone(),
                b: b.effect.clone(),
                both_rms_mm: b_adds.after,
                a_adds_p: a_adds.p_value,
                b_adds_p: b_adds.p_value,
                separability,
                verdict,
            })
        })
        .collect();
    // A rival that explains what the leader does (and more) leads instead: of several, the one
    // with the strongest calibration evidence (data the held-out tests never saw).
    let evidence_of =
        |name: &str| candidates.iter().find(|c| c.effect == name).map_or(f64::MIN, |c| c.calibration_z);
    let leader = tested
        .iter()
        .filter_map(|r| match &r.verdict {
            RivalVerdict::Proxy { cause, .. } if *cause == r.b => Some(cause.clone()),
            _ => None,
        })
        .max_by(|x, y| evidence_of(x).total_cmp(&evidence_of(y)))
        .unwrap_or_else(|| a.effect.clone());
    let tied: Vec<String> =
        tested.iter().filter(|r| r.verdict == RivalVerdict::CannotTell).map(|r| r.b.clone()).collect();
    let mut named = vec![leader.clone()];
    named.extend(tied.into_iter().filter(|t| *t != leader));
    (tested, named)
}

/// What scoring a data error needs.
struct DataErrorInputs<'a> {
    calibrated: &'a ArmModel,
    /// The identifiable parameters refitted.
    base_params: &'a [ParamId],
    cal: &'a Observations,
    /// The calibration data the landmark refits use (a subsample at scale).
    fit_data: &'a Observations,
    val: &'a Observations,
    options: &'a SolveOptions,
    baseline: &'a ErrorStats,
    baseline_blocks: &'a [((usize, u32), f64)],
    baseline_bic: f64,
}

/// Score every landmark's certificate freed, and each flagged block and touch dropped.
fn score_data_errors(
    x: &DataErrorInputs,
    disturbed: &[DisturbedBlock],
    mis_seated: &[MisSeatedTouch],
) -> Vec<Candidate> {
    let refit = |data: &Observations| solve_warm(x.calibrated, x.base_params, data, x.options);
    let candidate =
        |name: String, score: Score, delta_bic: f64, z: f64, evidence: String, action: String| Candidate {
            action: Some(action),
            ..Candidate::scored(name, &score, x.baseline.rms_mm, delta_bic, z, evidence)
        };

    let mut out: Vec<Candidate> = (0..x.cal.landmarks.len())
        .into_par_iter()
        .filter_map(|l| {
            let (model, corrected) =
                refit_with_landmark_freed(x.calibrated, x.base_params, x.fit_data, l, x.options).ok()?;
            let errors = distance_errors(&model, &x.val.with_landmarks(&corrected));
            let score = Score::of(&errors, x.baseline_blocks, x.val);
            let residuals = distance_residuals(&model, &x.fit_data.with_landmarks(&corrected));
            let m = residuals.len().max(2) as f64;
            let delta_bic = bic(&residuals, x.calibrated.free.len() + 3) - x.baseline_bic;
            // Likelihood ratio of the freed certificate (3 parameters), from the BIC change.
            let z = chi2_z(-(delta_bic - 3.0 * m.ln()), 3);
            let id = &x.cal.landmarks[l].id;
            let (was, now) = (x.cal.landmarks[l].xyz_mm, corrected[l].xyz_mm);
            let d = [now[0] - was[0], now[1] - was[1], now[2] - was[2]];
            let off = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let evidence = format!(
                "landmark {id} is measured {off:.2} mm from its certified position (Δ = ({:+.2}, {:+.2}, {:+.2}) mm in the artefact frame); with its position freed validation RMS goes from {:.3} to {:.3} mm",
                d[0], d[1], d[2], x.baseline.rms_mm, score.after
            );
            let action = format!("check the certificate of {id} (measured position above); meanwhile `kincal calibrate … --exclude-landmark {id}`");
            Some(candidate(format!("landmark:{id}"), score, delta_bic, z, evidence, action))
        })
        .collect();
    for b in disturbed {
        let name = format!("{}/{}", x.cal.groups[b.placement].name, b.repeat);
        let kept = x.cal.without(|k| x.cal.obs[k].group == b.placement && x.cal.obs[k].repeat == b.repeat);
        let Ok(model) = refit(&kept) else { continue };
        let score = Score::of(&distance_errors(&model, x.val), x.baseline_blocks, x.val);
        let evidence = format!(
            "in calibration placement {} repeat {} the touches from #{} ({}) on sit {:.2} mm off the rigid placement of the first {} (χ² {:.0} for 6 degrees of freedom): the artefact moved during the repeat; without the block validation RMS goes from {:.3} to {:.3} mm",
            x.cal.groups[b.placement].name, b.repeat, b.after_touch + 1, b.first_moved, b.moved_mm, b.after_touch, b.chi2, x.baseline.rms_mm, score.after
        );
        let action = format!("drop or re-measure calibration placement {} repeat {} (`kincal calibrate … --exclude-block {name}`)", x.cal.groups[b.placement].name, b.repeat);
        out.push(candidate(format!("block:{name}"), score, f64::NAN, chi2_z(b.chi2, 6), evidence, action));
    }
    for m in mis_seated {
        let t = &x.cal.obs[m.touch];
        let id = &x.cal.landmarks[t.touched()].id;
        let name = format!("{}/{}/{id}", x.cal.groups[t.group].name, t.repeat);
        let Ok(model) = refit(&x.cal.without(|k| k == m.touch)) else { continue };
        let score = Score::of(&distance_errors(&model, x.val), x.baseline_blocks, x.val);
        let evidence = format!(
            "the touch of {id} in calibration placement {} repeat {} sits {:.2} mm off its block's rigid fit (χ² {:.0} for 3 degrees of freedom): mis-seated; without it validation RMS goes from {:.3} to {:.3} mm",
            x.cal.groups[t.group].name, t.repeat, m.residual_mm, m.chi2, x.baseline.rms_mm, score.after
        );
        let action = format!(
            "re-measure {id} in {} repeat {} or drop that touch",
            x.cal.groups[t.group].name, t.repeat
        );
        out.push(candidate(format!("touch:{name}"), score, f64::NAN, chi2_z(m.chi2, 3), evidence, action));
    }
    out.sort_by(|a, b| a.validation_rms_mm.total_cmp(&b.validation_rms_mm));
    out
}

/// Mark candidates (sorted best first, with their changes to the held-out errors) that are
/// equivalent to a better-ranked one.
fn group_equivalents(scored: Vec<(Candidate, Vec<f64>)>) -> Vec<Candidate> {
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
    let mut out: Vec<Candidate> = Vec::with_capacity(scored.len());
    let mut leaders: Vec<(usize, &[f64])> = Vec::new();
    for (i, (candidate, change)) in scored.iter().enumerate() {
        let mut c = candidate.clone();
        match leaders.iter().find(|(_, lc)| correlation(lc, change) >= EQUIVALENT_CORRELATION) {
            Some(&(leader, _)) => {
                c.equivalent_to = Some(out[leader].effect.clone());
                out[leader].equivalent.push(c.effect.clone());
            }
            None => leaders.push((i, change)),
        }
        out.push(c);
    }
    out
}

fn subset_jacobian(jac: &[f64], n: usize, cols: &[usize]) -> Vec<f64> {
    jac.chunks_exact(n).flat_map(|row| cols.iter().map(move |&c| row[c])).collect()
}

/// Tip amplitude of a joint's harmonic: its amplitude times the RMS lever ‖∂p/∂θ‖, mm.
fn tip_amplitude_mm(j: &JointResiduals, s: &Sinusoid) -> f64 {
    let w: f64 = j.points.iter().map(|p| p.2).sum::<f64>() / j.points.len().max(1) as f64;
    s.amplitude_deg * w.sqrt()
}

/// The periodic-residual line: the named effect's joint and order when it is periodic; no line
/// when a non-periodic effect is named; else the largest harmonic at the tip over every joint.
fn periodic_line(joints: &[JointResiduals], named: &[String]) -> Option<String> {
    let periodic = named
        .iter()
        .filter_map(|n| Effect::parse(n))
        .find_map(|e| Some((e.joint?, e.kind.harmonic_order()?)));
    let (joint, order, s) = match periodic {
        Some((j, order)) => {
            let r = joints.get(j)?;
            (r, order, r.spectrum.iter().find(|s| s.0 == order)?.1)
        }
        None if !named.is_empty() => return None,
        None => joints
            .iter()
            .flat_map(|r| r.spectrum.iter().map(move |s| (r, s.0, s.1)))
            .filter(|(_, _, s)| s.explained > 0.1)
            .max_by(|a, b| tip_amplitude_mm(a.0, &a.2).total_cmp(&tip_amplitude_mm(b.0, &b.2)))?,
    };
    let angle = if order == 1 { format!("θ{}", joint.joint) } else { format!("{order}θ{}", joint.joint) };
    let aliased: Vec<String> = joint
        .aliased
        .iter()
        .filter(|a| a.0 == order || a.1 == order)
        .map(|a| format!("{} and {} per revolution alias (correlation {:.2})", a.0, a.1, a.2))
        .collect();
    let coverage = if aliased.is_empty() {
        format!("joint {} seen over {:.0}°", joint.joint, joint.coverage_deg)
    } else {
        format!("joint {} seen over {:.0}° only: {}", joint.joint, joint.coverage_deg, aliased.join(", "))
    };
    Some(format!(
        "largest periodic residual: joint {} apparent error follows sin {angle} ({order} per revolution) with {:.3}° amplitude ({:.3} mm at the tip, {:.0} % of its variance beyond the other orders; {coverage})",
        joint.joint,
        s.amplitude_deg,
        tip_amplitude_mm(joint, &s),
        100.0 * s.explained
    ))
}

#[allow(clippy::too_many_arguments)]
fn summarise(
    baseline: &ErrorStats,
    gap: Option<&Gap>,
    floor: Option<&NoiseFloor>,
    val: &Observations,
    candidates: &[Candidate],
    data_errors: &[Candidate],
    joints: &[JointResiduals],
    rivals: &[Rival],
    named: &[String],
) -> Vec<String> {
    let mut lines = vec![format!(
        "validation RMS of the calibrated model: {:.3} mm over {} pairs",
        baseline.rms_mm, baseline.count
    )];
    if let Some(g) = gap {
        lines.push(g.sentence());
    }
    lines.extend(periodic_line(joints, named));
    let by_name = |n: &str| candidates.iter().find(|c| c.effect == n);
    let best_arm = named.first().and_then(|n| by_name(n));
    let best_data = data_errors.iter().find(|c| c.significant);
    // A flagged block or touch is named even when the held-out data cannot show its harm.
    for c in data_errors.iter().filter(|c| !c.effect.starts_with("landmark:") && !c.significant) {
        lines.push(format!(
            "suspect data: {} — {}; {}",
            c.effect,
            c.evidence,
            c.action.as_deref().unwrap_or("")
        ));
    }
    match (best_data, best_arm) {
        (Some(d), arm) if arm.is_none_or(|a| d.validation_rms_mm <= DATA_ERROR_EXPLAINS * a.validation_rms_mm) => {
            lines.push(format!("data error: {} — {}", d.effect, d.evidence));
            lines.push(format!("what to do: {}", d.action.as_deref().unwrap_or("re-measure")));
            if let Some(a) = arm {
                lines.push(format!("no arm effect is claimed: the best one ({}, {:.3} mm) explains the residuals no better than this data error; fix the data first and diagnose again", a.effect, a.validation_rms_mm));
            }
        }
        (_, Some(_)) if named.len() > 1 => {
            let tied: Vec<&Rival> =
                rivals.iter().filter(|r| r.verdict == RivalVerdict::CannotTell).collect();
            let detail: Vec<String> = tied
                .iter()
                .map(|r| format!("adding {} to {} p = {:.3}, adding {} to {} p = {:.3}, separability λ = {:.1}", r.b, r.a, r.b_adds_p, r.a, r.b, r.a_adds_p, r.separability))
                .collect();
            lines.push(format!(
                "missing effect: {}: these data cannot tell them apart (neither lowers the held-out error beyond the other: {})",
                named.join(" or "),
                detail.join("; ")
            ));
            for n in named {
                if let Some(c) = by_name(n) {
                    lines.push(format!("  {} — {}", c.effect, c.evidence));
                }
            }
            lines.push(format!(
                "what to measure next: `kincal plan RUN` names reachable artefact placements where {} predict different touches (by default for the first pair these data cannot tell apart), the joint ranges they pass and how far apart the explanations put the touches there; measure them, add them to the calibration data, recalibrate and diagnose again",
                named.join(", ")
            ));
        }
        (_, Some(best)) => {
            let same = if best.equivalent.is_empty() {
                String::new()
            } else {
                format!(" (these touches cannot tell it from {})", best.equivalent.join(", "))
            };
            lines.push(format!("missing effect: {} — {}{same}", best.effect, best.evidence));
            for r in rivals {
                match &r.verdict {
                    RivalVerdict::Proxy { cause, proxy } => lines.push(format!(
                        "{proxy} looks like a proxy of {cause}: added to {cause} it gives no significant further gain on the held-out placements (p = {:.3}), while {cause} added to {proxy} does (p = {:.3})",
                        if *proxy == r.b { r.b_adds_p } else { r.a_adds_p },
                        if *proxy == r.b { r.a_adds_p } else { r.b_adds_p },
                    )),
                    RivalVerdict::Both => lines.push(format!(
                        "{} and {} are both missing: each lowers the held-out error beyond the other (p = {:.3} and {:.3}; both together {:.3} mm)",
                        r.a, r.b, r.b_adds_p, r.a_adds_p, r.both_rms_mm
                    )),
                    RivalVerdict::CannotTell => {}
                }
            }
        }
        (_, None) => lines.push(match gap {
            Some(g) if g.significant => format!(
                "no candidate effect or data error improves the held-out error beyond noise, yet the model misses about {:.3} mm: the model is incomplete (look at the apparent joint errors for an error outside the library)",
                g.missing_mm
            ),
            Some(g) if g.at_floor => "no candidate effect improves the held-out error beyond noise, and the error is at the floor expected from repeatability".into(),
            Some(_) => "no candidate effect improves the held-out error beyond noise; whether anything is missing cannot be told from these data".into(),
            None => "no candidate effect improves the held-out error beyond noise (no repeated touches: the noise floor is unknown, so whether the model is complete cannot be told)".into(),
        }),
    }
    let placements = val.groups.len();
    if (1..MIN_PLACEMENTS).contains(&placements) {
        lines.push(format!(
            "with {placements} validation placements the held-out test rests on {placements} numbers (the exact sign-flip test cannot go below 2⁻{placements}, only a t test on so few can pass): measure at least {MIN_PLACEMENTS} validation placements (8–10 with one repeat each carry more evidence than 5 × 3)"
        ));
    }
    if let (Some(best), Some(g), Some(floor)) = (best_arm.or(best_data), gap, floor) {
        let after = crate::calib::floor::gap(floor, best.validation_rms_mm, val);
        if g.significant && after.significant {
            lines.push(format!("even with {} the model would miss about {:.3} mm ({:.3} mm against ≈{:.3} mm expected): the model is incomplete — more effects, or an error outside the library (see the periodic residuals per joint)", best.effect, after.missing_mm, best.validation_rms_mm, after.expected_mm));
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_out_test_carries_a_large_gain_with_one_placement_slightly_worse() {
        // Sign-flip alone: 2/32. The t test on the sizes carries it; noise passes neither; five
        // placements all improved pass through the sign-flip part.
        let units = [0.9, 1.1, 0.8, -0.05, 1.0];
        assert!((sign_flip_p(&units) - 2.0 / 32.0).abs() < 1e-15);
        assert!(held_out_p(&units) < 0.05, "{}", held_out_p(&units));
        assert!(held_out_p(&[0.01, -0.02, 0.015, -0.01, 0.005]) > 0.3);
        assert!(held_out_p(&[0.1, 2.0, 0.05, 1.5, 0.3]) <= 0.05);
    }

    #[test]
    fn sign_flip_test_is_exact() {
        // Five placements all improved: one pattern of 32 is as extreme.
        assert!((sign_flip_p(&[0.3, 0.2, 0.5, 0.1, 0.4]) - 1.0 / 32.0).abs() < 1e-15);
        // The smallest one negative: that pattern and the all-positive one.
        assert!((sign_flip_p(&[0.3, 0.2, 0.5, -0.1, 0.4]) - 2.0 / 32.0).abs() < 1e-15);
        // Noise: small changes either way.
        assert!(sign_flip_p(&[0.01, -0.02, 0.015, -0.01, 0.005]) > 0.3);
        assert!((sign_flip_p(&[0.1, 0.1, 0.1]) - 0.125).abs() < 1e-15);
    }

    #[test]
    fn joint_spectrum_separates_orders_and_shows_aliasing() {
        // Over the whole circle: a 3-per-rev term beside a first harmonic, both recovered.
        let points: Vec<(f64, f64, f64)> = (0..72)
            .map(|k| {
                let phi = k as f64 * 5.0;
                let a = phi.to_radians();
                (phi, 0.3 * (a + 0.5).sin() + 0.12 * (3.0 * a).sin() + 0.01, 1.0)
            })
            .collect();
        let (spectrum, aliased) = fit_spectrum(&points);
        assert!((spectrum[0].1.amplitude_deg - 0.3).abs() < 1e-9, "{spectrum:?}");
        assert!((spectrum[2].1.amplitude_deg - 0.12).abs() < 1e-9, "{spectrum:?}");
        assert!(spectrum[1].1.amplitude_deg < 1e-9 && aliased.is_empty(), "{spectrum:?} {aliased:?}");
        assert!((coverage_deg(&points.iter().map(|p| p.0).collect::<Vec<_>>()) - 355.0).abs() < 1e-9);
        // Over 40° only, orders alias: the fit says so.
        let narrow: Vec<(f64, f64, f64)> =
            (0..40).map(|k| (100.0 + k as f64, (3.0 * (100.0 + k as f64)).to_radians().sin(), 1.0)).collect();
        let (_, aliased) = fit_spectrum(&narrow);
        assert!(!aliased.is_empty(), "a 40° range must show aliased orders");
        assert!((coverage_deg(&narrow.iter().map(|p| p.0).collect::<Vec<_>>()) - 39.0).abs() < 1e-9);
    }

    #[test]
    fn chi2_deviate_matches_chi2_quantiles() {
        // χ²₂ 95 % quantile 5.991, χ²₆ 99 % quantile 16.81.
        assert!((chi2_z(5.991, 2) - 1.645).abs() < 0.03, "{}", chi2_z(5.991, 2));
        assert!((chi2_z(16.81, 6) - 2.326).abs() < 0.03, "{}", chi2_z(16.81, 6));
    }
}
