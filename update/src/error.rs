//! Why an update step was refused, as the link reports it.

use core::fmt;

use embedded_storage::nor_flash::NorFlashErrorKind;
use epssn::blob::BlobError;
use epssn::link::ErrorCode;

use crate::image::HeaderError;

/// Why an update step was refused. The active model serves on after every one of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpdateError {
    /// The chunk's bytes do not match its CRC.
    ChunkCrc,
    /// A chunk not on a page, past the image, short of a page before the end, or beyond
    /// what is held (resume from [`Upload::held`](crate::Upload::held)); or a chunk after 0 with no upload begun.
    ChunkRange,
    /// The slot held bytes where the chunk goes that are neither the chunk's nor erased
    /// (another upload's): it was erased, resend from offset 0.
    Conflict,
    /// The image header of the chunk at offset 0 was refused.
    Header(HeaderError),
    /// Commit before the whole image is held.
    Incomplete,
    /// The blob was refused: format, CRC or spec hash (`epssn::blob`).
    Blob(BlobError),
    /// The signature is not by the compiled-in key.
    Signature,
    /// The version is not above the active model's.
    Rollback {
        /// The active version.
        active: u32,
        /// The upload's.
        offered: u32,
    },
    /// The boot self-test failed on the new model.
    SelfTest,
    /// The flash failed (a write read back wrong, or an error from the driver).
    Flash(NorFlashErrorKind),
}

impl UpdateError {
    /// The link's error code for this refusal (docs/LINK.md).
    pub fn code(&self) -> ErrorCode {
        match self {
            UpdateError::ChunkCrc => ErrorCode::UploadCrc,
            UpdateError::ChunkRange => ErrorCode::UploadRange,
            UpdateError::Conflict => ErrorCode::UploadConflict,
            UpdateError::Header(_) => ErrorCode::UpdateHeader,
            UpdateError::Incomplete => ErrorCode::UpdateIncomplete,
            UpdateError::Blob(BlobError::SpecMismatch { .. }) => ErrorCode::UpdateSpec,
            UpdateError::Blob(_) => ErrorCode::UpdateBlob,
            UpdateError::Signature => ErrorCode::UpdateSignature,
            UpdateError::Rollback { .. } => ErrorCode::UpdateVersion,
            UpdateError::SelfTest => ErrorCode::UpdateSelfTest,
            UpdateError::Flash(_) => ErrorCode::UpdateFlash,
        }
    }
}

impl fmt::Display for UpdateError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UpdateError::ChunkCrc => write!(f, "chunk crc"),
            UpdateError::ChunkRange => write!(f, "chunk range"),
            UpdateError::Conflict => write!(f, "slot held another upload: resend from 0"),
            UpdateError::Header(e) => write!(f, "image header {e:?}"),
            UpdateError::Incomplete => write!(f, "upload incomplete"),
            UpdateError::Blob(BlobError::SpecMismatch { blob, expected }) => {
                write!(f, "spec {blob:08x} != {expected:08x}")
            }
            UpdateError::Blob(e) => write!(f, "blob {e:?}"),
            UpdateError::Signature => write!(f, "signature"),
            UpdateError::Rollback { active, offered } => {
                write!(f, "version {offered} not above {active}")
            }
            UpdateError::SelfTest => write!(f, "self-test failed"),
            UpdateError::Flash(k) => write!(f, "flash {k:?}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_refusal_has_its_own_update_code() {
        let all = [
            UpdateError::ChunkRange,
            UpdateError::ChunkCrc,
            UpdateError::Conflict,
            UpdateError::Header(HeaderError::BadMagic),
            UpdateError::Incomplete,
            UpdateError::Blob(BlobError::BadMagic),
            UpdateError::Blob(BlobError::SpecMismatch {
                blob: 1,
                expected: 2,
            }),
            UpdateError::Signature,
            UpdateError::Rollback {
                active: 2,
                offered: 1,
            },
            UpdateError::SelfTest,
            UpdateError::Flash(NorFlashErrorKind::Other),
        ];
        let codes: [u16; 11] = all.map(|e| e.code().code());
        assert_eq!(codes, core::array::from_fn(|i| 13 + i as u16));
    }
}
