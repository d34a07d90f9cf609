//! The streaming decoder: bytes in, checked messages or [`DecodeError`]s out.

use core::fmt;

use crate::config;
use crate::crc32::Crc32;

use super::header::{ErrorCode, Header};
#[cfg(not(target_os = "none"))]
use super::message::pair_of;
use super::message::{DepthData, Held, Message, Serving, Status};
use super::{
    kind, CRC_LEN, DEPTH_PAYLOAD_LEN, FRAME_PAYLOAD_LEN, MAX_CHUNK_LEN, MAX_HEADER_LEN,
    MAX_MESSAGE_LEN, MAX_PAYLOAD_LEN, PREAMBLE_LEN, SYNC,
};
use crate::attitude::Attitude;
use crate::fault::{ResetCause, RECORD_LEN};

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
            // Optional (an older host sends none), but when present a unit quaternion.
            need(
                h.q()
                    .is_none_or(|q| q.and_then(Attitude::from_array).is_some()),
                "q",
            )?;
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
            check_pair_fields(h)?;
            expect(DEPTH_PAYLOAD_LEN)
        }
        kind::STATUS => {
            need(h.frames.is_some(), "frames")?;
            need(h.depths.is_some(), "depths")?;
            need(h.errors.is_some(), "errors")?;
            need(h.stack.is_some(), "stack")?;
            check_pair_fields(h)?;
            expect(0)
        }
        kind::ERROR => {
            need(h.code.is_some(), "code")?;
            expect(0)
        }
        #[cfg(feature = "fault-injection")]
        kind::INJECT => {
            need(h.code.is_some(), "code")?;
            expect(0)
        }
        kind::CHUNK => {
            need(h.off.is_some(), "off")?;
            need(h.crc.is_some(), "crc")?;
            if len as usize > MAX_PAYLOAD_LEN {
                Err(DecodeError::Oversized { len })
            } else if len == 0 || len as usize > MAX_CHUNK_LEN {
                Err(DecodeError::BadLength {
                    len,
                    expected: MAX_CHUNK_LEN as u32,
                })
            } else {
                Ok(len as usize)
            }
        }
        kind::UPLOAD => {
            need(h.slot.is_some(), "slot")?;
            let held = [h.id, h.ver, h.total, h.held].map(|f| f.is_some());
            // All four or none, and never more held than the image has.
            need(held.iter().all(|&p| p == held[0]), "id/ver/total/held")?;
            need(h.held <= h.total, "held")?;
            expect(0)
        }
        // A device's hello carries its fault record until the host acknowledges it.
        kind::HELLO if len as usize == RECORD_LEN => Ok(RECORD_LEN),
        kind::STATUS_REQUEST
        | kind::SHUTDOWN
        | kind::HELLO
        | kind::UPLOAD_REQUEST
        | kind::COMMIT => expect(0),
        _ => Err(DecodeError::UnknownType),
    }
}

/// The pair fields of a status or depth message (host side: the device refuses both kinds
/// and parses none of these fields, so its build skips the check).
#[cfg(not(target_os = "none"))]
fn check_pair_fields(h: &Header<'_>) -> Result<(), DecodeError> {
    pair_of(h)
        .map(|_| ())
        .map_err(|field| DecodeError::BadField { field })
}

#[cfg(target_os = "none")]
fn check_pair_fields(_: &Header<'_>) -> Result<(), DecodeError> {
    Ok(())
}

fn parse_header(json: &[u8]) -> Result<Header<'_>, DecodeError> {
    match serde_json_core::from_slice::<Header<'_>>(json) {
        Ok((h, n)) if n == json.len() => Ok(h),
        _ => Err(DecodeError::BadJson),
    }
}

fn status_of(h: &Header<'_>) -> Status {
    Status {
        frames: h.frames.unwrap_or(0),
        depth_maps: h.depths.unwrap_or(0),
        errors: h.errors.unwrap_or(0),
        stack_high_water: h.stack.unwrap_or(0),
        cached: h.cached.unwrap_or(0),
        // Checked by check_header (the device has none: it parses no pair fields).
        #[cfg(not(target_os = "none"))]
        pair: pair_of(h).ok().flatten(),
        #[cfg(target_os = "none")]
        pair: None,
        model: h.ver.map(|version| Serving {
            slot: h.slot,
            version,
        }),
    }
}

