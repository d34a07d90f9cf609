//! Bit-exactness of the whole library model against the independent integer reference, layer
//! by layer, through the real blob path (quantiser → blob → `Model::from_blob`): simulated-like
//! images, frames of the real ARIS recording and extreme inputs, with 2 and 3 views.

use epssn::config;
use epssn::model::{Model, WholeWorkspace, Workspace};
use epssn_quant::quantise;
use epssn_reference::{floatref, reference_model};
use epssn_tests::{random_float_weights, synthetic_image, Rng};
use fixed::types::U16F16;

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
    let ranges = epssn_quant::calibration::SortedMagnitudes::new(&calib).ranges(100.0);
    quantise::quantise(&weights, &ranges, epssn::config::VIEWS)
        .unwrap()
        .blob
}

/// The window's ends r_min and r_max, Q16.16: soft-argmax indices K and R − 1 + K (K the end
/// bins' offset beyond the window, QUANTISATION.md), between which every depth is clamped.
fn window_ends() -> [u32; 2] {
    let (k, step) = (config::END_BIN_OFFSET, config::DEPTH_STEP_Q16);
    [
        config::R_MIN_Q16 + k * step,
        config::R_MIN_Q16 + (config::DEPTH_RANGE_BINS as u32 - 1 + k) * step,
    ]
}

