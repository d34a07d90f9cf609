//! The fault generators of `host-sim sil`, against the device of `device.rs`.
//!
//! The fault campaign of `--faults N`: every fault class of docs/LINK.md sent to the firmware in
//! QEMU, `N` rounds per class from a fixed seed. Each fault is followed by a valid status
//! request. The expected replies come from an oracle: the library's own decoder
//! (`epssn::link::Decoder`, the one the firmware runs) fed the same bytes, with `idle()`
//! wherever the host leaves the line silent. A fault counts as answered when the device's reply
//! codes equal the oracle's, in order, and include the code that names the class; recovered
//! when the valid message after it was served.
//!
//! The fuzz run of `--fuzz N`: malformed messages of random kinds, each followed by a status
//! request that must be answered.

use std::collections::BTreeMap;

use anyhow::{bail, Result};
use epssn::config;
use epssn::link::ErrorCode::{
    BadCrc, BadJson, BadLength, BadSync, HeaderTooLong, OutOfOrder, Oversized, Truncated,
    Unexpected, UnknownType, WrongGeometry,
};
use epssn::link::{self, kind, DecodeError, Decoder, ErrorCode, Header, Message, Status};
use serde::Serialize;

use epssn_sim::synthetic::Rng;

use crate::device::{msg_bytes, raw_bytes, Device, Reply};

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
        (Expect::Status, Reply::Status(_)) | (Expect::Hello, Reply::Hello(..)) => true,
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
        msg_bytes(&Message::hello(seq))
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

    /// `v` followed by a valid status request, as one chunk: the shape of most faults.
    fn then_status(&mut self, mut v: Vec<u8>, named: &'static [ErrorCode]) -> Fault {
        v.extend(self.status_request());
        Fault {
            chunks: vec![v],
            named,
        }
    }

    /// The fault of `class`, ending with a valid status request (or hello).
    fn fault(&mut self, class: &str) -> Fault {
        match class {
            "header_len_zero" => self.header_len(false),
            "header_len_oversized" => self.header_len(true),
            "sync_flip" => self.sync_flip(),
            "length_flip" => self.length_flip(),
            "dropped_bytes" => self.dropped_bytes(),
            "stall_mid_header" => self.stall_mid_header(),
            "wrong_len" => self.wrong_len(),
            "missing_fields" => self.missing_fields(),
            "nonfinite_roll" => self.nonfinite_roll(),
            "wrong_direction" => self.wrong_direction(),
            "old_seq" => self.old_seq(),
            "wrapped_seq" => self.wrapped_seq(),
            "disconnect_mid_frame" => self.disconnect_mid_frame(),
            "flood" => self.flood(),
            "bad_crc" => self.bad_crc(),
            "oversized" => self.oversized(),
            "wrong_geometry" => self.wrong_geometry(),
            "unknown_type" => self.unknown_type(),
            _ => self.random_bytes(),
        }
    }

    /// A header length of zero, or above the largest header.
    fn header_len(&mut self, oversized: bool) -> Fault {
        let h: u16 = if oversized {
            (link::MAX_HEADER_LEN + 1 + self.below(0xFFFF - link::MAX_HEADER_LEN - 1)) as u16
        } else {
            0
        };
        let mut v = link::SYNC.to_vec();
        v.extend(h.to_le_bytes());
        self.then_status(v, &[HeaderTooLong])
    }

    /// One bit of the sync word flipped.
    fn sync_flip(&mut self) -> Fault {
        let mut v = self.status_request();
        let at = self.below(link::SYNC.len());
        v[at] ^= 1 << self.below(8);
        self.then_status(v, &[BadSync])
    }

    /// One bit of the header length flipped.
    fn length_flip(&mut self) -> Fault {
        // The header length grows, shrinks or leaves 1..=192: too long, bad JSON, or a
        // wait for bytes that never come (truncated) — the oracle says which.
        let mut v = self.status_request();
        let at = 4 + self.below(2);
        v[at] ^= 1 << self.below(8);
        self.then_status(v, &[HeaderTooLong, BadJson, Truncated])
    }

    /// 1 to 8 bytes after the preamble lost.
    fn dropped_bytes(&mut self) -> Fault {
        let mut v = if self.below(2) == 0 {
            self.frame()
        } else {
            self.status_request()
        };
        let n = 1 + self.below(8);
        let at = link::PREAMBLE_LEN + self.below(v.len() - link::PREAMBLE_LEN - n);
        v.drain(at..at + n);
        self.then_status(v, &[BadJson, BadCrc, Truncated])
    }

    /// The line goes silent inside a header; the status request comes after the silence.
    fn stall_mid_header(&mut self) -> Fault {
        let mut v = self.status_request();
        let keep = link::PREAMBLE_LEN + 1 + self.below(v.len() - link::PREAMBLE_LEN - 5);
        v.truncate(keep);
        Fault {
            chunks: vec![v, self.status_request()],
            named: &[Truncated],
        }
    }

    /// A payload shorter than a frame's, or one on a status request.
    fn wrong_len(&mut self) -> Fault {
        let seq = self.next();
        let v = if self.below(2) == 0 {
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
        self.then_status(v, &[BadLength])
    }

    /// A frame without its roll, an error without its code, a status without its counters.
    fn missing_fields(&mut self) -> Fault {
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
        let v = Self::json(json.as_bytes(), payload);
        self.then_status(v, &[BadJson])
    }

    /// A frame whose roll is not a finite f32.
    fn nonfinite_roll(&mut self) -> Fault {
        let seq = self.next();
        let roll = ["NaN", "Infinity", "-inf", "1e39", "null"][self.below(5)];
        let json =
            format!(r#"{{"t":"frame","seq":{seq},"roll":{roll},"r":256,"b":64,"len":16384}}"#);
        let v = Self::json(json.as_bytes(), &self.image);
        self.then_status(v, &[BadJson])
    }

    /// A message only the device sends.
    fn wrong_direction(&mut self) -> Fault {
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
                reset: None,
                record: None,
                ack: None,
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
        let v = msg_bytes(&msg);
        self.then_status(v, &[Unexpected])
    }

    /// A request with the last seq again or one before it.
    fn old_seq(&mut self) -> Fault {
        let last = self.seq;
        let old = last.saturating_sub(self.below(3) as u32);
        let v = msg_bytes(&Message::StatusRequest { seq: old });
        self.then_status(v, &[OutOfOrder])
    }

    /// Seq up to `u32::MAX`, then a wrapped one.
    fn wrapped_seq(&mut self) -> Fault {
        // Up to u32::MAX, then a wrapped seq (refused), then a hello restarts.
        let mut v = msg_bytes(&Message::StatusRequest { seq: u32::MAX });
        v.extend(msg_bytes(&Message::StatusRequest { seq: 0 }));
        self.seq = u32::MAX;
        let h = self.hello(0);
        v.extend(h);
        self.then_status(v, &[OutOfOrder])
    }

    /// Half a frame, then a new session.
    fn disconnect_mid_frame(&mut self) -> Fault {
        // The host goes away halfway through a frame (the line goes silent); a host
        // that reconnects starts with hello.
        let mut v = self.frame();
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

    /// Eight requests back to back, one of them broken.
    fn flood(&mut self) -> Fault {
        // Requests (and a broken one) without waiting for replies.
        let mut v = Vec::new();
        let bad = self.below(8);
        for i in 0..8 {
            let mut m = self.status_request();
            if i == bad {
                let n = m.len();
                m[n - 1] ^= 0x55;
            }
            v.extend(m);
        }
        self.then_status(v, &[BadCrc])
    }

    /// One bit flipped after the preamble of a frame or a request.
    fn bad_crc(&mut self) -> Fault {
        let mut v = if self.below(4) == 0 {
            self.frame()
        } else {
            self.status_request()
        };
        let at = link::PREAMBLE_LEN + self.below(v.len() - link::PREAMBLE_LEN);
        v[at] ^= 1 << self.below(8);
        // A flip in the JSON can also break the header itself.
        self.then_status(v, &[BadCrc, BadJson, UnknownType, BadLength, Oversized])
    }

    /// A frame header announcing more than the largest payload.
    fn oversized(&mut self) -> Fault {
        let seq = self.next();
        let mut h = self.frame_header(seq);
        h.len = Some(link::MAX_PAYLOAD_LEN as u32 + 1 + self.below(1000) as u32);
        let v = raw_bytes(&h, &[]);
        self.then_status(v, &[Oversized])
    }

    /// A frame header with twice the range bins.
    fn wrong_geometry(&mut self) -> Fault {
        let seq = self.next();
        let mut h = self.frame_header(seq);
        h.r = Some(2 * config::INPUT_RANGE_BINS as u32);
        let v = raw_bytes(&h, &[]);
        self.then_status(v, &[WrongGeometry])
    }

    /// A message type the protocol does not have.
    fn unknown_type(&mut self) -> Fault {
        let seq = self.next();
        let v = raw_bytes(
            &Header {
                t: "reboot",
                seq,
                ..Header::default()
            },
            &[],
        );
        self.then_status(v, &[UnknownType])
    }

    /// 1 to 200 random bytes.
    fn random_bytes(&mut self) -> Fault {
        let n = 1 + self.below(200);
        let v = (0..n).map(|_| self.rng.next_u64() as u8).collect();
        self.then_status(v, &[BadSync, HeaderTooLong, BadJson, BadCrc, Truncated])
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
            let x = c.exchange(&fault)?;
            report.messages += x.messages;
            let ok = x.score(&fault, entry);
            report.error_replies += x
                .replies
                .iter()
                .filter(|r| matches!(r, Reply::Error { .. }))
                .count();
            report.faults += 1;
            report.failed += usize::from(!ok);
            if c.oracle.pending() > 0 {
                bail!("fault campaign: the oracle holds bytes after {class}");
            }
        }
    }
    let hello = c.hello(0);
    report.stack_high_water_after = start(&mut c, &hello)?;
    report.messages += 1;
    Ok((report, c.seq))
}

/// One fault's traffic: what the oracle predicted and what came back.
struct Exchange {
    replies: Vec<Reply>,
    expected: Vec<Expect>,
    /// Why the replies stopped short (the device went silent or the link closed).
    lost: Option<String>,
    /// Messages the fault counts as: one per predicted reply.
    messages: usize,
}

impl Campaign<'_> {
    /// Sends the fault's chunks one after another, each followed by as many replies as the
    /// oracle predicts for it; stops at the first reply that does not come, so that a device
    /// that went silent is reported, not waited on chunk after chunk.
    fn exchange(&mut self, fault: &Fault) -> Result<Exchange> {
        let mut x = Exchange {
            replies: Vec::new(),
            expected: Vec::new(),
            lost: None,
            messages: 0,
        };
        for chunk in &fault.chunks {
            let want = predict(&mut self.oracle, chunk);
            x.messages += want.len();
            self.device.send(chunk)?;
            for _ in 0..want.len() {
                match self.device.reply() {
                    Ok(r) => x.replies.push(r),
                    Err(e) => {
                        x.lost = Some(e.to_string());
                        break;
                    }
                }
            }
            x.expected.extend(want);
            if x.lost.is_some() {
                break;
            }
        }
        Ok(x)
    }
}

