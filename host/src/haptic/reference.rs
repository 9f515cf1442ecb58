//! The orientation reference (paper eqs. 12–14) from the `reference/` step: the HIP held in its
//! stand, the stylus rolled about its own axis to both mechanical stops.
//!
//! Marker points of the stylus target are brought into stylus coordinates without the roll,
//! v′_i = F_i⁻¹·(EH⁻¹·v_i), F_i the device pose from θ1…θ5 (eq. 13). There they travel on
//! circles about the physical stylus axis: circles are fitted in the x–y plane by orthogonal
//! distance regression, the axis is the line through their centres and the stylus origin
//! (SVD), and it is expressed in the target frame by averaging (EH⁻¹·P_i)⁻¹·(F_i·z) over the
//! samples (eq. 14) — from then on the target's pose gives the physical axis. The roll stops
//! show as a gap in the angles of the markers around the best circle (360 bins); the direction
//! opposite the gap's centre is θ6 = 0.

use nalgebra::{Matrix3, Vector2, Vector3};

/// Virtual markers on the stylus target, target frame, mm: its origin and two points off it.
pub const MARKERS_MM: [[f64; 3]; 3] = [[0.0, 0.0, 0.0], [25.0, 0.0, 10.0], [0.0, 25.0, -10.0]];

/// A rigid pose: rotation and translation (mm).
pub type Pose = (Matrix3<f64>, Vector3<f64>);

/// Why no reference could be derived.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    /// Too few samples.
    #[error("the reference step has {0} samples; roll the stylus slowly to both stops (≥ 50 samples)")]
    TooFewSamples(usize),
    /// The markers hardly moved on their circles.
    #[error("the stylus was rolled through {0:.0}° only; roll it to both mechanical stops")]
    TooLittleRoll(f64),
}

/// The reference derived from the roll.
#[derive(Clone, Debug)]
pub struct OrientationReference {
    /// Physical stylus axis in the target frame (unit).
    pub axis_in_target: Vector3<f64>,
    /// Reference roll θ6 of every sample, radians.
    pub roll: Vec<f64>,
    /// Roll range covered between the stops, degrees.
    pub range_deg: f64,
    /// RMS distance of the marker points from their fitted circles, mm.
    pub circle_rms_mm: f64,
}

