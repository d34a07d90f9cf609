//! An MCAP file read front to back as a stream: records in order, chunks decompressed
//! (uncompressed, `lz4` frames with `lz4_flex`, `zstd` with `ruzstd`, both pure Rust) and their
//! records read in place, one chunk in memory at a time. Each kept message is handed over with
//! its [`Location`], from which it is read again later ([`message_record`],
//! [`chunk_records`], [`message_in_chunk`]): a bag far larger than memory is
//! scanned once and its pings read one by one. The summary section and indexes are not needed
//! for one pass and are not read.

use std::collections::BTreeMap;
use std::io::{self, Read};

use crate::header::{is_mcap, op, slice_at, Cursor, MAGIC};
use crate::record::{self, Channel, Chunk, Message, Record, Schema};
use crate::McapError;

/// Largest chunk this reader decompresses, bytes: a corrupt size must not allocate the heap away.
pub const MAX_CHUNK_BYTES: u64 = 1 << 28;

/// Largest record this reader reads into memory (a chunk's compressed records, a message).
pub const MAX_RECORD_BYTES: u64 = 1 << 28;

/// Every schema and channel of a file (its messages [`scan`] hands over as it reads them).
#[derive(Clone, Debug, Default)]
pub struct Contents {
    /// Schemas by id.
    pub schemas: BTreeMap<u16, Schema>,
    /// Channels by id.
    pub channels: BTreeMap<u16, Channel>,
}

impl Contents {
    /// The schema name of a channel (`""` when it has none).
    pub fn schema_name(&self, channel: &Channel) -> &str {
        self.schemas
            .get(&channel.schema_id)
            .map_or("", |s| s.name.as_str())
    }
}

/// Where a message lies in its file: the top-level record holding it (a message record, or the
/// chunk it is inside) and, for a chunked one, its record's body in the decompressed chunk.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Location {
    /// File offset of the top-level record's body, bytes.
    pub record: u64,
    /// Length of that body, bytes.
    pub record_len: u64,
    /// For a message inside a chunk: its record body's offset and length in the decompressed
    /// records.
    pub in_chunk: Option<(u64, u64)>,
}

/// Reads an MCAP stream front to back, handing each message of a kept channel to `visit` with
/// the schemas and channels read so far and its location; returns the schemas and channels.
pub fn scan(
    mut reader: impl Read,
    keep: &dyn Fn(&str) -> bool,
    visit: &mut dyn FnMut(&Contents, Message, Location) -> Result<(), McapError>,
) -> Result<Contents, McapError> {
    let mut magic = [0u8; MAGIC.len()];
    if read_full(&mut reader, &mut magic)? < magic.len() || !is_mcap(&magic) {
        return Err(McapError::Magic);
    }
    let mut pos = MAGIC.len() as u64;
    let mut out = Contents::default();
    loop {
        let mut head = [0u8; 9];
        match read_full(&mut reader, &mut head)? {
            // A file cut before its footer (a recorder that was killed): what was read stands.
            0 => return Ok(out),
            9 => {}
            _ => return Err(McapError::Truncated(pos as usize)),
        }
        let opcode = head[0];
        let len = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
        let body_at = pos + 9;
        pos = body_at.saturating_add(len);
        if !matches!(
            opcode,
            op::SCHEMA | op::CHANNEL | op::MESSAGE | op::CHUNK | op::FOOTER
        ) {
            let skipped = io::copy(&mut (&mut reader).take(len), &mut io::sink())
                .map_err(|e| McapError::Io(e.to_string()))?;
            if skipped < len {
                return Err(McapError::Truncated(body_at as usize));
            }
            continue;
        }
        let body = read_body(&mut reader, len, body_at)?;
        let top = Location {
            record: body_at,
            record_len: len,
            in_chunk: None,
        };
        match record::parse(opcode, &body)? {
            Record::Footer => return Ok(out),
            Record::Chunk(chunk) => {
                let records = decompress(&chunk)?;
                let mut inner = Cursor::new(&records);
                while inner.remaining() > 0 {
                    let (opcode, body) = next_record(&mut inner)?;
                    let at = (inner.position() - body.len()) as u64;
                    let location = Location {
                        in_chunk: Some((at, body.len() as u64)),
                        ..top
                    };
                    take(
                        record::parse(opcode, body)?,
                        &mut out,
                        keep,
                        location,
                        visit,
                    )?;
                }
            }
            r => take(r, &mut out, keep, top, visit)?,
        }
    }
}

