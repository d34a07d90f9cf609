//! Model updates on the QEMU boards (docs/UPDATE.md): the update partition is a RAM region of
//! the board's memory map (`UPDATE` in memory.x), which nothing loads, so it keeps its contents
//! across resets; `epssn_update::RamFlash` gives it NOR flash semantics, and
//! `epssn_update::Updater` the slots and the journal. [`BoardUpdates`] is the link server's
//! [`Updates`]: a commit runs the boot self-test on the new blob in place, and the switch
//! resets the board, whose boot then serves the journal's model from its slot in place.

use core::ops::Range;

use cortex_m_semihosting::hprintln;

use epssn::config;
use epssn::link::{error_text, Held, Serving};
use epssn::model::Workspace;
use epssn::pairing::FeatureCache;
use epssn::server::{Refusal, Updates};
use epssn_update::image::Header;
use epssn_update::ram_flash::Memory;
use epssn_update::{Active, RamFlash, UpdateError, Updater};
use fixed::types::U16F16;

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
pub struct BoardUpdates<'a> {
    updater: Updater<RamFlash<Sram>>,
    feed: &'a dyn Fn(),
    reset: fn() -> !,
    /// The board's clock and its instructions per tick: the commit's cost goes to the console.
    now: &'a dyn Fn() -> u32,
    instructions_per_tick: u32,
}

/// The blob that serves and its golden CRC: the active slot's, else the compiled-in one.
pub type ServedBlob = (&'static [u8], u32);

impl<'a> BoardUpdates<'a> {
    /// Opens the partition (erasing it whole if it is blank: QEMU's RAM starts zeroed, a part
    /// that no erase has ever touched) and the blob that serves, in place.
    pub fn open(
        mut mem: Sram,
        feed: &'a dyn Fn(),
        reset: fn() -> !,
        clock: (&'a dyn Fn() -> u32, u32),
    ) -> Option<(Self, Option<ServedBlob>)> {
        if mem.bytes().get(..4) == Some(&[0; 4]) {
            // A journal sector never starts with zeros: a record starts with its magic, and
            // an erase leaves 0xFF. Erased from the last sector to the first, so a reset
            // during it leaves the first word zero and the next boot erases again.
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
        Some((
            BoardUpdates {
                updater,
                feed,
                reset,
                now: clock.0,
                instructions_per_tick: clock.1,
            },
            served,
        ))
    }
}

fn refusal(e: UpdateError) -> Refusal {
    Refusal {
        code: e.code(),
        text: error_text(&e),
    }
}

fn serving(a: Active) -> Serving {
    match a {
        Active::Factory => Serving {
            slot: None,
            version: 0,
        },
        Active::Slot { slot, version } => Serving {
            slot: Some(slot),
            version,
        },
    }
}

impl Updates for BoardUpdates<'_> {
    fn serving(&self) -> Serving {
        serving(self.updater.active())
    }

    fn held(&self) -> (u8, Option<Held>) {
        let held = self.updater.upload().map(|u| Held {
            id: u.id,
            version: u.version,
            total: u.total,
            held: u.held,
        });
        (self.updater.upload_slot() as u8, held)
    }

    fn chunk(&mut self, offset: u32, data: &[u8], crc: u32) -> Result<(), Refusal> {
        self.updater
            .chunk(offset, data, crc)
            .map(|_| ())
            .map_err(refusal)
    }

    fn commit(
        &mut self,
        ws: &mut Workspace,
        cache: &mut FeatureCache,
        depth: &mut [U16F16; config::DEPTH_LEN],
    ) -> Result<Serving, Refusal> {
        (self.feed)();
        let (feed, now) = (self.feed, self.now);
        let start = now();
        let checked = core::cell::Cell::new(None);
        let r = self
            .updater
            .commit(&epssn_selftest::UPDATE_KEY, |blob, golden| {
                checked.set(Some(now()));
                // The signature check took its share of the watchdog's period.
                feed();
                epssn_selftest::check_update(blob, golden, ws, cache, depth)
            });
        let end = now();
        let units = |ticks: u32| ticks.saturating_mul(self.instructions_per_tick);
        let mid = checked.get().unwrap_or(end);
        let verdict: &dyn core::fmt::Display = match &r {
            Ok(_) => &"switching",
            Err(e) => e,
        };
        hprintln!(
            "update commit: checks {} instructions (blob, signature, version), self-test {} \
             instructions: {}",
            units(mid.wrapping_sub(start)),
            units(end.wrapping_sub(mid)),
            verdict
        );
        r.map(serving).map_err(refusal)
    }

    fn switch(&mut self) {
        (self.reset)()
    }
}
