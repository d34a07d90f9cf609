//! The link server (`epssn::server`, what the firmware runs) on the host: a mock serial line
//! and a mock busy pin, link messages in, every reply checked; the depth map of a valid view
//! set bit for bit against the independent integer reference.

use std::cell::Cell;
use std::convert::Infallible;

use epssn::config;
use epssn::fault::{Record, ResetCause};
use epssn::link::{encode, DecodeError, Decoder, ErrorCode, Message, Status};
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use epssn::server::Server;
use epssn_tests::{synthetic_image, Rng};
use fixed::types::U16F16;

/// A read-side error of the mock line, as a UART reports them.
#[derive(Debug, Clone, Copy, PartialEq)]
enum LineError {
    Overrun,
    Noise,
}

impl std::fmt::Display for LineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line error: {self:?}")
    }
}

impl std::error::Error for LineError {}

impl embedded_io::Error for LineError {
    fn kind(&self) -> embedded_io::ErrorKind {
        // What embassy-stm32 reports for every USART error.
        embedded_io::ErrorKind::Other
    }
}

/// What the line does at one call of `read` (or, for `ReadyError`, of `read_ready`).
#[derive(Debug, Clone, Copy)]
enum Step {
    /// Up to this many of the queued bytes (a UART FIFO delivers a few at a time).
    Bytes(usize),
    /// `read` fails with an overrun that cost this many queued bytes.
    Error { lost: usize },
    /// `read` returns `Ok(0)`: an empty receive ring (a driver's blocking read may).
    Empty,
    /// `read_ready` fails (noise); the next step is `read`'s.
    ReadyError,
}

/// A serial line: reads what the test queued, following a script of steps (the last step
/// repeats once the script is done), records what the server writes.
struct MockSerial {
    rx: Vec<u8>,
    at: usize,
    tx: Vec<u8>,
    script: Vec<Step>,
    step: usize,
    /// Errors the line reported.
    errors: u32,
}

impl MockSerial {
    /// A clean line.
    fn new(rx: Vec<u8>) -> Self {
        Self::scripted(rx, vec![Step::Bytes(7)])
    }

    fn scripted(rx: Vec<u8>, script: Vec<Step>) -> Self {
        assert!(!script.is_empty());
        Self {
            rx,
            at: 0,
            tx: Vec::new(),
            script,
            step: 0,
            errors: 0,
        }
    }

    fn current(&self) -> Step {
        self.script[self.step.min(self.script.len() - 1)]
    }
}

impl embedded_io::ErrorType for MockSerial {
    type Error = LineError;
}

impl embedded_io::Read for MockSerial {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, LineError> {
        if buf.is_empty() {
            return Ok(0);
        }
        let step = self.current();
        self.step += 1;
        let left = self.rx.len() - self.at;
        match step {
            Step::Bytes(n) => {
                let n = buf.len().min(n).min(left);
                buf[..n].copy_from_slice(&self.rx[self.at..self.at + n]);
                self.at += n;
                Ok(n)
            }
            Step::Error { lost } => {
                self.at += lost.min(left);
                self.errors += 1;
                Err(LineError::Overrun)
            }
            Step::Empty | Step::ReadyError => Ok(0),
        }
    }
}

impl embedded_io::ReadReady for MockSerial {
    fn read_ready(&mut self) -> Result<bool, LineError> {
        if let Step::ReadyError = self.current() {
            self.step += 1;
            self.errors += 1;
            return Err(LineError::Noise);
        }
        Ok(self.at < self.rx.len())
    }
}

impl embedded_io::Write for MockSerial {
    fn write(&mut self, buf: &[u8]) -> Result<usize, LineError> {
        self.tx.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), LineError> {
        Ok(())
    }
}

/// The busy LED: counts how often it was lit and must end dark.
#[derive(Default)]
struct MockPin {
    high: bool,
    lit: usize,
}

impl embedded_hal::digital::ErrorType for MockPin {
    type Error = Infallible;
}

impl embedded_hal::digital::OutputPin for MockPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.high = false;
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.lit += usize::from(!self.high);
        self.high = true;
        Ok(())
    }
}

