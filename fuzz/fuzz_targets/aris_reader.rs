//! The ARIS (DDF_05) reader on arbitrary bytes: opening validates the headers, then every
//! frame is read; it must refuse or read without panicking, and never report more frames than
//! the bytes can hold.
#![no_main]

use epssn_aris::aris::ArisReader;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(reader) = ArisReader::new(std::io::Cursor::new(data)) else {
        return;
    };
    let mut n = 0usize;
    for frame in reader.frames() {
        if frame.is_err() {
            break;
        }
        n += 1;
        assert!(n * 1024 <= data.len(), "{n} frames from {} bytes", data.len());
    }
});
