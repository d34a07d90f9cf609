//! The float EPSSN in burn 0.22 (flex CPU backend), built at run time from a model spec, and
//! its training (`host-sim train`, in host-sim's `train` feature). The only crate of the host
//! workspace that depends on burn; `host-sim eval` scores with the f64 reference network
//! instead (`epssn-eval`).
//!
//! The network follows `weights/<spec>.json` layer by layer, so the same code builds EPSSN-S
//! and any tiny test configuration:
//!
//! 1. the u8 polar images of all views (as f32 values 0..=255) are divided by 255 inside the
//!    model (the int8 path uses `s_in = 1/255` on the raw u8, so the first conv sees `x/255`);
//! 2. feature net `spec.feature_net` (Conv2d, optional BatchNorm, optional ReLU) on every view,
//!    all views stacked along the batch axis (view-major: row `v·B + b`);
//! 3. every source view k ≥ 1 is warped through [`ModelGrids::warp_table`]`(spec, k)` with the
//!    *quantised* fraction: `w = F[c]·(1 − α/2^bits) + F[c+1]·α/2^bits`, `F[c+1]` used only
//!    when `α > 0`, invisible entries give 0 — the very table the firmware uses. The gather is
//!    written as a product with a sparse `[Wf][N·Wf]` matrix (two non-zeros per column), which
//!    gives the same sums as the two-tap gather;
//! 4. the reference is repeated over the N planes; the cost volume is the population variance
//!    over the views: `Σ_k (V_k − mean)² / n`, shape `[B][C][N][H][W]`; with the spec's
//!    `features.mean_channels` = m > 0, the last m channels are the mean `max(Σ_k V_k / n, 0)`
//!    instead (clipped at 0, like the variance, so one unsigned int8 cost volume holds both);
//! 5. cost net `spec.cost_net` (Conv3d / ConvTranspose3d, optional BatchNorm, optional ReLU,
//!    then `+ skip` where the skip names an earlier layer output or `"cost"`); the last layer is
//!    the head whose output is the logits `[B][1][E][R][A]`;
//! 6. softmax over R, depth `= clamp(Σ_i p_i · depth_bin_ranges[i], r_min, r_max)` →
//!    `[B][E][A]` metres (the end bins may reach beyond the window: `end_bin_offset`).
//!
//! # Parameter names (SafeTensors, f32, canonical burn/PyTorch layouts)
//!
//! For every layer `L` of the spec (`f0`…`f3`, `d1`, `d2`, `m0`, `u1`, `u0`, `head` for
//! EPSSN-S):
//!
//! | name | shape |
//! | --- | --- |
//! | `L.conv.weight` | conv2d `[O][I][kh][kw]`, conv3d `[O][I][kd][kh][kw]`, conv-transpose3d `[I][O][kd][kh][kw]` |
//! | `L.conv.bias` | `[O]` (always present) |
//! | `L.bn.gamma`, `L.bn.beta` | `[O]` (only when the layer has batch norm) |
//! | `L.bn.running_mean`, `L.bn.running_var` | `[O]` (inference statistics) |
//!
//! Batch norm at inference is `y = (x − running_mean) / √(running_var + ε) · gamma + beta` with
//! `ε` = [`BN_EPSILON`] (also stored in the file's metadata as `bn_epsilon`).
//!
//! # Activations
//!
//! [`FloatModel::activations`] returns every intermediate tensor by name: `input` (the /255
//! input, views stacked), the feature layers (`f0`…, shape `[V·B][C][H][W]`, view-major), `cost`
//! (the cost volume), every cost-net layer (`d1`, …, `head` = logits, each *after* its ReLU and
//! skip add), `prob` (softmax) and `depth`.

#![deny(missing_docs)]

pub mod cli;
pub use epssn_eval::data;
pub mod plot;
pub mod train;

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, bail, ensure, Context, Result};
use burn::module::{Flag, Module, Param, ParamId, RunningState};
use burn::nn::conv::{Conv2d, Conv3d, ConvTranspose3d};
use burn::nn::{BatchNorm, PaddingConfig2d, PaddingConfig3d};
use burn::tensor::activation::{relu, softmax};
use burn::tensor::{Device, Tensor, TensorData};
use epssn::grids::ModelGrids;
use epssn::spec::{LayerKind, LayerSpec, ModelSpec};
pub use epssn_reference::float::BN_EPSILON;
pub use epssn_reference::safetensors_io::{load_safetensors, save_safetensors, NamedTensor};

/// Batch-norm running-statistics momentum (`running = (1 − m)·running + m·batch`).
pub const BN_MOMENTUM: f64 = 0.1;
/// File name of the float weights inside a weights directory.
pub const WEIGHTS_FILE: &str = "model.safetensors";
/// File name of the copy of the model spec inside a weights directory.
pub const SPEC_FILE: &str = "spec.json";

/// Parses a model spec from JSON bytes (the one spec parser, [`epssn_spec::load`]).
pub fn parse_spec(bytes: &[u8]) -> Result<ModelSpec> {
    epssn_spec::load::parse_spec(bytes).map_err(|e| anyhow!(e))
}

/// Beam centres (degrees, beam 0 first) of the spec's beam table, from the one beam-table
/// parser ([`epssn_aris::beams`]).
pub fn beam_centres_deg(spec: &ModelSpec) -> Result<Vec<f64>> {
    let name = spec.sonar.beam_table.as_str();
    Ok(epssn_aris::beams::table_by_name(name)
        .with_context(|| format!("beam table {name}"))?
        .centre_deg
        .clone())
}

