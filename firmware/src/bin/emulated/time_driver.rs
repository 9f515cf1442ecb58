//! embassy time driver on the two CMSDK APB timers of the mps2 (25 MHz).
//!
//! TIMER0 runs free from 0xFFFF_FFFF down; its wrap interrupt extends it to 64 bits. TIMER1 is a
//! one-shot alarm for the earliest timer-queue deadline. embassy ticks are 12 MHz (768 Hz divides
//! it exactly), converted from the 25 MHz timer counts.

use crate::irq::Irq;
use crate::mmio::{read, write, Block};
use core::cell::{Cell, RefCell};
use core::task::Waker;
use cortex_m::peripheral::NVIC;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

const TIMER0: Block = Block::Timer0;
const TIMER1: Block = Block::Timer1;
const CTRL: usize = 0x0;
const VALUE: usize = 0x4;
const RELOAD: usize = 0x8;
const INT: usize = 0xC;
const ENABLE: u32 = 1;
const IRQ_ENABLE: u32 = 1 << 3;
/// Timer clock.
const COUNTS_HZ: u64 = 25_000_000;

struct Mps2Time {
    periods: Mutex<CriticalSectionRawMutex, Cell<u64>>,
    queue: Mutex<CriticalSectionRawMutex, RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: Mps2Time = Mps2Time {
    periods: Mutex::new(Cell::new(0)),
    queue: Mutex::new(RefCell::new(Queue::new())),
});

fn ticks_from_counts(counts: u64) -> u64 {
    (counts as u128 * embassy_time_driver::TICK_HZ as u128 / COUNTS_HZ as u128) as u64
}

fn counts_from_ticks(ticks: u64) -> u64 {
    (ticks as u128 * COUNTS_HZ as u128).div_ceil(embassy_time_driver::TICK_HZ as u128) as u64
}

impl Mps2Time {
    fn now_counts(&self) -> u64 {
        critical_section::with(|cs| {
            let first = read(TIMER0, VALUE);
            let wrapped = read(TIMER0, INT) & 1 != 0;
            let second = read(TIMER0, VALUE);
            let periods = self.periods.borrow(cs).get();
            // A wrap not yet handled: count it and use the value read after it.
            let (periods, value) = if wrapped { (periods + 1, second) } else { (periods, first) };
            (periods << 32) + (u32::MAX - value) as u64
        })
    }

    fn set_alarm(&self, at_ticks: u64) {
        write(TIMER1, CTRL, 0);
        write(TIMER1, INT, 1);
        if at_ticks == u64::MAX {
            return;
        }
        let delta =
            counts_from_ticks(at_ticks).saturating_sub(self.now_counts()).clamp(2, u32::MAX as u64) as u32;
        write(TIMER1, RELOAD, delta);
        write(TIMER1, VALUE, delta);
        write(TIMER1, CTRL, ENABLE | IRQ_ENABLE);
    }
}

impl Driver for Mps2Time {
    fn now(&self) -> u64 {
        ticks_from_counts(self.now_counts())
    }

    fn schedule_wake(&self, at: u64, waker: &Waker) {
        critical_section::with(|cs| {
            let mut queue = self.queue.borrow(cs).borrow_mut();
            if queue.schedule_wake(at, waker) {
                let next = queue.next_expiration(self.now());
                self.set_alarm(next);
            }
        });
    }
}

/// Start the free-running timer and enable both interrupts.
pub fn init() {
    write(TIMER0, CTRL, 0);
    write(TIMER0, RELOAD, u32::MAX);
    write(TIMER0, VALUE, u32::MAX);
    write(TIMER0, INT, 1);
    write(TIMER0, CTRL, ENABLE | IRQ_ENABLE);
    write(TIMER1, CTRL, 0);
    // SAFETY: the handlers are installed (DefaultHandler dispatch) before the timers can fire.
    unsafe {
        NVIC::unmask(Irq::TIMER0);
        NVIC::unmask(Irq::TIMER1);
    }
}

/// TIMER0 wrapped: one more period of 2³² counts.
pub fn on_wrap() {
    critical_section::with(|cs| {
        if read(TIMER0, INT) & 1 != 0 {
            write(TIMER0, INT, 1);
            let p = DRIVER.periods.borrow(cs);
            p.set(p.get() + 1);
        }
    });
}

/// TIMER1 expired: wake what is due and arm the next deadline.
pub fn on_alarm() {
    critical_section::with(|cs| {
        write(TIMER1, INT, 1);
        let mut queue = DRIVER.queue.borrow(cs).borrow_mut();
        let next = queue.next_expiration(DRIVER.now());
        DRIVER.set_alarm(next);
    });
}
