//! The int8 EPSSN: weights from a verified blob, one static workspace, inference.
//!
//! ```text
//! u8 image ─► feature net (conv2d_s8 …) ─► features [C][H][W]      (once per frame: cacheable)
//! reference + warped sources ─► cost_volume_s8 ─► cost [C][N][H][W]
//! cost net (conv3d_s8, conv_transpose3d_s8 with skips in place) ─► head_soft_argmax_s8 ─► depth
//! ```
//!
//! Memory: the feature net's activations live inside the cost-volume buffer (it is free while
//! features are computed), skip additions overwrite the tensor they add to in place, and the
//! head is fused with the soft-argmax so the `1 × E × R × A` logits volume never exists. The
//! workspace is therefore the cost volume plus the UNet's own intermediate tensors.

use fixed::types::U16F16;

use crate::blob::{Blob, BlobError};
use crate::config::{self, LayerKind, LayerShape, LAYERS};
use crate::kernels::{
    check_layer_bounds, conv2d_s8::conv2d_s8, conv3d_s8::conv3d_s8,
    conv_transpose3d_s8::conv_transpose3d_s8, cost_volume_s8::cost_volume_s8,
    cost_volume_s8::CostShape, cost_volume_s8::SourceView, soft_argmax_s8::head_soft_argmax_s8,
    soft_argmax_s8::SoftArgmaxParams, ConvParams, ConvShape, KernelError, Skip,
};
use crate::requant::Requant;

/// The network input's zero point: int8 `q = u8 − 128`, added back by the first layer.
pub const INPUT_OFFSET: i32 = 128;

/// Why inference or model construction failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// The weight blob was refused.
    Blob(BlobError),
    /// A kernel refused its operands (a shape or bound the model should have prevented).
    Kernel(KernelError),
    /// Layer `index` could overflow its int32 accumulator or its requantisation shift.
    AccumulatorBound {
        /// Index into [`config::LAYERS`].
        index: usize,
    },
    /// A requantisation multiplier outside `[2^30, 2^31)` (and not zero).
    BadMultiplier {
        /// Index into [`config::LAYERS`], or `usize::MAX` for the cost volume.
        index: usize,
    },
    /// Source views given: 1 or 2 are supported (`MAX_VIEWS − 1`).
    SourceCount(usize),
    /// An input image or feature map has the wrong length.
    InputLength {
        /// Expected elements.
        expected: usize,
        /// Elements given.
        actual: usize,
    },
}

impl From<BlobError> for Error {
    fn from(e: BlobError) -> Self {
        Error::Blob(e)
    }
}

impl From<KernelError> for Error {
    fn from(e: KernelError) -> Self {
        Error::Kernel(e)
    }
}

/// Largest output channel count of any layer.
pub const MAX_CHANNELS: usize = {
    let mut m = 0;
    let mut i = 0;
    while i < LAYERS.len() {
        if LAYERS[i].out_channels > m {
            m = LAYERS[i].out_channels;
        }
        i += 1;
    }
    m
};

/// Layers of the feature net (the leading 2D layers).
pub const FEATURE_LAYERS: usize = {
    let mut n = 0;
    while n < LAYERS.len() && matches!(LAYERS[n].kind, LayerKind::Conv2d) {
        n += 1;
    }
    n
};

/// Where a layer's output lives in the [`Workspace`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Region {
    /// The cost-volume buffer, from `start`.
    Cost { start: usize, len: usize },
    /// The UNet buffer, from `start`.
    Unet { start: usize, len: usize },
    /// Streamed into the depth map (the fused head).
    Depth,
}

const fn str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

/// The memory plan of the cost net, computed at compile time from [`config::LAYERS`]: a layer
/// with a skip writes in place over the tensor it adds to, the last layer streams into the
/// depth map, every other layer gets its own slice of the UNet buffer.
const PLAN: ([Region; config::LAYER_COUNT], usize) = {
    let mut regions = [Region::Depth; config::LAYER_COUNT];
    let mut used = 0;
    let mut i = FEATURE_LAYERS;
    while i < LAYERS.len() {
        let l = &LAYERS[i];
        regions[i] = if i + 1 == LAYERS.len() {
            Region::Depth
        } else if let Some(skip) = l.skip {
            if str_eq(skip, "cost") {
                Region::Cost {
                    start: 0,
                    len: config::COST_VOLUME_LEN,
                }
            } else {
                let mut j = FEATURE_LAYERS;
                let mut found = Region::Depth;
                while j < i {
                    if str_eq(LAYERS[j].name, skip) {
                        found = regions[j];
                    }
                    j += 1;
                }
                found
            }
        } else {
            let r = Region::Unet {
                start: used,
                len: l.output_len(),
            };
            used += l.output_len();
            r
        };
        i += 1;
    }
    (regions, used)
};

