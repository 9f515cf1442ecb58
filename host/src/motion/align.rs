//! Temporal alignment of a reference tracker's recording with the arm's pose stream.
//!
//! 1. Coarse: the tool's speed is the same in any frame, so before anything is registered the
//!    two speed profiles (on a 10 ms grid, speed over ±25 ms) are correlated for every lag that
//!    leaves an overlap of half the shorter recording: the tracker's clock may have any epoch
//!    (a motion repeated exactly is ambiguous by its period).
//! 2. The shared delay estimator ([`crate::numerics::delay`], also the haptic calibration's)
//!    refines it on the speeds, to a few milliseconds.
//! 3. Fine, in the arm's frame: the tracker is registered to the arm (Horn) at the present lag;
//!    then, window by window ([`WINDOW_S`]), the time shift δ that best explains what is left
//!    is the least-squares solution of `q_k − p(t_k) ≈ v(t_k)·δ` (p, v: the arm's position and
//!    velocity at the sample's arm time t_k, q_k: the registered tracker position), with
//!    information Σ|v|². A line through the windows' lags, weighted by that information, gives
//!    the clock offset and its drift; register again and repeat until it settles. Their 95 %
//!    uncertainty is the larger of the windows' scatter about the line (Student's t) and what
//!    the residual noise alone allows.
//!
//! Run on the tracker's own timestamps it gives its clock against the arm's sample instants.

use crate::numerics::delay::{estimate_delay_ms_at_least, segments, DelayError, Signal, SEGMENT_GAP_FACTOR};
use crate::numerics::stats::t_upper_tail;
use nalgebra::{Matrix3, Vector3};

/// Window of the fine alignment, s.
pub const WINDOW_S: f64 = 2.0;
/// Fewest tracker samples in a window for its lag.
const MIN_WINDOW_SAMPLES: usize = 20;
/// Least RMS speed in a window for its lag, mm/s.
pub const MIN_WINDOW_SPEED_MM_S: f64 = 20.0;
/// Half-width of the arm's velocity in the fine alignment, s.
pub const VELOCITY_HALF_S: f64 = 0.005;
/// Grid of the coarse search, s.
const COARSE_STEP_S: f64 = 0.01;
/// Half-width of the speed's central difference, s.
const SPEED_HALF_S: f64 = 0.05;
/// Smallest mean correlation of the speeds accepted when refining the coarse lag. Lower than a
/// lag found from nothing ([`crate::numerics::delay::MIN_PEAK_CORRELATION`]): the coarse
/// alignment has already found the peak, the tracker's speed is the derivative of a noisy
/// 60–120 Hz position over ±50 ms, and the chunks where the arm rests correlate at noise level.
const REFINE_MIN_CORRELATION: f64 = 0.75;
/// Least overlap of the two recordings in the coarse search, s.
const MIN_OVERLAP_S: f64 = 3.0;

/// Why the recordings could not be aligned.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// The recordings do not overlap long enough with motion in both.
    #[error("the two recordings share no stretch of motion of half the shorter one ({MIN_OVERLAP_S} s or more) at any lag: are they of the same motion, recorded at the same time?")]
    NoOverlap,
    /// Too few windows gave a lag.
    #[error("only {windows} windows of {WINDOW_S} s gave a lag ({why}); at least 3 are needed for a lag with its uncertainty: record longer, with motion throughout")]
    TooFewWindows {
        /// Windows that gave a lag.
        windows: usize,
        /// Why the others did not.
        why: String,
    },
    /// The delay estimator refused the speeds.
    #[error("aligning the speeds: {0}")]
    Delay(#[from] DelayError),
}

/// A sampled path: positions at times, split into unbroken segments at gaps.
pub struct Path<'a> {
    t: &'a [f64],
    p: &'a [[f64; 3]],
    /// Segment number of every sample.
    segment: Vec<usize>,
}

