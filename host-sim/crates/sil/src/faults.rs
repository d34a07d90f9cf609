//! The fault campaign of `host-sim sil --faults N`: every fault class of issue 14 sent to the
//! firmware in QEMU, `N` rounds per class from a fixed seed. Each fault is followed by a valid
//! status request. The expected replies come from an oracle: the library's own decoder
//! (`epssn::link::Decoder`, the one the firmware runs) fed the same bytes, with `idle()`
//! wherever the host leaves the line silent. A fault counts as answered when the device's reply
//! codes equal the oracle's, in order, and include the code that names the class; recovered
//! when the valid message after it was served.

use std::collections::BTreeMap;

use anyhow::Result;
use epssn::config;
use epssn::link::{self, kind, DecodeError, Decoder, ErrorCode, Header, Message, Status};
use serde::Serialize;

use epssn_sim::synthetic::Rng;

use crate::sil::{msg_bytes, raw_bytes, Device, Reply};

/// One fault class's counts.
#[derive(Serialize, Debug, Clone, Default, PartialEq)]
pub struct ClassReport {
    /// Faults sent.
    pub sent: usize,
    /// The error code(s) that name the class (one of them must come back).
    pub expected_code: Vec<String>,
    /// Faults answered with exactly the oracle's replies, including a naming code.
    pub answered_expected: usize,
    /// Faults after which the following valid message was served.
    pub recovered: usize,
    /// What went wrong (at most 5 per class).
    pub failures: Vec<String>,
}

/// The campaign's result.
#[derive(Serialize, Debug, Clone, Default, PartialEq)]
pub struct FaultReport {
    /// Seed of the campaign.
    pub seed: u64,
    /// Rounds per class.
    pub rounds: usize,
    /// Per class.
    pub classes: BTreeMap<String, ClassReport>,
    /// Faults sent in all.
    pub faults: usize,
    /// Messages sent in all, valid and faulty: one per reply the oracle predicts (a fault's
    /// garbage, the status request after it, the hellos).
    pub messages: usize,
    /// Faults not answered as expected or not recovered from.
    pub failed: usize,
    /// Error replies received during the campaign.
    pub error_replies: usize,
    /// Stack high-water mark before and after the campaign (from the hello replies).
    pub stack_high_water_before: u32,
    /// After.
    pub stack_high_water_after: u32,
}

impl FaultReport {
    /// Adds `other`'s counts (a later block of a soak) to these; the stack high-water before
    /// stays this report's, the one after becomes `other`'s.
    pub fn merge(&mut self, other: FaultReport) {
        for (class, c) in other.classes {
            let e = self.classes.entry(class).or_default();
            e.sent += c.sent;
            e.expected_code = c.expected_code;
            e.answered_expected += c.answered_expected;
            e.recovered += c.recovered;
            let room = 5usize.saturating_sub(e.failures.len());
            e.failures.extend(c.failures.into_iter().take(room));
        }
        self.rounds += other.rounds;
        self.faults += other.faults;
        self.messages += other.messages;
        self.failed += other.failed;
        self.error_replies += other.error_replies;
        self.stack_high_water_after = other.stack_high_water_after;
    }
}

/// A reply the oracle predicts.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Expect {
    Code(u16),
    Status,
    Hello,
    /// A valid frame: a depth map or a status, depending on the cache.
    Frame,
}

fn expect_of(ev: Result<Message<'_>, DecodeError>) -> Expect {
    match ev {
        Err(e) => Expect::Code(e.code().code()),
        Ok(Message::StatusRequest { .. }) => Expect::Status,
        Ok(Message::Hello { status: None, .. }) => Expect::Hello,
        Ok(Message::Frame { .. }) => Expect::Frame,
        Ok(_) => Expect::Code(ErrorCode::Unexpected.code()),
    }
}

/// Feeds `bytes` to the oracle and lets the line go idle, as the device will.
fn predict(oracle: &mut Decoder, bytes: &[u8]) -> Vec<Expect> {
    let mut out = Vec::new();
    for &b in bytes {
        oracle.push(b);
        while let Some(ev) = oracle.poll() {
            out.push(expect_of(ev));
        }
    }
    while oracle.pending() > 0 {
        if let Some(e) = oracle.idle() {
            out.push(Expect::Code(e.code().code()));
        }
        while let Some(ev) = oracle.poll() {
            out.push(expect_of(ev));
        }
    }
    out
}

fn matches(e: Expect, r: &Reply) -> bool {
    match (e, r) {
        (Expect::Code(c), Reply::Error { code, .. }) => c == *code,
        (Expect::Status, Reply::Status(_)) | (Expect::Hello, Reply::Hello(_)) => true,
        (Expect::Frame, Reply::Status(_) | Reply::Depth { .. }) => true,
        _ => false,
    }
}