/// A named intermediate activation of one forward pass.
#[derive(Clone, Debug)]
pub struct Activation {
    /// Layer / tensor name (see the module docs).
    pub name: String,
    /// Shape, outermost first.
    pub shape: Vec<usize>,
    /// Values in C order.
    pub data: Vec<f32>,
}

/// The trainable layers of one spec layer (exactly one of the convolutions is present).
#[derive(Module, Debug)]
pub struct Layer {
    /// Present for `conv2d` layers.
    pub conv2d: Option<Conv2d>,
    /// Present for `conv3d` layers.
    pub conv3d: Option<Conv3d>,
    /// Present for `conv_transpose3d` layers.
    pub convt3d: Option<ConvTranspose3d>,
    /// Present when the spec asks for batch norm.
    pub bn: Option<BatchNorm>,
}

/// The trainable part of the model (what the optimizer updates).
#[derive(Module, Debug)]
pub struct EpssnNet {
    /// Feature net, in spec order.
    pub feature: Vec<Layer>,
    /// Cost net including the head, in spec order.
    pub cost: Vec<Layer>,
}

/// Everything that is not trained: spec, layer plan, warp matrices, soft-argmax bins.
#[derive(Clone, Debug)]
pub struct Statics {
    /// The model spec.
    pub spec: ModelSpec,
    feature_names: Vec<String>,
    feature_relu: Vec<bool>,
    cost_names: Vec<String>,
    cost_relu: Vec<bool>,
    cost_skip: Vec<Option<String>>,
    /// Warp matrices of source views 1 and 2: `[Wf][N·Wf]`, row = source column.
    warp: Vec<Vec<f32>>,
    feature_columns: usize,
    planes: usize,
    /// The last `mean_channels` cost channels are the views' mean, not their variance.
    mean_channels: usize,
    /// Soft-argmax bin ranges, metres.
    pub depth_bins: Vec<f32>,
    /// Range window start, metres.
    pub r_min: f32,
    /// Range window end, metres.
    pub r_max: f32,
    /// Quantisation-aware training: the int8 grid each named activation is rounded to in the
    /// forward pass (empty: none). See [`Statics::set_fake_quant`].
    fake_quant: BTreeMap<String, Grid>,
}

/// The int8 grid of one activation tensor: its scale and the codes its values may take.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Real value of one code.
    pub scale: f32,
    /// Lowest code (−128; 0 for the unsigned cost volume).
    pub lo: f32,
    /// Highest code (127; 255 for the unsigned cost volume).
    pub hi: f32,
}

/// `x` clipped to `grid`'s range and rounded to its codes in the forward pass; the gradient is
/// the clip's (the straight-through estimator: the rounding passes it unchanged).
fn fake_quant<const D: usize>(x: Tensor<D>, grid: Grid) -> Tensor<D> {
    let clipped = x.clamp(grid.lo * grid.scale, grid.hi * grid.scale);
    let rounded = clipped
        .clone()
        .div_scalar(grid.scale)
        .round()
        .mul_scalar(grid.scale);
    clipped.clone() + (rounded - clipped).detach()
}

/// The float EPSSN: trainable net plus its statics.
#[derive(Debug)]
pub struct EpssnModel {
    /// Trainable layers.
    pub net: EpssnNet,
    /// Spec-derived constants.
    pub statics: Statics,
}

/// Output of a forward pass.
pub struct ForwardOut {
    /// Front depth, `[B][E][A]` metres.
    pub depth: Tensor<3>,
    /// Head logits, `[B][1][E][R][A]`.
    pub logits: Tensor<5>,
}

impl Statics {
    /// Derives the statics of `spec`, checking that its layer chain produces the output shape.
    pub fn new(spec: &ModelSpec) -> Result<Self> {
        let beams = beam_centres_deg(spec)?;
        let grids = ModelGrids::derive(spec, &beams)
            .map_err(|e| anyhow!("cannot derive the grids of the spec: {e:?}"))?;
        let wf = grids.feature_azimuths.len();
        let n = grids.plane_elevations.len();
        ensure!(
            wf >= 2 && n >= 1,
            "spec has too few feature columns or planes"
        );
        let one = (1u32 << spec.warp.fraction_bits) as f32;
        let mut warp = Vec::new();
        for k in 1..=2 {
            let table = grids
                .warp_table(spec, k)
                .map_err(|e| anyhow!("cannot derive warp table {k}: {e:?}"))?;
            let mut m = vec![0f32; wf * n * wf];
            for (col, e) in table.iter().enumerate() {
                if !e.visible {
                    continue;
                }
                let c = e.column as usize;
                let alpha = e.fraction as f32;
                ensure!(c < wf, "warp entry column {c} outside {wf} feature columns");
                m[c * n * wf + col] = (one - alpha) / one;
                if e.fraction > 0 {
                    ensure!(c + 1 < wf, "warp entry reads column {} of {wf}", c + 1);
                    m[(c + 1) * n * wf + col] = alpha / one;
                }
            }
            warp.push(m);
        }
        ensure!(
            spec.features.mean_channels <= spec.features.channels,
            "mean_channels {} exceeds the {} feature channels",
            spec.features.mean_channels,
            spec.features.channels
        );
        let statics = Self {
            spec: spec.clone(),
            feature_names: spec
                .feature_net
                .iter()
                .map(|l| l.name.to_string())
                .collect(),
            feature_relu: spec.feature_net.iter().map(|l| l.relu).collect(),
            cost_names: spec.cost_net.iter().map(|l| l.name.to_string()).collect(),
            cost_relu: spec.cost_net.iter().map(|l| l.relu).collect(),
            cost_skip: spec
                .cost_net
                .iter()
                .map(|l| l.skip.as_ref().map(|s| s.to_string()))
                .collect(),
            warp,
            feature_columns: wf,
            planes: n,
            mean_channels: spec.features.mean_channels as usize,
            depth_bins: grids.depth_bin_ranges.iter().map(|&r| r as f32).collect(),
            r_min: grids.r_min as f32,
            r_max: grids.r_max as f32,
            fake_quant: BTreeMap::new(),
        };
        statics.check_shapes()?;
        Ok(statics)
    }

