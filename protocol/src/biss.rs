//! BiSS-C single-cycle frame of a 22-bit single-turn absolute encoder.
//!
//! After the master starts clocking, the slave holds the line low (ACK) for a variable number of
//! clocks, then sends: Start = 1, CDS = 0, 22 position bits MSB first, nE (error, active low),
//! nW (warning, active low), and a CRC-6 over position + nE + nW, MSB first, sent inverted.
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

/// Bits after the ACK period: Start, CDS, position, nE, nW, CRC.
pub const FRAME_BITS: u32 = 2 + POSITION_BITS + 2 + 6;
/// Longest ACK period (clocks) accepted before the start bit.
pub const MAX_ACK_BITS: u32 = 8;

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

/// A frame as clocked in: the newest bit is bit 0 of `bits`, `len` bits in all (ACK included).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Received bits, first bit most significant.
    pub bits: u64,
    /// Number of valid bits.
    pub len: u32,
}

/// A decoded position.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    /// Position, counts in 0..2²².
    pub position_counts: u32,
    /// The encoder raised its warning bit (nW low): position valid, condition degraded.
    pub warning: bool,
}

/// Why a frame was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BissError {
    /// No start bit within the ACK window (no encoder answered, or the line is stuck low).
    NoStart,
    /// The CDS bit after the start bit was not 0.
    BadCds,
    /// Too few bits after the start bit.
    Truncated,
    /// The CRC did not match.
    Crc {
        /// CRC computed over the received data.
        computed: u8,
        /// CRC received.
        received: u8,
    },
    /// The encoder raised its error bit (nE low): position invalid.
    ErrorBit,
}

/// Build the frame an encoder sends, with `ack_bits` ACK clocks before the start bit.
pub fn encode(position_counts: u32, error: bool, warning: bool, ack_bits: u32) -> Frame {
    let data24 =
        ((position_counts & (COUNTS_PER_TURN - 1)) << 2) | ((!error as u32) << 1) | (!warning as u32);
    let crc = crc6(data24) as u64;
    let body = (0b10u64 << 30) | ((data24 as u64) << 6) | crc;
    Frame { bits: body, len: FRAME_BITS + ack_bits.min(MAX_ACK_BITS) }
}

/// Decode a received frame (shifts and masks only: cheap on the controller).
pub fn decode(frame: Frame) -> Result<Reading, BissError> {
    let len = frame.len.min(64);
    let bits = if len == 64 { frame.bits } else { frame.bits & ((1u64 << len) - 1) };
    if bits == 0 {
        return Err(BissError::NoStart);
    }
    // Zeros received before the start bit (the ACK period).
    let ack = bits.leading_zeros() - (64 - len);
    if ack > MAX_ACK_BITS {
        return Err(BissError::NoStart);
    }
    let after_start = len - ack - 1;
    if after_start < FRAME_BITS - 1 {
        return Err(BissError::Truncated);
    }
    // Align the 32 frame bits (start … CRC) at the bottom.
    let body = (bits >> (after_start - (FRAME_BITS - 1))) as u32;
    if (body >> 30) & 1 != 0 {
        return Err(BissError::BadCds);
    }
    let data24 = (body >> 6) & 0x00FF_FFFF;
    let received = (body & 0x3F) as u8;
    let computed = crc6(data24);
    if computed != received {
        return Err(BissError::Crc { computed, received });
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

    #[test]
    fn frames_round_trip_with_any_ack_length() {
        for (pos, ack) in [(0u32, 0u32), (1, 1), (0x3F_FFFF, 3), (1 << 21, 8), (123_456, 2)] {
            let r = decode(encode(pos, false, false, ack)).unwrap();
            assert_eq!(r, Reading { position_counts: pos, warning: false });
        }
        assert!(decode(encode(77, false, true, 1)).unwrap().warning);
    }

    #[test]
    fn every_kind_of_bad_frame_is_rejected() {
        assert_eq!(decode(encode(5, true, false, 1)), Err(BissError::ErrorBit));
        let good = encode(0x2A_AAAA, false, false, 2);
        for flip in 0..(FRAME_BITS - 2) {
            // Any single flipped data or CRC bit is caught by the CRC.
            let bad = Frame { bits: good.bits ^ (1 << flip), ..good };
            assert!(matches!(decode(bad), Err(BissError::Crc { .. })), "bit {flip}");
        }
        assert_eq!(decode(Frame { bits: 0, len: 40 }), Err(BissError::NoStart));
        assert_eq!(decode(Frame { bits: good.bits >> 4, len: good.len - 4 }), Err(BissError::Truncated));
        assert_eq!(decode(Frame { bits: good.bits | (1 << 30), len: good.len }), Err(BissError::BadCds));
    }
}