impl Exchange {
    /// Counts the fault in its class's row; true when it was answered as the oracle said,
    /// with a code naming the class, and the valid message after it was served.
    fn score(&self, fault: &Fault, entry: &mut ClassReport) -> bool {
        let (replies, expected) = (&self.replies, &self.expected);
        let same = replies.len() == expected.len()
            && expected.iter().zip(replies).all(|(&e, r)| matches(e, r));
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
                self.lost
                    .as_ref()
                    .map(|l| format!(" (lost: {l})"))
                    .unwrap_or_default()
            ));
        }
        same && named && recovered
    }
}

/// Sends a hello, returns the stack high-water mark of the device's hello reply.
fn start(c: &mut Campaign<'_>, hello: &[u8]) -> Result<u32> {
    let want = predict(&mut c.oracle, hello);
    c.device.send(hello)?;
    let mut stack = 0;
    for _ in 0..want.len() {
        match c.device.reply()? {
            Reply::Hello(s, ..) => stack = s.stack_high_water,
            other => bail!("hello: unexpected reply {other:?}"),
        }
    }
    Ok(stack)
}

/// A reply as the failure lines show it: the error code's name, or the reply's kind.
fn short(r: &Reply) -> String {
    match r {
        Reply::Error { code, .. } => code_name(*code),
        Reply::Status(_) => "Status".into(),
        Reply::Hello(..) => "Hello".into(),
        Reply::Depth { .. } => "Depth".into(),
        other => format!("{other:?}"),
    }
}

