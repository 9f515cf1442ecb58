//! BiSS-C master over `embedded-hal-async` SPI: the one encoder driver of both boards.
//!
//! Each encoder is an [`SpiDevice`]: SCK drives the encoder's MA (clock) line through its RS-485
//! transmitter, MISO reads its SLO (data) line through its receiver, and chip select enables
//! that encoder's transceivers. The bus runs in SPI mode 3 (clock idles high, data sampled on
//! the rising edge), most significant bit first. One read clocks [`TRANSFER_BYTES`] bytes:
//! the first clock is the master's request (SLO still idles high), then the encoder pulls SLO
//! low for its ACK, sends the start bit and the frame ([`kincal_protocol::biss`]); what follows
//! the CRC is ignored. With DMA behind the SPI (the STM32 board) the CPU does not wait on bit
//! times: `read_all` awaits six short transfers.
//!
//! The emulated board implements the same trait with emulated encoders
//! ([`crate::emulated_encoders`]), so the code the tests run is the code that runs on the arm.

use embedded_hal_async::spi::SpiDevice;
use kincal_protocol::biss::{self, BissError, Frame, Reading, FRAME_BITS, MAX_ACK_BITS};
use kincal_protocol::messages::JOINTS;

/// Bytes clocked per encoder read: the request clock, the longest ACK and the frame.
pub const TRANSFER_BYTES: usize = (1 + MAX_ACK_BITS + FRAME_BITS).div_ceil(8) as usize;
/// Bits clocked per encoder read.
pub const TRANSFER_BITS: u32 = TRANSFER_BYTES as u32 * 8;
const _: () = assert!(1 + MAX_ACK_BITS + FRAME_BITS <= TRANSFER_BITS, "a read holds the longest frame");

/// MA clock of the real board (STM32F405 SPI1: 84 MHz APB2 / 16): short arm cables keep the
/// round trip through the RS-485 transceivers within half a clock period (95 ns), so no line
/// delay compensation is needed.
pub const REAL_BOARD_MA_HZ: u32 = 5_250_000;

/// Why one encoder read gave no position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadError {
    /// The SPI transfer itself failed (bus error, DMA fault).
    Bus,
    /// The line stayed high after the request: no ACK, no encoder answered.
    NoAck,
    /// The frame was received but is not valid (CRC, error bit, start, CDS, length).
    Frame(BissError),
}

/// Decode the bytes of one read (as clocked in, first bit = the request clock).
pub fn decode_transfer(bytes: &[u8; TRANSFER_BYTES]) -> Result<Reading, ReadError> {
    let mut word = [0u8; 8];
    word[8 - TRANSFER_BYTES..].copy_from_slice(bytes);
    let all = u64::from_be_bytes(word);
    // Drop the request clock's bit; what remains starts with the ACK.
    let len = TRANSFER_BITS - 1;
    let bits = all & ((1u64 << len) - 1);
    if bits >> (len - 1) & 1 == 1 {
        return Err(ReadError::NoAck);
    }
    biss::decode(Frame { bits, len }).map_err(ReadError::Frame)
}

