//! Shared helpers of the integration tests.

#![deny(missing_docs)]

/// Beam centres (degrees) of the model's sonar, read from the bundled CSV independently of the
/// generated tables.
pub fn model_beam_centres_deg() -> Vec<f64> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/aris-beam-widths/");
    let text = std::fs::read_to_string(format!("{path}{}.csv", epssn::config::BEAM_TABLE))
        .expect("beam table");
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').nth(1).unwrap().trim().parse().unwrap())
        .collect()
}

pub use epssn_reference::float::random_float_weights;
pub use epssn_sim::synthetic::{synthetic_image, Rng};

/// `blob` rewritten with its one-element int32 tensor `name` removed (`None`) or set (added
/// when missing), every other tensor kept: a blob from before the tensor existed, or one with
/// a hostile value.
pub fn with_i32_tensor(blob: &[u8], name: &str, value: Option<i32>) -> Vec<u8> {
    let hash = epssn::config::SPEC_HASH;
    let parsed = epssn::blob::Blob::parse(blob, hash).expect("a valid blob");
    let v = value.map(|z| z.to_le_bytes());
    let mut tensors: Vec<(&str, epssn::blob::Dtype, &[u8])> = (0..parsed.tensor_count())
        .filter_map(|i| parsed.entry(i))
        .filter_map(|e| {
            let n = std::str::from_utf8(e.name).expect("ASCII tensor names");
            match (n == name, &v) {
                (false, _) => Some((n, e.dtype, e.bytes)),
                (true, Some(v)) => Some((n, e.dtype, &v[..])),
                (true, None) => None,
            }
        })
        .collect();
    if let (Some(v), None) = (&v, tensors.iter().position(|t| t.0 == name)) {
        tensors.push((name, epssn::blob::Dtype::I32, &v[..]));
    }
    let mut out = vec![0u8; blob.len() + 64 + name.len()];
    let n = epssn::blob::write_blob(hash, &tensors, &mut out).expect("the blob fits");
    out.truncate(n);
    out
}
