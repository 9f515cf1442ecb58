//! Parameter flash of the real controller: sectors 10 and 11 (128 KiB each) of the STM32F405,
//! seen as a two-sector embedded-storage [`NorFlash`] starting at sector 10.
//!
//! The F405 has one flash bank: while a sector is erased (1–2 s for 128 KiB), instruction
//! fetches from flash stall and nothing runs. The parameter log therefore erases its spare
//! sector only while nothing samples (at boot, or idle after the ~239th commit filled a
//! sector); a commit that would need the erase during a stream or window is refused
//! (`FlashBusy`). Commits themselves program words (~16 µs each, ~140 words for a 526-byte
//! set: the sampling task runs about 2 ms late once per commit).

use embassy_stm32::flash::{Blocking, Error, Flash};
use embassy_stm32::Peri;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// Offset of sector 10 from the start of flash.
const AREA: u32 = 0x000C_0000;
const SECTOR: usize = 128 * 1024;

/// The two parameter sectors.
pub struct Stm32Nor {
    flash: Flash<'static, Blocking>,
}

impl Stm32Nor {
    /// Take the flash peripheral.
    pub fn new(flash: Peri<'static, embassy_stm32::peripherals::FLASH>) -> Self {
        Stm32Nor { flash: Flash::new_blocking(flash) }
    }
}

impl ErrorType for Stm32Nor {
    type Error = Error;
}

impl ReadNorFlash for Stm32Nor {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        self.flash.blocking_read(AREA + offset, bytes)
    }

    fn capacity(&self) -> usize {
        2 * SECTOR
    }
}

impl NorFlash for Stm32Nor {
    const WRITE_SIZE: usize = <Flash<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = SECTOR;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        self.flash.blocking_erase(AREA + from, AREA + to)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        self.flash.blocking_write(AREA + offset, bytes)
    }
}
