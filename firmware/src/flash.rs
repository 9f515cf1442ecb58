//! Power-loss-safe parameter storage on NOR flash (embedded-storage's [`NorFlash`]): an
//! append-only log over two erase sectors, so a commit only programs words. When the active
//! sector is full (every 3 commits of a 526-byte set on the emulated 2 KiB sectors, ~239 on the
//! STM32's 128 KiB ones) the log continues in the other, the spare, which must be erased by then.
//!
//! Erasing is the slow part (1–2 s for an F405 128 KiB sector, during which a single-bank part
//! fetches no instructions), so the spare is erased ahead of time, when nothing samples: at
//! boot and when the controller is idle after a sector switch ([`ParamStore::erase_spare`]). A
//! store that would need the erase now is refused while the caller says erasing is not allowed
//! ([`FlashError::SpareNotErased`]), and then nothing is written.
//!
//! Record (word-aligned, at the end of the sector's log): magic `KSL2` ‖ sequence u32 ‖ blob
//! length u16 ‖ 0xFFFF ‖ CRC-32 of the blob ‖ blob, padded to a word ‖ commit word `CMIT`.
//! A store programs the header, then the blob, reads the blob back, and only then programs the
//! commit word. At boot the committed record with the right CRC and the highest sequence wins.
//! A record cut short by a power loss has no commit word and is ignored; a header cut short makes
//! the rest of that sector unusable until it is erased. A full sector: the other one (holding
//! only older records) is erased and the log continues there. A power cut at any point leaves
//! the active record untouched: the controller boots with the old parameters or the new ones,
//! never neither and never a mix.

use embedded_storage::nor_flash::{ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash};
use kincal_protocol::params::{BLOB_CRC, MAX_PARAM_BLOB};

/// Bytes programmed at once (the log's alignment).
pub const WORD: usize = 4;
const MAGIC: [u8; 4] = *b"KSL2";
const ERASED: [u8; 4] = [0xFF; 4];
const HEADER: usize = 16;
const COMMITTED: [u8; 4] = *b"CMIT";

/// Why storing failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashError {
    /// The blob is larger than a sector's log can hold.
    TooLarge,
    /// The device refused an operation (or lost power, in simulation).
    Device(NorFlashErrorKind),
    /// What was programmed does not read back.
    Verify,
    /// The active sector is full and the spare is not erased yet; nothing was written.
    SpareNotErased,
}

fn device<E: NorFlashError>(e: E) -> FlashError {
    FlashError::Device(e.kind())
}

/// The active parameter record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stored {
    /// Sector index (0 or 1).
    pub sector: usize,
    /// Offset of the record in its sector.
    pub at: usize,
    /// Write sequence number.
    pub sequence: u32,
    /// Blob length, bytes.
    pub len: usize,
    /// CRC-32 of the blob.
    pub crc: u32,
}

/// Bytes of the record of a `len`-byte blob.
fn record_size(len: usize) -> usize {
    HEADER + len.div_ceil(WORD) * WORD + WORD
}

/// Where a sector's log ends: the offset to append at, or `None` when a damaged header makes the
/// rest of the sector unusable.
type LogEnd = Option<usize>;

/// The parameter log on the first two erase sectors of a [`NorFlash`].
pub struct ParamStore<F: NorFlash> {
    flash: F,
    active: Option<Stored>,
    ends: [LogEnd; 2],
    /// The sector the log does not use now is known to be erased.
    spare_blank: bool,
}

impl<F: NorFlash> ParamStore<F> {
    const SECTOR: usize = F::ERASE_SIZE;
    const WORDS_FIT: () = assert!(WORD.is_multiple_of(F::WRITE_SIZE) && F::ERASE_SIZE.is_multiple_of(WORD));

