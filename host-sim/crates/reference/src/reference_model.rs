//! The whole int8 network run through the independent integer reference ([`crate::intref`]),
//! reading its parameters from a weight blob: every layer's output, for comparing with the
//! library's [`epssn::model::Model`] bit for bit.

use std::collections::BTreeMap;

use anyhow::{anyhow, Result};
use epssn::blob::Blob;
use epssn::config::{self, LayerKind, LAYERS};

use crate::intref::{self, Mult, Shape};

/// Every intermediate tensor of one inference.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    /// Feature-net outputs per view: `features[view][layer]`.
    pub features: Vec<BTreeMap<String, Vec<i8>>>,
    /// The cost volume and every cost-net layer's output, the head's logits included.
    pub cost_net: BTreeMap<String, Vec<i8>>,
    /// Depth `[E][A]`, U16F16 bits.
    pub depth: Vec<u32>,
}

struct LayerParams {
    w: Vec<i8>,
    b: Vec<i32>,
    m: Vec<Mult>,
    skip: Option<Mult>,
}

fn i32s(blob: &Blob<'_>, name: &str, n: usize) -> Result<Vec<i32>> {
    let mut v = vec![0; n];
    blob.read_i32(name, &mut v)
        .map_err(|e| anyhow!("{name}: {e:?}"))?;
    Ok(v)
}

fn params(blob: &Blob<'_>, index: usize) -> Result<LayerParams> {
    let l = &LAYERS[index];
    let oc = l.out_channels;
    let w = blob
        .i8_tensor(&format!("{}.w", l.name), l.weight_len())
        .map_err(|e| anyhow!("{}.w: {e:?}", l.name))?
        .to_vec();
    let b = i32s(blob, &format!("{}.b", l.name), oc)?;
    let m = i32s(blob, &format!("{}.m", l.name), oc)?;
    let s = i32s(blob, &format!("{}.s", l.name), oc)?;
    let skip = if l.skip.is_some() {
        let k = i32s(blob, &format!("{}.k", l.name), 2)?;
        Some(Mult {
            m: k[0],
            shift: k[1],
        })
    } else {
        None
    };
    Ok(LayerParams {
        w,
        b,
        m: m.iter()
            .zip(&s)
            .map(|(&m, &shift)| Mult { m, shift })
            .collect(),
        skip,
    })
}

/// Runs the network on u8 polar images (`views[0]` is the reference, `views[k]` the view
/// rolled by k × the baseline).
pub fn run(blob_bytes: &[u8], views: &[&[u8]]) -> Result<Trace> {
    let blob = Blob::parse(blob_bytes, config::SPEC_HASH).map_err(|e| anyhow!("blob: {e:?}"))?;
    if views.len() < 2 || views.len() > config::MAX_VIEWS {
        return Err(anyhow!(
            "{} views given, 2..={} supported",
            views.len(),
            config::MAX_VIEWS
        ));
    }
    let feature_layers = LAYERS
        .iter()
        .take_while(|l| l.kind == LayerKind::Conv2d)
        .count();
    let all: Vec<LayerParams> = (0..LAYERS.len())
        .map(|i| params(&blob, i))
        .collect::<Result<_>>()?;
    let mut trace = Trace::default();
    let mut feats = Vec::new();
    for image in views {
        let (x, map) = feature_net(image, &all[..feature_layers])?;
        feats.push(x);
        trace.features.push(map);
    }
    let cost = CostParams::read(&blob, views.len())?;
    let sources: Vec<(&[i8], &[epssn::geometry::WarpEntry])> = (1..views.len())
        .map(|k| (feats[k].as_slice(), &config::WARP_TABLES[k - 1][..]))
        .collect();
    let volume = intref::cost_volume(
        &feats[0],
        &sources,
        config::FEATURE_CHANNELS,
        config::PLANES,
        config::FEATURE_RANGE_BINS,
        config::FEATURE_COLUMNS,
        cost.mult,
        config::MEAN_CHANNELS,
        cost.mean_mult,
        cost.zero_point,
    );
    trace.cost_net.insert("cost".into(), volume.clone());
    let x = cost_net(
        volume,
        &all,
        feature_layers,
        cost.zero_point,
        &mut trace.cost_net,
    )?;
    let mut exp = [0u16; 256];
    blob.read_u16("exp", &mut exp)
        .map_err(|e| anyhow!("exp: {e:?}"))?;
    trace.depth = intref::soft_argmax(
        &x,
        config::DEPTH_ROWS,
        config::DEPTH_RANGE_BINS,
        config::DEPTH_COLUMNS,
        &exp,
        config::R_MIN_Q16,
        config::DEPTH_STEP_Q16,
        config::END_BIN_OFFSET,
        no_return16(&blob)?,
    );
    Ok(trace)
}

