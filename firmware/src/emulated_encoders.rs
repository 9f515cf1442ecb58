//! Emulated encoders behind the same SPI trait as the real ones: the SLO bit stream of six
//! BiSS-C encoders at a pose the host sets, or moving along a trajectory the host sends
//! ([`kincal_protocol::trajectory`]), with noise and injected faults (CRC errors,
//! dropouts, error and warning bits, unplugged joints, a hang). Each encoder is a
//! [`kincal_biss_slave::Slave`], the slave model written from the BiSS-C description: its ACK
//! starts after the second MA edge, lasts 1 to 8 bits, and joint j's line delays it by
//! j mod 3 bits, so the decoder's compensation runs on every read. The emulated board and the
//! host tests read them through [`crate::biss_master::BissMaster`], exactly as the real board
//! reads its encoders.

use crate::biss_master::TRANSFER_BYTES;
use core::cell::RefCell;
use core::convert::Infallible;
use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embedded_hal_async::spi::{ErrorType, Operation, SpiDevice};
use kincal_biss_slave::{Line, Slave};
use kincal_protocol::biss::COUNTS_PER_TURN;
use kincal_protocol::joints::JOINTS;
use kincal_protocol::messages::{Crash, Request, SimFaults, SimPlay, SimSetPose, SimWaypoint, TICK_HZ};
use kincal_protocol::trajectory::{counts_at, Waypoint, MAX_WAYPOINTS};

/// The trajectory being followed: waypoints `0..len` of the stored ones, time 0 at `start_tick`.
#[derive(Clone, Copy)]
struct Playing {
    len: usize,
    start_tick: u32,
    repeat: bool,
}

/// The six emulated encoders' state.
///
/// Their clock is the controller's tick: every read of joint 1 starts a new tick (the master
/// reads all joints once per tick, base first), so the sample of controller tick `k` (counted
/// from 1 since boot, as [`kincal_protocol::messages::Info::ticks`]) is the trajectory's
/// position at `k − start_tick`.
pub struct EmulatedEncoders {
    counts: [u32; JOINTS],
    tick: u32,
    waypoints: [Waypoint; MAX_WAYPOINTS],
    playing: Option<Playing>,
    noise_counts: u16,
    crc_errors: u16,
    dropouts: u16,
    error_bits: u16,
    warnings: u16,
    unplugged: u8,
    hang: bool,
    rng: u32,
}

impl Default for EmulatedEncoders {
    fn default() -> Self {
        Self::new()
    }
}

impl EmulatedEncoders {
    /// Encoders at zero, no noise, no faults.
    pub const fn new() -> Self {
        EmulatedEncoders {
            counts: [0; JOINTS],
            tick: 0,
            waypoints: [Waypoint { at_tick: 0, counts: [0; JOINTS] }; MAX_WAYPOINTS],
            playing: None,
            noise_counts: 0,
            crc_errors: 0,
            dropouts: 0,
            error_bits: 0,
            warnings: 0,
            unplugged: 0,
            hang: false,
            rng: 0x1234_5678,
        }
    }

    /// Apply a simulation request ([`Request::SimSetPose`], [`Request::SimFaults`]).
    pub fn apply(&mut self, request: &Request) {
        match *request {
            Request::SimSetPose(SimSetPose { counts }) => {
                self.counts = counts.map(|c| c % COUNTS_PER_TURN);
                self.playing = None;
            }
            Request::SimWaypoint(SimWaypoint { index, waypoint }) => {
                if let Some(slot) = self.waypoints.get_mut(index as usize) {
                    *slot = waypoint;
                }
            }
            Request::SimPlay(SimPlay { waypoints, start_tick, repeat }) => {
                let len = (waypoints as usize).min(MAX_WAYPOINTS);
                self.playing = (len > 0).then_some(Playing { len, start_tick, repeat });
                self.follow();
            }
            Request::SimFaults(SimFaults {
                noise_counts,
                crc_errors_per_10k,
                dropouts_per_10k,
                error_bits_per_10k,
                warnings_per_10k,
                unplugged,
                crash,
            }) => {
                self.noise_counts = noise_counts;
                self.crc_errors = crc_errors_per_10k;
                self.dropouts = dropouts_per_10k;
                self.error_bits = error_bits_per_10k;
                self.warnings = warnings_per_10k;
                self.unplugged = unplugged;
                self.hang |= crash == Crash::Hang;
            }
            _ => {}
        }
    }

    fn next(&mut self) -> u32 {
        // xorshift32
        let mut x = self.rng;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.rng = x;
        x
    }

    fn chance(&mut self, per_10k: u16) -> bool {
        per_10k > 0 && self.next() % 10_000 < per_10k as u32
    }

    /// Roughly Gaussian noise (sum of four uniforms), standard deviation `noise_counts`.
    fn noise(&mut self) -> i32 {
        if self.noise_counts == 0 {
            return 0;
        }
        let sum: i32 = (0..4).map(|_| (self.next() % 2001) as i32 - 1000).sum();
        // Var of one uniform on ±1000 ≈ 1000²/3; four of them ≈ 4·1000²/3 → std ≈ 1154.7.
        sum * self.noise_counts as i32 / 1155
    }