/// Bytes of the UNet buffer.
pub const UNET_BUFFER_LEN: usize = PLAN.1;

/// Bytes of the cost-volume buffer, which also hosts the feature net's activations.
pub const COST_BUFFER_LEN: usize = {
    let features = config::INPUT_LEN + 2 * config::MAX_FEATURE_ACTIVATION;
    if features > config::COST_VOLUME_LEN {
        features
    } else {
        config::COST_VOLUME_LEN
    }
};

// The plan must give every skip a home and keep the head last and streamable.
const _: () = {
    let mut i = FEATURE_LAYERS;
    while i + 1 < LAYERS.len() {
        assert!(
            !matches!(PLAN.0[i], Region::Depth),
            "a skip names an unknown tensor"
        );
        i += 1;
    }
    assert!(FEATURE_LAYERS > 0 && FEATURE_LAYERS < LAYERS.len());
};

/// Scratch memory of one inference: put it in a `static` (firmware) or a `Box` (host).
pub struct Workspace {
    cost: [i8; COST_BUFFER_LEN],
    unet: [i8; UNET_BUFFER_LEN],
}

impl Default for Workspace {
    fn default() -> Self {
        Self::new()
    }
}

impl Workspace {
    /// A zeroed workspace.
    pub const fn new() -> Self {
        Self {
            cost: [0; COST_BUFFER_LEN],
            unet: [0; UNET_BUFFER_LEN],
        }
    }

    /// Bytes of RAM the workspace occupies.
    pub const BYTES: usize = COST_BUFFER_LEN + UNET_BUFFER_LEN;
}

/// Parameters of one layer: int8 weights borrowed from the blob, the rest copied to RAM
/// (the blob's alignment in memory is not guaranteed).
#[derive(Clone, Copy, Debug)]
struct LayerParams<'a> {
    weights: &'a [i8],
    bias: [i32; MAX_CHANNELS],
    requant: [Requant; MAX_CHANNELS],
    skip: Requant,
}

/// A verified int8 EPSSN.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    layers: [LayerParams<'a>; config::LAYER_COUNT],
    /// Cost-volume requantisation for 2 and 3 views.
    cost: [Requant; 2],
    exp: [u16; 256],
}

fn name_buf(layer: &str, suffix: &str) -> heapless::String<24> {
    let mut s = heapless::String::new();
    let _ = s.push_str(layer);
    let _ = s.push_str(suffix);
    s
}

fn valid_multiplier(r: Requant) -> bool {
    r.multiplier == 0 || r.multiplier >= (1 << 30)
}

/// The tensors a blob for the compiled configuration holds, as `(name, dtype, elements)`:
/// `<layer>.w` int8 weights (canonical layout), `<layer>.b` int32 biases, `<layer>.m` and
/// `<layer>.s` int32 per-channel multipliers and shifts, `<layer>.k` int32 `[multiplier,
/// shift]` of a skip, `cost.rq` int32 `[M2, s2, M3, s3]`, `exp` u16 `[256]`.
pub fn blob_tensor_names(mut f: impl FnMut(&str, crate::blob::Dtype, usize)) {
    use crate::blob::Dtype;
    for l in LAYERS.iter() {
        f(&name_buf(l.name, ".w"), Dtype::I8, l.weight_len());
        f(&name_buf(l.name, ".b"), Dtype::I32, l.out_channels);
        f(&name_buf(l.name, ".m"), Dtype::I32, l.out_channels);
        f(&name_buf(l.name, ".s"), Dtype::I32, l.out_channels);
        if l.skip.is_some() {
            f(&name_buf(l.name, ".k"), Dtype::I32, 2);
        }
    }
    f("cost.rq", Dtype::I32, 4);
    f("exp", Dtype::U16, 256);
}