    /// Rounds the named activations (the feature layers, `cost`, the cost-net layers and
    /// `head`, each where the int8 network stores it: after its ReLU and skip add) to their
    /// int8 grids in every forward pass, so that training sees the rounding the quantised
    /// network does (quantisation-aware training, docs/QUANTISATION.md). Every grid must name
    /// an activation of the spec and have a positive scale; an empty map turns it off.
    pub fn set_fake_quant(&mut self, grids: BTreeMap<String, Grid>) -> Result<()> {
        for (name, g) in &grids {
            ensure!(
                name == "cost"
                    || self.feature_names.contains(name)
                    || self.cost_names.contains(name),
                "fake quantisation names `{name}`, which is not an activation of the spec"
            );
            ensure!(
                g.scale.is_finite() && g.scale > 0.0 && g.lo < g.hi,
                "fake quantisation grid of {name} is {g:?}"
            );
        }
        self.fake_quant = grids;
        Ok(())
    }

    /// `x` on the grid of activation `name` when quantisation-aware training is on.
    fn quantised<const D: usize>(&self, name: &str, x: Tensor<D>) -> Tensor<D> {
        match self.fake_quant.get(name) {
            Some(&g) => fake_quant(x, g),
            None => x,
        }
    }

    /// Walks the layer chain with the spec's sizes and checks every hand-over.
    fn check_shapes(&self) -> Result<()> {
        let s = &self.spec;
        ensure!(
            !s.feature_net.is_empty() && !s.cost_net.is_empty(),
            "empty network"
        );
        let mut c = 1usize;
        let mut hw = vec![s.input.range_bins as usize, s.input.beam_columns as usize];
        for l in &s.feature_net {
            ensure!(
                l.kind == LayerKind::Conv2d,
                "feature layer {} must be conv2d",
                l.name
            );
            ensure!(
                l.in_channels as usize == c,
                "layer {} expects {} channels, gets {c}",
                l.name,
                l.in_channels
            );
            hw = l.output_size(&hw).to_vec();
            c = l.out_channels as usize;
        }
        let stride = s.features.stride as usize;
        ensure!(
            c == s.features.channels as usize
                && hw == [s.input.range_bins as usize / stride, self.feature_columns],
            "feature net output {c}×{hw:?} does not match the spec's features"
        );
        let mut shapes: BTreeMap<String, (usize, Vec<usize>)> = BTreeMap::new();
        let mut dims = vec![self.planes, hw[0], hw[1]];
        shapes.insert("cost".into(), (c, dims.clone()));
        for (i, l) in s.cost_net.iter().enumerate() {
            ensure!(
                matches!(l.kind, LayerKind::Conv3d | LayerKind::ConvTranspose3d),
                "cost layer {} must be 3D",
                l.name
            );
            ensure!(
                l.in_channels as usize == c,
                "layer {} expects {} channels, gets {c}",
                l.name,
                l.in_channels
            );
            dims = l.output_size(&dims).to_vec();
            c = l.out_channels as usize;
            if let Some(skip) = &self.cost_skip[i] {
                let (sc, sd) = shapes
                    .get(skip)
                    .ok_or_else(|| anyhow!("layer {} skips from unknown tensor {skip}", l.name))?;
                ensure!(
                    *sc == c && *sd == dims,
                    "skip {skip} does not match layer {}",
                    l.name
                );
            }
            shapes.insert(l.name.to_string(), (c, dims.clone()));
        }
        let o = &s.output;
        ensure!(
            c == 1
                && dims
                    == [
                        o.elevation_rows as usize,
                        o.range_bins as usize,
                        o.azimuth_columns as usize
                    ],
            "head output {c}×{dims:?} is not 1×E×R×A of the spec"
        );
        Ok(())
    }

    /// Warps source features `[B][C][H][Wf]` of view `k` (1 or 2) onto the planes:
    /// `[B][C][N][H][Wf]`, `out[.., j, h, b] = F[h, c]·(1 − α) + F[h, c+1]·α` for the table entry
    /// `(c, α = fraction/2^bits)` of `(j, b)`, 0 where invisible.
    pub fn warp(&self, f: Tensor<4>, k: usize) -> Result<Tensor<5>> {
        let m = self
            .warp
            .get(k.wrapping_sub(1))
            .ok_or_else(|| anyhow!("no warp table for view {k}"))?;
        let [b, c, h, wf] = f.dims();
        ensure!(wf == self.feature_columns, "features have {wf} columns");
        let n = self.planes;
        let m = Tensor::<2>::from_data(TensorData::new(m.clone(), [wf, n * wf]), &f.device());
        Ok(f.reshape([b * c * h, wf])
            .matmul(m)
            .reshape([b, c, h, n, wf])
            .permute([0, 1, 3, 2, 4]))
    }

    /// Input size per view: (range bins, columns).
    pub fn input_size(&self) -> (usize, usize) {
        (
            self.spec.input.range_bins as usize,
            self.spec.input.beam_columns as usize,
        )
    }

    /// Output size: (elevation rows, azimuth columns).
    pub fn output_size(&self) -> (usize, usize) {
        (
            self.spec.output.elevation_rows as usize,
            self.spec.output.azimuth_columns as usize,
        )
    }
}

