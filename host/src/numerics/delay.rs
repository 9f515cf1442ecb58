//! Time delay between two streams of the same motion: a device (the reference, densely
//! sampled) and a tracker that may lag it (sparser, with occlusion gaps).
//!
//! Used by the haptic calibration (tracker ↔ PHANToM) and the dynamic validation of a tracker
//! arm (optical tracker ↔ streamed pose). Both streams are reduced to one signal each by the
//! caller (e.g. the distance from the device origin, or the position along the path's main
//! direction after a registration) and put on a 1 ms grid. The tracker stream is cut at its occlusion gaps (never
//! interpolated across one) and its unbroken pieces into chunks of up to [`CHUNK_MS`] (at least
//! [`MIN_CHUNK_MS`]); for every lag in ±[`MAX_LAG_MS`] the Pearson correlation of each chunk with
//! the device signal shifted by that lag is averaged over the chunks, weighted by their length
//! (as in the reference implementation, which uses 2000 ms chunks). The best lag is refined
//! below the 1 ms grid by a parabola through the peak and its neighbours. A positive delay means
//! the tracker's samples arrive later than the device's for the same motion. A peak at the edge
//! of the window or a weak peak is an error, never a result.

/// A gap longer than this many median sample periods is an occlusion: it splits a stream.
pub const SEGMENT_GAP_FACTOR: f64 = 3.0;

/// Unbroken index ranges of increasing times `t_s`, split where a step exceeds `factor` median
/// steps.
pub fn segments(t_s: &[f64], factor: f64) -> Vec<std::ops::Range<usize>> {
    if t_s.len() < 2 {
        return std::iter::once(0..t_s.len()).collect();
    }
    let mut periods: Vec<f64> = t_s.windows(2).map(|w| w[1] - w[0]).collect();
    periods.sort_by(f64::total_cmp);
    let limit = periods[periods.len() / 2] * factor;
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..t_s.len() {
        if t_s[i] - t_s[i - 1] > limit {
            out.push(start..i);
            start = i;
        }
    }
    out.push(start..t_s.len());
    out
}

/// Resampling step, ms.
pub const STEP_MS: f64 = 1.0;
/// Chunk length, ms.
pub const CHUNK_MS: usize = 2000;
/// Shortest chunk used (an unbroken piece of tracker data between occlusions), ms.
pub const MIN_CHUNK_MS: usize = 500;
/// Largest delay searched, ms.
pub const MAX_LAG_MS: i64 = 200;
/// Smallest standard deviation of the distance signal accepted, mm.
pub const MIN_MOTION_MM: f64 = 2.0;
/// Smallest correlation at the peak accepted.
pub const MIN_PEAK_CORRELATION: f64 = 0.9;

/// Why no delay could be estimated.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum DelayError {
    /// Timestamps go backwards or repeat.
    #[error("{stream}: timestamps do not increase at sample {index} ({before} s then {after} s)")]
    NotMonotonic {
        /// Which stream.
        stream: &'static str,
        /// Sample index.
        index: usize,
        /// Time before, s.
        before: f64,
        /// Time after, s.
        after: f64,
    },
    /// Too little unbroken tracker data overlapping the device stream.
    #[error(
        "only {usable_ms:.0} ms of unbroken tracker data (pieces of at least {MIN_CHUNK_MS} ms between occlusions, {MAX_LAG_MS} ms inside the device stream's ends); at least {needed_ms} ms are needed"
    )]
    TooShort {
        /// Usable tracker data, ms.
        usable_ms: f64,
        /// Needed, ms.
        needed_ms: usize,
    },
    /// The signal hardly varies: the motion does not show in it.
    #[error("too little motion for a delay estimate: {what} varies by {std_mm:.2} mm (std), at least {MIN_MOTION_MM} mm are needed")]
    TooLittleMotion {
        /// What the signal is (the tracker's [`Signal::what`]), with advice.
        what: &'static str,
        /// Standard deviation of the signal, mm.
        std_mm: f64,
    },
    /// The best lag is at the edge of the search window.
    #[error("the delay search ended at its window edge ({lag_ms:+.0} ms of ±{MAX_LAG_MS} ms): the tracker is more than {MAX_LAG_MS} ms late or early, or its timestamps are not on the host clock; no delay is reported")]
    AtWindowEdge {
        /// The lag at the edge, ms.
        lag_ms: f64,
    },
    /// No lag makes the two signals agree.
    #[error("no clear correlation peak: the best lag ({lag_ms:+.1} ms) correlates the streams by {correlation:.2} only (≥ {needed} needed); the tracker may be more than {MAX_LAG_MS} ms off, or the streams are not of the same motion")]
    NoClearPeak {
        /// The best lag, ms.
        lag_ms: f64,
        /// Its mean correlation.
        correlation: f64,
        /// The correlation needed.
        needed: f64,
    },
}

