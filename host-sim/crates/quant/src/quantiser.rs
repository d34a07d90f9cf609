//! The quantiser: float EPSSN weights and calibrated activation ranges → the int8 weight blob
//! the library runs, following `docs/QUANTISATION.md` to the letter.
//!
//! Steps: fold batch norm into each convolution; quantise weights symmetrically per output
//! channel to [−127, 127]; take each activation's scale from its calibrated maximum; derive
//! int32 biases and TFLite-style (multiplier, shift) pairs; build the soft-argmax exp table;
//! prove every accumulator bound; assemble the blob. Nothing here reads files or calibration
//! data: the ranges come in, the blob and its report go out (`host-sim quantise` in
//! [`crate::quantise`] does the rest).

use std::collections::BTreeMap;

use anyhow::{anyhow, bail, ensure, Result};
use epssn::blob::{write_blob, Dtype};
use epssn::config::{self, LayerShape, LAYERS};
use epssn::requant::Requant;
use serde::Serialize;

use epssn_reference::float::{fold_batch_norm, FloatWeights, WeightLayout};

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

/// The blob's tensors in the order they are written: name, type, little-endian bytes.
type Tensors = Vec<(String, Dtype, Vec<u8>)>;

/// Activation scales by tensor name: `input` (1/255) and every calibrated tensor.
struct Scales(BTreeMap<String, f64>);

impl Scales {
    /// `max / top code` of every range; a range that is not a positive number means the
    /// calibration went wrong, so it is refused rather than quantised.
    fn calibrated(ranges: &ActivationRanges) -> Result<Self> {
        let mut scales = BTreeMap::new();
        scales.insert("input".to_string(), 1.0 / 255.0);
        for (name, &max) in ranges {
            if !(max.is_finite() && max > 0.0) {
                bail!("activation range of {name} is {max}: calibration failed");
            }
            scales.insert(name.clone(), max / top_code(name));
        }
        Ok(Self(scales))
    }

    fn get(&self, name: &str) -> Result<f64> {
        self.0
            .get(name)
            .copied()
            .ok_or_else(|| anyhow!("no calibrated range for tensor {name}"))
    }
}

/// Quantises `weights` with activation scales from `ranges` (max |x| per tensor).
/// `views`: the view count the model was trained for ([`int8_views`]), which the blob
/// carries so that the firmware pairs frames into sets of that size.
///
/// [`int8_views`]: epssn_reference::weights::int8_views
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
    let scales = Scales::calibrated(ranges)?;
    let mut tensors = Tensors::new();
    let mut reports = Vec::new();
    let mut input_name = "input";
    let feature_layers = epssn::model::FEATURE_LAYERS;
    for (index, l) in LAYERS.iter().enumerate() {
        // The cost net's first layer reads the cost volume, not the last feature map.
        if index == feature_layers {
            input_name = "cost";
        }
        reports.push(quantise_layer(
            weights,
            &scales,
            index,
            l,
            input_name,
            &mut tensors,
        )?);
        input_name = l.name;
    }
    let cost_multipliers = cost_tensors(&scales, &mut tensors)?;
    model_tensors(&scales, views, &mut tensors)?;
    let blob = assemble_blob(&tensors)?;
    Ok(Quantised {
        activation_scales: scales.0,
        layers: reports,
        cost_multipliers,
        cost_zero_point: COST_ZERO_POINT,
        views,
        spec_hash: config::SPEC_HASH,
        blob,
    })
}

