//! `host-sim quantise`: float weights and calibration data → the int8 blob and its manifest
//! (or `--restamp`, the blob of a folder carrying the current spec's CRC).
//!
//! The command gathers the calibration (trained weights on training samples, or an untrained
//! model on synthetic images), picks the activation ranges (one percentile, or the per-tensor
//! search of [`crate::calibration`]), quantises with [`crate::quantiser`] and writes the
//! result. The quantiser's API is re-exported here, where its callers have always found it.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, ensure, Context, Result};
use epssn::config;

use epssn_reference::float::FloatWeights;
use epssn_reference::floatref::FloatTrace;
use epssn_reference::weights::BLOB_FILE;

pub use crate::calibration::SearchPixels;
use crate::calibration::{search, CalibSample, SortedMagnitudes};
pub use crate::quantiser::{
    codes, exp_table, quantise, quantise_weights, top_code, ActivationRanges, LayerReport,
    Quantised, COST_ZERO_POINT,
};
pub use epssn_reference::weights::int8_views;

/// Writes `<dir>/epssn-s.q8.bin` and `<dir>/quantisation.json`; `float_source` says where the
/// float weights came from (see [`epssn_reference::weights`]).
pub fn write(dir: &Path, q: &Quantised, float_source: serde_json::Value) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    std::fs::write(dir.join(BLOB_FILE), &q.blob)?;
    let manifest = serde_json::json!({
        "format": "epssn int8 weight blob",
        "format_version": epssn::blob::FORMAT_VERSION,
        "spec": config::SPEC_NAME,
        "spec_hash": format!("{:#010x}", q.spec_hash),
        "blob_bytes": q.blob.len(),
        "blob_crc32": format!("{:#010x}", epssn::crc32::crc32(&q.blob[..q.blob.len() - 4])),
        "rounding": "TFLite MultiplyByQuantizedMultiplier (docs/QUANTISATION.md)",
        "float_source": float_source,
        "quantisation": q,
    });
    std::fs::write(
        dir.join("quantisation.json"),
        serde_json::to_string_pretty(&manifest)?,
    )?;
    Ok(())
}

/// `host-sim quantise`: float weights + calibration data → blob and manifest.
#[derive(Debug)]
pub struct QuantiseOptions {
    /// Quantise the trained model in this weights folder (`model.safetensors`); the blob and
    /// `quantisation.json` are written beside it unless `--out` says otherwise.
    pub weights: Option<PathBuf>,
    /// Calibration data: simulated sample folders (`DIR/train/...`); training data only, so
    /// that accuracy figures on the test split stay held-out.
    pub calib: Option<PathBuf>,
    /// Quantise an untrained, He-initialised model with this seed (for bit-exactness runs and
    /// benchmarks before trained weights exist), calibrated on synthetic images.
    pub random_init: Option<u64>,
    /// Number of calibration inputs.
    pub calibration_samples: usize,
    /// Activation range = this percentile of |x| over the calibration inputs (100 = max).
    pub percentile: f64,
    /// Choose each tensor's percentile by scoring candidate blobs with the int8 library on the
    /// calibration samples (`--percentile` is the starting point); see `calibration.rs`.
    pub search: bool,
    /// Sweeps of the per-tensor search.
    pub search_passes: usize,
    /// Depth pixels the search scores |int8 − float| on: the ground-truth mask (surfaces in the
    /// window), or all pixels, as the paper's MAE counts them (rays that meet nothing too).
    pub search_pixels: SearchPixels,
    /// Take every activation scale from this folder's `quantisation.json` instead of
    /// calibrating: for a model trained quantisation-aware on those scales (`train
    /// --fake-quant`), whose activations were clipped and rounded to them.
    pub ranges_from: Option<PathBuf>,
    /// Output folder for the blob and `quantisation.json`.
    pub out: Option<PathBuf>,
    /// Re-stamp the blob in this folder for the current spec instead of quantising: only the
    /// spec CRC (header offset 12) and the blob CRC change, every tensor byte stays, and
    /// `quantisation.json`'s `spec_hash` and `blob_crc32` follow. For spec edits that change
    /// no size, table or weight (e.g. a pairing tolerance); the build refuses others anyway.
    pub restamp: Option<PathBuf>,
    /// Write this no-return threshold τ (in `[0, 1]`; 0: no decision) into the blob
    /// ([`epssn::model::NO_RETURN_TENSOR`]) in place of the spec's `no_return_mass`: a
    /// calibration of the trained model, chosen on validation data (`no_return_sweep`). With
    /// `restamp`, into that folder's blob, every other tensor byte kept.
    pub no_return_mass: Option<f64>,
}