fn name(c: ErrorCode) -> String {
    format!("{c:?}")
}

/// The host's side of the campaign: sequence numbers, the oracle, the device.
struct Campaign<'d> {
    device: &'d mut Device,
    oracle: Box<Decoder>,
    seq: u32,
    rng: Rng,
    image: Vec<u8>,
}

/// One fault: chunks sent one after another, each followed by line silence; `named` the codes
/// that name the class. The last chunk ends with a valid message whose reply is `recovery`.
struct Fault {
    chunks: Vec<Vec<u8>>,
    named: &'static [ErrorCode],
}

impl Campaign<'_> {
    fn next(&mut self) -> u32 {
        self.seq = self.seq.wrapping_add(1);
        self.seq
    }

    fn status_request(&mut self) -> Vec<u8> {
        let seq = self.next();
        msg_bytes(&Message::StatusRequest { seq })
    }

    fn hello(&mut self, seq: u32) -> Vec<u8> {
        self.seq = seq;
        msg_bytes(&Message::Hello { seq, status: None })
    }

    fn below(&mut self, n: usize) -> usize {
        (self.rng.next_u64() % n.max(1) as u64) as usize
    }

    fn frame_header(&self, seq: u32) -> Header<'static> {
        Header {
            t: kind::FRAME,
            seq,
            roll: Some(7.0),
            r: Some(config::INPUT_RANGE_BINS as u32),
            b: Some(config::INPUT_COLUMNS as u32),
            len: Some(link::FRAME_PAYLOAD_LEN as u32),
            ..Header::default()
        }
    }

    fn frame(&mut self) -> Vec<u8> {
        let seq = self.next();
        raw_bytes(&self.frame_header(seq), &self.image)
    }

    fn json(json: &[u8], payload: &[u8]) -> Vec<u8> {
        let mut v = link::SYNC.to_vec();
        v.extend((json.len() as u16).to_le_bytes());
        v.extend_from_slice(json);
        v.extend_from_slice(payload);
        let mut c = epssn::crc32::Crc32::new();
        c.update(json);
        c.update(payload);
        v.extend(c.finish().to_le_bytes());
        v
    }

    /// The fault of `class`, ending with a valid status request (or hello).
    fn fault(&mut self, class: &str) -> Fault {
        use ErrorCode::*;
        let one = |bytes: Vec<u8>, named| Fault {
            chunks: vec![bytes],
            named,
        };
        let mut v: Vec<u8>;
        match class {
            "header_len_zero" | "header_len_oversized" => {
                let h: u16 = if class == "header_len_zero" {
                    0
                } else {
                    (link::MAX_HEADER_LEN + 1 + self.below(0xFFFF - link::MAX_HEADER_LEN - 1))
                        as u16
                };
                v = link::SYNC.to_vec();
                v.extend(h.to_le_bytes());
                v.extend(self.status_request());
                one(v, &[HeaderTooLong])
            }
            "sync_flip" => {
                v = self.status_request();
                let at = self.below(link::SYNC.len());
                v[at] ^= 1 << self.below(8);
                v.extend(self.status_request());
                one(v, &[BadSync])
            }
            "length_flip" => {
                // The header length grows, shrinks or leaves 1..=192: too long, bad JSON, or a
                // wait for bytes that never come (truncated) — the oracle says which.
                v = self.status_request();
                let at = 4 + self.below(2);
                v[at] ^= 1 << self.below(8);
                v.extend(self.status_request());
                one(v, &[HeaderTooLong, BadJson, Truncated])
            }
            "dropped_bytes" => {
                v = if self.below(2) == 0 {
                    self.frame()
                } else {
                    self.status_request()
                };
                let n = 1 + self.below(8);
                let at = link::PREAMBLE_LEN + self.below(v.len() - link::PREAMBLE_LEN - n);
                v.drain(at..at + n);
                v.extend(self.status_request());
                one(v, &[BadJson, BadCrc, Truncated])
            }
            "stall_mid_header" => {
                v = self.status_request();
                let keep = link::PREAMBLE_LEN + 1 + self.below(v.len() - link::PREAMBLE_LEN - 5);
                v.truncate(keep);
                Fault {
                    chunks: vec![v, self.status_request()],
                    named: &[Truncated],
                }
            }
            "wrong_len" => {
                let seq = self.next();
                v = if self.below(2) == 0 {
                    let mut h = self.frame_header(seq);
                    h.len = Some(1 + self.below(link::FRAME_PAYLOAD_LEN - 1) as u32);
                    let n = h.len.unwrap_or(0) as usize;
                    raw_bytes(&h, &self.image[..n])
                } else {
                    let h = Header {
                        t: kind::STATUS_REQUEST,
                        seq,
                        len: Some(4),
                        ..Header::default()
                    };
                    raw_bytes(&h, &[1, 2, 3, 4])
                };
                v.extend(self.status_request());
                one(v, &[BadLength])
            }
            "missing_fields" => {
                let seq = self.next();
                let json = match self.below(3) {
                    0 => format!(r#"{{"t":"frame","seq":{seq},"r":256,"b":64,"len":16384}}"#),
                    1 => format!(r#"{{"t":"error","seq":{seq},"msg":"x"}}"#),
                    _ => format!(r#"{{"t":"status","seq":{seq},"frames":1}}"#),
                };
                let payload: &[u8] = if json.contains("16384") {
                    &self.image
                } else {
                    &[]
                };
                v = Self::json(json.as_bytes(), payload);
                v.extend(self.status_request());
                one(v, &[BadJson])
            }
            "nonfinite_roll" => {
                let seq = self.next();
                let roll = ["NaN", "Infinity", "-inf", "1e39", "null"][self.below(5)];
                let json = format!(
                    r#"{{"t":"frame","seq":{seq},"roll":{roll},"r":256,"b":64,"len":16384}}"#
                );
                v = Self::json(json.as_bytes(), &self.image);
                v.extend(self.status_request());
                one(v, &[BadJson])
            }
            "wrong_direction" => {
                let seq = self.next();
                let depth = vec![0u8; link::DEPTH_PAYLOAD_LEN];
                let msg = match self.below(4) {
                    0 => Message::Status {
                        seq,
                        status: Status::default(),
                    },
                    1 => Message::Error {
                        seq,
                        code: 1,
                        msg: "x",
                    },
                    2 => Message::Hello {
                        seq,
                        status: Some(Status::default()),
                    },
                    _ => Message::Depth {
                        seq,
                        reference: 1,
                        sources: [1u32].into_iter().collect(),
                        instructions: 1,
                        depth: link::DepthData::Bytes(&depth),
                        pair: None,
                    },
                };
                v = msg_bytes(&msg);
                v.extend(self.status_request());
                one(v, &[Unexpected])
            }
            "old_seq" => {
                let last = self.seq;
                let old = last.saturating_sub(self.below(3) as u32);
                v = msg_bytes(&Message::StatusRequest { seq: old });
                v.extend(self.status_request());
                one(v, &[OutOfOrder])
            }
            "wrapped_seq" => {
                // Up to u32::MAX, then a wrapped seq (refused), then a hello restarts.
                v = msg_bytes(&Message::StatusRequest { seq: u32::MAX });
                v.extend(msg_bytes(&Message::StatusRequest { seq: 0 }));
                self.seq = u32::MAX;
                let h = self.hello(0);
                v.extend(h);
                v.extend(self.status_request());
                one(v, &[OutOfOrder])
            }
            "disconnect_mid_frame" => {
                // The host goes away halfway through a frame (the line goes silent); a host
                // that reconnects starts with hello.
                v = self.frame();
                v.truncate(link::PREAMBLE_LEN + 60 + self.below(v.len() / 2));
                let at = self.below(1000) as u32;
                let h = self.hello(at);
                let mut w = h;
                w.extend(self.status_request());
                Fault {
                    chunks: vec![v, w],
                    named: &[Truncated],
                }
            }
            "flood" => {
                // Requests (and a broken one) without waiting for replies.
                v = Vec::new();
                let bad = self.below(8);
                for i in 0..8 {
                    let mut m = self.status_request();
                    if i == bad {
                        let n = m.len();
                        m[n - 1] ^= 0x55;
                    }
                    v.extend(m);
                }
                v.extend(self.status_request());
                one(v, &[BadCrc])
            }
            "bad_crc" => {
                v = if self.below(4) == 0 {
                    self.frame()
                } else {
                    self.status_request()
                };
                let at = link::PREAMBLE_LEN + self.below(v.len() - link::PREAMBLE_LEN);
                v[at] ^= 1 << self.below(8);
                v.extend(self.status_request());
                // A flip in the JSON can also break the header itself.
                one(v, &[BadCrc, BadJson, UnknownType, BadLength, Oversized])
            }
            "oversized" => {
                let seq = self.next();
                let mut h = self.frame_header(seq);
                h.len = Some(link::MAX_PAYLOAD_LEN as u32 + 1 + self.below(1000) as u32);
                v = raw_bytes(&h, &[]);
                v.extend(self.status_request());
                one(v, &[Oversized])
            }
            "wrong_geometry" => {
                let seq = self.next();
                let mut h = self.frame_header(seq);
                h.r = Some(2 * config::INPUT_RANGE_BINS as u32);
                v = raw_bytes(&h, &[]);
                v.extend(self.status_request());
                one(v, &[WrongGeometry])
            }
            "unknown_type" => {
                let seq = self.next();
                v = raw_bytes(
                    &Header {
                        t: "reboot",
                        seq,
                        ..Header::default()
                    },
                    &[],
                );
                v.extend(self.status_request());
                one(v, &[UnknownType])
            }
            _ => {
                // random_bytes
                let n = 1 + self.below(200);
                v = (0..n).map(|_| self.rng.next_u64() as u8).collect();
                v.extend(self.status_request());
                one(v, &[BadSync, HeaderTooLong, BadJson, BadCrc, Truncated])
            }
        }
    }
}

/// Every class, in the order sent.
pub const CLASSES: [&str; 19] = [
    "header_len_zero",
    "header_len_oversized",
    "sync_flip",
    "length_flip",
    "dropped_bytes",
    "stall_mid_header",
    "wrong_len",
    "missing_fields",
    "nonfinite_roll",
    "wrong_direction",
    "old_seq",
    "wrapped_seq",
    "disconnect_mid_frame",
    "flood",
    "bad_crc",
    "oversized",
    "wrong_geometry",
    "unknown_type",
    "random_bytes",
];

/// Runs `rounds` faults of every class (round-robin) against `device`, starting a session with
/// hello; leaves the device in a session whose last `seq` is returned.
pub(crate) fn campaign(
    device: &mut Device,
    rounds: usize,
    seed: u64,
    image: &[u8],
) -> Result<(FaultReport, u32)> {
    let mut c = Campaign {
        device,
        oracle: Box::new(Decoder::new()),
        seq: 0,
        rng: Rng(seed),
        image: image.to_vec(),
    };
    let mut report = FaultReport {
        seed,
        rounds,
        ..FaultReport::default()
    };
    let hello = c.hello(0);
    report.stack_high_water_before = start(&mut c, &hello)?;
    report.messages += 1;
    for _ in 0..rounds {
        for class in CLASSES {
            let fault = c.fault(class);
            let entry = report.classes.entry(class.to_string()).or_default();
            entry.sent += 1;
            entry.expected_code = fault.named.iter().map(|&n| name(n)).collect();
            let mut replies = Vec::new();
            let mut expected = Vec::new();
            let mut lost = None;
            for chunk in &fault.chunks {
                let want = predict(&mut c.oracle, chunk);
                report.messages += want.len();
                c.device.send(chunk)?;
                for _ in 0..want.len() {
                    match c.device.reply() {
                        Ok(r) => replies.push(r),
                        Err(e) => {
                            lost = Some(e.to_string());
                            break;
                        }
                    }
                }
                expected.extend(want);
                if lost.is_some() {
                    break;
                }
            }
            let same = replies.len() == expected.len()
                && expected.iter().zip(&replies).all(|(&e, r)| matches(e, r));
            let named = replies.iter().any(|r| {
                matches!(r, Reply::Error { code, .. }
                    if fault.named.iter().any(|n| n.code() == *code))
            });
            let recovered = same
                && matches!(
                    (expected.last(), replies.last()),
                    (Some(Expect::Status), Some(Reply::Status(_)))
                );
            entry.answered_expected += usize::from(same && named);
            entry.recovered += usize::from(recovered);
            if !(same && named && recovered) && entry.failures.len() < 5 {
                entry.failures.push(format!(
                    "expected {expected:?}, got {:?}{}",
                    replies.iter().map(short).collect::<Vec<_>>(),
                    lost.map(|l| format!(" (lost: {l})")).unwrap_or_default()
                ));
            }
            report.error_replies += replies
                .iter()
                .filter(|r| matches!(r, Reply::Error { .. }))
                .count();
            report.faults += 1;
            report.failed += usize::from(!(same && named && recovered));
            if c.oracle.pending() > 0 {
                anyhow::bail!("fault campaign: the oracle holds bytes after {class}");
            }
        }
    }
    let hello = c.hello(0);
    report.stack_high_water_after = start(&mut c, &hello)?;
    report.messages += 1;
    Ok((report, c.seq))
}

/// Sends a hello, returns the stack high-water mark of the device's hello reply.
fn start(c: &mut Campaign<'_>, hello: &[u8]) -> Result<u32> {
    let want = predict(&mut c.oracle, hello);
    c.device.send(hello)?;
    let mut stack = 0;
    for _ in 0..want.len() {
        match c.device.reply()? {
            Reply::Hello(s) => stack = s.stack_high_water,
            other => anyhow::bail!("hello: unexpected reply {other:?}"),
        }
    }
    Ok(stack)
}

fn short(r: &Reply) -> String {
    match r {
        Reply::Error { code, .. } => {
            ErrorCode::from_code(*code).map_or_else(|| format!("code {code}"), |c| format!("{c:?}"))
        }
        Reply::Status(_) => "Status".into(),
        Reply::Hello(_) => "Hello".into(),
        Reply::Depth { .. } => "Depth".into(),
        other => format!("{other:?}"),
    }
}
