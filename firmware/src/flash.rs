//! Power-loss-safe parameter storage on NOR flash: two slots, written A/B with a commit word.
//!
//! Slot layout (one erase sector each): magic `KSL1` ‖ sequence u32 ‖ blob length u16 ‖ 0xFFFF ‖
//! CRC-32 of the blob ‖ blob … ‖ commit word (last 4 bytes of the sector).
//! A store goes to the slot *not* holding the active parameters: erase, write the blob, write
//! the header, and only then write the commit word. At boot the valid slot (commit word set,
//! magic, length and CRC right) with the highest sequence wins. A power cut at any point leaves
//! the old slot untouched and the new one either uncommitted (ignored) or complete: the
//! controller boots with the old parameters or the new ones, never neither and never a mix.

use kincal_protocol::params::{BLOB_CRC, MAX_PARAM_BLOB};

/// Bytes programmed at once.
pub const WORD: usize = 4;
const MAGIC: [u8; 4] = *b"KSL1";
const HEADER: usize = 16;
const COMMITTED: [u8; 4] = *b"CMIT";

/// Why a flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// Offset or length outside the device.
    OutOfBounds,
    /// The device lost power (simulation) or refused the operation.
    Failed,
}

/// NOR flash: erase sets a whole sector to 0xFF, programming can only clear bits.
pub trait NorFlash {
    /// Bytes per erase sector.
    fn sector_size(&self) -> usize;
    /// Read `buf.len()` bytes at `offset`.
    fn read(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), FlashError>;
    /// Erase the sector starting at `offset`.
    fn erase(&mut self, offset: usize) -> Result<(), FlashError>;
    /// Program one word at a word-aligned `offset` (bits can only go from 1 to 0).
    fn program(&mut self, offset: usize, word: [u8; WORD]) -> Result<(), FlashError>;
}

/// The active parameter blob's identity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stored {
    /// Slot index (0 or 1).
    pub slot: usize,
    /// Write sequence number.
    pub sequence: u32,
    /// Blob length, bytes.
    pub len: usize,
    /// CRC-32 of the blob.
    pub crc: u32,
}

/// A/B parameter store on the first two sectors of a [`NorFlash`].
pub struct ParamStore<F: NorFlash> {
    flash: F,
    active: Option<Stored>,
}

impl<F: NorFlash> ParamStore<F> {
    /// Scan both slots and pick the valid one with the highest sequence.
    pub fn mount(mut flash: F) -> Self {
        let active = (0..2).filter_map(|slot| inspect(&mut flash, slot)).max_by_key(|s| s.sequence);
        ParamStore { flash, active }
    }

    /// The active blob, if any.
    pub fn active(&self) -> Option<Stored> {
        self.active
    }

    /// Read the active blob into `buf`; returns its bytes.
    pub fn load<'a>(&mut self, buf: &'a mut [u8; MAX_PARAM_BLOB]) -> Option<&'a [u8]> {
        let s = self.active?;
        let base = s.slot * self.flash.sector_size();
        self.flash.read(base + HEADER, &mut buf[..s.len]).ok()?;
        Some(&buf[..s.len])
    }

    /// Store `blob` in the other slot and make it active once committed.
    pub fn store(&mut self, blob: &[u8]) -> Result<(), FlashError> {
        let sector = self.flash.sector_size();
        if blob.len() > MAX_PARAM_BLOB || HEADER + blob.len() + WORD > sector {
            return Err(FlashError::OutOfBounds);
        }
        let slot = self.active.map_or(0, |s| 1 - s.slot);
        let sequence = self.active.map_or(1, |s| s.sequence.wrapping_add(1));
        let base = slot * sector;
        self.flash.erase(base)?;
        for (k, chunk) in blob.chunks(WORD).enumerate() {
            let mut word = [0xFF; WORD];
            word[..chunk.len()].copy_from_slice(chunk);
            self.flash.program(base + HEADER + k * WORD, word)?;
        }
        let crc = BLOB_CRC.checksum(blob);
        let len = (blob.len() as u16).to_le_bytes();
        let words: [[u8; WORD]; 4] =
            [MAGIC, sequence.to_le_bytes(), [len[0], len[1], 0xFF, 0xFF], crc.to_le_bytes()];
        for (k, w) in words.into_iter().enumerate() {
            self.flash.program(base + k * WORD, w)?;
        }
        self.flash.program(base + sector - WORD, COMMITTED)?;
        self.active = Some(Stored { slot, sequence, len: blob.len(), crc });
        Ok(())
    }

    /// Give the flash back (e.g. to simulate a reboot).
    pub fn into_flash(self) -> F {
        self.flash
    }
}