fn tensor<const D: usize>(t: &NamedTensor, device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(t.data.clone(), t.shape.clone()), device)
}

fn param<const D: usize>(t: &NamedTensor, device: &Device) -> Param<Tensor<D>> {
    let id = t.id.map(ParamId::from).unwrap_or_default();
    Param::initialized(id, tensor(t, device)).set_require_grad(true)
}

fn expect_shape(map: &BTreeMap<String, NamedTensor>, name: &str, shape: &[usize]) -> Result<()> {
    let t = map
        .get(name)
        .ok_or_else(|| anyhow!("weights have no tensor {name}"))?;
    ensure!(
        t.shape == shape && t.data.len() == shape.iter().product::<usize>(),
        "tensor {name} has shape {:?}, the spec needs {shape:?}",
        t.shape
    );
    Ok(())
}

fn arr<const N: usize>(v: &[u8]) -> Result<[usize; N]> {
    ensure!(
        v.len() == N,
        "expected {N} values per axis, got {}",
        v.len()
    );
    let mut a = [0usize; N];
    for (o, &x) in a.iter_mut().zip(v) {
        *o = x as usize;
    }
    Ok(a)
}

/// The parameter shapes of one layer: `(name, shape)`.
pub fn layer_param_shapes(l: &LayerSpec) -> Vec<(String, Vec<usize>)> {
    let (i, o) = (l.in_channels as usize, l.out_channels as usize);
    let k: Vec<usize> = l.kernel.iter().map(|&k| k as usize).collect();
    let mut w = match l.kind {
        LayerKind::ConvTranspose3d => vec![i, o],
        _ => vec![o, i],
    };
    w.extend(k);
    let n = &l.name;
    let mut v = vec![
        (format!("{n}.conv.weight"), w),
        (format!("{n}.conv.bias"), vec![o]),
    ];
    if l.batch_norm {
        for p in ["gamma", "beta", "running_mean", "running_var"] {
            v.push((format!("{n}.bn.{p}"), vec![o]));
        }
    }
    v
}

/// Every parameter name of `spec` with its shape, in spec order.
pub fn param_shapes(spec: &ModelSpec) -> Vec<(String, Vec<usize>)> {
    spec.feature_net
        .iter()
        .chain(spec.cost_net.iter())
        .flat_map(layer_param_shapes)
        .collect()
}

/// Deterministic initial weights: uniform(±1/√fan_in) for weights and biases (PyTorch's
/// default), gamma 1, beta 0, running mean 0, running var 1.
pub fn init_tensors(spec: &ModelSpec, seed: u64) -> BTreeMap<String, NamedTensor> {
    let mut rng = SplitMix64::new(seed);
    let mut map = BTreeMap::new();
    for l in spec.feature_net.iter().chain(spec.cost_net.iter()) {
        let fan_in =
            l.in_channels as usize * l.kernel.iter().map(|&k| k as usize).product::<usize>();
        let bound = 1.0 / (fan_in.max(1) as f32).sqrt();
        for (name, shape) in layer_param_shapes(l) {
            let count = shape.iter().product();
            let data: Vec<f32> = if name.ends_with(".conv.weight") || name.ends_with(".conv.bias") {
                (0..count)
                    .map(|_| (rng.unit() * 2.0 - 1.0) * bound)
                    .collect()
            } else if name.ends_with(".gamma") || name.ends_with(".running_var") {
                vec![1.0; count]
            } else {
                vec![0.0; count]
            };
            map.insert(
                name,
                NamedTensor {
                    shape,
                    data,
                    id: None,
                },
            );
        }
    }
    map
}

fn build_layer(
    l: &LayerSpec,
    map: &BTreeMap<String, NamedTensor>,
    device: &Device,
) -> Result<Layer> {
    for (name, shape) in layer_param_shapes(l) {
        expect_shape(map, &name, &shape)?;
    }
    let n = &l.name;
    let get = |s: &str| &map[&format!("{n}.{s}")];
    let weight4 = || param::<4>(get("conv.weight"), device);
    let weight5 = || param::<5>(get("conv.weight"), device);
    let bias = Some(param::<1>(get("conv.bias"), device));
    let (i, o) = (l.in_channels as usize, l.out_channels as usize);
    let mut layer = Layer {
        conv2d: None,
        conv3d: None,
        convt3d: None,
        bn: None,
    };
    match l.kind {
        LayerKind::Conv2d => {
            let p = arr::<2>(&l.padding)?;
            layer.conv2d = Some(Conv2d {
                weight: weight4(),
                bias,
                stride: arr(&l.stride)?,
                kernel_size: arr(&l.kernel)?,
                dilation: [1, 1],
                groups: 1,
                padding: PaddingConfig2d::Explicit(p[0], p[1], p[0], p[1]),
            });
        }
        LayerKind::Conv3d => {
            let p = arr::<3>(&l.padding)?;
            layer.conv3d = Some(Conv3d {
                weight: weight5(),
                bias,
                stride: arr(&l.stride)?,
                kernel_size: arr(&l.kernel)?,
                dilation: [1, 1, 1],
                groups: 1,
                padding: PaddingConfig3d::Explicit(p[0], p[1], p[2]),
            });
        }
        LayerKind::ConvTranspose3d => {
            let op = if l.output_padding.is_empty() {
                [0; 3]
            } else {
                arr::<3>(&l.output_padding)?
            };
            layer.convt3d = Some(ConvTranspose3d {
                weight: weight5(),
                bias,
                stride: arr(&l.stride)?,
                kernel_size: arr(&l.kernel)?,
                dilation: [1, 1, 1],
                groups: 1,
                padding: arr(&l.padding)?,
                padding_out: op,
                channels: [i, o],
            });
        }
    }
    if l.batch_norm {
        let running = |s: &str| {
            let t = get(s);
            let id = t.id.map(ParamId::from).unwrap_or_default();
            RunningState::with_id(id, tensor::<1>(t, device))
        };
        layer.bn = Some(BatchNorm {
            gamma: param(get("bn.gamma"), device),
            beta: param(get("bn.beta"), device),
            training: Param::<Flag>::from_bool(true),
            running_mean: running("bn.running_mean"),
            running_var: running("bn.running_var"),
            momentum: BN_MOMENTUM,
            epsilon: BN_EPSILON,
        });
    }
    Ok(layer)
}