/// The message of a top-level message record's body.
pub fn message_record(body: &[u8]) -> Result<Message, McapError> {
    match record::parse(op::MESSAGE, body)? {
        Record::Message(m) => Ok(m),
        _ => Err(McapError::Changed("no message record there")),
    }
}

/// The records of a top-level chunk record's body, decompressed.
pub fn chunk_records(body: &[u8]) -> Result<Vec<u8>, McapError> {
    match record::parse(op::CHUNK, body)? {
        Record::Chunk(c) => decompress(&c),
        _ => Err(McapError::Changed("no chunk record there")),
    }
}

/// The message at `location` in its chunk's decompressed `records`.
pub fn message_in_chunk(records: &[u8], location: &Location) -> Result<Message, McapError> {
    let (at, len) = location
        .in_chunk
        .ok_or(McapError::Changed("not in a chunk"))?;
    let body = slice_at(records, at, len).ok_or(McapError::Changed("the chunk is shorter"))?;
    message_record(body)
}

/// Fills `buf` as far as the stream goes; how many bytes it read.
fn read_full(reader: &mut impl Read, buf: &mut [u8]) -> Result<usize, McapError> {
    let mut n = 0;
    while n < buf.len() {
        match reader.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(McapError::Io(e.to_string())),
        }
    }
    Ok(n)
}

/// A record's body of `len` bytes, growing as the bytes arrive (a corrupt length allocates no
/// more than the file holds).
fn read_body(reader: &mut impl Read, len: u64, at: u64) -> Result<Vec<u8>, McapError> {
    if len > MAX_RECORD_BYTES {
        return Err(McapError::RecordTooLarge(len));
    }
    let mut body = Vec::new();
    reader
        .take(len)
        .read_to_end(&mut body)
        .map_err(|e| McapError::Io(e.to_string()))?;
    if (body.len() as u64) < len {
        return Err(McapError::Truncated(at as usize));
    }
    Ok(body)
}

/// One record's opcode and body.
fn next_record<'a>(c: &mut Cursor<'a>) -> Result<(u8, &'a [u8]), McapError> {
    let opcode = c.u8()?;
    let len = c.u64()?;
    Ok((opcode, c.take(len)?))
}

fn take(
    r: Record<'_>,
    out: &mut Contents,
    keep: &dyn Fn(&str) -> bool,
    location: Location,
    visit: &mut dyn FnMut(&Contents, Message, Location) -> Result<(), McapError>,
) -> Result<(), McapError> {
    match r {
        Record::Schema(s) => {
            out.schemas.insert(s.id, s);
        }
        Record::Channel(ch) => {
            out.channels.insert(ch.id, ch);
        }
        Record::Message(m) => {
            let channel = out
                .channels
                .get(&m.channel_id)
                .ok_or(McapError::UnknownChannel(m.channel_id))?;
            if keep(out.schema_name(channel)) {
                visit(out, m, location)?;
            }
        }
        Record::Chunk(_) => return Err(McapError::NestedChunk),
        Record::Footer | Record::Other => {}
    }
    Ok(())
}

/// A chunk's records, decompressed and checked against the size the chunk declares.
pub fn decompress(chunk: &Chunk<'_>) -> Result<Vec<u8>, McapError> {
    let size = chunk.uncompressed_size;
    if size > MAX_CHUNK_BYTES {
        return Err(McapError::ChunkTooLarge(size));
    }
    let mut out = Vec::new();
    // One byte more than declared: a longer stream is caught, not read to exhaustion.
    let limit = size + 1;
    match chunk.compression.as_str() {
        "" => out.extend_from_slice(chunk.records),
        "lz4" => {
            lz4_flex::frame::FrameDecoder::new(chunk.records)
                .take(limit)
                .read_to_end(&mut out)
                .map_err(|e| McapError::Decompress(format!("lz4: {e}")))?;
        }
        "zstd" => {
            let mut records = chunk.records;
            let decoder = ruzstd::decoding::StreamingDecoder::new(&mut records)
                .map_err(|e| McapError::Decompress(format!("zstd: {e}")))?;
            decoder
                .take(limit)
                .read_to_end(&mut out)
                .map_err(|e| McapError::Decompress(format!("zstd: {e}")))?;
        }
        other => return Err(McapError::Compression(other.to_string())),
    }
    if out.len() as u64 != size {
        return Err(McapError::ChunkSize {
            declared: size,
            actual: out.len() as u64,
        });
    }
    Ok(out)
}
