//! The update state machine: boot (which slot serves), upload chunks into the other slot,
//! commit.
//!
//! Nothing is kept in RAM that the flash does not also say: after any reset [`Updater::open`]
//! finds the same active model and the same upload progress from the journal, the slot headers
//! and the page marks (module `layout`). The active slot is never written; the one switch is
//! one journal record.

use embedded_storage::nor_flash::{NorFlashError, NorFlashErrorKind};

pub use crate::error::UpdateError;

use epssn::blob::Blob;
use epssn::config;
use epssn::crc32::crc32;

use crate::image::{Header, HeaderError, HEADER_LEN};
use crate::journal::{self, Record};
use crate::layout::{BadGeometry, Layout, MAX_WRITE, PAGE};
use crate::verify::verify;
use crate::MappedFlash;

/// The model that serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Active {
    /// The model compiled into the image (version 0): no slot holds a committed model.
    Factory,
    /// A committed model.
    Slot {
        /// Slot 0 or 1.
        slot: u8,
        /// Its version.
        version: u32,
    },
}

impl Active {
    /// The version: 0 for the compiled-in model.
    pub fn version(&self) -> u32 {
        match self {
            Active::Factory => 0,
            Active::Slot { version, .. } => *version,
        }
    }
}

/// What the inactive slot holds of an upload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Upload {
    /// The slot.
    pub slot: u8,
    /// CRC-32 of the image's header: which upload (the host computes it from its file).
    pub id: u32,
    /// The model version it carries.
    pub version: u32,
    /// Bytes of the whole image, header included.
    pub total: u32,
    /// Bytes held from the start, written and read back; the upload resumes here.
    pub held: u32,
}

/// The update partition and what it says.
pub struct Updater<F> {
    flash: F,
    layout: Layout,
    active: Active,
    /// The journal sector new records go to, and the offset of the next one in it.
    sector: usize,
    free: usize,
    next_seq: u32,
}

fn flash_err<E: NorFlashError>(e: E) -> UpdateError {
    UpdateError::Flash(e.kind())
}

impl<F: MappedFlash> Updater<F> {
    /// Reads the journal and checks the slot it names (header and image CRC); a record whose
    /// slot fails the check gives way to the one before it, and with none the compiled-in
    /// model serves.
    pub fn open(flash: F) -> Result<Self, BadGeometry> {
        let layout = Layout::new(flash.capacity(), F::ERASE_SIZE, F::WRITE_SIZE)?;
        let stride = journal::stride(F::WRITE_SIZE);
        let mut scans = [journal::SectorScan::default(); 2];
        for (i, s) in scans.iter_mut().enumerate() {
            let at = layout.journal(i);
            *s = journal::scan(&flash.mapped()[at..at + layout.erase], stride);
        }
        let mut updater = Self {
            flash,
            layout,
            active: Active::Factory,
            sector: 0,
            free: scans[0].free,
            next_seq: 0,
        };
        // Candidates newest first: each sector's newest and the one before it.
        let mut candidates: [(usize, Option<Record>); 4] = [
            (0, scans[0].newest),
            (0, scans[0].previous),
            (1, scans[1].newest),
            (1, scans[1].previous),
        ];
        candidates.sort_unstable_by_key(|(_, r)| core::cmp::Reverse(r.map(|r| r.seq)));
        if let Some((_, Some(r))) = candidates.first() {
            updater.next_seq = r.seq.wrapping_add(1);
        }
        for (sector, record) in candidates {
            let Some(r) = record else { continue };
            if updater.slot_image_crc(r.slot as usize) == Some(r.image_crc) {
                updater.active = Active::Slot {
                    slot: r.slot as u8,
                    version: r.version,
                };
                // Appends go where the serving record lies, so the other sector, the one a
                // full sector's successor erases, never holds it.
                updater.sector = sector;
                updater.free = scans[sector].free;
                break;
            }
        }
        Ok(updater)
    }

