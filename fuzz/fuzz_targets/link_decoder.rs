//! The link's streaming decoder on arbitrary bytes, with line-idle events at byte positions the
//! input chooses: it must never panic or hang, every message it returns must encode back to
//! the bytes it came from (decode ∘ encode is the identity on what the decoder accepts), and
//! accepted sequence numbers must increase strictly except at a session's `hello`, and a hello's
//! fault record (its payload) is exactly `fault::RECORD_LEN` bytes, carried through re-encoding.
#![no_main]

use epssn::fault::{Record, RECORD_LEN};
use epssn::link::{encode_to_slice, Decoder, Message, MAX_MESSAGE_LEN};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // First byte: every how many bytes the line goes idle (0 = never).
    let Some((&idle_every, bytes)) = data.split_first() else {
        return;
    };
    let mut decoder = Box::new(Decoder::new());
    let mut last: Option<u32> = None;
    let mut out = vec![0u8; MAX_MESSAGE_LEN];
    let mut check = |decoder: &mut Decoder, last: &mut Option<u32>| {
        // Each poll consumes bytes or reports; bound the loop anyway.
        for _ in 0..=MAX_MESSAGE_LEN {
            match decoder.poll() {
                None => return,
                Some(Ok(msg)) => {
                    let seq = msg.seq();
                    // A hello starts a session at any seq; everything else must increase.
                    let hello = msg.kind() == "hello";
                    assert!(hello || last.is_none_or(|l| seq > l), "seq {seq} after {last:?}");
                    *last = Some(seq);
                    let n = encode_to_slice(&msg, &mut out).expect("a decoded message encodes");
                    let mut again = Decoder::new();
                    for &b in &out[..n] {
                        again.push(b);
                    }
                    let re = again.poll().expect("complete").expect("valid");
                    assert_eq!(re.seq(), seq);
                    assert_eq!(re.kind(), msg.kind());
                    if let Message::Hello { record, .. } = &msg {
                        if let Some(r) = record {
                            assert_eq!(r.len(), RECORD_LEN);
                            // Validation never panics; a valid record re-encodes to its bytes.
                            if let Some(v) = Record::from_bytes(r) {
                                assert_eq!(&v.to_bytes()[..], &r[..]);
                            }
                        }
                        assert_eq!(&re, &msg, "a hello round-trips whole (reset, record, ack)");
                    }
                }
                Some(Err(_)) => {}
            }
        }
        panic!("poll did not settle");
    };
    for (i, &b) in bytes.iter().enumerate() {
        decoder.push(b);
        check(&mut decoder, &mut last);
        if idle_every != 0 && i % idle_every as usize == 0 {
            let _ = decoder.idle();
            check(&mut decoder, &mut last);
        }
    }
    let _ = decoder.idle();
    check(&mut decoder, &mut last);
});
