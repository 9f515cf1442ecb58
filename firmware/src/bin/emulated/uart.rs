//! CMSDK APB UART0 of the mps2: the host link (QEMU connects it to a pty or a TCP socket).

use crate::irq::Irq;
use crate::mmio::{read, write, Block};
use cortex_m::peripheral::NVIC;
use kincal_firmware::app::{FROM_HOST, TO_HOST};

const UART0: Block = Block::Uart0;
const DATA: usize = 0x0;
const STATE: usize = 0x4;
const CTRL: usize = 0x8;
const INT: usize = 0xC;
const BAUDDIV: usize = 0x10;
const TX_FULL: u32 = 1;
const RX_FULL: u32 = 2;

/// Enable transmit, receive and the receive interrupt.
pub fn init() {
    write(UART0, BAUDDIV, 16);
    write(UART0, CTRL, 0b1011); // TX, RX, RX interrupt
                                // SAFETY: the receive handler is installed (DefaultHandler dispatch) and touches only
                                // FROM_HOST, which is behind a critical-section lock.
    unsafe { NVIC::unmask(Irq::UART0_RX) };
}

/// Receive interrupt: move every waiting byte into [`FROM_HOST`] (one short critical section).
pub fn on_rx() {
    write(UART0, INT, 2);
    let mut bytes = [0u8; 16];
    let mut n = 0;
    while n < bytes.len() && read(UART0, STATE) & RX_FULL != 0 {
        bytes[n] = read(UART0, DATA) as u8;
        n += 1;
    }
    // try_write stops at the ring buffer's wrap point: write the rest too (bytes that do not
    // fit a full buffer are lost and show as a bad frame on the controller).
    let mut rest = &bytes[..n];
    while let Ok(k @ 1..) = FROM_HOST.try_write(rest) {
        rest = &rest[k..];
    }
}

/// Drain [`TO_HOST`] into the transmitter, forever.
pub async fn send_to_host() -> ! {
    let mut buf = [0u8; 256];
    loop {
        let n = TO_HOST.read(&mut buf).await;
        for &byte in &buf[..n] {
            // A full transmitter (QEMU's backend not keeping up) must not hold up the sampling
            // task: yield to the executor instead of spinning.
            while read(UART0, STATE) & TX_FULL != 0 {
                embassy_futures::yield_now().await;
            }
            write(UART0, DATA, byte as u32);
        }
    }
}
