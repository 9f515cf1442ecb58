//! Reading the six encoders once per tick, with rejection and health counters.

use kincal_protocol::biss::{self, BissError, Frame};
use kincal_protocol::messages::{EncoderHealth, JOINTS};

/// The RS-485 bus to the six BiSS-C encoders (board specific).
pub trait EncoderBus {
    /// Clock one frame out of encoder `joint`; `None` when nothing answered.
    fn transfer(&mut self, joint: usize) -> Option<Frame>;
}

/// One tick's positions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sample {
    /// Position per joint, counts (the last good one where this tick's frame was rejected).
    pub counts: [u32; JOINTS],
    /// Bit j set: joint j's frame was rejected this tick.
    pub rejected: u8,
}

/// Reads the bus and keeps the health counters.
#[derive(Clone, Debug, Default)]
pub struct Sampler {
    last: [u32; JOINTS],
    /// Counters since boot.
    pub health: [EncoderHealth; JOINTS],
}

impl Sampler {
    /// Read every encoder once.
    pub fn sample(&mut self, bus: &mut impl EncoderBus) -> Sample {
        let mut rejected = 0u8;
        for j in 0..JOINTS {
            let h = &mut self.health[j];
            match bus.transfer(j).map(biss::decode) {
                Some(Ok(reading)) => {
                    self.last[j] = reading.position_counts;
                    h.accepted += 1;
                    if reading.warning {
                        h.warnings += 1;
                    }
                }
                Some(Err(BissError::Crc { .. })) => {
                    h.crc_errors += 1;
                    rejected |= 1 << j;
                }
                Some(Err(BissError::ErrorBit)) => {
                    h.error_bits += 1;
                    rejected |= 1 << j;
                }
                Some(Err(_)) | None => {
                    h.dropouts += 1;
                    rejected |= 1 << j;
                }
            }
        }
        Sample { counts: self.last, rejected }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Script(Vec<[Option<Frame>; JOINTS]>);
    impl EncoderBus for Script {
        fn transfer(&mut self, joint: usize) -> Option<Frame> {
            let f = self.0[0][joint];
            if joint == JOINTS - 1 {
                self.0.remove(0);
            }
            f
        }
    }

    #[test]
    fn every_fault_is_counted_and_rejected() {
        let good = |p| Some(biss::encode(p, false, false, 1));
        let mut crc = biss::encode(7, false, false, 1);
        crc.bits ^= 1 << 3;
        let ticks = vec![
            [good(10), good(20), good(30), good(40), good(50), good(60)],
            [
                Some(crc),
                Some(biss::encode(1, true, false, 1)),
                None,
                Some(biss::encode(41, false, true, 1)),
                good(51),
                Some(Frame { bits: 0, len: 40 }),
            ],
        ];
        let mut s = Sampler::default();
        let mut bus = Script(ticks);
        assert_eq!(s.sample(&mut bus), Sample { counts: [10, 20, 30, 40, 50, 60], rejected: 0 });
        let second = s.sample(&mut bus);
        assert_eq!(second.rejected, 0b10_0111);
        assert_eq!(second.counts, [10, 20, 30, 41, 51, 60], "rejected joints keep their last good count");
        assert_eq!(s.health[0].crc_errors, 1);
        assert_eq!(s.health[1].error_bits, 1);
        assert_eq!(s.health[2].dropouts, 1);
        assert_eq!((s.health[3].warnings, s.health[3].accepted), (1, 2));
        assert_eq!(s.health[5].dropouts, 1);
    }
}
