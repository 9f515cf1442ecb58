//! The emulated arm in motion: joint waypoints with times, and the smooth path through them.
//!
//! The emulated controller's encoders follow this path tick by tick ([`counts_at`]); the host
//! evaluates the same path at any instant ([`position_at`]) to know the true motion, e.g. for a
//! simulated optical tracker. Both run the same arithmetic (IEEE f64 add and multiply only), so
//! the counts the host computes for a tick are the counts the emulated encoders reported.
//!
//! Between two waypoints each joint follows a quintic Hermite segment: position and velocity
//! given at both ends, acceleration zero there, so position, velocity and acceleration are
//! continuous along the whole path (C²). The velocity at an inner waypoint is the slope between
//! its neighbours (Catmull–Rom, for uneven times `(p₊ − p₋)/(t₊ − t₋)`), except where the joint
//! turns back at that waypoint (a local extremum): there it is zero, so a joint never overshoots
//! a turning point. The path starts and ends at rest. Times are controller ticks
//! ([`crate::messages::TICK_HZ`]); positions are unwrapped encoder counts (a joint may pass
//! through 0/2²² counts; [`counts_at`] wraps them as the encoder reports them).

use crate::biss::COUNTS_PER_TURN;
use crate::joints::JOINTS;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Most waypoints of one trajectory.
pub const MAX_WAYPOINTS: usize = 32;

/// One waypoint: where every joint is at a time after the trajectory's start.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Waypoint {
    /// Time from the trajectory's start, ticks (strictly increasing along a trajectory).
    pub at_tick: u32,
    /// Joint positions, unwrapped encoder counts (2²² per turn), base to tip.
    pub counts: [i32; JOINTS],
}

/// Velocity of one joint at waypoint `i`, counts per tick.
fn velocity(waypoints: &[Waypoint], i: usize, joint: usize) -> f64 {
    if i == 0 || i + 1 >= waypoints.len() {
        return 0.0;
    }
    let (before, here, after) = (&waypoints[i - 1], &waypoints[i], &waypoints[i + 1]);
    let (p0, p1, p2) = (before.counts[joint] as f64, here.counts[joint] as f64, after.counts[joint] as f64);
    let span = after.at_tick as f64 - before.at_tick as f64;
    if (p1 - p0) * (p2 - p1) <= 0.0 || span <= 0.0 {
        return 0.0; // the joint turns back (or stops) here
    }
    (p2 - p0) / span
}

/// Quintic Hermite basis with zero end accelerations at `s` in [0, 1]: weights of the start
/// position, start velocity·T, end velocity·T and end position.
fn basis(s: f64) -> [f64; 4] {
    let (s2, s3) = (s * s, s * s * s);
    let (s4, s5) = (s3 * s, s3 * s2);
    [
        1.0 - 10.0 * s3 + 15.0 * s4 - 6.0 * s5,
        s - 6.0 * s3 + 8.0 * s4 - 3.0 * s5,
        -4.0 * s3 + 7.0 * s4 - 3.0 * s5,
        10.0 * s3 - 15.0 * s4 + 6.0 * s5,
    ]
}

/// Length of the trajectory, ticks (the last waypoint's time; 0 without waypoints).
pub fn duration_ticks(waypoints: &[Waypoint]) -> u32 {
    waypoints.last().map_or(0, |w| w.at_tick)
}

/// Every joint's position at `t_ticks` after the start (unwrapped counts, not rounded). Before
/// the start the arm is at the first waypoint; after the end at the last one, or, with
/// `repeat`, the path starts again (its first and last waypoints should then be the same pose).
/// Without waypoints every joint is at 0.
pub fn position_at(waypoints: &[Waypoint], t_ticks: f64, repeat: bool) -> [f64; JOINTS] {
    let (Some(first), Some(last)) = (waypoints.first(), waypoints.last()) else {
        return [0.0; JOINTS];
    };
    let period = last.at_tick as f64;
    let t = if repeat && period > 0.0 && t_ticks > period { t_ticks % period } else { t_ticks };
    if t <= first.at_tick as f64 {
        return first.counts.map(|c| c as f64);
    }
    let Some(i) = waypoints.windows(2).position(|w| t < w[1].at_tick as f64) else {
        return last.counts.map(|c| c as f64);
    };
    let (a, b) = (&waypoints[i], &waypoints[i + 1]);
    let span = b.at_tick as f64 - a.at_tick as f64;
    if span <= 0.0 {
        return b.counts.map(|c| c as f64);
    }
    let w = basis((t - a.at_tick as f64) / span);
    core::array::from_fn(|j| {
        w[0] * a.counts[j] as f64
            + w[1] * span * velocity(waypoints, i, j)
            + w[2] * span * velocity(waypoints, i + 1, j)
            + w[3] * b.counts[j] as f64
    })
}