/// The no-return threshold the blob carries (`no_return`, `round(τ · 2^16)` in `0..=2^16`),
/// else the spec's.
fn no_return16(blob: &Blob<'_>) -> Result<u32> {
    let mut v = [config::NO_RETURN_MASS_Q16 as i32];
    match blob.read_i32(epssn::model::NO_RETURN_TENSOR, &mut v) {
        Ok(()) | Err(epssn::blob::BlobError::MissingTensor) => {}
        Err(e) => return Err(anyhow!("no_return: {e:?}")),
    }
    u32::try_from(v[0])
        .ok()
        .filter(|&t| t <= 1 << 16)
        .ok_or_else(|| anyhow!("no_return {} is outside 0..=65536", v[0]))
}

/// Tensors by layer name.
type Outputs = BTreeMap<String, Vec<i8>>;

/// One view through the feature net (`params`, its layers in order): the features and every
/// layer's output by name.
fn feature_net(image: &[u8], params: &[LayerParams]) -> Result<(Vec<i8>, Outputs)> {
    if image.len() != config::INPUT_LEN {
        return Err(anyhow!(
            "image has {} values, {} expected",
            image.len(),
            config::INPUT_LEN
        ));
    }
    let mut x: Vec<i8> = image.iter().map(|&u| (u as i16 - 128) as i8).collect();
    let mut map = BTreeMap::new();
    for (i, (l, p)) in LAYERS.iter().zip(params).enumerate() {
        let offset = if i == 0 { 128 } else { 0 };
        x = intref::conv(&Shape::from(l), &x, &p.w, &p.b, &p.m, offset, l.relu);
        map.insert(l.name.to_string(), x.clone());
    }
    Ok((x, map))
}

/// The cost volume's requantisation for `views` views, its mean channels' and its zero point.
struct CostParams {
    mult: Mult,
    mean_mult: Mult,
    zero_point: i32,
}

impl CostParams {
    fn read(blob: &Blob<'_>, views: usize) -> Result<Self> {
        let mut c = [0i32; 4];
        blob.read_i32("cost.rq", &mut c)
            .map_err(|e| anyhow!("cost.rq: {e:?}"))?;
        // Two views' multiplier first, then three views'.
        let k = if views == 2 { 0 } else { 2 };
        let mult = Mult {
            m: c[k],
            shift: c[k + 1],
        };
        // The mean channels' multipliers, present when the spec has mean channels.
        let mut mean = [0i32; 4];
        if config::MEAN_CHANNELS > 0 {
            blob.read_i32(epssn::model::COST_MEAN_TENSOR, &mut mean)
                .map_err(|e| anyhow!("cost.mean: {e:?}"))?;
        }
        let mean_mult = Mult {
            m: mean[k],
            shift: mean[k + 1],
        };
        // The cost volume's zero point: 0 when the blob predates it.
        let zero_point = match blob.read_i32("cost.zp", &mut c[..1]) {
            Ok(()) => c[0],
            Err(epssn::blob::BlobError::MissingTensor) => 0,
            Err(e) => return Err(anyhow!("cost.zp: {e:?}")),
        };
        Ok(CostParams {
            mult,
            mean_mult,
            zero_point,
        })
    }
}

/// The cost net from the cost volume `x`: its layers (`all` from `first` on), each output
/// stored in `outputs` by name (skips read theirs there); the head's logits.
fn cost_net(
    mut x: Vec<i8>,
    all: &[LayerParams],
    first: usize,
    zero_point: i32,
    outputs: &mut Outputs,
) -> Result<Vec<i8>> {
    for (i, l) in LAYERS.iter().enumerate().skip(first) {
        let p = &all[i];
        let sh = Shape::from(l);
        x = match l.kind {
            // The layer reading the cost volume adds its zero point back.
            LayerKind::Conv3d => {
                let offset = if i == first { -zero_point } else { 0 };
                intref::conv(&sh, &x, &p.w, &p.b, &p.m, offset, l.relu)
            }
            LayerKind::ConvTranspose3d => {
                let skip = match (l.skip, p.skip) {
                    (Some(name), Some(m)) => Some((
                        outputs
                            .get(name)
                            .ok_or_else(|| anyhow!("skip tensor {name} not computed"))?
                            .clone(),
                        m,
                    )),
                    _ => None,
                };
                // The skip from the cost volume adds its zero point back too.
                let offset = if l.skip == Some("cost") {
                    -zero_point
                } else {
                    0
                };
                intref::conv_transpose(
                    &sh,
                    &x,
                    &p.w,
                    &p.b,
                    &p.m,
                    0,
                    l.relu,
                    skip.as_ref().map(|(t, m)| (t.as_slice(), *m, offset)),
                )
            }
            LayerKind::Conv2d => return Err(anyhow!("2D layer {} in the cost net", l.name)),
        };
        outputs.insert(l.name.to_string(), x.clone());
    }
    Ok(x)
}