    /// The model that serves.
    pub fn active(&self) -> Active {
        self.active
    }

    /// The active slot's blob, in place in the flash; `None` when the compiled-in model serves.
    pub fn active_blob(&self) -> Option<&[u8]> {
        match self.active {
            Active::Factory => None,
            Active::Slot { slot, .. } => self.slot_header(slot as usize).map(|(_, blob)| blob),
        }
    }

    /// The active slot's header and where its blob lies in the partition (offsets from its
    /// start); `None` when the compiled-in model serves. A board that serves the blob in place
    /// maps this range: the updater never writes or erases the active slot.
    pub fn active_image(&self) -> Option<(Header, core::ops::Range<usize>)> {
        match self.active {
            Active::Factory => None,
            Active::Slot { slot, .. } => {
                let (header, _) = self.slot_header(slot as usize)?;
                let at = self.layout.slot(slot as usize) + HEADER_LEN;
                Some((header, at..at + header.blob_len as usize))
            }
        }
    }

    /// The partition's layout.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// The slot uploads go to: the one that does not serve.
    pub fn upload_slot(&self) -> usize {
        match self.active {
            Active::Slot { slot: 0, .. } => 1,
            _ => 0,
        }
    }

    /// What the upload slot holds, if an upload has begun (its first page is held) and can go
    /// on: the page after the held ones is blank. One that is not was cut short by a reset (or
    /// its mark was), and a write unit is never programmed twice between erases: the upload
    /// starts over, and its first chunk erases the slot.
    pub fn upload(&self) -> Option<Upload> {
        let slot = self.upload_slot();
        if !self.mark_done(slot, 0) {
            return None;
        }
        let at = self.layout.slot(slot);
        let bytes = &self.flash.mapped()[at..at + HEADER_LEN];
        let header = Header::parse(bytes, self.blob_cap()).ok()?;
        let total = header.image_len();
        let mut pages = 0;
        while pages < total.div_ceil(PAGE) && self.mark_done(slot, pages) {
            pages += 1;
        }
        if pages < total.div_ceil(PAGE) && !self.page_blank(slot, pages) {
            return None;
        }
        Some(Upload {
            slot: slot as u8,
            id: crc32(bytes),
            version: header.version,
            total: total as u32,
            held: (pages * PAGE).min(total) as u32,
        })
    }

    /// The flash, for a board that also reads it otherwise (or a test that cuts its power).
    pub fn flash(&mut self) -> &mut F {
        &mut self.flash
    }

    /// Gives the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// Writes `data`, the image's bytes from `offset`, into the upload slot after checking it
    /// against `crc` (CRC-32). A chunk at offset 0 starts the upload its header names (erasing
    /// the slot unless it holds that upload, [`Updater::upload`]); a later chunk must start on
    /// a page at or before [`Upload::held`]. Bytes already held are not written again.
    pub fn chunk(&mut self, offset: u32, data: &[u8], crc: u32) -> Result<Upload, UpdateError> {
        if crc32(data) != crc {
            return Err(UpdateError::ChunkCrc);
        }
        let offset = offset as usize;
        if !offset.is_multiple_of(PAGE) || data.is_empty() {
            return Err(UpdateError::ChunkRange);
        }
        let slot = self.upload_slot();
        // The image's length: from the chunk's own header at offset 0, else from the slot's.
        let (total, restart) = if offset == 0 {
            let header = Header::parse(data, self.blob_cap()).map_err(UpdateError::Header)?;
            let at = self.layout.slot(slot);
            let same = self.upload().is_some_and(|u| {
                self.flash.mapped()[at..at + HEADER_LEN] == data[..HEADER_LEN]
                    && u.total as usize == header.image_len()
            });
            (header.image_len(), !same)
        } else {
            let up = self.upload().ok_or(UpdateError::ChunkRange)?;
            if offset > up.held as usize {
                return Err(UpdateError::ChunkRange);
            }
            (up.total as usize, false)
        };
        let end = offset
            .checked_add(data.len())
            .ok_or(UpdateError::ChunkRange)?;
        if end > total || (!data.len().is_multiple_of(PAGE) && end != total) {
            return Err(UpdateError::ChunkRange);
        }
        // Only a chunk found good starts a new upload (erasing the slot).
        if restart {
            self.erase_slot(slot)?;
        }
        for (i, page) in data.chunks(PAGE).enumerate() {
            self.write_page(slot, offset / PAGE + i, page)?;
        }
        self.upload()
            .ok_or(UpdateError::Flash(NorFlashErrorKind::Other))
    }

