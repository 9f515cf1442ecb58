//! Measurement windows: mean, spread and counts of fresh samples, wrap-safe and exact.
//!
//! A window starts empty when requested and takes only samples pushed after that, so nothing
//! buffered before the request leaks in. Per joint the first accepted sample is the reference
//! r; every later sample c enters as its signed shortest distance from r,
//! δ = ((c − r + 2²¹) mod 2²²) − 2²¹, so an encoder sitting at 359.99°/0.01° averages to ~0°.
//! Σδ and Σδ² are exact integers (|δ| ≤ 2²¹ and at most 4096 samples keep Σδ² below 2⁶⁴);
//! mean = r + Σδ/n (mod 2²²). A window in which any joint
//! rejected more than [`MAX_REJECT_PER_1000`]‰ of its samples is flagged, not silently averaged.

use kincal_protocol::biss::COUNTS_PER_TURN;
use kincal_protocol::{
    joints::JOINTS,
    messages::{JointWindow, WindowReport, MAX_REJECT_PER_1000},
};
const HALF_TURN: i64 = (COUNTS_PER_TURN / 2) as i64;

/// Signed shortest distance from `reference` to `counts`, in (−2²¹, 2²¹].
pub fn wrapped_delta(counts: u32, reference: u32) -> i64 {
    let turn = COUNTS_PER_TURN as i64;
    (counts as i64 - reference as i64 + HALF_TURN).rem_euclid(turn) - HALF_TURN
}

#[derive(Clone, Copy, Debug, Default)]
struct JointSums {
    reference: Option<u32>,
    sum: i64,
    sum_sq: u64,
    min: i64,
    max: i64,
    accepted: u16,
    rejected: u16,
}

/// One window being measured.
#[derive(Clone, Debug)]
pub struct Window {
    ticks: u16,
    seen: u16,
    joints: [JointSums; JOINTS],
}

impl Window {
    /// A window over the next `ticks` samples.
    pub fn new(ticks: u16) -> Window {
        Window { ticks, seen: 0, joints: [JointSums::default(); JOINTS] }
    }

    /// Add one tick: `counts` per joint and the mask of joints whose frame was rejected.
    /// Returns the report when the window is complete.
    pub fn push(&mut self, counts: &[u32; JOINTS], rejected: u8) -> Option<WindowReport> {
        for (j, s) in self.joints.iter_mut().enumerate() {
            if rejected & (1 << j) != 0 {
                s.rejected += 1;
                continue;
            }
            let r = *s.reference.get_or_insert(counts[j]);
            let d = wrapped_delta(counts[j], r);
            s.sum += d;
            s.sum_sq += (d * d) as u64;
            s.min = s.min.min(d);
            s.max = s.max.max(d);
            s.accepted += 1;
        }
        self.seen += 1;
        (self.seen >= self.ticks).then(|| self.report())
    }

    fn report(&self) -> WindowReport {
        let mut flagged = false;
        let joints = core::array::from_fn(|j| {
            let s = &self.joints[j];
            let n = s.accepted.max(1) as f64;
            let mean_delta = s.sum as f64 / n;
            // Variance from exact integer sums: (Σδ² − (Σδ)²/n)/n.
            let var = ((s.sum_sq as f64) - (s.sum as f64) * (s.sum as f64) / n) / n;
            let reference = s.reference.unwrap_or(0) as f64;
            let turn = COUNTS_PER_TURN as f64;
            let mut mean = reference + mean_delta;
            mean -= turn * libm::floor(mean / turn);
            let total = (s.accepted as u32 + s.rejected as u32).max(1);
            if s.accepted == 0 || s.rejected as u32 * 1000 > MAX_REJECT_PER_1000 * total {
                flagged = true;
            }
            let rounded = libm::round(mean_delta) as i64;
            JointWindow {
                mean_counts: mean,
                std_counts: libm::sqrt(var.max(0.0)) as f32,
                min_counts: (s.min - rounded).clamp(i32::MIN as i64, 0) as i32,
                max_counts: (s.max - rounded).clamp(0, i32::MAX as i64) as i32,
                accepted: s.accepted,
                rejected: s.rejected,
            }
        });
        WindowReport { ticks: self.ticks, joints, flagged }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn averages_across_the_wrap_to_zero_not_half_a_turn() {
        let top = COUNTS_PER_TURN - 1;
        let mut w = Window::new(4);
        let mut report = None;
        for c in [top, 0, top - 1, 1] {
            report = w.push(&[c; JOINTS], 0);
        }
        let r = report.expect("complete after 4 ticks");
        let m = r.joints[0].mean_counts;
        let distance_to_zero = m.min(COUNTS_PER_TURN as f64 - m);
        assert!(distance_to_zero <= 0.5, "mean {m} counts should sit at the wrap");
        assert!((r.joints[0].std_counts - 1.118).abs() < 1e-3, "{}", r.joints[0].std_counts);
        // Deltas from the first sample: 0, 1, −1, 2; min and max relative to the rounded mean (1).
        assert_eq!((r.joints[0].min_counts, r.joints[0].max_counts), (-2, 1));
        assert!(!r.flagged);
    }

    #[test]
    fn mean_is_exact_over_a_full_window() {
        let mut w = Window::new(1536);
        let mut report = None;
        for k in 0..1536u32 {
            let c = 1_000_000 + (k % 7);
            report = w.push(&[c, c, c, c, c, c], 0);
        }
        let expect = 1_000_000.0 + (0..1536u32).map(|k| (k % 7) as f64).sum::<f64>() / 1536.0;
        assert!((report.unwrap().joints[3].mean_counts - expect).abs() < 1e-9);
    }

    #[test]
    fn rejected_samples_are_counted_excluded_and_flag_the_window() {
        let mut w = Window::new(100);
        let mut report = None;
        for k in 0..100u32 {
            // Joint 2 rejects 5 % of ticks; its rejected ticks carry garbage that must not count.
            let bad = k % 20 == 0;
            let mut counts = [500; JOINTS];
            if bad {
                counts[2] = 3_000_000;
            }
            report = w.push(&counts, if bad { 1 << 2 } else { 0 });
        }
        let r = report.unwrap();
        assert_eq!((r.joints[2].accepted, r.joints[2].rejected), (95, 5));
        assert_eq!(r.joints[2].mean_counts, 500.0);
        assert!(r.flagged, "5 % rejects exceeds the 2 % limit");
        assert_eq!(r.joints[0].rejected, 0);
    }

    #[test]
    fn delta_is_the_shortest_way_round() {
        assert_eq!(wrapped_delta(0, COUNTS_PER_TURN - 1), 1);
        assert_eq!(wrapped_delta(COUNTS_PER_TURN - 1, 0), -1);
        assert_eq!(wrapped_delta(100, 40), 60);
    }
}
