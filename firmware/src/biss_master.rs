//! BiSS-C master over `embedded-hal-async` SPI: the one encoder driver of both boards.
//!
//! Each encoder is an [`SpiDevice`]: SCK drives the encoder's MA (clock) line through its RS-485
//! transmitter, MISO reads its SLO (data) line through its receiver, and the device's select
//! enables that encoder's transceivers. The bus runs in SPI mode 3 (clock idles high, data
//! sampled on the rising edge), most significant bit first. One read clocks [`TRANSFER_BITS`]
//! bits: the slave leaves SLO high for the first two edges, holds it low for its ACK, sends the
//! start bit and the frame, then holds it low (timeout); [`kincal_protocol::biss::decode_transfer`]
//! checks every part. With DMA behind the SPI (the STM32 board) the CPU does not wait on bit
//! times: `read_all` awaits six short transfers.
//!
//! The emulated board implements the same trait with emulated encoders
//! ([`crate::emulated_encoders`]), so the code the tests run is the code that runs on the arm.

use embedded_hal_async::spi::SpiDevice;
use kincal_protocol::biss::{self, BissError, Reading, TRANSFER_BITS};
use kincal_protocol::{joints::JOINTS, messages::TICK_HZ};

/// Bytes clocked per encoder read.
pub const TRANSFER_BYTES: usize = (TRANSFER_BITS / 8) as usize;

/// MA clock of the real board: STM32F405 SPI1, 84 MHz APB2 / 64 = 1.3125 MHz.
///
/// Chosen conservative: a bit is 762 ns, so the round trip of a long cable through two RS-485
/// transceivers and the encoder (100–300 ns) costs at most one extra leading bit, which the
/// decoder skips (it compensates up to [`biss::MAX_LINE_DELAY_BITS`] bits), and the longest
/// ACK accepted ([`biss::MAX_ACK_BITS`] bits) is 18 µs of encoder processing. Six reads take
/// 6 × 64 bits = 293 µs of the 1302 µs tick.
///
/// To raise it (84 MHz / 32 = 2.625 MHz, / 16 = 5.25 MHz): measure on a scope, at the board's
/// MISO pin, the delay from a rising SCK edge to the SLO edge it caused (the round trip) and
/// the longest ACK of the encoders fitted; the round trip must stay below
/// `MAX_LINE_DELAY_BITS` bit times, and `REQUEST_BITS + MAX_LINE_DELAY_BITS + ACK + 32` bits
/// must fit the 64-bit read. `kincal info` counts every rejected frame per joint
/// (`frame-errors` grow first when the clock is too fast for the line).
pub const REAL_BOARD_MA_HZ: u32 = 1_312_500;
const _: () = assert!(
    JOINTS as u64 * TRANSFER_BITS as u64 * TICK_HZ as u64 <= REAL_BOARD_MA_HZ as u64 / 2,
    "six reads take at most half a tick"
);

/// Why one encoder read gave no position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadError {
    /// The SPI transfer itself failed (bus error, DMA fault).
    Bus,
    /// The bits read are not a valid answer (see [`BissError`]).
    Frame(BissError),
}

/// Decode the bytes of one read (as clocked in, first bit = the first rising MA edge's sample).
pub fn decode_transfer(bytes: &[u8; TRANSFER_BYTES]) -> Result<Reading, ReadError> {
    biss::decode_transfer(u64::from_be_bytes(*bytes)).map_err(ReadError::Frame)
}

/// The master of the six joint encoders.
pub struct BissMaster<D> {
    encoders: [D; JOINTS],
}

impl<D: SpiDevice> BissMaster<D> {
    /// A master over one SPI device per joint, base to tip.
    pub fn new(encoders: [D; JOINTS]) -> Self {
        BissMaster { encoders }
    }