impl<'a> Model<'a> {
    /// Builds the model from a blob: magic, version, length, CRC-32, model-spec hash, every
    /// tensor's dtype and size, every multiplier and every layer's worst-case accumulator are
    /// checked; any failure is an error and nothing is half-built.
    pub fn from_blob(bytes: &'a [u8]) -> Result<Self, Error> {
        let blob = Blob::parse(bytes, config::SPEC_HASH)?;
        let empty = LayerParams {
            weights: &[],
            bias: [0; MAX_CHANNELS],
            requant: [Requant::default(); MAX_CHANNELS],
            skip: Requant::default(),
        };
        let mut layers = [empty; config::LAYER_COUNT];
        for (index, (l, p)) in LAYERS.iter().zip(layers.iter_mut()).enumerate() {
            let oc = l.out_channels;
            p.weights = blob.i8_tensor(&name_buf(l.name, ".w"), l.weight_len())?;
            blob.read_i32(&name_buf(l.name, ".b"), &mut p.bias[..oc])?;
            let mut m = [0i32; MAX_CHANNELS];
            let mut s = [0i32; MAX_CHANNELS];
            blob.read_i32(&name_buf(l.name, ".m"), &mut m[..oc])?;
            blob.read_i32(&name_buf(l.name, ".s"), &mut s[..oc])?;
            for o in 0..oc {
                p.requant[o] = Requant {
                    multiplier: m[o],
                    shift: s[o],
                };
                if !valid_multiplier(p.requant[o]) || !p.requant[o].shift_in_range() {
                    return Err(Error::BadMultiplier { index });
                }
            }
            if l.skip.is_some() {
                let mut k = [0i32; 2];
                blob.read_i32(&name_buf(l.name, ".k"), &mut k)?;
                p.skip = Requant {
                    multiplier: k[0],
                    shift: k[1],
                };
                // The skip input is int8, so |q| · 2^left must stay below 2^31.
                if !valid_multiplier(p.skip) || !p.skip.shift_in_range() || !p.skip.fits(128) {
                    return Err(Error::BadMultiplier { index });
                }
            }
            let params = layer_params(l, p, index);
            let bound = check_layer_bounds(
                &ConvShape::from(l),
                &params,
                matches!(l.kind, LayerKind::ConvTranspose3d),
            )
            .map_err(|_| Error::AccumulatorBound { index })?;
            if !p.requant[..oc].iter().all(|r| r.fits(bound)) {
                return Err(Error::AccumulatorBound { index });
            }
        }
        let mut c = [0i32; 4];
        blob.read_i32("cost.rq", &mut c)?;
        let cost = [
            Requant {
                multiplier: c[0],
                shift: c[1],
            },
            Requant {
                multiplier: c[2],
                shift: c[3],
            },
        ];
        // X ≤ 3·3·128² < 2^18 for any int8 features.
        if !cost
            .iter()
            .all(|r| valid_multiplier(*r) && r.shift_in_range() && r.fits(1 << 18))
        {
            return Err(Error::BadMultiplier { index: usize::MAX });
        }
        let mut exp = [0u16; 256];
        blob.read_u16("exp", &mut exp)?;
        if exp[0] == 0 {
            return Err(Error::Blob(BlobError::ShapeMismatch));
        }
        Ok(Self { layers, cost, exp })
    }

