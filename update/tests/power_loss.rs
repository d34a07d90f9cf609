//! Updates with the power cut at every write and erase, and the refusals, on the shipped blobs,
//! each on NOR flash (a location may be programmed again) and on ECC flash (`RamFlash`'s
//! write-once mode: a second program of a write unit is an error, a cut unit reads back as
//! garbage).
//!
//! After every cut the partition is opened again ("reboot") and must name exactly one active
//! model whose blob is intact (its image CRC, the blob's own checks) and is the old one until
//! the commit's journal record is whole; the upload then resumes from what the device says it
//! holds (from 0 when a page was cut short) and the commit completes.

use epssn::blob::{Blob, BlobError};
use epssn::config;
use epssn_update::image::{self, HEADER_LEN};
use epssn_update::layout::PAGE;
use epssn_update::ram_flash::{ERASE_SIZE, WRITE_SIZE};
use epssn_update::{Active, RamFlash, UpdateError, Updater};

const OLD: &[u8] = include_bytes!("../../weights/general/epssn-s.q8.bin");
const NEW: &[u8] = include_bytes!("../../weights/site-tank/epssn-s.q8.bin");
/// A blob of another spec (EPSSN-P).
const OTHER_SPEC: &[u8] = include_bytes!("../../weights/paper/epssn-p.q8.bin");

const SECRET: [u8; 32] = [0x42; 32];
/// Two journal sectors and two 32 KiB slots (28 KiB of image each).
const CAPACITY: usize = 2 * ERASE_SIZE + 2 * 32 * 1024;
/// Chunks of two pages: a chunk is several writes, so cuts fall inside chunks too.
const CHUNK: usize = 2 * PAGE;

/// A partition: its bytes and, on ECC flash, the state of each write unit (kept across
/// reboots as the part keeps it).
#[derive(Clone)]
struct Part {
    bytes: Vec<u8>,
    cells: Option<Vec<u8>>,
}

/// The flash of a [`Part`].
type Flash<'a> = RamFlash<&'a mut [u8], Option<&'a mut [u8]>>;

/// NOR flash, then ECC flash (write once).
const WRITE_ONCE: [bool; 2] = [false, true];

impl Part {
    fn blank(write_once: bool) -> Self {
        Part {
            bytes: vec![0xFF; CAPACITY],
            cells: write_once.then(|| vec![0; CAPACITY / WRITE_SIZE]),
        }
    }

    /// The flash at power-on.
    fn flash(&mut self) -> Flash<'_> {
        RamFlash::with_cells(&mut self.bytes[..], self.cells.as_deref_mut()).unwrap()
    }
}

fn key() -> [u8; 32] {
    epssn_update::verify::public_key(&SECRET)
}

fn signed(secret: &[u8; 32], version: u32, blob: &[u8]) -> Vec<u8> {
    let mut out = image::sign(secret, version, 0, blob).to_bytes().to_vec();
    out.extend_from_slice(blob);
    out
}

/// The board's self-test stands in as the model's own construction check.
fn self_test(blob: &[u8], _golden: u32) -> bool {
    epssn::model::Model::from_blob(blob).is_ok()
}

/// Sends the image from `from` in chunks; stops at the first error.
fn upload(u: &mut Updater<Flash<'_>>, img: &[u8], from: usize) -> Result<(), UpdateError> {
    let mut at = from;
    while at < img.len() {
        let end = (at + CHUNK).min(img.len());
        let part = &img[at..end];
        u.chunk(at as u32, part, epssn::crc32::crc32(part))?;
        at = end;
    }
    Ok(())
}

/// Where a resumed upload starts: what the device holds of this image, else 0.
fn resume_point(u: &Updater<Flash<'_>>, img: &[u8]) -> usize {
    let id = epssn::crc32::crc32(&img[..HEADER_LEN]);
    match u.upload() {
        Some(up) if up.id == id => up.held as usize,
        _ => 0,
    }
}

/// The one active model: its version, with its blob checked against what it must be.
fn check_active(u: &Updater<Flash<'_>>, expect: &[(u32, &[u8])]) -> u32 {
    let v = u.active().version();
    let blob = u.active_blob().expect("a slot serves");
    let (_, want) = expect
        .iter()
        .find(|(ver, _)| *ver == v)
        .unwrap_or_else(|| panic!("version {v} serves, none expected"));
    assert_eq!(blob, *want, "the active slot holds version {v}'s blob");
    assert!(Blob::parse(blob, config::SPEC_HASH).is_ok());
    v
}

