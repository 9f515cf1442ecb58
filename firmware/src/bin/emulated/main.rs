//! The emulated controller: QEMU `mps2-an386` (Cortex-M4F), emulated encoders, UART0 to the host.
//!
//! Start it with `cargo emulator` (see README): QEMU prints the pty to connect to. Start option
//! (semihosting command line, `-semihosting-config …,arg=emulated,arg=arm-id=NAME`): the arm
//! identity, default `emulated-arm` (or `KINCAL_ARM_ID` at build time).
#![no_std]
#![no_main]
// The tick-bench build runs the measurement instead of the tasks.
#![cfg_attr(feature = "tick-bench", allow(dead_code, unused_imports))]

mod irq;
mod mmio;
mod nor;
#[cfg(feature = "tick-bench")]
mod tick_bench;
mod time_driver;
mod uart;
mod watchdog;

use core::cell::RefCell;
use core::sync::atomic::{AtomicBool, Ordering};
use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::hprintln;
use embassy_executor::raw::Executor;
use embassy_sync::blocking_mutex::raw::ThreadModeRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use irq::Irq;
#[cfg(not(feature = "tick-bench"))]
use kincal_firmware::app::Shared;
use kincal_firmware::app::{self, SharedCell};
use kincal_firmware::biss_master::BissMaster;
use kincal_firmware::controller::Action;
#[cfg(not(feature = "tick-bench"))]
use kincal_firmware::controller::Controller;
use kincal_firmware::emulated_encoders::{EmulatedEncoder, EmulatedEncoders, SharedEncoders};
use kincal_firmware::reset_cause;
#[cfg(not(feature = "tick-bench"))]
use kincal_firmware::trust::{Trust, BUILD_ARM_ID, EMULATED_ARM_ID};
use kincal_protocol::messages::{Crash, Request, ResetCause, SimFaults};
use nor::EmulatedNor;
use static_cell::StaticCell;

#[cfg_attr(feature = "tick-bench", allow(dead_code))]
static SHARED: StaticCell<SharedCell<EmulatedNor>> = StaticCell::new();
/// The emulated arm's encoders: read by the BiSS-C master, posed by the host.
static ENCODERS: SharedEncoders<ThreadModeRawMutex> = Mutex::new(RefCell::new(EmulatedEncoders::new()));
static WORK_PENDING: AtomicBool = AtomicBool::new(true);
static EXECUTOR: StaticCell<Executor> = StaticCell::new();

#[embassy_executor::task]
async fn sample_encoders(shared: &'static SharedCell<EmulatedNor>) -> ! {
    app::sample_encoders(shared, BissMaster::new(EmulatedEncoder::all(&ENCODERS)), watchdog::feed).await
}

#[embassy_executor::task]
async fn serve_host(shared: &'static SharedCell<EmulatedNor>) -> ! {
    app::serve_host(shared, |action| match action {
        Action::Simulate(request) => {
            ENCODERS.lock(|e| e.borrow_mut().apply(&request));
            if let Request::SimFaults(SimFaults { crash: Crash::Panic, .. }) = request {
                panic!("panic injected by the host (emulated-arm faults --crash panic)");
            }
        }
        Action::Reset => reset_cause::reset_because(ResetCause::Software),
        // serve_host carries out the signature check itself.
        Action::None | Action::Verify => {}
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

/// The semihosting command line QEMU was started with (`arg=…` of `-semihosting-config`), into
/// `buf`; empty when there is none.
fn command_line(buf: &mut [u8; 128]) -> &str {
    let mut block = [buf.as_mut_ptr() as usize, buf.len() - 1];
    // SAFETY: SYS_GET_CMDLINE writes at most block[1] bytes plus a NUL into `buf` and the length
    // into block[1]; both outlive the call.
    let failed = unsafe {
        cortex_m_semihosting::syscall1(cortex_m_semihosting::nr::GET_CMDLINE, block.as_mut_ptr() as usize)
    } != 0;
    let len = if failed { 0 } else { block[1].min(buf.len() - 1) };
    core::str::from_utf8(&buf[..len]).unwrap_or("")
}

#[cfg(not(feature = "tick-bench"))]
fn run() -> ! {
    let mut line = [0u8; 128];
    let arm_id = command_line(&mut line)
        .split(' ')
        .find_map(|arg| arg.strip_prefix("arm-id="))
        .or(BUILD_ARM_ID)
        .unwrap_or(EMULATED_ARM_ID);
    let Some(trust) = Trust::provisioned(arm_id) else {
        // The panic handler prints this and stops QEMU with a failure.
        panic!("arm-id={arm_id} is not an arm identity (1 to 24 letters, digits or -_.:)")
    };
    let mut controller = Controller::new(
        concat!("kincal-fw ", env!("CARGO_PKG_VERSION")),
        "mps2-an386 (emulated)",
        true,
        trust,
        EmulatedNor::take().expect("the flash is taken once, here"),
    );
    // No reset flags on this board: what the firmware recorded, else a power-on (QEMU starts
    // with zeroed RAM).
    let reset_cause = reset_cause::take_recorded().unwrap_or(ResetCause::PowerOn);
    controller.set_boot(reset_cause, 0);
    let has_params = controller.params().is_some();
    // Sampling has not started: the moment to erase the parameter log's spare sector if needed.
    controller.maintain_flash();
    let shared = SHARED.init(Mutex::new(RefCell::new(Shared::new(controller))));
    uart::init();
    time_driver::init();
    watchdog::start();
    hprintln!(
        "kincal emulated controller ready on UART0 (arm {}, stored parameters: {}; reset cause: {:?})",
        arm_id,
        if has_params { "yes" } else { "none" },
        reset_cause
    );
    let executor: &'static Executor = EXECUTOR.init(Executor::new(core::ptr::null_mut()));
    let spawner = executor.spawner();
    match (sample_encoders(shared), serve_host(shared), send_to_host()) {
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
    match Irq::from_handler(irqn) {
        Some(Irq::UART0_RX) => uart::on_rx(),
        Some(Irq::TIMER0) => time_driver::on_wrap(),
        Some(Irq::TIMER1) => time_driver::on_alarm(),
        _ => {}
    }
}

/// The watchdog expired (its interrupt is the NMI): the sampling loop stopped. Reset.
#[exception]
// SAFETY (cortex-m-rt's requirement for an NMI handler): it shares no state with the code it
// interrupts except the reset word, which it only writes before resetting.
unsafe fn NonMaskableInt() {
    if watchdog::expired() {
        reset_cause::reset_because(ResetCause::Watchdog);
    }
}

/// A processor fault (bad memory access, stack overflow): record it and reset.
#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    reset_cause::reset_because(ResetCause::Fault)
}

/// A panic: say so on the semihosting console, record it and reset (the field behaviour; the
/// tick bench exits instead).
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("firmware panic: {}", info);
    if cfg!(feature = "tick-bench") {
        cortex_m_semihosting::debug::exit(cortex_m_semihosting::debug::EXIT_FAILURE);
    }
    reset_cause::reset_because(ResetCause::Panic)
}
