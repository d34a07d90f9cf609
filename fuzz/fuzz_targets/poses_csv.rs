//! The poses file reader of `host-sim label` (`epssn_sim::poses`) on arbitrary bytes: any text
//! must come back as rows or an error, never a panic, and the rows it accepts are well formed.
#![no_main]

use epssn_sim::poses::parse;
use libfuzzer_sys::fuzz_target;

/// Frames of the recording the file is checked against.
const FRAMES: usize = 64;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(rows) = parse(text, FRAMES) {
        for (frame, p) in rows {
            assert!(frame < FRAMES);
            assert!(p.position_m.iter().all(|c| c.is_finite()));
            assert!([p.roll_deg, p.pitch_deg, p.yaw_deg].iter().all(|a| a.is_finite()));
        }
    }
});
