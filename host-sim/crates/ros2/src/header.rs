//! MCAP's framing (<https://mcap.dev/spec>): the magic at both ends of a file, the record
//! opcodes, and a bounds-checked little-endian cursor over a record's bytes. Every read that
//! would pass the end is an error, never a panic.

use crate::McapError;

/// The 8 bytes that open and close an MCAP file: `0x89 "MCAP" '0' '\r' '\n'`.
pub const MAGIC: [u8; 8] = [0x89, b'M', b'C', b'A', b'P', b'0', b'\r', b'\n'];

/// Record opcodes this reader acts on (every other record is skipped by its length).
pub mod op {
    /// Header: profile and library.
    pub const HEADER: u8 = 0x01;
    /// Footer: the end of the data section.
    pub const FOOTER: u8 = 0x02;
    /// Schema: id, name, encoding, data.
    pub const SCHEMA: u8 = 0x03;
    /// Channel: id, schema id, topic, message encoding, metadata.
    pub const CHANNEL: u8 = 0x04;
    /// Message: channel id, sequence, log and publish time, data.
    pub const MESSAGE: u8 = 0x05;
    /// Chunk: a (possibly compressed) run of schema, channel and message records.
    pub const CHUNK: u8 = 0x06;
}

/// Whether `bytes` starts as an MCAP file does.
pub fn is_mcap(bytes: &[u8]) -> bool {
    bytes.starts_with(&MAGIC)
}

/// The `len` bytes of `bytes` at `offset`, or `None` where they run past its end.
pub fn slice_at(bytes: &[u8], offset: u64, len: u64) -> Option<&[u8]> {
    let at = usize::try_from(offset).ok()?;
    bytes.get(at..at.checked_add(usize::try_from(len).ok()?)?)
}

/// A cursor over a byte slice, little-endian as MCAP is.
#[derive(Clone, Debug)]
pub struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    /// At the start of `bytes`.
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0 }
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.pos
    }

    /// Offset from the start.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: u64) -> Result<&'a [u8], McapError> {
        let n = usize::try_from(n).map_err(|_| McapError::Truncated(self.pos))?;
        if n > self.remaining() {
            return Err(McapError::Truncated(self.pos));
        }
        let out = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], McapError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.take(N as u64)?);
        Ok(out)
    }

    /// One byte.
    pub fn u8(&mut self) -> Result<u8, McapError> {
        Ok(self.array::<1>()?[0])
    }

    /// A little-endian u16.
    pub fn u16(&mut self) -> Result<u16, McapError> {
        Ok(u16::from_le_bytes(self.array()?))
    }

    /// A little-endian u32.
    pub fn u32(&mut self) -> Result<u32, McapError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    /// A little-endian u64.
    pub fn u64(&mut self) -> Result<u64, McapError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    /// A string: u32 byte length, then UTF-8.
    pub fn string(&mut self) -> Result<String, McapError> {
        let n = self.u32()?;
        let at = self.pos;
        let bytes = self.take(u64::from(n))?;
        String::from_utf8(bytes.to_vec()).map_err(|_| McapError::Utf8(at))
    }

    /// A byte array with a u32 length.
    pub fn bytes_u32(&mut self) -> Result<&'a [u8], McapError> {
        let n = self.u32()?;
        self.take(u64::from(n))
    }
}