impl<'a> Path<'a> {
    /// The path of positions `p` at times `t` (increasing).
    pub fn new(t: &'a [f64], p: &'a [[f64; 3]]) -> Path<'a> {
        let mut segment = vec![0; t.len()];
        for (k, range) in segments(t, SEGMENT_GAP_FACTOR).into_iter().enumerate() {
            segment[range].fill(k);
        }
        Path { t, p, segment }
    }

    /// Position at `t`, linear between samples of one segment; None in a gap or outside.
    pub fn at(&self, t: f64) -> Option<Vector3<f64>> {
        let i = self.t.partition_point(|&x| x <= t);
        if i == 0 || i >= self.t.len() {
            return (i > 0 && self.t.last() == Some(&t)).then(|| Vector3::from(self.p[self.p.len() - 1]));
        }
        if self.segment[i - 1] != self.segment[i] {
            return None;
        }
        let w = (t - self.t[i - 1]) / (self.t[i] - self.t[i - 1]);
        Some(Vector3::from(self.p[i - 1]) * (1.0 - w) + Vector3::from(self.p[i]) * w)
    }

    /// Velocity at `t` (mm/s), central difference over ±`half` s.
    pub fn velocity(&self, t: f64, half: f64) -> Option<Vector3<f64>> {
        Some((self.at(t + half)? - self.at(t - half)?) / (2.0 * half))
    }

    /// Acceleration at `t` (mm/s²), second difference over ±`half` s.
    pub fn acceleration(&self, t: f64, half: f64) -> Option<Vector3<f64>> {
        Some((self.at(t + half)? - 2.0 * self.at(t)? + self.at(t - half)?) / (half * half))
    }

    /// First and last time.
    pub fn span(&self) -> (f64, f64) {
        (self.t[0], self.t[self.t.len() - 1])
    }
}

/// Speed on a grid from `start` with step [`COARSE_STEP_S`] (NaN where undefined).
fn speed_grid(path: &Path, start: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| path.velocity(start + k as f64 * COARSE_STEP_S, SPEED_HALF_S).map_or(f64::NAN, |v| v.norm()))
        .collect()
}

/// The coarse lag (tracker time − arm time for the same motion, s) from the speed profiles.
pub fn coarse_lag(arm: &Path, tracker: &Path) -> Result<f64, AlignError> {
    let ((a0, a1), (t0, t1)) = (arm.span(), tracker.span());
    let na = ((a1 - a0) / COARSE_STEP_S) as usize;
    let nt = ((t1 - t0) / COARSE_STEP_S) as usize;
    let sa = speed_grid(arm, a0, na);
    let st = speed_grid(tracker, t0, nt);
    // At least half the shorter recording must overlap: a motion that repeats would otherwise
    // also match one period off.
    let min_pairs = ((MIN_OVERLAP_S / COARSE_STEP_S) as usize).max(na.min(nt) / 2);
    // Tracker grid point j pairs with arm grid point j + shift.
    let (lo, hi) = (-(nt as i64), na as i64);
    let mut best: Option<(f64, i64)> = None;
    for shift in lo..=hi {
        let (mut n, mut sx, mut sy, mut sxx, mut syy, mut sxy) = (0usize, 0.0, 0.0, 0.0, 0.0, 0.0);
        let j0 = (-shift).max(0) as usize;
        let j1 = (na as i64 - shift).min(nt as i64).max(0) as usize;
        for j in j0..j1 {
            let (x, y) = (st[j], sa[(j as i64 + shift) as usize]);
            if x.is_nan() || y.is_nan() {
                continue;
            }
            n += 1;
            sx += x;
            sy += y;
            sxx += x * x;
            syy += y * y;
            sxy += x * y;
        }
        if n < min_pairs {
            continue;
        }
        let nf = n as f64;
        let (vx, vy) = (sxx - sx * sx / nf, syy - sy * sy / nf);
        if vx <= 0.0 || vy <= 0.0 {
            continue;
        }
        let r = (sxy - sx * sy / nf) / (vx * vy).sqrt();
        if best.is_none_or(|(b, _)| r > b) {
            best = Some((r, shift));
        }
    }
    let (r, shift) = best.ok_or(AlignError::NoOverlap)?;
    if r < 0.5 {
        return Err(AlignError::NoOverlap);
    }
    // Tracker time t0 + j·step is arm time a0 + (j + shift)·step.
    Ok(t0 - a0 - shift as f64 * COARSE_STEP_S)
}

/// The speed-based refinement of a coarse lag, s.
pub fn refine_on_speed(arm: &Path, tracker: &Path, lag_s: f64) -> Result<f64, AlignError> {
    let speed = |path: &Path, t: &[f64], shift: f64| -> (Vec<f64>, Vec<f64>) {
        t.iter().filter_map(|&t| path.velocity(t, SPEED_HALF_S).map(|v| (t - shift, v.norm()))).unzip()
    };
    let (at, av) = speed(arm, arm.t, 0.0);
    let (tt, tv) = speed(tracker, tracker.t, lag_s);
    let est = estimate_delay_ms_at_least(
        &Signal { name: "arm pose", what: "the tool's speed (mm/s)", t_s: &at, value: &av },
        &Signal { name: "tracker", what: "the tool's speed (mm/s)", t_s: &tt, value: &tv },
        REFINE_MIN_CORRELATION,
    )?;
    Ok(lag_s + est.delay_ms / 1000.0)
}

