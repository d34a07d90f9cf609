//! The quantiser: float EPSSN weights and calibrated activation ranges → the int8 weight blob
//! the library runs, following `docs/QUANTISATION.md` to the letter.
//!
//! Steps: fold batch norm into each convolution; quantise weights symmetrically per output
//! channel to [−127, 127]; take each activation's scale from its calibrated maximum; derive
//! int32 biases and TFLite-style (multiplier, shift) pairs; build the soft-argmax exp table;
//! prove every accumulator bound; write the blob and a readable manifest.

use std::collections::BTreeMap;

use anyhow::{anyhow, bail, ensure, Context, Result};
use epssn::blob::{write_blob, Dtype};
use epssn::config::{self, LAYERS};
use epssn::requant::Requant;
use serde::Serialize;

use epssn_reference::float::{fold_batch_norm, FloatWeights, WeightLayout};
use epssn_reference::weights::BLOB_FILE;

use crate::calibration::{search, CalibSample, SortedMagnitudes};

/// Calibrated maximum |x| of each activation tensor: `f0`…`f3`, `cost`, `d1`, `d2`, `m0`,
/// `u1`, `u0` (after their skip additions) and `head` (the logits).
pub type ActivationRanges = BTreeMap<String, f64>;

/// Rounds half away from zero (the contract's `round_half_away`; `f64::round` does this).
fn round_half_away(x: f64) -> f64 {
    x.round()
}

/// Symmetric per-channel int8 quantisation: `s_w[o] = max|w[o]|/127` (1 for an all-zero
/// channel), `q = round_half_away(w / s_w)`.
pub fn quantise_weights(w: &[f64], layout: &WeightLayout) -> (Vec<i8>, Vec<f64>) {
    let mut scales = vec![1.0; layout.out_channels];
    let mut q = vec![0i8; w.len()];
    for (o, scale) in scales.iter_mut().enumerate() {
        let max = layout
            .channel_indices(o)
            .map(|i| w[i].abs())
            .fold(0.0, f64::max);
        if max > 0.0 {
            *scale = max / 127.0;
        }
        for i in layout.channel_indices(o) {
            q[i] = round_half_away(w[i] / *scale).clamp(-127.0, 127.0) as i8;
        }
    }
    (q, scales)
}

/// The integer form of a real multiplier, refusing what the library would refuse.
fn requant(m: f64, what: &str) -> Result<Requant> {
    Requant::from_real(m).ok_or_else(|| anyhow!("{what}: multiplier {m} cannot be represented"))
}

/// `EXP[d] = round_half_away(65535 · exp(−d · s_l))`.
pub fn exp_table(logit_scale: f64) -> [u16; 256] {
    let mut t = [0u16; 256];
    for (d, e) in t.iter_mut().enumerate() {
        *e = round_half_away(65535.0 * (-(d as f64) * logit_scale).exp()) as u16;
    }
    t
}

/// One quantised layer, for the manifest.
#[derive(Clone, Debug, Serialize)]
pub struct LayerReport {
    /// Layer name.
    pub name: String,
    /// Scale of the layer's input.
    pub input_scale: f64,
    /// Scale of its output.
    pub output_scale: f64,
    /// Smallest and largest weight scale over the output channels.
    pub weight_scale_range: [f64; 2],
    /// Worst-case |accumulator| over all int8 inputs.
    pub accumulator_bound: i64,
    /// Headroom: log2(2^31 / bound).
    pub accumulator_headroom_bits: f64,
    /// Skip multiplier (real), if the layer has a skip.
    pub skip_multiplier: Option<f64>,
}

/// The quantised model: blob bytes plus what the manifest reports.
#[derive(Clone, Debug, Serialize)]
pub struct Quantised {
    /// Activation scales by tensor name (`input` is 1/255).
    pub activation_scales: BTreeMap<String, f64>,
    /// Per-layer report.
    pub layers: Vec<LayerReport>,
    /// Real cost-volume multipliers for 2 and 3 views.
    pub cost_multipliers: [f64; 2],
    /// The cost volume's zero point ([`COST_ZERO_POINT`]).
    pub cost_zero_point: i32,
    /// Views the model was trained for, written to the blob ([`epssn::model::VIEWS_TENSOR`]).
    pub views: usize,
    /// Spec hash the blob carries.
    pub spec_hash: u32,
    /// The blob.
    #[serde(skip)]
    pub blob: Vec<u8>,
}