/// The bytes an encoder sends for `frame` (from [`biss::encode`]): request clock high, the
/// frame, then the line held low (timeout). For emulated encoders and tests.
pub fn transfer_bytes(frame: Frame) -> [u8; TRANSFER_BYTES] {
    let len = frame.len.min(TRANSFER_BITS - 1);
    let body = frame.bits & ((1u64 << len) - 1);
    let all = (1u64 << (TRANSFER_BITS - 1)) | (body << (TRANSFER_BITS - 1 - len));
    core::array::from_fn(|k| (all >> (8 * (TRANSFER_BYTES - 1 - k))) as u8)
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

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_async::spi::{ErrorKind, ErrorType, Operation};
    use std::collections::VecDeque;

    #[derive(Debug)]
    struct MockError;
    impl embedded_hal_async::spi::Error for MockError {
        fn kind(&self) -> ErrorKind {
            ErrorKind::Other
        }
    }

    /// An SPI device that answers each read with the next scripted bytes, or a bus error.
    struct Mock {
        answers: VecDeque<Option<[u8; TRANSFER_BYTES]>>,
        reads: usize,
    }

    impl ErrorType for Mock {
        type Error = MockError;
    }

    impl SpiDevice for Mock {
        async fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), MockError> {
            for op in operations {
                let Operation::Read(buf) = op else { panic!("the master only reads") };
                assert_eq!(buf.len(), TRANSFER_BYTES);
                self.reads += 1;
                let answer = self.answers.pop_front().expect("a scripted answer").ok_or(MockError)?;
                buf.copy_from_slice(&answer);
            }
            Ok(())
        }
    }

    fn master(answers: [Option<[u8; TRANSFER_BYTES]>; JOINTS]) -> BissMaster<Mock> {
        BissMaster::new(answers.map(|a| Mock { answers: VecDeque::from([a]), reads: 0 }))
    }

    fn read_all(m: &mut BissMaster<Mock>) -> [Result<Reading, ReadError>; JOINTS] {
        embassy_futures::block_on(m.read_all())
    }

    #[test]
    fn a_read_takes_six_bytes() {
        assert_eq!(TRANSFER_BYTES, 6);
    }

    #[test]
    fn good_frames_with_any_ack_length_give_the_positions() {
        let positions = [0, 1, 0x3F_FFFF, 0x2A_AAAA, 0x15_5555, 123_456];
        let mut m = master(core::array::from_fn(|j| {
            Some(transfer_bytes(biss::encode(positions[j], false, false, 1 + j as u32)))
        }));
        let got = read_all(&mut m);
        for j in 0..JOINTS {
            assert_eq!(got[j], Ok(Reading { position_counts: positions[j], warning: false }), "joint {j}");
            assert_eq!(m.encoders[j].reads, 1);
        }
    }

    #[test]
    fn crc_errors_missing_ack_error_and_warning_bits_and_bus_errors_are_told_apart() {
        let good = biss::encode(777, false, false, 2);
        let mut flipped = good;
        flipped.bits ^= 1 << 10; // a position bit
        let mut m = master([
            Some(transfer_bytes(flipped)),
            Some([0xFF; TRANSFER_BYTES]), // no encoder: the line stays high
            Some(transfer_bytes(biss::encode(5, true, false, 1))),
            Some(transfer_bytes(biss::encode(6, false, true, 1))),
            None,
            Some([0x80, 0, 0, 0, 0, 0]), // ACK but never a start bit
        ]);
        let got = read_all(&mut m);
        assert!(matches!(got[0], Err(ReadError::Frame(BissError::Crc { .. }))), "{:?}", got[0]);
        assert_eq!(got[1], Err(ReadError::NoAck));
        assert_eq!(got[2], Err(ReadError::Frame(BissError::ErrorBit)));
        assert_eq!(got[3], Ok(Reading { position_counts: 6, warning: true }));
        assert_eq!(got[4], Err(ReadError::Bus));
        assert_eq!(got[5], Err(ReadError::Frame(BissError::NoStart)));
    }

    #[test]
    fn every_single_bit_error_in_the_frame_is_caught() {
        let frame = biss::encode(0x2A_5A5A, false, false, 3);
        let bytes = transfer_bytes(frame);
        assert!(decode_transfer(&bytes).is_ok());
        // Flip each bit from the ACK to the CRC's last bit: none may give a wrong position.
        let frame_end = 1 + frame.len;
        for bit in 1..frame_end {
            let mut bad = bytes;
            bad[bit as usize / 8] ^= 0x80 >> (bit % 8);
            if let Ok(r) = decode_transfer(&bad) {
                panic!("bit {bit}: accepted {r:?}");
            }
        }
    }
}