/// Rigid transform (R, t) taking tracker positions at `times` (already on the arm's clock) to
/// the arm's positions there, over the samples the arm has a position for.
pub fn register(
    arm: &Path,
    tracker_p: &[[f64; 3]],
    arm_times: &[f64],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let (from, to): (Vec<Vector3<f64>>, Vec<Vector3<f64>>) = arm_times
        .iter()
        .zip(tracker_p)
        .filter_map(|(&t, q)| arm.at(t).map(|p| (Vector3::from(*q), p)))
        .unzip();
    (from.len() >= 10).then(|| crate::numerics::geometry::absolute_orientation(&from, &to))
}

/// One window's lag.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct WindowLag {
    /// Window centre (information-weighted), arm time, s.
    pub at_s: f64,
    /// Lag there, ms.
    pub lag_ms: f64,
    /// Its standard uncertainty from the residual noise, ms.
    pub sd_ms: f64,
}

/// A lag that may drift: `lag(t) = lag_ms + drift·(t − at_s)`, t the arm's time.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct LagLine {
    /// Reference time (the windows' weighted mean centre), arm time, s.
    pub at_s: f64,
    /// Lag at `at_s`, ms.
    pub lag_ms: f64,
    /// Its 95 % uncertainty, ms.
    pub lag_u95_ms: f64,
    /// Drift of the lag, ppm (µs per s).
    pub drift_ppm: f64,
    /// Its 95 % uncertainty, ppm.
    pub drift_u95_ppm: f64,
    /// The windows' lags.
    pub windows: Vec<WindowLag>,
}

impl LagLine {
    /// A constant lag of `lag_s`, not yet measured (no uncertainty, no windows).
    pub fn constant(lag_s: f64) -> LagLine {
        LagLine {
            at_s: 0.0,
            lag_ms: lag_s * 1000.0,
            lag_u95_ms: f64::INFINITY,
            drift_ppm: 0.0,
            drift_u95_ppm: f64::INFINITY,
            windows: Vec::new(),
        }
    }

    /// The lag at arm time `t`, s.
    pub fn lag_s(&self, t: f64) -> f64 {
        self.lag_ms / 1000.0 + self.drift_ppm * 1e-6 * (t - self.at_s)
    }

    /// 95 % uncertainty of the lag at arm time `t`, ms.
    pub fn lag_u95_at_ms(&self, t: f64) -> f64 {
        self.lag_u95_ms.hypot(self.drift_u95_ppm * 1e-3 * (t - self.at_s))
    }

    /// The arm time of a tracker stamp `tau` (inverse of `tau = t + lag(t)`).
    pub fn arm_time(&self, tau: f64) -> f64 {
        let b = self.drift_ppm * 1e-6;
        (tau - self.lag_ms / 1000.0 + b * self.at_s) / (1.0 + b)
    }
}

