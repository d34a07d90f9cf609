//! # epssn-spec
//!
//! The one source of every size, angle and range of epssn: the model spec
//! (`weights/epssn-s.json`) as types ([`spec`]), the sonar geometry ([`geometry`]), the grids
//! and warp tables derived from a spec ([`grids`]) and the CRC-32 that names a spec
//! ([`crc32`]). `no_std` and allocation-free, so the library and the firmware use it as is;
//! the `std` feature adds `load`, the one spec loader and the one beam-table parser that the
//! library's build script and the host tools share, `check`, the rules a spec must keep for
//! the library to be built from it, and `codegen`, the library's generated `config.rs` as
//! text (the build script only reads files and writes it).

#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

#[cfg(any(test, feature = "std"))]
extern crate std;

#[cfg(any(test, feature = "std"))]
pub mod check;
#[cfg(any(test, feature = "std"))]
pub mod codegen;
pub mod crc32;
pub mod geometry;
pub mod grids;
#[cfg(any(test, feature = "std"))]
pub mod load;
pub mod spec;
