//! Where the model fails: the apparent joint errors of the held-out residuals, for every kind of
//! held-out data.
//!
//! After each held-out block's frame is refitted (a rigid fit of the artefact to the touched
//! positions of each placement; a session's frame, and its tool where it floats), every
//! observation leaves a 3-D residual r, predicted − measured in the arm's base frame. Projected
//! on ∂p/∂θ_j it becomes the *apparent error of joint j*, e_j = (g_j·r)/‖g_j‖² with
//! g_j = ∂p/∂θ_j — what joint j would have to be off by to explain the residual. e_j is binned
//! against θ_j and fitted, jointly over the orders 1..=[`SPECTRUM_ORDERS`], by weighted least
//! squares (weights ‖g_j‖²): e ≈ c + Σ_n a_n sin nθ + b_n cos nθ. Fitting the orders together
//! shows aliasing over the angles actually visited: each joint reports its angle coverage and the
//! pairs of orders the visited angles cannot tell apart. The apparent error is also drawn
//! against the joint's gravity lever, and |r| against height and reach.

use crate::calib::validate::{placement_residuals, session_offset_mm, session_residuals_mm};
use crate::data::Observations;
use crate::model::effects::Effect;
use crate::model::kinematics::{Chain, ColumnMap};
use crate::model::{ArmModel, ParamId};
use nalgebra::{DMatrix, DVector, Vector3};

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