    /// Read the encoder of `joint` once.
    pub async fn read(&mut self, joint: usize) -> Result<Reading, ReadError> {
        let mut bytes = [0u8; TRANSFER_BYTES];
        self.encoders[joint].read(&mut bytes).await.map_err(|_| ReadError::Bus)?;
        decode_transfer(&bytes)
    }

    /// Read all six encoders, base to tip.
    pub async fn read_all(&mut self) -> [Result<Reading, ReadError>; JOINTS] {
        let mut out = [Err(ReadError::Bus); JOINTS];
        for (j, slot) in out.iter_mut().enumerate() {
            *slot = self.read(j).await;
        }
        out
    }
}

/// The decoder held to the BiSS-C slave model of `kincal-biss-slave`, which is written from the
/// protocol description and shares no code with the decoder.
#[cfg(test)]
mod tests {
    use super::*;
    use biss::{MAX_ACK_BITS, MAX_LINE_DELAY_BITS};
    use embedded_hal_async::spi::{ErrorKind, ErrorType, Operation};
    use kincal_biss_slave::{Line, Slave};

    #[derive(Debug)]
    struct BusError;
    impl embedded_hal_async::spi::Error for BusError {
        fn kind(&self) -> ErrorKind {
            ErrorKind::Other
        }
    }

    /// An SPI device that clocks a slave model (or fails the transfer when `slave` is None).
    struct ModelEncoder {
        slave: Option<Slave>,
        reads: usize,
    }

    impl ErrorType for ModelEncoder {
        type Error = BusError;
    }

