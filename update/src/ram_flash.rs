//! A NorFlash in RAM with the semantics of NOR flash and injectable power loss: the update
//! partition of the QEMU boards, and the flash of the host tests.
//!
//! Erase sets whole sectors to 0xFF; a write can only clear bits (the stored byte becomes
//! `old & new`, as programming NOR does). With [`RamFlash::cut_power_at`] the `n`th write or
//! erase (counting from 0) does only part of its work — a write programs the first half of its
//! bytes and clears only some bits of the next, an erase erases the first half of its range and
//! leaves one byte beyond half-erased — and it and every later operation fail with
//! [`Error::PowerLoss`] until [`RamFlash::power_on`].
//!
//! Write-once mode ([`RamFlash::with_cells`]) has the semantics of ECC flash such as the
//! STM32H7's: each write unit may be programmed once between erases (a second program, even of
//! the same bytes, is [`Error::Reprogram`]), and the unit a power loss cut reads back as garbage
//! (never erased, never the bytes meant) through [`MappedFlash::mapped`] and as [`Error::Ecc`]
//! through [`ReadNorFlash::read`]. It keeps one state byte per write unit in a slice of the
//! caller's; [`RamFlash::new`] keeps none, and compiles to NOR flash alone.
//!
//! The bytes are any [`Memory`]: a slice (`&mut [u8]`, the tests), or a board's RAM region
//! reached by address (the QEMU boards, whose served blob lies in the same region).

use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashError, NorFlashErrorKind,
    ReadNorFlash,
};

use crate::MappedFlash;

/// Erase sector of [`RamFlash`], bytes.
pub const ERASE_SIZE: usize = 4096;
/// Write unit of [`RamFlash`], bytes.
pub const WRITE_SIZE: usize = 4;

/// Why a [`RamFlash`] operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Error {
    /// Misaligned or out of bounds.
    Bounds(NorFlashErrorKind),
    /// The power went: the operation was cut and the flash answers nothing until power-on.
    PowerLoss,
    /// Write-once mode: a write unit programmed since its erase (or cut) was programmed again.
    Reprogram,
    /// Write-once mode: a read covered a unit whose programming or erase a power loss cut.
    Ecc,
}

impl NorFlashError for Error {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Error::Bounds(k) => *k,
            Error::PowerLoss | Error::Reprogram | Error::Ecc => NorFlashErrorKind::Other,
        }
    }
}

/// The RAM under a [`RamFlash`]: read whole, programmed and erased by range.
pub trait Memory {
    /// All its bytes.
    fn bytes(&self) -> &[u8];
    /// Programs `data` at `at`: each byte becomes `old & new` (in bounds: the caller checked).
    fn program(&mut self, at: usize, data: &[u8]);
    /// Sets `range` to 0xFF (in bounds: the caller checked).
    fn erase(&mut self, range: core::ops::Range<usize>);
}

impl Memory for &mut [u8] {
    fn bytes(&self) -> &[u8] {
        self
    }

    fn program(&mut self, at: usize, data: &[u8]) {
        for (m, d) in self[at..at + data.len()].iter_mut().zip(data) {
            *m &= *d;
        }
    }

    fn erase(&mut self, range: core::ops::Range<usize>) {
        self[range].fill(0xFF);
    }
}

/// A write unit's state in write-once mode: erased, programmed, or left unreliable by a cut.
const ERASED: u8 = 0;
const PROGRAMMED: u8 = 1;
const CUT: u8 = 2;

/// The write units `range` of bytes touches.
fn units(range: core::ops::Range<usize>) -> core::ops::Range<usize> {
    range.start / WRITE_SIZE..range.end.div_ceil(WRITE_SIZE)
}

/// Where a [`RamFlash`] keeps the state of each write unit: in write-once mode a slice, one
/// byte per unit.
pub trait Cells {
    /// The states, in write-once mode.
    fn states(&self) -> Option<&[u8]>;
    /// The states, to change, in write-once mode.
    fn states_mut(&mut self) -> Option<&mut [u8]>;
}