impl Sinusoid {
    /// True when the amplitude of order `order` is one an encoder error of the library could
    /// have: within the bounds its effect is given ([`crate::model::effects::default_half_range`]).
    /// A larger one is not a periodic error of that joint but the whole residual put on a joint
    /// that barely moves the tip (on a humanoid's tip-mass model, the sag the model misses read as
    /// a 39° wave of a wrist joint), and it is not a result to print.
    pub fn is_plausible(&self, order: u32) -> bool {
        Effect::harmonic(0, order)
            .and_then(|e| e.params().first().copied())
            .is_some_and(|p| self.amplitude_deg <= crate::model::effects::default_half_range(p))
    }
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

/// Per-observation residual vectors (predicted − measured, the arm's base frame, mm) after
/// each held-out block's frame is refitted: a rigid fit of the artefact in each placement (four
/// touches or more), or each session's frame (and tool, for the groups in `float_tool`).
fn residuals(model: &ArmModel, data: &Observations, float_tool: &[String]) -> Vec<Option<Vector3<f64>>> {
    let mut out = placement_residuals(model, data, 4);
    for b in data.sessions() {
        let offset = session_offset_mm(model, data, b, float_tool);
        let points = data.blocks[b].members.iter().filter(|&&k| data.obs[k].point_mm().is_some());
        for (&k, r) in points.zip(session_residuals_mm(model, data, b, offset)) {
            out[k] = Some(-r);
        }
    }
    out
}

/// Points (x, y) of a scatter plot.
pub type Points = Vec<(f64, f64)>;

/// The apparent joint errors of `model` on held-out `data`, and |r| against height and reach.
pub fn apparent(
    model: &ArmModel,
    data: &Observations,
    float_tool: &[String],
) -> (Vec<JointResiduals>, Points, Points) {
    let residuals = residuals(model, data, float_tool);
    let joints = model.joints.len();
    let offsets: Vec<ParamId> = (0..joints).map(ParamId::Offset).collect();
    let columns = ColumnMap::new(&offsets);
    let mut per_joint: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new(); joints];
    let mut gravity: Vec<Vec<(f64, f64)>> = vec![Vec::new(); joints];
    let mut gravity_weights: Vec<Vec<f64>> = vec![Vec::new(); joints];
    let (mut by_height, mut by_reach) = (Vec::new(), Vec::new());
    for (k, (t, r)) in data.obs.iter().zip(&residuals).enumerate() {
        let Some(r) = r else { continue };
        let mut jac = vec![[0.0; 9]; joints];
        let chain = Chain::for_tip(model, t.tip);
        let pose = data.encoders().with_row(k, t, |sin_cos| {
            chain.pose_with_sin_cos_and_jacobian(&t.q_deg, sin_cos, &columns, &mut jac)
        });
        let levers = gravity_levers(model, &chain, &t.q_deg);
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
                    let inside: Vec<&(f64, f64, f64)> = points
                        .iter()
                        .filter(|p| ((p.0.rem_euclid(360.0) / width) as usize).min(ANGLE_BINS - 1) == b)
                        .collect();
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
fn gravity_levers(model: &ArmModel, chain: &Chain, enc_deg: &[f64]) -> Vec<f64> {
    // ∂p/∂compliance_j = ∂p/∂θ_j · λ_j: the ratio of the two columns gives λ_j.
    let joints = model.joints.len();
    let params: Vec<ParamId> =
        (0..joints).flat_map(|j| [ParamId::Offset(j), ParamId::Compliance(j)]).collect();
    let mut jac = vec![[0.0; 9]; params.len()];
    chain.pose_with_jacobian(enc_deg, &ColumnMap::new(&params), &mut jac);
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

/// Tip amplitude of a joint's harmonic: its amplitude times the RMS lever ‖∂p/∂θ‖, mm.
fn tip_amplitude_mm(j: &JointResiduals, s: &Sinusoid) -> f64 {
    let w: f64 = j.points.iter().map(|p| p.2).sum::<f64>() / j.points.len().max(1) as f64;
    s.amplitude_deg * w.sqrt()
}

/// True when the wave `s` of order `order` at the tip holds no more than the joint's apparent
/// error itself: Σ w·(a sin nφ + b cos nφ)² ≤ Σ w·e² over its touches. Fitted jointly with the
/// other orders over part of a turn, two orders can take large opposite values that cancel; such
/// an order's amplitude is not in the data, and it is not a result to print.
fn within_the_residual(j: &JointResiduals, order: u32, s: &Sinusoid) -> bool {
    let (sin_phase, cos_phase) = s.phase_deg.to_radians().sin_cos();
    let (a, b) = (s.amplitude_deg * cos_phase, s.amplitude_deg * sin_phase);
    let wave: f64 = j
        .points
        .iter()
        .map(|&(phi, _, w)| {
            let x = (order as f64 * phi).to_radians();
            w * (a * x.sin() + b * x.cos()).powi(2)
        })
        .sum();
    let data: f64 = j.points.iter().map(|&(_, e, w)| w * e * e).sum();
    wave <= data * (1.0 + 1e-9)
}

/// The periodic-residual line: the named effect's joint and order when it is periodic; no line
/// when a non-periodic effect is named; else the largest harmonic at the tip over every joint.
pub fn periodic_line(joints: &[JointResiduals], named: &[String]) -> Option<String> {
    let periodic = named
        .iter()
        .filter_map(|n| Effect::parse(n))
        .find_map(|e| Some((e.joint?, e.kind.harmonic_order()?)));
    let (joint, order, s) = match periodic {
        Some((j, order)) => {
            let r = joints.get(j)?;
            (
                r,
                order,
                r.spectrum
                    .iter()
                    .find(|s| s.0 == order && s.1.is_plausible(order) && within_the_residual(r, order, &s.1))?
                    .1,
            )
        }
        None if !named.is_empty() => return None,
        None => joints
            .iter()
            .flat_map(|r| r.spectrum.iter().map(move |s| (r, s.0, s.1)))
            .filter(|(r, order, s)| {
                s.explained > 0.1 && s.is_plausible(*order) && within_the_residual(r, *order, s)
            })
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

#[cfg(test)]
mod tests {
    use super::*;

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

    /// A wave an encoder error could have is printed; one beyond its effect's bounds (a residual
    /// put on a joint that barely moves the tip) gives no figure.
    #[test]
    fn the_periodic_line_prints_no_amplitude_an_encoder_error_cannot_have() {
        let joint = |amplitude_deg: f64| {
            let points: Vec<(f64, f64, f64)> = (0..72)
                .map(|k| (k as f64 * 5.0, amplitude_deg * (k as f64 * 5.0).to_radians().sin(), 1.0))
                .collect();
            let (spectrum, aliased) = fit_spectrum(&points);
            JointResiduals {
                joint: 7,
                points,
                bins: Vec::new(),
                sinusoid: spectrum[0].1,
                spectrum,
                coverage_deg: 355.0,
                aliased,
                gravity: Vec::new(),
                gravity_slope_deg_per_m: 0.0,
            }
        };
        let line = periodic_line(&[joint(0.3)], &[]).expect("a 0.3° wave is a result");
        assert!(line.contains("0.300° amplitude"), "{line}");
        assert_eq!(periodic_line(&[joint(39.0)], &[]), None, "a 39° wave is no encoder error");
        assert_eq!(periodic_line(&[joint(39.0)], &["eccentricity:7".into()]), None);
        // A wave larger at the tip than the apparent error it was fitted to (orders cancelling
        // over part of a turn) is not in the data.
        let mut cancelled = joint(0.3);
        cancelled.points.iter_mut().for_each(|p| p.1 *= 0.1);
        assert_eq!(periodic_line(&[cancelled.clone()], &[]), None);
        assert_eq!(periodic_line(&[cancelled], &["eccentricity:7".into()]), None);
    }
}