fn export<const D: usize>(p: &Param<Tensor<D>>) -> NamedTensor {
    let t = p.val();
    NamedTensor {
        shape: t.dims().to_vec(),
        data: t
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap_or_default(),
        id: Some(p.id.val()),
    }
}

fn export_running(r: &RunningState<Tensor<1>>) -> NamedTensor {
    let t = r.value_sync();
    NamedTensor {
        shape: t.dims().to_vec(),
        data: t
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .unwrap_or_default(),
        id: None,
    }
}

impl EpssnModel {
    /// Builds the model of `spec` from named tensors on `device` (use `device.autodiff()` to
    /// train).
    pub fn from_tensors(
        spec: &ModelSpec,
        tensors: &BTreeMap<String, NamedTensor>,
        device: &Device,
    ) -> Result<Self> {
        let statics = Statics::new(spec)?;
        let feature = spec
            .feature_net
            .iter()
            .map(|l| build_layer(l, tensors, device))
            .collect::<Result<_>>()?;
        let cost = spec
            .cost_net
            .iter()
            .map(|l| build_layer(l, tensors, device))
            .collect::<Result<_>>()?;
        Ok(Self {
            net: EpssnNet { feature, cost },
            statics,
        })
    }

    /// A freshly initialised model (deterministic in `seed`).
    pub fn init(spec: &ModelSpec, seed: u64, device: &Device) -> Result<Self> {
        Self::from_tensors(spec, &init_tensors(spec, seed), device)
    }

    /// All parameters and running statistics by their documented names.
    pub fn to_tensors(&self) -> BTreeMap<String, NamedTensor> {
        let mut map = BTreeMap::new();
        let names = self
            .statics
            .feature_names
            .iter()
            .zip(&self.net.feature)
            .chain(self.statics.cost_names.iter().zip(&self.net.cost));
        for (n, layer) in names {
            let (w, b) = if let Some(c) = &layer.conv2d {
                (export(&c.weight), c.bias.as_ref().map(export))
            } else if let Some(c) = &layer.conv3d {
                (export(&c.weight), c.bias.as_ref().map(export))
            } else if let Some(c) = &layer.convt3d {
                (export(&c.weight), c.bias.as_ref().map(export))
            } else {
                continue;
            };
            map.insert(format!("{n}.conv.weight"), w);
            if let Some(b) = b {
                map.insert(format!("{n}.conv.bias"), b);
            }
            if let Some(bn) = &layer.bn {
                map.insert(format!("{n}.bn.gamma"), export(&bn.gamma));
                map.insert(format!("{n}.bn.beta"), export(&bn.beta));
                map.insert(
                    format!("{n}.bn.running_mean"),
                    export_running(&bn.running_mean),
                );
                map.insert(
                    format!("{n}.bn.running_var"),
                    export_running(&bn.running_var),
                );
            }
        }
        map
    }

    /// Forward pass. `views[k]` is `[B][1][R][W]` with raw u8 values as f32; 2 or 3 views
    /// (view 0 = reference). With `sink`, every intermediate activation is appended to it.
    pub fn forward(
        &self,
        views: &[Tensor<4>],
        sink: Option<&mut Vec<Activation>>,
    ) -> Result<ForwardOut> {
        let st = &self.statics;
        let nv = views.len();
        ensure!(
            (2..=3).contains(&nv),
            "the model takes 2 or 3 views, got {nv}"
        );
        let [b, _, _, _] = views[0].dims();
        let mut rec = Recorder { sink };
        let x = self.features(views, &mut rec)?;
        let device = x.device();
        let cost = st.cost_volume(x, b, nv)?;
        rec.record("cost", &cost);
        let logits = self.cost_net(cost, &mut rec)?;
        let [_, _, e, r, a] = logits.dims();
        ensure!(
            r == st.depth_bins.len(),
            "head gives {r} range bins, spec has {}",
            st.depth_bins.len()
        );
        let p = softmax(logits.clone(), 3);
        let bins = Tensor::<1>::from_data(TensorData::new(st.depth_bins.clone(), [r]), &device)
            .reshape([1, 1, 1, r, 1]);
        // The end bins may reach beyond the window (spec `end_bin_offset`); the depth is
        // clamped to it, as in the int8 soft-argmax.
        let depth = (p.clone() * bins)
            .sum_dim(3)
            .reshape([b, e, a])
            .clamp(st.r_min, st.r_max);
        rec.record("prob", &p);
        rec.record("depth", &depth);
        Ok(ForwardOut { depth, logits })
    }

    /// The feature net on every view, stacked along the batch (view k's samples at k·B).
    fn features(&self, views: &[Tensor<4>], rec: &mut Recorder) -> Result<Tensor<4>> {
        let st = &self.statics;
        let mut x = Tensor::cat(views.to_vec(), 0).div_scalar(255.0);
        rec.record("input", &x);
        for (i, layer) in self.net.feature.iter().enumerate() {
            let conv = layer
                .conv2d
                .as_ref()
                .ok_or_else(|| anyhow!("feature layer {i} is not conv2d"))?;
            x = conv.forward(x);
            if let Some(bn) = &layer.bn {
                x = bn.forward(x);
            }
            if st.feature_relu[i] {
                x = relu(x);
            }
            x = st.quantised(&st.feature_names[i], x);
            rec.record(&st.feature_names[i], &x);
        }
        Ok(x)
    }