/// The typed message of a checked header and its payload.
fn build<'a>(h: Header<'a>, payload: &'a [u8]) -> Message<'a> {
    let seq = h.seq;
    match h.t {
        kind::FRAME => Message::Frame {
            seq,
            roll_deg: h.roll.unwrap_or(0.0),
            attitude: h.q().flatten().and_then(Attitude::from_array),
            image: payload,
        },
        kind::DEPTH => Message::Depth {
            seq,
            #[cfg(not(target_os = "none"))]
            pair: pair_of(&h).ok().flatten(),
            #[cfg(target_os = "none")]
            pair: None,
            reference: h.reference.unwrap_or(0),
            sources: h.src.unwrap_or_default(),
            instructions: h.instr.unwrap_or(0),
            depth: DepthData::Bytes(payload),
        },
        kind::STATUS | kind::HELLO => {
            let status = status_of(&h);
            if h.t == kind::STATUS {
                Message::Status { seq, status }
            } else {
                // A hello carries counters (`frames` present) when it is the device's reply.
                Message::Hello {
                    seq,
                    status: h.frames.map(|_| status),
                    reset: h.reset.and_then(|c| ResetCause::from_code(c.into())),
                    record: (!payload.is_empty()).then_some(payload),
                    ack: h.ack,
                }
            }
        }
        kind::ERROR => Message::Error {
            seq,
            code: h.code.unwrap_or(0),
            msg: h.msg.unwrap_or(""),
        },
        kind::SHUTDOWN => Message::Shutdown { seq },
        kind::CHUNK => Message::Chunk {
            seq,
            offset: h.off.unwrap_or(0),
            crc: h.crc.unwrap_or(0),
            data: payload,
        },
        kind::UPLOAD_REQUEST => Message::UploadRequest { seq },
        kind::COMMIT => Message::Commit { seq },
        kind::UPLOAD => Message::Upload {
            seq,
            slot: h.slot.unwrap_or(0),
            held: match (h.id, h.ver, h.total, h.held) {
                (Some(id), Some(version), Some(total), Some(held)) => Some(Held {
                    id,
                    version,
                    total,
                    held,
                }),
                _ => None,
            },
        },
        #[cfg(feature = "fault-injection")]
        kind::INJECT => Message::Inject {
            seq,
            what: h.code.unwrap_or(0),
        },
        // check_header admitted only known types; a status request is the remaining one.
        _ => Message::StatusRequest { seq },
    }
}

/// A streaming decoder: [`Decoder::push`] bytes as they arrive, then call [`Decoder::poll`]
/// until it returns `None`. After any error it rescans the bytes it holds from the one after
/// the rejected message's first sync byte, so a valid message hidden behind a corrupt length
/// is still found. Sequence numbers must increase strictly, except that a `hello` is accepted
/// whatever its `seq` and restarts the sequence from it (a new session; see docs/LINK.md).
pub struct Decoder {
    buf: [u8; MAX_MESSAGE_LEN],
    fill: usize,
    /// Message length once the header has been checked.
    total: Option<usize>,
    /// `seq` of the checked header.
    seq: u32,
    /// The checked header is a `hello` (restarts the sequence).
    hello: bool,
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
            hello: false,
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

    /// Forgets the sequence state: the next message is accepted whatever its `seq`. For a
    /// host that starts a session itself (it sends `hello`); the device's decoder restarts on
    /// the `hello` it receives.
    pub fn restart(&mut self) {
        self.last_seq = None;
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
                        Ok((len, hdr.seq, hdr.t == kind::HELLO))
                    });
                    match checked {
                        Ok((len, seq, hello)) => {
                            let t = PREAMBLE_LEN + h + len + CRC_LEN;
                            self.total = Some(t);
                            self.seq = seq;
                            self.hello = hello;
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
            if let (Some(last), false) = (self.last_seq, self.hello) {
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
