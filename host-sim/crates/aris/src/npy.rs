//! A small reader and writer for NumPy `.npy` files holding float32 arrays.
//!
//! Only what the sample folders need: format version 1.0, little-endian `<f4`, C order. The
//! header is padded so that the data starts on a 64-byte boundary, as NumPy itself writes it.

use std::io::{Read, Write};
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};

const MAGIC: &[u8; 6] = b"\x93NUMPY";

/// Encodes a float32 array of `shape` (C order) as `.npy` bytes.
pub fn encode_f32(shape: &[usize], data: &[f32]) -> Result<Vec<u8>> {
    let count: usize = shape.iter().product();
    ensure!(
        count == data.len(),
        "npy: shape {shape:?} holds {count} elements but {} were given",
        data.len()
    );
    let dims = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {dims}, }}");
    // 10 bytes of preamble, then the header, padded with spaces and ended by '\n'.
    let unpadded = 10 + header.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let header_len = u16::try_from(header.len()).context("npy: header too long")?;
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 4);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&header_len.to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    Ok(out)
}

/// Writes a float32 array of `shape` to `path`.
pub fn write_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    let bytes = encode_f32(shape, data)?;
    let mut f =
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    f.write_all(&bytes)
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// A float32 array read from a `.npy` file.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayF32 {
    /// Shape, C order.
    pub shape: Vec<usize>,
    /// Elements, C order.
    pub data: Vec<f32>,
}

/// Decodes `.npy` bytes holding a little-endian float32 C-order array (format 1.0 or 2.0).
pub fn decode_f32(bytes: &[u8]) -> Result<ArrayF32> {
    ensure!(
        bytes.len() >= 10 && &bytes[..6] == MAGIC,
        "npy: not a NumPy file (bad magic)"
    );
    let major = bytes[6];
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10usize),
        2 | 3 => {
            ensure!(bytes.len() >= 12, "npy: truncated header length");
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => bail!("npy: unsupported format version {v}"),
    };
    let end = start
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .context("npy: header runs past the end of the file")?;
    let header = std::str::from_utf8(&bytes[start..end]).context("npy: header is not text")?;
    let descr = dict_value(header, "descr").context("npy: header has no 'descr'")?;
    ensure!(
        descr.trim_matches(|c| c == '\'' || c == '"') == "<f4",
        "npy: element type {descr} is not little-endian float32 ('<f4')"
    );
    let fortran = dict_value(header, "fortran_order").context("npy: no 'fortran_order'")?;
    ensure!(fortran == "False", "npy: Fortran order is not supported");
    let shape_text = dict_value(header, "shape").context("npy: header has no 'shape'")?;
    let shape: Vec<usize> = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("npy: bad shape {shape_text}"))?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .context("npy: shape overflows")?;
    let payload = &bytes[end..];
    ensure!(
        payload.len() == count * 4,
        "npy: shape {shape:?} needs {} data bytes, file has {}",
        count * 4,
        payload.len()
    );
    let data = payload
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
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

/// The value text of `key` in the header's Python dict literal (`'key': value`).
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pat = format!("'{key}':");
    let at = header.find(&pat)? + pat.len();
    let rest = header[at..].trim_start();
    let end = if rest.starts_with('(') {
        rest.find(')')? + 1
    } else {
        rest.find([',', '}'])?
    };
    Some(rest[..end].trim())
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
        assert!(header.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2), }"));
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
        let f8 = encode_f32(&[1], &[1.0]).unwrap();
        let text = String::from_utf8_lossy(&f8).replace("<f4", "<f8");
        assert!(decode_f32(text.as_bytes()).is_err());
    }
}