/// Counts of a fuzz run.
#[derive(Serialize, Debug, Clone, Default, PartialEq)]
pub struct FuzzReport {
    /// Malformed messages sent, per kind.
    pub sent: BTreeMap<String, usize>,
    /// Error replies received, per error code name.
    pub error_replies: BTreeMap<String, usize>,
    /// Status requests sent between the malformed messages.
    pub status_requests: usize,
    /// Status replies received to them.
    pub status_replies: usize,
    /// Malformed messages that got no error reply before the next status reply.
    pub unanswered: usize,
}

/// One malformed message of a random kind; `seq` is the next valid sequence number and
/// `last` the last one the device accepted.
fn malformed(rng: &mut Rng, seq: &mut u32, last: u32, image: &[u8]) -> (&'static str, Vec<u8>) {
    let frame_header = |seq: u32| Header {
        t: kind::FRAME,
        seq,
        roll: Some(7.0),
        r: Some(config::INPUT_RANGE_BINS as u32),
        b: Some(config::INPUT_COLUMNS as u32),
        len: Some(image.len() as u32),
        ..Header::default()
    };
    let pick = (rng.next_u64() % 8) as usize;
    *seq += 1;
    let s = *seq;
    match pick {
        0 => {
            let n = 1 + (rng.next_u64() % 200) as usize;
            (
                "random_bytes",
                (0..n).map(|_| rng.next_u64() as u8).collect(),
            )
        }
        1 => {
            let full = if rng.next_u64() & 1 == 0 {
                raw_bytes(&frame_header(s), image)
            } else {
                msg_bytes(&Message::StatusRequest { seq: s })
            };
            let n = 1 + (rng.next_u64() as usize) % (full.len() - 1);
            ("truncated", full[..n].to_vec())
        }
        2 => {
            let mut v = if rng.next_u64() & 3 == 0 {
                raw_bytes(&frame_header(s), image)
            } else {
                msg_bytes(&Message::StatusRequest { seq: s })
            };
            let at =
                link::PREAMBLE_LEN + (rng.next_u64() as usize) % (v.len() - link::PREAMBLE_LEN);
            v[at] ^= 1 << (rng.next_u64() % 8);
            ("bad_crc", v)
        }
        3 => {
            let json = br#"{"t":"frame","seq":}"#;
            let mut v = link::SYNC.to_vec();
            v.extend((json.len() as u16).to_le_bytes());
            v.extend_from_slice(json);
            let crc = epssn::crc32::crc32(json);
            v.extend(crc.to_le_bytes());
            ("bad_json", v)
        }
        4 => {
            let mut h = frame_header(s);
            h.len = Some(link::MAX_PAYLOAD_LEN as u32 + 1 + (rng.next_u64() % 1000) as u32);
            ("oversized", raw_bytes(&h, &[]))
        }
        5 => {
            *seq -= 1;
            (
                "out_of_order",
                msg_bytes(&Message::StatusRequest { seq: last }),
            )
        }
        6 => {
            let mut h = frame_header(s);
            h.r = Some(2 * config::INPUT_RANGE_BINS as u32);
            ("wrong_geometry", raw_bytes(&h, &[]))
        }
        _ => {
            let mut h = raw_header_unknown(s);
            h.len = None;
            ("unknown_type", raw_bytes(&h, &[]))
        }
    }
}

