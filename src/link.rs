//! The link protocol between the vehicle's host and the co-processor (UART), shared by the
//! firmware and the host tools. Wire format (see `docs/LINK.md`):
//!
//! ```text
//! SYNC (4 bytes: A5 5A 45 50) | header length H (u16 LE) | H bytes JSON header
//!     | payload (`len` bytes from the header, 0 when absent) | CRC-32 (u32 LE) over header+payload
//! ```
//!
//! The JSON header always has `t` (type) and `seq`; the other fields depend on the type
//! ([`Header`]). [`Decoder`] is a streaming decoder that never panics, resynchronises on
//! garbage and reports every rejected message with a [`DecodeError`].
//!
//! ```
//! use epssn::link::{encode_to_slice, Decoder, Message, MAX_MESSAGE_LEN};
//!
//! let mut wire = [0u8; 64];
//! let n = encode_to_slice(&Message::StatusRequest { seq: 7 }, &mut wire).unwrap();
//! let mut decoder = Decoder::new();
//! let mut got = None;
//! for &byte in &wire[..n] {
//!     decoder.push(byte);
//!     while let Some(event) = decoder.poll() {
//!         got = Some(event.map(|m| m.seq()));
//!     }
//! }
//! assert_eq!(got, Some(Ok(7)));
//! ```

use core::fmt;

use fixed::types::U16F16;
use serde::{Deserialize, Serialize};

use crate::config;
use crate::crc32::Crc32;

/// Start of every message. Two bytes unlikely in text, then "EP".
pub const SYNC: [u8; 4] = [0xA5, 0x5A, b'E', b'P'];
/// Sync bytes plus the u16 header length.
pub const PREAMBLE_LEN: usize = SYNC.len() + 2;
/// Longest JSON header accepted.
pub const MAX_HEADER_LEN: usize = 192;
/// Bytes of the trailing CRC-32.
pub const CRC_LEN: usize = 4;
/// Payload of a frame message: one u8 polar image, R × B.
pub const FRAME_PAYLOAD_LEN: usize = config::INPUT_LEN;
/// Payload of a depth message: the depth map as U16F16 bits, u32 LE each.
pub const DEPTH_PAYLOAD_LEN: usize = config::DEPTH_LEN * 4;
/// Largest payload of any message type.
pub const MAX_PAYLOAD_LEN: usize = if FRAME_PAYLOAD_LEN > DEPTH_PAYLOAD_LEN {
    FRAME_PAYLOAD_LEN
} else {
    DEPTH_PAYLOAD_LEN
};
/// Largest message on the wire.
pub const MAX_MESSAGE_LEN: usize = PREAMBLE_LEN + MAX_HEADER_LEN + MAX_PAYLOAD_LEN + CRC_LEN;
/// Longest error text in an error message.
pub const MAX_ERROR_TEXT: usize = 48;
/// Source views of a depth map at most.
pub const MAX_SOURCES: usize = config::MAX_VIEWS - 1;

/// Message types (`t` in the header).
pub mod kind {
    /// Host → device: one polar image and its roll.
    pub const FRAME: &str = "frame";
    /// Device → host: a depth map.
    pub const DEPTH: &str = "depth";
    /// Host → device: asks for a status reply.
    pub const STATUS_REQUEST: &str = "status?";
    /// Device → host: counters.
    pub const STATUS: &str = "status";
    /// Device → host: a message was rejected.
    pub const ERROR: &str = "error";
    /// Host → device: stop serving (the device answers with a status first).
    pub const SHUTDOWN: &str = "shutdown";
}

/// The JSON header as on the wire: every field but `t` and `seq` is optional and only the
/// fields of the message type are written.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Header<'a> {
    /// Message type, one of [`kind`].
    pub t: &'a str,
    /// Sequence number: strictly increasing per direction.
    pub seq: u32,
    /// Frame: roll of the sonar, degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roll: Option<f32>,
    /// Frame: range bins of the polar image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub r: Option<u32>,
    /// Frame: beam columns of the polar image.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub b: Option<u32>,
    /// Payload bytes (absent = 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub len: Option<u32>,
    /// Depth: `seq` of the reference frame.
    #[serde(default, rename = "ref", skip_serializing_if = "Option::is_none")]
    pub reference: Option<u32>,
    /// Depth: `seq`s of the source frames, view 1 first.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub src: Option<heapless::Vec<u32, MAX_SOURCES>>,
    /// Depth: instructions spent computing the map.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instr: Option<u32>,
    /// Status: frames accepted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<u32>,
    /// Status: depth maps sent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depths: Option<u32>,
    /// Status: errors replied.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub errors: Option<u32>,
    /// Status: stack high-water mark, bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stack: Option<u32>,
    /// Status: feature maps cached for pairing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cached: Option<u32>,
    /// Error: [`ErrorCode`] number.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub code: Option<u16>,
    /// Error: short text.
    #[serde(default, borrow, skip_serializing_if = "Option::is_none")]
    pub msg: Option<&'a str>,
}

/// Error codes of error messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// Bytes before a sync pattern were skipped.
    BadSync = 1,
    /// Header length over [`MAX_HEADER_LEN`] (or zero).
    HeaderTooLong = 2,
    /// The header is not valid JSON of the expected shape, or a field is missing or invalid.
    BadJson = 3,
    /// CRC mismatch.
    BadCrc = 4,
    /// Payload length over [`MAX_PAYLOAD_LEN`].
    Oversized = 5,
    /// Unknown message type.
    UnknownType = 6,
    /// Frame dimensions differ from the compiled configuration.
    WrongGeometry = 7,
    /// `seq` not greater than the previous message's.
    OutOfOrder = 8,
    /// Payload length inconsistent with the message type.
    BadLength = 9,
    /// A valid message the receiver does not accept (e.g. a depth map sent to the device).
    Unexpected = 10,
    /// Inference failed on the device.
    Model = 11,
    /// The line went idle inside a message.
    Truncated = 12,
}