    /// The cost net from the cost volume, skips added by name: the head's logits.
    fn cost_net(&self, cost: Tensor<5>, rec: &mut Recorder) -> Result<Tensor<5>> {
        let st = &self.statics;
        let mut named: BTreeMap<&str, Tensor<5>> = BTreeMap::new();
        named.insert("cost", cost.clone());
        let mut y = cost;
        for (i, layer) in self.net.cost.iter().enumerate() {
            y = if let Some(conv) = &layer.conv3d {
                conv.forward(y)
            } else if let Some(conv) = &layer.convt3d {
                conv.forward(y)
            } else {
                bail!("cost layer {i} is not 3D");
            };
            if let Some(bn) = &layer.bn {
                y = bn.forward(y);
            }
            if st.cost_relu[i] {
                y = relu(y);
            }
            if let Some(skip) = &st.cost_skip[i] {
                let s = named
                    .get(skip.as_str())
                    .ok_or_else(|| anyhow!("unknown skip {skip}"))?;
                y = y + s.clone();
            }
            y = st.quantised(&st.cost_names[i], y);
            rec.record(&st.cost_names[i], &y);
            named.insert(st.cost_names[i].as_str(), y.clone());
        }
        Ok(y)
    }
}

/// Where `forward` appends its intermediate activations, if anywhere: a tensor is read back
/// from the device only when one is kept.
struct Recorder<'a> {
    sink: Option<&'a mut Vec<Activation>>,
}

impl Recorder<'_> {
    fn record<const D: usize>(&mut self, name: &str, t: &Tensor<D>) {
        if let Some(s) = self.sink.as_deref_mut() {
            let t = t.to_data();
            s.push(Activation {
                name: name.to_string(),
                shape: t.shape().to_vec(),
                data: t.convert::<f32>().try_to_vec::<f32>().unwrap_or_default(),
            });
        }
    }
}

impl Statics {
    /// The cost volume of the features `x` of `nv` views of `b` samples each: the variance of
    /// the reference and the warped sources over the views, its last `mean_channels` channels
    /// the (ReLU'd) mean instead; on the int8 grid when training quantisation-aware.
    fn cost_volume(&self, x: Tensor<4>, b: usize, nv: usize) -> Result<Tensor<5>> {
        let [_, c, h, wf] = x.dims();
        let n = self.planes;
        let reference: Tensor<5> = x
            .clone()
            .narrow(0, 0, b)
            .unsqueeze_dim::<5>(2)
            .expand([b, c, n, h, wf]);
        let mut volumes = vec![reference];
        for k in 1..nv {
            volumes.push(self.warp(x.clone().narrow(0, k * b, b), k)?);
        }
        let mean = volumes
            .iter()
            .cloned()
            .reduce(|a, v| a + v)
            .expect("at least two views")
            .div_scalar(nv as f32);
        let variance = volumes
            .into_iter()
            .map(|v| {
                let d = v - mean.clone();
                d.clone() * d
            })
            .reduce(|a, v| a + v)
            .expect("at least two views")
            .div_scalar(nv as f32);
        let means = self.mean_channels;
        let cost = if means == 0 {
            variance
        } else {
            Tensor::cat(
                vec![
                    variance.narrow(1, 0, c - means),
                    relu(mean.narrow(1, c - means, means)),
                ],
                1,
            )
        };
        Ok(self.quantised("cost", cost))
    }
}

/// Builds a `[B][1][R][W]` tensor of raw u8 values (as f32) from per-sample images.
pub fn images_tensor(images: &[&[u8]], r: usize, w: usize, device: &Device) -> Result<Tensor<4>> {
    let mut data = Vec::with_capacity(images.len() * r * w);
    for img in images {
        ensure!(
            img.len() == r * w,
            "image has {} values, expected {r}×{w}",
            img.len()
        );
        data.extend(img.iter().map(|&v| v as f32));
    }
    Ok(Tensor::from_data(
        TensorData::new(data, [images.len(), 1, r, w]),
        device,
    ))
}

/// The model spec of a weights folder; see [`FloatModel::load`].
pub fn folder_spec(dir: &Path) -> Result<ModelSpec> {
    let manifest = dir.join("manifest.json");
    let recorded = match std::fs::read(&manifest) {
        Ok(bytes) => {
            let v: serde_json::Value = serde_json::from_slice(&bytes)
                .with_context(|| format!("parsing {}", manifest.display()))?;
            let hash = v["spec_crc32"]
                .as_str()
                .and_then(|h| u32::from_str_radix(h.trim_start_matches("0x"), 16).ok());
            hash.map(|h| (v["spec_file"].as_str().map(str::to_owned), h))
        }
        Err(_) => None,
    };
    if let Some((Some(file), hash)) = &recorded {
        // The spec files of manifests are relative to the repository root.
        let path = epssn_spec::load::repo_root().join(file);
        if let Ok(loaded) = epssn_spec::load::load_spec(&path) {
            if loaded.hash == *hash {
                return Ok(loaded.spec);
            }
        }
    }
    let own = dir.join(SPEC_FILE);
    let loaded = epssn_spec::load::load_spec(&own).map_err(|e| anyhow!(e))?;
    if let Some((_, hash)) = recorded {
        ensure!(
            loaded.hash == hash,
            "{}: CRC-32 {:#010x}, the manifest records {hash:#010x}",
            own.display(),
            loaded.hash
        );
    }
    Ok(loaded.spec)
}