/// A time series: strictly increasing times (s) and values.
pub struct Signal<'a> {
    /// Name for error messages.
    pub name: &'static str,
    /// What the values are, for the message when they hardly vary (e.g. "the stylus's distance
    /// from the device origin (move the stylus towards and away from the device)").
    pub what: &'static str,
    /// Times, seconds.
    pub t_s: &'a [f64],
    /// Values.
    pub value: &'a [f64],
}

/// A delay estimate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DelayEstimate {
    /// Tracker behind device, ms.
    pub delay_ms: f64,
    /// Mean correlation at the peak.
    pub correlation: f64,
    /// Tracker data used, ms.
    pub used_ms: f64,
}

fn check(s: &Signal) -> Result<(), DelayError> {
    if let Some(i) =
        s.t_s.windows(2).position(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
    {
        return Err(DelayError::NotMonotonic {
            stream: s.name,
            index: i + 1,
            before: s.t_s[i],
            after: s.t_s[i + 1],
        });
    }
    Ok(())
}

/// Linear interpolation of `s` at time `t` (inside its span).
pub fn interpolate(t_s: &[f64], value: &[f64], t: f64) -> f64 {
    let i = t_s.partition_point(|&x| x <= t).clamp(1, t_s.len() - 1);
    let (t0, t1) = (t_s[i - 1], t_s[i]);
    let w = ((t - t0) / (t1 - t0)).clamp(0.0, 1.0);
    value[i - 1] * (1.0 - w) + value[i] * w
}

fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        ab += dx * dy;
        aa += dx * dx;
        bb += dy * dy;
    }
    if aa > 0.0 && bb > 0.0 {
        ab / (aa * bb).sqrt()
    } else {
        0.0
    }
}

/// A chunk of the tracker signal on the device's 1 ms grid: first grid index, values.
struct Chunk {
    first: usize,
    values: Vec<f64>,
}

/// Estimate by how much `tracker` lags `device`.
pub fn estimate_delay_ms(device: &Signal, tracker: &Signal) -> Result<DelayEstimate, DelayError> {
    estimate_delay_ms_at_least(device, tracker, MIN_PEAK_CORRELATION)
}