impl ErrorCode {
    /// Every code, for lookups.
    pub const ALL: [ErrorCode; 12] = [
        ErrorCode::BadSync,
        ErrorCode::HeaderTooLong,
        ErrorCode::BadJson,
        ErrorCode::BadCrc,
        ErrorCode::Oversized,
        ErrorCode::UnknownType,
        ErrorCode::WrongGeometry,
        ErrorCode::OutOfOrder,
        ErrorCode::BadLength,
        ErrorCode::Unexpected,
        ErrorCode::Model,
        ErrorCode::Truncated,
    ];

    /// The number on the wire.
    pub fn code(self) -> u16 {
        self as u16
    }

    /// The code of a wire number.
    pub fn from_code(code: u16) -> Option<Self> {
        Self::ALL.iter().copied().find(|c| c.code() == code)
    }
}

/// Why the decoder rejected bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// `skipped` bytes arrived that did not start a message.
    BadSync {
        /// Bytes dropped before the next sync pattern.
        skipped: usize,
    },
    /// The header length field is zero or over [`MAX_HEADER_LEN`].
    HeaderTooLong {
        /// The length field.
        len: usize,
    },
    /// The header is not JSON of the expected shape.
    BadJson,
    /// A field the message type needs is absent or invalid.
    BadField {
        /// The field.
        field: &'static str,
    },
    /// CRC mismatch.
    BadCrc {
        /// CRC on the wire.
        wire: u32,
        /// CRC of the received header and payload.
        computed: u32,
    },
    /// Payload length over [`MAX_PAYLOAD_LEN`].
    Oversized {
        /// The `len` field.
        len: u32,
    },
    /// `t` is not one of [`kind`].
    UnknownType,
    /// A frame whose dimensions are not the compiled configuration's R × B.
    WrongGeometry {
        /// `r` on the wire.
        r: u32,
        /// `b` on the wire.
        b: u32,
    },
    /// Payload length wrong for the type.
    BadLength {
        /// The `len` field.
        len: u32,
        /// The length the type needs.
        expected: u32,
    },
    /// The line went idle with `have` bytes of an incomplete message.
    Truncated {
        /// Bytes held.
        have: usize,
    },
    /// `seq` not greater than the last accepted one.
    OutOfOrder {
        /// The last accepted `seq`.
        last: u32,
        /// The `seq` received.
        seq: u32,
    },
}

impl DecodeError {
    /// The error code reported to the peer.
    pub fn code(&self) -> ErrorCode {
        match self {
            DecodeError::BadSync { .. } => ErrorCode::BadSync,
            DecodeError::HeaderTooLong { .. } => ErrorCode::HeaderTooLong,
            DecodeError::BadJson | DecodeError::BadField { .. } => ErrorCode::BadJson,
            DecodeError::BadCrc { .. } => ErrorCode::BadCrc,
            DecodeError::Oversized { .. } => ErrorCode::Oversized,
            DecodeError::UnknownType => ErrorCode::UnknownType,
            DecodeError::WrongGeometry { .. } => ErrorCode::WrongGeometry,
            DecodeError::BadLength { .. } => ErrorCode::BadLength,
            DecodeError::OutOfOrder { .. } => ErrorCode::OutOfOrder,
            DecodeError::Truncated { .. } => ErrorCode::Truncated,
        }
    }
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::BadSync { skipped } => write!(f, "skipped {skipped} bytes"),
            DecodeError::HeaderTooLong { len } => write!(f, "header length {len}"),
            DecodeError::BadJson => write!(f, "bad json header"),
            DecodeError::BadField { field } => write!(f, "bad field {field}"),
            DecodeError::BadCrc { wire, computed } => {
                write!(f, "crc {wire:08x} != {computed:08x}")
            }
            DecodeError::Oversized { len } => write!(f, "payload {len} too long"),
            DecodeError::UnknownType => write!(f, "unknown type"),
            DecodeError::WrongGeometry { r, b } => write!(
                f,
                "geometry {r}x{b} != {}x{}",
                config::INPUT_RANGE_BINS,
                config::INPUT_COLUMNS
            ),
            DecodeError::BadLength { len, expected } => write!(f, "len {len} != {expected}"),
            DecodeError::OutOfOrder { last, seq } => write!(f, "seq {seq} after {last}"),
            DecodeError::Truncated { have } => write!(f, "idle after {have} bytes"),
        }
    }
}

/// Short error text for an error message: `Display` of `e`, cut to [`MAX_ERROR_TEXT`].
pub fn error_text(e: &impl fmt::Display) -> heapless::String<MAX_ERROR_TEXT> {
    struct Cut(heapless::String<MAX_ERROR_TEXT>);
    impl fmt::Write for Cut {
        fn write_str(&mut self, s: &str) -> fmt::Result {
            for c in s.chars() {
                // Full: drop the rest rather than fail the whole message.
                if self.0.push(c).is_err() {
                    break;
                }
            }
            Ok(())
        }
    }
    let mut cut = Cut(heapless::String::new());
    let _ = fmt::write(&mut cut, format_args!("{e}"));
    cut.0
}

