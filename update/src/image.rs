//! The signed update image: a 96-byte header, then the weight blob.
//!
//! ```text
//! 0   [u8; 8]   magic "EPSSNUP1"
//! 8   u32       model version (the rollback counter: a commit needs one above the active)
//! 12  u32       blob length in bytes
//! 16  u32       golden CRC: CRC-32 of the depth map this blob computes from the boot
//!               self-test's golden pair (`epssn::golden`), which the device reproduces
//!               before the model serves
//! 20  [u8; 12]  reserved, zero
//! 32  [u8; 64]  Ed25519 signature of `header[0..32] ‖ SHA-512(blob)`
//! 96  ..        the blob (`epssn::blob`), 4-byte aligned in the slot like every tensor in it
//! ```
//!
//! The signature covers the version, the length and, through its SHA-512 digest, every byte of
//! the blob (as MCUboot signs an image's hash): the device streams the digest from flash and
//! verifies a 96-byte message, so no copy of the blob is needed in RAM.

use crate::verify;

/// Magic bytes of an update image.
pub const MAGIC: [u8; 8] = *b"EPSSNUP1";
/// Bytes of the header.
pub const HEADER_LEN: usize = 96;
/// Bytes of the header the signature covers directly (the rest is the signature).
pub const SIGNED_LEN: usize = 32;
/// Bytes of the message the signature is over: the signed header and the blob's digest.
pub const MESSAGE_LEN: usize = SIGNED_LEN + 64;

/// Why an image header was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HeaderError {
    /// Fewer than [`HEADER_LEN`] bytes.
    Truncated,
    /// Not [`MAGIC`], or reserved bytes not zero.
    BadMagic,
    /// Version 0 is the compiled-in model's; an update needs 1 or more.
    ZeroVersion,
    /// A blob of 0 bytes, or one that no slot holds.
    BadLength,
}

/// A parsed image header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// The model version.
    pub version: u32,
    /// The blob's length.
    pub blob_len: u32,
    /// CRC-32 of the golden pair's depth map with this blob (the self-test's expectation).
    pub golden: u32,
    /// The Ed25519 signature.
    pub signature: [u8; 64],
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut w = [0u8; 4];
    w.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(w)
}

impl Header {
    /// Parses the first [`HEADER_LEN`] bytes of `bytes`; `max_blob` bounds the length.
    pub fn parse(bytes: &[u8], max_blob: usize) -> Result<Self, HeaderError> {
        let h = bytes.get(..HEADER_LEN).ok_or(HeaderError::Truncated)?;
        if h[..8] != MAGIC || h[20..SIGNED_LEN].iter().any(|&b| b != 0) {
            return Err(HeaderError::BadMagic);
        }
        let version = u32_at(h, 8);
        if version == 0 {
            return Err(HeaderError::ZeroVersion);
        }
        let blob_len = u32_at(h, 12);
        if blob_len == 0 || blob_len as usize > max_blob {
            return Err(HeaderError::BadLength);
        }
        let mut signature = [0u8; 64];
        signature.copy_from_slice(&h[SIGNED_LEN..HEADER_LEN]);
        Ok(Self {
            version,
            blob_len,
            golden: u32_at(h, 16),
            signature,
        })
    }

    /// The header's bytes.
    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut h = [0u8; HEADER_LEN];
        h[..SIGNED_LEN].copy_from_slice(&self.signed_part());
        h[SIGNED_LEN..].copy_from_slice(&self.signature);
        h
    }

    /// The first [`SIGNED_LEN`] bytes: what the signature covers of the header.
    pub fn signed_part(&self) -> [u8; SIGNED_LEN] {
        let mut h = [0u8; SIGNED_LEN];
        h[..8].copy_from_slice(&MAGIC);
        h[8..12].copy_from_slice(&self.version.to_le_bytes());
        h[12..16].copy_from_slice(&self.blob_len.to_le_bytes());
        h[16..20].copy_from_slice(&self.golden.to_le_bytes());
        h
    }

    /// The message the signature is over: [`Header::signed_part`] and SHA-512 of `blob`.
    pub fn message(&self, blob: &[u8]) -> [u8; MESSAGE_LEN] {
        let mut m = [0u8; MESSAGE_LEN];
        m[..SIGNED_LEN].copy_from_slice(&self.signed_part());
        m[SIGNED_LEN..].copy_from_slice(&verify::sha512(blob));
        m
    }

    /// Header and blob length: the bytes an upload carries.
    pub fn image_len(&self) -> usize {
        HEADER_LEN + self.blob_len as usize
    }
}

/// The header of `blob` as model `version` whose golden pair gives a depth map of CRC
/// `golden`, signed with the private key `secret` (the host's `sign`; the device only
/// verifies).
pub fn sign(secret: &[u8; 32], version: u32, golden: u32, blob: &[u8]) -> Header {
    let mut h = Header {
        version,
        blob_len: u32::try_from(blob.len()).unwrap_or(u32::MAX),
        golden,
        signature: [0; 64],
    };
    h.signature = verify::sign(secret, &h.message(blob));
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_round_trips_and_refuses_what_it_must() {
        let h = Header {
            version: 7,
            blob_len: 100,
            golden: 0xDEAD_BEEF,
            signature: [3; 64],
        };
        let b = h.to_bytes();
        assert_eq!(Header::parse(&b, 100), Ok(h));
        assert_eq!(Header::parse(&b, 99), Err(HeaderError::BadLength));
        assert_eq!(Header::parse(&b[..95], 100), Err(HeaderError::Truncated));
        let mut bad = b;
        bad[20] = 1;
        assert_eq!(Header::parse(&bad, 100), Err(HeaderError::BadMagic));
        let zero = Header { version: 0, ..h };
        assert_eq!(
            Header::parse(&zero.to_bytes(), 100),
            Err(HeaderError::ZeroVersion)
        );
    }

    #[test]
    fn message_binds_version_length_and_every_blob_byte() {
        let blob = [1u8, 2, 3, 4];
        let h = Header {
            version: 2,
            blob_len: 4,
            golden: 9,
            signature: [0; 64],
        };
        let m = h.message(&blob);
        assert_ne!(m, Header { version: 3, ..h }.message(&blob));
        assert_ne!(m, Header { golden: 8, ..h }.message(&blob));
        assert_ne!(m, h.message(&[1, 2, 3, 5]));
        assert_ne!(m, Header { blob_len: 3, ..h }.message(&blob[..3]));
    }
}
