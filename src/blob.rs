//! The quantised weight blob: a versioned, checksummed container of named tensors.
//!
//! Layout (all integers little-endian):
//!
//! ```text
//! 0   [u8; 8]  magic "EPSSNQ8\0"
//! 8   u32      format version (FORMAT_VERSION)
//! 12  u32      CRC-32 of the model spec file the blob was quantised for
//! 16  u32      tensor count T
//! 20  u32      total blob length in bytes, CRC included
//! 24  T × 32   tensor table: name [u8; 20] (NUL-padded ASCII), dtype u8, 3 reserved bytes,
//!              byte offset u32 (from the blob start, aligned to 4), element count u32
//! ..           tensor data
//! end−4 u32    CRC-32 of every byte before it
//! ```
//!
//! [`Blob::parse`] checks all of it — magic, version, length, CRC, spec hash, that every tensor
//! lies inside the data region — before anything reads a tensor, so a corrupt or mismatched blob
//! is refused with a [`BlobError`] that says which check failed.

use crate::crc32::crc32;

/// Magic bytes at the start of every blob.
pub const MAGIC: [u8; 8] = *b"EPSSNQ8\0";
/// The blob format this library reads and the quantiser writes.
pub const FORMAT_VERSION: u32 = 1;
/// Bytes of the fixed header.
pub const HEADER_LEN: usize = 24;
/// Bytes of one tensor-table entry.
pub const ENTRY_LEN: usize = 32;
/// Bytes of a tensor name field.
pub const NAME_LEN: usize = 20;

/// Element type of a tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Dtype {
    /// Signed 8-bit (weights).
    I8,
    /// Signed 32-bit (biases, requantisation multipliers and shifts).
    I32,
    /// Unsigned 16-bit (the soft-argmax exp table).
    U16,
}

impl Dtype {
    /// Code stored in the tensor table.
    pub const fn code(self) -> u8 {
        match self {
            Dtype::I8 => 0,
            Dtype::I32 => 1,
            Dtype::U16 => 2,
        }
    }

    /// Bytes per element.
    pub const fn size(self) -> usize {
        match self {
            Dtype::I8 => 1,
            Dtype::I32 => 4,
            Dtype::U16 => 2,
        }
    }

    fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Dtype::I8),
            1 => Some(Dtype::I32),
            2 => Some(Dtype::U16),
            _ => None,
        }
    }
}

/// Why a blob was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BlobError {
    /// Shorter than its header, table or declared length.
    Truncated,
    /// The first 8 bytes are not [`MAGIC`].
    BadMagic,
    /// A format version this library does not read.
    UnsupportedVersion(u32),
    /// The declared length differs from the bytes given.
    LengthMismatch {
        /// Length in the header.
        declared: u32,
        /// Bytes given.
        actual: u32,
    },
    /// The CRC-32 does not match: the blob is corrupt.
    BadChecksum {
        /// CRC stored in the blob.
        stored: u32,
        /// CRC computed over the bytes.
        computed: u32,
    },
    /// The blob was quantised for another model spec.
    SpecMismatch {
        /// Spec hash in the blob.
        blob: u32,
        /// Spec hash this library was built from.
        expected: u32,
    },
    /// A tensor-table entry has an unknown dtype, a misaligned offset or lies outside the data.
    BadTensorEntry(u16),
    /// A tensor the model needs is missing.
    MissingTensor,
    /// A tensor has the wrong dtype or element count for the model's shapes.
    ShapeMismatch,
}

/// A tensor-table entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TensorEntry<'a> {
    /// Name bytes without NUL padding.
    pub name: &'a [u8],
    /// Element type.
    pub dtype: Dtype,
    /// Element count.
    pub len: usize,
    /// The tensor's bytes.
    pub bytes: &'a [u8],
}

/// A parsed, verified blob borrowing its bytes (in flash or RAM).
#[derive(Clone, Copy, Debug)]
pub struct Blob<'a> {
    bytes: &'a [u8],
    count: usize,
    spec_hash: u32,
}