/// The activation ranges (scale × top code) `quantisation.json` of `dir` records, for exactly
/// the tensors `calibrated` has: a missing or extra one means another network.
fn recorded_ranges(dir: &Path, calibrated: &ActivationRanges) -> Result<ActivationRanges> {
    let scales = epssn_reference::weights::activation_scales(dir).context("--ranges-from")?;
    let mut ranges = ActivationRanges::new();
    for name in calibrated.keys() {
        let s = scales.get(name).with_context(|| {
            format!(
                "{}/quantisation.json has no scale for {name}",
                dir.display()
            )
        })?;
        ranges.insert(name.clone(), s * top_code(name));
    }
    let extra: Vec<&String> = scales
        .keys()
        .filter(|n| !calibrated.contains_key(*n))
        .collect();
    ensure!(
        extra.is_empty(),
        "{}/quantisation.json has scales for {extra:?}, which this network does not have",
        dir.display()
    );
    Ok(ranges)
}

/// `quantise --restamp DIR`: the blob of `DIR` carrying the current spec's CRC.
pub fn restamp(dir: &Path, out: &mut impl std::io::Write) -> Result<()> {
    let path = dir.join(BLOB_FILE);
    let mut blob = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    ensure!(blob.len() >= 28, "{}: too short for a blob", path.display());
    let old = u32::from_le_bytes([blob[12], blob[13], blob[14], blob[15]]);
    // The blob must be intact for the spec it names before anything is re-stamped.
    epssn::blob::Blob::parse(&blob, old)
        .map_err(|e| anyhow!("{}: not a valid blob: {e:?}", path.display()))?;
    blob[12..16].copy_from_slice(&config::SPEC_HASH.to_le_bytes());
    let body = blob.len() - 4;
    let crc = epssn::crc32::crc32(&blob[..body]);
    blob[body..].copy_from_slice(&crc.to_le_bytes());
    epssn::model::Model::from_blob(&blob)
        .map_err(|e| anyhow!("the re-stamped blob is refused: {e:?}"))?;
    write_blob_and_manifest(dir, &blob, |j, _| {
        j["spec_hash"] = format!("{:#010x}", config::SPEC_HASH).into();
    })?;
    writeln!(
        out,
        "re-stamped {}: spec {:#010x} -> {:#010x}, blob CRC {crc:#010x}",
        path.display(),
        old,
        config::SPEC_HASH
    )?;
    Ok(())
}

