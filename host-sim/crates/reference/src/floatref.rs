//! A plain f32 forward pass of EPSSN (straightforward loops, no framework), from the same
//! float weights the quantiser reads. It serves calibration (the range of every activation)
//! and is what the PyTorch trainer's float network is checked against; batch norm is applied in inference form.

use std::collections::BTreeMap;

use anyhow::{anyhow, Result};
use epssn::config::{self, LayerKind, LayerShape, LAYERS};
use epssn::geometry::WarpEntry;
use epssn::kernels::cost_volume_s8::CostShape;

use crate::float::{fold_batch_norm, FloatWeights, WeightLayout};

/// Every activation of one float inference.
#[derive(Clone, Debug, Default)]
pub struct FloatTrace {
    /// Feature-net outputs per view: `features[view][layer]`.
    pub features: Vec<BTreeMap<String, Vec<f32>>>,
    /// The cost volume ("cost") and every cost-net output, head logits included.
    pub cost_net: BTreeMap<String, Vec<f32>>,
    /// Depth `[E][A]`, metres: the soft-argmax clamped to the window, or exactly `r_max`
    /// (`r_min`) where the no-return decision says the ray met nothing (something nearer).
    pub depth: Vec<f32>,
    /// The soft-argmax before the decision (clamped to the window), `[E][A]`, metres.
    pub soft_depth: Vec<f32>,
    /// Softmax mass of each ray's last bin, `[E][A]`.
    pub far_mass: Vec<f32>,
    /// Softmax mass of each ray's first bin, `[E][A]`.
    pub near_mass: Vec<f32>,
}

impl FloatTrace {
    /// The depth map under the no-return decision at threshold `round(τ · 2^16) = tau16`
    /// instead of the spec's (the int8 model's own, `Model::no_return16`; 0 decides nothing).
    pub fn decided(&self, tau16: u32) -> Vec<f32> {
        let tau = f64::from(tau16) / 65536.0;
        self.soft_depth
            .iter()
            .zip(self.near_mass.iter().zip(&self.far_mass))
            .map(|(&soft, (&near, &far))| decide(soft, near, far, tau))
            .collect()
    }
}

/// The no-return decision on one ray at threshold `tau` (the spec's `no_return_mass`; 0
/// decides nothing): `r_max` when the last bin holds at least `tau` of the mass, else `r_min`
/// when the first does, else the soft-argmax `soft`.
pub fn decide(soft: f32, near_mass: f32, far_mass: f32, tau: f64) -> f32 {
    if tau > 0.0 && far_mass as f64 >= tau {
        config::R_MAX_M as f32
    } else if tau > 0.0 && near_mass as f64 >= tau {
        config::R_MIN_M as f32
    } else {
        soft
    }
}

fn conv(l: &LayerShape, x: &[f32], w: &[f64], b: &[f64]) -> Vec<f32> {
    let [d, h, wd] = l.in_size;
    let [od, oh, ow] = l.out_size;
    let k = l.kernel.map(usize::from);
    let s = l.stride.map(usize::from);
    let p = l.padding.map(usize::from);
    let (ic, oc) = (l.in_channels, l.out_channels);
    let mut out = vec![0f32; oc * od * oh * ow];
    for o in 0..oc {
        for z in 0..od {
            for y in 0..oh {
                for xx in 0..ow {
                    let mut acc = b[o];
                    for i in 0..ic {
                        for kz in 0..k[0] {
                            let iz = (z * s[0] + kz) as isize - p[0] as isize;
                            if iz < 0 || iz >= d as isize {
                                continue;
                            }
                            for ky in 0..k[1] {
                                let iy = (y * s[1] + ky) as isize - p[1] as isize;
                                if iy < 0 || iy >= h as isize {
                                    continue;
                                }
                                for kx in 0..k[2] {
                                    let ix = (xx * s[2] + kx) as isize - p[2] as isize;
                                    if ix < 0 || ix >= wd as isize {
                                        continue;
                                    }
                                    let xi = ((i * d + iz as usize) * h + iy as usize) * wd
                                        + ix as usize;
                                    let wi = (((o * ic + i) * k[0] + kz) * k[1] + ky) * k[2] + kx;
                                    acc += x[xi] as f64 * w[wi];
                                }
                            }
                        }
                    }
                    out[((o * od + z) * oh + y) * ow + xx] = acc as f32;
                }
            }
        }
    }
    out
}

