//! Memory-mapped registers of the mps2-an386 peripherals.

/// Write `value` to the register at `base + offset`.
pub fn write(base: usize, offset: usize, value: u32) {
    // SAFETY: callers pass registers of the mps2-an386 memory map (CMSDK timers and UART).
    unsafe { core::ptr::write_volatile((base + offset) as *mut u32, value) }
}

/// Read the register at `base + offset`.
pub fn read(base: usize, offset: usize) -> u32 {
    // SAFETY: callers pass registers of the mps2-an386 memory map (CMSDK timers and UART).
    unsafe { core::ptr::read_volatile((base + offset) as *const u32) }
}
