//! Parameter flash of the real controller: sectors 10 and 11 (128 KiB each) of the STM32F405.

use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::Peri;
use kincal_firmware::flash::{FlashError, NorFlash, WORD};

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

impl NorFlash for Stm32Nor {
    fn sector_size(&self) -> usize {
        SECTOR
    }

    fn read(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), FlashError> {
        self.flash.blocking_read(AREA + offset as u32, buf).map_err(|_| FlashError::Failed)
    }

    fn erase(&mut self, offset: usize) -> Result<(), FlashError> {
        let from = AREA + offset as u32;
        self.flash.blocking_erase(from, from + SECTOR as u32).map_err(|_| FlashError::Failed)
    }

    fn program(&mut self, offset: usize, word: [u8; WORD]) -> Result<(), FlashError> {
        self.flash.blocking_write(AREA + offset as u32, &word).map_err(|_| FlashError::Failed)
    }
}