    /// Scan both sectors and pick the committed record with the highest sequence.
    pub fn mount(mut flash: F) -> Self {
        let () = Self::WORDS_FIT;
        let mut active: Option<Stored> = None;
        let mut ends = [None; 2];
        for (sector, end) in ends.iter_mut().enumerate() {
            *end = scan(&mut flash, sector, |found| {
                if active.is_none_or(|a| found.sequence > a.sequence) {
                    active = Some(found);
                }
            });
        }
        let mut store = ParamStore { flash, active, ends, spare_blank: false };
        store.spare_blank = store.is_blank(store.spare());
        store
    }

    /// The sector the log writes to now.
    fn current(&self) -> usize {
        self.active.map_or(0, |a| a.sector)
    }

    /// The other sector.
    fn spare(&self) -> usize {
        1 - self.current()
    }

    /// Every byte of `sector` reads erased (an interrupted erase can leave stray bits anywhere).
    fn is_blank(&mut self, sector: usize) -> bool {
        let mut chunk = [0u8; 64];
        (0..Self::SECTOR).step_by(chunk.len()).all(|at| {
            let n = chunk.len().min(Self::SECTOR - at);
            self.flash.read((sector * Self::SECTOR + at) as u32, &mut chunk[..n]).is_ok()
                && chunk[..n].iter().all(|&b| b == 0xFF)
        })
    }

    /// The spare sector still has to be erased before the log can move there.
    pub fn spare_needs_erase(&self) -> bool {
        !self.spare_blank
    }

    /// Erase the spare sector now (slow: call when nothing samples).
    pub fn erase_spare(&mut self) -> Result<(), FlashError> {
        let spare = self.spare();
        let base = (spare * Self::SECTOR) as u32;
        self.ends[spare] = None;
        self.flash.erase(base, base + Self::SECTOR as u32).map_err(device)?;
        self.ends[spare] = Some(0);
        self.spare_blank = true;
        Ok(())
    }

    /// The active record, if any.
    pub fn active(&self) -> Option<Stored> {
        self.active
    }

    /// Read the active blob into `buf`; returns its bytes.
    pub fn load<'a>(&mut self, buf: &'a mut [u8; MAX_PARAM_BLOB]) -> Option<&'a [u8]> {
        let s = self.active?;
        let from = (s.sector * Self::SECTOR + s.at + HEADER) as u32;
        self.flash.read(from, &mut buf[..s.len]).ok()?;
        Some(&buf[..s.len])
    }

    /// Append `blob` to the log and make it active once committed. When the active sector is
    /// full the log moves to the spare; if that is not erased yet it is erased here only when
    /// `may_erase` (otherwise [`FlashError::SpareNotErased`], nothing written).
    pub fn store(&mut self, blob: &[u8], may_erase: bool) -> Result<(), FlashError> {
        let size = record_size(blob.len());
        if blob.len() > MAX_PARAM_BLOB || size > Self::SECTOR {
            return Err(FlashError::TooLarge);
        }
        let current = self.current();
        let (sector, at) = match self.ends[current] {
            Some(end) if end + size <= Self::SECTOR => (current, end),
            _ => {
                // Full (or damaged): continue in the spare, which holds only older records.
                if !self.spare_blank {
                    if !may_erase {
                        return Err(FlashError::SpareNotErased);
                    }
                    self.erase_spare()?;
                }
                self.spare_blank = false;
                (self.spare(), 0)
            }
        };
        // From here on a failure leaves a record without its commit word: skip past it next time.
        self.ends[sector] = Some(at + size);
        let base = sector * Self::SECTOR + at;
        let sequence = self.active.map_or(1, |a| a.sequence.wrapping_add(1));
        let crc = BLOB_CRC.checksum(blob);
        let len = (blob.len() as u16).to_le_bytes();
        let mut header = [0u8; HEADER];
        header[..4].copy_from_slice(&MAGIC);
        header[4..8].copy_from_slice(&sequence.to_le_bytes());
        header[8..12].copy_from_slice(&[len[0], len[1], 0xFF, 0xFF]);
        header[12..].copy_from_slice(&crc.to_le_bytes());
        for (k, word) in header.chunks(WORD).enumerate() {
            self.flash.write((base + k * WORD) as u32, word).map_err(device)?;
        }
        for (k, chunk) in blob.chunks(WORD).enumerate() {
            let mut word = [0xFF; WORD];
            word[..chunk.len()].copy_from_slice(chunk);
            self.flash.write((base + HEADER + k * WORD) as u32, &word).map_err(device)?;
        }
        let mut back = [0u8; MAX_PARAM_BLOB];
        self.flash.read((base + HEADER) as u32, &mut back[..blob.len()]).map_err(device)?;
        if back[..blob.len()] != *blob {
            return Err(FlashError::Verify);
        }
        self.flash.write((base + size - WORD) as u32, &COMMITTED).map_err(device)?;
        self.active = Some(Stored { sector, at, sequence, len: blob.len(), crc });
        if sector != current {
            // The sector left behind is the new spare; it holds older records until erased.
            self.spare_blank = false;
        }
        Ok(())
    }

    /// Give the flash back (e.g. to simulate a reboot).
    pub fn into_flash(self) -> F {
        self.flash
    }
}

