//! Model diagnostics: where the calibrated model fails, which physical effect is missing.
//!
//! *Where it fails* reads the residuals of the calibrated model on the held-out placements:
//! after a rigid fit of the artefact to the touched positions of each placement, every touch
//! leaves a 3-D residual r. Projected on ∂p/∂θ_j it becomes the *apparent error of joint j*,
//! e_j = (g_j·r)/‖g_j‖² with g_j = ∂p/∂θ_j — what joint j would have to be off by to explain the
//! residual. e_j is binned against θ_j and fitted with a sinusoid a·sin φ + b·cos φ + c
//! (weighted by ‖g_j‖²), against the joint's gravity lever, and |r| against height and reach.
//!
//! *Which effect is missing*: every library effect not yet in the model is checked for
//! identifiability (does it add rank to the Jacobian of the identifiable parameters?), then
//! refitted on the calibration data from the calibrated values and scored on the validation
//! data. `significant` is decided in two stages on independent data. *Screen* on the
//! calibration data: the BIC falls with the effect. *Confirm* on the validation data: a held-out
//! improvement over the (placement, repeat) blocks with p below [`FAMILY_ALPHA`] / (number of
//! candidates that passed the screen, arm effects and data errors together), and at least
//! [`SIGNIFICANT_GAIN`] lower validation RMS. Correcting only for the screened candidates keeps
//! the family-wise rate (the screen never sees the held-out data) without paying for the
//! dozens of candidates the calibration data already reject. Once the gap between validation
//! RMS and the floor estimated from repeatability is itself significant (see
//! [`crate::calib::floor`]), "is anything missing?" is answered; a screened candidate that
//! closes the gap (its validation RMS within the noise of the floor) is then confirmed at
//! [`FAMILY_ALPHA`] without the multiplicity correction (a closed-testing argument: the global
//! null was rejected by the gap test; an effect that only fits noise cannot close a real gap). The held-out p
//! is the smaller of two one-sided tests, doubled (Bonferroni over the pair): a t test on the
//! per-block log ratios ln(MSE_before / MSE_after), and a sign test on how many blocks improved.
//! The log ratio makes a block's improvement scale-free (a block far off the floor does not
//! dominate) and the t test uses its size and consistency: with 3 validation placements
//! (9 blocks) a ratio that is large in every block passes at 0.05/40, which no sign or rank test
//! can (2⁻⁹ > 0.05/27). The sign test keeps the power where one block of many got worse (a
//! heavy tail the t test pays for). An effect that only fits noise moves the log ratios by a few
//! per cent either way and improves about half the blocks: it passes neither.
//!
//! An effect with several parameters (`tcp`, `eccentricity`) keeps those that are identifiable;
//! the rest stay at zero and are named in the evidence. Candidates whose refits change the
//! held-out errors the same way (correlation of the changes ≥ [`EQUIVALENT_CORRELATION`]) are
//! reported as equivalent: a tool-tip offset along the last joint axis and the link length d6,
//! say, move every touch alike and no data of this kind separates them.

use crate::calib::calibrate::{calibrate, CalibrationOptions};
use crate::calib::data_errors::{
    calibrate_with_landmark_freed, suspicious, without, DisturbedBlock, MisSeatedTouch,
};
use crate::calib::floor::{gap, noise_floor, Gap, NoiseFloor};
use crate::calib::identify;
use crate::calib::objective::{CalibrationProblem, Objective};
use crate::calib::validate::{distance_errors, ErrorStats, PairError};
use crate::data::{Artefact, Dataset};
use crate::model::effects::{Effect, EffectKind};
use crate::model::kinematics::{tool_pose, tool_pose_with_jacobian, ColumnMap};
use crate::model::{ArmModel, ParamId, JOINTS};
use crate::numerics::geometry::absolute_orientation;
use crate::numerics::solver::Residuals;
use crate::numerics::stats::one_sided_t;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Family-wise false-alarm rate of the significance test over all candidates.
pub const FAMILY_ALPHA: f64 = 0.05;
/// Correlation of two candidates' changes to the held-out errors above which they are reported
/// as equivalent.
pub const EQUIVALENT_CORRELATION: f64 = 0.98;
/// Relative drop of validation RMS a candidate must reach to be called significant.
pub const SIGNIFICANT_GAIN: f64 = 0.02;
/// Flagged blocks and touches scored at most (each kind).
const MAX_FLAGGED: usize = 3;
/// A data error is named instead of an arm effect when its held-out RMS is within this factor
/// of the best arm effect's.
pub const DATA_ERROR_EXPLAINS: f64 = 1.05;
/// Share of a joint's apparent-error variance a harmonic of order ≥ 3 must explain (as the
/// strongest order) to be scored as a candidate `harmonic:J:N`.
pub const SPECTRUM_PEAK: f64 = 0.2;
/// Highest harmonic order in each joint's apparent-error spectrum.
pub const SPECTRUM_ORDERS: u32 = 4;
/// Angle bins for the residual-vs-joint-angle plots.
const ANGLE_BINS: usize = 12;