    /// Features of one view (`[C][H][W]`, `config::FEATURE_LEN` elements) from its u8 polar
    /// image (`config::INPUT_LEN`). `probe` sees every layer's output.
    pub fn features_probed(
        &self,
        image: &[u8],
        ws: &mut Workspace,
        features: &mut [i8],
        mut probe: impl FnMut(&'static str, &[i8]),
    ) -> Result<(), Error> {
        expect_len(config::INPUT_LEN, image.len())?;
        expect_len(config::FEATURE_LEN, features.len())?;
        let (input, rest) = ws.cost.split_at_mut(config::INPUT_LEN);
        let (a, rest) = rest.split_at_mut(config::MAX_FEATURE_ACTIVATION);
        let b = &mut rest[..config::MAX_FEATURE_ACTIVATION];
        for (q, &u) in input.iter_mut().zip(image) {
            *q = (u ^ 0x80) as i8; // u − 128
        }
        let mut bufs = [a, b];
        for (i, l) in LAYERS.iter().enumerate().take(FEATURE_LAYERS) {
            let params = layer_params(l, &self.layers[i], i);
            let shape = ConvShape::from(l);
            let last = i + 1 == FEATURE_LAYERS;
            let [a, b] = &mut bufs;
            let (src, dst): (&[i8], &mut [i8]) = match (i == 0, i % 2 == 0) {
                (true, _) => (&*input, &mut a[..l.output_len()]),
                (false, true) => (&b[..l.input_len()], &mut a[..l.output_len()]),
                (false, false) => (&a[..l.input_len()], &mut b[..l.output_len()]),
            };
            if last {
                conv2d_s8(&shape, src, &params, features)?;
                probe(l.name, features);
            } else {
                conv2d_s8(&shape, src, &params, dst)?;
                probe(l.name, dst);
            }
        }
        Ok(())
    }

    /// Features of one view; see [`Model::features_probed`].
    pub fn features(
        &self,
        image: &[u8],
        ws: &mut Workspace,
        features: &mut [i8],
    ) -> Result<(), Error> {
        self.features_probed(image, ws, features, |_, _| {})
    }

    /// The front depth map (`[E][A]`, metres) from the reference view's features and one or
    /// two source views' features (view k rolled by k × the baseline). `probe` sees the cost
    /// volume ("cost") and every cost-net layer's output but the fused head.
    pub fn depth_from_features_probed(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut Workspace,
        depth: &mut [U16F16],
        mut probe: impl FnMut(&'static str, &[i8]),
    ) -> Result<(), Error> {
        if sources.is_empty() || sources.len() > config::MAX_VIEWS - 1 {
            return Err(Error::SourceCount(sources.len()));
        }
        expect_len(config::FEATURE_LEN, reference.len())?;
        expect_len(config::DEPTH_LEN, depth.len())?;
        let mut views = [SourceView {
            features: &[],
            warp: &[],
        }; config::MAX_VIEWS - 1];
        for (k, (v, s)) in views.iter_mut().zip(sources).enumerate() {
            expect_len(config::FEATURE_LEN, s.len())?;
            *v = SourceView {
                features: s,
                warp: &config::WARP_TABLES[k],
            };
        }
        let cost = &mut ws.cost[..config::COST_VOLUME_LEN];
        cost_volume_s8(
            &CostShape::EPSSN,
            reference,
            &views[..sources.len()],
            self.cost[sources.len() - 1],
            cost,
        )?;
        probe("cost", cost);
        let mut input = Region::Cost {
            start: 0,
            len: config::COST_VOLUME_LEN,
        };
        for (i, l) in LAYERS.iter().enumerate().skip(FEATURE_LAYERS) {
            let p = &self.layers[i];
            let params = layer_params(l, p, i);
            let shape = ConvShape::from(l);
            let out = PLAN.0[i];
            if out == Region::Depth {
                let src = region(ws, input);
                let soft = SoftArgmaxParams {
                    exp: &self.exp,
                    r_min16: U16F16::from_bits(config::R_MIN_Q16),
                    step16: U16F16::from_bits(config::DEPTH_STEP_Q16),
                };
                head_soft_argmax_s8(&shape, src, &params, &soft, depth)?;
                break;
            }
            let (src, dst) = regions(ws, input, out);
            match l.kind {
                LayerKind::Conv3d => conv3d_s8(&shape, src, &params, dst)?,
                LayerKind::ConvTranspose3d => {
                    let skip = if l.skip.is_some() {
                        Skip::InPlace { requant: p.skip }
                    } else {
                        Skip::None
                    };
                    conv_transpose3d_s8(&shape, src, &params, skip, dst)?
                }
                LayerKind::Conv2d => return Err(Error::Kernel(KernelError::NotTwoDimensional)),
            }
            probe(l.name, dst);
            input = out;
        }
        Ok(())
    }

    /// The front depth map from features; see [`Model::depth_from_features_probed`].
    pub fn depth_from_features(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut Workspace,
        depth: &mut [U16F16],
    ) -> Result<(), Error> {
        self.depth_from_features_probed(reference, sources, ws, depth, |_, _| {})
    }
}

fn layer_params<'p>(l: &LayerShape, p: &'p LayerParams<'_>, index: usize) -> ConvParams<'p> {
    ConvParams {
        weights: p.weights,
        bias: &p.bias[..l.out_channels],
        requant: &p.requant[..l.out_channels],
        input_offset: if index == 0 { INPUT_OFFSET } else { 0 },
        relu: l.relu,
    }
}

fn expect_len(expected: usize, actual: usize) -> Result<(), Error> {
    if expected == actual {
        Ok(())
    } else {
        Err(Error::InputLength { expected, actual })
    }
}

fn region(ws: &Workspace, r: Region) -> &[i8] {
    match r {
        Region::Cost { start, len } => &ws.cost[start..start + len],
        Region::Unet { start, len } => &ws.unet[start..start + len],
        Region::Depth => &[],
    }
}

/// A layer's input and output slices; the plan never makes them overlap.
fn regions(ws: &mut Workspace, input: Region, output: Region) -> (&[i8], &mut [i8]) {
    match (input, output) {
        (Region::Cost { start, len }, Region::Unet { start: o, len: ol }) => {
            (&ws.cost[start..start + len], &mut ws.unet[o..o + ol])
        }
        (Region::Unet { start, len }, Region::Cost { start: o, len: ol }) => {
            (&ws.unet[start..start + len], &mut ws.cost[o..o + ol])
        }
        (Region::Unet { start, len }, Region::Unet { start: o, len: ol }) => {
            if start < o {
                let (a, b) = ws.unet.split_at_mut(o);
                (&a[start..start + len], &mut b[..ol])
            } else {
                let (a, b) = ws.unet.split_at_mut(start);
                (&b[..len], &mut a[o..o + ol])
            }
        }
        // Cost → cost or anything → depth does not occur in a valid plan (checked at compile
        // time); give the kernel empty slices so it reports a length error.
        _ => (&[], &mut []),
    }
}
