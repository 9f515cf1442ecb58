//! The controller's pose stream on the host: every pose frame with its controller tick and the
//! instant the tick was sampled, on the host clock.
//!
//! A pose frame carries its tick (16 bits, wrapping). [`PoseClock`] extends it to the
//! controller's full tick count (from [`Info::ticks`] read before the stream, then by
//! the arrival times, so a gap of more than 65 536 ticks is still counted right) and maps it to
//! the host clock: the sample instant is `tick / 768 Hz + offset`, the offset being the lower
//! envelope of `arrival − tick / 768 Hz` — the frames that crossed the link fastest — allowed to
//! rise by [`MAX_DRIFT_PPM`] between them, so a controller crystal slower than the host's clock
//! is followed too. The stamp is the sampling instant up to the link's fixed minimum delay
//! (the wire time of a frame, 1.15 ms at 460 800 baud, and the serial adapter's), not the host's
//! receive time, whose scheduling jitter it does not carry.
//!
//! [`Info::ticks`]: kincal_protocol::messages::Info::ticks

use crate::controller::igtl_server::PoseServer;
use crate::controller::link::{Link, LinkError};
use kincal_protocol::messages::{PoseReport, Stream, StreamPose, TICK_HZ};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Largest rate difference between the controller's and the host's clocks followed, ppm
/// (crystals are within ±50 ppm; NTP slews the host by at most 500 ppm, mostly far less).
pub const MAX_DRIFT_PPM: f64 = 200.0;

/// A pose frame as the host received it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedPose {
    /// Stream frame counter.
    pub seq: u16,
    /// Controller tick of the sample, counted since the controller started.
    pub tick: u64,
    /// When the tick was sampled, host clock, seconds since 1970.
    pub t_s: f64,
    /// When the frame arrived, host clock, seconds since 1970.
    pub host_s: f64,
    /// The pose as the controller sent it.
    pub report: PoseReport,
}

impl TimedPose {
    /// The tool frame in the base frame: upper three rows of the 4×4 matrix (columns: tool x, y,
    /// z axes, tool point in mm); NaN when the pose is invalid.
    pub fn rows(&self) -> [[f32; 4]; 3] {
        let p = &self.report;
        let (x, z) = (p.x_axis.map(f64::from), p.z_axis.map(f64::from));
        let y = [z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]];
        std::array::from_fn(|r| [x[r] as f32, y[r] as f32, z[r] as f32, p.position_mm[r]])
    }
}

/// Extends pose ticks to the full count and stamps them on the host clock.
pub struct PoseClock {
    /// Host time of `Instant` zero: arrival instants are monotonic, stamps are since 1970.
    epoch: (Instant, f64),
    last: (u64, Instant),
    offset_s: Option<f64>,
    last_arrival: Option<Instant>,
}

impl PoseClock {
    /// A clock for a stream that starts after the controller's `ticks_now` ([`Info::ticks`]).
    ///
    /// [`Info::ticks`]: kincal_protocol::messages::Info::ticks
    pub fn new(ticks_now: u32) -> PoseClock {
        let unix = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
        let now = Instant::now();
        PoseClock { epoch: (now, unix), last: (ticks_now as u64, now), offset_s: None, last_arrival: None }
    }

    /// Host time of `at`, seconds since 1970.
    pub fn host_s(&self, at: Instant) -> f64 {
        self.epoch.1 + at.saturating_duration_since(self.epoch.0).as_secs_f64()
    }

    /// The full tick count of a frame stamped `tick16` that arrived at `at`.
    fn unwrap(&mut self, tick16: u16, at: Instant) -> u64 {
        let (last, last_at) = self.last;
        let step = tick16.wrapping_sub(last as u16) as i64;
        // Turns of the 16-bit counter that the time since the last frame asks for.
        let expected = at.saturating_duration_since(last_at).as_secs_f64() * TICK_HZ as f64;
        let turns = ((expected - step as f64) / 65_536.0).round().max(0.0) as i64;
        let tick = (last as i64 + step + turns * 65_536) as u64;
        self.last = (tick, at);
        tick
    }

    /// Stamp a pose frame `report` (stream counter `seq`) that arrived at `at`.
    pub fn time(&mut self, seq: u16, report: PoseReport, at: Instant) -> TimedPose {
        let tick = self.unwrap(report.tick, at);
        let arrival = self.host_s(at);
        let seen = arrival - tick as f64 / TICK_HZ as f64;
        let offset = match (self.offset_s, self.last_arrival) {
            (Some(offset), Some(before)) => {
                let rise = at.saturating_duration_since(before).as_secs_f64() * MAX_DRIFT_PPM * 1e-6;
                (offset + rise).min(seen)
            }
            _ => seen,
        };
        self.offset_s = Some(offset);
        self.last_arrival = Some(at);
        TimedPose { seq, tick, t_s: tick as f64 / TICK_HZ as f64 + offset, host_s: arrival, report }
    }
}

/// What a pose stream delivered.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamCount {
    /// Pose frames received.
    pub poses: u64,
    /// Of them invalid.
    pub invalid: u64,
    /// Stream frames lost on the link (gaps in the frame counter).
    pub lost: u64,
    /// Corrupt frames dropped by the link.
    pub corrupt: u64,
}

