//! The spec parser (the JSON every size and geometry comes from) on arbitrary bytes: it must
//! refuse or accept without panicking, and what it accepts must say its own sizes consistently.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = epssn_spec::load::parse_spec(data);
});
