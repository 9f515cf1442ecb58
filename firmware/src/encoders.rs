//! One tick's encoder readings: rejection, plausibility, freshness and health counters.

use crate::biss_master::ReadError;
use kincal_protocol::biss::{BissError, Reading, COUNTS_PER_TURN};
use kincal_protocol::{
    joints::JOINTS,
    messages::{EncoderHealth, TICK_HZ},
};

/// Fastest a joint of the hand-guided arm turns, turns per second: 3 turns/s = 1080 °/s, above
/// the fastest wrist flick of a surgeon (about 1000 °/s peak) and far above a tracking motion.
pub const MAX_JOINT_TURNS_PER_S: u32 = 3;
/// Largest count change accepted from one tick to the next: 2²² counts × 3 turns/s / 768 Hz =
/// 16 384 counts (1.41°). A frame that passes the CRC by chance (1 in 64 of the multi-bit
/// corruptions) lands within it only once in 128, so together one in 8192 gets through.
pub const MAX_JUMP_COUNTS_PER_TICK: u32 = COUNTS_PER_TURN * MAX_JOINT_TURNS_PER_S / TICK_HZ;
const _: () = assert!(MAX_JUMP_COUNTS_PER_TICK == 16_384);

/// One tick's positions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sample {
    /// Position per joint, counts (the last good one where this tick's frame was rejected, 0
    /// for a joint never read since boot: only for windows, which count the rejects).
    pub counts: [u32; JOINTS],
    /// Bit j set: joint j's frame was rejected this tick (or implausible): its count is stale.
    pub rejected: u8,
    /// Ticks since the stalest joint's last accepted frame (0: all fresh; `u16::MAX`: some
    /// joint never read since boot; otherwise at most `u16::MAX - 1`).
    pub stale_ticks: u16,
}

/// Turns readings into samples and keeps the health counters.
#[derive(Clone, Debug)]
pub struct Sampler {
    last: [u32; JOINTS],
    /// Ticks since each joint's last accepted frame (`u16::MAX`: never; else saturating one
    /// below).
    age_ticks: [u16; JOINTS],
    /// The last count rejected as a jump, per joint: a next frame within one tick's reach of
    /// it confirms the encoder is really there (the joint turned while it was not read).
    jumped_to: [Option<u32>; JOINTS],
    /// Counters since boot.
    pub health: [EncoderHealth; JOINTS],
    /// Ticks whose read started more than one period late since boot (set by the sampling task).
    pub late_ticks: u32,
}

impl Default for Sampler {
    fn default() -> Self {
        Sampler {
            last: [0; JOINTS],
            age_ticks: [u16::MAX; JOINTS],
            jumped_to: [None; JOINTS],
            health: Default::default(),
            late_ticks: 0,
        }
    }
}

/// Whether `to` is within what a joint can turn in `ticks` ticks from `from` (the shorter way
/// round the circle).
fn plausible(from: u32, to: u32, ticks: u16) -> bool {
    let d = to.wrapping_sub(from) % COUNTS_PER_TURN;
    let distance = d.min(COUNTS_PER_TURN - d);
    distance <= MAX_JUMP_COUNTS_PER_TICK.saturating_mul(ticks as u32)
}

impl Sampler {
    /// The arm was moved without the encoders being read (the emulated arm's pose was set):
    /// the next frames are taken without the jump check, as after boot.
    pub fn forget_positions(&mut self) {
        self.age_ticks = [u16::MAX; JOINTS];
        self.jumped_to = [None; JOINTS];
    }