/// No states: NOR flash, whose locations may be programmed again to clear more bits.
#[derive(Clone, Copy, Debug, Default)]
pub struct Nor;

impl Cells for Nor {
    fn states(&self) -> Option<&[u8]> {
        None
    }

    fn states_mut(&mut self) -> Option<&mut [u8]> {
        None
    }
}

/// Write-once mode when `Some`.
impl Cells for Option<&mut [u8]> {
    fn states(&self) -> Option<&[u8]> {
        self.as_deref()
    }

    fn states_mut(&mut self) -> Option<&mut [u8]> {
        self.as_deref_mut()
    }
}

/// NOR flash semantics over RAM (a multiple of [`ERASE_SIZE`] bytes); ECC flash semantics with
/// a write unit state store `C` in write-once mode.
#[derive(Debug)]
pub struct RamFlash<M, C = Nor> {
    mem: M,
    /// Write-once mode: one state per write unit ([`ERASED`], [`PROGRAMMED`], [`CUT`]).
    cells: C,
    ops: u32,
    cut_at: Option<u32>,
    off: bool,
}

impl<M: Memory> RamFlash<M> {
    /// NOR flash over `mem`, as it is (erase it first for a blank part).
    pub fn new(mem: M) -> Self {
        Self {
            mem,
            cells: Nor,
            ops: 0,
            cut_at: None,
            off: false,
        }
    }
}

impl<'c, M: Memory> RamFlash<M, Option<&'c mut [u8]>> {
    /// With `cells`, ECC flash over `mem` (module documentation): `cells` holds one state byte
    /// per write unit, all zero for a part whose every unit is erased, and the caller keeps it
    /// with the bytes across power cycles. Without, NOR flash. `None` when `cells` is shorter
    /// than one byte per write unit.
    pub fn with_cells(mem: M, cells: Option<&'c mut [u8]>) -> Option<Self> {
        if cells
            .as_deref()
            .is_some_and(|c| c.len() < mem.bytes().len() / WRITE_SIZE)
        {
            return None;
        }
        Some(Self {
            mem,
            cells,
            ops: 0,
            cut_at: None,
            off: false,
        })
    }
}

impl<M: Memory, C: Cells> RamFlash<M, C> {
    /// The memory underneath.
    pub fn memory(&self) -> &M {
        &self.mem
    }

    /// Cuts the power during write or erase number `n` (0 = the next one), counted from now.
    pub fn cut_power_at(&mut self, n: u32) {
        self.cut_at = Some(self.ops.saturating_add(n));
    }

    /// Writes and erases done since creation.
    pub fn ops(&self) -> u32 {
        self.ops
    }

    /// Whether the power was cut.
    pub fn is_off(&self) -> bool {
        self.off
    }

    /// Power back: operations work again and no cut is pending.
    pub fn power_on(&mut self) {
        self.off = false;
        self.cut_at = None;
    }

    /// Counts an operation; true when the power goes during it.
    fn step(&mut self) -> Result<bool, Error> {
        if self.off {
            return Err(Error::PowerLoss);
        }
        let cut = self.cut_at == Some(self.ops);
        self.ops = self.ops.saturating_add(1);
        self.off = cut;
        Ok(cut)
    }

    /// Write-once mode: unit `u`'s state (every unit is erased in the other mode).
    fn cell(&self, u: usize) -> u8 {
        self.cells
            .states()
            .and_then(|c| c.get(u))
            .copied()
            .unwrap_or(ERASED)
    }

    /// Write-once mode: sets the state of `units`.
    fn set_cells(&mut self, units: core::ops::Range<usize>, state: u8) {
        if let Some(c) = self.cells.states_mut().and_then(|c| c.get_mut(units)) {
            c.fill(state);
        }
    }

