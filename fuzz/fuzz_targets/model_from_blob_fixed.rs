//! The weight-blob parser past its outer checks: the input's declared length and CRC-32 are
//! rewritten to match before parsing, so mutations reach the tensor table, the shapes, the
//! requantisation parameters and the per-layer accumulator bounds. No panic on any input.
#![no_main]

use epssn::crc32::crc32;
use epssn::model::Model;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut blob = data.to_vec();
    if blob.len() >= 28 {
        let len = blob.len() as u32;
        blob[20..24].copy_from_slice(&len.to_le_bytes());
        let body = blob.len() - 4;
        let crc = crc32(&blob[..body]);
        blob[body..].copy_from_slice(&crc.to_le_bytes());
    }
    let _ = Model::from_blob(&blob);
});
