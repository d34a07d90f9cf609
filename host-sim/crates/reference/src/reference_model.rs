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
        if image.len() != config::INPUT_LEN {
            return Err(anyhow!(
                "image has {} values, {} expected",
                image.len(),
                config::INPUT_LEN
            ));
        }
        let mut x: Vec<i8> = image.iter().map(|&u| (u as i16 - 128) as i8).collect();
        let mut map = BTreeMap::new();
        for (i, l) in LAYERS.iter().enumerate().take(feature_layers) {
            let p = &all[i];
            let offset = if i == 0 { 128 } else { 0 };
            x = intref::conv(&Shape::from(l), &x, &p.w, &p.b, &p.m, offset, l.relu);
            map.insert(l.name.to_string(), x.clone());
        }
        feats.push(x);
        trace.features.push(map);
    }
    let mut c = [0i32; 4];
    blob.read_i32("cost.rq", &mut c)
        .map_err(|e| anyhow!("cost.rq: {e:?}"))?;
    let n = views.len();
    let mult = if n == 2 {
        Mult {
            m: c[0],
            shift: c[1],
        }
    } else {
        Mult {
            m: c[2],
            shift: c[3],
        }
    };
    // The mean channels' multipliers, present when the spec has mean channels.
    let mut mean = [0i32; 4];
    if config::MEAN_CHANNELS > 0 {
        blob.read_i32(epssn::model::COST_MEAN_TENSOR, &mut mean)
            .map_err(|e| anyhow!("cost.mean: {e:?}"))?;
    }
    let k = if n == 2 { 0 } else { 2 };
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
    let sources: Vec<(&[i8], &[epssn::geometry::WarpEntry])> = (1..n)
        .map(|k| (feats[k].as_slice(), &config::WARP_TABLES[k - 1][..]))
        .collect();
    let cost = intref::cost_volume(
        &feats[0],
        &sources,
        config::FEATURE_CHANNELS,
        config::PLANES,
        config::FEATURE_RANGE_BINS,
        config::FEATURE_COLUMNS,
        mult,
        config::MEAN_CHANNELS,
        mean_mult,
        zero_point,
    );
    trace.cost_net.insert("cost".into(), cost.clone());
    let mut x = cost;
    for (i, l) in LAYERS.iter().enumerate().skip(feature_layers) {
        let p = &all[i];
        let sh = Shape::from(l);
        x = match l.kind {
            // The layer reading the cost volume adds its zero point back.
            LayerKind::Conv3d => {
                let offset = if i == feature_layers { -zero_point } else { 0 };
                intref::conv(&sh, &x, &p.w, &p.b, &p.m, offset, l.relu)
            }
            LayerKind::ConvTranspose3d => {
                let skip = match (l.skip, p.skip) {
                    (Some(name), Some(m)) => Some((
                        trace
                            .cost_net
                            .get(name)
                            .ok_or_else(|| anyhow!("skip tensor {name} not computed"))?
                            .clone(),
                        m,
                    )),
                    _ => None,
                };
                intref::conv_transpose(
                    &sh,
                    &x,
                    &p.w,
                    &p.b,
                    &p.m,
                    0,
                    l.relu,
                    skip.as_ref().map(|(t, m)| {
                        let offset = if l.skip == Some("cost") {
                            -zero_point
                        } else {
                            0
                        };
                        (t.as_slice(), *m, offset)
                    }),
                )
            }
            LayerKind::Conv2d => return Err(anyhow!("2D layer {} in the cost net", l.name)),
        };
        trace.cost_net.insert(l.name.to_string(), x.clone());
    }
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
        config::NO_RETURN_MASS_Q16,
    );
    Ok(trace)
}