/// A blank partition with general's blob committed as version 1.
fn with_v1(write_once: bool) -> Part {
    let mut part = Part::blank(write_once);
    commit_v1(part.flash());
    part
}

fn commit_v1(flash: Flash<'_>) {
    let mut u = Updater::open(flash).unwrap();
    assert_eq!(u.active(), Active::Factory);
    upload(&mut u, &signed(&SECRET, 1, OLD), 0).unwrap();
    assert_eq!(
        u.commit(&key(), self_test),
        Ok(Active::Slot {
            slot: 0,
            version: 1
        })
    );
}

#[test]
fn a_cut_at_every_write_and_erase_of_an_update_leaves_one_valid_model() {
    for write_once in WRITE_ONCE {
        cut_at_every_operation(write_once);
    }
}

fn cut_at_every_operation(write_once: bool) {
    let base = with_v1(write_once);
    let img = signed(&SECRET, 2, NEW);
    // The clean run: how many operations, and which one writes the journal record.
    let mut part = base.clone();
    let mut u = Updater::open(part.flash()).unwrap();
    let start = u.flash().ops();
    upload(&mut u, &img, 0).unwrap();
    let before_record = u.flash().ops() - start;
    u.commit(&key(), self_test).unwrap();
    let total = u.flash().ops() - start;
    assert_eq!(total, before_record + 1, "the switch is one write");
    let (mut resumed, mut restarted) = (0, 0);
    for cut in 0..total {
        let mut part = base.clone();
        let mut u = Updater::open(part.flash()).unwrap();
        u.flash().cut_power_at(cut);
        let r = upload(&mut u, &img, 0).and_then(|()| u.commit(&key(), self_test).map(|_| ()));
        assert!(r.is_err() && u.flash().is_off(), "cut {cut} of {total}");
        let mut flash = u.into_flash();
        flash.power_on();
        let mut u = Updater::open(flash).unwrap();
        // The record write is the last operation: cut, it fails its CRC and v1 still serves.
        assert_eq!(check_active(&u, &[(1, OLD)]), 1, "cut {cut}");
        let from = resume_point(&u, &img);
        assert!(
            from.is_multiple_of(PAGE) || from == img.len(),
            "cut {cut}: resume at {from}"
        );
        if from == 0 {
            restarted += 1;
        } else {
            resumed += 1;
        }
        upload(&mut u, &img, from).unwrap_or_else(|e| panic!("cut {cut}: resume: {e:?}"));
        assert_eq!(u.commit(&key(), self_test).map(|a| a.version()), Ok(2));
        let u = Updater::open(u.into_flash()).unwrap();
        assert_eq!(
            check_active(&u, &[(2, NEW)]),
            2,
            "cut {cut}: after the reboot"
        );
    }
    eprintln!(
        "{}: an update is {total} writes and erases; after a cut at each, {resumed} uploads \
         resumed and {restarted} started over",
        if write_once { "ECC flash" } else { "NOR flash" }
    );
    // A cut between pages leaves their progress; one inside a page or before the first mark
    // starts the upload over.
    assert!(resumed > 0 && restarted > 0);
}

#[test]
fn a_page_cut_short_is_not_written_again_the_upload_starts_over() {
    for write_once in WRITE_ONCE {
        let mut part = with_v1(write_once);
        let img = signed(&SECRET, 2, NEW);
        let mut u = Updater::open(part.flash()).unwrap();
        upload(&mut u, &img[..2 * CHUNK], 0).unwrap();
        assert_eq!(resume_point(&u, &img), 2 * CHUNK);
        // The next chunk's first write is its first page: cut halfway.
        u.flash().cut_power_at(0);
        let part3 = &img[2 * CHUNK..3 * CHUNK];
        let crc = epssn::crc32::crc32(part3);
        assert!(u.chunk(2 * CHUNK as u32, part3, crc).is_err());
        let mut flash = u.into_flash();
        flash.power_on();
        let mut u = Updater::open(flash).unwrap();
        assert_eq!(u.upload(), None, "nothing to resume");
        assert_eq!(
            u.chunk(2 * CHUNK as u32, part3, crc),
            Err(UpdateError::ChunkRange)
        );
        assert_eq!(u.commit(&key(), self_test), Err(UpdateError::Incomplete));
        // From 0: the slot is erased first, so no unit is programmed twice.
        let ops = u.flash().ops();
        upload(&mut u, &img[..CHUNK], 0).unwrap();
        assert_eq!(
            u.flash().ops() - ops,
            2 + 2 * 2,
            "two erases, two pages and marks"
        );
        upload(&mut u, &img, CHUNK).unwrap();
        assert_eq!(u.commit(&key(), self_test).map(|a| a.version()), Ok(2));
    }
}