/// Circle (centre, radius, RMS residual) through 2-D points: algebraic fit, then Gauss–Newton on
/// the orthogonal distances ‖p − c‖ − r.
pub fn fit_circle(points: &[Vector2<f64>]) -> (Vector2<f64>, f64, f64) {
    let n = points.len().max(1) as f64;
    let mean = points.iter().sum::<Vector2<f64>>() / n;
    // Kåsa: minimise Σ(‖p − c‖² − r²)², linear in (c, r² − ‖c‖²).
    let (mut a, mut b) = (nalgebra::Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
    for p in points {
        let q = p - mean;
        let row = Vector3::new(q.x, q.y, 1.0);
        a += row * row.transpose();
        b += row * q.norm_squared();
    }
    let sol = a.lu().solve(&b).unwrap_or_else(Vector3::zeros);
    let mut c = Vector2::new(sol.x / 2.0, sol.y / 2.0);
    let mut r = (sol.z + c.norm_squared()).max(0.0).sqrt();
    for _ in 0..20 {
        let (mut jtj, mut jtr) = (nalgebra::Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
        for p in points {
            let d = p - mean - c;
            let dist = d.norm().max(1e-12);
            let res = dist - r;
            let j = Vector3::new(-d.x / dist, -d.y / dist, -1.0);
            jtj += j * j.transpose();
            jtr += j * res;
        }
        let Some(step) = jtj.lu().solve(&(-jtr)) else { break };
        c += Vector2::new(step.x, step.y);
        r += step.z;
        if step.norm() < 1e-12 {
            break;
        }
    }
    let rms = (points.iter().map(|p| ((p - mean - c).norm() - r).powi(2)).sum::<f64>() / n).sqrt();
    (c + mean, r, rms)
}

/// Derive the reference from target poses `targets` (target → tracker), device poses `frames`
/// (θ1…θ5, device coordinates) and the device → tracker transform `eh`.
pub fn orientation_reference(
    targets: &[Pose],
    frames: &[Pose],
    eh: &Pose,
) -> Result<OrientationReference, ReferenceError> {
    let n = targets.len().min(frames.len());
    if n < 50 {
        return Err(ReferenceError::TooFewSamples(n));
    }
    let (re, te) = eh;
    // Marker points in stylus coordinates without the roll (eq. 13).
    let local = |i: usize, m: &[f64; 3]| -> Vector3<f64> {
        let (rp, tp) = &targets[i];
        let (rf, tf) = &frames[i];
        let v = rp * Vector3::from(*m) + tp;
        rf.transpose() * (re.transpose() * (v - te) - tf)
    };
    let mut centres = vec![Vector3::zeros()];
    // The circle with the largest radius over residual: (quality, its points, centre).
    let mut best: Option<(f64, Vec<Vector2<f64>>, Vector2<f64>)> = None;
    let mut rms_all = 0.0;
    for m in &MARKERS_MM {
        let pts: Vec<Vector3<f64>> = (0..n).map(|i| local(i, m)).collect();
        let flat: Vec<Vector2<f64>> = pts.iter().map(|p| p.xy()).collect();
        let (c, r, rms) = fit_circle(&flat);
        rms_all += rms * rms;
        let height = pts.iter().map(|p| p.z).sum::<f64>() / n as f64;
        centres.push(Vector3::new(c.x, c.y, height));
        let quality = r / rms.max(1e-9);
        if best.as_ref().is_none_or(|b| quality > b.0) {
            best = Some((quality, flat, c));
        }
    }
    // Axis through the stylus origin and the centres (SVD of the centred points).
    let mean = centres.iter().sum::<Vector3<f64>>() / centres.len() as f64;
    let m = nalgebra::DMatrix::from_fn(centres.len(), 3, |i, k| centres[i][k] - mean[k]);
    let svd = m.svd(false, true);
    let mut z = svd.v_t.map(|v| Vector3::new(v[(0, 0)], v[(0, 1)], v[(0, 2)])).unwrap_or_else(Vector3::z);
    if z.z < 0.0 {
        z = -z;
    }
    // Eq. 14: the axis in the target frame, averaged over the samples.
    let sum: Vector3<f64> = (0..n).map(|i| targets[i].0.transpose() * (re * (frames[i].0 * z))).sum();
    let axis_in_target = sum.normalize();
    // θ6 origin from the gap in the marker angles around the best circle.
    let (_, flat, c) = best.unwrap_or((0.0, Vec::new(), Vector2::zeros()));
    let angles: Vec<f64> = flat.iter().map(|p| (p.y - c.y).atan2(p.x - c.x)).collect();
    let mut bins = [false; 360];
    for a in &angles {
        bins[((a.to_degrees().rem_euclid(360.0)) as usize).min(359)] = true;
    }
    let (mut gap_start, mut gap_len, mut run_start, mut run) = (0usize, 0usize, 0usize, 0usize);
    for k in 0..720 {
        if !bins[k % 360] {
            if run == 0 {
                run_start = k;
            }
            run += 1;
            if run > gap_len && run <= 360 {
                gap_len = run;
                gap_start = run_start;
            }
        } else {
            run = 0;
        }
    }
    let range_deg = 360.0 - gap_len as f64;
    if range_deg < 90.0 {
        return Err(ReferenceError::TooLittleRoll(range_deg));
    }
    let gap_centre = (gap_start as f64 + gap_len as f64 / 2.0).to_radians();
    let origin = gap_centre + std::f64::consts::PI;
    // The roll turns markers by −θ6 about z (R6 = Rz(−θ6)): θ6 = origin angle − marker angle.
    let roll = angles.iter().map(|a| wrap(origin - a)).collect();
    Ok(OrientationReference {
        axis_in_target,
        roll,
        range_deg,
        circle_rms_mm: (rms_all / MARKERS_MM.len() as f64).sqrt(),
    })
}

fn wrap(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::haptic::kinematics::Device;
    use nalgebra::Rotation3;

    #[test]
    fn circle_fit_recovers_centre_and_radius() {
        let pts: Vec<Vector2<f64>> = (0..40)
            .map(|k| {
                let a = k as f64 * 0.1;
                Vector2::new(3.0 + 20.0 * a.cos(), -7.0 + 20.0 * a.sin())
                    + Vector2::new(0.01 * ((k * 7 % 5) as f64 - 2.0), 0.0)
            })
            .collect();
        let (c, r, rms) = fit_circle(&pts);
        assert!(
            (c - Vector2::new(3.0, -7.0)).norm() < 0.05 && (r - 20.0).abs() < 0.05 && rms < 0.05,
            "{c} {r} {rms}"
        );
    }

    #[test]
    fn recovers_the_stylus_axis_and_roll_origin() {
        let device = Device::omni();
        let eh: Pose =
            (Rotation3::from_euler_angles(0.3, -0.5, 0.9).into_inner(), Vector3::new(200.0, 50.0, 800.0));
        // The target sits on the stylus 40 mm from the HIP, turned against it.
        let mount = Rotation3::from_euler_angles(0.4, 0.2, -0.7).into_inner();
        let mount_offset = Vector3::new(12.0, -5.0, 40.0);
        // Gimbal sensors read 3° and −2° off; the stylus rolls between ±2.6 rad with some wobble.
        let (e4, e5) = (3f64.to_radians(), -2f64.to_radians());
        let (mut targets, mut frames, mut truth_roll) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..400 {
            let s = k as f64 / 400.0;
            let roll = -2.6 + 5.2 * (0.5 - 0.5 * (std::f64::consts::TAU * 2.0 * s).cos());
            let (t4, t5) = (0.2 + 0.03 * (9.0 * s).sin(), -0.1 + 0.02 * (7.0 * s).cos());
            let theta = [0.1, 0.4, 0.3, t4, t5, roll];
            let r_true = device.rotation(&theta);
            let p_hip = device.position_mm(&theta);
            let r_target = eh.0 * r_true * mount;
            let t_target = eh.0 * (p_hip + r_true * mount_offset) + eh.1;
            targets.push((r_target, t_target));
            // The device's own view: θ4, θ5 read with offsets, no roll (HIP′, eq. 12).
            let measured = [0.1, 0.4, 0.3, t4 + e4, t5 + e5, 0.0];
            frames.push((device.rotation(&measured), p_hip));
            truth_roll.push(roll);
        }
        let reference = orientation_reference(&targets, &frames, &eh).unwrap();
        let truth_axis = mount.transpose() * Vector3::z();
        let axis_error_deg = reference.axis_in_target.dot(&truth_axis).clamp(-1.0, 1.0).acos().to_degrees();
        assert!(axis_error_deg < 0.05, "axis off by {axis_error_deg}°");
        assert!((reference.range_deg - 298.0).abs() < 3.0, "range {}", reference.range_deg);
        // θ6 reference agrees with the true roll up to the sensor-frame offset it cannot see.
        let offsets: Vec<f64> = reference.roll.iter().zip(&truth_roll).map(|(a, b)| wrap(a - b)).collect();
        let mean = offsets.iter().sum::<f64>() / offsets.len() as f64;
        let spread = offsets.iter().map(|o| (o - mean).abs()).fold(0.0, f64::max);
        assert!(spread.to_degrees() < 1.0, "roll reference spread {}°", spread.to_degrees());
        assert!(mean.to_degrees().abs() < 1.5, "θ6 origin off by {}°", mean.to_degrees());
        assert!(matches!(
            orientation_reference(&targets[..10], &frames[..10], &eh),
            Err(ReferenceError::TooFewSamples(10))
        ));
    }
}
