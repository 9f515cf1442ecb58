//! The emulated controller's parameter flash: 4 KiB of data RAM (two 2 KiB sectors) that the
//! startup code never touches (`.uninit`), so it keeps its contents across a controller reset
//! (SYSRESETREQ), as flash would. It starts zeroed when QEMU starts: no valid record, no
//! parameters. Programming only clears bits and erasing sets a sector to 0xFF, as on NOR flash.

use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, Ordering};
use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash};

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

    fn range(offset: u32, len: usize) -> Result<core::ops::Range<usize>, NorFlashErrorKind> {
        let from = offset as usize;
        (from + len <= SIZE).then_some(from..from + len).ok_or(NorFlashErrorKind::OutOfBounds)
    }
}

impl ErrorType for EmulatedNor {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for EmulatedNor {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let range = Self::range(offset, bytes.len())?;
        bytes.copy_from_slice(&self.bytes()[range]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        SIZE
    }
}

impl NorFlash for EmulatedNor {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = SIZE / 2;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let aligned = |v: u32| (v as usize).is_multiple_of(Self::ERASE_SIZE);
        if !aligned(from) || !aligned(to) || from > to {
            return Err(NorFlashErrorKind::NotAligned);
        }
        let range = Self::range(from, (to - from) as usize)?;
        self.bytes()[range].fill(0xFF);
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        if !(offset as usize).is_multiple_of(Self::WRITE_SIZE)
            || !bytes.len().is_multiple_of(Self::WRITE_SIZE)
        {
            return Err(NorFlashErrorKind::NotAligned);
        }
        let range = Self::range(offset, bytes.len())?;
        for (d, w) in self.bytes()[range].iter_mut().zip(bytes) {
            *d &= w;
        }
        Ok(())
    }
}