/// A fitted first harmonic e ≈ a·sin φ + b·cos φ + c of the apparent joint error.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Sinusoid {
    /// √(a² + b²), degrees.
    pub amplitude_deg: f64,
    /// atan2(b, a), degrees.
    pub phase_deg: f64,
    /// Constant part c, degrees.
    pub mean_deg: f64,
    /// Share of the weighted variance the sinusoid explains (0–1).
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
    /// First harmonic of the apparent error.
    pub sinusoid: Sinusoid,
    /// Harmonics 1..=[`SPECTRUM_ORDERS`] of the apparent error, each fitted alone: (cycles per
    /// revolution, fit).
    pub spectrum: Vec<(u32, Sinusoid)>,
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
    /// Held-out p-value: 2 × min(t test on the per-block log ratios, sign test), at most 1.
    pub p_value: f64,
    /// Change of BIC on the calibration data (negative favours the effect).
    pub delta_bic: f64,
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
fn touch_residuals(model: &ArmModel, artefact: &Artefact, data: &Dataset) -> Vec<Option<Vector3<f64>>> {
    let p: Vec<Vector3<f64>> =
        data.touches.iter().map(|t| tool_pose(model, &t.enc_deg).position_mm).collect();
    let mut out = vec![None; p.len()];
    for placement in 0..data.placements.len() {
        let idx: Vec<usize> = (0..p.len()).filter(|&k| data.touches[k].placement == placement).collect();
        if idx.len() < 4 {
            continue;
        }
        let q: Vec<Vector3<f64>> =
            idx.iter().map(|&k| Vector3::from(artefact.landmarks[data.touches[k].landmark].xyz_mm)).collect();
        let pm: Vec<Vector3<f64>> = idx.iter().map(|&k| p[k]).collect();
        let (r, t): (Matrix3<f64>, Vector3<f64>) = absolute_orientation(&q, &pm);
        for (i, &k) in idx.iter().enumerate() {
            out[k] = Some(pm[i] - (r * q[i] + t));
        }
    }
    out
}

/// Weighted least squares e ≈ a sin φ + b cos φ + c.
fn fit_sinusoid(points: &[(f64, f64, f64)]) -> Sinusoid {
    fit_harmonic(points, 1)
}

/// Weighted least squares e ≈ a sin nφ + b cos nφ + c.
fn fit_harmonic(points: &[(f64, f64, f64)], order: u32) -> Sinusoid {
    let n = f64::from(order);
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for &(phi, e, w) in points {
        let x = Vector3::new((n * phi.to_radians()).sin(), (n * phi.to_radians()).cos(), 1.0);
        ata += x * x.transpose() * w;
        atb += x * (e * w);
    }
    let coef = ata.cholesky().map(|c| c.solve(&atb)).unwrap_or_else(Vector3::zeros);
    let total_w: f64 = points.iter().map(|p| p.2).sum::<f64>().max(1e-300);
    let mean = points.iter().map(|p| p.1 * p.2).sum::<f64>() / total_w;
    let (mut ss_tot, mut ss_res) = (0.0, 0.0);
    for &(phi, e, w) in points {
        let fit = coef[0] * (n * phi.to_radians()).sin() + coef[1] * (n * phi.to_radians()).cos() + coef[2];
        ss_tot += w * (e - mean).powi(2);
        ss_res += w * (e - fit).powi(2);
    }
    Sinusoid {
        amplitude_deg: coef[0].hypot(coef[1]),
        phase_deg: coef[1].atan2(coef[0]).to_degrees(),
        mean_deg: coef[2],
        explained: if ss_tot > 0.0 { (1.0 - ss_res / ss_tot).max(0.0) } else { 0.0 },
    }
}