/// What to do next, from the caller's check between frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Keep streaming.
    Go,
    /// Stop the stream.
    Stop,
}

/// Stream the pose every tick from `link` (greeted, parameters stored): stamp every frame, hand
/// it to `server` (the OpenIGTLink clients) and to `on_pose`; between frames (at least every
/// 5 ms) `between` may use the link (e.g. move the emulated arm) and ends the stream. The pose
/// stream is switched off at the end, also after an error.
pub fn stream_poses(
    link: &mut Link,
    server: Option<&PoseServer>,
    mut on_pose: impl FnMut(&TimedPose),
    mut between: impl FnMut(&mut Link, &StreamCount) -> Result<Flow, LinkError>,
) -> Result<StreamCount, LinkError> {
    let ticks_now = link.info()?.ticks;
    let mut clock = PoseClock::new(ticks_now);
    link.call(StreamPose { divider: 1 })?;
    let (lost0, corrupt0) = (link.stats.stream_gaps, link.stats.bad_frames);
    let mut count = StreamCount::default();
    let result = loop {
        match link.next_stream(Duration::from_millis(5)) {
            Ok(Some((seq, Stream::Pose(report)))) => {
                let pose = clock.time(seq, report, Instant::now());
                count.poses += 1;
                count.invalid += !report.valid as u64;
                if let Some(server) = server {
                    server.publish(&pose);
                }
                on_pose(&pose);
            }
            Ok(_) => {}
            Err(e) => break Err(e),
        }
        count.lost = link.stats.stream_gaps - lost0;
        count.corrupt = link.stats.bad_frames - corrupt0;
        match between(link, &count) {
            Ok(Flow::Go) => {}
            Ok(Flow::Stop) => break Ok(count),
            Err(e) => break Err(e),
        }
    };
    // The answer comes after every frame queued before it: a host that fell behind needs longer.
    let stopped = link.call_within(StreamPose { divider: 0 }, Duration::from_secs(10));
    let count = result?;
    stopped?;
    Ok(count)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(tick: u16) -> PoseReport {
        PoseReport {
            tick,
            valid: true,
            fresh: 0x3F,
            stale_ticks: 0,
            position_mm: [1.0, 2.0, 3.0],
            z_axis: [0.0, 0.0, 1.0],
            x_axis: [1.0, 0.0, 0.0],
        }
    }

    /// Ticks wrap at 16 bits; the full count follows them, also across a silence longer than a
    /// turn of the counter.
    #[test]
    fn ticks_are_extended_past_the_16_bit_wrap() {
        let t0 = Instant::now();
        let mut clock = PoseClock::new(65_530);
        let at = |ticks: f64| t0 + Duration::from_secs_f64(ticks / 768.0);
        assert_eq!(clock.time(0, report(65_531), at(1.0)).tick, 65_531);
        assert_eq!(clock.time(1, report(2), at(8.0)).tick, 65_538);
        // 100 000 ticks later (130 s of silence): one more turn than the 16 bits show.
        let far = 65_538 + 100_000;
        assert_eq!(clock.time(2, report(far as u16), at(100_008.0)).tick, far);
    }

    /// The stamp is the sample instant: frames delayed by a varying amount get the stamps of
    /// the fastest ones, and a controller clock 100 ppm slow is followed.
    #[test]
    fn stamps_follow_the_fastest_frames_and_a_slow_controller_clock() {
        let t0 = Instant::now();
        let mut clock = PoseClock::new(0);
        let host0 = clock.host_s(t0);
        let mut worst: f64 = 0.0;
        for k in 1..=30_000u64 {
            // True sample instant: controller time stretched by 100 ppm; the link delays by
            // 1 ms plus up to 4 ms, the fastest frame every 16.
            let sampled = k as f64 / 768.0 * (1.0 + 100e-6);
            let delay = 1e-3 + if k % 16 == 0 { 0.0 } else { 4e-3 * ((k * 7919) % 97) as f64 / 97.0 };
            let pose = clock.time(k as u16, report(k as u16), t0 + Duration::from_secs_f64(sampled + delay));
            if k > 1000 {
                worst = worst.max((pose.t_s - (host0 + sampled + 1e-3)).abs());
            }
        }
        assert!(worst < 0.1e-3, "stamps off the sample instants by {:.3} ms", worst * 1e3);
    }

    #[test]
    fn the_rows_are_the_tool_axes_and_point() {
        let mut p = report(1);
        p.z_axis = [0.0, 1.0, 0.0];
        p.x_axis = [1.0, 0.0, 0.0];
        let pose = TimedPose { seq: 0, tick: 1, t_s: 0.0, host_s: 0.0, report: p };
        // y = z × x = (0,1,0) × (1,0,0) = (0,0,-1).
        assert_eq!(pose.rows(), [[1.0, 0.0, 0.0, 1.0], [0.0, 0.0, 1.0, 2.0], [0.0, -1.0, 0.0, 3.0]]);
    }
}