    /// Put the encoders where the trajectory is at the present tick.
    fn follow(&mut self) {
        if let Some(p) = self.playing {
            let t = self.tick.wrapping_sub(p.start_tick);
            // Before the start (the difference wrapped) the arm holds the first waypoint.
            let t = if t > u32::MAX / 2 { 0 } else { t };
            self.counts = counts_at(&self.waypoints[..p.len], t, p.repeat);
        }
    }

    /// What the master samples from encoder `joint` in one read (a tick after the last).
    pub fn answer(&mut self, joint: usize) -> [u8; TRANSFER_BYTES] {
        if joint == 0 {
            self.tick = self.tick.wrapping_add(1);
            self.follow();
        }
        let connected = self.unplugged & (1 << joint) == 0 && !self.chance(self.dropouts);
        let position =
            (self.counts[joint] as i64 + self.noise() as i64).rem_euclid(COUNTS_PER_TURN as i64) as u32;
        let mut slave = Slave {
            error: self.chance(self.error_bits),
            warning: self.chance(self.warnings),
            ack_bits: 1 + self.next() % 8,
            line_delay_bits: joint as u32 % 3,
            line: if connected { Line::Connected } else { Line::StuckHigh },
            ..Slave::new(position)
        };
        let mut bytes = [0u8; TRANSFER_BYTES];
        slave.idle_ns(1_000_000_000 / TICK_HZ);
        slave.read(&mut bytes);
        if connected && self.chance(self.crc_errors) {
            let bit = slave.first_data_bit() + (self.next() % 24) as usize; // a flipped data bit
            bytes[bit / 8] ^= 0x80 >> (bit % 8);
        }
        bytes
    }

    /// Whether the encoders were told to hang ([`Crash::Hang`]).
    pub fn hung(&self) -> bool {
        self.hang
    }
}

/// The encoders shared by the six SPI devices and whoever sets the pose and faults.
pub type SharedEncoders<M> = Mutex<M, RefCell<EmulatedEncoders>>;

/// One emulated encoder as an SPI device.
pub struct EmulatedEncoder<'a, M: RawMutex> {
    encoders: &'a SharedEncoders<M>,
    joint: usize,
}

impl<'a, M: RawMutex> EmulatedEncoder<'a, M> {
    /// The six devices, base to tip.
    pub fn all(encoders: &'a SharedEncoders<M>) -> [Self; JOINTS] {
        core::array::from_fn(|joint| EmulatedEncoder { encoders, joint })
    }
}

impl<M: RawMutex> ErrorType for EmulatedEncoder<'_, M> {
    type Error = Infallible;
}

impl<M: RawMutex> SpiDevice for EmulatedEncoder<'_, M> {
    async fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), Infallible> {
        for op in operations {
            let (Operation::Read(buf) | Operation::Transfer(buf, _) | Operation::TransferInPlace(buf)) = op
            else {
                continue;
            };
            if self.encoders.lock(|e| e.borrow().hung()) {
                // A read that never finishes, as on a dead DMA or clock: only the watchdog ends it.
                loop {
                    core::hint::spin_loop();
                }
            }
            let answer = self.encoders.lock(|e| e.borrow_mut().answer(self.joint));
            for (k, b) in buf.iter_mut().enumerate() {
                *b = answer.get(k).copied().unwrap_or(0);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::biss_master::BissMaster;
    use embassy_sync::blocking_mutex::raw::NoopRawMutex;

    /// Tick k's reads (the k-th read of joint 1 since boot) are the trajectory at k − start;
    /// before the start the arm holds the first waypoint, a new pose stops the motion.
    #[test]
    fn the_encoders_follow_the_trajectory_tick_by_tick() {
        let encoders: SharedEncoders<NoopRawMutex> = Mutex::new(RefCell::new(EmulatedEncoders::new()));
        let mut master = BissMaster::new(EmulatedEncoder::all(&encoders));
        let w =
            |at_tick, c: i32| Waypoint { at_tick, counts: [c, 2 * c, -c, 0, 5, COUNTS_PER_TURN as i32 - c] };
        let path = [w(0, 1000), w(300, 90_000), w(500, 20_000), w(900, 20_000)];
        for (index, waypoint) in path.iter().enumerate() {
            encoders.lock(|e| {
                e.borrow_mut()
                    .apply(&Request::SimWaypoint(SimWaypoint { index: index as u8, waypoint: *waypoint }))
            });
        }
        let start_tick = 40;
        encoders.lock(|e| {
            e.borrow_mut().apply(&Request::SimPlay(SimPlay { waypoints: 4, start_tick, repeat: false }))
        });
        for tick in 1..=1000u32 {
            let read = embassy_futures::block_on(master.read_all());
            let got: [u32; JOINTS] = core::array::from_fn(|j| read[j].expect("a clean bus").position_counts);
            let t = tick.saturating_sub(start_tick);
            assert_eq!(got, counts_at(&path, t, false), "tick {tick}");
        }
        encoders.lock(|e| e.borrow_mut().apply(&Request::SimSetPose(SimSetPose { counts: [7; JOINTS] })));
        let read = embassy_futures::block_on(master.read_all());
        assert!(read.iter().all(|r| r.expect("clean").position_counts == 7), "a pose stops the motion");
    }
}