    impl SpiDevice for ModelEncoder {
        async fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), BusError> {
            for op in operations {
                let Operation::Read(buf) = op else { panic!("the master only reads") };
                assert_eq!(buf.len(), TRANSFER_BYTES);
                self.reads += 1;
                let slave = self.slave.as_mut().ok_or(BusError)?;
                slave.idle_ns(1_000_000_000 / TICK_HZ);
                slave.read(buf);
            }
            Ok(())
        }
    }

    /// What the master samples from `slave` in one read (the slave's timeout has run out).
    fn sampled(slave: &mut Slave) -> [u8; TRANSFER_BYTES] {
        let mut bytes = [0u8; TRANSFER_BYTES];
        slave.idle_ns(u32::MAX);
        slave.read(&mut bytes);
        bytes
    }

    fn slave(position_counts: u32, ack_bits: u32, line_delay_bits: u32) -> Slave {
        Slave { ack_bits, line_delay_bits, ..Slave::new(position_counts) }
    }

    #[test]
    fn a_read_takes_eight_bytes() {
        assert_eq!(TRANSFER_BYTES, 8);
    }

    /// The slave answers after the second MA edge (`1 1 0 …`), the line delays by 0, 1 or 2
    /// bits, the ACK lasts 1 to the longest accepted: every read decodes to the position.
    #[test]
    fn ack_after_the_second_edge_any_line_delay_and_ack_length_decode() {
        let positions = [0, 1, 0x3F_FFFF, 0x2A_AAAA, 0x15_5555, 123_456];
        let first = sampled(&mut slave(5, 1, 0));
        assert_eq!(first[0] >> 5, 0b110, "the master reads 1 1 0: the ACK starts after the second edge");
        for delay in 0..=MAX_LINE_DELAY_BITS {
            for ack in 1..=MAX_ACK_BITS {
                for (k, &p) in positions.iter().enumerate() {
                    let mut s = slave(p, ack, delay);
                    s.warning = k == 3;
                    let got = decode_transfer(&sampled(&mut s));
                    assert_eq!(
                        got,
                        Ok(Reading { position_counts: p, warning: k == 3 }),
                        "delay {delay} ack {ack}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_master_reads_six_model_encoders() {
        let positions = [10, 20, 30, 0x3F_FFFF, 50, 60];
        let mut m = BissMaster::new(core::array::from_fn(|j| ModelEncoder {
            slave: Some(slave(positions[j], 1 + j as u32 * 4, j as u32 % 3)),
            reads: 0,
        }));
        for _ in 0..3 {
            let got = embassy_futures::block_on(m.read_all());
            for j in 0..JOINTS {
                assert_eq!(
                    got[j],
                    Ok(Reading { position_counts: positions[j], warning: false }),
                    "joint {j}"
                );
            }
        }
        assert!(m.encoders.iter().all(|e| e.reads == 3));
        m.encoders[2].slave = None;
        assert_eq!(embassy_futures::block_on(m.read(2)), Err(ReadError::Bus));
    }

    #[test]
    fn stuck_lines_timeouts_and_answers_outside_the_limits_are_rejected() {
        let frame = |s: &mut Slave| biss::decode_transfer(u64::from_be_bytes(sampled(s)));
        let mut high = Slave { line: Line::StuckHigh, ..Slave::new(7) };
        assert_eq!(frame(&mut high), Err(BissError::LineHigh));
        let mut low = Slave { line: Line::StuckLow, ..Slave::new(7) };
        assert_eq!(frame(&mut low), Err(BissError::LineLow));
        let mut busy = Slave::new(7);
        let mut bytes = [0u8; TRANSFER_BYTES];
        busy.read(&mut bytes);
        busy.read(&mut bytes);
        assert_eq!(
            decode_transfer(&bytes),
            Err(ReadError::Frame(BissError::LineLow)),
            "read during the timeout"
        );
        assert_eq!(frame(&mut slave(7, 1, MAX_LINE_DELAY_BITS + 1)), Err(BissError::LateAck));
        assert_eq!(frame(&mut slave(7, MAX_ACK_BITS + 1, 0)), Err(BissError::NoStart));
        assert_eq!(frame(&mut Slave { error: true, ..Slave::new(7) }), Err(BissError::ErrorBit));
        // An answer one edge early (a slave that ACKs after the first edge) is not BiSS-C.
        let early = u64::from_be_bytes(sampled(&mut Slave::new(7))) << 1;
        assert_eq!(biss::decode_transfer(early), Err(BissError::EarlyAck));
    }

    /// Every single flipped bit and every burst of 2 to 6 flipped bits anywhere in the read is
    /// rejected, whatever the line delay and ACK length; the only flips let through lie among the
    /// line-delay and ACK bits and change nothing (the same position is read).
    #[test]
    fn single_bit_and_burst_errors_are_rejected() {
        for (delay, ack) in [(0, 1), (1, 5), (2, MAX_ACK_BITS)] {
            let truth = Reading { position_counts: 0x2A_5A5A, warning: false };
            let good = u64::from_be_bytes(sampled(&mut slave(truth.position_counts, ack, delay)));
            assert_eq!(biss::decode_transfer(good), Ok(truth));
            let (mut tried, mut rejected) = (0, 0);
            for len in 1..=6u32 {
                for at in 0..=(64 - len) {
                    let burst = ((1u64 << len) - 1) << at;
                    // A burst's first and last bits are flipped, the ones between either way.
                    let ends_only = burst & !(((1u64 << len.saturating_sub(2)) - 1) << (at + 1));
                    for flips in [burst, ends_only] {
                        tried += 1;
                        match biss::decode_transfer(good ^ flips) {
                            Err(_) => rejected += 1,
                            Ok(r) => {
                                assert_eq!(r, truth, "delay {delay} ack {ack}: {flips:016x} read wrong");
                                // Only flips among the line-delay and ACK bits (after the two
                                // request bits, before the start bit) can shift where the ACK
                                // seems to begin without changing the frame.
                                let before_start = 2 + delay + ack;
                                let region = (u64::MAX >> 2) & !(u64::MAX >> before_start);
                                assert_eq!(
                                    flips & !region,
                                    0,
                                    "delay {delay} ack {ack}: {flips:016x} let through"
                                );
                            }
                        }
                    }
                }
            }
            assert!(rejected as f64 >= 0.98 * tried as f64, "delay {delay} ack {ack}: {rejected}/{tried}");
        }
    }
}