#[test]
fn the_journal_moves_to_its_other_sector_safely() {
    for write_once in WRITE_ONCE {
        journal_sector_change(write_once);
    }
}

fn journal_sector_change(write_once: bool) {
    // Enough commits to fill the first journal sector; cut every operation of the commit
    // that erases the second sector and writes there.
    let mut part = with_v1(write_once);
    let per_sector = ERASE_SIZE / epssn_update::journal::stride(WRITE_SIZE);
    let mut version = 1;
    {
        let mut flash = part.flash();
        for _ in 1..per_sector {
            let mut u = Updater::open(flash).unwrap();
            version += 1;
            upload(&mut u, &signed(&SECRET, version, NEW), 0).unwrap();
            u.commit(&key(), |_, _| true).unwrap();
            flash = u.into_flash();
        }
    }
    let img = signed(&SECRET, version + 1, NEW);
    let snapshot = part.clone();
    let mut u = Updater::open(part.flash()).unwrap();
    upload(&mut u, &img, 0).unwrap();
    let start = u.flash().ops();
    u.commit(&key(), |_, _| true).unwrap();
    let ops = u.flash().ops() - start;
    assert_eq!(ops, 2, "a sector erase, then the record");
    for cut in 0..ops {
        let mut part = snapshot.clone();
        let mut u = Updater::open(part.flash()).unwrap();
        upload(&mut u, &img, 0).unwrap();
        u.flash().cut_power_at(cut);
        assert!(u.commit(&key(), |_, _| true).is_err());
        let mut flash = u.into_flash();
        flash.power_on();
        let mut u = Updater::open(flash).unwrap();
        assert_eq!(
            u.active().version(),
            version,
            "cut {cut}: the previous model"
        );
        assert_eq!(u.active_blob(), Some(NEW));
        assert_eq!(
            u.commit(&key(), |_, _| true).map(|a| a.version()),
            Ok(version + 1)
        );
        let u = Updater::open(u.into_flash()).unwrap();
        assert_eq!(u.active().version(), version + 1);
    }
}

#[test]
fn refusals_leave_the_old_model_serving_and_say_why() {
    for write_once in WRITE_ONCE {
        refusals(write_once);
    }
}