/// A header of a message type the protocol does not have.
fn raw_header_unknown(seq: u32) -> Header<'static> {
    Header {
        t: "reboot",
        seq,
        ..Header::default()
    }
}

/// An error code's name (`code N` for one the library does not know).
fn code_name(code: u16) -> String {
    ErrorCode::from_code(code).map_or_else(|| format!("code {code}"), |c| format!("{c:?}"))
}

/// The fuzz run: `n` malformed messages from `seed`, each followed by a status request whose
/// reply must come (error replies before it are counted per code).
pub(crate) fn fuzz(
    device: &mut Device,
    n: usize,
    seed: u64,
    seq: &mut u32,
    image: &[u8],
) -> Result<FuzzReport> {
    let mut rng = Rng(seed);
    let mut report = FuzzReport::default();
    for _ in 0..n {
        let last = *seq;
        let (what, bytes) = malformed(&mut rng, seq, last, image);
        *report.sent.entry(what.to_string()).or_default() += 1;
        device.send(&bytes)?;
        *seq += 1;
        device.send_msg(&Message::StatusRequest { seq: *seq })?;
        report.status_requests += 1;
        let mut errors = 0;
        loop {
            match device.reply()? {
                Reply::Status(_) => {
                    report.status_replies += 1;
                    break;
                }
                Reply::Error { code, .. } => {
                    errors += 1;
                    *report.error_replies.entry(code_name(code)).or_default() += 1;
                }
                other => bail!("fuzz: unexpected reply {other:?}"),
            }
        }
        if errors == 0 {
            report.unanswered += 1;
        }
    }
    Ok(report)
}
