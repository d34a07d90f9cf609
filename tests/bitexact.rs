//! Bit-exactness of the whole library model against the independent integer reference, layer
//! by layer, through the real blob path (quantiser → blob → `Model::from_blob`): simulated-like
//! images, frames of the real ARIS recording and extreme inputs, with 2 and 3 views.

use epssn::config;
use epssn::model::{Model, Workspace};
use epssn_tests::{random_float_weights, synthetic_image, Rng};
use fixed::types::U16F16;
use host_sim::{floatref, quantise, reference_model};

fn quantised_blob(seed: u64) -> Vec<u8> {
    let weights = random_float_weights(seed);
    let mut rng = Rng(seed ^ 0xABCD);
    let calib: Vec<_> = (0..2)
        .map(|s| {
            let a = synthetic_image(&mut rng, s as f64);
            let b = synthetic_image(&mut rng, s as f64 + 0.2);
            floatref::run(&weights, &[&a, &b]).unwrap()
        })
        .collect();
    let ranges = host_sim::calibration::SortedMagnitudes::new(&calib).ranges(100.0);
    quantise::quantise(&weights, &ranges).unwrap().blob
}

/// Runs the library and the reference on `views` and compares every tensor.
fn assert_bit_exact(blob: &[u8], views: &[&[u8]], what: &str) -> usize {
    let model = Model::from_blob(blob).unwrap();
    let mut ws = Box::new(Workspace::new());
    let reference = reference_model::run(blob, views).unwrap();
    let mut feats = vec![vec![0i8; config::FEATURE_LEN]; views.len()];
    let mut compared = 0;
    for (v, image) in views.iter().enumerate() {
        model
            .features_probed(image, &mut ws, &mut feats[v], |name, out| {
                assert_eq!(
                    out,
                    &reference.features[v][name][..],
                    "{what}: view {v} layer {name}"
                );
                compared += 1;
            })
            .unwrap();
    }
    let sources: Vec<&[i8]> = feats[1..].iter().map(|f| f.as_slice()).collect();
    let mut depth = vec![U16F16::ZERO; config::DEPTH_LEN];
    model
        .depth_from_features_probed(&feats[0], &sources, &mut ws, &mut depth, |name, out| {
            assert_eq!(out, &reference.cost_net[name][..], "{what}: layer {name}");
            compared += 1;
        })
        .unwrap();
    let bits: Vec<u32> = depth.iter().map(|d| d.to_bits()).collect();
    assert_eq!(bits, reference.depth, "{what}: depth");
    // Every layer was seen: feature layers per view, the cost volume, the cost net but the head.
    let feature_layers = epssn::model::FEATURE_LAYERS;
    assert_eq!(
        compared,
        views.len() * feature_layers + 1 + config::LAYER_COUNT - feature_layers - 1
    );
    // The depth is not degenerate: inside the window, not a single value everywhere.
    let top =
        config::R_MIN_Q16 + (config::DEPTH_RANGE_BINS as u32 - 1) * config::DEPTH_STEP_Q16 + 1;
    assert!(bits.iter().all(|&d| d >= config::R_MIN_Q16 && d <= top));
    let mut distinct = bits.clone();
    distinct.sort_unstable();
    distinct.dedup();
    distinct.len()
}

#[test]
fn simulated_like_pairs_and_triples() {
    let blob = quantised_blob(1);
    let mut rng = Rng(7);
    for s in 0..2 {
        let a = synthetic_image(&mut rng, s as f64 * 0.7);
        let b = synthetic_image(&mut rng, s as f64 * 0.7 + 0.1);
        let c = synthetic_image(&mut rng, s as f64 * 0.7 + 0.2);
        // Structured inputs give structured depth maps, not one value everywhere.
        assert!(assert_bit_exact(&blob, &[&a, &b], "pair") > 50);
        assert!(assert_bit_exact(&blob, &[&a, &b, &c], "triple") > 50);
    }
}

#[test]
fn extreme_inputs() {
    let blob = quantised_blob(2);
    let zeros = vec![0u8; config::INPUT_LEN];
    let full = vec![255u8; config::INPUT_LEN];
    let mut rng = Rng(3);
    let noise: Vec<u8> = (0..config::INPUT_LEN)
        .map(|_| rng.next_u64() as u8)
        .collect();
    let checker: Vec<u8> = (0..config::INPUT_LEN)
        .map(|i| if (i / 64 + i) % 2 == 0 { 255 } else { 0 })
        .collect();
    assert_bit_exact(&blob, &[&zeros, &zeros], "all 0");
    assert_bit_exact(&blob, &[&full, &full], "all 255");
    assert_bit_exact(&blob, &[&noise, &full, &zeros], "noise, 255, 0");
    assert_bit_exact(&blob, &[&checker, &noise], "checkerboard, noise");
}

#[test]
fn frames_of_the_real_recording() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/aris1200-telephoto-6frames.aris"
    );
    let reader = host_sim::aris::ArisReader::open(path).unwrap();
    let frames: Vec<Vec<u8>> = (0..reader.frame_count())
        .map(|i| host_sim::polar::frame_to_polar(&reader.frame(i).unwrap()).unwrap())
        .collect();
    assert!(
        frames.iter().all(|f| f.iter().any(|&v| v > 0)),
        "resampled frames carry data"
    );
    let blob = quantised_blob(3);
    assert_bit_exact(&blob, &[&frames[0], &frames[1]], "real frames 0, 1");
    assert_bit_exact(
        &blob,
        &[&frames[2], &frames[3], &frames[4]],
        "real frames 2, 3, 4",
    );
}

#[test]
fn corrupt_or_mismatched_blobs_are_refused() {
    let blob = quantised_blob(4);
    assert!(Model::from_blob(&blob).is_ok());
    let mut rng = Rng(5);
    for _ in 0..200 {
        let mut bad = blob.clone();
        let i = (rng.next_u64() as usize) % bad.len();
        bad[i] ^= 1 << (rng.next_u64() % 8);
        assert!(Model::from_blob(&bad).is_err(), "flipped byte {i} accepted");
    }
    for cut in [0, 10, 100, blob.len() / 2, blob.len() - 1] {
        assert!(Model::from_blob(&blob[..cut]).is_err());
    }
    // A blob for another spec is refused even with a valid checksum.
    let mut other = blob.clone();
    other[12] ^= 0xFF;
    let n = other.len() - 4;
    let crc = epssn::crc32::crc32(&other[..n]);
    other[n..].copy_from_slice(&crc.to_le_bytes());
    assert!(matches!(
        Model::from_blob(&other),
        Err(epssn::model::Error::Blob(
            epssn::blob::BlobError::SpecMismatch { .. }
        ))
    ));
}