/// The float model for inference on the plain flex CPU device (batch norm uses its running
/// statistics).
pub struct FloatModel {
    /// The model (in validation mode).
    pub model: EpssnModel,
    device: Device,
}

impl FloatModel {
    /// Loads `dir/spec.json` and `dir/model.safetensors`.
    ///
    /// The spec is the one the folder's `manifest.json` names (`spec_file`, relative to the
    /// repository, normally `weights/epssn-s.json`) when that file's CRC-32 is the recorded
    /// `spec_crc32`; otherwise (a model of an older spec, a folder without manifest) the
    /// folder's own `spec.json`, which must then match the recorded hash if there is one.
    pub fn load(dir: &Path) -> Result<Self> {
        let spec = folder_spec(dir)?;
        let tensors = load_safetensors(&dir.join(WEIGHTS_FILE))?;
        Self::from_tensors(&spec, &tensors)
    }

    /// Builds the inference model from named tensors.
    pub fn from_tensors(spec: &ModelSpec, tensors: &BTreeMap<String, NamedTensor>) -> Result<Self> {
        let device = Device::flex();
        let mut model = EpssnModel::from_tensors(spec, tensors, &device)?;
        model.net = model.net.valid();
        Ok(Self { model, device })
    }

    /// The spec-derived constants.
    pub fn statics(&self) -> &Statics {
        &self.model.statics
    }

    fn view_tensors(&self, samples: &[&[Vec<u8>]]) -> Result<Vec<Tensor<4>>> {
        let (r, w) = self.model.statics.input_size();
        ensure!(!samples.is_empty(), "no samples");
        let nv = samples[0].len();
        ensure!(
            (1..=3).contains(&nv),
            "1, 2 or 3 views per sample, got {nv}"
        );
        ensure!(
            samples.iter().all(|s| s.len() == nv),
            "samples differ in view count"
        );
        // One view: the reference is its own source (the single-view ablation).
        let used = nv.max(2);
        (0..used)
            .map(|k| {
                let k = if nv == 1 { 0 } else { k };
                let imgs: Vec<&[u8]> = samples.iter().map(|s| s[k].as_slice()).collect();
                images_tensor(&imgs, r, w, &self.device)
            })
            .collect()
    }

    /// Front depth `E×A` (metres, `depth[e·A + a]`) of one sample; `views[0]` is the reference
    /// (R×B u8 each); one view is fed as its own source.
    pub fn predict(&self, views: &[Vec<u8>]) -> Result<Vec<f32>> {
        Ok(self.predict_batch(&[views])?.remove(0))
    }

    /// [`predict`](Self::predict) for several samples at once (same view count).
    pub fn predict_batch(&self, samples: &[&[Vec<u8>]]) -> Result<Vec<Vec<f32>>> {
        let views = self.view_tensors(samples)?;
        per_sample(self.model.forward(&views, None)?.depth)
    }

    /// The head's logits of a batch, one `[E][R][A]` vector per sample (before the
    /// soft-argmax), for studies of the depth readout.
    pub fn logits_batch(&self, samples: &[&[Vec<u8>]]) -> Result<Vec<Vec<f32>>> {
        let views = self.view_tensors(samples)?;
        per_sample(self.model.forward(&views, None)?.logits)
    }

    /// Every named intermediate activation of one sample (see the module docs for names).
    pub fn activations(&self, views: &[Vec<u8>]) -> Result<Vec<Activation>> {
        let t = self.view_tensors(&[views])?;
        let mut sink = Vec::new();
        self.model.forward(&t, Some(&mut sink))?;
        Ok(sink)
    }
}

/// A batch tensor `[B][…]` as one vector per sample.
fn per_sample<const D: usize>(t: Tensor<D>) -> Result<Vec<Vec<f32>>> {
    let len = t.dims()[1..].iter().product::<usize>().max(1);
    let data = t
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow!("{e:?}"))?;
    Ok(data.chunks(len).map(<[f32]>::to_vec).collect())
}

