//! The journal: which slot serves, as records appended to two erase sectors in turn.
//!
//! A record (24 bytes, little-endian words, padded to the write unit):
//!
//! ```text
//! 0  magic "EPSJ"   4  seq   8  slot   12  version   16  CRC-32 of the slot's image   20  CRC-32 of bytes 0..20
//! ```
//!
//! The valid record (magic and CRC hold) with the highest `seq` in either sector names the
//! active slot. A record cut by a power loss fails its CRC and the one before it still rules. A
//! sector is erased only to receive the next record when the other sector holds the current
//! one, so an erase cut short leaves that record standing.

use epssn::crc32::crc32;

/// Bytes of a record before padding.
pub const RECORD_LEN: usize = 24;
const MAGIC: [u8; 4] = *b"EPSJ";

/// A journal record: slot `slot` holds image `image_crc` of model `version`, and serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Record {
    /// Increases with every record.
    pub seq: u32,
    /// The slot, 0 or 1.
    pub slot: u32,
    /// The model version in it.
    pub version: u32,
    /// CRC-32 of the slot's image (header and blob).
    pub image_crc: u32,
}

fn word(b: &[u8], i: usize) -> u32 {
    let mut w = [0u8; 4];
    w.copy_from_slice(&b[4 * i..4 * i + 4]);
    u32::from_le_bytes(w)
}

impl Record {
    /// The record's bytes.
    pub fn to_bytes(&self) -> [u8; RECORD_LEN] {
        let mut b = [0u8; RECORD_LEN];
        b[..4].copy_from_slice(&MAGIC);
        for (i, w) in [self.seq, self.slot, self.version, self.image_crc]
            .into_iter()
            .enumerate()
        {
            b[4 + 4 * i..8 + 4 * i].copy_from_slice(&w.to_le_bytes());
        }
        let crc = crc32(&b[..20]);
        b[20..].copy_from_slice(&crc.to_le_bytes());
        b
    }

    /// The record in `b`, if its magic, CRC and slot hold.
    pub fn parse(b: &[u8]) -> Option<Self> {
        let b = b.get(..RECORD_LEN)?;
        if b[..4] != MAGIC || crc32(&b[..20]) != word(b, 5) || word(b, 2) > 1 {
            return None;
        }
        Some(Self {
            seq: word(b, 1),
            slot: word(b, 2),
            version: word(b, 3),
            image_crc: word(b, 4),
        })
    }
}

/// Bytes a record occupies in a sector: [`RECORD_LEN`] rounded up to the write unit.
pub const fn stride(write: usize) -> usize {
    RECORD_LEN.div_ceil(write) * write
}

/// What a scan of one sector found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SectorScan {
    /// Valid records in the order written (at most two are kept: the newest and the one
    /// before, which serves again should the newest slot fail its check).
    pub newest: Option<Record>,
    /// The valid record before `newest`.
    pub previous: Option<Record>,
    /// Offset in the sector of the first record position after the last programmed one.
    pub free: usize,
}

/// Scans a sector's bytes (`sector`, one erase sector) with records every `stride` bytes.
pub fn scan(sector: &[u8], stride: usize) -> SectorScan {
    let mut s = SectorScan::default();
    let mut at = 0;
    while at + stride <= sector.len() {
        let rec = &sector[at..at + stride];
        if rec.iter().all(|&b| b == 0xFF) {
            break;
        }
        // A cut record is skipped but keeps its place: nothing is programmed over it.
        if let Some(r) = Record::parse(rec) {
            if s.newest.is_none_or(|n| r.seq > n.seq) {
                s.previous = s.newest;
                s.newest = Some(r);
            }
        }
        at += stride;
    }
    s.free = at;
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cut_record_is_skipped_and_the_one_before_rules() {
        let a = Record {
            seq: 1,
            slot: 0,
            version: 1,
            image_crc: 9,
        };
        let b = Record {
            seq: 2,
            slot: 1,
            ..a
        };
        let mut sector = [0xFFu8; 256];
        sector[..24].copy_from_slice(&a.to_bytes());
        let mut cut = b.to_bytes();
        cut[12..].fill(0xFF);
        sector[24..48].copy_from_slice(&cut);
        let s = scan(&sector, 24);
        assert_eq!((s.newest, s.free), (Some(a), 48));
        sector[48..72].copy_from_slice(&b.to_bytes());
        let s = scan(&sector, 24);
        assert_eq!((s.newest, s.previous, s.free), (Some(b), Some(a), 72));
    }

    #[test]
    fn parse_refuses_a_bad_slot_or_crc() {
        let r = Record {
            seq: 5,
            slot: 2,
            version: 1,
            image_crc: 0,
        };
        assert_eq!(Record::parse(&r.to_bytes()), None);
        let mut b = Record { slot: 1, ..r }.to_bytes();
        assert!(Record::parse(&b).is_some());
        b[8] ^= 1;
        assert_eq!(Record::parse(&b), None);
    }
}