/// The cost volume's zero point: the variance is never negative, so its int8 codes hold
/// `0..=255` stored as `q − 128` (QUANTISATION.md "Warp and cost volume"), twice the
/// resolution of the signed `0..=127`.
pub const COST_ZERO_POINT: i32 = -128;

/// The codes (real value / scale) a tensor's int8 values stand for: `0..=127 − z` for the cost
/// volume with zero point `z` (`0..=255` for the unsigned one), `−128..=127` for every other
/// tensor.
pub fn codes(name: &str, cost_zero_point: i32) -> (f64, f64) {
    if name == "cost" {
        (0.0, (127 - cost_zero_point) as f64)
    } else {
        (-128.0, 127.0)
    }
}

/// Largest code of a tensor as this quantiser writes it: 255 for the cost volume, 127 for the
/// rest.
pub fn top_code(name: &str) -> f64 {
    codes(name, COST_ZERO_POINT).1
}

/// Quantises `weights` with activation scales from `ranges` (max |x| per tensor).
/// `views`: the view count the model was trained for ([`int8_views`]), which the blob
/// carries so that the firmware pairs frames into sets of that size.
pub fn quantise(
    weights: &FloatWeights,
    ranges: &ActivationRanges,
    views: usize,
) -> Result<Quantised> {
    ensure!(
        (2..=config::MAX_VIEWS).contains(&views),
        "views {views}: the int8 model runs 2..={}",
        config::MAX_VIEWS
    );
    let mut scales = BTreeMap::new();
    scales.insert("input".to_string(), 1.0 / 255.0);
    for (name, &max) in ranges {
        if !(max.is_finite() && max > 0.0) {
            bail!("activation range of {name} is {max}: calibration failed");
        }
        scales.insert(name.clone(), max / top_code(name));
    }
    let scale = |name: &str| -> Result<f64> {
        scales
            .get(name)
            .copied()
            .ok_or_else(|| anyhow!("no calibrated range for tensor {name}"))
    };
    let mut tensors: Vec<(String, Dtype, Vec<u8>)> = Vec::new();
    let mut reports = Vec::new();
    let mut input_name = "input".to_string();
    let feature_layers = epssn::model::FEATURE_LAYERS;
    for (index, l) in LAYERS.iter().enumerate() {
        if index == feature_layers {
            input_name = "cost".to_string();
        }
        let layout = WeightLayout::of(l);
        let fl = weights
            .get(l.name)
            .ok_or_else(|| anyhow!("float weights have no layer {}", l.name))?;
        if fl.weight.len() != layout.len() || fl.bias.len() != l.out_channels {
            bail!(
                "layer {}: float weights have {} weights and {} biases, the spec wants {} and {}",
                l.name,
                fl.weight.len(),
                fl.bias.len(),
                layout.len(),
                l.out_channels
            );
        }
        let (w, b) = fold_batch_norm(fl, &layout);
        let (qw, ws) = quantise_weights(&w, &layout);
        let s_in = scale(&input_name)?;
        let s_out = scale(l.name)?;
        let mut qb = Vec::with_capacity(l.out_channels);
        let mut mult = Vec::with_capacity(l.out_channels);
        let mut shift = Vec::with_capacity(l.out_channels);
        let mut rq = Vec::with_capacity(l.out_channels);
        for o in 0..l.out_channels {
            let bias = round_half_away(b[o] / (s_in * ws[o]));
            if bias.abs() >= 2f64.powi(31) {
                bail!(
                    "layer {} channel {o}: bias {bias} does not fit int32",
                    l.name
                );
            }
            qb.push(bias as i32);
            let r = requant(s_in * ws[o] / s_out, l.name)?;
            mult.push(r.multiplier);
            shift.push(r.shift);
            rq.push(r);
        }
        let params = epssn::kernels::ConvParams {
            weights: &qw,
            bias: &qb,
            requant: &rq,
            input_offset: epssn::model::layer_input_offset(index, COST_ZERO_POINT),
            relu: l.relu,
        };
        let bound = epssn::kernels::check_layer_bounds(
            &epssn::kernels::ConvShape::from(l),
            &params,
            layout.transposed,
        )
        .map_err(|e| anyhow!("layer {}: {e:?}", l.name))?;
        if !rq.iter().all(|r| r.fits(bound)) {
            bail!(
                "layer {}: accumulator bound {bound} overflows after the left shift",
                l.name
            );
        }
        let mut skip_m = None;
        if let Some(skip) = l.skip {
            let m = scale(skip)? / s_out;
            let r = requant(m, l.name)?;
            tensors.push((
                format!("{}.k", l.name),
                Dtype::I32,
                i32_bytes(&[r.multiplier, r.shift]),
            ));
            skip_m = Some(m);
        }
        tensors.push((
            format!("{}.w", l.name),
            Dtype::I8,
            qw.iter().map(|&q| q as u8).collect(),
        ));
        tensors.push((format!("{}.b", l.name), Dtype::I32, i32_bytes(&qb)));
        tensors.push((format!("{}.m", l.name), Dtype::I32, i32_bytes(&mult)));
        tensors.push((format!("{}.s", l.name), Dtype::I32, i32_bytes(&shift)));
        reports.push(LayerReport {
            name: l.name.to_string(),
            input_scale: s_in,
            output_scale: s_out,
            weight_scale_range: [
                ws.iter().copied().fold(f64::INFINITY, f64::min),
                ws.iter().copied().fold(0.0, f64::max),
            ],
            accumulator_bound: bound,
            accumulator_headroom_bits: (2f64.powi(31) / bound.max(1) as f64).log2(),
            skip_multiplier: skip_m,
        });
        input_name = l.name.to_string();
    }
    let last_feature = LAYERS[feature_layers - 1].name;
    let s_f = scale(last_feature)?;
    let s_cost = scale("cost")?;
    let m2 = s_f * s_f / (4.0 * s_cost);
    let m3 = s_f * s_f / (9.0 * s_cost);
    let (r2, r3) = (
        requant(m2, "cost (2 views)")?,
        requant(m3, "cost (3 views)")?,
    );
    tensors.push((
        "cost.rq".into(),
        Dtype::I32,
        i32_bytes(&[r2.multiplier, r2.shift, r3.multiplier, r3.shift]),
    ));
    if config::MEAN_CHANNELS > 0 {
        // The mean channels: real mean s_f·Σv/n in units of s_cost.
        let (q2, q3) = (
            requant(s_f / (2.0 * s_cost), "cost mean (2 views)")?,
            requant(s_f / (3.0 * s_cost), "cost mean (3 views)")?,
        );
        tensors.push((
            epssn::model::COST_MEAN_TENSOR.into(),
            Dtype::I32,
            i32_bytes(&[q2.multiplier, q2.shift, q3.multiplier, q3.shift]),
        ));
    }
    tensors.push((
        epssn::model::COST_ZERO_POINT_TENSOR.into(),
        Dtype::I32,
        i32_bytes(&[COST_ZERO_POINT]),
    ));
    tensors.push((
        epssn::model::VIEWS_TENSOR.into(),
        Dtype::I32,
        i32_bytes(&[views as i32]),
    ));
    let head = LAYERS[LAYERS.len() - 1].name;
    let exp = exp_table(scale(head)?);
    tensors.push((
        "exp".into(),
        Dtype::U16,
        exp.iter().flat_map(|e| e.to_le_bytes()).collect(),
    ));
    let total: usize = tensors
        .iter()
        .map(|t| t.2.len() + 4 + epssn::blob::ENTRY_LEN)
        .sum();
    let mut out = vec![0u8; total + epssn::blob::HEADER_LEN + 8];
    let refs: Vec<(&str, Dtype, &[u8])> = tensors
        .iter()
        .map(|(n, d, b)| (n.as_str(), *d, b.as_slice()))
        .collect();
    let n = write_blob(config::SPEC_HASH, &refs, &mut out)
        .map_err(|e| anyhow!("writing blob: {e:?}"))?;
    out.truncate(n);
    // The library must accept what we wrote: the same checks the firmware runs at boot.
    epssn::model::Model::from_blob(&out)
        .map_err(|e| anyhow!("the library refuses the blob: {e:?}"))?;
    Ok(Quantised {
        activation_scales: scales,
        layers: reports,
        cost_multipliers: [m2, m3],
        cost_zero_point: COST_ZERO_POINT,
        views,
        spec_hash: config::SPEC_HASH,
        blob: out,
    })
}

