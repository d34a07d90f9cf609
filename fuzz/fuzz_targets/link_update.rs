//! The update messages (`chunk`, `upload?`, `upload`, `commit`) decoded from arbitrary bytes and
//! driven into the update state machine over a RAM flash: nothing may panic or hang, each of
//! these messages must re-encode to itself, a chunk carries 1 to `MAX_CHUNK_LEN` bytes, every
//! refusal carries an update code, the held bytes never exceed the image, no commit succeeds
//! (no input can carry a signature by the key below: a forgery would be a finding), and the
//! flash, ECC flash (`RamFlash` write-once), never refuses an operation: the updater programs
//! no write unit twice between erases, whatever the messages.
#![no_main]

use epssn::link::{encode_to_slice, Decoder, Message, MAX_CHUNK_LEN, MAX_MESSAGE_LEN};
use epssn_update::ram_flash::{ERASE_SIZE, WRITE_SIZE};
use epssn_update::{Active, RamFlash, UpdateError, Updater};
use libfuzzer_sys::fuzz_target;

/// The public half of the private key [0x42; 32], which the fuzzer cannot know to sign with.
fn key() -> [u8; 32] {
    epssn_update::verify::public_key(&[0x42; 32])
}

fuzz_target!(|data: &[u8]| {
    let mut mem = vec![0xFFu8; 2 * ERASE_SIZE + 2 * 32 * 1024];
    let mut cells = vec![0u8; mem.len() / WRITE_SIZE];
    let flash = RamFlash::with_cells(&mut mem[..], Some(&mut cells[..])).expect("a cell a unit");
    let Ok(mut updater) = Updater::open(flash) else {
        panic!("the partition holds two slots");
    };
    let key = key();
    let mut decoder = Box::new(Decoder::new());
    let mut out = vec![0u8; MAX_MESSAGE_LEN];
    for &b in data {
        decoder.push(b);
        // Each poll consumes bytes or reports; bound the loop anyway.
        for _ in 0..=MAX_MESSAGE_LEN {
            let Some(event) = decoder.poll() else { break };
            let Ok(msg) = event else { continue };
            let update = matches!(
                msg,
                Message::Chunk { .. }
                    | Message::UploadRequest { .. }
                    | Message::Upload { .. }
                    | Message::Commit { .. }
            );
            if update {
                let n = encode_to_slice(&msg, &mut out).expect("a decoded message encodes");
                let mut again = Decoder::new();
                out[..n].iter().for_each(|&b| again.push(b));
                let re = again.poll().expect("complete").expect("valid");
                assert_eq!(re, msg, "an update message round-trips whole");
            }
            let result = match msg {
                Message::Chunk {
                    offset, crc, data, ..
                } => {
                    assert!((1..=MAX_CHUNK_LEN).contains(&data.len()));
                    updater.chunk(offset, data, crc).map(|_| ())
                }
                Message::Commit { .. } => updater.commit(&key, |_, _| true).map(|_| ()),
                _ => Ok(()),
            };
            if let Err(e) = result {
                assert!((13..=23).contains(&e.code().code()), "{e:?}");
                assert!(!matches!(e, UpdateError::Flash(_)), "{e:?}");
            }
            if let Some(u) = updater.upload() {
                assert!(u.held <= u.total);
            }
            assert_eq!(updater.active(), Active::Factory);
        }
    }
});
