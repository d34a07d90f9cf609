//! ROS 2's wire format: OMG CDR, little endian, after the 4-byte encapsulation header
//! (`CDR_LE`), as rmw serialises a message and rosbag2 stores it. The body is written by
//! `cdr-encoding` (serde); its alignment counts from the first byte after the header, which is
//! what the ROS 2 decoders expect.

use anyhow::{Context, Result};
use byteorder::LittleEndian;
use serde::{Serialize, Serializer};

/// The encapsulation header of a little-endian plain CDR message (representation id
/// `CDR_LE` = 0x0001, options 0).
pub const ENCAPSULATION_CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A message as the bytes of an MCAP message record with encoding `cdr`.
pub fn encode<T: Serialize>(msg: &T) -> Result<Vec<u8>> {
    let mut out = ENCAPSULATION_CDR_LE.to_vec();
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut out, msg).context("CDR encoding")?;
    Ok(out)
}

/// A `uint8[]` field: serde's bytes (length, then the bytes in one write) rather than a
/// sequence of single `u8`s, which encodes the same but byte by byte.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Bytes(pub Vec<u8>);

impl Serialize for Bytes {
    fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_bytes(&self.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Probe {
        a: u8,
        b: u32,
        s: String,
        c: f64,
        d: Bytes,
    }

    #[test]
    fn layout_is_little_endian_cdr_aligned_after_the_header() {
        let bytes = encode(&Probe {
            a: 7,
            b: 0x0102_0304,
            s: "ab".into(),
            c: 1.5,
            d: Bytes(vec![9, 8]),
        })
        .unwrap();
        let mut want = ENCAPSULATION_CDR_LE.to_vec();
        want.extend([7, 0, 0, 0]); // u8, then padding to 4
        want.extend([4, 3, 2, 1]); // u32 LE
        want.extend([3, 0, 0, 0, b'a', b'b', 0]); // length with the NUL, bytes, NUL
        want.extend([0]); // padding to 8 (offset 15 → 16)
        want.extend(1.5f64.to_le_bytes());
        want.extend([2, 0, 0, 0, 9, 8]);
        assert_eq!(bytes, want);
    }
}