/// Apparent joint errors of `model` on `data`.
/// Points (x, y) of a scatter plot.
type Points = Vec<(f64, f64)>;

fn joint_residuals(
    model: &ArmModel,
    artefact: &Artefact,
    data: &Dataset,
) -> (Vec<JointResiduals>, Points, Points) {
    let residuals = touch_residuals(model, artefact, data);
    let offsets: Vec<ParamId> = (0..JOINTS).map(ParamId::Offset).collect();
    let columns = ColumnMap::new(&offsets);
    let mut per_joint: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new(); JOINTS];
    let mut gravity: Vec<Vec<(f64, f64)>> = vec![Vec::new(); JOINTS];
    let mut gravity_weights: Vec<Vec<f64>> = vec![Vec::new(); JOINTS];
    let (mut by_height, mut by_reach) = (Vec::new(), Vec::new());
    for (t, r) in data.touches.iter().zip(&residuals) {
        let Some(r) = r else { continue };
        let mut jac = vec![[0.0; 9]; JOINTS];
        let pose = tool_pose_with_jacobian(model, &t.enc_deg, &columns, &mut jac);
        let levers = gravity_levers(model, &t.enc_deg);
        by_height.push((pose.position_mm.z, r.norm()));
        by_reach.push((pose.position_mm.xy().norm(), r.norm()));
        for j in 0..JOINTS {
            let g = Vector3::new(jac[j][0], jac[j][1], jac[j][2]); // mm per degree
            let w = g.norm_squared();
            if w < 1e-9 {
                continue;
            }
            let e = g.dot(r) / w;
            per_joint[j].push((t.enc_deg[j], e, w));
            gravity[j].push((levers[j], e));
            gravity_weights[j].push(w);
        }
    }
    let joints = (0..JOINTS)
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
            JointResiduals {
                joint: j + 1,
                sinusoid: fit_sinusoid(&points),
                spectrum: (1..=SPECTRUM_ORDERS).map(|n| (n, fit_harmonic(&points, n))).collect(),
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
fn gravity_levers(model: &ArmModel, enc_deg: &[f64; JOINTS]) -> [f64; JOINTS] {
    // ∂p/∂compliance_j = ∂p/∂θ_j · λ_j: the ratio of the two columns gives λ_j.
    let params: Vec<ParamId> =
        (0..JOINTS).flat_map(|j| [ParamId::Offset(j), ParamId::Compliance(j)]).collect();
    let mut jac = vec![[0.0; 9]; params.len()];
    tool_pose_with_jacobian(model, enc_deg, &ColumnMap::new(&params), &mut jac);
    std::array::from_fn(|j| {
        let (dtheta, dc) = (&jac[2 * j], &jac[2 * j + 1]);
        let n: f64 = (0..3).map(|k| dtheta[k] * dtheta[k]).sum();
        if n > 1e-12 {
            (0..3).map(|k| dc[k] * dtheta[k]).sum::<f64>() / n
        } else {
            0.0
        }
    })
}

/// Mean square validation error per (placement, repeat) block.
fn block_mse(errors: &[PairError], data: &Dataset) -> Vec<((usize, u32), f64)> {
    let mut blocks: Vec<((usize, u32), f64, usize)> = Vec::new();
    for e in errors {
        let key = (e.placement, data.touches[e.touches.0].repeat);
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
    mean_log_ratio: f64,
    p_value: f64,
}

impl Score {
    fn of(errors: &[PairError], baseline_blocks: &[((usize, u32), f64)], val: &Dataset) -> Score {
        let blocks = block_mse(errors, val);
        let log_ratios: Vec<f64> = baseline_blocks
            .iter()
            .filter_map(|(k, before)| {
                blocks.iter().find(|b| b.0 == *k).map(|b| (before.max(1e-300) / b.1.max(1e-300)).ln())
            })
            .collect();
        Score {
            after: rms(errors),
            blocks_improved: (log_ratios.iter().filter(|r| **r > 0.0).count(), log_ratios.len()),
            mean_log_ratio: log_ratios.iter().sum::<f64>() / log_ratios.len().max(1) as f64,
            p_value: held_out_p(&log_ratios),
        }
    }
}

/// One-sided sign test: P(X ≥ k) for X ~ Binomial(n, ½).
fn sign_test_p(k: usize, n: usize) -> f64 {
    let mut p = 0.0;
    let mut choose = 1.0_f64; // C(n, 0)
    for i in 0..=n {
        if i >= k {
            p += choose;
        }
        choose = choose * (n - i) as f64 / (i + 1) as f64;
    }
    p / 2f64.powi(n as i32)
}

/// Held-out p-value of per-block log ratios ln(MSE_before / MSE_after): twice the smaller of a
/// one-sided t test and a sign test (see the module doc).
pub fn held_out_p(log_ratios: &[f64]) -> f64 {
    let (_, p_t) = one_sided_t(log_ratios);
    let p_sign = sign_test_p(log_ratios.iter().filter(|r| **r > 0.0).count(), log_ratios.len());
    (2.0 * p_t.min(p_sign)).min(1.0)
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

fn distance_residuals(model: &ArmModel, artefact: &Artefact, data: &Dataset) -> Vec<f64> {
    distance_errors(model, artefact, data).iter().map(|e| e.error_mm).collect()
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
            format!("joint {j} sags under gravity: the residual grows with its gravity lever ({slope:+.3} °/m seen, {:+.3} °/m fitted); compliance of joint {j} {gain}", value(0))
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

/// Diagnose `calibrated` (whose free set and bounds are those it was calibrated with).
pub fn diagnose(
    calibrated: &ArmModel,
    artefact: &Artefact,
    cal: &Dataset,
    val: &Dataset,
    options: &CalibrationOptions,
) -> Diagnosis {
    let baseline_errors = distance_errors(calibrated, artefact, val);
    let baseline = ErrorStats::of(&baseline_errors.iter().map(|e| e.error_mm).collect::<Vec<_>>());
    let (joints, by_height, by_reach) = joint_residuals(calibrated, artefact, val);
    let current: Vec<ParamId> = calibrated.free.iter().map(|f| f.id).collect();
    let baseline_bic = bic(&distance_residuals(calibrated, artefact, cal), current.len());
    let baseline_blocks = block_mse(&baseline_errors, val);
    // Higher harmonics only where a joint's apparent-error spectrum peaks at that order.
    let peaks: Vec<Effect> = joints
        .iter()
        .filter_map(|r| {
            let (order, s) = r.spectrum.iter().max_by(|a, b| a.1.explained.total_cmp(&b.1.explained))?;
            (*order >= 3 && s.explained > SPECTRUM_PEAK)
                .then(|| Effect::harmonic(r.joint - 1, *order))
                .flatten()
        })
        .collect();
    let candidates_effects: Vec<Effect> = Effect::library()
        .into_iter()
        .filter(|e| !e.is_in(calibrated))
        .filter(|e| e.kind.harmonic_order().is_none_or(|n| n <= 2) || peaks.contains(e))
        .collect();
    let floor = noise_floor(calibrated, artefact, cal, val, current.len());
    let (disturbed, mis_seated) = match &floor {
        Some(f) => suspicious(calibrated, artefact, cal, f.touch_std_mm.powi(2)),
        None => (Vec::new(), Vec::new()),
    };
    let disturbed: Vec<DisturbedBlock> = disturbed.into_iter().take(MAX_FLAGGED).collect();
    let mis_seated: Vec<MisSeatedTouch> = mis_seated.into_iter().take(MAX_FLAGGED).collect();
    let results: Vec<Result<(Candidate, Vec<f64>), NotIdentifiable>> = candidates_effects
        .par_iter()
        .map(|&effect| {
            let mut model = calibrated.clone();
            effect.add_to(&mut model);
            let all: Vec<ParamId> = model.free.iter().map(|f| f.id).collect();
            let ranges: Vec<f64> = model.free.iter().map(|f| (f.upper - f.lower).max(1e-9)).collect();
            let problem = CalibrationProblem::new(&model, all.clone(), artefact, cal, Objective::Distance);
            let mut r = vec![0.0; problem.len()];
            let mut jac = vec![0.0; problem.len() * all.len()];
            problem.evaluate(&model.free_values(), &mut r, Some(&mut jac));
            // The identifiable base set of the current parameters, then what the effect adds to it.
            let existing: Vec<usize> = (0..all.len()).filter(|&c| current.contains(&all[c])).collect();
            let existing_ranges: Vec<f64> = existing.iter().map(|&c| ranges[c]).collect();
            let base: Vec<usize> = identify::base_columns(
                &subset_jacobian(&jac, all.len(), &existing),
                existing.len(),
                &existing_ranges,
            )
            .0
            .into_iter()
            .map(|k| existing[k])
            .collect();
            let extra: Vec<usize> = (0..all.len()).filter(|c| !current.contains(&all[*c])).collect();
            let rank = identify::added_rank(&jac, all.len(), &ranges, &base, &extra);
            let describe = |k: usize| {
                let r = &rank[k];
                if r.moves_nothing {
                    return format!("{} changes no distance", all[extra[k]]);
                }
                let mut terms: Vec<(ParamId, f64, f64)> = base
                    .iter()
                    .enumerate()
                    .map(|(i, &c)| (all[c], -r.like[i], r.share[i]))
                    .filter(|t| t.2.abs() > 1e-3)
                    .collect();
                terms.sort_by(|a, b| b.2.abs().total_cmp(&a.2.abs()));
                let list: Vec<String> = terms
                    .iter()
                    .take(4)
                    .map(|(p, b, _)| format!("{p} ({b:+.4} {} per {})", p.unit(), all[extra[k]].unit()))
                    .collect();
                format!("{}'s effect on distances is absorbed by {}", all[extra[k]], list.join(", "))
            };
            let unidentified: Vec<usize> = (0..extra.len()).filter(|&k| !rank[k].adds).collect();
            if unidentified.len() == extra.len() {
                let reasons: Vec<String> = unidentified.iter().map(|&k| describe(k)).collect();
                return Err(NotIdentifiable {
                    effect: effect.to_string(),
                    reason: format!("not identifiable from these touches: {}", reasons.join("; ")),
                });
            }
            for &k in &unidentified {
                model.fix_param(all[extra[k]]);
            }
            let partial: Vec<String> = unidentified.iter().map(|&k| describe(k)).collect();
            let refit = calibrate(&model, artefact, cal, &CalibrationOptions { restarts: 0, ..*options })
                .map_err(|e| NotIdentifiable { effect: effect.to_string(), reason: e.to_string() })?;
            let errors = distance_errors(&refit.model, artefact, val);
            let Score { after, blocks_improved, mean_log_ratio, p_value } =
                Score::of(&errors, &baseline_blocks, val);
            let delta_bic =
                bic(&distance_residuals(&refit.model, artefact, cal), model.free.len()) - baseline_bic;
            let explained = ((baseline.rms_mm.powi(2) - after.powi(2)) / baseline.rms_mm.powi(2).max(1e-300))
                .clamp(0.0, 1.0);
            let significant = false; // decided over all candidates below
            let fitted: Vec<(String, f64, &'static str)> = effect
                .params()
                .iter()
                .map(|p| (p.to_string(), refit.model.get(*p) - calibrated.get(*p), p.unit()))
                .collect();
            let mut evidence = evidence(effect, &fitted, &joints, baseline.rms_mm, after);
            if !partial.is_empty() {
                evidence.push_str(&format!(" (held at zero: {})", partial.join("; ")));
            }
            let change: Vec<f64> =
                errors.iter().zip(&baseline_errors).map(|(a, b)| a.error_mm - b.error_mm).collect();
            Ok((
                Candidate {
                    effect: effect.to_string(),
                    validation_rms_mm: after,
                    explained,
                    significant,
                    blocks_improved,
                    mean_log_ratio,
                    p_value,
                    delta_bic,
                    fitted,
                    evidence,
                    equivalent: Vec::new(),
                    equivalent_to: None,
                    action: None,
                },
                change,
            ))
        })
        .collect();
    let mut scored = Vec::new();
    let mut not_identifiable = Vec::new();
    for r in results {
        match r {
            Ok(c) => scored.push(c),
            Err(n) => not_identifiable.push(n),
        }
    }
    scored.sort_by(|a, b| a.0.validation_rms_mm.total_cmp(&b.0.validation_rms_mm));
    let mut candidates = group_equivalents(scored);
    let mut worst: Vec<&PairError> = baseline_errors.iter().collect();
    worst.sort_by(|a, b| b.error_mm.abs().total_cmp(&a.error_mm.abs()));
    let worst = worst
        .into_iter()
        .take(10)
        .map(|e| WorstPair {
            placement: val.placements[e.placement].clone(),
            landmarks: (
                artefact.landmarks[e.landmarks.0].id.clone(),
                artefact.landmarks[e.landmarks.1].id.clone(),
            ),
            error_mm: e.error_mm,
        })
        .collect();
    let by_placement = val
        .placements
        .iter()
        .enumerate()
        .map(|(p, name)| {
            (
                name.clone(),
                rms(&baseline_errors.iter().filter(|e| e.placement == p).cloned().collect::<Vec<_>>()),
            )
        })
        .collect();
    let mut data_errors = score_data_errors(
        &DataErrorInputs {
            calibrated,
            artefact,
            cal,
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
    let closes_gap =
        |rms_mm: f64| floor.as_ref().is_some_and(|f| !crate::calib::floor::gap(f, rms_mm, val).significant);
    decide(
        &mut candidates,
        &mut data_errors,
        baseline.rms_mm,
        gap.as_ref().is_some_and(|g| g.significant),
        closes_gap,
    );
    let summary = summarise(&baseline, gap.as_ref(), floor.as_ref(), val, &candidates, &data_errors, &joints);
    Diagnosis {
        baseline,
        floor,
        gap,
        data_errors,
        disturbed,
        mis_seated,
        candidates,
        not_identifiable,
        joints,
        by_height,
        by_reach,
        worst,
        by_placement,
        summary,
    }
}

/// A candidate passes the calibration screen when its BIC on the calibration data falls (a
/// dropped block or touch changes the data, so it has no BIC and passes).
fn screened(c: &Candidate) -> bool {
    c.delta_bic.is_nan() || c.delta_bic < 0.0
}

/// Mark the significant candidates: screened on the calibration data, then confirmed on the
/// held-out data at [`FAMILY_ALPHA`] / (number screened), with the minimum gain — or, once the
/// gap to the floor is itself significant (the model is known to be incomplete), at
/// [`FAMILY_ALPHA`] alone for a candidate that closes the gap (`closes_gap`: its validation RMS
/// is within the noise of the floor).
fn decide(
    candidates: &mut [Candidate],
    data_errors: &mut [Candidate],
    baseline_rms_mm: f64,
    gap_significant: bool,
    closes_gap: impl Fn(f64) -> bool,
) {
    let count = candidates.iter().chain(data_errors.iter()).filter(|c| screened(c)).count().max(1);
    for c in candidates.iter_mut().chain(data_errors.iter_mut()) {
        let confirmed = c.p_value < FAMILY_ALPHA / count as f64
            || (gap_significant && c.p_value < FAMILY_ALPHA && closes_gap(c.validation_rms_mm));
        c.significant =
            screened(c) && confirmed && c.validation_rms_mm <= (1.0 - SIGNIFICANT_GAIN) * baseline_rms_mm;
    }
}

/// What scoring a data error needs.
struct DataErrorInputs<'a> {
    calibrated: &'a ArmModel,
    artefact: &'a Artefact,
    cal: &'a Dataset,
    val: &'a Dataset,
    options: &'a CalibrationOptions,
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
    let refit_options = CalibrationOptions { restarts: 0, ..*x.options };
    let base_ms = x.baseline.rms_mm.powi(2).max(1e-300);
    let candidate = |name: String, score: Score, delta_bic: f64, evidence: String, action: String| {
        let explained = ((base_ms - score.after.powi(2)) / base_ms).clamp(0.0, 1.0);
        Candidate {
            effect: name,
            validation_rms_mm: score.after,
            explained,
            significant: false,
            blocks_improved: score.blocks_improved,
            mean_log_ratio: score.mean_log_ratio,
            p_value: score.p_value,
            delta_bic,
            fitted: Vec::new(),
            evidence,
            equivalent: Vec::new(),
            equivalent_to: None,
            action: Some(action),
        }
    };
    let mut out: Vec<Candidate> = (0..x.artefact.landmarks.len())
        .into_par_iter()
        .filter_map(|l| {
            let (fit, corrected) =
                calibrate_with_landmark_freed(x.calibrated, x.artefact, x.cal, l, &refit_options).ok()?;
            let errors = distance_errors(&fit.model, &corrected, x.val);
            let score = Score::of(&errors, x.baseline_blocks, x.val);
            let delta_bic =
                bic(&distance_residuals(&fit.model, &corrected, x.cal), x.calibrated.free.len() + 3) - x.baseline_bic;
            let id = &x.artefact.landmarks[l].id;
            let (was, now) = (x.artefact.landmarks[l].xyz_mm, corrected.landmarks[l].xyz_mm);
            let d = [now[0] - was[0], now[1] - was[1], now[2] - was[2]];
            let off = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let evidence = format!(
                "landmark {id} is measured {off:.2} mm from its certified position (Δ = ({:+.2}, {:+.2}, {:+.2}) mm in the artefact frame); with its position freed validation RMS goes from {:.3} to {:.3} mm",
                d[0], d[1], d[2], x.baseline.rms_mm, score.after
            );
            let action = format!("check the certificate of {id} (measured position above); meanwhile `kincal calibrate … --exclude-landmark {id}`");
            Some(candidate(format!("landmark:{id}"), score, delta_bic, evidence, action))
        })
        .collect();
    for b in disturbed {
        let name = format!("{}/{}", x.cal.placements[b.placement], b.repeat);
        let kept = without(x.cal, |k| {
            x.cal.touches[k].placement == b.placement && x.cal.touches[k].repeat == b.repeat
        });
        let Ok(fit) = calibrate(x.calibrated, x.artefact, &kept, &refit_options) else { continue };
        let score = Score::of(&distance_errors(&fit.model, x.artefact, x.val), x.baseline_blocks, x.val);
        let evidence = format!(
            "in calibration placement {} repeat {} the touches from #{} ({}) on sit {:.2} mm off the rigid placement of the first {} (χ² {:.0} for 6 degrees of freedom): the artefact moved during the repeat; without the block validation RMS goes from {:.3} to {:.3} mm",
            x.cal.placements[b.placement], b.repeat, b.after_touch + 1, b.first_moved, b.moved_mm, b.after_touch, b.chi2, x.baseline.rms_mm, score.after
        );
        let action = format!("drop or re-measure calibration placement {} repeat {} (`kincal calibrate … --exclude-block {name}`)", x.cal.placements[b.placement], b.repeat);
        out.push(candidate(format!("block:{name}"), score, f64::NAN, evidence, action));
    }
    for m in mis_seated {
        let t = &x.cal.touches[m.touch];
        let id = &x.artefact.landmarks[t.landmark].id;
        let name = format!("{}/{}/{id}", x.cal.placements[t.placement], t.repeat);
        let Ok(fit) = calibrate(x.calibrated, x.artefact, &without(x.cal, |k| k == m.touch), &refit_options)
        else {
            continue;
        };
        let score = Score::of(&distance_errors(&fit.model, x.artefact, x.val), x.baseline_blocks, x.val);
        let evidence = format!(
            "the touch of {id} in calibration placement {} repeat {} sits {:.2} mm off its block's rigid fit (χ² {:.0} for 3 degrees of freedom): mis-seated; without it validation RMS goes from {:.3} to {:.3} mm",
            x.cal.placements[t.placement], t.repeat, m.residual_mm, m.chi2, x.baseline.rms_mm, score.after
        );
        let action = format!(
            "re-measure {id} in {} repeat {} or drop that touch",
            x.cal.placements[t.placement], t.repeat
        );
        out.push(candidate(format!("touch:{name}"), score, f64::NAN, evidence, action));
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

fn summarise(
    baseline: &ErrorStats,
    gap: Option<&Gap>,
    floor: Option<&NoiseFloor>,
    val: &Dataset,
    candidates: &[Candidate],
    data_errors: &[Candidate],
    joints: &[JointResiduals],
) -> Vec<String> {
    let mut lines = vec![format!(
        "validation RMS of the calibrated model: {:.3} mm over {} pairs",
        baseline.rms_mm, baseline.pairs
    )];
    if let Some(g) = gap {
        lines.push(g.sentence());
    }
    let best_arm = candidates.iter().find(|c| c.significant);
    // The periodic line names the joint of a periodic effect found, else the strongest harmonic.
    let effect_joint = best_arm
        .and_then(|c| Effect::parse(&c.effect))
        .filter(|e| e.kind.harmonic_order().is_some())
        .and_then(|e| e.joint);
    let strongest = |j: &JointResiduals| {
        j.spectrum.iter().copied().max_by(|a, b| {
            (a.1.amplitude_deg * a.1.explained).total_cmp(&(b.1.amplitude_deg * b.1.explained))
        })
    };
    let periodic = match effect_joint {
        Some(j) => joints.get(j).and_then(|r| strongest(r).map(|s| (r.joint, s))),
        None => joints.iter().filter_map(|r| strongest(r).map(|s| (r.joint, s))).max_by(|a, b| {
            (a.1 .1.amplitude_deg * a.1 .1.explained).total_cmp(&(b.1 .1.amplitude_deg * b.1 .1.explained))
        }),
    };
    if let Some((joint, (order, s))) = periodic.filter(|p| p.1 .1.explained > 0.1) {
        let angle = if order == 1 { format!("θ{joint}") } else { format!("{order}θ{joint}") };
        lines.push(format!("largest periodic residual: joint {joint} apparent error follows sin {angle} ({order} per revolution) with {:.3}° amplitude ({:.0} % of its variance)", s.amplitude_deg, 100.0 * s.explained));
    }
    let best_arm = candidates.iter().find(|c| c.significant);
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
        (_, Some(best)) if !best.equivalent.is_empty() => lines.push(format!(
            "missing effect: {} — {} (these touches cannot tell it from {})",
            best.effect,
            best.evidence,
            best.equivalent.join(", ")
        )),
        (_, Some(best)) => lines.push(format!("missing effect: {} — {}", best.effect, best.evidence)),
        (_, None) => lines.push(match gap {
            Some(g) if g.significant => format!(
                "no candidate effect or data error improves the held-out error beyond noise, yet the model misses about {:.3} mm: the model is incomplete (look at the apparent joint errors for an error outside the library)",
                g.missing_mm
            ),
            Some(_) => "no candidate effect improves the held-out error beyond noise, and the error is at the floor expected from repeatability".into(),
            None => "no candidate effect improves the held-out error beyond noise (no repeated touches: the noise floor is unknown, so whether the model is complete cannot be told)".into(),
        }),
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
    fn sign_test_tail_probabilities() {
        assert!((sign_test_p(15, 15) - 1.0 / 32768.0).abs() < 1e-15);
        assert!((sign_test_p(14, 15) - 16.0 / 32768.0).abs() < 1e-15);
        assert!((sign_test_p(0, 15) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn held_out_test_has_power_with_nine_blocks_and_none_on_noise() {
        // Nine blocks, all improved about 9× in mean square: far below 0.05/40.
        let strong = [2.1, 2.4, 1.9, 2.3, 2.2, 2.0, 2.5, 1.8, 2.2];
        assert!(held_out_p(&strong) < 0.05 / 40.0, "{}", held_out_p(&strong));
        // Fifteen blocks, 14 improved and one much worse: the sign test carries it.
        let mut one_bad = vec![0.5; 14];
        one_bad.push(-4.0);
        assert!(held_out_p(&one_bad) < 0.05 / 25.0, "{}", held_out_p(&one_bad));
        // Noise: small changes either way.
        let noise = [0.01, -0.02, 0.015, -0.01, 0.0, 0.02, -0.015, 0.005, -0.005];
        assert!(held_out_p(&noise) > 0.1);
    }

    #[test]
    fn sinusoid_fit_recovers_amplitude_and_phase() {
        let points: Vec<(f64, f64, f64)> = (0..72)
            .map(|k| {
                let phi = k as f64 * 5.0;
                (phi, 0.3 * (phi.to_radians() + 0.5).sin() + 0.01, 1.0)
            })
            .collect();
        let s = fit_sinusoid(&points);
        assert!(
            (s.amplitude_deg - 0.3).abs() < 1e-9 && (s.mean_deg - 0.01).abs() < 1e-9 && s.explained > 0.999,
            "{s:?}"
        );
    }
}