/// Layer `l` (model index `index`, reading tensor `input_name`): its tensors `.k` (with a
/// skip), `.w`, `.b`, `.m`, `.s` appended to `tensors`, and its manifest row.
fn quantise_layer(
    weights: &FloatWeights,
    scales: &Scales,
    index: usize,
    l: &LayerShape,
    input_name: &str,
    tensors: &mut Tensors,
) -> Result<LayerReport> {
    let layout = WeightLayout::of(l);
    let (w, b) = folded_layer(weights, l, &layout)?;
    let (qw, ws) = quantise_weights(&w, &layout);
    let s_in = scales.get(input_name)?;
    let s_out = scales.get(l.name)?;
    let (qb, rq) = channel_params(l, &b, &ws, s_in, s_out)?;
    let bound = proven_bound(index, l, &layout, &qw, &qb, &rq)?;
    let mut skip_m = None;
    if let Some(skip) = l.skip {
        let m = scales.get(skip)? / s_out;
        let r = requant(m, l.name)?;
        tensors.push((
            format!("{}.k", l.name),
            Dtype::I32,
            i32_bytes(&[r.multiplier, r.shift]),
        ));
        skip_m = Some(m);
    }
    let mult: Vec<i32> = rq.iter().map(|r| r.multiplier).collect();
    let shift: Vec<i32> = rq.iter().map(|r| r.shift).collect();
    tensors.push((
        format!("{}.w", l.name),
        Dtype::I8,
        qw.iter().map(|&q| q as u8).collect(),
    ));
    tensors.push((format!("{}.b", l.name), Dtype::I32, i32_bytes(&qb)));
    tensors.push((format!("{}.m", l.name), Dtype::I32, i32_bytes(&mult)));
    tensors.push((format!("{}.s", l.name), Dtype::I32, i32_bytes(&shift)));
    Ok(LayerReport {
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
    })
}

/// The float weights and biases of layer `l` with batch norm folded in, after checking they
/// have the sizes the spec gives (a model trained for another spec is refused here).
fn folded_layer(
    weights: &FloatWeights,
    l: &LayerShape,
    layout: &WeightLayout,
) -> Result<(Vec<f64>, Vec<f64>)> {
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
    Ok(fold_batch_norm(fl, layout))
}

/// Per output channel: the int32 bias `round(b / (s_in · s_w))` and the requantisation of
/// `s_in · s_w / s_out`.
fn channel_params(
    l: &LayerShape,
    b: &[f64],
    ws: &[f64],
    s_in: f64,
    s_out: f64,
) -> Result<(Vec<i32>, Vec<Requant>)> {
    let mut qb = Vec::with_capacity(l.out_channels);
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
        rq.push(requant(s_in * ws[o] / s_out, l.name)?);
    }
    Ok((qb, rq))
}

/// The layer's worst-case accumulator over all int8 inputs, by the library's own check, and
/// that it survives every channel's requantisation left shift: what `Model::from_blob` will
/// demand, refused here with the layer's name instead.
fn proven_bound(
    index: usize,
    l: &LayerShape,
    layout: &WeightLayout,
    qw: &[i8],
    qb: &[i32],
    rq: &[Requant],
) -> Result<i64> {
    let params = epssn::kernels::ConvParams {
        weights: qw,
        bias: qb,
        requant: rq,
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
    Ok(bound)
}

/// The cost volume's tensors (`cost.rq`, the mean channels' multipliers when the spec has
/// them); returns its real multipliers for 2 and 3 views.
fn cost_tensors(scales: &Scales, tensors: &mut Tensors) -> Result<[f64; 2]> {
    let last_feature = LAYERS[epssn::model::FEATURE_LAYERS - 1].name;
    let s_f = scales.get(last_feature)?;
    let s_cost = scales.get("cost")?;
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
    Ok([m2, m3])
}

/// The model-wide tensors after the cost volume's: its zero point, the view count and the
/// soft-argmax exp table of the head's logit scale.
fn model_tensors(scales: &Scales, views: usize, tensors: &mut Tensors) -> Result<()> {
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
    let exp = exp_table(scales.get(head)?);
    tensors.push((
        "exp".into(),
        Dtype::U16,
        exp.iter().flat_map(|e| e.to_le_bytes()).collect(),
    ));
    Ok(())
}

/// The blob of `tensors`, in their order, checked by the library.
fn assemble_blob(tensors: &Tensors) -> Result<Vec<u8>> {
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
    Ok(out)
}

fn i32_bytes(v: &[i32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
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
    fn exp_table_is_monotone_and_anchored() {
        let t = exp_table(0.05);
        assert_eq!(t[0], 65535);
        assert!(t.windows(2).all(|w| w[1] <= w[0]));
        assert_eq!(t[20], (65535.0 * (-1.0f64).exp()).round() as u16);
    }
}