fn read_u32(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

impl<'a> Blob<'a> {
    /// Verifies `bytes` against `expected_spec_hash` and the format rules.
    pub fn parse(bytes: &'a [u8], expected_spec_hash: u32) -> Result<Self, BlobError> {
        if bytes.len() < HEADER_LEN + 4 {
            return Err(BlobError::Truncated);
        }
        if bytes[..8] != MAGIC {
            return Err(BlobError::BadMagic);
        }
        let version = read_u32(bytes, 8).ok_or(BlobError::Truncated)?;
        if version != FORMAT_VERSION {
            return Err(BlobError::UnsupportedVersion(version));
        }
        let declared = read_u32(bytes, 20).ok_or(BlobError::Truncated)?;
        let actual = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
        if declared != actual {
            return Err(BlobError::LengthMismatch { declared, actual });
        }
        let body = bytes.len() - 4;
        let stored = read_u32(bytes, body).ok_or(BlobError::Truncated)?;
        let computed = crc32(&bytes[..body]);
        if stored != computed {
            return Err(BlobError::BadChecksum { stored, computed });
        }
        let spec_hash = read_u32(bytes, 12).ok_or(BlobError::Truncated)?;
        if spec_hash != expected_spec_hash {
            return Err(BlobError::SpecMismatch {
                blob: spec_hash,
                expected: expected_spec_hash,
            });
        }
        let count = read_u32(bytes, 16).ok_or(BlobError::Truncated)? as usize;
        let table_end = count
            .checked_mul(ENTRY_LEN)
            .and_then(|t| t.checked_add(HEADER_LEN))
            .ok_or(BlobError::Truncated)?;
        if table_end > body {
            return Err(BlobError::Truncated);
        }
        let blob = Self {
            bytes,
            count,
            spec_hash,
        };
        for i in 0..count {
            let ok = blob
                .entry_checked(i, table_end, body)
                .ok_or(BlobError::BadTensorEntry(i as u16))?;
            let _ = ok;
        }
        Ok(blob)
    }

    fn entry_checked(
        &self,
        i: usize,
        data_start: usize,
        data_end: usize,
    ) -> Option<TensorEntry<'a>> {
        let at = HEADER_LEN + i * ENTRY_LEN;
        let raw = self.bytes.get(at..at + ENTRY_LEN)?;
        let name_len = raw[..NAME_LEN]
            .iter()
            .position(|&c| c == 0)
            .unwrap_or(NAME_LEN);
        let dtype = Dtype::from_code(raw[NAME_LEN])?;
        let offset = read_u32(raw, 24)? as usize;
        let len = read_u32(raw, 28)? as usize;
        let size = len.checked_mul(dtype.size())?;
        let end = offset.checked_add(size)?;
        if !offset.is_multiple_of(4) || offset < data_start || end > data_end {
            return None;
        }
        Some(TensorEntry {
            name: &raw[..name_len],
            dtype,
            len,
            bytes: self.bytes.get(offset..end)?,
        })
    }

    /// Spec hash stored in the blob.
    pub fn spec_hash(&self) -> u32 {
        self.spec_hash
    }

    /// Number of tensors.
    pub fn tensor_count(&self) -> usize {
        self.count
    }

    /// Tensor `i` of the table.
    pub fn entry(&self, i: usize) -> Option<TensorEntry<'a>> {
        if i >= self.count {
            return None;
        }
        self.entry_checked(i, HEADER_LEN + self.count * ENTRY_LEN, self.bytes.len() - 4)
    }

    /// The tensor called `name` with `dtype` and exactly `len` elements.
    pub fn tensor(
        &self,
        name: &str,
        dtype: Dtype,
        len: usize,
    ) -> Result<TensorEntry<'a>, BlobError> {
        let e = (0..self.count)
            .filter_map(|i| self.entry(i))
            .find(|e| e.name == name.as_bytes())
            .ok_or(BlobError::MissingTensor)?;
        if e.dtype != dtype || e.len != len {
            return Err(BlobError::ShapeMismatch);
        }
        Ok(e)
    }

    /// An int8 tensor as a slice.
    pub fn i8_tensor(&self, name: &str, len: usize) -> Result<&'a [i8], BlobError> {
        Ok(bytemuck::cast_slice(
            self.tensor(name, Dtype::I8, len)?.bytes,
        ))
    }

    /// Copies an int32 tensor into `out` (the blob's alignment in memory is not guaranteed).
    pub fn read_i32(&self, name: &str, out: &mut [i32]) -> Result<(), BlobError> {
        let e = self.tensor(name, Dtype::I32, out.len())?;
        for (o, c) in out.iter_mut().zip(e.bytes.chunks_exact(4)) {
            *o = i32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        Ok(())
    }

    /// Copies a u16 tensor into `out`.
    pub fn read_u16(&self, name: &str, out: &mut [u16]) -> Result<(), BlobError> {
        let e = self.tensor(name, Dtype::U16, out.len())?;
        for (o, c) in out.iter_mut().zip(e.bytes.chunks_exact(2)) {
            *o = u16::from_le_bytes([c[0], c[1]]);
        }
        Ok(())
    }
}