    /// Checks the held upload and makes it the active model: the whole image held, the blob
    /// (format, CRC, `config::SPEC_HASH`), the signature by `key`, a version above the active
    /// one, then `self_test` on the blob in place and its header's golden CRC
    /// ([`Header::golden`]); only then the journal record that switches.
    pub fn commit(
        &mut self,
        key: &[u8; 32],
        self_test: impl FnOnce(&[u8], u32) -> bool,
    ) -> Result<Active, UpdateError> {
        let up = self.upload().ok_or(UpdateError::Incomplete)?;
        if up.held != up.total {
            return Err(UpdateError::Incomplete);
        }
        let slot = up.slot as usize;
        let (header, blob) = self
            .slot_header(slot)
            .ok_or(UpdateError::Header(HeaderError::BadMagic))?;
        Blob::parse(blob, config::SPEC_HASH).map_err(UpdateError::Blob)?;
        if !verify(key, &header.message(blob), &header.signature) {
            return Err(UpdateError::Signature);
        }
        let active = self.active.version();
        if header.version <= active {
            return Err(UpdateError::Rollback {
                active,
                offered: header.version,
            });
        }
        if !self_test(blob, header.golden) {
            return Err(UpdateError::SelfTest);
        }
        let image_crc = self
            .slot_image_crc(slot)
            .ok_or(UpdateError::Flash(NorFlashErrorKind::Other))?;
        self.append(Record {
            seq: self.next_seq,
            slot: slot as u32,
            version: header.version,
            image_crc,
        })?;
        self.active = Active::Slot {
            slot: slot as u8,
            version: header.version,
        };
        Ok(self.active)
    }

    fn blob_cap(&self) -> usize {
        self.layout.image_cap - HEADER_LEN
    }

    /// Slot `s`'s header and blob, if its header parses.
    fn slot_header(&self, s: usize) -> Option<(Header, &[u8])> {
        let at = self.layout.slot(s);
        let bytes = &self.flash.mapped()[at..at + self.layout.image_cap];
        let header = Header::parse(bytes, self.blob_cap()).ok()?;
        Some((header, &bytes[HEADER_LEN..header.image_len()]))
    }

    /// CRC-32 of slot `s`'s image, if its header parses.
    // Not inlined: `open` checks up to four journal records, and a copy each costs flash.
    #[inline(never)]
    fn slot_image_crc(&self, s: usize) -> Option<u32> {
        let (header, _) = self.slot_header(s)?;
        let at = self.layout.slot(s);
        Some(crc32(&self.flash.mapped()[at..at + header.image_len()]))
    }

    /// Whether the `len` bytes at `at` are all erased.
    fn blank(&self, at: usize, len: usize) -> bool {
        self.flash.mapped()[at..at + len].iter().all(|&b| b == 0xFF)
    }

    /// Whether page `p` of slot `s` (its bytes within the image area) is all erased.
    fn page_blank(&self, s: usize, p: usize) -> bool {
        let at = self.layout.slot(s) + p * PAGE;
        self.blank(at, PAGE.min(self.layout.image_cap.saturating_sub(p * PAGE)))
    }

