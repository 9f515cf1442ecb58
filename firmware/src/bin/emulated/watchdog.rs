//! The controller's watchdog on the emulated board.
//!
//! QEMU models the mps2's CMSDK APB watchdog (0x4000_8000, clocked at 25 MHz): its counter
//! runs down from `LOAD`; at zero it raises its interrupt, wired to the NMI, and reloads; at zero
//! again with the interrupt still raised it resets the machine. The sampling loop feeds it every
//! tick (clearing the interrupt reloads it). The NMI records the cause (`ResetCause::Watchdog`) and resets
//! at once, the watchdog's own reset backs it up. The same policy as the real board's IWDG: only a
//! sampling loop that completes its ticks keeps the controller running.

use crate::mmio::{read, write, Block};

const WATCHDOG: Block = Block::Watchdog;
const LOAD: usize = 0x000;
const CONTROL: usize = 0x008;
const INTCLR: usize = 0x00C;
const LOCK: usize = 0xC00;
const UNLOCK_KEY: u32 = 0x1ACC_E551;
const INTEN: u32 = 1;
const RESEN: u32 = 1 << 1;
/// Watchdog clock (the mps2's system clock).
const COUNTS_HZ: u32 = 25_000_000;
/// Time without a completed tick before the controller is reset, ms: 768 ticks, long enough
/// that a QEMU process descheduled by a loaded host is not reset, short for a test. (The real
/// board's timeout is set by its flash erase, see its `watchdog` docs.)
pub const TIMEOUT_MS: u32 = 1000;

/// Start the watchdog.
pub fn start() {
    write(WATCHDOG, LOCK, UNLOCK_KEY);
    write(WATCHDOG, LOAD, COUNTS_HZ / 1000 * TIMEOUT_MS);
    write(WATCHDOG, CONTROL, INTEN | RESEN);
    write(WATCHDOG, LOCK, 0);
}

/// The sampling loop completed a tick: reload the counter.
pub fn feed() {
    write(WATCHDOG, LOCK, UNLOCK_KEY);
    write(WATCHDOG, INTCLR, 1);
    write(WATCHDOG, LOCK, 0);
}

/// Whether the watchdog's interrupt is raised (the NMI's source).
pub fn expired() -> bool {
    read(WATCHDOG, 0x010) & 1 != 0
}
