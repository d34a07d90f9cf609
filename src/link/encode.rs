//! Encoding messages onto the wire.

use crate::crc32::Crc32;

use super::header::Header;
use super::message::{Message, Payload};
use super::{CRC_LEN, MAX_HEADER_LEN, PREAMBLE_LEN, SYNC};

/// Why encoding failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError<E> {
    /// The JSON header does not fit in [`MAX_HEADER_LEN`] bytes.
    HeaderTooLong,
    /// The sink failed.
    Sink(E),
}

/// The sink of [`encode_to_slice`] is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SliceFull;

/// Encodes a raw header and payload (no validation: the host's fuzzer sends invalid ones on
/// purpose) into `sink`, in pieces. Returns the bytes written.
pub fn encode_raw<E>(
    header: &Header<'_>,
    payload: Payload<'_>,
    sink: &mut impl FnMut(&[u8]) -> Result<(), E>,
) -> Result<usize, EncodeError<E>> {
    let mut json = [0u8; MAX_HEADER_LEN];
    let h = serde_json_core::to_slice(header, &mut json).map_err(|_| EncodeError::HeaderTooLong)?;
    let json = json.get(..h).ok_or(EncodeError::HeaderTooLong)?;
    let h16 = u16::try_from(h).map_err(|_| EncodeError::HeaderTooLong)?;
    let mut crc = Crc32::new();
    sink(&SYNC).map_err(EncodeError::Sink)?;
    sink(&h16.to_le_bytes()).map_err(EncodeError::Sink)?;
    sink(json).map_err(EncodeError::Sink)?;
    crc.update(json);
    match payload {
        Payload::Bytes(b) => {
            crc.update(b);
            sink(b).map_err(EncodeError::Sink)?;
        }
        Payload::Depth(values) => {
            // Chunks keep the stack small on the device.
            let mut chunk = [0u8; 256];
            for part in values.chunks(chunk.len() / 4) {
                let n = part.len() * 4;
                for (out, v) in chunk.chunks_exact_mut(4).zip(part) {
                    out.copy_from_slice(&v.to_bits().to_le_bytes());
                }
                crc.update(&chunk[..n]);
                sink(&chunk[..n]).map_err(EncodeError::Sink)?;
            }
        }
    }
    sink(&crc.finish().to_le_bytes()).map_err(EncodeError::Sink)?;
    Ok(PREAMBLE_LEN + h + payload.len() + CRC_LEN)
}

/// Encodes a message into `sink`; returns the bytes written.
pub fn encode<E>(
    msg: &Message<'_>,
    sink: &mut impl FnMut(&[u8]) -> Result<(), E>,
) -> Result<usize, EncodeError<E>> {
    let (header, payload) = msg.to_parts();
    encode_raw(&header, payload, sink)
}

/// Encodes a message into `out`; returns the bytes written.
pub fn encode_to_slice(msg: &Message<'_>, out: &mut [u8]) -> Result<usize, EncodeError<SliceFull>> {
    let mut at = 0usize;
    encode(msg, &mut |bytes: &[u8]| {
        let end = at.checked_add(bytes.len()).ok_or(SliceFull)?;
        let dst = out.get_mut(at..end).ok_or(SliceFull)?;
        dst.copy_from_slice(bytes);
        at += bytes.len();
        Ok(())
    })
}