fn i32_bytes(v: &[i32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Writes `<dir>/epssn-s.q8.bin` and `<dir>/quantisation.json`; `float_source` says where the
/// float weights came from (see [`epssn_reference::weights`]).
pub fn write(dir: &std::path::Path, q: &Quantised, float_source: serde_json::Value) -> Result<()> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_quantise_symmetrically_per_channel() {
        let layout = WeightLayout {
            in_channels: 1,
            out_channels: 3,
            kernel_volume: 2,
            transposed: false,
        };
        let (q, s) = quantise_weights(&[0.5, -1.27, 0.0, 0.0, 0.01, 0.0025], &layout);
        assert_eq!(&q[..2], &[50, -127]);
        assert!((s[0] - 0.01).abs() < 1e-15);
        assert_eq!(&q[2..4], &[0, 0]);
        assert_eq!(s[1], 1.0);
        assert_eq!(&q[4..], &[127, 32]); // 31.75 rounds to 32
    }

    #[test]
    fn search_scores_the_mask_or_every_pixel() {
        let mask = [1.0, 0.0, 1.0, 0.0];
        assert_eq!(SearchPixels::Mask.scored(&mask), [true, false, true, false]);
        assert_eq!(SearchPixels::All.scored(&mask), [true; 4]);
    }

    #[test]
    fn exp_table_is_monotone_and_anchored() {
        let t = exp_table(0.05);
        assert_eq!(t[0], 65535);
        assert!(t.windows(2).all(|w| w[1] <= w[0]));
        assert_eq!(t[20], (65535.0 * (-1.0f64).exp()).round() as u16);
    }
}

/// `host-sim quantise`: float weights + calibration data → blob and manifest.
#[derive(clap::Args, Debug)]
pub struct QuantiseArgs {
    /// Quantise the trained model in this weights folder (`model.safetensors`); the blob and
    /// `quantisation.json` are written beside it unless `--out` says otherwise.
    #[arg(long, conflicts_with = "random_init")]
    pub weights: Option<std::path::PathBuf>,
    /// Calibration data: simulated sample folders (`DIR/train/...`); training data only, so
    /// that accuracy figures on the test split stay held-out.
    #[arg(long, requires = "weights")]
    pub calib: Option<std::path::PathBuf>,
    /// Quantise an untrained, He-initialised model with this seed (for bit-exactness runs and
    /// benchmarks before trained weights exist), calibrated on synthetic images.
    #[arg(long)]
    pub random_init: Option<u64>,
    /// Number of calibration inputs.
    #[arg(long, default_value_t = 32)]
    pub calibration_samples: usize,
    /// Activation range = this percentile of |x| over the calibration inputs (100 = max).
    #[arg(long, default_value_t = 100.0)]
    pub percentile: f64,
    /// Choose each tensor's percentile by scoring candidate blobs with the int8 library on the
    /// calibration samples (`--percentile` is the starting point); see `calibration.rs`.
    #[arg(long, requires = "weights")]
    pub search: bool,
    /// Sweeps of the per-tensor search.
    #[arg(long, default_value_t = 1)]
    pub search_passes: usize,
    /// Depth pixels the search scores |int8 − float| on: the ground-truth mask (surfaces in the
    /// window), or all pixels, as the paper's MAE counts them (rays that meet nothing too).
    #[arg(long, value_enum, default_value_t = SearchPixels::Mask)]
    pub search_pixels: SearchPixels,
    /// Output folder for the blob and `quantisation.json`.
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Re-stamp the blob in this folder for the current spec instead of quantising: only the
    /// spec CRC (header offset 12) and the blob CRC change, every tensor byte stays, and
    /// `quantisation.json`'s `spec_hash` and `blob_crc32` follow. For spec edits that change
    /// no size, table or weight (e.g. a pairing tolerance); the build refuses others anyway.
    #[arg(long, conflicts_with_all = ["weights", "random_init"])]
    pub restamp: Option<std::path::PathBuf>,
}

/// Which depth pixels the per-tensor search scores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SearchPixels {
    /// The ground-truth mask: rays that meet a surface inside the window.
    Mask,
    /// Every pixel of the depth map, as the paper's MAE: on sphere scenes 90 % of the rays
    /// meet nothing and read r_max, and their int8 error counts as much.
    All,
}