/// A reply, owned.
#[derive(Debug, PartialEq)]
enum Reply {
    Depth {
        reference: u32,
        sources: Vec<u32>,
        bits: Vec<u32>,
    },
    Status {
        frames: u32,
        depth_maps: u32,
        errors: u32,
    },
    Error(u16),
    /// A status reply carrying the pose gate's rejection.
    Rejected {
        reference: u32,
        source: u32,
        reason: &'static str,
        residual_deg: f32,
    },
    Hello {
        seq: u32,
        frames: u32,
        errors: u32,
        cached: u32,
    },
}

fn wire(msgs: &[Message<'_>]) -> Vec<u8> {
    let mut out = Vec::new();
    for m in msgs {
        encode(m, &mut |b: &[u8]| -> Result<(), Infallible> {
            out.extend_from_slice(b);
            Ok(())
        })
        .unwrap();
    }
    out
}

/// Calls `each` with every message decoded from the server's output, in order.
fn each_message(bytes: &[u8], mut each: impl FnMut(Result<Message<'_>, DecodeError>)) {
    let mut decoder = Decoder::new();
    for &b in bytes {
        decoder.push(b);
        while let Some(event) = decoder.poll() {
            each(event);
        }
    }
}

fn replies(bytes: &[u8]) -> Vec<Reply> {
    let mut out = Vec::new();
    each_message(bytes, |event| {
        out.push(match event.expect("the server's replies decode") {
            Message::Depth {
                reference,
                sources,
                depth,
                ..
            } => Reply::Depth {
                reference,
                sources: sources.to_vec(),
                bits: (0..depth.len())
                    .map(|i| depth.get(i).unwrap().to_bits())
                    .collect(),
            },
            Message::Status {
                status: Status { pair: Some(p), .. },
                ..
            } if !p.verdict.accepted() => Reply::Rejected {
                reference: p.reference,
                source: p.source,
                reason: p.verdict.reason(),
                residual_deg: p.residual_deg,
            },
            Message::Status { status, .. } => Reply::Status {
                frames: status.frames,
                depth_maps: status.depth_maps,
                errors: status.errors,
            },
            Message::Error { code, .. } => Reply::Error(code),
            Message::Hello {
                seq,
                status: Some(status),
                ..
            } => Reply::Hello {
                seq,
                frames: status.frames,
                errors: status.errors,
                cached: status.cached,
            },
            m => panic!("unexpected reply {m:?}"),
        });
    });
    out
}

/// The independent integer reference's depth map of `views` (U16F16 bits), what every depth
/// reply must equal.
fn reference_depth(blob: &[u8], views: &[&[u8]]) -> Vec<u32> {
    epssn_reference::reference_model::run(blob, views)
        .unwrap()
        .depth
}

fn blob() -> Vec<u8> {
    std::fs::read(epssn_reference::weights::firmware_blob_path().unwrap()).unwrap()
}

/// Serves `input` to the end (it must end with a shutdown) and returns the replies and the pin.
fn serve(blob: &[u8], input: Vec<u8>) -> (Vec<Reply>, MockPin) {
    let (replies, pin, line_errors) = serve_on(blob, MockSerial::new(input));
    assert_eq!(line_errors, 0);
    (replies, pin)
}

/// Serves what `serial` holds to the end (it must end with a shutdown) and returns the
/// replies, the pin and the line errors the server counted (checked against those the line
/// reported).
fn serve_on(blob: &[u8], mut serial: MockSerial) -> (Vec<Reply>, MockPin, u32) {
    let model = Model::from_blob(blob).unwrap();
    let mut ws = Box::new(Workspace::new());
    let mut cache = Box::new(FeatureCache::new());
    let mut depth = Box::new([U16F16::ZERO; config::DEPTH_LEN]);
    let mut decoder = Box::new(Decoder::new());
    let ticks = Cell::new(0u32);
    let now = || {
        ticks.set(ticks.get().wrapping_add(1));
        ticks.get()
    };
    let high_water = || 0;
    let mut server = Server::new(
        &model,
        &mut ws,
        &mut cache,
        &mut depth,
        &now,
        1,
        1_000_000,
        &high_water,
    );
    let mut pin = MockPin::default();
    server.serve(&mut serial, &mut pin, &mut decoder).unwrap();
    assert_eq!(serial.at, serial.rx.len(), "the server stopped early");
    assert_eq!(
        server.line_errors, serial.errors,
        "every line error counted"
    );
    (replies(&serial.tx), pin, server.line_errors)
}

#[test]
fn status_garbage_and_unexpected_messages_get_replies() {
    let mut input = wire(&[Message::StatusRequest { seq: 1 }]);
    // A message with a broken CRC.
    let mut bad = wire(&[Message::StatusRequest { seq: 2 }]);
    let last = bad.len() - 1;
    bad[last] ^= 0xff;
    input.extend(bad);
    // A message only the device sends.
    input.extend(wire(&[Message::Error {
        seq: 3,
        code: 1,
        msg: "x",
    }]));
    input.extend(wire(&[Message::Shutdown { seq: 4 }]));
    let (got, pin) = serve(&blob(), input);
    assert_eq!(got.len(), 4, "{got:?}");
    assert_eq!(
        got[0],
        Reply::Status {
            frames: 0,
            depth_maps: 0,
            errors: 0
        }
    );
    assert_eq!(got[1], Reply::Error(ErrorCode::BadCrc.code()));
    assert_eq!(got[2], Reply::Error(ErrorCode::Unexpected.code()));
    assert_eq!(
        got[3],
        Reply::Status {
            frames: 0,
            depth_maps: 0,
            errors: 2
        }
    );
    assert_eq!(pin.lit, 0);
}

#[test]
fn a_view_set_gets_the_integer_reference_depth_map_bit_for_bit() {
    let blob = blob();
    let mut rng = Rng(21);
    let reference = synthetic_image(&mut rng, 0.0);
    let source = synthetic_image(&mut rng, 0.4);
    let input = wire(&[
        Message::Frame {
            seq: 1,
            roll_deg: 0.0,
            attitude: None,
            image: &reference,
        },
        Message::Frame {
            seq: 2,
            roll_deg: config::ROLL_STEP_DEG as f32,
            attitude: None,
            image: &source,
        },
        Message::Shutdown { seq: 3 },
    ]);
    let (got, pin) = serve(&blob, input);
    let expected = reference_depth(&blob, &[&reference, &source]);
    assert_eq!(got.len(), 3, "{got:?}");
    assert_eq!(
        got[0],
        Reply::Status {
            frames: 1,
            depth_maps: 0,
            errors: 0
        }
    );
    assert_eq!(
        got[1],
        Reply::Depth {
            reference: 1,
            sources: vec![2],
            bits: expected,
        }
    );
    assert_eq!(
        got[2],
        Reply::Status {
            frames: 2,
            depth_maps: 1,
            errors: 0
        }
    );
    assert_eq!(pin.lit, 2, "the busy LED is lit once per frame");
    assert!(!pin.high, "and dark when idle");
}

fn status(frames: u32, depth_maps: u32, errors: u32) -> Reply {
    Reply::Status {
        frames,
        depth_maps,
        errors,
    }
}

fn frame(seq: u32, roll_deg: f32, image: &[u8]) -> Message<'_> {
    Message::Frame {
        seq,
        roll_deg,
        attitude: None,
        image,
    }
}

const HELLO: fn(u32) -> Message<'static> = |seq| Message::hello(seq);

#[test]
fn a_restarted_host_is_served_at_once_after_hello() {
    let blob = blob();
    let mut rng = Rng(22);
    let a = synthetic_image(&mut rng, 0.0);
    let b = synthetic_image(&mut rng, 0.4);
    let step = config::ROLL_STEP_DEG as f32;
    let input = wire(&[
        // The old session got as far as seq 10 with one frame cached.
        frame(10, 0.0, &a),
        // The host restarts: its old-style seqs are refused...
        Message::StatusRequest { seq: 1 },
        // ...until it says hello, which restarts the sequence at any seq and forgets the
        // old session's frames.
        HELLO(0),
        frame(1, step, &b),
        frame(2, 0.0, &a),
        Message::Shutdown { seq: 3 },
    ]);
    let (got, _) = serve(&blob, input);
    let expected = reference_depth(&blob, &[&a, &b]);
    assert_eq!(
        got,
        vec![
            status(1, 0, 0),
            Reply::Error(ErrorCode::OutOfOrder.code()),
            Reply::Hello {
                seq: 1,
                frames: 1,
                errors: 1,
                cached: 0
            },
            // Frame 1 does not pair with the forgotten frame 10 (same roll as frame 2).
            status(2, 0, 1),
            Reply::Depth {
                reference: 2,
                sources: vec![1],
                bits: expected,
            },
            status(3, 1, 1),
        ]
    );
}

#[test]
fn seq_u32_max_then_hello_restarts_the_sequence() {
    let input = wire(&[
        Message::StatusRequest { seq: u32::MAX },
        // Nothing is greater than u32::MAX: refused, as before hello existed...
        Message::StatusRequest { seq: 0 },
        Message::StatusRequest { seq: u32::MAX },
        // ...a hello restarts (the line may also go idle meanwhile: that changes nothing).
        HELLO(0),
        Message::StatusRequest { seq: 1 },
        HELLO(u32::MAX),
        HELLO(5),
        Message::Shutdown { seq: 6 },
    ]);
    let (got, _) = serve(&blob(), input);
    let hello = |seq, errors| Reply::Hello {
        seq,
        frames: 0,
        errors,
        cached: 0,
    };
    assert_eq!(
        got,
        vec![
            status(0, 0, 0),
            Reply::Error(ErrorCode::OutOfOrder.code()),
            Reply::Error(ErrorCode::OutOfOrder.code()),
            hello(1, 2),
            status(0, 0, 2),
            hello(1, 2),
            hello(1, 2),
            status(0, 0, 2),
        ]
    );
}

#[test]
fn hello_mid_stream_starts_a_new_session() {
    let blob = blob();
    let mut rng = Rng(23);
    let a = synthetic_image(&mut rng, 0.0);
    let b = synthetic_image(&mut rng, 0.4);
    let step = config::ROLL_STEP_DEG as f32;
    let input = wire(&[
        frame(1, 0.0, &a),
        // Sent without waiting, seq still increasing: a session restart all the same.
        HELLO(2),
        frame(3, step, &b),
        frame(4, 0.0, &a),
        Message::Shutdown { seq: 5 },
    ]);
    let (got, _) = serve(&blob, input);
    let expected = reference_depth(&blob, &[&a, &b]);
    assert_eq!(
        got,
        vec![
            status(1, 0, 0),
            Reply::Hello {
                seq: 1,
                frames: 1,
                errors: 0,
                cached: 0
            },
            status(2, 0, 0),
            Reply::Depth {
                reference: 4,
                sources: vec![3],
                bits: expected,
            },
            status(3, 1, 0),
        ]
    );
}

#[test]
fn a_hello_with_counters_sent_to_the_device_is_unexpected() {
    let input = wire(&[
        Message::Hello {
            seq: 1,
            status: Some(Default::default()),
            reset: None,
            record: None,
            ack: None,
        },
        Message::Shutdown { seq: 2 },
    ]);
    let (got, _) = serve(&blob(), input);
    assert_eq!(
        got,
        vec![Reply::Error(ErrorCode::Unexpected.code()), status(0, 0, 1)]
    );
}

#[test]
fn the_pose_gate_rejects_a_yawed_source_and_reports_why() {
    use epssn::attitude::Attitude;
    let blob = blob();
    let mut rng = Rng(5);
    let reference = synthetic_image(&mut rng, 0.0);
    let source = synthetic_image(&mut rng, 0.4);
    let step = config::ROLL_STEP_DEG as f32;
    let posed = |seq, roll: f32, yaw: f32, image| Message::Frame {
        seq,
        roll_deg: roll,
        attitude: Attitude::from_header_deg(yaw, 0.0, 0.0, 0.0, 0.0, roll),
        image,
    };
    let tol = config::PAIR_RESIDUAL_TOLERANCE_DEG as f32;
    let input = wire(&[
        posed(1, 0.0, 0.0, &reference[..]),
        // Yawed by twice the tolerance: refused, with its figures.
        posed(2, step, 2.0 * tol.min(1.0), &source[..]),
        // Within the tolerance: a depth map, the reference the same frame.
        posed(3, step, 0.5 * tol.min(1.0), &source[..]),
        Message::Shutdown { seq: 4 },
    ]);
    let (got, _) = serve(&blob, input);
    assert_eq!(got.len(), 4, "{got:?}");
    assert_eq!(got[0], status(1, 0, 0));
    match got[1] {
        Reply::Rejected {
            reference: 1,
            source: 2,
            reason: "residual",
            residual_deg,
        } => assert!((residual_deg - 2.0 * tol.min(1.0)).abs() < 1e-3),
        ref r => panic!("expected a rejection, got {r:?}"),
    }
    let expected = reference_depth(&blob, &[&reference, &source]);
    assert_eq!(
        got[2],
        Reply::Depth {
            reference: 1,
            sources: vec![3],
            bits: expected,
        }
    );
    assert_eq!(got[3], status(3, 1, 0));
}

/// A blob trained for three views makes the server wait for a third frame (+2 roll steps) and
/// answer with the three-view depth map, bit for bit the integer reference's.
#[test]
fn a_three_view_blob_pairs_three_frames() {
    let blob = epssn_tests::with_i32_tensor(&blob(), epssn::model::VIEWS_TENSOR, Some(3));
    assert_eq!(Model::from_blob(&blob).unwrap().views(), 3);
    let mut rng = Rng(31);
    let images: Vec<Vec<u8>> = (0..3)
        .map(|k| synthetic_image(&mut rng, 0.3 * k as f64))
        .collect();
    let mut msgs: Vec<Message<'_>> = images
        .iter()
        .enumerate()
        .map(|(k, image)| {
            frame(
                k as u32 + 1,
                (k as f64 * config::ROLL_STEP_DEG) as f32,
                image,
            )
        })
        .collect();
    msgs.push(Message::Shutdown { seq: 4 });
    let (got, _) = serve(&blob, wire(&msgs));
    let views: Vec<&[u8]> = images.iter().map(|v| v.as_slice()).collect();
    let expected = reference_depth(&blob, &views);
    assert_eq!(
        got,
        vec![
            status(1, 0, 0),
            status(2, 0, 0),
            Reply::Depth {
                reference: 1,
                sources: vec![2, 3],
                bits: expected,
            },
            status(3, 1, 0),
        ]
    );
}

/// Line errors and empty reads between bytes: no byte lost, so the replies are a clean line's
/// (the depth map bit for bit the integer reference's); every error counted; `Ok(0)` is not
/// the end of the stream.
#[test]
fn line_errors_and_empty_reads_between_bytes_are_served_through() {
    let blob = blob();
    let mut rng = Rng(41);
    let reference = synthetic_image(&mut rng, 0.0);
    let source = synthetic_image(&mut rng, 0.4);
    let input = wire(&[
        Message::StatusRequest { seq: 1 },
        frame(2, 0.0, &reference),
        frame(3, config::ROLL_STEP_DEG as f32, &source),
        Message::Shutdown { seq: 4 },
    ]);
    // Per 4 bytes: an overrun, two empty reads and a noisy `read_ready`, none losing a byte.
    let pattern = [
        Step::Bytes(1),
        Step::Error { lost: 0 },
        Step::Empty,
        Step::Bytes(3),
        Step::ReadyError,
        Step::Empty,
    ];
    let script: Vec<Step> = pattern
        .iter()
        .copied()
        .cycle()
        .take(6 * input.len())
        .collect();
    let (got, pin, line_errors) = serve_on(&blob, MockSerial::scripted(input.clone(), script));
    // Two errors per 4 bytes until the shutdown's last byte.
    let cycles = input.len().div_ceil(4) as u32;
    let (clean, _) = serve(&blob, input);
    let expected = reference_depth(&blob, &[&reference, &source]);
    assert_eq!(
        got,
        vec![
            status(0, 0, 0),
            status(1, 0, 0),
            Reply::Depth {
                reference: 2,
                sources: vec![3],
                bits: expected,
            },
            status(2, 1, 0),
        ]
    );
    assert_eq!(got, clean);
    assert!(
        (2 * cycles - 2..=2 * cycles - 1).contains(&line_errors),
        "{line_errors} line errors for {cycles} cycles"
    );
    assert_eq!(pin.lit, 2);
    assert!(!pin.high);
}

/// A line error that loses bytes inside a message: that message is answered with an error,
/// the decoder resynchronises and the ones behind it are served.
#[test]
fn a_line_error_that_loses_bytes_costs_only_its_message() {
    let first = wire(&[Message::StatusRequest { seq: 1 }]);
    let input = wire(&[
        Message::StatusRequest { seq: 1 },
        Message::StatusRequest { seq: 2 },
        Message::StatusRequest { seq: 3 },
        Message::Shutdown { seq: 4 },
    ]);
    // Message 2 loses three bytes of its header, its first ten bytes delivered.
    let script = vec![
        Step::Bytes(first.len() + 10),
        Step::Empty,
        Step::Error { lost: 3 },
        Step::Empty,
        Step::Bytes(5),
    ];
    let (got, _, line_errors) = serve_on(&blob(), MockSerial::scripted(input, script));
    assert_eq!(line_errors, 1);
    assert_eq!(
        got,
        vec![
            status(0, 0, 0),
            // The damaged header, then the rest of message 2 skipped up to message 3's sync.
            Reply::Error(ErrorCode::BadJson.code()),
            Reply::Error(ErrorCode::BadSync.code()),
            status(0, 0, 2),
            status(0, 0, 2),
        ]
    );
}

/// The hellos the server sends: (seq, reset cause, fault record) each.
fn hellos(bytes: &[u8]) -> Vec<(u32, Option<ResetCause>, Option<Record>)> {
    let mut out = Vec::new();
    each_message(bytes, |event| {
        if let Ok(Message::Hello {
            seq,
            status: Some(_),
            reset,
            record,
            ..
        }) = event
        {
            let record = record.map(|r| Record::from_bytes(r).expect("a valid record"));
            out.push((seq, reset, record));
        }
    });
    out
}

#[test]
fn hello_reports_the_reset_and_its_record_until_a_hello_acknowledges_it() {
    let blob = blob();
    let model = Model::from_blob(&blob).unwrap();
    let mut ws = Box::new(Workspace::new());
    let mut cache = Box::new(FeatureCache::new());
    let mut depth = Box::new([U16F16::ZERO; config::DEPTH_LEN]);
    let mut decoder = Box::new(Decoder::new());
    let now = || 0;
    let high_water = || 0;
    let mut server = Server::new(
        &model,
        &mut ws,
        &mut cache,
        &mut depth,
        &now,
        1,
        1_000_000,
        &high_water,
    );
    let record = Record::panic(&"index out of bounds", "src/x.rs", 7, 3);
    let cleared = Cell::new(0);
    let clear = || cleared.set(cleared.get() + 1);
    let feeds = Cell::new(0u32);
    let feed = || feeds.set(feeds.get() + 1);
    server.reset = ResetCause::Panic;
    server.fault = Some(record);
    server.clear_fault = &clear;
    server.feed = &feed;
    let ack = |seq, ack| Message::Hello {
        seq,
        status: None,
        reset: None,
        record: None,
        ack: Some(ack),
    };
    let input = wire(&[
        Message::hello(0),
        // A wrong id acknowledges nothing.
        ack(0, record.id() ^ 1),
        ack(0, record.id()),
        Message::hello(0),
        Message::Shutdown { seq: 1 },
    ]);
    let mut serial = MockSerial::new(input);
    server
        .serve(&mut serial, &mut MockPin::default(), &mut decoder)
        .unwrap();
    let with = (1, Some(ResetCause::Panic), Some(record));
    // The reply to the acknowledging hello no longer has it; the cause stays for the boot.
    let without = (1, Some(ResetCause::Panic), None);
    assert_eq!(hellos(&serial.tx), vec![with, with, without, without]);
    assert_eq!(cleared.get(), 1);
    assert_eq!(server.fault, None);
    // Fed once per pass of the loop: at least once per byte read.
    assert!(feeds.get() as usize >= serial.rx.len() / 64);
}

#[test]
fn a_hello_carrying_a_record_sent_to_the_device_is_unexpected() {
    let record = Record::new(ResetCause::Watchdog).to_bytes();
    let input = wire(&[
        Message::Hello {
            seq: 1,
            status: None,
            reset: None,
            record: Some(&record),
            ack: None,
        },
        Message::Shutdown { seq: 2 },
    ]);
    let (got, _) = serve(&blob(), input);
    assert_eq!(
        got,
        vec![Reply::Error(ErrorCode::Unexpected.code()), status(0, 0, 1)]
    );
}

/// A board's model updates, recorded: what the server hands it and what it answers.
#[derive(Default)]
struct MockUpdates {
    /// Offsets of the chunks taken.
    chunks: Vec<u32>,
    commits: u32,
    switches: u32,
    serving: epssn::link::Serving,
}

impl epssn::server::Updates for MockUpdates {
    fn serving(&self) -> epssn::link::Serving {
        self.serving
    }

    fn held(&self) -> (u8, Option<epssn::link::Held>) {
        let held = self.chunks.last().map(|&off| epssn::link::Held {
            id: 7,
            version: 2,
            total: 5000,
            held: off + 1024,
        });
        (1, held)
    }

    fn chunk(&mut self, offset: u32, data: &[u8], crc: u32) -> Result<(), epssn::server::Refusal> {
        if epssn::crc32::crc32(data) != crc {
            return Err(epssn::server::Refusal {
                code: ErrorCode::UploadCrc,
                text: epssn::link::error_text(&"chunk crc"),
            });
        }
        self.chunks.push(offset);
        Ok(())
    }

    fn commit(
        &mut self,
        _: &mut Workspace,
        _: &mut FeatureCache,
        _: &mut [U16F16; config::DEPTH_LEN],
    ) -> Result<epssn::link::Serving, epssn::server::Refusal> {
        self.commits += 1;
        self.serving = epssn::link::Serving {
            slot: Some(1),
            version: 2,
        };
        Ok(self.serving)
    }

    fn switch(&mut self) {
        self.switches += 1;
    }
}

#[test]
fn update_messages_go_to_the_boards_updates_and_hello_names_the_model() {
    let blob = blob();
    let model = Model::from_blob(&blob).unwrap();
    let mut ws = Box::new(Workspace::new());
    let mut cache = Box::new(FeatureCache::new());
    let mut depth = Box::new([U16F16::ZERO; config::DEPTH_LEN]);
    let mut decoder = Box::new(Decoder::new());
    let (now, high_water) = (|| 0, || 0);
    let mut updates = MockUpdates::default();
    let mut server = Server::new(
        &model,
        &mut ws,
        &mut cache,
        &mut depth,
        &now,
        1,
        1_000_000,
        &high_water,
    );
    server.updates = Some(&mut updates);
    let data = [5u8; 1024];
    let crc = epssn::crc32::crc32(&data);
    let chunk = |seq, crc| Message::Chunk {
        seq,
        offset: 0,
        crc,
        data: &data,
    };
    let input = wire(&[
        Message::hello(0),
        Message::UploadRequest { seq: 1 },
        chunk(2, crc ^ 1),
        chunk(3, crc),
        Message::Commit { seq: 4 },
        Message::hello(0),
        Message::Shutdown { seq: 1 },
    ]);
    let mut serial = MockSerial::new(input);
    server
        .serve(&mut serial, &mut MockPin::default(), &mut decoder)
        .unwrap();
    let mut got = Vec::new();
    each_message(&serial.tx, |m| {
        got.push(match m.unwrap() {
            Message::Hello {
                status: Some(s), ..
            } => format!("hello {:?}", s.model),
            Message::Upload { slot, held, .. } => {
                format!("upload {slot} {:?}", held.map(|h| h.held))
            }
            Message::Error { code, .. } => format!("error {code}"),
            Message::Status { status, .. } => format!("status {:?}", status.model),
            m => panic!("unexpected reply {m:?}"),
        });
    });
    let old = Some(epssn::link::Serving::default());
    let new = Some(epssn::link::Serving {
        slot: Some(1),
        version: 2,
    });
    assert_eq!(
        got,
        [
            format!("hello {old:?}"),
            "upload 1 None".into(),
            format!("error {}", ErrorCode::UploadCrc.code()),
            "upload 1 Some(1024)".into(),
            format!("status {new:?}"),
            format!("hello {new:?}"),
            "status None".into(),
        ]
    );
    assert_eq!(updates.chunks, [0]);
    assert_eq!((updates.commits, updates.switches), (1, 1));
}
