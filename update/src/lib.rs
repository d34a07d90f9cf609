//! # epssn-update
//!
//! Signed model updates for the epssn co-processor, `no_std` and without unsafe code: a new
//! weight blob arrives over the link in chunks into the slot that does not serve, and a
//! commit checks it whole — image header, blob format, CRC and spec hash (`epssn::blob`), the
//! Ed25519 signature by the compiled-in key over its version and blob ([`image`]), a version
//! above the active one, the board's self-test — before one journal record makes it serve.
//!
//! The state lives in one NorFlash partition (`embedded-storage`; [`layout`]): two journal
//! sectors ([`journal`]) and two slots with per-page progress marks. A power loss at any
//! write or erase leaves exactly one valid active model, and [`Updater::open`] after it finds
//! that model and how much of the upload is held (the tests cut the power at every write and
//! erase of an upload and a commit). Each write unit is programmed at most once between
//! erases, so ECC flash that allows no second program (the STM32H7's) serves as well as NOR
//! flash that does. [`RamFlash`] is NOR flash in RAM with power loss on demand, and ECC flash
//! in RAM in its write-once mode: the QEMU boards' partition and the tests' flash.

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

mod error;
pub mod image;
pub mod journal;
pub mod layout;
pub mod ram_flash;
pub mod updater;
pub mod verify;

pub use ram_flash::RamFlash;
pub use updater::{Active, UpdateError, Updater, Upload};

/// A NorFlash whose contents can also be read in place: memory-mapped flash (the STM32H7's
/// bank 2) or RAM ([`RamFlash`]). The blob is checked, hashed and served from there, never
/// copied. The updater programs no write unit twice between erases, so the flash need not
/// allow it (no `MultiwriteNorFlash`).
pub trait MappedFlash: embedded_storage::nor_flash::NorFlash {
    /// The partition's bytes.
    fn mapped(&self) -> &[u8];
}