fn refusals(write_once: bool) {
    let mut part = with_v1(write_once);
    let mut u = Updater::open(part.flash()).unwrap();
    let cases: [(&str, Vec<u8>, UpdateError); 4] = [
        (
            "other key",
            signed(&[7; 32], 2, NEW),
            UpdateError::Signature,
        ),
        (
            "older version",
            signed(&SECRET, 1, NEW),
            UpdateError::Rollback {
                active: 1,
                offered: 1,
            },
        ),
        (
            "other spec",
            signed(&SECRET, 2, OTHER_SPEC),
            UpdateError::Blob(BlobError::SpecMismatch {
                blob: u32::from_le_bytes(OTHER_SPEC[12..16].try_into().unwrap()),
                expected: config::SPEC_HASH,
            }),
        ),
        ("self-test", signed(&SECRET, 2, NEW), UpdateError::SelfTest),
    ];
    for (name, img, why) in cases {
        upload(&mut u, &img, 0).unwrap();
        let test = |_: &[u8], _: u32| name != "self-test";
        assert_eq!(u.commit(&key(), test), Err(why), "{name}");
        assert_eq!(check_active(&u, &[(1, OLD)]), 1, "{name}");
    }
    // A chunk whose bytes do not match its CRC is refused and nothing is written.
    let img = signed(&SECRET, 2, NEW);
    let held = u.upload();
    let mut bad = img[..CHUNK].to_vec();
    let crc = epssn::crc32::crc32(&bad);
    bad[100] ^= 1;
    assert_eq!(u.chunk(0, &bad, crc), Err(UpdateError::ChunkCrc));
    assert_eq!(u.upload(), held);
    // A blob corrupted before signing its CRC fails the blob's checks at the commit.
    let mut corrupt = NEW.to_vec();
    corrupt[1000] ^= 1;
    upload(&mut u, &signed(&SECRET, 2, &corrupt), 0).unwrap();
    assert!(matches!(
        u.commit(&key(), self_test),
        Err(UpdateError::Blob(BlobError::BadChecksum { .. }))
    ));
    // Nothing held past a gap, a misaligned chunk, a commit of half an upload.
    upload(&mut u, &img[..CHUNK], 0).unwrap();
    let tail = &img[3 * CHUNK..4 * CHUNK];
    let crc = epssn::crc32::crc32(tail);
    assert_eq!(
        u.chunk(3 * CHUNK as u32, tail, crc),
        Err(UpdateError::ChunkRange)
    );
    assert_eq!(u.chunk(5, tail, crc), Err(UpdateError::ChunkRange));
    assert_eq!(u.commit(&key(), self_test), Err(UpdateError::Incomplete));
    assert_eq!(u.upload().map(|h| h.held), Some(CHUNK as u32));
    // A refused first chunk of another image erases nothing of the held upload.
    let other = signed(&SECRET, 3, NEW);
    let short = &other[..1500];
    let crc = epssn::crc32::crc32(short);
    assert_eq!(u.chunk(0, short, crc), Err(UpdateError::ChunkRange));
    assert_eq!(
        u.upload().map(|h| (h.version, h.held)),
        Some((2, CHUNK as u32))
    );
    upload(&mut u, &img, CHUNK).unwrap();
    assert_eq!(u.commit(&key(), self_test).map(|a| a.version()), Ok(2));
}

#[test]
fn a_resent_chunk_is_not_written_again_and_a_new_upload_restarts_the_slot() {
    for write_once in WRITE_ONCE {
        resent_chunk(write_once);
    }
}

fn resent_chunk(write_once: bool) {
    let mut part = with_v1(write_once);
    let mut u = Updater::open(part.flash()).unwrap();
    let img = signed(&SECRET, 2, NEW);
    upload(&mut u, &img[..2 * CHUNK], 0).unwrap();
    let ops = u.flash().ops();
    upload(&mut u, &img[..2 * CHUNK], 0).unwrap();
    assert_eq!(
        u.flash().ops(),
        ops,
        "held pages are neither erased nor written"
    );
    // Another image at offset 0 erases the slot and starts over.
    let other = signed(&SECRET, 3, NEW);
    let part = &other[..CHUNK];
    let up = u.chunk(0, part, epssn::crc32::crc32(part)).unwrap();
    assert_eq!((up.version, up.held), (3, CHUNK as u32));
    assert_eq!(up.id, epssn::crc32::crc32(&other[..HEADER_LEN]));
}

#[test]
fn a_journal_position_that_is_not_blank_is_skipped() {
    // A sector erase cut short leaves older records after its erased half, past the blank
    // position the scan stops at: appends (here all in one session, no reboot between
    // commits to rescan) must skip them, never program over them.
    let stride = epssn_update::journal::stride(WRITE_SIZE);
    let leftover = 85 * stride;
    for write_once in WRITE_ONCE {
        let mut part = Part::blank(write_once);
        part.bytes[leftover..leftover + stride].fill(0);
        if let Some(cells) = &mut part.cells {
            cells[leftover / WRITE_SIZE..(leftover + stride) / WRITE_SIZE].fill(1);
        }
        let mut u = Updater::open(part.flash()).unwrap();
        for version in 1..=90 {
            upload(&mut u, &signed(&SECRET, version, NEW), 0).unwrap();
            assert_eq!(
                u.commit(&key(), |_, _| true).map(|a| a.version()),
                Ok(version),
                "commit {version}"
            );
        }
        let u = Updater::open(u.into_flash()).unwrap();
        assert_eq!(u.active().version(), 90);
        assert_eq!(u.active_blob(), Some(NEW));
    }
}