impl SearchPixels {
    /// The pixels scored, from a sample's ground-truth mask (1 = surface in the window).
    pub fn scored(self, mask: &[f32]) -> Vec<bool> {
        match self {
            SearchPixels::Mask => epssn_sim::metrics::mask_from_f32(mask),
            SearchPixels::All => vec![true; mask.len()],
        }
    }
}

/// `quantise --restamp DIR`: the blob of `DIR` carrying the current spec's CRC.
pub fn restamp(dir: &std::path::Path, out: &mut impl std::io::Write) -> Result<()> {
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
    std::fs::write(&path, &blob).with_context(|| format!("writing {}", path.display()))?;
    let qpath = dir.join("quantisation.json");
    if let Ok(text) = std::fs::read_to_string(&qpath) {
        let mut j: serde_json::Value = serde_json::from_str(&text)?;
        j["spec_hash"] = format!("{:#010x}", config::SPEC_HASH).into();
        if j.get("blob_crc32").is_some() {
            j["blob_crc32"] = format!("{crc:#010x}").into();
        }
        std::fs::write(&qpath, serde_json::to_string_pretty(&j)? + "\n")?;
    }
    writeln!(
        out,
        "re-stamped {}: spec {:#010x} -> {:#010x}, blob CRC {crc:#010x}",
        path.display(),
        old,
        config::SPEC_HASH
    )?;
    Ok(())
}

