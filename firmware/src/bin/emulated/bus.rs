//! Emulated RS-485 encoder bus: real BiSS-C frames from a pose the host sets, with noise and
//! injected faults (CRC errors, dropouts, error and warning bits).

use kincal_firmware::encoders::EncoderBus;
use kincal_protocol::biss::{self, Frame, COUNTS_PER_TURN};
use kincal_protocol::messages::{Request, JOINTS};

/// The six emulated encoders.
pub struct EmulatedBus {
    counts: [u32; JOINTS],
    noise_counts: u16,
    crc_errors: u16,
    dropouts: u16,
    error_bits: u16,
    warnings: u16,
    rng: u32,
}

impl EmulatedBus {
    /// Encoders at zero, no noise, no faults.
    pub const fn new() -> Self {
        EmulatedBus {
            counts: [0; JOINTS],
            noise_counts: 0,
            crc_errors: 0,
            dropouts: 0,
            error_bits: 0,
            warnings: 0,
            rng: 0x1234_5678,
        }
    }

    /// Apply a simulation request.
    pub fn apply(&mut self, request: &Request) {
        match *request {
            Request::SimSetPose { counts } => self.counts = counts.map(|c| c % COUNTS_PER_TURN),
            Request::SimFaults {
                noise_counts,
                crc_errors_per_10k,
                dropouts_per_10k,
                error_bits_per_10k,
                warnings_per_10k,
            } => {
                self.noise_counts = noise_counts;
                self.crc_errors = crc_errors_per_10k;
                self.dropouts = dropouts_per_10k;
                self.error_bits = error_bits_per_10k;
                self.warnings = warnings_per_10k;
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
}

impl EncoderBus for EmulatedBus {
    fn transfer(&mut self, joint: usize) -> Option<Frame> {
        if self.chance(self.dropouts) {
            return None;
        }
        let position =
            (self.counts[joint] as i64 + self.noise() as i64).rem_euclid(COUNTS_PER_TURN as i64) as u32;
        let error = self.chance(self.error_bits);
        let warning = self.chance(self.warnings);
        let mut frame = biss::encode(position, error, warning, 1 + self.next() % 3);
        if self.chance(self.crc_errors) {
            frame.bits ^= 1 << (6 + self.next() % 24); // a flipped data bit
        }
        Some(frame)
    }
}