/// As [`estimate_delay_ms`], accepting a peak whose mean correlation is at least
/// `min_peak_correlation` (a refinement of a lag already found by other means may accept less
/// than [`MIN_PEAK_CORRELATION`]).
pub fn estimate_delay_ms_at_least(
    device: &Signal,
    tracker: &Signal,
    min_peak_correlation: f64,
) -> Result<DelayEstimate, DelayError> {
    check(device)?;
    check(tracker)?;
    let too_short = |usable_ms: f64| DelayError::TooShort { usable_ms, needed_ms: CHUNK_MS };
    if device.t_s.len() < 2 || tracker.t_s.len() < 2 {
        return Err(too_short(0.0));
    }
    let step_s = STEP_MS / 1000.0;
    let start = device.t_s[0];
    let n = ((device.t_s[device.t_s.len() - 1] - start) / step_s) as usize;
    let d: Vec<f64> =
        (0..n).map(|k| interpolate(device.t_s, device.value, start + k as f64 * step_s)).collect();
    let lag_max = MAX_LAG_MS as usize;
    // Tracker chunks inside unbroken segments, on the device grid, clear of the device ends.
    let mut chunks: Vec<Chunk> = Vec::new();
    for seg in segments(tracker.t_s, SEGMENT_GAP_FACTOR) {
        if seg.len() < 2 {
            continue;
        }
        let (ts, vs) = (&tracker.t_s[seg.clone()], &tracker.value[seg]);
        let first = (((ts[0] - start) / step_s).ceil().max(0.0) as usize).max(lag_max);
        let last = (((ts[ts.len() - 1] - start) / step_s).floor().max(0.0) as usize)
            .min(n.saturating_sub(lag_max + 1));
        let mut k = first;
        while k + MIN_CHUNK_MS <= last + 1 {
            let len = CHUNK_MS.min(last + 1 - k);
            let len = if last + 1 - (k + len) < MIN_CHUNK_MS { last + 1 - k } else { len };
            let values = (k..k + len).map(|g| interpolate(ts, vs, start + g as f64 * step_s)).collect();
            chunks.push(Chunk { first: k, values });
            k += len;
        }
    }
    let used: usize = chunks.iter().map(|c| c.values.len()).sum();
    if used < CHUNK_MS {
        return Err(too_short(used as f64 * STEP_MS));
    }
    let all: Vec<f64> = chunks.iter().flat_map(|c| c.values.iter().copied()).collect();
    let mean = all.iter().sum::<f64>() / all.len() as f64;
    let std_mm = (all.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / all.len() as f64).sqrt();
    if std_mm < MIN_MOTION_MM {
        return Err(DelayError::TooLittleMotion { what: tracker.what, std_mm });
    }
    let score = |lag: i64| -> f64 {
        chunks
            .iter()
            .map(|c| {
                let shifted = (c.first as i64 - lag) as usize;
                pearson(&c.values, &d[shifted..shifted + c.values.len()]) * c.values.len() as f64
            })
            .sum::<f64>()
            / used as f64
    };
    let scores: Vec<f64> = (-MAX_LAG_MS..=MAX_LAG_MS).map(score).collect();
    let best = scores.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).map_or(0, |b| b.0);
    let lag = best as f64 - MAX_LAG_MS as f64;
    if best == 0 || best + 1 >= scores.len() {
        return Err(DelayError::AtWindowEdge { lag_ms: lag * STEP_MS });
    }
    if scores[best] < min_peak_correlation {
        return Err(DelayError::NoClearPeak {
            lag_ms: lag * STEP_MS,
            correlation: scores[best],
            needed: min_peak_correlation,
        });
    }
    let (a, b, c) = (scores[best - 1], scores[best], scores[best + 1]);
    let denom = a - 2.0 * b + c;
    let offset = if denom.abs() > 1e-15 { 0.5 * (a - c) / denom } else { 0.0 };
    Ok(DelayEstimate {
        delay_ms: (lag + offset.clamp(-0.5, 0.5)) * STEP_MS,
        correlation: scores[best],
        used_ms: used as f64 * STEP_MS,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Distance-from-origin signal of a stylus moving smoothly and irregularly.
    fn motion(t: f64) -> f64 {
        150.0 + 40.0 * (1.3 * t).sin() + 25.0 * (2.9 * t + 0.4).sin() + 12.0 * (5.3 * t + 1.1).sin()
    }

    #[test]
    fn recovers_a_delay_below_the_grid_step() {
        for true_ms in [9.0, 13.4, 18.7, -6.2] {
            // Device at 1 kHz with jittered timestamps, tracker at 90 Hz with noise, delayed.
            let dev_t: Vec<f64> =
                (0..30_000).map(|k| k as f64 * 1e-3 + 1e-5 * ((k * 7 % 13) as f64)).collect();
            let dev_v: Vec<f64> = dev_t.iter().map(|&t| motion(t)).collect();
            let trk_t: Vec<f64> = (0..2_700).map(|k| 0.05 + k as f64 / 90.0).collect();
            let trk_v: Vec<f64> = trk_t
                .iter()
                .enumerate()
                .map(|(k, &t)| motion(t - true_ms / 1000.0) + 0.05 * (((k * 31) % 17) as f64 - 8.0) / 8.0)
                .collect();
            let got = estimate_delay_ms(
                &Signal { name: "device", what: "x", t_s: &dev_t, value: &dev_v },
                &Signal { name: "tracker", what: "x", t_s: &trk_t, value: &trk_v },
            )
            .unwrap()
            .delay_ms;
            assert!((got - true_ms).abs() < 0.25, "true {true_ms} ms, estimated {got} ms");
        }
    }

    #[test]
    fn bad_streams_give_clear_errors() {
        let t: Vec<f64> = (0..5000).map(|k| k as f64 * 1e-3).collect();
        let v: Vec<f64> = t.iter().map(|&x| motion(x)).collect();
        let still = vec![150.0; t.len()];
        let mut back = t.clone();
        back[100] = back[99];
        let s = |name, t_s, value| Signal { name, what: "x", t_s, value };
        assert!(matches!(
            estimate_delay_ms(&s("device", &back, &v), &s("tracker", &t, &v)),
            Err(DelayError::NotMonotonic { stream: "device", index: 100, .. })
        ));
        assert!(matches!(
            estimate_delay_ms(&s("device", &t, &still), &s("tracker", &t, &still)),
            Err(DelayError::TooLittleMotion { .. })
        ));
        assert!(matches!(
            estimate_delay_ms(&s("device", &t[..1000], &v[..1000]), &s("tracker", &t[..1000], &v[..1000])),
            Err(DelayError::TooShort { .. })
        ));
    }

    #[test]
    fn occlusions_are_skipped_and_a_delay_beyond_the_window_is_refused() {
        let dev_t: Vec<f64> = (0..30_000).map(|k| k as f64 * 1e-3).collect();
        let dev_v: Vec<f64> = dev_t.iter().map(|&t| motion(t)).collect();
        let tracker = |true_ms: f64| -> (Vec<f64>, Vec<f64>) {
            // 90 Hz with an occlusion of 50–450 ms every 1.7 s; a wrong value would show if
            // anything were interpolated across a gap (the values jump there).
            let t: Vec<f64> = (0..2_700)
                .map(|k| 0.05 + k as f64 / 90.0)
                .filter(|t| (t % 1.7) > 0.05 + 0.4 * ((t / 1.7).floor() * 0.37).fract())
                .collect();
            let v = t.iter().map(|&x| motion(x - true_ms / 1000.0)).collect();
            (t, v)
        };
        let (t, v) = tracker(11.6);
        let got = estimate_delay_ms(
            &Signal { name: "device", what: "x", t_s: &dev_t, value: &dev_v },
            &Signal { name: "tracker", what: "x", t_s: &t, value: &v },
        )
        .unwrap();
        assert!((got.delay_ms - 11.6).abs() < 0.25, "{got:?}");
        let lost_ms: f64 = t.windows(2).map(|w| w[1] - w[0]).filter(|d| *d > 0.03).sum::<f64>() * 1000.0;
        assert!(lost_ms > 3000.0 && got.used_ms < 30_000.0 - lost_ms, "the gaps are not used: {got:?}");
        let (t, v) = tracker(450.0);
        let err = estimate_delay_ms(
            &Signal { name: "device", what: "x", t_s: &dev_t, value: &dev_v },
            &Signal { name: "tracker", what: "x", t_s: &t, value: &v },
        )
        .unwrap_err();
        assert!(matches!(err, DelayError::AtWindowEdge { .. } | DelayError::NoClearPeak { .. }), "{err}");
    }
}