/// Device counters carried by a status message.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// Frames accepted.
    pub frames: u32,
    /// Depth maps sent.
    pub depth_maps: u32,
    /// Error replies sent.
    pub errors: u32,
    /// Stack high-water mark, bytes.
    pub stack_high_water: u32,
    /// Feature maps cached for pairing.
    pub cached: u32,
}

/// A depth map payload: values to send, or received little-endian bytes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DepthData<'a> {
    /// `config::DEPTH_LEN` values, to encode.
    Values(&'a [U16F16]),
    /// Received payload, `config::DEPTH_LEN` × u32 LE.
    Bytes(&'a [u8]),
}

impl DepthData<'_> {
    /// Values in the payload.
    pub fn len(&self) -> usize {
        match self {
            DepthData::Values(v) => v.len(),
            DepthData::Bytes(b) => b.len() / 4,
        }
    }

    /// True without values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i`, if present.
    pub fn get(&self, i: usize) -> Option<U16F16> {
        match self {
            DepthData::Values(v) => v.get(i).copied(),
            DepthData::Bytes(b) => {
                let at = i.checked_mul(4)?;
                let w = b.get(at..at.checked_add(4)?)?;
                Some(U16F16::from_bits(u32::from_le_bytes([
                    w[0], w[1], w[2], w[3],
                ])))
            }
        }
    }

    /// Copies the values into `out` (same length), or returns false.
    pub fn copy_to(&self, out: &mut [U16F16]) -> bool {
        if out.len() != self.len() {
            return false;
        }
        for (i, o) in out.iter_mut().enumerate() {
            match self.get(i) {
                Some(v) => *o = v,
                None => return false,
            }
        }
        true
    }
}

/// A typed message.
#[derive(Clone, Debug, PartialEq)]
pub enum Message<'a> {
    /// Host → device: a polar image (`config::INPUT_LEN` bytes, `img[i · B + k]`).
    Frame {
        /// Sequence number.
        seq: u32,
        /// Sonar roll, degrees.
        roll_deg: f32,
        /// The image.
        image: &'a [u8],
    },
    /// Device → host: a depth map.
    Depth {
        /// Sequence number.
        seq: u32,
        /// `seq` of the reference frame.
        reference: u32,
        /// `seq`s of the source frames (view 1 first).
        sources: heapless::Vec<u32, MAX_SOURCES>,
        /// Instructions spent: the newest frame's features plus the depth map.
        instructions: u32,
        /// The map, `config::DEPTH_LEN` values, `[E][A]`, metres.
        depth: DepthData<'a>,
    },
    /// Host → device: status request.
    StatusRequest {
        /// Sequence number.
        seq: u32,
    },
    /// Device → host: status reply.
    Status {
        /// Sequence number.
        seq: u32,
        /// The counters.
        status: Status,
    },
    /// Device → host: a rejected message.
    Error {
        /// Sequence number.
        seq: u32,
        /// [`ErrorCode`] number.
        code: u16,
        /// Short text.
        msg: &'a str,
    },
    /// Host → device: stop serving.
    Shutdown {
        /// Sequence number.
        seq: u32,
    },
}

impl Message<'_> {
    /// The sequence number.
    pub fn seq(&self) -> u32 {
        match self {
            Message::Frame { seq, .. }
            | Message::Depth { seq, .. }
            | Message::StatusRequest { seq }
            | Message::Status { seq, .. }
            | Message::Error { seq, .. }
            | Message::Shutdown { seq } => *seq,
        }
    }

    /// The type string on the wire.
    pub fn kind(&self) -> &'static str {
        match self {
            Message::Frame { .. } => kind::FRAME,
            Message::Depth { .. } => kind::DEPTH,
            Message::StatusRequest { .. } => kind::STATUS_REQUEST,
            Message::Status { .. } => kind::STATUS,
            Message::Error { .. } => kind::ERROR,
            Message::Shutdown { .. } => kind::SHUTDOWN,
        }
    }

    /// Header and payload of the message.
    pub fn to_parts(&self) -> (Header<'_>, Payload<'_>) {
        let mut h = Header {
            t: self.kind(),
            seq: self.seq(),
            ..Header::default()
        };
        let payload = match self {
            Message::Frame {
                roll_deg, image, ..
            } => {
                h.roll = Some(*roll_deg);
                h.r = Some(config::INPUT_RANGE_BINS as u32);
                h.b = Some(config::INPUT_COLUMNS as u32);
                Payload::Bytes(image)
            }
            Message::Depth {
                reference,
                sources,
                instructions,
                depth,
                ..
            } => {
                h.reference = Some(*reference);
                h.src = Some(sources.clone());
                h.instr = Some(*instructions);
                match depth {
                    DepthData::Values(v) => Payload::Depth(v),
                    DepthData::Bytes(b) => Payload::Bytes(b),
                }
            }
            Message::Status { status, .. } => {
                h.frames = Some(status.frames);
                h.depths = Some(status.depth_maps);
                h.errors = Some(status.errors);
                h.stack = Some(status.stack_high_water);
                h.cached = Some(status.cached);
                Payload::Bytes(&[])
            }
            Message::Error { code, msg, .. } => {
                h.code = Some(*code);
                h.msg = Some(msg);
                Payload::Bytes(&[])
            }
            Message::StatusRequest { .. } | Message::Shutdown { .. } => Payload::Bytes(&[]),
        };
        if !payload.is_empty() {
            h.len = Some(u32::try_from(payload.len()).unwrap_or(u32::MAX));
        }
        (h, payload)
    }
}

