//! A NorFlash in RAM with the semantics of NOR flash and injectable power loss: the update
//! partition of the QEMU boards, and the flash of the host tests.
//!
//! Erase sets whole sectors to 0xFF; a write can only clear bits (the stored byte becomes
//! `old & new`, as programming NOR does; hence [`MultiwriteNorFlash`]). With
//! [`RamFlash::cut_power_at`] the `n`th write or erase (counting from 0) does only part of its
//! work — a write programs the first half of its bytes and clears only some bits of the next,
//! an erase erases the first half of its range and leaves one byte beyond half-erased — and it
//! and every later operation fail with [`Error::PowerLoss`] until [`RamFlash::power_on`].
//!
//! The bytes are any [`Memory`]: a slice (`&mut [u8]`, the tests), or a board's RAM region
//! reached by address (the QEMU boards, whose served blob lies in the same region).

use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, MultiwriteNorFlash, NorFlash, NorFlashError,
    NorFlashErrorKind, ReadNorFlash,
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
}

impl NorFlashError for Error {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            Error::Bounds(k) => *k,
            Error::PowerLoss => NorFlashErrorKind::Other,
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

/// NOR flash semantics over RAM (a multiple of [`ERASE_SIZE`] bytes).
#[derive(Debug)]
pub struct RamFlash<M> {
    mem: M,
    ops: u32,
    cut_at: Option<u32>,
    off: bool,
}

impl<M: Memory> RamFlash<M> {
    /// The flash over `mem`, as it is (erase it first for a blank part).
    pub fn new(mem: M) -> Self {
        Self {
            mem,
            ops: 0,
            cut_at: None,
            off: false,
        }
    }

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
}

impl<M> ErrorType for RamFlash<M> {
    type Error = Error;
}

impl<M: Memory> ReadNorFlash for RamFlash<M> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Error> {
        check_read(self, offset, bytes.len()).map_err(Error::Bounds)?;
        if self.off {
            return Err(Error::PowerLoss);
        }
        let at = offset as usize;
        bytes.copy_from_slice(&self.mem.bytes()[at..at + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        self.mem.bytes().len()
    }
}

impl<M: Memory> NorFlash for RamFlash<M> {
    const WRITE_SIZE: usize = WRITE_SIZE;
    const ERASE_SIZE: usize = ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Error> {
        check_erase(self, from, to).map_err(Error::Bounds)?;
        let (from, to) = (from as usize, to as usize);
        if self.step()? {
            let half = from + (to - from) / 2;
            self.mem.erase(from..half);
            // One byte beyond half-erased: erasing sets bits, so programming cannot model it.
            let b = self.mem.bytes()[half];
            self.mem.erase(half..half + 1);
            self.mem.program(half, &[b | 0x5A]);
            return Err(Error::PowerLoss);
        }
        self.mem.erase(from..to);
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Error> {
        check_write(self, offset, bytes.len()).map_err(Error::Bounds)?;
        let at = offset as usize;
        let cut = self.step()?;
        let done = if cut { bytes.len() / 2 } else { bytes.len() };
        self.mem.program(at, &bytes[..done]);
        if cut {
            if let Some(b) = bytes.get(done) {
                self.mem.program(at + done, &[*b | 0xA5]);
            }
            return Err(Error::PowerLoss);
        }
        Ok(())
    }
}

// Programming ANDs: a location may be written again to clear more bits.
impl<M: Memory> MultiwriteNorFlash for RamFlash<M> {}

impl<M: Memory> MappedFlash for RamFlash<M> {
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
}
