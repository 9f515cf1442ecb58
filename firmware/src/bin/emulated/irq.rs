//! Interrupt numbers of the mps2-an386 peripherals, for `NVIC::unmask`.

/// An external interrupt line of the board.
#[derive(Clone, Copy)]
pub struct Irq(pub u16);

// SAFETY: only the board's own IRQ numbers (UART0 RX 0, TIMER0 8, TIMER1 9) are built.
unsafe impl cortex_m::interrupt::InterruptNumber for Irq {
    fn number(self) -> u16 {
        self.0
    }
}