/// Walk the log of `sector`, calling `found` for every valid committed record; returns where the
/// log ends.
fn scan<F: NorFlash>(flash: &mut F, sector: usize, mut found: impl FnMut(Stored)) -> LogEnd {
    let sector_size = F::ERASE_SIZE;
    let base = sector * sector_size;
    let mut at = 0;
    while at + HEADER + WORD <= sector_size {
        let mut header = [0u8; HEADER];
        flash.read((base + at) as u32, &mut header).ok()?;
        if header[..4] == ERASED {
            return Some(at);
        }
        let len = u16::from_le_bytes([header[8], header[9]]) as usize;
        if header[..4] != MAGIC || len > MAX_PARAM_BLOB || at + record_size(len) > sector_size {
            return None;
        }
        let size = record_size(len);
        let mut commit = [0u8; WORD];
        flash.read((base + at + size - WORD) as u32, &mut commit).ok()?;
        let mut blob = [0u8; MAX_PARAM_BLOB];
        flash.read((base + at + HEADER) as u32, &mut blob[..len]).ok()?;
        let crc = u32::from_le_bytes([header[12], header[13], header[14], header[15]]);
        if commit == COMMITTED && BLOB_CRC.checksum(&blob[..len]) == crc {
            let sequence = u32::from_le_bytes([header[4], header[5], header[6], header[7]]);
            found(Stored { sector, at, sequence, len, crc });
        }
        at += size;
    }
    Some(at)
}

/// NOR flash in RAM with `N` bytes (two sectors of `N/2`), for tests and the emulated board's
/// tick bench. With a power budget it fails after that many erase/program operations, leaving
/// the interrupted operation half done, as a real power cut would.
pub struct RamNor<const N: usize> {
    /// Contents.
    pub bytes: [u8; N],
    /// Operations left before the simulated power cut (`None`: unlimited).
    pub power_budget: Option<u32>,
    /// Sector erases so far.
    pub erases: u32,
}