/// `blob` with the int32 tensor `name` set to `value` (`None`: removed): replaced in place, or
/// appended; every other tensor's bytes and order kept, the spec hash the blob's own.
pub fn with_i32_tensor(blob: &[u8], name: &str, value: Option<i32>) -> Result<Vec<u8>> {
    let hash = u32::from_le_bytes(
        blob.get(12..16)
            .context("too short for a blob")?
            .try_into()?,
    );
    let parsed =
        epssn::blob::Blob::parse(blob, hash).map_err(|e| anyhow!("not a valid blob: {e:?}"))?;
    let v = value.map(i32::to_le_bytes);
    let mut tensors = Vec::new();
    for e in (0..parsed.tensor_count()).filter_map(|i| parsed.entry(i)) {
        let n = std::str::from_utf8(e.name).context("tensor name")?;
        match (n == name, &v) {
            (false, _) => tensors.push((n, e.dtype, e.bytes)),
            (true, Some(v)) => tensors.push((n, e.dtype, &v[..])),
            (true, None) => {}
        }
    }
    if let (Some(v), None) = (&v, tensors.iter().position(|t| t.0 == name)) {
        tensors.push((name, epssn::blob::Dtype::I32, &v[..]));
    }
    let mut out = vec![0u8; blob.len() + epssn::blob::ENTRY_LEN + 8 + name.len()];
    let n = epssn::blob::write_blob(hash, &tensors, &mut out)
        .map_err(|e| anyhow!("writing the blob: {e:?}"))?;
    out.truncate(n);
    Ok(out)
}

/// `blob` with its no-return threshold set to `tau` ([`epssn::model::NO_RETURN_TENSOR`],
/// `round(τ · 2^16)`), every other tensor's bytes kept; checked by the library.
pub fn with_no_return(blob: &[u8], tau: f64) -> Result<Vec<u8>> {
    ensure!(
        (0.0..=1.0).contains(&tau),
        "no-return threshold {tau} is outside [0, 1]"
    );
    let tau16 = (tau * 65536.0).round() as i32;
    let out = with_i32_tensor(blob, epssn::model::NO_RETURN_TENSOR, Some(tau16))?;
    if out[12..16] == config::SPEC_HASH.to_le_bytes() {
        let model = epssn::model::Model::from_blob(&out)
            .map_err(|e| anyhow!("the blob with a no-return threshold is refused: {e:?}"))?;
        ensure!(
            model.no_return16() == tau16 as u32,
            "the threshold did not take"
        );
    }
    Ok(out)
}

/// Writes `blob` to `dir` and has `quantisation.json` (when there is one) follow it:
/// `blob_crc32` where it records one, then `edit` (given the CRC). Returns the blob's CRC.
fn write_blob_and_manifest(
    dir: &Path,
    blob: &[u8],
    edit: impl FnOnce(&mut serde_json::Value, u32),
) -> Result<u32> {
    let path = dir.join(BLOB_FILE);
    std::fs::write(&path, blob).with_context(|| format!("writing {}", path.display()))?;
    let crc = epssn::crc32::crc32(&blob[..blob.len() - 4]);
    let qpath = dir.join("quantisation.json");
    if let Ok(text) = std::fs::read_to_string(&qpath) {
        let mut j: serde_json::Value = serde_json::from_str(&text)?;
        if j.get("blob_crc32").is_some() {
            j["blob_crc32"] = format!("{crc:#010x}").into();
        }
        edit(&mut j, crc);
        std::fs::write(&qpath, serde_json::to_string_pretty(&j)? + "\n")?;
    }
    Ok(crc)
}

/// `quantise --no-return-mass τ`: `dir`'s blob with its no-return threshold set to τ, and
/// `quantisation.json` following (`no_return_mass`, `blob_bytes`, `blob_crc32`).
pub fn set_no_return(dir: &Path, tau: f64, out: &mut impl std::io::Write) -> Result<()> {
    let path = dir.join(BLOB_FILE);
    let blob = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
    let blob = with_no_return(&blob, tau).with_context(|| path.display().to_string())?;
    let crc = write_blob_and_manifest(dir, &blob, |j, crc| {
        j["no_return_mass"] = tau.into();
        j["blob_bytes"] = blob.len().into();
        j["blob_crc32"] = format!("{crc:#010x}").into();
    })?;
    writeln!(
        out,
        "{}: no-return threshold {tau} (tau16 {}), blob CRC {crc:#010x}",
        path.display(),
        (tau * 65536.0).round()
    )?;
    Ok(())
}

/// Candidate percentiles of the per-tensor search.
pub const SEARCH_PERCENTILES: [f64; 9] =
    [100.0, 99.999, 99.99, 99.95, 99.9, 99.5, 99.0, 98.0, 95.0];