/// A payload to encode.
#[derive(Clone, Copy, Debug)]
pub enum Payload<'a> {
    /// Raw bytes.
    Bytes(&'a [u8]),
    /// Depth values, written as u32 LE bits.
    Depth(&'a [U16F16]),
}

impl Payload<'_> {
    /// Bytes on the wire.
    pub fn len(&self) -> usize {
        match self {
            Payload::Bytes(b) => b.len(),
            Payload::Depth(v) => v.len() * 4,
        }
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

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

/// Checks a parsed header; returns its payload length.
fn check_header(h: &Header<'_>) -> Result<usize, DecodeError> {
    let len = h.len.unwrap_or(0);
    // Type and geometry first (they say more), then the length.
    let expect = |expected: usize| {
        if len as usize > MAX_PAYLOAD_LEN {
            Err(DecodeError::Oversized { len })
        } else if len as usize == expected {
            Ok(len as usize)
        } else {
            Err(DecodeError::BadLength {
                len,
                expected: expected as u32,
            })
        }
    };
    let need = |present: bool, field: &'static str| {
        if present {
            Ok(())
        } else {
            Err(DecodeError::BadField { field })
        }
    };
    match h.t {
        kind::FRAME => {
            need(h.roll.is_some_and(f32::is_finite), "roll")?;
            let (r, b) = match (h.r, h.b) {
                (Some(r), Some(b)) => (r, b),
                _ => return Err(DecodeError::BadField { field: "r/b" }),
            };
            if r as usize != config::INPUT_RANGE_BINS || b as usize != config::INPUT_COLUMNS {
                return Err(DecodeError::WrongGeometry { r, b });
            }
            expect(FRAME_PAYLOAD_LEN)
        }
        kind::DEPTH => {
            need(h.reference.is_some(), "ref")?;
            need(h.instr.is_some(), "instr")?;
            need(h.src.as_ref().is_some_and(|s| !s.is_empty()), "src")?;
            expect(DEPTH_PAYLOAD_LEN)
        }
        kind::STATUS => {
            need(h.frames.is_some(), "frames")?;
            need(h.depths.is_some(), "depths")?;
            need(h.errors.is_some(), "errors")?;
            need(h.stack.is_some(), "stack")?;
            expect(0)
        }
        kind::ERROR => {
            need(h.code.is_some(), "code")?;
            expect(0)
        }
        kind::STATUS_REQUEST | kind::SHUTDOWN => expect(0),
        _ => Err(DecodeError::UnknownType),
    }
}

fn parse_header(json: &[u8]) -> Result<Header<'_>, DecodeError> {
    match serde_json_core::from_slice::<Header<'_>>(json) {
        Ok((h, n)) if n == json.len() => Ok(h),
        _ => Err(DecodeError::BadJson),
    }
}

/// The typed message of a checked header and its payload.
fn build<'a>(h: Header<'a>, payload: &'a [u8]) -> Message<'a> {
    let seq = h.seq;
    match h.t {
        kind::FRAME => Message::Frame {
            seq,
            roll_deg: h.roll.unwrap_or(0.0),
            image: payload,
        },
        kind::DEPTH => Message::Depth {
            seq,
            reference: h.reference.unwrap_or(0),
            sources: h.src.unwrap_or_default(),
            instructions: h.instr.unwrap_or(0),
            depth: DepthData::Bytes(payload),
        },
        kind::STATUS => Message::Status {
            seq,
            status: Status {
                frames: h.frames.unwrap_or(0),
                depth_maps: h.depths.unwrap_or(0),
                errors: h.errors.unwrap_or(0),
                stack_high_water: h.stack.unwrap_or(0),
                cached: h.cached.unwrap_or(0),
            },
        },
        kind::ERROR => Message::Error {
            seq,
            code: h.code.unwrap_or(0),
            msg: h.msg.unwrap_or(""),
        },
        kind::SHUTDOWN => Message::Shutdown { seq },
        // check_header admitted only known types; a status request is the remaining one.
        _ => Message::StatusRequest { seq },
    }
}