impl<const N: usize> RamNor<N> {
    /// An erased device.
    pub const fn new() -> Self {
        RamNor { bytes: [0xFF; N], power_budget: None, erases: 0 }
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

impl<const N: usize> ErrorType for RamNor<N> {
    type Error = NorFlashErrorKind;
}

impl<const N: usize> ReadNorFlash for RamNor<N> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let offset = offset as usize;
        let src = self.bytes.get(offset..offset + bytes.len()).ok_or(NorFlashErrorKind::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }

    fn capacity(&self) -> usize {
        N
    }
}

impl<const N: usize> NorFlash for RamNor<N> {
    const WRITE_SIZE: usize = WORD;
    const ERASE_SIZE: usize = N / 2;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let (from, to) = (from as usize, to as usize);
        let sector = Self::ERASE_SIZE;
        if !from.is_multiple_of(sector) || !to.is_multiple_of(sector) || to > N || from > to {
            return Err(NorFlashErrorKind::NotAligned);
        }
        self.erases += 1;
        if !self.spend() {
            // Interrupted: the first half is erased, the rest keeps its old bits.
            self.bytes[from..from + (to - from) / 2].fill(0xFF);
            return Err(NorFlashErrorKind::Other);
        }
        self.bytes[from..to].fill(0xFF);
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let offset = offset as usize;
        if !offset.is_multiple_of(WORD) || !bytes.len().is_multiple_of(WORD) || offset + bytes.len() > N {
            return Err(NorFlashErrorKind::NotAligned);
        }
        for (k, word) in bytes.chunks(WORD).enumerate() {
            let at = offset + k * WORD;
            let interrupted = !self.spend();
            let n = if interrupted { WORD / 2 } else { WORD };
            for (byte, w) in self.bytes[at..at + n].iter_mut().zip(word) {
                *byte &= w;
            }
            if interrupted {
                return Err(NorFlashErrorKind::Other);
            }
        }
        Ok(())
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
            store.store(&blob(k, len), true).unwrap();
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
            store.store(&blob(1, 64), true).unwrap();
            store.store(&old, true).unwrap(); // the second slot now holds `old`, the first an older blob
            let mut flash = store.into_flash();
            flash.power_budget = Some(budget);
            let mut store = ParamStore::mount(flash);
            let finished = store.store(&new, true).is_ok();
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
            // After a cut the next store still works and keeps the active record until committed.
            rebooted.store(&blob(7, 10), true).unwrap();
            let mut again = ParamStore::mount(rebooted.into_flash());
            assert_eq!(load(&mut again), Some(blob(7, 10)));
        }
        assert!(steps_seen_new > 0 && steps_seen_new < 200);
    }

    /// Commits append: a sector is erased only when the log comes back to it.
    #[test]
    fn commits_append_and_erase_only_when_the_log_comes_back_to_a_sector() {
        let mut store = ParamStore::mount(Flash::new());
        let per_sector = 2048 / record_size(300);
        for k in 0..(3 * per_sector) as u8 {
            store.store(&blob(k, 300), true).unwrap();
            store = ParamStore::mount(store.into_flash());
            assert_eq!(load(&mut store), Some(blob(k, 300)));
        }
        let erases = store.into_flash().erases;
        assert_eq!(erases, 1, "{} commits of 300 bytes, {per_sector} per 2 KiB sector", 3 * per_sector);
    }

    /// While sampling the controller may not erase: a store that needs the spare erased is
    /// refused without writing anything; erasing it ahead of time lets the next one through.
    #[test]
    fn a_full_sector_waits_for_the_spare_to_be_erased() {
        let mut store = ParamStore::mount(Flash::new());
        assert!(!store.spare_needs_erase(), "a new device is blank");
        let per_sector = 2048 / record_size(300);
        for k in 0..(2 * per_sector) as u8 {
            store.store(&blob(k, 300), false).unwrap();
        }
        assert!(store.spare_needs_erase());
        let last = blob((2 * per_sector - 1) as u8, 300);
        let before = store.into_flash();
        let mut store = ParamStore::mount(before);
        assert!(store.spare_needs_erase(), "seen again after a reboot");
        assert_eq!(store.store(&blob(200, 300), false), Err(FlashError::SpareNotErased));
        assert_eq!(load(&mut store), Some(last.clone()));
        store.erase_spare().unwrap();
        assert!(!store.spare_needs_erase());
        assert_eq!(load(&mut store), Some(last), "erasing the spare keeps the active record");
        store.store(&blob(200, 300), false).unwrap();
        let mut store = ParamStore::mount(store.into_flash());
        assert_eq!(load(&mut store), Some(blob(200, 300)));
        assert_eq!(store.into_flash().erases, 1);
    }

    /// A stray programmed byte anywhere in the spare (an erase cut short) counts as not erased.
    #[test]
    fn a_spare_with_stray_bits_needs_erasing() {
        let mut flash = Flash::new();
        flash.bytes[2048 + 1500] = 0x7F;
        assert!(ParamStore::mount(flash).spare_needs_erase());
    }
}
