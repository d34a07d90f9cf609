//! CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320; `CRC_32_ISO_HDLC`), as zlib and PNG
//! compute it, through the maintained `crc` crate (one 1 KiB table, no_std).
//!
//! Used for weight blobs, the link protocol and the model-spec hash; the build script runs this
//! crate too, so the build-time hash and the run-time check are the same code.

use crc::{Crc, Digest, Table, CRC_32_ISO_HDLC};

/// The algorithm with its byte-wise table.
const CRC: Crc<u32, Table<1>> = Crc::<u32, Table<1>>::new(&CRC_32_ISO_HDLC);
/// The same, in one place in flash (a digest borrows it).
static ALGORITHM: Crc<u32, Table<1>> = CRC;

/// Incremental CRC-32 state.
#[derive(Clone)]
pub struct Crc32(Digest<'static, u32, Table<1>>);

impl core::fmt::Debug for Crc32 {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_tuple("Crc32").field(&self.finish()).finish()
    }
}

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

impl Crc32 {
    /// A fresh state.
    pub const fn new() -> Self {
        Self(ALGORITHM.digest())
    }

    /// Feeds bytes.
    pub fn update(&mut self, bytes: &[u8]) {
        self.0.update(bytes);
    }

    /// The checksum of everything fed so far.
    pub fn finish(&self) -> u32 {
        self.0.clone().finalize()
    }
}

/// CRC-32 of `bytes` in one call.
pub fn crc32(bytes: &[u8]) -> u32 {
    ALGORITHM.checksum(bytes)
}

#[cfg(test)]
mod tests {
    #[test]
    fn check_value() {
        // The standard check value of CRC-32/ISO-HDLC.
        assert_eq!(super::crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn incremental_equals_one_call() {
        let mut c = super::Crc32::new();
        c.update(b"1234");
        assert_eq!(c.finish(), super::crc32(b"1234"));
        c.update(b"56789");
        assert_eq!(c.finish(), 0xCBF4_3926);
    }
}