    /// Count and keep one tick's readings ([`crate::biss_master::BissMaster::read_all`]).
    pub fn record(&mut self, readings: &[Result<Reading, ReadError>; JOINTS]) -> Sample {
        let mut rejected = 0u8;
        for (j, reading) in readings.iter().enumerate() {
            let h = &mut self.health[j];
            // A joint never read has nothing to compare with: its first good frame is taken.
            let never = self.age_ticks[j] == u16::MAX;
            let since_last = if never { u16::MAX } else { (self.age_ticks[j] + 1).min(u16::MAX - 1) };
            let confirms =
                |to: Option<u32>, r: &Reading| to.is_some_and(|c| plausible(c, r.position_counts, 1));
            let accepted = match reading {
                Ok(r)
                    if !never
                        && !plausible(self.last[j], r.position_counts, since_last)
                        && !confirms(self.jumped_to[j], r) =>
                {
                    self.jumped_to[j] = Some(r.position_counts);
                    h.jumps += 1;
                    false
                }
                Ok(r) => {
                    self.last[j] = r.position_counts;
                    h.accepted += 1;
                    h.warnings += r.warning as u32;
                    true
                }
                Err(ReadError::Frame(BissError::Crc { .. })) => {
                    h.crc_errors += 1;
                    false
                }
                Err(ReadError::Frame(BissError::ErrorBit)) => {
                    h.error_bits += 1;
                    false
                }
                Err(ReadError::Bus | ReadError::Frame(BissError::LineHigh | BissError::LineLow)) => {
                    h.dropouts += 1;
                    false
                }
                Err(ReadError::Frame(_)) => {
                    h.frame_errors += 1;
                    false
                }
            };
            if accepted {
                self.age_ticks[j] = 0;
                self.jumped_to[j] = None;
            } else {
                rejected |= 1 << j;
                self.age_ticks[j] = since_last;
            }
        }
        let stale_ticks = self.age_ticks.iter().copied().max().unwrap_or(0);
        Sample { counts: self.last, rejected, stale_ticks }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::biss_master::{decode_transfer, TRANSFER_BYTES};
    use kincal_biss_slave::{Line, Slave};

    fn read(slave: &mut Slave) -> Result<Reading, ReadError> {
        let mut bytes = [0u8; TRANSFER_BYTES];
        slave.idle_ns(u32::MAX);
        slave.read(&mut bytes);
        decode_transfer(&bytes)
    }

    fn good(position_counts: u32) -> Result<Reading, ReadError> {
        read(&mut Slave::new(position_counts))
    }

    #[test]
    fn every_fault_is_counted_and_rejected() {
        let mut s = Sampler::default();
        let never = s.record(&[Err(ReadError::Bus); JOINTS]);
        assert_eq!((never.rejected, never.stale_ticks), (0x3F, u16::MAX), "never read: stale");
        let first = [good(10), good(20), good(30), good(40), good(50), good(60)];
        assert_eq!(
            s.record(&first),
            Sample { counts: [10, 20, 30, 40, 50, 60], rejected: 0, stale_ticks: 0 }
        );
        let mut crc = Slave::new(11);
        let mut bytes = [0u8; TRANSFER_BYTES];
        crc.read(&mut bytes);
        let at = crc.first_data_bit() + 5;
        bytes[at / 8] ^= 0x80 >> (at % 8);
        let second = [
            decode_transfer(&bytes),
            read(&mut Slave { error: true, ..Slave::new(21) }),
            read(&mut Slave { line: Line::StuckLow, ..Slave::new(31) }),
            read(&mut Slave { warning: true, ..Slave::new(41) }),
            good(51),
            read(&mut Slave { ack_bits: 40, ..Slave::new(61) }),
        ];
        let second = s.record(&second);
        assert_eq!(second.rejected, 0b10_0111);
        assert_eq!(second.counts, [10, 20, 30, 41, 51, 60], "rejected joints keep their last good count");
        assert_eq!(second.stale_ticks, 1);
        assert_eq!(s.health[0].crc_errors, 1);
        assert_eq!(s.health[1].error_bits, 1);
        assert_eq!(s.health[2].dropouts, 2);
        assert_eq!((s.health[3].warnings, s.health[3].accepted), (1, 2));
        assert_eq!(s.health[5].frame_errors, 1);
        let third = s.record(&[good(10), good(20), Err(ReadError::Bus), good(41), good(51), good(60)]);
        assert_eq!((third.rejected, third.stale_ticks), (0b100, 2));
    }

    /// A count farther from the last good one than the arm can turn is rejected and counted;
    /// after a gap of several ticks the allowance grows with the time since the last good one;
    /// a second frame that agrees with a jumped one confirms it (the joint turned unseen).
    #[test]
    fn a_jump_beyond_the_arms_speed_is_rejected() {
        let mut s = Sampler::default();
        let at = |p: u32| core::array::from_fn(|j| if j == 0 { good(p) } else { good(7) });
        assert_eq!(s.record(&at(4_194_000)).rejected, 0);
        // Across the wrap, within one tick's reach: accepted.
        assert_eq!(s.record(&at((4_194_000 + MAX_JUMP_COUNTS_PER_TICK) % COUNTS_PER_TURN)).rejected, 0);
        let last = (4_194_000 + MAX_JUMP_COUNTS_PER_TICK) % COUNTS_PER_TURN;
        let far = s.record(&at(last + MAX_JUMP_COUNTS_PER_TICK + 1));
        assert_eq!((far.rejected, far.counts[0], s.health[0].jumps), (1, last, 1));
        // Two ticks since the last good count now: twice the reach (the other way round, so
        // not confirming the first jump).
        let back = |n: u32| (last + COUNTS_PER_TURN - n) % COUNTS_PER_TURN;
        assert_eq!(s.record(&at(back(2 * MAX_JUMP_COUNTS_PER_TICK + 1))).rejected, 1);
        assert_eq!(s.record(&at(back(3 * MAX_JUMP_COUNTS_PER_TICK))).rejected, 0);
        assert_eq!(s.health[0].jumps, 2);
        let now = back(3 * MAX_JUMP_COUNTS_PER_TICK);
        assert_eq!(s.record(&at(now + 1_000_000)).rejected, 1);
        assert_eq!(s.record(&at(now + 1_000_000 + 3 * MAX_JUMP_COUNTS_PER_TICK)).rejected, 1, "not in reach");
        let confirmed = s.record(&at(now + 1_000_000 + 3 * MAX_JUMP_COUNTS_PER_TICK + 100));
        assert_eq!((confirmed.rejected, s.health[0].jumps), (0, 4), "confirmed by a second frame");
        s.forget_positions();
        assert_eq!(s.record(&at(7)).rejected, 0, "the arm was moved: no jump check");
    }

    /// Random 64-bit reads (seeded), each after a good tick: none is taken as a position. The
    /// decoder rejects nearly all; one with a valid CRC by chance lands outside the tick's reach
    /// and is counted as a jump.
    #[test]
    fn random_reads_are_rejected_and_counted() {
        let mut s = Sampler::default();
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let ticks = 50_000;
        for _ in 0..ticks {
            assert_eq!(s.record(&[good(1_000_000); JOINTS]).rejected, 0);
            let readings = core::array::from_fn(|_| decode_transfer(&next().to_be_bytes()));
            assert_eq!(s.record(&readings).rejected, 0x3F);
        }
        for h in &s.health {
            assert_eq!(h.accepted, ticks);
            assert_eq!(h.dropouts + h.frame_errors + h.crc_errors + h.error_bits + h.jumps, ticks);
            assert!(h.dropouts > 0 && h.frame_errors > 0 && h.crc_errors > 0, "{h:?}");
        }
    }
}