/// Candidate percentiles of the per-tensor search.
pub const SEARCH_PERCENTILES: [f64; 9] =
    [100.0, 99.999, 99.99, 99.95, 99.9, 99.5, 99.0, 98.0, 95.0];

pub use epssn_reference::weights::int8_views;

/// Runs `host-sim quantise`.
pub fn run(args: &QuantiseArgs, out: &mut impl std::io::Write) -> Result<()> {
    if let Some(dir) = &args.restamp {
        return restamp(dir, out);
    }
    let n = args.calibration_samples.max(1);
    let (weights, traces, samples, mut source, dir, views) = match (&args.weights, args.random_init)
    {
        (Some(dir), None) => {
            let weights = epssn_reference::safetensors_io::load_float_weights(
                &dir.join("model.safetensors"),
            )?;
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
            let src = serde_json::json!({
                "safetensors": "model.safetensors",
                "calibration": {
                    "data": calib.display().to_string(),
                    "split": "train",
                    "samples": traces.len(),
                    "percentile": args.percentile,
                },
                "search_pixels": args.search_pixels,
            });
            (
                weights,
                traces,
                samples,
                src,
                args.out.clone().unwrap_or_else(|| dir.clone()),
                views_n,
            )
        }
        (None, Some(seed)) => {
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
            (
                weights,
                traces,
                Vec::new(),
                serde_json::json!({ "random_init": seed }),
                dir,
                config::VIEWS,
            )
        }
        _ => bail!("give --weights DIR --calib DATA, or --random-init SEED"),
    };
    let magnitudes = SortedMagnitudes::new(&traces);
    let (ranges, search) = if args.search {
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
    Ok(())
}