    /// A write cut after `done` of its bytes at `at`: in write-once mode the unit the cut fell
    /// in holds garbage (never erased, never `bytes`: the rest of it has bit 7 clear and differs
    /// from what was meant); otherwise some bits of the next byte are cleared.
    fn cut_write(&mut self, at: usize, bytes: &[u8], done: usize) {
        if self.cells.states().is_none() {
            if let Some(b) = bytes.get(done) {
                self.mem.program(at + done, &[*b | 0xA5]);
            }
            return;
        }
        let cut = (at + done) / WRITE_SIZE;
        self.set_cells(at / WRITE_SIZE..cut, PROGRAMMED);
        let end = ((cut + 1) * WRITE_SIZE).min(at + bytes.len());
        for i in at + done..end {
            let b = bytes[i - at];
            self.mem.program(i, &[(b ^ 0xA5) & 0x7F]);
        }
        if at + done < end {
            self.set_cells(cut..cut + 1, CUT);
        }
    }
}

impl<M, C> ErrorType for RamFlash<M, C> {
    type Error = Error;
}

impl<M: Memory, C: Cells> ReadNorFlash for RamFlash<M, C> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        check_read(self, offset, bytes.len()).map_err(Error::Bounds)?;
        if self.off {
            return Err(Error::PowerLoss);
        }
        let at = offset as usize;
        if units(at..at + bytes.len()).any(|u| self.cell(u) == CUT) {
            return Err(Error::Ecc);
        }
        bytes.copy_from_slice(&self.mem.bytes()[at..at + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.bytes().len()
    }
}

impl<M: Memory, C: Cells> NorFlash for RamFlash<M, C> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        check_erase(self, from, to).map_err(Error::Bounds)?;
        let (from, to) = (from as usize, to as usize);
        if self.step()? {
            let half = from + (to - from) / 2;
            self.mem.erase(from..half);
            self.set_cells(units(from..half), ERASED);
            // One byte beyond half-erased: erasing sets bits, so programming cannot model it.
            let b = self.mem.bytes()[half];
            self.mem.erase(half..half + 1);
            self.mem.program(half, &[b | 0x5A]);
            // Its unit, unless it was erased already, is now neither erased nor programmed.
            let u = half / WRITE_SIZE;
            if self.cell(u) != ERASED {
                self.set_cells(u..u + 1, CUT);
            }
            return Err(Error::PowerLoss);
        }
        self.mem.erase(from..to);
        self.set_cells(units(from..to), ERASED);
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        check_write(self, offset, bytes.len()).map_err(Error::Bounds)?;
        if self.off {
            return Err(Error::PowerLoss);
        }
        let at = offset as usize;
        if units(at..at + bytes.len()).any(|u| self.cell(u) != ERASED) {
            return Err(Error::Reprogram);
        }
        let cut = self.step()?;
        let done = if cut { bytes.len() / 2 } else { bytes.len() };
        self.mem.program(at, &bytes[..done]);
        if cut {
            self.cut_write(at, bytes, done);
            return Err(Error::PowerLoss);
        }
        self.set_cells(units(at..at + bytes.len()), PROGRAMMED);
        Ok(())
    }
}

