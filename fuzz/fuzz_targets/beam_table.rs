//! The beam-table CSV parser (Sound Metrics' per-beam angle tables) on arbitrary text.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = epssn_spec::load::parse_beam_table("fuzz", text);
    }
});
