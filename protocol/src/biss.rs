//! BiSS-C single-cycle frame of a 22-bit single-turn absolute encoder.
//!
//! The master clocks MA (idle high); the slave leaves SLO high until the second rising MA edge,
//! then holds it low (ACK) for its processing time, then sends: Start = 1, CDS = 0, 22 position
//! bits MSB first, nE (error, active low), nW (warning, active low), and a CRC-6 over
//! position + nE + nW, MSB first, sent inverted; after the CRC it holds SLO low (timeout) until
//! MA has stayed high for its timeout, then idles high again. [`decode_transfer`] checks all of
//! it; the tests hold it to a slave model written separately from the specification
//! (`firmware/biss-slave`).
//! CRC-6: polynomial x⁶ + x + 1 (0x03), init 0, not reflected, output XOR 0x3F (the inversion).
//! 22 + 2 data bits pack into exactly three bytes, which is what the CRC runs over.

/// Position bits of the encoder.
pub const POSITION_BITS: u32 = 22;
/// Counts per turn.
pub const COUNTS_PER_TURN: u32 = 1 << POSITION_BITS;
/// Encoder counts as degrees (no wrapping).
pub fn counts_to_deg(counts: f64) -> f64 {
    counts * (360.0 / COUNTS_PER_TURN as f64)
}

/// An angle in degrees as the nearest encoder count in 0..2²².
#[cfg(feature = "std")]
pub fn deg_to_counts(deg: f64) -> u32 {
    ((deg.rem_euclid(360.0) / 360.0 * COUNTS_PER_TURN as f64).round() as u32) % COUNTS_PER_TURN
}

/// Bits from the start bit to the CRC's last bit: Start, CDS, position, nE, nW, CRC.
pub const FRAME_BITS: u32 = 2 + POSITION_BITS + 2 + 6;
/// Bits sampled high before any answer: the slave pulls SLO low for its ACK only after the
/// *second* rising MA edge, so a master sampling on rising edges (SPI mode 3) reads `1 1 0 …`.
pub const REQUEST_BITS: u32 = 2;
/// Longest round trip (MA out, SLO back through both transceivers and the cable) compensated,
/// whole bit times: each started bit time of delay adds one more leading 1, which the decoder
/// skips. At the 1.3125 MHz MA clock two bits are 1.5 µs, five times a long arm cable's.
pub const MAX_LINE_DELAY_BITS: u32 = 2;
/// Longest ACK (the encoder's processing time) accepted, bits: 18 µs at 1.3125 MHz. The
/// encoders' datasheets give their longest processing time; the bring-up counts the ACK bits
/// on a scope (README checklist).
pub const MAX_ACK_BITS: u32 = 24;
/// Bits clocked per read: one `u64`.
pub const TRANSFER_BITS: u32 = 64;
/// Bits after the CRC that a read always holds, checked low: the encoder holds SLO low
/// (its timeout) after the frame for as long as MA keeps clocking.
pub const MIN_TIMEOUT_BITS: u32 =
    TRANSFER_BITS - (REQUEST_BITS + MAX_LINE_DELAY_BITS + MAX_ACK_BITS + FRAME_BITS);
const _: () = assert!(MIN_TIMEOUT_BITS >= 4, "a read holds the longest answer and some timeout bits");

/// The BiSS-C CRC-6 (see the module doc).
pub const CRC6_BISS: crc::Algorithm<u8> = crc::Algorithm {
    width: 6,
    poly: 0x03,
    init: 0x00,
    refin: false,
    refout: false,
    xorout: 0x3F,
    check: 0x2E,
    residue: 0x02,
};

/// [`CRC6_BISS`] six bits at a time: entry v is the register after shifting v through six
/// zero bits (polynomial x⁶ + x + 1, MSB first). 64 bytes; a test holds it to the `crc` crate.
const CRC6_TABLE: [u8; 64] = {
    let mut table = [0u8; 64];
    let mut v = 0;
    while v < 64 {
        let mut crc = v as u8;
        let mut k = 0;
        while k < 6 {
            crc = if crc & 0x20 != 0 { ((crc << 1) ^ CRC6_BISS.poly) & 0x3F } else { (crc << 1) & 0x3F };
            k += 1;
        }
        table[v] = crc;
        v += 1;
    }
    table
};