    /// A page mark with any bit programmed: its page was written and read back before it.
    fn mark_done(&self, s: usize, page: usize) -> bool {
        let at = self.layout.mark(s, page);
        self.flash.mapped()[at..at + self.layout.write]
            .iter()
            .any(|&b| b != 0xFF)
    }

    /// Erases slot `s`: its marks first, so that no mark outlives the bytes it vouches for.
    fn erase_slot(&mut self, s: usize) -> Result<(), UpdateError> {
        let (slot, marks) = (self.layout.slot(s), self.layout.marks(s));
        let end = slot + self.layout.slot_len;
        self.flash
            .erase(marks as u32, end as u32)
            .map_err(flash_err)?;
        self.flash
            .erase(slot as u32, marks as u32)
            .map_err(flash_err)
    }

    /// Writes page `p` of slot `s` (skipped when it already holds `data`), reads it back,
    /// then programs its mark (unless it reads programmed).
    fn write_page(&mut self, s: usize, p: usize, data: &[u8]) -> Result<(), UpdateError> {
        let at = self.layout.slot(s) + p * PAGE;
        if &self.flash.mapped()[at..at + data.len()] != data {
            // Only a blank page is written: each write unit is programmed once between erases
            // (ECC flash allows no second program). A page that is not blank holds another
            // upload's bytes, or a page cut short: the slot is erased and the upload restarts.
            if !self.page_blank(s, p) {
                self.erase_slot(s)?;
                return Err(UpdateError::Conflict);
            }
            let w = self.layout.write;
            let whole = data.len() / w * w;
            self.flash
                .write(at as u32, &data[..whole])
                .map_err(flash_err)?;
            if whole < data.len() {
                // The image's last bytes in one unit, padded with the erased value.
                let mut tail = [0xFFu8; MAX_WRITE];
                tail[..data.len() - whole].copy_from_slice(&data[whole..]);
                self.flash
                    .write((at + whole) as u32, &tail[..w])
                    .map_err(flash_err)?;
            }
            if &self.flash.mapped()[at..at + data.len()] != data {
                return Err(UpdateError::Flash(NorFlashErrorKind::Other));
            }
        }
        if !self.mark_done(s, p) {
            let zeros = [0u8; MAX_WRITE];
            let mark = self.layout.mark(s, p) as u32;
            self.flash
                .write(mark, &zeros[..self.layout.write])
                .map_err(flash_err)?;
        }
        Ok(())
    }

    /// Appends a journal record: after the last in the current sector, or at the start of the
    /// other sector (erased first) when this one is full.
    fn append(&mut self, r: Record) -> Result<(), UpdateError> {
        let stride = journal::stride(self.layout.write);
        // Only a blank position is programmed: past a sector's last record the scan stops at
        // the first blank one, and a sector erase a reset cut short can leave older records
        // (or a half-erased word) after it.
        while self.free + stride <= self.layout.erase
            && !self.blank(self.layout.journal(self.sector) + self.free, stride)
        {
            self.free += stride;
        }
        if self.free + stride > self.layout.erase {
            let other = 1 - self.sector;
            let at = self.layout.journal(other);
            self.flash
                .erase(at as u32, (at + self.layout.erase) as u32)
                .map_err(flash_err)?;
            self.sector = other;
            self.free = 0;
        }
        let mut buf = [0xFFu8; journal::RECORD_LEN + MAX_WRITE];
        buf[..journal::RECORD_LEN].copy_from_slice(&r.to_bytes());
        let at = self.layout.journal(self.sector) + self.free;
        if !self.blank(at, stride) {
            return Err(UpdateError::Flash(NorFlashErrorKind::Other));
        }
        // The position is used whatever happens: a cut record is never written over.
        self.free += stride;
        self.flash
            .write(at as u32, &buf[..stride])
            .map_err(flash_err)?;
        self.next_seq = r.seq.wrapping_add(1);
        Ok(())
    }
}
