//! The spec parser (the JSON every size and geometry comes from) on arbitrary bytes, and the
//! build's rules and generator on every spec it accepts: each must refuse or accept without
//! panicking, so a bad spec fails the library's build with its message, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(spec) = epssn_spec::load::parse_spec(data) {
        // A beam table of the spec's own count, ascending a quarter degree a beam.
        let beams: Vec<f64> = (0..spec.sonar.beams)
            .map(|i| f64::from(i) * 0.25 - 16.0)
            .collect();
        let _ = epssn_spec::codegen::config_source(&spec, &beams, 0);
    }
});
