//! Model updates on the QEMU boards (docs/UPDATE.md): the update partition is a RAM region of
//! the board's memory map (`UPDATE` in memory.x), which nothing loads, so it keeps its contents
//! across resets; `epssn_update::RamFlash` gives it NOR flash semantics, and
//! `epssn_update::Updater` the slots and the journal. The link server's side is the boards'
//! shared `epssn_selftest::updates::BoardUpdates`; this module opens the partition and lends
//! the served blob in place.

use core::fmt::Arguments;
use core::ops::Range;

use cortex_m_semihosting::hprintln;

use epssn_selftest::updates::BoardUpdates;
use epssn_selftest::Clock;
use epssn_update::image::Header;
use epssn_update::ram_flash::Memory;
use epssn_update::{RamFlash, Updater};

/// The partition's RAM, reached by address: every access goes through the raw pointer, never
/// through a `&mut` over the whole region, so the served slot's blob can be borrowed for good
/// while other parts are programmed ([`Sram::blob`]).
pub struct Sram {
    base: *mut u8,
    len: usize,
}

impl Sram {
    /// # Safety
    ///
    /// `base..base + len` is RAM of this board that nothing else uses (the memory map's
    /// `UPDATE` region), and only one `Sram` is made for it.
    pub unsafe fn new(base: *mut u8, len: usize) -> Self {
        Sram { base, len }
    }

    /// The bytes in `range` (within the region), borrowed for the rest of the run: the served
    /// blob, read in place.
    ///
    /// # Safety
    ///
    /// Nothing writes or erases `range` while the slice lives: the updater never touches the
    /// slot that serves, and the board resets right after a commit changes which slot serves,
    /// before the old one can be written.
    unsafe fn blob(&self, range: Range<usize>) -> &'static [u8] {
        assert!(range.start <= range.end && range.end <= self.len);
        // SAFETY: in bounds (asserted), and unwritten while it lives (the contract).
        unsafe { core::slice::from_raw_parts(self.base.add(range.start), range.len()) }
    }
}

impl Memory for Sram {
    fn bytes(&self) -> &[u8] {
        // SAFETY: the region is ours (`new`), and every write below goes through the raw
        // pointer while no slice from here is alive (the updater drops its reads first).
        unsafe { core::slice::from_raw_parts(self.base, self.len) }
    }

    fn program(&mut self, at: usize, data: &[u8]) {
        assert!(at <= self.len && data.len() <= self.len - at);
        for (i, d) in data.iter().enumerate() {
            // SAFETY: in bounds (asserted); a byte of our region that no live slice covers.
            unsafe {
                let p = self.base.add(at + i);
                p.write_volatile(p.read_volatile() & d);
            }
        }
    }

    fn erase(&mut self, range: Range<usize>) {
        assert!(range.start <= range.end && range.end <= self.len);
        // SAFETY: in bounds (asserted); bytes of our region that no live slice covers.
        unsafe { core::ptr::write_bytes(self.base.add(range.start), 0xFF, range.len()) }
    }
}

/// The model updates of a QEMU board.
pub type QemuUpdates<'a> = BoardUpdates<'a, RamFlash<Sram>>;

/// The blob that serves and its golden CRC: the active slot's, else the compiled-in one.
pub type ServedBlob = (&'static [u8], u32);

/// The semihosting console, one line per call.
fn console(line: Arguments<'_>) {
    hprintln!("{}", line);
}

/// Opens the partition (erasing it whole if it is blank: QEMU's RAM starts zeroed, a part that
/// no erase has ever touched) and the blob that serves, in place. `clock` is the board's
/// counter and its instructions per tick.
pub fn open<'a>(
    mut mem: Sram,
    feed: &'a dyn Fn(),
    reset: fn() -> !,
    clock: (&'a dyn Fn() -> u32, u32),
) -> Option<(QemuUpdates<'a>, Option<ServedBlob>)> {
    if mem.bytes().get(..4) == Some(&[0; 4]) {
        // A journal sector never starts with zeros: a record starts with its magic, and an
        // erase leaves 0xFF. Erased from the last sector to the first, so a reset during it
        // leaves the first word zero and the next boot erases again.
        let sector = epssn_update::ram_flash::ERASE_SIZE;
        for s in (0..mem.len / sector).rev() {
            mem.erase(s * sector..(s + 1) * sector);
        }
    }
    let mut updater = Updater::open(RamFlash::new(mem)).ok()?;
    let active: Option<(Header, Range<usize>)> = updater.active_image();
    let served = active.map(|(h, range)| {
        // SAFETY: the active slot's blob, which stays unwritten (see `Sram::blob`).
        (unsafe { updater.flash().memory().blob(range) }, h.golden)
    });
    let clock = Clock {
        now: clock.0,
        units_per_tick: clock.1,
        unit: "instructions",
    };
    Some((
        BoardUpdates::new(updater, feed, reset, clock, &console),
        served,
    ))
}
