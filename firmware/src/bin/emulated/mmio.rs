//! Memory-mapped registers of the mps2-an386 peripherals this board uses.
//!
//! Only the blocks below can be addressed, and offsets are confined to their 4 KiB block and
//! word-aligned, so these safe functions can only touch device registers, never memory.

/// A peripheral block of the mps2-an386 memory map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Block {
    /// CMSDK APB timer 0 (free-running time base, tick bench).
    Timer0 = 0x4000_0000,
    /// CMSDK APB timer 1 (alarm).
    Timer1 = 0x4000_1000,
    /// CMSDK APB UART 0 (host link).
    Uart0 = 0x4000_4000,
    /// CMSDK APB watchdog.
    Watchdog = 0x4000_8000,
}

fn address(block: Block, offset: usize) -> usize {
    block as usize + (offset & 0xFFC)
}

/// Write `value` to the register at `offset` in `block`.
pub fn write(block: Block, offset: usize, value: u32) {
    // SAFETY: the address is a word-aligned register inside one of the peripheral blocks above
    // (device memory, not RAM): writing it cannot break memory safety.
    unsafe { core::ptr::write_volatile(address(block, offset) as *mut u32, value) }
}

/// Read the register at `offset` in `block`.
pub fn read(block: Block, offset: usize) -> u32 {
    // SAFETY: as for `write`; these registers have no read side effects on memory.
    unsafe { core::ptr::read_volatile(address(block, offset) as *const u32) }
}
