//! Writes one encoded link message of every type, and a stream of them, into a folder: the
//! seed corpus of the `link_decoder` fuzz target (scripts/fuzz.sh).
//!
//! `cargo run --example link_seeds -- fuzz/corpus/link_decoder`

use epssn::config;
use epssn::link::{encode_to_slice, DepthData, Message, Status, MAX_MESSAGE_LEN};
use fixed::types::U16F16;

fn main() {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).expect("output folder"));
    std::fs::create_dir_all(&dir).expect("create the folder");
    let image: Vec<u8> = (0..config::INPUT_LEN)
        .map(|i| (i * 7 % 251) as u8)
        .collect();
    let depth: Vec<U16F16> = (0..config::DEPTH_LEN)
        .map(|i| U16F16::from_num(2.0 + (i % 97) as f64 / 64.0))
        .collect();
    let record = epssn::fault::Record::panic(&"index out of bounds", "src/x.rs", 12, 5).to_bytes();
    let mut sources = heapless::Vec::new();
    let _ = sources.push(4);
    let messages = [
        Message::Frame {
            seq: 1,
            roll_deg: 7.0,
            attitude: epssn::attitude::Attitude::from_header_deg(12.0, 0.5, 0.0, 0.0, 0.0, 7.0),
            image: &image,
        },
        Message::Depth {
            seq: 2,
            reference: 3,
            sources,
            instructions: 47_793_040,
            depth: DepthData::Values(&depth),
            pair: None,
        },
        Message::StatusRequest { seq: 5 },
        Message::Status {
            seq: 6,
            status: Status::default(),
        },
        Message::Error {
            seq: 7,
            code: 3,
            msg: "sequence",
        },
        Message::Shutdown { seq: 8 },
        // The device's hello with its fault record, and the host's that acknowledges it.
        Message::Hello {
            seq: 1,
            status: Some(Status::default()),
            reset: Some(epssn::fault::ResetCause::Panic),
            record: Some(&record),
            ack: None,
        },
        Message::Hello {
            seq: 0,
            status: None,
            reset: None,
            record: None,
            ack: Some(0x1234_5678),
        },
    ];
    let mut stream = Vec::new();
    let mut buf = vec![0u8; MAX_MESSAGE_LEN];
    for (i, m) in messages.iter().enumerate() {
        let n = encode_to_slice(m, &mut buf).expect("encodes");
        // The fuzz target reads its first byte as the idle period: 0 = never idle.
        let mut seed = vec![0u8];
        seed.extend_from_slice(&buf[..n]);
        std::fs::write(dir.join(format!("{i}-{}", m.kind())), &seed).expect("write");
        stream.extend_from_slice(&buf[..n]);
    }
    let mut seed = vec![0u8];
    seed.extend_from_slice(&stream);
    std::fs::write(dir.join("stream"), seed).expect("write");
}
