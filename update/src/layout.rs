//! Where things lie in the update partition (one NorFlash region, offsets from its start).
//!
//! ```text
//! [journal sector 0][journal sector 1][slot 0: image … | page marks][slot 1: image … | page marks]
//! ```
//!
//! Each journal sector is one erase sector; each slot is a whole number of erase sectors whose
//! last ones hold one write unit per [`PAGE`] of the image (its *page mark*: programmed once the
//! page is written and read back), so the marks are erased before the image on a new upload.

/// The largest write unit the updater handles (the STM32H7's flash word is 32 bytes).
pub const MAX_WRITE: usize = 32;

/// Bytes of an upload page: chunks start on a page and cover whole pages (the image's last one
/// may be short); progress is kept per page.
pub const PAGE: usize = 1024;

/// The partition's geometry, from the flash's erase and write sizes and its capacity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// Erase sector, bytes.
    pub erase: usize,
    /// Write unit, bytes.
    pub write: usize,
    /// Bytes of one slot, marks included.
    pub slot_len: usize,
    /// Bytes of a slot that hold the image.
    pub image_cap: usize,
}

/// Why a partition cannot hold two slots and the journal (or its write unit is over
/// [`MAX_WRITE`] or does not divide a page).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BadGeometry;

const fn round_up(x: usize, to: usize) -> usize {
    x.div_ceil(to) * to
}

impl Layout {
    /// The layout of a partition of `capacity` bytes.
    pub const fn new(capacity: usize, erase: usize, write: usize) -> Result<Self, BadGeometry> {
        if erase == 0
            || write == 0
            || write > MAX_WRITE
            || !PAGE.is_multiple_of(write)
            || capacity < 2 * erase
        {
            return Err(BadGeometry);
        }
        let slot_len = (capacity - 2 * erase) / 2 / erase * erase;
        // Marks for every page the slot could hold (a few more than the image can use).
        let marks = round_up(slot_len / PAGE * write, erase);
        if slot_len <= marks {
            return Err(BadGeometry);
        }
        let image_cap = slot_len - marks;
        Ok(Self {
            erase,
            write,
            slot_len,
            image_cap,
        })
    }

    /// Offset of journal sector `i` (0 or 1).
    pub const fn journal(&self, i: usize) -> usize {
        i * self.erase
    }

    /// Offset of slot `s` (0 or 1).
    pub const fn slot(&self, s: usize) -> usize {
        2 * self.erase + s * self.slot_len
    }

    /// Offset of the page marks of slot `s`.
    pub const fn marks(&self, s: usize) -> usize {
        self.slot(s) + self.image_cap
    }

    /// Offset of page `p`'s mark in slot `s`.
    pub const fn mark(&self, s: usize, p: usize) -> usize {
        self.marks(s) + p * self.write
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_and_marks_do_not_overlap() {
        let l = Layout::new(2 * 4096 + 2 * 65536, 4096, 4).unwrap();
        assert_eq!(l.slot(0), 8192);
        assert_eq!(l.slot(1), 8192 + 65536);
        assert!(l.image_cap / PAGE * l.write <= l.slot_len - l.image_cap);
        assert_eq!(l.marks(0) % l.erase, 0);
        assert!(l.mark(1, l.image_cap / PAGE) < l.slot(1) + l.slot_len);
        assert_eq!(Layout::new(3 * 4096, 4096, 4), Err(BadGeometry));
        assert_eq!(Layout::new(1 << 20, 4096, 3), Err(BadGeometry));
    }
}