/// The deterministic generator (SplitMix64) of initialisation and shuffling: the host's one
/// test-data generator, [`epssn_sim::synthetic::Rng`].
pub use epssn_sim::synthetic::Rng as SplitMix64;

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> ModelSpec {
        parse_spec(include_bytes!("../../../../weights/epssn-s.json")).unwrap()
    }

    #[test]
    fn warp_is_the_two_tap_table_gather() {
        let spec = spec();
        let st = Statics::new(&spec).unwrap();
        let grids = ModelGrids::derive(&spec, &beam_centres_deg(&spec).unwrap()).unwrap();
        let (c, h, wf, n) = (2, 3, st.feature_columns, st.planes);
        let mut rng = SplitMix64::new(5);
        let f: Vec<f32> = (0..c * h * wf).map(|_| rng.unit() * 4.0 - 2.0).collect();
        let device = Device::flex();
        let t = Tensor::<4>::from_data(TensorData::new(f.clone(), [1, c, h, wf]), &device);
        for k in 1..=2 {
            let table = grids.warp_table(&spec, k).unwrap();
            let got = st
                .warp(t.clone(), k)
                .unwrap()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            let mut visible = 0;
            for ci in 0..c {
                for j in 0..n {
                    for hi in 0..h {
                        for b in 0..wf {
                            let e = table[j * wf + b];
                            let at = |col: usize| f[(ci * h + hi) * wf + col];
                            let want = if !e.visible {
                                0.0
                            } else {
                                visible += 1;
                                let a = e.fraction as f32 / 256.0;
                                let right = if e.fraction > 0 {
                                    at(e.column as usize + 1) * a
                                } else {
                                    0.0
                                };
                                at(e.column as usize) * (1.0 - a) + right
                            };
                            let g = got[((ci * n + j) * h + hi) * wf + b];
                            assert!(
                                (g - want).abs() <= 1e-6,
                                "view {k} c{ci} j{j} h{hi} b{b}: {g} vs {want}"
                            );
                        }
                    }
                }
            }
            assert!(
                visible > 0 && visible < c * n * h * wf,
                "the table has visible and invisible entries"
            );
        }
    }

    #[test]
    fn fake_quant_rounds_to_the_grid_and_passes_the_gradient_inside_it() {
        let device = Device::flex().autodiff();
        let grid = Grid {
            scale: 0.5,
            lo: -128.0,
            hi: 127.0,
        };
        let x = [0.2f32, 0.26, -0.74, 63.4, 64.0, -70.0];
        let t =
            Tensor::<1>::from_data(TensorData::new(x.to_vec(), [x.len()]), &device).require_grad();
        let y = fake_quant(t.clone(), grid);
        let got = y.clone().into_data().try_to_vec::<f32>().unwrap();
        // Rounded to multiples of 0.5 (ties away from zero is not needed: none is a tie), the
        // range [−64, 63.5] clipping the last two.
        assert_eq!(got, vec![0.0, 0.5, -0.5, 63.5, 63.5, -64.0]);
        let grads = y.sum().backward();
        let g = t
            .grad(&grads)
            .unwrap()
            .into_data()
            .try_to_vec::<f32>()
            .unwrap();
        assert_eq!(g, vec![1.0, 1.0, 1.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn set_fake_quant_refuses_unknown_tensors_and_bad_scales() {
        let mut st = Statics::new(&spec()).unwrap();
        let g = Grid {
            scale: 0.1,
            lo: 0.0,
            hi: 255.0,
        };
        assert!(st
            .set_fake_quant(BTreeMap::from([("cost".into(), g)]))
            .is_ok());
        assert!(st
            .set_fake_quant(BTreeMap::from([("nope".into(), g)]))
            .is_err());
        let bad = Grid { scale: 0.0, ..g };
        assert!(st
            .set_fake_quant(BTreeMap::from([("cost".into(), bad)]))
            .is_err());
    }

    #[test]
    fn epssn_s_has_the_documented_parameters() {
        let spec = spec();
        let shapes: BTreeMap<String, Vec<usize>> = param_shapes(&spec).into_iter().collect();
        assert_eq!(shapes["f0.conv.weight"], vec![8, 1, 3, 3]);
        assert_eq!(shapes["d2.conv.weight"], vec![16, 8, 3, 3, 3]);
        assert_eq!(shapes["u1.conv.weight"], vec![16, 8, 3, 3, 3]);
        assert_eq!(shapes["head.conv.weight"], vec![8, 1, 4, 1, 8]);
        assert!(shapes.contains_key("m0.bn.running_var"));
        assert!(!shapes.contains_key("f3.bn.gamma"));
        // A spec whose head does not give E×R×A is refused.
        let mut bad = spec.clone();
        bad.output.range_bins = 32;
        assert!(Statics::new(&bad).is_err());
    }

    #[test]
    fn cost_volume_is_the_population_variance_of_reference_and_warped_source() {
        // Single-view ablation: the reference is its own source, so the cost at (c, j, h, b) is
        // the variance of {F[h, b], warp(F)[j, h, b]} = ((F − warp(F)) / 2)², and in the spec's
        // mean channels (the last ones) their mean clipped at 0, max((F + warp(F)) / 2, 0).
        let spec = spec();
        let model = FloatModel::from_tensors(&spec, &init_tensors(&spec, 1)).unwrap();
        let st = model.statics();
        let grids = ModelGrids::derive(&spec, &beam_centres_deg(&spec).unwrap()).unwrap();
        let table = grids.warp_table(&spec, 1).unwrap();
        let (r, w) = st.input_size();
        let mut rng = SplitMix64::new(9);
        let img: Vec<u8> = (0..r * w).map(|_| (rng.next_u64() & 0xff) as u8).collect();
        let acts = model.activations(&[img]).unwrap();
        let get = |n: &str| acts.iter().find(|a| a.name == n).unwrap();
        let (f3, cost) = (get("f3"), get("cost"));
        let [c, n, h, wf] = [8, 16, 64, 16];
        assert_eq!(f3.shape, vec![2, c, h, wf]);
        assert_eq!(cost.shape, vec![1, c, n, h, wf]);
        let means = spec.features.mean_channels as usize;
        let mut nonzero = 0;
        for ci in 0..c {
            for j in 0..n {
                for hi in 0..h {
                    for b in 0..wf {
                        let at = |col: usize| f3.data[(ci * h + hi) * wf + col];
                        let e = table[j * wf + b];
                        let warped = if e.visible {
                            let a = e.fraction as f32 / 256.0;
                            let right = if e.fraction > 0 {
                                at(e.column as usize + 1) * a
                            } else {
                                0.0
                            };
                            at(e.column as usize) * (1.0 - a) + right
                        } else {
                            0.0
                        };
                        let want = if ci + means >= c {
                            ((at(b) + warped) / 2.0).max(0.0)
                        } else {
                            ((at(b) - warped) / 2.0).powi(2)
                        };
                        let got = cost.data[((ci * n + j) * h + hi) * wf + b];
                        assert!((got - want).abs() <= 1e-5 * (1.0 + want), "{got} vs {want}");
                        nonzero += usize::from(got > 0.0);
                    }
                }
            }
        }
        assert!(nonzero > 0);
    }
}
