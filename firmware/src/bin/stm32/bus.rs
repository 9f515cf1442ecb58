//! BiSS-C master over RS-485: one shared clock line (MA), six data lines (SLO), read in the
//! same clock cycles so all six encoders sample the same instant.

use embassy_stm32::gpio::{AnyPin, Input, Level, Output, Pull, Speed};
use embassy_stm32::Peri;
use kincal_firmware::encoders::EncoderBus;
use kincal_protocol::biss::{Frame, FRAME_BITS, MAX_ACK_BITS};
use kincal_protocol::messages::JOINTS;

/// Clock half-period in busy-wait loops (~1 MHz MA at 168 MHz).
const HALF_PERIOD_LOOPS: u32 = 40;

/// The encoder bus of the real controller.
pub struct Rs485Bus {
    ma: Output<'static>,
    _driver_enable: Output<'static>,
    slo: [Input<'static>; JOINTS],
    frames: [Option<Frame>; JOINTS],
}

impl Rs485Bus {
    /// MA line, its transmitter's driver enable, and the six SLO inputs.
    pub fn new(
        ma: Peri<'static, impl embassy_stm32::gpio::Pin>,
        driver_enable: Peri<'static, impl embassy_stm32::gpio::Pin>,
        slo: [Peri<'static, AnyPin>; JOINTS],
    ) -> Self {
        Rs485Bus {
            ma: Output::new(ma, Level::High, Speed::VeryHigh),
            _driver_enable: Output::new(driver_enable, Level::High, Speed::Low),
            slo: slo.map(|p| Input::new(p, Pull::Up)),
            frames: [None; JOINTS],
        }
    }

    fn half_period() {
        cortex_m::asm::delay(HALF_PERIOD_LOOPS);
    }

    /// Clock one frame out of all six encoders at once.
    fn read_all(&mut self) {
        let total = FRAME_BITS + MAX_ACK_BITS + 2;
        let mut bits = [0u64; JOINTS];
        for _ in 0..total {
            self.ma.set_low();
            Self::half_period();
            self.ma.set_high();
            Self::half_period();
            for (j, input) in self.slo.iter().enumerate() {
                bits[j] = (bits[j] << 1) | input.is_high() as u64;
            }
        }
        // The first clock is the master's request; SLO idles high before the ACK.
        self.frames = core::array::from_fn(|j| {
            let b = bits[j] & ((1u64 << (total - 1)) - 1);
            (b != (1u64 << (total - 1)) - 1).then_some(Frame { bits: b, len: total - 1 })
        });
        // MA stays high: the encoders' timeout ends the cycle before the next tick.
    }
}

impl EncoderBus for Rs485Bus {
    fn transfer(&mut self, joint: usize) -> Option<Frame> {
        if joint == 0 {
            self.read_all();
        }
        self.frames[joint]
    }
}
