//! Time delay between the external tracker and the haptic device.
//!
//! Both streams, in a common frame, are reduced to one signal each (the distance from the
//! device origin), resampled to a 1 ms grid by linear interpolation over their common span,
//! cut into chunks of [`CHUNK_MS`], and for every lag in ±[`MAX_LAG_MS`] the Pearson correlation
//! of each chunk with the other signal shifted by that lag is averaged over the chunks (as in the
//! reference implementation). The best lag is refined below the 1 ms grid by a parabola through
//! the peak and its neighbours. A positive delay means the tracker's samples arrive later than
//! the device's for the same motion.

/// Resampling step, ms.
pub const STEP_MS: f64 = 1.0;
/// Chunk length, ms.
pub const CHUNK_MS: usize = 2000;
/// Largest delay searched, ms.
pub const MAX_LAG_MS: i64 = 200;
/// Smallest standard deviation of the distance signal accepted, mm.
pub const MIN_MOTION_MM: f64 = 2.0;

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
    /// The streams overlap too briefly for one chunk plus the lag window.
    #[error(
        "the streams overlap for {overlap_ms:.0} ms; at least {needed_ms} ms of common motion are needed"
    )]
    TooShort {
        /// Overlap, ms.
        overlap_ms: f64,
        /// Needed, ms.
        needed_ms: usize,
    },
    /// The stylus hardly moved relative to the device origin.
    #[error("too little motion for a delay estimate: the distance from the device origin varies by {std_mm:.2} mm (std); move the stylus towards and away from the device (≥ {MIN_MOTION_MM} mm)")]
    TooLittleMotion {
        /// Standard deviation of the signal, mm.
        std_mm: f64,
    },
}

/// A time series: strictly increasing times (s) and values.
pub struct Signal<'a> {
    /// Name for error messages.
    pub name: &'static str,
    /// Times, seconds.
    pub t_s: &'a [f64],
    /// Values.
    pub value: &'a [f64],
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

/// Estimate by how much `tracker` lags `device`, in milliseconds.
pub fn estimate_delay_ms(device: &Signal, tracker: &Signal) -> Result<f64, DelayError> {
    check(device)?;
    check(tracker)?;
    let needed_ms = CHUNK_MS + 2 * MAX_LAG_MS as usize;
    let start = device.t_s.first().copied().unwrap_or(0.0).max(tracker.t_s.first().copied().unwrap_or(0.0));
    let end = device.t_s.last().copied().unwrap_or(0.0).min(tracker.t_s.last().copied().unwrap_or(0.0));
    let overlap_ms = (end - start) * 1000.0;
    if device.t_s.len() < 2 || tracker.t_s.len() < 2 || overlap_ms < needed_ms as f64 {
        return Err(DelayError::TooShort { overlap_ms: overlap_ms.max(0.0), needed_ms });
    }
    let n = (overlap_ms / STEP_MS) as usize;
    let grid = |s: &Signal| -> Vec<f64> {
        (0..n).map(|k| interpolate(s.t_s, s.value, start + k as f64 * STEP_MS / 1000.0)).collect()
    };
    let (d, t) = (grid(device), grid(tracker));
    let mean = t.iter().sum::<f64>() / n as f64;
    let std_mm = (t.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
    if std_mm < MIN_MOTION_MM {
        return Err(DelayError::TooLittleMotion { std_mm });
    }
    // Chunks of the tracker signal, kept clear of the ends by the lag window.
    let lag_max = MAX_LAG_MS as usize;
    let chunk_starts: Vec<usize> =
        (lag_max..n.saturating_sub(CHUNK_MS + lag_max) + 1).step_by(CHUNK_MS).collect();
    let score = |lag: i64| -> f64 {
        chunk_starts
            .iter()
            .map(|&s| {
                let shifted = (s as i64 - lag) as usize;
                pearson(&t[s..s + CHUNK_MS], &d[shifted..shifted + CHUNK_MS])
            })
            .sum::<f64>()
            / chunk_starts.len() as f64
    };
    let scores: Vec<f64> = (-MAX_LAG_MS..MAX_LAG_MS).map(score).collect();
    let best = scores.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).map_or(0, |b| b.0);
    let lag = best as f64 - MAX_LAG_MS as f64;
    if best == 0 || best + 1 >= scores.len() {
        return Ok(lag * STEP_MS);
    }
    let (a, b, c) = (scores[best - 1], scores[best], scores[best + 1]);
    let denom = a - 2.0 * b + c;
    let offset = if denom.abs() > 1e-15 { 0.5 * (a - c) / denom } else { 0.0 };
    Ok((lag + offset.clamp(-0.5, 0.5)) * STEP_MS)
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
                &Signal { name: "device", t_s: &dev_t, value: &dev_v },
                &Signal { name: "tracker", t_s: &trk_t, value: &trk_v },
            )
            .unwrap();
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
        let s = |name, t_s, value| Signal { name, t_s, value };
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
}