/// Writes a blob into `out` from `(name, dtype, little-endian bytes)` tensors; returns its
/// length. Used by the host quantiser and by tests; needs no allocator.
pub fn write_blob(
    spec_hash: u32,
    tensors: &[(&str, Dtype, &[u8])],
    out: &mut [u8],
) -> Result<usize, BlobError> {
    let table_end = HEADER_LEN + tensors.len() * ENTRY_LEN;
    let mut offset = table_end.next_multiple_of(4);
    if out.len() < offset {
        return Err(BlobError::Truncated);
    }
    out[..offset].fill(0);
    out[..8].copy_from_slice(&MAGIC);
    out[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    out[12..16].copy_from_slice(&spec_hash.to_le_bytes());
    out[16..20].copy_from_slice(&(tensors.len() as u32).to_le_bytes());
    for (i, (name, dtype, data)) in tensors.iter().enumerate() {
        if name.len() >= NAME_LEN || data.len() % dtype.size() != 0 {
            return Err(BlobError::BadTensorEntry(i as u16));
        }
        let at = HEADER_LEN + i * ENTRY_LEN;
        out[at..at + name.len()].copy_from_slice(name.as_bytes());
        out[at + NAME_LEN] = dtype.code();
        out[at + 24..at + 28].copy_from_slice(&(offset as u32).to_le_bytes());
        out[at + 28..at + 32].copy_from_slice(&((data.len() / dtype.size()) as u32).to_le_bytes());
        let end = offset + data.len();
        let padded = end.next_multiple_of(4);
        if out.len() < padded + 4 {
            return Err(BlobError::Truncated);
        }
        out[offset..end].copy_from_slice(data);
        out[end..padded].fill(0);
        offset = padded;
    }
    let total = offset + 4;
    out[20..24].copy_from_slice(&(total as u32).to_le_bytes());
    let crc = crc32(&out[..offset]);
    out[offset..total].copy_from_slice(&crc.to_le_bytes());
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(out: &mut [u8]) -> usize {
        let w: [u8; 5] = [1, 0xFF, 3, 0x80, 5];
        let b: [u8; 8] = [1, 0, 0, 0, 0xFE, 0xFF, 0xFF, 0xFF];
        write_blob(
            0xABCD,
            &[("f0.w", Dtype::I8, &w), ("f0.b", Dtype::I32, &b)],
            out,
        )
        .unwrap()
    }

    #[test]
    fn round_trip() {
        let mut buf = [0u8; 256];
        let n = sample(&mut buf);
        let blob = Blob::parse(&buf[..n], 0xABCD).unwrap();
        assert_eq!(blob.tensor_count(), 2);
        assert_eq!(blob.i8_tensor("f0.w", 5).unwrap(), &[1, -1, 3, -128, 5]);
        let mut b = [0i32; 2];
        blob.read_i32("f0.b", &mut b).unwrap();
        assert_eq!(b, [1, -2]);
        assert_eq!(blob.i8_tensor("f0.w", 4), Err(BlobError::ShapeMismatch));
        assert_eq!(blob.i8_tensor("f1.w", 5), Err(BlobError::MissingTensor));
    }

    #[test]
    fn every_single_bit_flip_is_refused() {
        let mut buf = [0u8; 256];
        let n = sample(&mut buf);
        for byte in 0..n {
            for bit in 0..8 {
                let mut c = buf;
                c[byte] ^= 1 << bit;
                assert!(
                    Blob::parse(&c[..n], 0xABCD).is_err(),
                    "flip {byte}.{bit} accepted"
                );
            }
        }
    }

    #[test]
    fn wrong_spec_and_truncation() {
        let mut buf = [0u8; 256];
        let n = sample(&mut buf);
        assert!(matches!(
            Blob::parse(&buf[..n], 0x1234),
            Err(BlobError::SpecMismatch { .. })
        ));
        for cut in 0..n {
            assert!(Blob::parse(&buf[..cut], 0xABCD).is_err());
        }
    }
}