/// CRC-6 (as transmitted, i.e. inverted) over the 24 data bits position ‖ nE ‖ nW.
pub fn crc6(data24: u32) -> u8 {
    let mut crc = CRC6_BISS.init;
    for shift in [18, 12, 6, 0] {
        crc = CRC6_TABLE[((crc as u32 ^ (data24 >> shift)) & 0x3F) as usize];
    }
    crc ^ CRC6_BISS.xorout
}

/// A decoded position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    /// Position, counts in 0..2²².
    pub position_counts: u32,
    /// The encoder raised its warning bit (nW low): position valid, condition degraded.
    pub warning: bool,
}

/// Why a read was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BissError {
    /// The line was low at the request: the encoder is still in its timeout (not ready), or
    /// the line is stuck low (shorted, dead receiver driving low).
    LineLow,
    /// The line stayed high: no encoder answered (unplugged, no power, dead transceiver,
    /// MISO pulled up).
    LineHigh,
    /// The ACK began before the second MA edge: not a BiSS-C answer.
    EarlyAck,
    /// The ACK began more than [`MAX_LINE_DELAY_BITS`] bits late: the round trip is longer
    /// than compensated (lower the MA clock).
    LateAck,
    /// No start bit within [`MAX_ACK_BITS`] bits of ACK.
    NoStart,
    /// The CDS bit after the start bit was not 0.
    BadCds,
    /// The CRC did not match.
    Crc {
        /// CRC computed over the received data.
        computed: u8,
        /// CRC received.
        received: u8,
    },
    /// The line was not low after the CRC (the encoder's timeout): a shifted or torn frame.
    Timeout,
    /// The encoder raised its error bit (nE low): position invalid.
    ErrorBit,
}

/// Decode one read: the [`TRANSFER_BITS`] bits sampled on the rising MA edges, the first
/// sampled in the most significant bit. Skips the request bits and up to
/// [`MAX_LINE_DELAY_BITS`] more leading ones (line delay), then the ACK, and checks the start
/// bit, CDS, CRC, the timeout bits after the frame and the error bit. Shifts and masks only.
pub fn decode_transfer(bits: u64) -> Result<Reading, BissError> {
    let ones = bits.leading_ones();
    match ones {
        0 => return Err(BissError::LineLow),
        64 => return Err(BissError::LineHigh),
        n if n < REQUEST_BITS => return Err(BissError::EarlyAck),
        n if n > REQUEST_BITS + MAX_LINE_DELAY_BITS => return Err(BissError::LateAck),
        _ => {}
    }
    let from_ack = bits << ones;
    let ack = from_ack.leading_zeros();
    if ack > MAX_ACK_BITS {
        return Err(BissError::NoStart);
    }
    // The start bit is at `start` (from the most significant bit); the frame ends at most at
    // bit 60 (the asserted MIN_TIMEOUT_BITS), so both shifts stay below 64.
    let start = ones + ack;
    let body = ((bits << start) >> (64 - FRAME_BITS)) as u32;
    if (body >> 30) & 1 != 0 {
        return Err(BissError::BadCds);
    }
    let data24 = (body >> 6) & 0x00FF_FFFF;
    let received = (body & 0x3F) as u8;
    let computed = crc6(data24);
    if computed != received {
        return Err(BissError::Crc { computed, received });
    }
    if bits << (start + FRAME_BITS) != 0 {
        return Err(BissError::Timeout);
    }
    if data24 & 0b10 == 0 {
        return Err(BissError::ErrorBit);
    }
    Ok(Reading { position_counts: data24 >> 2, warning: data24 & 1 == 0 })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc6_check_values_from_the_reference() {
        let reference = crc::Crc::<u8>::new(&CRC6_BISS);
        assert_eq!(reference.checksum(b"123456789"), 0x2E);
        for data24 in (0..1u32 << 24).step_by(997).chain([0xFF_FFFF]) {
            let bytes = [(data24 >> 16) as u8, (data24 >> 8) as u8, data24 as u8];
            assert_eq!(crc6(data24), reference.checksum(&bytes), "{data24:06x}");
        }
        assert_eq!(crc6(0x123456), 0x2C);
        assert_eq!(crc6(0x000000), 0x3F);
    }
}
