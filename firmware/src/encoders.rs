//! One tick's encoder readings: rejection and health counters.

use crate::biss_master::ReadError;
use kincal_protocol::biss::{BissError, Reading};
use kincal_protocol::messages::{EncoderHealth, JOINTS};

/// One tick's positions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sample {
    /// Position per joint, counts (the last good one where this tick's frame was rejected).
    pub counts: [u32; JOINTS],
    /// Bit j set: joint j's frame was rejected this tick.
    pub rejected: u8,
}

/// Turns readings into samples and keeps the health counters.
#[derive(Clone, Debug, Default)]
pub struct Sampler {
    last: [u32; JOINTS],
    /// Counters since boot.
    pub health: [EncoderHealth; JOINTS],
    /// Ticks whose read started more than one period late since boot (set by the sampling task).
    pub late_ticks: u32,
}

impl Sampler {
    /// Count and keep one tick's readings ([`crate::biss_master::BissMaster::read_all`]).
    pub fn record(&mut self, readings: &[Result<Reading, ReadError>; JOINTS]) -> Sample {
        let mut rejected = 0u8;
        for (j, reading) in readings.iter().enumerate() {
            let h = &mut self.health[j];
            match reading {
                Ok(reading) => {
                    self.last[j] = reading.position_counts;
                    h.accepted += 1;
                    if reading.warning {
                        h.warnings += 1;
                    }
                }
                Err(ReadError::Frame(BissError::Crc { .. })) => {
                    h.crc_errors += 1;
                    rejected |= 1 << j;
                }
                Err(ReadError::Frame(BissError::ErrorBit)) => {
                    h.error_bits += 1;
                    rejected |= 1 << j;
                }
                Err(_) => {
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
    use crate::biss_master::decode_transfer;
    use crate::biss_master::transfer_bytes;
    use kincal_protocol::biss;

    #[test]
    fn every_fault_is_counted_and_rejected() {
        let good = |p| decode_transfer(&transfer_bytes(biss::encode(p, false, false, 1)));
        let mut crc = biss::encode(7, false, false, 1);
        crc.bits ^= 1 << 3;
        let mut s = Sampler::default();
        let first = [good(10), good(20), good(30), good(40), good(50), good(60)];
        assert_eq!(s.record(&first), Sample { counts: [10, 20, 30, 40, 50, 60], rejected: 0 });
        let second = [
            decode_transfer(&transfer_bytes(crc)),
            decode_transfer(&transfer_bytes(biss::encode(1, true, false, 1))),
            Err(ReadError::Bus),
            decode_transfer(&transfer_bytes(biss::encode(41, false, true, 1))),
            good(51),
            decode_transfer(&[0xFF; 6]),
        ];
        let second = s.record(&second);
        assert_eq!(second.rejected, 0b10_0111);
        assert_eq!(second.counts, [10, 20, 30, 41, 51, 60], "rejected joints keep their last good count");
        assert_eq!(s.health[0].crc_errors, 1);
        assert_eq!(s.health[1].error_bits, 1);
        assert_eq!(s.health[2].dropouts, 1);
        assert_eq!((s.health[3].warnings, s.health[3].accepted), (1, 2));
        assert_eq!(s.health[5].dropouts, 1);
    }
}
