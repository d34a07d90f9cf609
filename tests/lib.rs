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
    epssn_quant::quantise::with_i32_tensor(blob, name, value).expect("a valid blob")
}