/// A streaming decoder: [`Decoder::push`] bytes as they arrive, then call [`Decoder::poll`]
/// until it returns `None`. After any error it rescans the bytes it holds from the one after
/// the rejected message's first sync byte, so a valid message hidden behind a corrupt length
/// is still found. Sequence numbers must increase strictly.
pub struct Decoder {
    buf: [u8; MAX_MESSAGE_LEN],
    fill: usize,
    /// Message length once the header has been checked.
    total: Option<usize>,
    /// `seq` of the checked header.
    seq: u32,
    /// Garbage bytes dropped since the last report.
    skipped: usize,
    /// Bytes of the message returned by the last `poll`, removed on the next call.
    consumed: usize,
    last_seq: Option<u32>,
    overflows: u32,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

enum Step {
    NeedMore,
    Error(DecodeError),
    Ready(usize),
}

impl Decoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_MESSAGE_LEN],
            fill: 0,
            total: None,
            seq: 0,
            skipped: 0,
            consumed: 0,
            last_seq: None,
            overflows: 0,
        }
    }

    /// Appends one received byte. Call [`Decoder::poll`] until `None` after each push; a
    /// byte pushed into a full buffer (only possible without polling) restarts the search.
    pub fn push(&mut self, byte: u8) {
        self.take_consumed();
        if self.fill == self.buf.len() {
            self.overflows = self.overflows.saturating_add(1);
            self.resync(1, true);
        }
        if let Some(slot) = self.buf.get_mut(self.fill) {
            *slot = byte;
            self.fill += 1;
        }
    }

    /// Times the buffer was full on a push (the caller did not poll).
    pub fn overflows(&self) -> u32 {
        self.overflows
    }

    /// `seq` of the last message accepted.
    pub fn last_seq(&self) -> Option<u32> {
        self.last_seq
    }

    /// Bytes held that are not yet a complete message.
    pub fn pending(&self) -> usize {
        self.fill - self.consumed
    }

    /// The next event from the bytes held: a message, an error, or `None` (more bytes
    /// needed).
    pub fn poll(&mut self) -> Option<Result<Message<'_>, DecodeError>> {
        self.take_consumed();
        match self.step() {
            Step::NeedMore => None,
            Step::Error(e) => Some(Err(e)),
            Step::Ready(total) => {
                self.consumed = total;
                let h = (self.buf[4] as usize) | ((self.buf[5] as usize) << 8);
                let json = self.buf.get(PREAMBLE_LEN..PREAMBLE_LEN + h)?;
                let payload = self.buf.get(PREAMBLE_LEN + h..total - CRC_LEN)?;
                // The header was checked when it completed; parsing again only borrows.
                Some(parse_header(json).map(|hdr| build(hdr, payload)))
            }
        }
    }

    /// The line went idle (the caller's timeout): abandons an incomplete message, so that a
    /// truncated message cannot hold back the ones behind it. Returns the error to report, if
    /// any; call [`Decoder::poll`] afterwards (the rescan may complete messages).
    pub fn idle(&mut self) -> Option<DecodeError> {
        self.take_consumed();
        if self.fill == 0 {
            return None;
        }
        if self.fill >= SYNC.len() && self.buf[..SYNC.len()] == SYNC {
            let have = self.fill;
            self.resync(1, false);
            return Some(DecodeError::Truncated { have });
        }
        // A partial sync pattern or garbage: drop it.
        self.skipped = self.skipped.saturating_add(self.fill);
        self.fill = 0;
        self.total = None;
        let skipped = core::mem::take(&mut self.skipped);
        Some(DecodeError::BadSync { skipped })
    }

    fn take_consumed(&mut self) {
        if self.consumed > 0 {
            let n = self.consumed.min(self.fill);
            self.buf.copy_within(n..self.fill, 0);
            self.fill -= n;
            self.consumed = 0;
            self.total = None;
        }
    }

    /// Drops at least `min` bytes: up to the next position that could start a sync pattern.
    fn resync(&mut self, min: usize, garbage: bool) {
        let min = min.min(self.fill);
        let mut i = min;
        while i < self.fill {
            let n = (self.fill - i).min(SYNC.len());
            if self.buf[i..i + n] == SYNC[..n] {
                break;
            }
            i += 1;
        }
        self.buf.copy_within(i..self.fill, 0);
        self.fill -= i;
        self.total = None;
        if garbage {
            self.skipped = self.skipped.saturating_add(i);
        }
    }

    fn step(&mut self) -> Step {
        loop {
            let n = self.fill.min(SYNC.len());
            if self.buf[..n] != SYNC[..n] {
                self.resync(1, true);
                continue;
            }
            if self.fill < SYNC.len() {
                return Step::NeedMore;
            }
            if self.skipped > 0 {
                let skipped = self.skipped;
                self.skipped = 0;
                return Step::Error(DecodeError::BadSync { skipped });
            }
            if self.fill < PREAMBLE_LEN {
                return Step::NeedMore;
            }
            let h = (self.buf[4] as usize) | ((self.buf[5] as usize) << 8);
            if h == 0 || h > MAX_HEADER_LEN {
                self.resync(1, false);
                return Step::Error(DecodeError::HeaderTooLong { len: h });
            }
            if self.fill < PREAMBLE_LEN + h {
                return Step::NeedMore;
            }
            let total = match self.total {
                Some(t) => t,
                None => {
                    let json = &self.buf[PREAMBLE_LEN..PREAMBLE_LEN + h];
                    let checked = parse_header(json).and_then(|hdr| {
                        let len = check_header(&hdr)?;
                        Ok((len, hdr.seq))
                    });
                    match checked {
                        Ok((len, seq)) => {
                            let t = PREAMBLE_LEN + h + len + CRC_LEN;
                            self.total = Some(t);
                            self.seq = seq;
                            t
                        }
                        Err(e) => {
                            self.resync(1, false);
                            return Step::Error(e);
                        }
                    }
                }
            };
            if self.fill < total {
                return Step::NeedMore;
            }
            let mut crc = Crc32::new();
            crc.update(&self.buf[PREAMBLE_LEN..total - CRC_LEN]);
            let computed = crc.finish();
            let w = &self.buf[total - CRC_LEN..total];
            let wire = u32::from_le_bytes([w[0], w[1], w[2], w[3]]);
            if wire != computed {
                self.resync(1, false);
                return Step::Error(DecodeError::BadCrc { wire, computed });
            }
            let seq = self.seq;
            if let Some(last) = self.last_seq {
                if seq <= last {
                    // A whole valid message: drop it, not just its first byte.
                    self.resync(total, false);
                    return Step::Error(DecodeError::OutOfOrder { last, seq });
                }
            }
            self.last_seq = Some(seq);
            return Step::Ready(total);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    fn wire(msg: &Message<'_>) -> Vec<u8> {
        let mut v = Vec::new();
        encode(msg, &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .unwrap();
        v
    }

    fn raw(h: &Header<'_>, payload: &[u8]) -> Vec<u8> {
        let mut v = Vec::new();
        encode_raw(h, Payload::Bytes(payload), &mut |b: &[u8]| {
            v.extend_from_slice(b);
            Ok::<(), ()>(())
        })
        .unwrap();
        v
    }

    /// Everything the decoder reports for `bytes`, as owned summaries.
    #[derive(Debug, PartialEq)]
    enum Ev {
        Msg(u32, &'static str, usize),
        Err(DecodeError),
    }

    fn feed(d: &mut Decoder, bytes: &[u8]) -> Vec<Ev> {
        let mut out = drain(d);
        for &b in bytes {
            d.push(b);
            out.extend(drain(d));
        }
        out
    }

    fn drain(d: &mut Decoder) -> Vec<Ev> {
        let mut out = Vec::new();
        {
            while let Some(e) = d.poll() {
                out.push(match e {
                    Ok(m) => {
                        let payload = match &m {
                            Message::Frame { image, .. } => image.len(),
                            Message::Depth { depth, .. } => depth.len(),
                            _ => 0,
                        };
                        Ev::Msg(m.seq(), m.kind(), payload)
                    }
                    Err(e) => Ev::Err(e),
                });
            }
        }
        out
    }

    fn image(seed: u8) -> Vec<u8> {
        (0..FRAME_PAYLOAD_LEN)
            .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
            .collect()
    }

    fn frame_header(seq: u32) -> Header<'static> {
        Header {
            t: kind::FRAME,
            seq,
            roll: Some(7.0),
            r: Some(config::INPUT_RANGE_BINS as u32),
            b: Some(config::INPUT_COLUMNS as u32),
            len: Some(FRAME_PAYLOAD_LEN as u32),
            ..Header::default()
        }
    }

    #[test]
    fn round_trip_every_type() {
        let img = image(3);
        let depth: Vec<U16F16> = (0..config::DEPTH_LEN)
            .map(|i| U16F16::from_bits(0x0002_0000 + i as u32 * 77))
            .collect();
        let mut srcs = heapless::Vec::new();
        srcs.push(11).unwrap();
        let msgs = [
            Message::Frame {
                seq: 1,
                roll_deg: -7.25,
                image: &img,
            },
            Message::Depth {
                seq: 2,
                reference: 10,
                sources: srcs,
                instructions: 123_456_789,
                depth: DepthData::Values(&depth),
            },
            Message::StatusRequest { seq: 3 },
            Message::Status {
                seq: 4,
                status: Status {
                    frames: 5,
                    depth_maps: 4,
                    errors: 3,
                    stack_high_water: 2048,
                    cached: 2,
                },
            },
            Message::Error {
                seq: 5,
                code: ErrorCode::BadCrc.code(),
                msg: "crc 1 != 2",
            },
            Message::Shutdown { seq: 6 },
        ];
        let mut d = Decoder::new();
        for m in &msgs {
            let w = wire(m);
            let mut got = Vec::new();
            for &b in &w {
                d.push(b);
                while let Some(e) = d.poll() {
                    let e = e.unwrap();
                    // Compare through the depth values: bytes received vs values sent.
                    match (&e, m) {
                        (
                            Message::Depth {
                                depth: DepthData::Bytes(_),
                                ..
                            },
                            Message::Depth { depth: sent, .. },
                        ) => {
                            let Message::Depth { depth: got_d, .. } = &e else {
                                unreachable!()
                            };
                            let mut a = std::vec![U16F16::ZERO; config::DEPTH_LEN];
                            assert!(got_d.copy_to(&mut a));
                            for (i, v) in a.iter().enumerate() {
                                assert_eq!(Some(*v), sent.get(i));
                            }
                            let (h1, _) = e.to_parts();
                            let (h2, _) = m.to_parts();
                            assert_eq!(h1, h2);
                        }
                        _ => assert_eq!(&e, m),
                    }
                    got.push(e.seq());
                }
            }
            assert_eq!(got, std::vec![m.seq()]);
            assert_eq!(d.pending(), 0);
        }
    }

    #[test]
    fn garbage_before_message_is_reported_then_message_decoded() {
        let mut bytes = std::vec![0x00, 0xA5, 0x11, 0xA5, 0x5A, b'E', 0x42];
        bytes.extend(wire(&Message::StatusRequest { seq: 1 }));
        let mut d = Decoder::new();
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Err(DecodeError::BadSync { skipped: 7 }),
                Ev::Msg(1, kind::STATUS_REQUEST, 0)
            ]
        );
    }

    #[test]
    fn header_length_zero_or_too_long() {
        for len in [0usize, MAX_HEADER_LEN + 1, 0xFFFF] {
            let mut bytes = SYNC.to_vec();
            bytes.extend((len as u16).to_le_bytes());
            bytes.extend(wire(&Message::StatusRequest { seq: 9 }));
            let mut d = Decoder::new();
            assert_eq!(
                feed(&mut d, &bytes),
                std::vec![
                    Ev::Err(DecodeError::HeaderTooLong { len }),
                    Ev::Msg(9, kind::STATUS_REQUEST, 0)
                ]
            );
        }
    }

    fn with_json(json: &[u8], payload: &[u8]) -> Vec<u8> {
        let mut v = SYNC.to_vec();
        v.extend((json.len() as u16).to_le_bytes());
        v.extend_from_slice(json);
        v.extend_from_slice(payload);
        let mut c = Crc32::new();
        c.update(json);
        c.update(payload);
        v.extend(c.finish().to_le_bytes());
        v
    }

    #[test]
    fn bad_json_and_missing_fields() {
        let cases: [(&[u8], DecodeError); 6] = [
            (b"{\"t\":\"frame\",", DecodeError::BadJson),
            (b"not json at all", DecodeError::BadJson),
            (b"{\"seq\":1}", DecodeError::BadJson),
            (b"{\"t\":\"status?\",\"seq\":1} x", DecodeError::BadJson),
            (
                b"{\"t\":\"frame\",\"seq\":1,\"r\":256,\"b\":64,\"len\":16384}",
                DecodeError::BadField { field: "roll" },
            ),
            (
                b"{\"t\":\"error\",\"seq\":1}",
                DecodeError::BadField { field: "code" },
            ),
        ];
        for (json, err) in cases {
            let mut bytes = with_json(json, &[]);
            bytes.extend(wire(&Message::Shutdown { seq: 2 }));
            let mut d = Decoder::new();
            let ev = feed(&mut d, &bytes);
            assert_eq!(ev.first(), Some(&Ev::Err(err)), "{:?}", json);
            assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::SHUTDOWN, 0)));
            assert!(ev[1..ev.len() - 1]
                .iter()
                .all(|e| matches!(e, Ev::Err(DecodeError::BadSync { .. }))));
        }
        assert_eq!(DecodeError::BadJson.code(), ErrorCode::BadJson);
    }

    #[test]
    fn bad_crc_then_resync() {
        let mut bytes = wire(&Message::StatusRequest { seq: 1 });
        let n = bytes.len();
        bytes[n - 1] ^= 0x01;
        bytes.extend(wire(&Message::StatusRequest { seq: 2 }));
        let mut d = Decoder::new();
        let ev = feed(&mut d, &bytes);
        assert!(matches!(ev[0], Ev::Err(DecodeError::BadCrc { .. })));
        assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::STATUS_REQUEST, 0)));
        // Corrupt payload of a frame: same.
        let img = image(1);
        let mut bytes = wire(&Message::Frame {
            seq: 3,
            roll_deg: 0.0,
            image: &img,
        });
        bytes[100] ^= 0x80;
        bytes.extend(wire(&Message::StatusRequest { seq: 4 }));
        let ev = feed(&mut d, &bytes);
        assert!(matches!(ev[0], Ev::Err(DecodeError::BadCrc { .. })));
        assert_eq!(ev.last(), Some(&Ev::Msg(4, kind::STATUS_REQUEST, 0)));
    }

    #[test]
    fn oversized_unknown_geometry_length() {
        let img = image(2);
        let mut big = frame_header(1);
        big.len = Some(MAX_PAYLOAD_LEN as u32 + 1);
        let mut geo = frame_header(1);
        geo.r = Some(512);
        geo.len = Some(512 * 64);
        let mut short = frame_header(1);
        short.len = Some(100);
        let unknown = Header {
            t: "reboot",
            seq: 1,
            ..Header::default()
        };
        let mut status_len = Header {
            t: kind::STATUS_REQUEST,
            seq: 1,
            ..Header::default()
        };
        status_len.len = Some(4);
        let cases = [
            (raw(&big, &[]), DecodeError::Oversized { len: 16385 }),
            (
                raw(&geo, &img),
                DecodeError::WrongGeometry { r: 512, b: 64 },
            ),
            (
                raw(&short, &img[..100]),
                DecodeError::BadLength {
                    len: 100,
                    expected: FRAME_PAYLOAD_LEN as u32,
                },
            ),
            (raw(&unknown, &[]), DecodeError::UnknownType),
            (
                raw(&status_len, &[1, 2, 3, 4]),
                DecodeError::BadLength {
                    len: 4,
                    expected: 0,
                },
            ),
        ];
        for (mut bytes, err) in cases {
            bytes.extend(wire(&Message::StatusRequest { seq: 2 }));
            let mut d = Decoder::new();
            let ev = feed(&mut d, &bytes);
            assert_eq!(ev[0], Ev::Err(err));
            assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::STATUS_REQUEST, 0)));
            assert!(ev.iter().filter(|e| matches!(e, Ev::Msg(..))).count() == 1);
        }
        assert_eq!(
            DecodeError::WrongGeometry { r: 1, b: 1 }.code(),
            ErrorCode::WrongGeometry
        );
    }

    #[test]
    fn out_of_order_is_rejected_and_does_not_advance() {
        let mut d = Decoder::new();
        let mut bytes = wire(&Message::StatusRequest { seq: 5 });
        bytes.extend(wire(&Message::StatusRequest { seq: 5 }));
        bytes.extend(wire(&Message::StatusRequest { seq: 3 }));
        bytes.extend(wire(&Message::StatusRequest { seq: 6 }));
        assert_eq!(
            feed(&mut d, &bytes),
            std::vec![
                Ev::Msg(5, kind::STATUS_REQUEST, 0),
                Ev::Err(DecodeError::OutOfOrder { last: 5, seq: 5 }),
                Ev::Err(DecodeError::OutOfOrder { last: 5, seq: 3 }),
                Ev::Msg(6, kind::STATUS_REQUEST, 0),
            ]
        );
        assert_eq!(d.last_seq(), Some(6));
    }

    #[test]
    fn message_hidden_behind_a_corrupt_length_is_found() {
        // A status request whose header length claims one byte too many swallows the next
        // message's first byte; the rescan must still find that message.
        let mut first = wire(&Message::StatusRequest { seq: 1 });
        let h = u16::from_le_bytes([first[4], first[5]]) + 1;
        first[4..6].copy_from_slice(&h.to_le_bytes());
        let mut bytes = first;
        bytes.extend(wire(&Message::StatusRequest { seq: 2 }));
        let mut d = Decoder::new();
        let ev = feed(&mut d, &bytes);
        assert!(matches!(ev[0], Ev::Err(_)));
        assert_eq!(ev.last(), Some(&Ev::Msg(2, kind::STATUS_REQUEST, 0)));
    }

    #[test]
    fn depth_data_access_is_bounded() {
        let bytes = [1u8, 0, 0, 0, 2, 0, 0];
        let d = DepthData::Bytes(&bytes);
        assert_eq!(d.len(), 1);
        assert_eq!(d.get(0), Some(U16F16::from_bits(1)));
        assert_eq!(d.get(1), None);
        assert_eq!(d.get(usize::MAX), None);
        let mut out = [U16F16::ZERO; 2];
        assert!(!d.copy_to(&mut out));
        let mut small = [0u8; 8];
        assert_eq!(
            encode_to_slice(&Message::Shutdown { seq: 1 }, &mut small),
            Err(EncodeError::Sink(SliceFull))
        );
    }

    #[test]
    fn error_text_is_cut_not_failed() {
        let t = error_text(&DecodeError::BadCrc {
            wire: 1,
            computed: 2,
        });
        assert_eq!(t.as_str(), "crc 00000001 != 00000002");
        struct Long;
        impl fmt::Display for Long {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                for _ in 0..100 {
                    f.write_str("ab")?;
                }
                Ok(())
            }
        }
        assert_eq!(error_text(&Long).len(), MAX_ERROR_TEXT);
        for c in ErrorCode::ALL {
            assert_eq!(ErrorCode::from_code(c.code()), Some(c));
        }
        assert_eq!(ErrorCode::from_code(0), None);
    }

    /// SplitMix64, for reproducible fuzzing without a dependency.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n.max(1) as u64) as usize
        }
    }

    #[test]
    fn fuzz_random_and_mutated_input_never_panics_and_resyncs() {
        let mut rng = Rng(0x5EED);
        let img = image(9);
        let mut d = Decoder::new();
        let mut seq = 0u32;
        for round in 0..400 {
            // A corrupted thing: random bytes, or a valid message with mutations.
            let mut junk: Vec<u8> = match rng.below(3) {
                0 => (0..rng.below(300)).map(|_| rng.next() as u8).collect(),
                _ => {
                    seq += 1;
                    let mut w = if rng.below(4) == 0 {
                        wire(&Message::Frame {
                            seq,
                            roll_deg: 14.0,
                            image: &img,
                        })
                    } else {
                        wire(&Message::Error {
                            seq,
                            code: 3,
                            msg: "x",
                        })
                    };
                    let header_end = PREAMBLE_LEN + (w[4] as usize | (w[5] as usize) << 8);
                    for _ in 0..1 + rng.below(4) {
                        // Mostly in the preamble and header, where it matters for framing.
                        let at = if rng.below(2) == 0 {
                            rng.below(header_end)
                        } else {
                            rng.below(w.len())
                        };
                        w[at] ^= 1 << rng.below(8);
                    }
                    if rng.below(4) == 0 {
                        w.truncate(rng.below(w.len()));
                    }
                    w
                }
            };
            // Then a valid message, which must come out (with a fresh, larger seq).
            seq += 1;
            let valid = wire(&Message::StatusRequest { seq });
            junk.extend_from_slice(&valid);
            let mut ev = feed(&mut d, &junk);
            // A truncated frame can swallow the valid message while it waits for its
            // payload: the line then goes idle, which abandons it and rescans.
            while let Some(e) = d.idle() {
                ev.push(Ev::Err(e));
                ev.extend(drain(&mut d));
            }
            // Bit flips break the CRC, so the valid message is the only one.
            assert_eq!(
                ev.last(),
                Some(&Ev::Msg(seq, kind::STATUS_REQUEST, 0)),
                "round {round}: {ev:?}"
            );
            assert_eq!(
                ev.iter().filter(|e| matches!(e, Ev::Msg(..))).count(),
                1,
                "round {round}"
            );
            assert_eq!(d.pending(), 0, "round {round}");
        }
        assert_eq!(d.overflows(), 0);
    }

    #[test]
    fn never_panics_on_pure_noise_and_survives_overflow() {
        let mut rng = Rng(42);
        let mut d = Decoder::new();
        for _ in 0..200_000 {
            // Biased towards sync bytes so that headers get parsed.
            let b = match rng.below(8) {
                0 => SYNC[rng.below(4)],
                _ => rng.next() as u8,
            };
            d.push(b);
            while let Some(e) = d.poll() {
                let _ = e.map(|m| m.seq());
            }
        }
        // Pushing without polling fills the buffer; the decoder restarts instead of failing.
        let mut d = Decoder::new();
        for b in SYNC
            .iter()
            .copied()
            .chain(core::iter::repeat_n(0x20, MAX_MESSAGE_LEN))
        {
            d.push(b);
        }
        assert!(d.overflows() > 0);
        let mut n = 0;
        while d.poll().is_some() {
            n += 1;
            assert!(n < 10_000);
        }
        for &b in &wire(&Message::StatusRequest { seq: 77 }) {
            d.push(b);
        }
        let mut last = None;
        while let Some(e) = d.poll() {
            last = Some(e.map(|m| m.seq()));
        }
        assert_eq!(last, Some(Ok(77)));
    }
}
