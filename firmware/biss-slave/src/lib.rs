//! A BiSS-C slave (single-cycle read of a 22-bit single-turn absolute encoder) and its line, as
//! the master samples it on the rising edges of MA (SPI mode 3, most significant bit first).
//!
//! Written from the BiSS-C protocol description, not from kincal's decoder, with which it
//! shares no code (not even the CRC): the emulated encoders send what it gives, and the
//! decoder's tests hold the decoder to it.
//!
//! What the slave does, edge by edge (MA idles high; the master's first falling edge starts
//! the cycle and it samples SLO on each rising edge):
//! 1. SLO idles high. The slave latches its position at the first rising MA edge and pulls SLO
//!    low (ACK) only after the **second** rising edge: the master reads `1 1 0 …`.
//! 2. SLO stays low for the encoder's processing time ([`Slave::ack_bits`], at least one bit).
//! 3. Start bit (1), CDS bit (0), 22 position bits MSB first, nE and nW (error and warning,
//!    active low), CRC-6 over position ‖ nE ‖ nW (polynomial x⁶ + x + 1, "0x43", initial value
//!    0, MSB first) sent inverted.
//! 4. Timeout: SLO low for as long as MA keeps clocking and until MA has stayed high for
//!    [`Slave::timeout_ns`]; then SLO high again (ready). A read started earlier finds SLO low.
//!
//! The line delays SLO as the master sees it: a round trip of up to one bit time makes the
//! master sample every bit one edge later, two bit times two edges later
//! ([`Slave::line_delay_bits`]); the master then reads more leading ones. A line can also be
//! stuck high (unplugged, pulled up) or stuck low ([`Line`]).
#![no_std]
#![deny(missing_docs)]

/// Position bits of the encoder.
pub const POSITION_BITS: u32 = 22;

/// The state of the SLO line between the encoder and the master.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Line {
    /// Connected: the slave drives SLO.
    Connected,
    /// Stuck high: unplugged (the master's pull-up), no power, dead transceiver.
    StuckHigh,
    /// Stuck low: shorted line, or a receiver driving low.
    StuckLow,
}

/// One BiSS-C slave and its line.
#[derive(Clone, Debug)]
pub struct Slave {
    /// Position, counts (0..2²²; higher bits are ignored).
    pub position_counts: u32,
    /// Error condition (sent as nE = 0).
    pub error: bool,
    /// Warning condition (sent as nW = 0).
    pub warning: bool,
    /// Processing time: bits SLO stays low (ACK) before the start bit, at least 1.
    pub ack_bits: u32,
    /// Round trip of the line in whole bit times (0: the master samples what the slave sent
    /// at the previous edge).
    pub line_delay_bits: u32,
    /// The line's state.
    pub line: Line,
    /// Time MA must stay high after a read before the slave answers again, ns.
    pub timeout_ns: u32,
    /// Timeout still running, ns (0: ready).
    pub busy_ns: u32,
}

impl Slave {
    /// A ready slave at `position_counts`, no error or warning, a one-bit ACK, no line delay,
    /// a 20 µs timeout.
    pub const fn new(position_counts: u32) -> Slave {
        Slave {
            position_counts,
            error: false,
            warning: false,
            ack_bits: 1,
            line_delay_bits: 0,
            line: Line::Connected,
            timeout_ns: 20_000,
            busy_ns: 0,
        }
    }

    /// MA stays high for `ns`: the timeout runs out.
    pub fn idle_ns(&mut self, ns: u32) {
        self.busy_ns = self.busy_ns.saturating_sub(ns);
    }

    /// Whether the slave would answer a read now.
    pub fn ready(&self) -> bool {
        self.busy_ns == 0
    }

    /// One read of `out.len() * 8` MA clocks: what the master samples, first bit in the most
    /// significant bit of `out[0]`. Starts the timeout.
    pub fn read(&mut self, out: &mut [u8]) {
        let ready = self.ready();
        let delay = self.line_delay_bits as usize;
        let frame = self.frame();
        for (k, byte) in out.iter_mut().enumerate() {
            *byte = 0;
            for b in 0..8 {
                // The master's sample at rising edge `edge` (1-based) sees SLO as the slave set
                // it `1 + delay` edges earlier (before the read: high when ready, low while the
                // timeout runs).
                let edge = k * 8 + b + 1;
                let level = match self.line {
                    Line::StuckHigh => true,
                    Line::StuckLow => false,
                    Line::Connected if !ready => false,
                    Line::Connected => {
                        edge.checked_sub(1 + delay).is_none_or(|after| self.level_after_edge(frame, after))
                    }
                };
                *byte |= (level as u8) << (7 - b);
            }
        }
        self.busy_ns = self.timeout_ns;
    }