impl<M: Memory, C: Cells> MappedFlash for RamFlash<M, C> {
    fn mapped(&self) -> &[u8] {
        self.mem.bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn programs_only_clear_bits_and_erase_sets_them() {
        let mut mem = [0u8; 2 * ERASE_SIZE];
        let mut f = RamFlash::new(&mut mem[..]);
        f.erase(0, ERASE_SIZE as u32).unwrap();
        f.write(0, &[0xF0, 0x0F, 0xFF, 0x00]).unwrap();
        f.write(0, &[0x3C, 0xFF, 0xFF, 0xFF]).unwrap();
        assert_eq!(&f.mapped()[..4], &[0x30, 0x0F, 0xFF, 0x00]);
        assert_eq!(f.mapped()[ERASE_SIZE], 0, "the other sector untouched");
        assert!(f.write(1, &[0; 4]).is_err(), "misaligned");
    }

    #[test]
    fn a_cut_leaves_part_done_and_silences_the_flash() {
        let mut mem = [0xFFu8; ERASE_SIZE];
        let mut f = RamFlash::new(&mut mem[..]);
        f.cut_power_at(1);
        f.write(0, &[0; 8]).unwrap();
        assert_eq!(f.write(8, &[0; 8]), Err(Error::PowerLoss));
        assert_eq!(&f.mapped()[8..12], &[0; 4]);
        assert_eq!(f.mapped()[12], 0xA5, "some bits of the next byte cleared");
        assert_eq!(&f.mapped()[13..16], &[0xFF; 3]);
        assert_eq!(f.erase(0, ERASE_SIZE as u32), Err(Error::PowerLoss));
        f.power_on();
        f.erase(0, ERASE_SIZE as u32).unwrap();
        assert!(f.mapped().iter().all(|&b| b == 0xFF));
    }

    #[test]
    fn write_once_programs_a_unit_once_between_erases() {
        let mut mem = [0xFFu8; ERASE_SIZE];
        let mut cells = [0u8; ERASE_SIZE / WRITE_SIZE];
        let mut f = RamFlash::with_cells(&mut mem[..], Some(&mut cells)).unwrap();
        f.write(0, &[1, 2, 3, 4]).unwrap();
        assert_eq!(
            f.write(0, &[1, 2, 3, 4]),
            Err(Error::Reprogram),
            "not even the same"
        );
        assert_eq!(f.write(4, &[0xFF; 4]), Ok(()));
        assert_eq!(
            f.write(4, &[0; 4]),
            Err(Error::Reprogram),
            "erased bytes, programmed"
        );
        f.erase(0, ERASE_SIZE as u32).unwrap();
        assert_eq!(f.write(0, &[1, 2, 3, 4]), Ok(()));
        let mut short = [0u8; 3];
        assert!(RamFlash::with_cells(&mut mem[..], Some(&mut short)).is_none());
    }

    #[test]
    fn write_once_leaves_a_cut_unit_garbage_and_unreadable() {
        let mut mem = [0xFFu8; ERASE_SIZE];
        let mut cells = [0u8; ERASE_SIZE / WRITE_SIZE];
        let mut f = RamFlash::with_cells(&mut mem[..], Some(&mut cells)).unwrap();
        let data = [0x5Au8; 12];
        f.cut_power_at(0);
        assert_eq!(f.write(0, &data), Err(Error::PowerLoss));
        f.power_on();
        // Half of 12 bytes: unit 0 programmed, unit 1 cut, unit 2 untouched.
        assert_eq!(&f.mapped()[..4], &data[..4]);
        let cut = &f.mapped()[4..8];
        assert!(
            cut != [0xFF; 4] && cut != &data[4..8],
            "garbage: {cut:02x?}"
        );
        assert_eq!(&f.mapped()[8..12], &[0xFF; 4]);
        let mut buf = [0u8; 4];
        assert_eq!(f.read(4, &mut buf), Err(Error::Ecc));
        assert_eq!(f.read(0, &mut buf), Ok(()));
        assert_eq!(
            f.write(4, &data[4..8]),
            Err(Error::Reprogram),
            "the cut unit"
        );
        assert_eq!(f.write(8, &data[8..]), Ok(()), "the unit after it");
        // A cut erase leaves the programmed unit at its half unreliable.
        f.write(2048, &data[..4]).unwrap();
        f.cut_power_at(0);
        assert_eq!(f.erase(0, ERASE_SIZE as u32), Err(Error::PowerLoss));
        f.power_on();
        assert_eq!(f.read(2048, &mut buf), Err(Error::Ecc));
        assert_eq!(f.write(4, &data[4..8]), Ok(()), "erased in the first half");
    }
}
