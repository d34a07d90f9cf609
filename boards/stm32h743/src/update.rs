//! Model updates on the STM32H743 (docs/UPDATE.md): the update partition is bank 2 of the
//! part's flash (`UPDATE` in memory.x: 0x0810_0000, 1 MiB, eight 128 KiB sectors), erased and
//! programmed through embassy-stm32's blocking flash driver while the image runs from bank 1,
//! and read in place: the updater checks and hashes the blob where it lies, and the model
//! serves from its slot without a copy in RAM. Bank 2 is ECC flash (a 32-byte flash word is
//! programmed once between erases), which the updater's rule respects. The link server's side
//! is the boards' shared `epssn_selftest::updates::BoardUpdates`.

use core::fmt::Arguments;
use core::ops::Range;

use cortex_m::peripheral::SCB;
use embassy_stm32::flash::{Bank2Region, Blocking, Error, BANK2_REGION};
use embedded_storage::nor_flash::{
    check_erase, check_write, ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash,
};
use epssn_selftest::updates::BoardUpdates;
use epssn_selftest::Clock;
use epssn_update::{MappedFlash, Updater};

/// Bank 2 as the update partition: embassy-stm32's driver for the writes and erases, the
/// memory map for reads.
pub struct Bank2<'a> {
    region: Bank2Region<'static, Blocking>,
    /// The D-cache caches flash reads: lines of a range just erased or programmed are dropped.
    scb: SCB,
    /// Feeds the watchdog before each erase and write (a sector's erase takes seconds).
    feed: &'a dyn Fn(),
}

/// The driver's error for a range the embedded-storage checks refuse.
fn range_error(kind: NorFlashErrorKind) -> Error {
    match kind {
        NorFlashErrorKind::NotAligned => Error::Unaligned,
        _ => Error::Size,
    }
}

impl<'a> Bank2<'a> {
    /// The partition over bank 2's driver; `scb` for the D-cache maintenance.
    pub fn new(region: Bank2Region<'static, Blocking>, scb: SCB, feed: &'a dyn Fn()) -> Self {
        Bank2 { region, scb, feed }
    }

    /// Drops the D-cache's lines of `from..to` (offsets in the bank): the flash changed under
    /// them. The bank is never written through the cache, so no line is dirty.
    fn invalidate(&mut self, from: u32, to: u32) {
        let base = BANK2_REGION.base() as usize;
        self.scb
            .clean_invalidate_dcache_by_address(base + from as usize, (to - from) as usize);
    }
}

impl ErrorType for Bank2<'_> {
    type Error = Error;
}

impl ReadNorFlash for Bank2<'_> {
    const READ_SIZE: usize = <Bank2Region<'static, Blocking> as ReadNorFlash>::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        self.region.read(offset, bytes)
    }

    fn capacity(&self) -> usize {
        self.region.capacity()
    }
}

impl NorFlash for Bank2<'_> {
    const WRITE_SIZE: usize = <Bank2Region<'static, Blocking> as NorFlash>::WRITE_SIZE;
    const ERASE_SIZE: usize = <Bank2Region<'static, Blocking> as NorFlash>::ERASE_SIZE;

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        check_write(self, offset, bytes.len()).map_err(range_error)?;
        (self.feed)();
        let r = self.region.write(offset, bytes);
        self.invalidate(offset, offset + bytes.len() as u32);
        r
    }

    /// One sector at a time, the watchdog fed before each.
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        // Checked here: the driver panics on an address outside the flash.
        check_erase(self, from, to).map_err(range_error)?;
        let mut at = from;
        while at < to {
            let end = at + Self::ERASE_SIZE as u32;
            (self.feed)();
            let r = self.region.erase(at, end);
            self.invalidate(at, end);
            r?;
            at = end;
        }
        Ok(())
    }
}

impl MappedFlash for Bank2<'_> {
    fn mapped(&self) -> &[u8] {
        let (base, len) = (BANK2_REGION.base() as usize, BANK2_REGION.size as usize);
        // SAFETY: bank 2 is memory-mapped flash, `len` bytes from `base`, always readable.
        // Erasing and programming it take `&mut self`, so neither runs while this borrow of
        // `self` lives, and nothing writes it through a reference.
        unsafe { core::slice::from_raw_parts(base as *const u8, len) }
    }
}

/// The board's model updates.
pub type Updates<'a> = BoardUpdates<'a, Bank2<'a>>;

/// The blob that serves and its golden CRC: the active slot's, else the compiled-in one.
pub type ServedBlob = (&'static [u8], u32);

/// Bytes `range` of bank 2 (offsets from its start), borrowed for the rest of the run: the
/// active slot's blob, in place. `None` when the range is not within the bank.
fn in_place(range: Range<usize>) -> Option<&'static [u8]> {
    if range.start > range.end || range.end > BANK2_REGION.size as usize {
        return None;
    }
    let at = BANK2_REGION.base() as usize + range.start;
    // SAFETY: within bank 2 (checked), memory-mapped flash. The updater never erases or
    // programs the active slot, and the board resets right after a commit changes which slot
    // serves, before the old one can be written: the bytes stay as they are while this lives.
    Some(unsafe { core::slice::from_raw_parts(at as *const u8, range.len()) })
}

/// Opens the partition and the blob that serves, in place (`None` on a blank bank: the
/// compiled-in model serves). A commit logs its cost in `clock`'s unit to `log`, and its
/// switch resets the core.
pub fn open<'a>(
    flash: Bank2<'a>,
    feed: &'a dyn Fn(),
    clock: Clock<'a>,
    log: &'a dyn Fn(Arguments<'_>),
) -> Option<(Updates<'a>, Option<ServedBlob>)> {
    let updater = Updater::open(flash).ok()?;
    let served = updater
        .active_image()
        .and_then(|(header, range)| Some((in_place(range)?, header.golden)));
    let updates = BoardUpdates::new(updater, feed, SCB::sys_reset, clock, log);
    Some((updates, served))
}