/// What the ranges are calibrated on, and where the result goes.
struct Calibration {
    weights: FloatWeights,
    /// The float model's traces of the calibration inputs (their activations' magnitudes).
    traces: Vec<FloatTrace>,
    /// The inputs the per-tensor search scores (none for an untrained model).
    samples: Vec<CalibSample>,
    /// `float_source` of the manifest.
    source: serde_json::Value,
    /// Output folder.
    dir: PathBuf,
    /// The view count the blob carries.
    views: usize,
}

/// `--weights DIR --calib DATA`: the trained model on `n` training samples, evenly spread
/// over the split (training data only, so accuracy on the test split stays held out).
fn trained_calibration(args: &QuantiseOptions, dir: &Path, n: usize) -> Result<Calibration> {
    let weights =
        epssn_reference::safetensors_io::load_float_weights(&dir.join("model.safetensors"))?;
    let calib = args
        .calib
        .as_ref()
        .ok_or_else(|| anyhow!("--calib DATA (training split) is needed with --weights"))?;
    let views_n = int8_views(dir)?;
    let samples = epssn_sim::dataset::sample_dirs(calib, epssn_sim::scene::Split::Train)?;
    if samples.is_empty() {
        bail!("no training samples under {}", calib.display());
    }
    // Evenly spread over the split.
    let step = (samples.len() / n).max(1);
    let traces = samples
        .iter()
        .step_by(step)
        .take(n)
        .map(|d| {
            let s = epssn_sim::dataset::Sample::load(d)?;
            let mut views = s.polar_views_u8();
            ensure!(
                views.len() >= views_n,
                "{}: {} views, the model was trained on {views_n}",
                d.display(),
                views.len()
            );
            views.truncate(views_n);
            let refs: Vec<&[u8]> = views.iter().map(|v| v.as_slice()).collect();
            let trace = epssn_reference::floatref::run(&weights, &refs)?;
            let sample = CalibSample {
                scored: args.search_pixels.scored(&s.mask),
                float_depth: trace.depth.clone(),
                views,
            };
            Ok((trace, sample))
        })
        .collect::<Result<Vec<_>>>()?;
    let (traces, samples): (Vec<_>, Vec<_>) = traces.into_iter().unzip();
    let source = serde_json::json!({
        "safetensors": "model.safetensors",
        "calibration": {
            "data": calib.display().to_string(),
            "split": "train",
            "samples": traces.len(),
            "percentile": args.percentile,
        },
        "search_pixels": args.search_pixels,
    });
    Ok(Calibration {
        weights,
        traces,
        samples,
        source,
        dir: args.out.clone().unwrap_or_else(|| dir.to_path_buf()),
        views: views_n,
    })
}

/// `--random-init SEED`: an untrained model on up to 8 pairs of synthetic images.
fn random_calibration(args: &QuantiseOptions, seed: u64, n: usize) -> Result<Calibration> {
    let weights = epssn_reference::float::random_float_weights(seed);
    let mut rng = epssn_sim::synthetic::Rng(seed ^ 0x5EED);
    let traces = (0..n.min(8))
        .map(|s| {
            let a = epssn_sim::synthetic::synthetic_image(&mut rng, s as f64 * 0.37);
            let b = epssn_sim::synthetic::synthetic_image(&mut rng, s as f64 * 0.37 + 0.1);
            epssn_reference::floatref::run(&weights, &[&a, &b])
        })
        .collect::<Result<Vec<_>>>()?;
    let dir = args
        .out
        .clone()
        .ok_or_else(|| anyhow!("--out is needed with --random-init"))?;
    Ok(Calibration {
        weights,
        traces,
        samples: Vec::new(),
        source: serde_json::json!({ "random_init": seed }),
        dir,
        views: config::VIEWS,
    })
}

