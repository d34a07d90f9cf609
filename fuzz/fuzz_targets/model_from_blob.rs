//! The weight-blob parser on arbitrary bytes: `Model::from_blob` must refuse or accept without
//! panicking. Seeded with the shipped blob (scripts/fuzz.sh), so mutations explore every
//! check behind the header, the CRC and the per-layer bounds.
#![no_main]

use epssn::model::Model;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = Model::from_blob(data);
});