    /// SLO as the slave drives it after rising MA edge `edge` (0: before the first edge), with
    /// `frame` the 32 bits from the start bit to the CRC's last.
    fn level_after_edge(&self, frame: u32, edge: usize) -> bool {
        let ack = self.ack_bits.max(1) as usize;
        // Edges 0 and 1: idle. Then the ACK, then the frame, then the timeout (low).
        let Some(in_answer) = edge.checked_sub(2) else { return true };
        let Some(in_frame) = in_answer.checked_sub(ack) else { return false };
        in_frame < 32 && (frame >> (31 - in_frame)) & 1 == 1
    }

    /// The frame, first bit most significant: start (1), CDS (0), position ‖ nE ‖ nW, CRC-6.
    fn frame(&self) -> u32 {
        let data = self.data_bits();
        (1 << 31) | (data << 6) | crc6_inverted(data) as u32
    }

    /// Position ‖ nE ‖ nW, 24 bits.
    fn data_bits(&self) -> u32 {
        let position = self.position_counts & ((1 << POSITION_BITS) - 1);
        (position << 2) | ((!self.error as u32) << 1) | (!self.warning as u32)
    }

    /// Where the first data bit (position MSB) lands in a read, counted from the first sampled
    /// bit (0): for tests that corrupt data bits on purpose.
    pub fn first_data_bit(&self) -> usize {
        2 + self.line_delay_bits as usize + self.ack_bits.max(1) as usize + 2
    }
}

/// CRC-6 with polynomial x⁶ + x + 1 over the 24 data bits, MSB first, initial value 0,
/// inverted as sent: one bit at a time, as a shift register.
fn crc6_inverted(data24: u32) -> u8 {
    let mut register = 0u8;
    for i in (0..24).rev() {
        let feedback = ((register >> 5) & 1) ^ ((data24 >> i) & 1) as u8;
        register = (register << 1) & 0x3F;
        if feedback == 1 {
            register ^= 0b00_0011; // x¹ + x⁰ (x⁶ is the feedback itself)
        }
    }
    !register & 0x3F
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits(slave: &mut Slave) -> u64 {
        let mut out = [0u8; 8];
        slave.read(&mut out);
        u64::from_be_bytes(out)
    }

    /// A frame written out by hand from the description: position 0x2A5A5A, no error, no
    /// warning, ACK of 3 bits, no delay.
    #[test]
    fn the_line_matches_a_frame_written_out_by_hand() {
        let mut s = Slave::new(0x2A_5A5A);
        s.ack_bits = 3;
        let data = (0x2A_5A5Au64 << 2) | 0b11;
        let crc = crc6_inverted(data as u32) as u64;
        // 1 1 | 0 0 0 | 1 0 | data(24) | crc(6) | 0…
        let expected = (0b11u64 << 62) | (0b10u64 << 57) | (data << 33) | (crc << 27);
        assert_eq!(bits(&mut s), expected);
    }

    #[test]
    fn the_crc_of_known_values() {
        // The register is data(x)·x⁶ mod (x⁶ + x + 1), and x⁶ ≡ x + 1.
        assert_eq!(crc6_inverted(0), 0x3F);
        assert_eq!(crc6_inverted(1) ^ 0x3F, 0b00_0011, "x⁶ ≡ x + 1");
        assert_eq!(crc6_inverted(1 << 1) ^ 0x3F, 0b00_0110, "x⁷ ≡ x² + x");
        assert_eq!(crc6_inverted(1 << 6) ^ 0x3F, 0b00_0101, "x¹² ≡ (x + 1)² = x² + 1");
    }

    #[test]
    fn delay_adds_leading_ones_and_timeout_holds_the_line_low() {
        let mut s = Slave::new(5);
        let plain = bits(&mut s);
        s.idle_ns(20_000);
        s.line_delay_bits = 2;
        assert_eq!(bits(&mut s), (plain >> 2) | (0b11 << 62));
        assert!(!s.ready());
        assert_eq!(bits(&mut s), 0, "a read during the timeout finds the line low");
        s.idle_ns(20_000);
        assert!(s.ready());
    }
}