fn conv_transpose(l: &LayerShape, x: &[f32], w: &[f64], b: &[f64]) -> Vec<f32> {
    let [d, h, wd] = l.in_size;
    let [od, oh, ow] = l.out_size;
    let k = l.kernel.map(usize::from);
    let s = l.stride.map(usize::from);
    let p = l.padding.map(usize::from);
    let (ic, oc) = (l.in_channels, l.out_channels);
    let mut acc = vec![0f64; oc * od * oh * ow];
    for (o, chunk) in acc.chunks_mut(od * oh * ow).enumerate() {
        chunk.fill(b[o]);
    }
    for i in 0..ic {
        for z in 0..d {
            for y in 0..h {
                for xx in 0..wd {
                    let v = x[((i * d + z) * h + y) * wd + xx] as f64;
                    for o in 0..oc {
                        for kz in 0..k[0] {
                            let tz = (z * s[0] + kz) as isize - p[0] as isize;
                            if tz < 0 || tz >= od as isize {
                                continue;
                            }
                            for ky in 0..k[1] {
                                let ty = (y * s[1] + ky) as isize - p[1] as isize;
                                if ty < 0 || ty >= oh as isize {
                                    continue;
                                }
                                for kx in 0..k[2] {
                                    let tx = (xx * s[2] + kx) as isize - p[2] as isize;
                                    if tx < 0 || tx >= ow as isize {
                                        continue;
                                    }
                                    let wi = (((i * oc + o) * k[0] + kz) * k[1] + ky) * k[2] + kx;
                                    acc[((o * od + tz as usize) * oh + ty as usize) * ow
                                        + tx as usize] += v * w[wi];
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    acc.into_iter().map(|a| a as f32).collect()
}

/// Bilinear warp of one source feature map through a table, as the float model and the
/// quantised kernel both define it (fraction / 2^bits, invisible → 0).
pub fn warp(
    features: &[f32],
    table: &[WarpEntry],
    planes: usize,
    channels: usize,
    h: usize,
    w: usize,
) -> Vec<f32> {
    let one = (1u32 << config::WARP_FRACTION_BITS) as f32;
    let mut out = vec![0f32; channels * planes * h * w];
    for c in 0..channels {
        for j in 0..planes {
            for r in 0..h {
                for b in 0..w {
                    let e = table[j * w + b];
                    if !e.visible {
                        continue;
                    }
                    let base = (c * h + r) * w + e.column as usize;
                    let a = e.fraction as f32 / one;
                    let right = if e.fraction > 0 {
                        features[base + 1]
                    } else {
                        0.0
                    };
                    out[((c * planes + j) * h + r) * w + b] =
                        features[base] * (1.0 - a) + right * a;
                }
            }
        }
    }
    out
}

/// Every layer's weights and biases with batch norm folded in, in `LAYERS` order.
pub type FoldedWeights = Vec<(Vec<f64>, Vec<f64>)>;

/// Folds batch norm into every layer of `weights`.
pub fn fold_all(weights: &FloatWeights) -> Result<FoldedWeights> {
    LAYERS
        .iter()
        .map(|l| {
            let fl = weights
                .get(l.name)
                .ok_or_else(|| anyhow!("no float layer {}", l.name))?;
            Ok(fold_batch_norm(fl, &WeightLayout::of(l)))
        })
        .collect()
}

/// Runs the float network on u8 polar images (`views[0]` the reference).
pub fn run(weights: &FloatWeights, views: &[&[u8]]) -> Result<FloatTrace> {
    run_folded(&fold_all(weights)?, views, &mut |_, _| {})
}

/// The float network on folded weights; `hook(name, tensor)` may change every activation as it
/// is produced (`f0`…`f3` per view after ReLU, `cost`, each cost-net output after its skip
/// addition, `head`): `host-sim qdiag` rounds chosen tensors to their int8 grid with it.
pub fn run_folded(
    folded: &FoldedWeights,
    views: &[&[u8]],
    hook: &mut dyn FnMut(&str, &mut [f32]),
) -> Result<FloatTrace> {
    if folded.len() != LAYERS.len() {
        return Err(anyhow!(
            "{} folded layers, the spec has {}",
            folded.len(),
            LAYERS.len()
        ));
    }
    let nf = LAYERS
        .iter()
        .take_while(|l| l.kind == LayerKind::Conv2d)
        .count();
    let mut trace = FloatTrace::default();
    let mut feats = Vec::new();
    for image in views {
        let mut x: Vec<f32> = image.iter().map(|&u| u as f32 / 255.0).collect();
        let mut map = BTreeMap::new();
        for (l, (w, b)) in LAYERS.iter().zip(folded).take(nf) {
            x = conv(l, &x, w, b);
            if l.relu {
                x.iter_mut().for_each(|v| *v = v.max(0.0));
            }
            hook(l.name, &mut x);
            map.insert(l.name.to_string(), x.clone());
        }
        feats.push(x);
        trace.features.push(map);
    }
    let (c, n, h, w) = (
        config::FEATURE_CHANNELS,
        config::PLANES,
        config::FEATURE_RANGE_BINS,
        config::FEATURE_COLUMNS,
    );
    let warped: Vec<Vec<f32>> = (1..views.len())
        .map(|k| warp(&feats[k], &config::WARP_TABLES[k - 1], n, c, h, w))
        .collect();
    let nv = views.len() as f32;
    let mut cost = vec![0f32; c * n * h * w];
    for ch in 0..c {
        for j in 0..n {
            for i in 0..h * w {
                let r = feats[0][ch * h * w + i];
                let idx = (ch * n + j) * h * w + i;
                let (mut s, mut s2) = (r, r * r);
                for v in &warped {
                    s += v[idx];
                    s2 += v[idx] * v[idx];
                }
                let mean = s / nv;
                cost[idx] = if CostShape::EPSSN.is_mean(ch) {
                    mean.max(0.0)
                } else {
                    (s2 / nv - mean * mean).max(0.0)
                };
            }
        }
    }
    hook("cost", &mut cost);
    trace.cost_net.insert("cost".into(), cost.clone());
    let mut x = cost;
    for (l, (wt, b)) in LAYERS.iter().zip(folded).skip(nf) {
        x = match l.kind {
            LayerKind::Conv3d => conv(l, &x, wt, b),
            _ => conv_transpose(l, &x, wt, b),
        };
        if l.relu {
            x.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        if let Some(skip) = l.skip {
            let s = trace
                .cost_net
                .get(skip)
                .ok_or_else(|| anyhow!("skip {skip} missing"))?;
            x.iter_mut().zip(s).for_each(|(a, b)| *a += b);
        }
        hook(l.name, &mut x);
        trace.cost_net.insert(l.name.to_string(), x.clone());
    }
    let (e, r, a) = (
        config::DEPTH_ROWS,
        config::DEPTH_RANGE_BINS,
        config::DEPTH_COLUMNS,
    );
    trace.depth = vec![0f32; e * a];
    trace.soft_depth = vec![0f32; e * a];
    trace.far_mass = vec![0f32; e * a];
    trace.near_mass = vec![0f32; e * a];
    for row in 0..e {
        for col in 0..a {
            let logit = |i: usize| x[(row * r + i) * a + col];
            let m = (0..r).map(logit).fold(f32::NEG_INFINITY, f32::max);
            let (mut s, mut t) = (0f64, 0f64);
            for i in 0..r {
                let p = ((logit(i) - m) as f64).exp();
                s += p;
                t += p * config::DEPTH_BIN_RANGE_M[i];
            }
            let at = row * a + col;
            // The end bins may reach beyond the window; the depth is clamped to it.
            let soft = (t / s).clamp(config::R_MIN_M, config::R_MAX_M) as f32;
            let mass = |i: usize| (((logit(i) - m) as f64).exp() / s) as f32;
            let (near, far) = (mass(0), mass(r - 1));
            trace.soft_depth[at] = soft;
            trace.near_mass[at] = near;
            trace.far_mass[at] = far;
            trace.depth[at] = decide(soft, near, far, config::NO_RETURN_MASS);
        }
    }
    Ok(trace)
}
