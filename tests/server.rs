//! The link server (`epssn::server`, what the firmware runs) on the host: a mock serial line
//! and a mock busy pin, link messages in, every reply checked; the depth map of a valid view
//! set bit for bit against the independent integer reference.

use std::cell::Cell;
use std::convert::Infallible;

use epssn::config;
use epssn::link::{encode, Decoder, ErrorCode, Message, Status};
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use epssn::server::Server;
use epssn_tests::{synthetic_image, Rng};
use fixed::types::U16F16;

/// A serial line: reads what the test queued, records what the server writes.
struct MockSerial {
    rx: Vec<u8>,
    at: usize,
    tx: Vec<u8>,
}

impl embedded_io::ErrorType for MockSerial {
    type Error = Infallible;
}

impl embedded_io::Read for MockSerial {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        // A few bytes at a time, as a UART FIFO delivers them.
        let n = buf.len().min(7).min(self.rx.len() - self.at);
        buf[..n].copy_from_slice(&self.rx[self.at..self.at + n]);
        self.at += n;
        Ok(n)
    }
}

impl embedded_io::ReadReady for MockSerial {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.at < self.rx.len())
    }
}

impl embedded_io::Write for MockSerial {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.tx.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Infallible> {
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

fn replies(bytes: &[u8]) -> Vec<Reply> {
    let mut decoder = Decoder::new();
    let mut out = Vec::new();
    for &b in bytes {
        decoder.push(b);
        while let Some(event) = decoder.poll() {
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
                } => Reply::Hello {
                    seq,
                    frames: status.frames,
                    errors: status.errors,
                    cached: status.cached,
                },
                m => panic!("unexpected reply {m:?}"),
            });
        }
    }
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
    let mut serial = MockSerial {
        rx: input,
        at: 0,
        tx: Vec::new(),
    };
    let mut pin = MockPin::default();
    server.serve(&mut serial, &mut pin, &mut decoder).unwrap();
    assert_eq!(serial.at, serial.rx.len(), "the server stopped early");
    (replies(&serial.tx), pin)
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

const HELLO: fn(u32) -> Message<'static> = |seq| Message::Hello { seq, status: None };

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
