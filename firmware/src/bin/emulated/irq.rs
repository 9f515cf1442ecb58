//! Interrupt numbers of the mps2-an386 peripherals, for `NVIC::unmask`.

/// An external interrupt line of the board; only the constants below exist.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Irq(u16);

impl Irq {
    /// CMSDK UART0 receive.
    pub const UART0_RX: Irq = Irq(0);
    /// CMSDK timer 0.
    pub const TIMER0: Irq = Irq(8);
    /// CMSDK timer 1.
    pub const TIMER1: Irq = Irq(9);

    /// The interrupt of exception number `irqn` as cortex-m-rt's `DefaultHandler` gets it.
    pub fn from_handler(irqn: i16) -> Option<Irq> {
        [Irq::UART0_RX, Irq::TIMER0, Irq::TIMER1].into_iter().find(|i| i.0 as i16 == irqn)
    }
}

// SAFETY: the only values are the board's own IRQ numbers above (a private field, no other
// constructor), each a valid external interrupt of the mps2-an386.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}
