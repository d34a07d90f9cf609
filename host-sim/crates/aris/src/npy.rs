//! NumPy `.npy` files holding float32 arrays, through the `npyz` crate.
//!
//! The sample folders hold little-endian `<f4`, C-order arrays; these functions write exactly
//! that (NumPy's own layout: header padded so the data starts on a 64-byte boundary) and refuse
//! anything else on reading, so a wrong file names its cause instead of being converted.

use std::io::{Cursor, Read};
use std::path::Path;

use anyhow::{ensure, Context, Result};
use npyz::{DType, NpyFile, NpyHeader, Order, TypeStr, WriterBuilder};

/// The one element type of the sample folders.
const F32_LE: &str = "<f4";

fn f32_le() -> DType {
    DType::Plain(
        F32_LE
            .parse::<TypeStr>()
            .expect("'<f4' is a numpy type string"),
    )
}

/// Encodes a float32 array of `shape` (C order) as `.npy` bytes.
pub fn encode_f32(shape: &[usize], data: &[f32]) -> Result<Vec<u8>> {
    let count: usize = shape.iter().product();
    ensure!(
        count == data.len(),
        "npy: shape {shape:?} holds {count} elements but {} were given",
        data.len()
    );
    let dims: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
    let mut out = Vec::with_capacity(128 + data.len() * 4);
    let mut writer = npyz::WriteOptions::new()
        .dtype(f32_le())
        .shape(&dims)
        .writer(&mut out)
        .begin_nd()
        .context("npy: writing the header")?;
    writer
        .extend(data.iter().copied())
        .context("npy: writing the data")?;
    writer.finish().context("npy: finishing the array")?;
    Ok(out)
}

/// Writes a float32 array of `shape` to `path`.
pub fn write_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    let bytes = encode_f32(shape, data)?;
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// A float32 array read from a `.npy` file.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayF32 {
    /// Shape, C order.
    pub shape: Vec<usize>,
    /// Elements, C order.
    pub data: Vec<f32>,
}

/// Decodes `.npy` bytes holding a little-endian float32 C-order array (any format version).
pub fn decode_f32(bytes: &[u8]) -> Result<ArrayF32> {
    let mut cursor = Cursor::new(bytes);
    let header = NpyHeader::from_reader(&mut cursor).context("npy: not a readable NumPy header")?;
    let descr = header.dtype().descr();
    ensure!(
        header.dtype() == f32_le(),
        "npy: element type {descr} is not little-endian float32 ('{F32_LE}')"
    );
    ensure!(
        header.order() == Order::C,
        "npy: Fortran order is not supported"
    );
    let shape = header
        .shape()
        .iter()
        .map(|&d| usize::try_from(d))
        .collect::<Result<Vec<_>, _>>()
        .context("npy: shape too large")?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .context("npy: shape overflows")?;
    // The payload must be exactly the array: a short or long file is refused, not cut.
    let start = usize::try_from(cursor.position()).context("npy: header too long")?;
    let payload = bytes.get(start..).unwrap_or_default();
    ensure!(
        Some(payload.len()) == count.checked_mul(4),
        "npy: shape {shape:?} needs {} data bytes, file has {}",
        count.saturating_mul(4),
        payload.len()
    );
    let data = NpyFile::with_header(header, payload)
        .into_vec::<f32>()
        .context("npy: reading the data")?;
    Ok(ArrayF32 { shape, data })
}

/// Reads a float32 `.npy` file.
pub fn read_f32(path: &Path) -> Result<ArrayF32> {
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .with_context(|| format!("reading {}", path.display()))?;
    decode_f32(&bytes).with_context(|| format!("in {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_2d() {
        let data: Vec<f32> = (0..12).map(|i| i as f32 * 0.5 - 1.0).collect();
        let bytes = encode_f32(&[3, 4], &data).unwrap();
        assert_eq!((bytes.len() - data.len() * 4) % 64, 0, "data 64-aligned");
        let back = decode_f32(&bytes).unwrap();
        assert_eq!(back.shape, vec![3, 4]);
        assert_eq!(back.data, data);
    }

    #[test]
    fn round_trip_nan_and_1d() {
        let data = vec![f32::NAN, 1.5, -0.0];
        let back = decode_f32(&encode_f32(&[3], &data).unwrap()).unwrap();
        assert_eq!(back.shape, vec![3]);
        assert!(back.data[0].is_nan());
        assert_eq!(back.data[1], 1.5);
        assert_eq!(back.data[2].to_bits(), (-0.0f32).to_bits());
    }

    #[test]
    fn header_is_numpy_format() {
        let bytes = encode_f32(&[2, 2], &[1.0, 2.0, 3.0, 4.0]).unwrap();
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        let hl = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        let header = std::str::from_utf8(&bytes[10..10 + hl]).unwrap();
        // npyz writes the shape with a trailing comma, a tuple literal NumPy reads as (2, 2).
        assert!(header.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2, ), }"));
        assert!(header.ends_with('\n'));
        assert_eq!(&bytes[10 + hl..10 + hl + 4], &1.0f32.to_le_bytes());
    }

    #[test]
    fn rejects_bad_input() {
        assert!(encode_f32(&[2, 2], &[1.0]).is_err());
        assert!(decode_f32(b"hello world").is_err());
        let mut bytes = encode_f32(&[2], &[1.0, 2.0]).unwrap();
        bytes.pop();
        assert!(decode_f32(&bytes).is_err());
        // Header edits in place on the bytes (the data is not UTF-8), lengths kept.
        let edit = |from: &[u8], to: &[u8]| {
            let mut b = encode_f32(&[1], &[1.0]).unwrap();
            let at = b.windows(from.len()).position(|w| w == from).unwrap();
            b[at..at + to.len()].copy_from_slice(to);
            b
        };
        let err = decode_f32(&edit(b"<f4", b"<f8")).unwrap_err();
        assert!(format!("{err:#}").contains("float32"), "{err:#}");
        // Trailing bytes past the array are refused too.
        let mut long = encode_f32(&[1], &[1.0]).unwrap();
        long.push(0);
        assert!(decode_f32(&long).is_err());
        // Fortran order is refused, not read transposed.
        let err = decode_f32(&edit(b"False", b"True ")).unwrap_err();
        assert!(format!("{err:#}").contains("Fortran"), "{err:#}");
    }
}
