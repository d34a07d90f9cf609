//! The boot self-test's golden pair: two synthetic sonar images and the CRC-32 of the depth map
//! a model computes from them. The images and the depth map are made on the host (feature
//! `std`): the firmware's build embeds the pair and its compiled-in model's CRC
//! (`boards/selftest/build.rs`), and `host-sim sign` writes an update's CRC into its signed
//! header, so a device checks a new model bit for bit as it checks its own, before it serves.
//! The CRC is the one definition both sides compute.

#[cfg(feature = "std")]
use std::{boxed::Box, vec, vec::Vec};

use fixed::types::U16F16;

#[cfg(feature = "std")]
use crate::config;
#[cfg(feature = "std")]
use crate::model::{Error, Model, Workspace};

/// The golden pair's image `seed` (1: the reference, 2: the source): an LCG speckle over a
/// bright arc whose range varies across the columns.
#[cfg(feature = "std")]
pub fn image(seed: u32) -> Vec<u8> {
    let mut s = seed.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let (r, b) = (config::INPUT_RANGE_BINS, config::INPUT_COLUMNS);
    let mut img = vec![0u8; r * b];
    for k in 0..b {
        let centre =
            (r as f64) * (0.35 + 0.25 * ((k as f64) * 0.11 + seed as f64 * 0.3).sin().abs());
        for i in 0..r {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let d = (i as f64 - centre) / 5.0;
            let v = 210.0 * (-d * d).exp() + (s >> 27) as f64;
            img[i * b + k] = v.clamp(0.0, 255.0) as u8;
        }
    }
    img
}

/// The depth map `model` computes from the golden pair (reference 1, source 2).
#[cfg(feature = "std")]
pub fn depth(model: &Model<'_>) -> Result<Vec<U16F16>, Error> {
    let mut ws = Box::new(Workspace::new());
    let (reference, source) = (image(1), image(2));
    let mut features = vec![0i8; 2 * config::FEATURE_LEN];
    let mut depth = vec![U16F16::ZERO; config::DEPTH_LEN];
    model.depth(&[&reference, &source], &mut features, &mut ws, &mut depth)?;
    Ok(depth)
}

/// CRC-32 of a depth map's values (U16F16 bits, u32 LE), as the boot self-test computes it.
pub fn depth_crc(depth: &[U16F16]) -> u32 {
    let mut crc = crate::crc32::Crc32::new();
    for d in depth {
        crc.update(&d.to_bits().to_le_bytes());
    }
    crc.finish()
}
