//! A simulated optical tracker watching the emulated arm's tool while it moves.
//!
//! The truth is computed apart from kincal's kinematics: the trajectory's joint angles at any
//! instant ([`kincal_protocol::trajectory::position_at`], what the emulated encoders follow) go
//! through the true arm's plain-matrix forward kinematics ([`super::reference_tool_frame`]).
//! The true tool also flexes under acceleration, as a hand-guided link does: its point lags by
//! [`OpticalOptions::flex_mm_per_m_s2`] per m/s² (opposite to the acceleration), which the
//! encoders cannot see.
//!
//! The tracker samples at its own rate on its own clock (reading `t + offset + drift·(t − start)`
//! at host time `t`),
//! sees the tool in its own frame with Gaussian noise per axis, loses it during occlusions, and
//! delivers each sample to the host `latency` (± jitter) after it was taken; both the tracker's
//! stamp (`t_s`) and the arrival on the host clock (`host_s`) are recorded.
//!
//! Times: the arm's controller samples tick `k` at host time `anchor_s + k / tick_hz` (what
//! `kincal stream` stamps; `tick_hz` is 768 Hz on the controller's crystal, as measured on the
//! host's clock); the trajectory's time 0 is tick `start_tick`.

use super::reference_tool_frame;
use crate::model::{ArmModel, SUTA_JOINTS};
use kincal_protocol::biss::counts_to_deg;
use kincal_protocol::trajectory::{position_at, Waypoint};
use nalgebra::{Rotation3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// How the simulated tracker behaves.
#[derive(Clone, Debug, PartialEq)]
pub struct OpticalOptions {
    /// Sample rate, Hz (optical trackers: 60–120).
    pub rate_hz: f64,
    /// Time from a sample to its arrival on the host, ms (5–20).
    pub latency_ms: f64,
    /// Standard deviation of the arrival time around it, ms.
    pub latency_jitter_ms: f64,
    /// The tracker's clock reading minus the host's at the recording's start, s.
    pub clock_offset_s: f64,
    /// The tracker's clock rate error, ppm.
    pub drift_ppm: f64,
    /// Position noise, standard deviation per axis, mm (0.1–0.25).
    pub noise_mm: f64,
    /// Occlusions per minute (each 0.1–0.6 s).
    pub occlusions_per_min: f64,
    /// The true tool point's lag under acceleration, mm per m/s².
    pub flex_mm_per_m_s2: f64,
    /// Seed of the noise, sample jitter and occlusions.
    pub seed: u64,
}

impl Default for OpticalOptions {
    fn default() -> Self {
        OpticalOptions {
            rate_hz: 60.0,
            latency_ms: 12.0,
            latency_jitter_ms: 0.3,
            clock_offset_s: 3.7,
            drift_ppm: 40.0,
            noise_mm: 0.15,
            occlusions_per_min: 6.0,
            flex_mm_per_m_s2: 0.2,
            seed: 1,
        }
    }
}

/// The moving arm as the tracker sees it: truth arm, trajectory and timing.
pub struct MovingArm<'a> {
    /// The true arm.
    pub truth: &'a ArmModel,
    /// The trajectory the encoders follow.
    pub waypoints: &'a [Waypoint],
    /// Whether it repeats.
    pub repeat: bool,
    /// Controller tick of the trajectory's time 0.
    pub start_tick: u32,
    /// Host time of controller tick 0, s.
    pub anchor_s: f64,
    /// The controller's tick rate on the host's clock, Hz.
    pub tick_hz: f64,
}

impl MovingArm<'_> {
    /// The joints' encoder angles at host time `t`, degrees.
    pub fn angles_deg(&self, t: f64) -> [f64; SUTA_JOINTS] {
        let ticks = (t - self.anchor_s) * self.tick_hz - self.start_tick as f64;
        let counts = position_at(self.waypoints, ticks.max(0.0), self.repeat);
        std::array::from_fn(|j| counts_to_deg(counts[j]))
    }

    /// Where the encoders put the tool at host time `t` (the rigid true arm), mm.
    pub fn rigid_point(&self, t: f64) -> Vector3<f64> {
        reference_tool_frame(self.truth, &self.angles_deg(t)).0.fixed_view::<3, 1>(0, 3).into_owned()
    }

    /// The true tool point at host time `t` with the link's flex under acceleration, mm.
    pub fn true_point(&self, t: f64, flex_mm_per_m_s2: f64) -> Vector3<f64> {
        let h = 0.004;
        let p = self.rigid_point(t);
        if flex_mm_per_m_s2 == 0.0 {
            return p;
        }
        let a_m_s2 = (self.rigid_point(t + h) - 2.0 * p + self.rigid_point(t - h)) / (h * h) / 1000.0;
        p - a_m_s2 * flex_mm_per_m_s2
    }
}

/// One tracker sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OpticalSample {
    /// The tracker's timestamp (its clock), s.
    pub t_s: f64,
    /// Arrival on the host, host clock, s.
    pub host_s: f64,
    /// When it was truly taken, host clock, s.
    pub taken_s: f64,
    /// Position in the tracker's frame, mm.
    pub p: [f64; 3],
}

/// The tracker's frame: where it stands relative to the arm's base (1.6 m away, looking back).
pub fn tracker_from_base() -> (Rotation3<f64>, Vector3<f64>) {
    (Rotation3::from_euler_angles(0.3, -0.2, 2.6), Vector3::new(250.0, -1600.0, 900.0))
}

/// Record the moving arm from host time `from` to `to`.
pub fn record(arm: &MovingArm, from: f64, to: f64, o: &OpticalOptions) -> Vec<OpticalSample> {
    let mut rng = ChaCha8Rng::seed_from_u64(o.seed);
    let noise =
        Normal::new(0.0, o.noise_mm.max(0.0)).unwrap_or(Normal::new(0.0, 0.0).expect("zero is valid"));
    let jitter = Normal::new(0.0, o.latency_jitter_ms.max(0.0) / 1000.0)
        .unwrap_or(Normal::new(0.0, 0.0).expect("zero is valid"));
    let (rot, shift) = tracker_from_base();
    // Occlusions: random intervals.
    let minutes = (to - from) / 60.0;
    let occlusions: Vec<(f64, f64)> = (0..(o.occlusions_per_min * minutes).round() as usize)
        .map(|_| {
            let at = from + rng.random::<f64>() * (to - from);
            (at, at + 0.1 + 0.5 * rng.random::<f64>())
        })
        .collect();
    let drift = o.drift_ppm * 1e-6;
    let clock = |t: f64| t + o.clock_offset_s + drift * (t - from);
    let (first, last) = ((clock(from) * o.rate_hz).ceil() / o.rate_hz, clock(to));
    let mut out: Vec<OpticalSample> = Vec::new();
    let mut k = 0u64;
    loop {
        let stamp = first + k as f64 / o.rate_hz;
        k += 1;
        if stamp > last {
            break;
        }
        let taken = (stamp - o.clock_offset_s + drift * from) / (1.0 + drift);
        if occlusions.iter().any(|(a, b)| (*a..*b).contains(&taken)) {
            continue;
        }
        let p = rot * arm.true_point(taken, o.flex_mm_per_m_s2) + shift;
        let p = [p.x + noise.sample(&mut rng), p.y + noise.sample(&mut rng), p.z + noise.sample(&mut rng)];
        let mut host = taken + o.latency_ms / 1000.0 + jitter.sample(&mut rng);
        if let Some(before) = out.last() {
            host = host.max(before.host_s + 1e-6);
        }
        out.push(OpticalSample { t_s: stamp, host_s: host, taken_s: taken, p });
    }
    out
}
