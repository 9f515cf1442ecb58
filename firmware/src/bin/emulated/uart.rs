//! CMSDK APB UART0 of the mps2: the host link (QEMU connects it to a pty or a TCP socket).

use crate::irq::Irq;
use crate::mmio::{read, write};
use cortex_m::peripheral::NVIC;
use kincal_firmware::app::{FROM_HOST, TO_HOST};

const UART0: usize = 0x4000_4000;
const DATA: usize = 0x0;
const STATE: usize = 0x4;
const CTRL: usize = 0x8;
const INT: usize = 0xC;
const BAUDDIV: usize = 0x10;
const TX_FULL: u32 = 1;
const RX_FULL: u32 = 2;
/// UART0 receive interrupt number.
pub const RX_IRQ: u16 = 0;

/// Enable transmit, receive and the receive interrupt.
pub fn init() {
    write(UART0, BAUDDIV, 16);
    write(UART0, CTRL, 0b1011); // TX, RX, RX interrupt
                                // SAFETY: the receive handler is installed (DefaultHandler dispatch).
    unsafe { NVIC::unmask(Irq(RX_IRQ)) };
}

/// Receive interrupt: move every waiting byte into [`FROM_HOST`].
pub fn on_rx() {
    write(UART0, INT, 2);
    while read(UART0, STATE) & RX_FULL != 0 {
        let byte = read(UART0, DATA) as u8;
        let _ = FROM_HOST.try_write(&[byte]);
    }
}

/// Drain [`TO_HOST`] into the transmitter, forever.
pub async fn send_to_host() -> ! {
    let mut buf = [0u8; 256];
    loop {
        let n = TO_HOST.read(&mut buf).await;
        for &byte in &buf[..n] {
            while read(UART0, STATE) & TX_FULL != 0 {}
            write(UART0, DATA, byte as u32);
        }
    }
}
