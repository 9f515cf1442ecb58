//! The emulated controller: QEMU `mps2-an386` (Cortex-M4F), emulated encoders, UART0 to the host.
//!
//! Start it with `cargo emulator` (see README): QEMU prints the pty to connect to.
#![no_std]
#![no_main]
// The tick-bench build runs the measurement instead of the tasks.
#![cfg_attr(feature = "tick-bench", allow(dead_code, unused_imports))]

mod bus;
mod irq;
mod mmio;
mod nor;
#[cfg(feature = "tick-bench")]
mod tick_bench;
mod time_driver;
mod uart;

use bus::EmulatedBus;
use core::cell::RefCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m_rt::{entry, exception};
use cortex_m_semihosting::hprintln;
use embassy_executor::raw::Executor;
use embassy_sync::blocking_mutex::Mutex;
#[cfg(not(feature = "tick-bench"))]
use kincal_firmware::app::Shared;
use kincal_firmware::app::{self, SharedCell};
use kincal_firmware::controller::Action;
#[cfg(not(feature = "tick-bench"))]
use kincal_firmware::{controller::Controller, encoders::Sampler};
use nor::EmulatedNor;

#[cfg_attr(feature = "tick-bench", allow(dead_code))]
static SHARED: SharedCell<EmulatedNor, EmulatedBus> = Mutex::new(RefCell::new(None));
static WORK_PENDING: AtomicBool = AtomicBool::new(true);
static mut EXECUTOR: MaybeUninit<Executor> = MaybeUninit::uninit();

#[embassy_executor::task]
async fn sample_encoders() -> ! {
    app::sample_encoders(&SHARED).await
}

#[embassy_executor::task]
async fn serve_host() -> ! {
    app::serve_host(&SHARED, |action, bus| match action {
        Action::Simulate(request) => bus.apply(&request),
        Action::Reset => cortex_m::peripheral::SCB::sys_reset(),
        Action::None => {}
    })
    .await
}

#[embassy_executor::task]
async fn send_to_host() -> ! {
    uart::send_to_host().await
}

#[entry]
fn main() -> ! {
    #[cfg(feature = "tick-bench")]
    {
        tick_bench::run()
    }
    #[cfg(not(feature = "tick-bench"))]
    run()
}

#[cfg(not(feature = "tick-bench"))]
fn run() -> ! {
    let controller = Controller::new(
        concat!("kincal-fw ", env!("CARGO_PKG_VERSION")),
        "mps2-an386 (emulated)",
        true,
        EmulatedNor::take(),
    );
    let has_params = controller.params().is_some();
    SHARED.lock(|s| {
        *s.borrow_mut() = Some(Shared { controller, sampler: Sampler::default(), bus: EmulatedBus::new() })
    });
    uart::init();
    time_driver::init();
    hprintln!(
        "kincal emulated controller ready on UART0 (stored parameters: {})",
        if has_params { "yes" } else { "none" }
    );
    // SAFETY: written once here, before anything can read it; lives for the whole program.
    let executor: &'static Executor = unsafe {
        let slot = &mut *core::ptr::addr_of_mut!(EXECUTOR);
        slot.write(Executor::new(core::ptr::null_mut()))
    };
    let spawner = executor.spawner();
    match (sample_encoders(), serve_host(), send_to_host()) {
        (Ok(a), Ok(b), Ok(c)) => {
            spawner.spawn(a);
            spawner.spawn(b);
            spawner.spawn(c);
        }
        _ => panic!("task already spawned"),
    }
    loop {
        WORK_PENDING.store(false, Ordering::SeqCst);
        // SAFETY: poll is never called re-entrantly: only this loop calls it.
        unsafe { executor.poll() };
        // Sleep until an interrupt unless a task was woken meanwhile (WFE is a no-op in QEMU).
        cortex_m::interrupt::free(|_| {
            if !WORK_PENDING.load(Ordering::SeqCst) {
                cortex_m::asm::wfi();
            }
        });
    }
}

#[unsafe(export_name = "__pender")]
fn pender(_context: *mut ()) {
    WORK_PENDING.store(true, Ordering::SeqCst);
}

#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    match irqn {
        n if n == uart::RX_IRQ as i16 => uart::on_rx(),
        n if n == time_driver::TIMER0_IRQ as i16 => time_driver::on_wrap(),
        n if n == time_driver::TIMER1_IRQ as i16 => time_driver::on_alarm(),
        _ => {}
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("firmware panic: {}", info);
    cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    loop {}
}