fn inspect<F: NorFlash>(flash: &mut F, slot: usize) -> Option<Stored> {
    let sector = flash.sector_size();
    let base = slot * sector;
    let mut commit = [0u8; WORD];
    flash.read(base + sector - WORD, &mut commit).ok()?;
    let mut header = [0u8; HEADER];
    flash.read(base, &mut header).ok()?;
    if commit != COMMITTED || header[..4] != MAGIC {
        return None;
    }
    let sequence = u32::from_le_bytes([header[4], header[5], header[6], header[7]]);
    let len = u16::from_le_bytes([header[8], header[9]]) as usize;
    let crc = u32::from_le_bytes([header[12], header[13], header[14], header[15]]);
    if len > MAX_PARAM_BLOB || HEADER + len + WORD > sector {
        return None;
    }
    let mut blob = [0u8; MAX_PARAM_BLOB];
    flash.read(base + HEADER, &mut blob[..len]).ok()?;
    (BLOB_CRC.checksum(&blob[..len]) == crc).then_some(Stored { slot, sequence, len, crc })
}

/// NOR flash in RAM with `N` bytes (two sectors of `N/2`), for the emulated board and tests.
/// With a power budget it fails after that many erase/program operations, leaving the
/// interrupted operation half done, as a real power cut would.
pub struct RamNor<const N: usize> {
    /// Contents.
    pub bytes: [u8; N],
    /// Operations left before the simulated power cut (`None`: unlimited).
    pub power_budget: Option<u32>,
}

impl<const N: usize> RamNor<N> {
    /// An erased device.
    pub const fn new() -> Self {
        RamNor { bytes: [0xFF; N], power_budget: None }
    }

    fn spend(&mut self) -> bool {
        match &mut self.power_budget {
            None => true,
            Some(0) => false,
            Some(n) => {
                *n -= 1;
                true
            }
        }
    }
}

impl<const N: usize> Default for RamNor<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> NorFlash for RamNor<N> {
    fn sector_size(&self) -> usize {
        N / 2
    }

    fn read(&mut self, offset: usize, buf: &mut [u8]) -> Result<(), FlashError> {
        let src = self.bytes.get(offset..offset + buf.len()).ok_or(FlashError::OutOfBounds)?;
        buf.copy_from_slice(src);
        Ok(())
    }

    fn erase(&mut self, offset: usize) -> Result<(), FlashError> {
        let sector = self.sector_size();
        if !offset.is_multiple_of(sector) || offset + sector > N {
            return Err(FlashError::OutOfBounds);
        }
        if !self.spend() {
            // Interrupted: the first half is erased, the rest keeps its old bits.
            self.bytes[offset..offset + sector / 2].fill(0xFF);
            return Err(FlashError::Failed);
        }
        self.bytes[offset..offset + sector].fill(0xFF);
        Ok(())
    }

    fn program(&mut self, offset: usize, word: [u8; WORD]) -> Result<(), FlashError> {
        if !offset.is_multiple_of(WORD) || offset + WORD > N {
            return Err(FlashError::OutOfBounds);
        }
        let interrupted = !self.spend();
        let n = if interrupted { WORD / 2 } else { WORD };
        for (byte, w) in self.bytes[offset..offset + n].iter_mut().zip(word) {
            *byte &= w;
        }
        if interrupted {
            Err(FlashError::Failed)
        } else {
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Flash = RamNor<4096>;

    fn blob(tag: u8, len: usize) -> Vec<u8> {
        (0..len).map(|k| tag.wrapping_add(k as u8)).collect()
    }

    fn load(store: &mut ParamStore<Flash>) -> Option<Vec<u8>> {
        let mut buf = [0u8; MAX_PARAM_BLOB];
        store.load(&mut buf).map(|b| b.to_vec())
    }

    #[test]
    fn stores_alternate_and_survive_a_reboot() {
        let mut store = ParamStore::mount(Flash::new());
        assert_eq!(load(&mut store), None);
        for (k, len) in [(1u8, 500usize), (2, 37), (3, 1024)] {
            store.store(&blob(k, len)).unwrap();
            store = ParamStore::mount(store.into_flash());
            assert_eq!(load(&mut store), Some(blob(k, len)), "write {k}");
        }
    }

    /// Cut the power after every possible number of flash operations during an update: the
    /// store must come back with the old blob or the new one, never neither, never a mix.
    #[test]
    fn power_cut_at_every_step_keeps_old_or_new() {
        let (old, new) = (blob(10, 300), blob(99, 301));
        let mut steps_seen_new = 0;
        for budget in 0..200 {
            let mut store = ParamStore::mount(Flash::new());
            store.store(&blob(1, 64)).unwrap();
            store.store(&old).unwrap(); // the second slot now holds `old`, the first an older blob
            let mut flash = store.into_flash();
            flash.power_budget = Some(budget);
            let mut store = ParamStore::mount(flash);
            let finished = store.store(&new).is_ok();
            let mut flash = store.into_flash();
            flash.power_budget = None;
            let mut rebooted = ParamStore::mount(flash);
            let got = load(&mut rebooted).expect("never neither");
            assert!(got == old || got == new, "budget {budget}: a mix");
            if finished {
                assert_eq!(got, new, "budget {budget}: a finished store must be active");
            }
            if got == new {
                steps_seen_new += 1;
            }
            // After a cut the next store still works and does not touch the active slot.
            rebooted.store(&blob(7, 10)).unwrap();
            let mut again = ParamStore::mount(rebooted.into_flash());
            assert_eq!(load(&mut again), Some(blob(7, 10)));
        }
        assert!(steps_seen_new > 0 && steps_seen_new < 200);
    }
}
