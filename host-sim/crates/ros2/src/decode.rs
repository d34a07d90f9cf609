//! An MCAP file read front to back: records in order, chunks decompressed (uncompressed, `lz4`
//! frames with `lz4_flex`, `zstd` with `ruzstd`, both pure Rust) and their records read in
//! place. The summary section and indexes are not needed for one pass and are not read.

use std::collections::BTreeMap;
use std::io::Read;

use crate::header::{is_mcap, Cursor, MAGIC};
use crate::record::{self, Channel, Chunk, Message, Record, Schema};
use crate::McapError;

/// Largest chunk this reader decompresses, bytes: a corrupt size must not allocate the heap away.
pub const MAX_CHUNK_BYTES: u64 = 1 << 28;

/// Every schema, channel and message of a file (messages in file order).
#[derive(Clone, Debug, Default)]
pub struct Contents {
    /// Schemas by id.
    pub schemas: BTreeMap<u16, Schema>,
    /// Channels by id.
    pub channels: BTreeMap<u16, Channel>,
    /// Messages, in file order.
    pub messages: Vec<Message>,
}

impl Contents {
    /// The schema name of a channel (`""` when it has none).
    pub fn schema_name(&self, channel: &Channel) -> &str {
        self.schemas
            .get(&channel.schema_id)
            .map_or("", |s| s.name.as_str())
    }
}

/// Reads a whole MCAP file held in `bytes`. `keep` says, from a channel's schema name, whether
/// its messages are kept (the others are dropped as they are read, sparing the memory).
pub fn read(bytes: &[u8], keep: &dyn Fn(&str) -> bool) -> Result<Contents, McapError> {
    if !is_mcap(bytes) {
        return Err(McapError::Magic);
    }
    let mut c = Cursor::new(&bytes[MAGIC.len()..]);
    let mut out = Contents::default();
    loop {
        if c.remaining() == 0 {
            // A file cut before its footer (a recorder that was killed): what was read stands.
            return Ok(out);
        }
        let (opcode, body) = next_record(&mut c)?;
        match record::parse(opcode, body)? {
            Record::Footer => return Ok(out),
            Record::Chunk(chunk) => {
                let records = decompress(&chunk)?;
                let mut inner = Cursor::new(&records);
                while inner.remaining() > 0 {
                    let (opcode, body) = next_record(&mut inner)?;
                    take(record::parse(opcode, body)?, &mut out, keep)?;
                }
            }
            r => take(r, &mut out, keep)?,
        }
    }
}

/// One record's opcode and body.
fn next_record<'a>(c: &mut Cursor<'a>) -> Result<(u8, &'a [u8]), McapError> {
    let opcode = c.u8()?;
    let len = c.u64()?;
    Ok((opcode, c.take(len)?))
}

fn take(r: Record<'_>, out: &mut Contents, keep: &dyn Fn(&str) -> bool) -> Result<(), McapError> {
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
                out.messages.push(m);
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