/// Runs `host-sim quantise`.
pub fn run(args: &QuantiseOptions, out: &mut impl std::io::Write) -> Result<()> {
    if let Some(dir) = &args.restamp {
        restamp(dir, out)?;
        if let Some(tau) = args.no_return_mass {
            set_no_return(dir, tau, out)?;
        }
        return Ok(());
    }
    let n = args.calibration_samples.max(1);
    let Calibration {
        weights,
        traces,
        samples,
        mut source,
        dir,
        views,
    } = match (&args.weights, args.random_init) {
        (Some(dir), None) => trained_calibration(args, dir, n)?,
        (None, Some(seed)) => random_calibration(args, seed, n)?,
        _ => bail!("give --weights DIR --calib DATA, or --random-init SEED"),
    };
    let magnitudes = SortedMagnitudes::new(&traces);
    let (ranges, search) = if let Some(from) = &args.ranges_from {
        let ranges = recorded_ranges(from, &magnitudes.ranges(args.percentile))?;
        if let serde_json::Value::Object(m) = &mut source {
            m.insert("ranges_from".into(), from.display().to_string().into());
        }
        (ranges, None)
    } else if args.search {
        let (r, s) = search(
            &weights,
            &magnitudes,
            &samples,
            args.percentile,
            &SEARCH_PERCENTILES,
            args.search_passes,
        )?;
        writeln!(
            out,
            "per-tensor search: {} blobs scored; calibration |int8 − float| {:.2} → {:.2} mm",
            s.evaluations, s.start_mm, s.final_mm
        )?;
        (r, Some(s))
    } else {
        (magnitudes.ranges(args.percentile), None)
    };
    let q = quantise(&weights, &ranges, views)?;
    if let (Some(s), serde_json::Value::Object(m)) = (&search, &mut source) {
        m.insert("search".into(), serde_json::to_value(s)?);
    }
    write(&dir, &q, source)?;
    writeln!(
        out,
        "wrote {} ({} bytes, spec {} {:#010x}) and quantisation.json to {}",
        BLOB_FILE,
        q.blob.len(),
        config::SPEC_NAME,
        q.spec_hash,
        dir.display()
    )?;
    if let Some(tau) = args.no_return_mass {
        set_no_return(&dir, tau, out)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder of this test process holding `quantisation.json` with these scales.
    fn folder(name: &str, scales: &[(&str, f64)]) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("epssn-ranges-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let table: serde_json::Map<String, serde_json::Value> = scales
            .iter()
            .map(|&(n, s)| (n.to_string(), s.into()))
            .collect();
        let json = serde_json::json!({ "quantisation": { "activation_scales": table } });
        std::fs::write(dir.join("quantisation.json"), json.to_string()).unwrap();
        dir
    }

    #[test]
    fn recorded_ranges_are_scale_times_top_code_for_exactly_the_networks_tensors() {
        let calibrated: ActivationRanges =
            [("cost".to_string(), 1.0), ("f0".to_string(), 1.0)].into();
        let dir = folder(
            "ok",
            &[("input", 1.0 / 255.0), ("cost", 0.02), ("f0", 0.05)],
        );
        let r = recorded_ranges(&dir, &calibrated).unwrap();
        assert!((r["cost"] - 0.02 * 255.0).abs() < 1e-12);
        assert!((r["f0"] - 0.05 * 127.0).abs() < 1e-12);
        let missing = folder("missing", &[("cost", 0.02)]);
        assert!(recorded_ranges(&missing, &calibrated).is_err());
        let extra = folder("extra", &[("cost", 0.02), ("f0", 0.05), ("g9", 0.1)]);
        assert!(recorded_ranges(&extra, &calibrated).is_err());
        let bad = folder("bad", &[("cost", 0.0), ("f0", 0.05)]);
        assert!(recorded_ranges(&bad, &calibrated).is_err());
        for d in [dir, missing, extra, bad] {
            std::fs::remove_dir_all(d).unwrap();
        }
    }
}