/// Two-sided 95 % quantile of Student's t with `dof` degrees of freedom.
pub fn t95(dof: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, 100.0);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if t_upper_tail(mid, dof) > 0.025 {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Sums of one window's least-squares time shift.
#[derive(Clone, Copy, Default)]
struct WindowSums {
    /// Samples.
    n: usize,
    /// Σ v·r (mm²/s).
    vr: f64,
    /// Σ |v|² (mm²/s²): the information on the shift.
    vv: f64,
    /// Σ |r|² (mm²).
    rr: f64,
    /// Σ t·|v|² (for the weighted centre).
    tvv: f64,
}

/// The lag of the tracker's `stamps` behind the arm, from the registered tracker positions
/// `registered` (the arm's frame), window by window around the present `guess`.
pub fn lag_line(
    arm: &Path,
    stamps: &[f64],
    registered: &[Vector3<f64>],
    guess: &LagLine,
) -> Result<LagLine, AlignError> {
    let times: Vec<f64> = stamps.iter().map(|&tau| guess.arm_time(tau)).collect();
    let (first, last) = (times[0], times[times.len() - 1]);
    let count = ((last - first) / WINDOW_S).floor().max(1.0) as usize;
    let width = (last - first) / count as f64;
    let mut sums = vec![WindowSums::default(); count];
    for (&t, q) in times.iter().zip(registered) {
        let (Some(p), Some(v)) = (arm.at(t), arm.velocity(t, VELOCITY_HALF_S)) else { continue };
        let r = q - p;
        let w = &mut sums[(((t - first) / width) as usize).min(count - 1)];
        w.n += 1;
        w.vr += v.dot(&r);
        w.vv += v.norm_squared();
        w.rr += r.norm_squared();
        w.tvv += t * v.norm_squared();
    }
    let mut windows = Vec::new();
    let mut still = 0;
    for w in &sums {
        let moving = w.n >= MIN_WINDOW_SAMPLES && (w.vv / w.n.max(1) as f64).sqrt() >= MIN_WINDOW_SPEED_MM_S;
        if !moving {
            still += 1;
            continue;
        }
        // q ≈ p(t + δ): the sample is δ later on the arm's clock than the guess puts it.
        let delta = w.vr / w.vv;
        let residual = ((w.rr - delta * w.vr) / (3 * w.n - 1) as f64).max(0.0);
        let at = w.tvv / w.vv;
        windows.push(WindowLag {
            at_s: at,
            lag_ms: (guess.lag_s(at) - delta) * 1000.0,
            sd_ms: (residual / w.vv).sqrt() * 1000.0,
        });
    }
    if windows.len() < 3 {
        return Err(AlignError::TooFewWindows {
            windows: windows.len(),
            why: format!("{still} of {count} had too little motion (rms speed under {MIN_WINDOW_SPEED_MM_S} mm/s) or too few samples"),
        });
    }
    Ok(weighted_line(windows))
}

/// The information-weighted line through the windows' lags.
fn weighted_line(windows: Vec<WindowLag>) -> LagLine {
    let weight = |w: &WindowLag| 1.0 / (w.sd_ms * w.sd_ms).max(1e-18);
    let sw: f64 = windows.iter().map(weight).sum();
    let mean_t = windows.iter().map(|w| weight(w) * w.at_s).sum::<f64>() / sw;
    let mean_l = windows.iter().map(|w| weight(w) * w.lag_ms).sum::<f64>() / sw;
    let sxx: f64 = windows.iter().map(|w| weight(w) * (w.at_s - mean_t).powi(2)).sum();
    let sxy: f64 = windows.iter().map(|w| weight(w) * (w.at_s - mean_t) * (w.lag_ms - mean_l)).sum();
    let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 }; // ms per s
    let n = windows.len() as f64;
    let chi2: f64 =
        windows.iter().map(|w| weight(w) * (w.lag_ms - mean_l - slope * (w.at_s - mean_t)).powi(2)).sum();
    // The scatter's scale, never below what the noise alone gives (scale 1).
    let scale = (chi2 / (n - 2.0)).max(1.0);
    let t = t95(n - 2.0);
    LagLine {
        at_s: mean_t,
        lag_ms: mean_l,
        lag_u95_ms: t * (scale / sw).sqrt(),
        drift_ppm: slope * 1e3,
        drift_u95_ppm: t * (scale / sxx).sqrt() * 1e3,
        windows,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wandering path (mm) at time t (s).
    fn path_at(t: f64) -> [f64; 3] {
        [
            100.0 * (0.7 * t).sin() + 20.0 * (2.3 * t).sin(),
            60.0 * (1.1 * t + 0.5).sin(),
            30.0 * (0.4 * t).cos() + 10.0 * (3.1 * t).sin(),
        ]
    }

    #[test]
    fn the_speed_profiles_find_a_lag_of_any_size() {
        let arm_t: Vec<f64> = (0..30_000).map(|k| 100.0 + k as f64 / 768.0).collect();
        let arm_p: Vec<[f64; 3]> = arm_t.iter().map(|&t| path_at(t)).collect();
        // The tracker at 60 Hz, its clock 4321.0123 s ahead, rotated by 90° about z.
        let lag = 4321.0123;
        let trk_t: Vec<f64> = (0..2000).map(|k| 100.0 + lag + 2.0 + k as f64 / 60.0).collect();
        let trk_p: Vec<[f64; 3]> = trk_t
            .iter()
            .map(|&t| {
                let p = path_at(t - lag);
                [-p[1], p[0], p[2]]
            })
            .collect();
        let (arm, trk) = (Path::new(&arm_t, &arm_p), Path::new(&trk_t, &trk_p));
        let coarse = coarse_lag(&arm, &trk).unwrap();
        assert!((coarse - lag).abs() < 0.02, "{coarse}");
        let fine = refine_on_speed(&arm, &trk, coarse).unwrap();
        assert!((fine - lag).abs() < 0.5e-3, "{fine}");
    }

    #[test]
    fn the_t_quantile_is_right() {
        assert!((t95(1.0) - 12.706).abs() < 1e-3);
        assert!((t95(10.0) - 2.228).abs() < 1e-3);
        assert!((t95(1e6) - 1.960).abs() < 1e-3);
    }
}