/// Runs the library's whole-tensor path and its streamed path and the reference on `views`;
/// compares every tensor the whole path shows, every tensor the streamed path shows, and both
/// depth maps.
fn assert_bit_exact(blob: &[u8], views: &[&[u8]], what: &str) -> usize {
    let model = Model::from_blob(blob).unwrap();
    let mut whole = Box::new(WholeWorkspace::new());
    let mut ws = Box::new(Workspace::new());
    let reference = reference_model::run(blob, views).unwrap();
    let feature_layers = epssn::model::FEATURE_LAYERS;
    let last_feature = config::LAYERS[feature_layers - 1].name;
    let mut feats = vec![vec![0i8; config::FEATURE_LEN]; views.len()];
    let mut compared = 0;
    for (v, image) in views.iter().enumerate() {
        model
            .features_whole_probed(image, &mut whole, &mut feats[v], |name, out| {
                assert_eq!(
                    out,
                    &reference.features[v][name][..],
                    "{what}: view {v} layer {name}"
                );
                compared += 1;
            })
            .unwrap();
        let mut streamed = vec![0i8; config::FEATURE_LEN];
        let mut stages = 0;
        model
            .features_probed(image, &mut ws, &mut streamed, |_, out| {
                assert_eq!(out, &reference.features[v][last_feature][..]);
                stages += 1;
            })
            .unwrap();
        assert_eq!(stages, 1);
        assert_eq!(streamed, feats[v], "{what}: view {v} streamed features");
    }
    let sources: Vec<&[i8]> = feats[1..].iter().map(|f| f.as_slice()).collect();
    let mut depth = vec![U16F16::ZERO; config::DEPTH_LEN];
    model
        .depth_from_features_whole_probed(
            &feats[0],
            &sources,
            &mut whole,
            &mut depth,
            |name, out| {
                assert_eq!(out, &reference.cost_net[name][..], "{what}: layer {name}");
                compared += 1;
            },
        )
        .unwrap();
    let bits: Vec<u32> = depth.iter().map(|d| d.to_bits()).collect();
    assert_eq!(bits, reference.depth, "{what}: depth");
    // Every layer was seen: feature layers per view, the cost volume, the cost net but the head.
    assert_eq!(
        compared,
        views.len() * feature_layers + 1 + config::LAYER_COUNT - feature_layers - 1
    );
    // The streamed path: the UNet tensors it holds whole (d1 … u1), then the same depth map.
    let mut streamed = vec![U16F16::ZERO; config::DEPTH_LEN];
    let mut seen = Vec::new();
    model
        .depth_from_features_probed(&feats[0], &sources, &mut ws, &mut streamed, |name, out| {
            let layer = name.rsplit('+').next().unwrap();
            assert_eq!(
                out,
                &reference.cost_net[layer][..],
                "{what}: streamed {name}"
            );
            seen.push(layer.to_string());
        })
        .unwrap();
    let middle: Vec<String> = config::LAYERS[feature_layers..config::LAYER_COUNT - 2]
        .iter()
        .map(|l| l.name.to_string())
        .collect();
    assert_eq!(seen, middle, "{what}: streamed stages");
    let streamed_bits: Vec<u32> = streamed.iter().map(|d| d.to_bits()).collect();
    assert_eq!(streamed_bits, bits, "{what}: streamed depth");
    // The depth is not degenerate: inside the window, not a single value everywhere.
    let [lo, hi] = window_ends();
    assert!(bits.iter().all(|&d| d >= lo && d <= hi));
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
    let reader = epssn_aris::aris::ArisReader::open(path).unwrap();
    let frames: Vec<Vec<u8>> = (0..reader.frame_count())
        .map(|i| epssn_aris::polar::frame_to_polar(&reader.frame(i).unwrap()).unwrap())
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

/// The streamed path (line buffers, cost volume never whole) against the whole-tensor twin on
/// random blobs and random images, with one workspace reused dirty across calls and view
/// counts, so no result can depend on what an earlier call left in the scratch.
#[test]
fn streamed_path_equals_whole_tensor_path() {
    let mut ws = Box::new(Workspace::new());
    let mut whole = Box::new(WholeWorkspace::new());
    for seed in 10..13 {
        let blob = quantised_blob(seed);
        let model = Model::from_blob(&blob).unwrap();
        let mut rng = Rng(seed * 31);
        let images: Vec<Vec<u8>> = (0..3)
            .map(|v| {
                if v == 2 {
                    (0..config::INPUT_LEN)
                        .map(|_| rng.next_u64() as u8)
                        .collect()
                } else {
                    synthetic_image(&mut rng, seed as f64 * 0.3 + v as f64 * 0.1)
                }
            })
            .collect();
        let mut a = vec![vec![0i8; config::FEATURE_LEN]; 3];
        let mut b = vec![vec![0i8; config::FEATURE_LEN]; 3];
        for v in 0..3 {
            model.features(&images[v], &mut ws, &mut a[v]).unwrap();
            model
                .features_whole_probed(&images[v], &mut whole, &mut b[v], |_, _| {})
                .unwrap();
            assert_eq!(a[v], b[v], "seed {seed} view {v}");
        }
        for views in [2, 3] {
            let sources: Vec<&[i8]> = a[1..views].iter().map(|f| f.as_slice()).collect();
            let mut d0 = vec![U16F16::ZERO; config::DEPTH_LEN];
            let mut d1 = vec![U16F16::MAX; config::DEPTH_LEN];
            model
                .depth_from_features(&a[0], &sources, &mut ws, &mut d0)
                .unwrap();
            model
                .depth_from_features_whole_probed(&a[0], &sources, &mut whole, &mut d1, |_, _| {})
                .unwrap();
            assert_eq!(d0, d1, "seed {seed}, {views} views");
        }
    }
}

/// `blob` rewritten with its cost-volume zero point tensor removed (`None`) or set.
fn with_cost_zero_point(blob: &[u8], zero_point: Option<i32>) -> Vec<u8> {
    epssn_tests::with_i32_tensor(blob, epssn::model::COST_ZERO_POINT_TENSOR, zero_point)
}

/// The quantiser writes the unsigned cost volume (zero point −128); blobs written before it
/// (no zero-point tensor) still load with zero point 0 and run bit-exactly against the
/// reference, and any other zero point is refused.
#[test]
fn cost_zero_points_old_new_and_invalid() {
    let blob = quantised_blob(21);
    let model = Model::from_blob(&blob).unwrap();
    assert_eq!(model.cost_zero_point(), -128);
    let old = with_cost_zero_point(&blob, None);
    assert_eq!(Model::from_blob(&old).unwrap().cost_zero_point(), 0);
    let mut rng = Rng(22);
    let a = synthetic_image(&mut rng, 0.4);
    let b = synthetic_image(&mut rng, 0.5);
    assert!(assert_bit_exact(&old, &[&a, &b], "blob without a cost zero point") > 0);
    for bad in [-127, -1, 1, 128, i32::MIN] {
        assert_eq!(
            Model::from_blob(&with_cost_zero_point(&blob, Some(bad))).unwrap_err(),
            epssn::model::Error::Kernel(epssn::kernels::KernelError::CostZeroPoint {
                zero_point: bad
            }),
            "zero point {bad}"
        );
    }
}

/// With mean channels (spec 3) the blob carries their multipliers (`cost.mean`), and a blob
/// without them, or with a tensor of another size, is refused; a spec without mean channels
/// has no such tensor.
#[test]
fn mean_channel_multipliers_present_exactly_with_mean_channels() {
    let blob = quantised_blob(25);
    let name = epssn::model::COST_MEAN_TENSOR;
    let parsed = epssn::blob::Blob::parse(&blob, config::SPEC_HASH).unwrap();
    let mut mean = [0i32; 4];
    if config::MEAN_CHANNELS == 0 {
        assert_eq!(
            parsed.read_i32(name, &mut mean),
            Err(epssn::blob::BlobError::MissingTensor)
        );
        return;
    }
    parsed.read_i32(name, &mut mean).unwrap();
    assert!(mean[0] >= 1 << 30 && mean[2] >= 1 << 30, "{mean:?}");
    let without = epssn_tests::with_i32_tensor(&blob, name, None);
    assert_eq!(
        Model::from_blob(&without).unwrap_err(),
        epssn::model::Error::Blob(epssn::blob::BlobError::MissingTensor)
    );
    let short = epssn_tests::with_i32_tensor(&blob, name, Some(1 << 30));
    assert!(matches!(
        Model::from_blob(&short).unwrap_err(),
        epssn::model::Error::Blob(_)
    ));
}

/// The blob records the views its model was trained for (the server pairs sets of that size);
/// a blob without the tensor has the spec's, and counts the library cannot run are refused.
#[test]
fn views_tensor_trained_default_and_invalid() {
    let blob = quantised_blob(23);
    assert_eq!(Model::from_blob(&blob).unwrap().views(), config::VIEWS);
    let name = epssn::model::VIEWS_TENSOR;
    let three = epssn_tests::with_i32_tensor(&blob, name, Some(3));
    assert_eq!(Model::from_blob(&three).unwrap().views(), 3);
    let old = epssn_tests::with_i32_tensor(&blob, name, None);
    assert_eq!(Model::from_blob(&old).unwrap().views(), config::VIEWS);
    for bad in [i32::MIN, -2, 0, 1, config::MAX_VIEWS as i32 + 1, i32::MAX] {
        assert_eq!(
            Model::from_blob(&epssn_tests::with_i32_tensor(&blob, name, Some(bad))).unwrap_err(),
            epssn::model::Error::Views { views: bad },
            "views {bad}"
        );
    }
    // The quantiser writes the count it is given and refuses one the library cannot run.
    let weights = epssn_tests::random_float_weights(23);
    let mut rng = Rng(24);
    let a = synthetic_image(&mut rng, 0.2);
    let b = synthetic_image(&mut rng, 0.3);
    let c = synthetic_image(&mut rng, 0.4);
    let trace = floatref::run(&weights, &[&a, &b, &c]).unwrap();
    let ranges = epssn_quant::calibration::SortedMagnitudes::new(&[trace]).ranges(100.0);
    let q = quantise::quantise(&weights, &ranges, 3).unwrap();
    assert_eq!(q.views, 3);
    assert_eq!(Model::from_blob(&q.blob).unwrap().views(), 3);
    assert!(quantise::quantise(&weights, &ranges, 4).is_err());
    assert!(quantise::quantise(&weights, &ranges, 1).is_err());
}

/// The blob may carry its model's own no-return threshold: without the tensor the model runs
/// the spec's, with it the blob's (and the reference follows it bit for bit), and thresholds
/// outside `0..=2^16` are refused.
#[test]
fn no_return_tensor_overrides_the_spec_and_bad_values_are_refused() {
    let blob = quantised_blob(29);
    let model = Model::from_blob(&blob).unwrap();
    assert_eq!(model.no_return16(), config::NO_RETURN_MASS_Q16);
    let name = epssn::model::NO_RETURN_TENSOR;
    let mut rng = Rng(30);
    let a = synthetic_image(&mut rng, 0.25);
    let b = synthetic_image(&mut rng, 0.35);
    let depth = |blob: &[u8]| -> Vec<u32> {
        assert_bit_exact(blob, &[&a, &b], "no-return threshold");
        reference_model::run(blob, &[&a, &b]).unwrap().depth
    };
    // τ16 = 1 decides nearly every ray (its end bins hold any mass at all), τ16 = 0 none.
    let none = quantise::with_no_return(&blob, 0.0).unwrap();
    let all = quantise::with_no_return(&blob, 1.0 / 65536.0).unwrap();
    assert_eq!(Model::from_blob(&none).unwrap().no_return16(), 0);
    assert_eq!(Model::from_blob(&all).unwrap().no_return16(), 1);
    let (undecided, decided) = (depth(&none), depth(&all));
    let ends = window_ends();
    let changed: Vec<u32> = decided
        .iter()
        .zip(&undecided)
        .filter(|(d, u)| d != u)
        .map(|(d, _)| *d)
        .collect();
    assert!(!changed.is_empty(), "τ16 = 1 decided no ray");
    assert!(changed.iter().all(|d| ends.contains(d)), "{changed:?}");
    // Setting it again replaces it; the other tensors keep their bytes.
    let half = quantise::with_no_return(&all, 0.5).unwrap();
    assert_eq!(half, quantise::with_no_return(&blob, 0.5).unwrap());
    assert_eq!(Model::from_blob(&half).unwrap().no_return16(), 1 << 15);
    for tau in [-0.1, 1.5, f64::NAN] {
        assert!(quantise::with_no_return(&blob, tau).is_err(), "τ {tau}");
    }
    for bad in [i32::MIN, -1, (1 << 16) + 1, i32::MAX] {
        assert_eq!(
            Model::from_blob(&epssn_tests::with_i32_tensor(&blob, name, Some(bad))).unwrap_err(),
            epssn::model::Error::NoReturn { tau16: bad },
            "τ16 {bad}"
        );
        assert!(reference_model::run(
            &epssn_tests::with_i32_tensor(&blob, name, Some(bad)),
            &[&a, &b]
        )
        .is_err());
    }
}