/// The counts the emulated encoders report at tick `t_ticks` after the start: [`position_at`]
/// rounded to the nearest count and wrapped into one turn.
pub fn counts_at(waypoints: &[Waypoint], t_ticks: u32, repeat: bool) -> [u32; JOINTS] {
    position_at(waypoints, t_ticks as f64, repeat).map(|p| {
        let rounded = if p >= 0.0 { (p + 0.5) as i64 } else { (p - 0.5) as i64 };
        rounded.rem_euclid(COUNTS_PER_TURN as i64) as u32
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path() -> [Waypoint; 5] {
        let w = |at_tick, c: i32| Waypoint { at_tick, counts: [c, -c, 2 * c, 0, c / 2, 4_194_000 + c] };
        [w(0, 0), w(768, 100_000), w(1152, 40_000), w(1920, 160_000), w(2304, 160_000)]
    }

    #[test]
    fn the_path_passes_every_waypoint_and_holds_before_and_after() {
        let p = path();
        for w in &p {
            assert_eq!(position_at(&p, w.at_tick as f64, false), w.counts.map(|c| c as f64));
        }
        assert_eq!(position_at(&p, -50.0, false), p[0].counts.map(|c| c as f64));
        assert_eq!(position_at(&p, 1e6, false), p[4].counts.map(|c| c as f64));
        assert_eq!(position_at(&[], 10.0, false), [0.0; JOINTS]);
        // Joint 6 passes through the encoder's wrap: reported counts stay within one turn.
        let c = counts_at(&p, 768, false);
        assert_eq!(c[5], (4_194_000 + 100_000) % COUNTS_PER_TURN);
        assert_eq!(c[1], COUNTS_PER_TURN - 100_000);
    }

    /// Position, velocity and acceleration are continuous (C²) at every waypoint, the velocity
    /// is zero where a joint turns back, and nothing overshoots a turning point.
    #[test]
    fn the_path_is_smooth_and_turns_back_without_overshoot() {
        let p = path();
        let x = |t: f64| position_at(&p, t, false)[0];
        let h = 1e-3;
        for w in &p[1..4] {
            let t = w.at_tick as f64;
            let (v_before, v_after) = ((x(t) - x(t - h)) / h, (x(t + h) - x(t)) / h);
            assert!((v_before - v_after).abs() < 1.0, "velocity jumps at {t}: {v_before} {v_after}");
            let acc = |t: f64| (x(t + h) - 2.0 * x(t) + x(t - h)) / (h * h);
            assert!(acc(t - 0.01).abs() < 2.0 && acc(t + 0.01).abs() < 2.0, "acceleration at {t}");
        }
        // Joint 1 turns back at the waypoints at 768 and 1152 ticks.
        assert!((x(768.5) - x(767.5)).abs() < 0.01, "joint 1 stops where it turns back");
        let max = (0..2304).map(|t| x(t as f64)).fold(f64::MIN, f64::max);
        assert!(max <= 160_000.0 + 1e-6, "overshoot: {max}");
        let dip = (768..1920).map(|t| x(t as f64)).fold(f64::MAX, f64::min);
        assert!((dip - 40_000.0).abs() < 1e-6, "undershoot at the turning point: {dip}");
    }

    #[test]
    fn a_repeated_path_starts_again() {
        let mut p = path();
        p[4].counts = p[0].counts;
        assert_eq!(position_at(&p, 2304.0 + 768.0, true), position_at(&p, 768.0, false));
        assert_eq!(position_at(&p, 2304.0 + 768.0, false), p[4].counts.map(|c| c as f64));
        assert_eq!(duration_ticks(&p), 2304);
    }
}
