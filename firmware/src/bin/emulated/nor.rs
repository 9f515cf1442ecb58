//! The emulated controller's parameter flash: 4 KiB of data RAM that the startup code never
//! touches (`.uninit`), so it keeps its contents across a controller reset (SYSRESETREQ), as
//! flash would. It starts zeroed when QEMU starts: no valid slot, no parameters.

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use kincal_firmware::flash::{FlashError, NorFlash, WORD};

const SIZE: usize = 4096;

#[unsafe(link_section = ".uninit.PARAM_FLASH")]
static mut PARAM_FLASH: MaybeUninit<[u8; SIZE]> = MaybeUninit::uninit();

static TAKEN: AtomicBool = AtomicBool::new(false);

/// Handle to the emulated flash; at most one exists.
pub struct EmulatedNor(());

impl EmulatedNor {
    /// The flash the first time, `None` after that.
    pub fn take() -> Option<Self> {
        (!TAKEN.swap(true, Ordering::SeqCst)).then_some(EmulatedNor(()))
    }

    fn bytes(&mut self) -> &mut [u8; SIZE] {
        // SAFETY: `take` hands out one handle only and this is its `&mut self`, so no other
        // reference to PARAM_FLASH exists; every bit pattern is a valid [u8; N].
        unsafe { (*core::ptr::addr_of_mut!(PARAM_FLASH)).assume_init_mut() }
    }
}

impl NorFlash for EmulatedNor {
    fn sector_size(&self) -> usize {
        SIZE / 2
    }

    fn read(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), FlashError> {
        buf.copy_from_slice(self.bytes().get(offset..offset + buf.len()).ok_or(FlashError::OutOfBounds)?);
        Ok(())
    }

    fn erase(&mut self, offset: usize) -> Result<(), FlashError> {
        let sector = self.sector_size();
        self.bytes().get_mut(offset..offset + sector).ok_or(FlashError::OutOfBounds)?.fill(0xFF);
        Ok(())
    }

    fn program(&mut self, offset: usize, word: [u8; WORD]) -> Result<(), FlashError> {
        let dst = self.bytes().get_mut(offset..offset + WORD).ok_or(FlashError::OutOfBounds)?;
        for (d, w) in dst.iter_mut().zip(word) {
            *d &= w;
        }
        Ok(())
    }
}
