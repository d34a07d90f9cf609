//! A reader of ROS 2's wire format: OMG CDR (XCDR1) after the 4-byte encapsulation header,
//! little or big endian as the header's representation id says (`CDR_LE` 0x0001, `CDR_BE`
//! 0x0000). Primitives are aligned to their size counted from the first byte after the header;
//! strings are a u32 length (with the NUL) and the bytes; sequences a u32 count and the
//! elements. Every read is bounds-checked, and a count is checked against the bytes left
//! before anything is allocated.

use crate::McapError;

/// A CDR message being read.
#[derive(Clone, Debug)]
pub struct CdrReader<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> CdrReader<'a> {
    /// After the encapsulation header of `bytes`.
    pub fn new(bytes: &'a [u8]) -> Result<Self, McapError> {
        let head = bytes
            .get(..4)
            .ok_or(McapError::Cdr("no encapsulation header"))?;
        let little = match (head[0], head[1]) {
            (0, 1) => true,
            (0, 0) => false,
            _ => return Err(McapError::Cdr("not plain CDR (representation id)")),
        };
        Ok(Self {
            body: &bytes[4..],
            pos: 0,
            little,
        })
    }

    fn bytes<const N: usize>(&mut self) -> Result<[u8; N], McapError> {
        // Aligned to the primitive's size, from the start of the body.
        let pad = (N - self.pos % N) % N;
        let start = self.pos + pad;
        let end = start
            .checked_add(N)
            .filter(|&e| e <= self.body.len())
            .ok_or(McapError::Cdr("message ends early"))?;
        let mut out = [0u8; N];
        out.copy_from_slice(&self.body[start..end]);
        if !self.little {
            out.reverse();
        }
        self.pos = end;
        Ok(out)
    }

    /// A bool (one byte, 0 or 1).
    pub fn bool(&mut self) -> Result<bool, McapError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(McapError::Cdr("bool neither 0 nor 1")),
        }
    }

    /// A u8.
    pub fn u8(&mut self) -> Result<u8, McapError> {
        Ok(self.bytes::<1>()?[0])
    }

    /// A u32.
    pub fn u32(&mut self) -> Result<u32, McapError> {
        Ok(u32::from_le_bytes(self.bytes()?))
    }

    /// An i32.
    pub fn i32(&mut self) -> Result<i32, McapError> {
        Ok(i32::from_le_bytes(self.bytes()?))
    }

    /// An f32.
    pub fn f32(&mut self) -> Result<f32, McapError> {
        Ok(f32::from_le_bytes(self.bytes()?))
    }

    /// An f64.
    pub fn f64(&mut self) -> Result<f64, McapError> {
        Ok(f64::from_le_bytes(self.bytes()?))
    }

    /// A sequence's element count, checked against the bytes left (each element takes at
    /// least `min_size` bytes).
    pub fn count(&mut self, min_size: usize) -> Result<usize, McapError> {
        let n = self.u32()? as usize;
        let left = self.body.len() - self.pos;
        if n.checked_mul(min_size.max(1)).is_none_or(|b| b > left) {
            return Err(McapError::Cdr("sequence longer than the message"));
        }
        Ok(n)
    }

    /// A string (its NUL dropped).
    pub fn string(&mut self) -> Result<String, McapError> {
        let n = self.count(1)?;
        let raw = &self.body[self.pos..self.pos + n];
        self.pos += n;
        let raw = raw.strip_suffix(&[0]).unwrap_or(raw);
        String::from_utf8(raw.to_vec()).map_err(|_| McapError::Cdr("string not UTF-8"))
    }

    /// A `uint8[]`.
    pub fn byte_seq(&mut self) -> Result<&'a [u8], McapError> {
        let n = self.count(1)?;
        let out = &self.body[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    /// A `float32[]`.
    pub fn f32_seq(&mut self) -> Result<Vec<f32>, McapError> {
        let n = self.count(4)?;
        (0..n).map(|_| self.f32()).collect()
    }
}
