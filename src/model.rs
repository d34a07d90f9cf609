//! The int8 EPSSN: weights from a verified blob, one static workspace, inference.
//!
//! ```text
//! u8 image ─► feature net (conv2d_s8 …) ─► features [C][H][W]      (once per frame: cacheable)
//! reference + warped sources ─► cost_volume_s8 ─► cost [C][N][H][W]
//! cost net (conv3d_s8, conv_transpose3d_s8 with skips in place) ─► head_soft_argmax_s8 ─► depth
//! ```
//!
//! Memory: the firmware runs the *streamed* path ([`Workspace`], [`WORKSPACE_LEN`] bytes). The
//! feature net computes [`FEATURE_CHUNKS`] row chunks per layer from line buffers (MCUNetV2
//! style) instead of whole activations. The cost volume never exists whole: d1 reads windows
//! of `kd` cost-volume planes × a tile of rows computed on the fly; u0 is computed one output
//! plane at a time, its skip (a cost-volume plane, recomputed: the price is one more cost
//! volume's instructions) written first into the plane buffer and the transposed convolution
//! added in place; each u0 plane goes straight through the head, which is fused with the
//! soft-argmax so the `1 × E × R × A` logits volume never exists either. Only d1/u1, d2 and m0
//! are whole. Sub-volumes carry explicit zero rows/planes where the whole tensor has padding,
//! which adds exactly 0, so the bits equal those of the plain whole-tensor twin
//! ([`WholeWorkspace`], [`Model::depth_from_features_whole_probed`]) that tests compare with.

use core::ops::Range;

use fixed::types::U16F16;

use crate::blob::{Blob, BlobError};
use crate::config::{self, LayerKind, LayerShape, LAYERS};
use crate::kernels::LineScratch;
use crate::kernels::{
    check_layer_bounds, conv2d_s8::conv2d_s8, conv2d_s8::conv2d_s8_checked, conv3d_s8::conv3d_s8,
    conv3d_s8::conv3d_s8_checked, conv_transpose3d_s8::conv_transpose3d_s8,
    conv_transpose3d_s8::conv_transpose3d_s8_checked, cost_volume_s8::cost_volume_s8,
    cost_volume_s8::CostShape, cost_volume_s8::CostVolume, cost_volume_s8::SourceView,
    head_s8::head_step_s8, head_s8::head_steps, soft_argmax_s8::head_soft_argmax_s8,
    soft_argmax_s8::soft_argmax_s8, soft_argmax_s8::SoftArgmaxParams,
    soft_argmax_s8::SoftArgmaxShape, CheckedParams, ConvParams, ConvShape, KernelError, Skip,
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

/// Bytes of the UNet buffer (d1, d2, m0 for EPSSN-S; u1 writes over d1).
pub const UNET_BUFFER_LEN: usize = PLAN.1;

/// Bytes of the whole-tensor path's cost-volume buffer, which also hosts the feature net's
/// activations there.
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

/// Scratch of the whole-tensor reference path ([`Model::features_whole_probed`],
/// [`Model::depth_from_features_whole_probed`]): the full cost volume plus the UNet buffer.
/// It is the plain twin the streamed [`Workspace`] is tested against; put it in a `Box`.
pub struct WholeWorkspace {
    cost: [i8; COST_BUFFER_LEN],
    unet: [i8; UNET_BUFFER_LEN],
    logits: [i8; WHOLE_LOGITS_LEN],
}

/// The whole `[E][R][A]` logits volume, which the whole-tensor path needs only when the head
/// is not fused with the soft-argmax.
const WHOLE_LOGITS_LEN: usize = if HEAD_FUSED {
    0
} else {
    config::DEPTH_LEN * config::DEPTH_RANGE_BINS
};

impl Default for WholeWorkspace {
    fn default() -> Self {
        Self::new()
    }
}

impl WholeWorkspace {
    /// A zeroed workspace.
    pub const fn new() -> Self {
        Self {
            cost: [0; COST_BUFFER_LEN],
            unet: [0; UNET_BUFFER_LEN],
            logits: [0; WHOLE_LOGITS_LEN],
        }
    }

    /// Bytes of RAM the workspace occupies.
    pub const BYTES: usize = COST_BUFFER_LEN + UNET_BUFFER_LEN + WHOLE_LOGITS_LEN;
}

/// Parameters of one layer: int8 weights borrowed from the blob, the rest copied to RAM
/// (the blob's alignment in memory is not guaranteed).
#[derive(Clone, Copy, Debug)]
struct LayerParams<'a> {
    weights: &'a [i8],
    bias: [i32; MAX_CHANNELS],
    requant: [Requant; MAX_CHANNELS],
    skip: Requant,
    /// Worst-case accumulator ([`check_layer_bounds`]), verified in [`Model::from_blob`].
    bound: i64,
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
            bound: 0,
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
            p.bound = bound;
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

    /// Features of one view through the whole-tensor reference path: every layer's full
    /// output is materialised and shown to `probe`. Same bits as [`Model::features_probed`].
    pub fn features_whole_probed(
        &self,
        image: &[u8],
        ws: &mut WholeWorkspace,
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

    /// The front depth map through the whole-tensor reference path: the full cost volume
    /// and every cost-net layer's full output exist and are shown to `probe` ("cost", then
    /// each layer but the fused head). Same bits as [`Model::depth_from_features_probed`].
    pub fn depth_from_features_whole_probed(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut WholeWorkspace,
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
                let soft = self.soft();
                if HEAD_FUSED {
                    head_soft_argmax_s8(&shape, region(ws, input), &params, &soft, depth)?;
                } else {
                    // The plain twin: the whole logits volume, then the soft-argmax.
                    let WholeWorkspace { cost, unet, logits } = ws;
                    let src = match input {
                        Region::Cost { start, len } => &cost[start..start + len],
                        Region::Unet { start, len } => &unet[start..start + len],
                        Region::Depth => &[][..],
                    };
                    conv_transpose3d_s8(&shape, src, &params, Skip::None, logits)?;
                    soft_argmax_s8(&head_soft_shape(config::DEPTH_ROWS), logits, &soft, depth)?;
                }
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
}

// ---------------------------------------------------------------------------------------------
// Streamed execution (what the firmware runs): no tensor bigger than the UNet's own is ever
// whole. The feature net runs row chunk by row chunk through line buffers; d1 reads a small
// window of cost-volume planes and rows computed on the fly; u0 is computed one output plane at
// a time (its skip, a cost-volume plane, recomputed into the output plane) and fed straight to
// the fused head. Every kernel call sees a sub-volume with explicit zero rows/planes where the
// whole tensor has padding, which adds exactly 0 to every accumulator: the bits are those of
// the whole-tensor path.
// ---------------------------------------------------------------------------------------------

/// Chunks each feature layer's output is computed in (rows per chunk = output rows / this).
pub const FEATURE_CHUNKS: usize = 8;

/// Row tiles of d1's output (rows per tile = d1's output rows / this).
pub const COST_ROW_CHUNKS: usize = 2;

/// Index of d1, the first cost-net layer (reads the cost volume).
const D1: usize = FEATURE_LAYERS;
/// Index of the head (last layer, streamed into the depth map).
const HEAD: usize = config::LAYER_COUNT - 1;
/// Index of u0, the layer whose skip is the cost volume (just before the head).
const U0: usize = HEAD - 1;

/// Line buffers of one feature layer: a window of `window_rows` input rows
/// (`[C_in][window_rows][W_in]`) and one chunk of `rows` output rows (`[C_out][rows][W_out]`).
#[derive(Clone, Copy, Debug)]
struct RowStream {
    rows: usize,
    window_rows: usize,
    window_start: usize,
    chunk_start: usize,
}

/// Line buffers of every feature layer, packed from offset 0 of the workspace; and their
/// total length.
const FEATURE_STREAMS: ([RowStream; FEATURE_LAYERS], usize) = {
    let empty = RowStream {
        rows: 0,
        window_rows: 0,
        window_start: 0,
        chunk_start: 0,
    };
    let mut s = [empty; FEATURE_LAYERS];
    let mut used = 0;
    let mut i = 0;
    while i < FEATURE_LAYERS {
        let l = &LAYERS[i];
        let rows = l.out_size[0] / FEATURE_CHUNKS;
        let window_rows = l.stride[0] as usize * (rows - 1) + l.kernel[0] as usize;
        let window_start = used;
        used += l.in_channels * window_rows * l.in_size[1];
        let chunk_start = used;
        used += l.out_channels * rows * l.out_size[1];
        s[i] = RowStream {
            rows,
            window_rows,
            window_start,
            chunk_start,
        };
        i += 1;
    }
    (s, used)
};

/// Rows per tile of d1's output and the cost-volume rows (`stride·(rows − 1) + kernel`) a
/// tile reads.
const D1_ROWS: usize = LAYERS[D1].out_size[1] / COST_ROW_CHUNKS;
const D1_WINDOW_ROWS: usize =
    LAYERS[D1].stride[1] as usize * (D1_ROWS - 1) + LAYERS[D1].kernel[1] as usize;
/// d1's input window `[C][kd][D1_WINDOW_ROWS][W]` and one output tile `[O][1][D1_ROWS][W_out]`.
const D1_WINDOW_LEN: usize =
    LAYERS[D1].in_channels * LAYERS[D1].kernel[0] as usize * D1_WINDOW_ROWS * LAYERS[D1].in_size[2];
const D1_TILE_LEN: usize = LAYERS[D1].out_channels * D1_ROWS * LAYERS[D1].out_size[2];

/// Input planes one output plane of u0 reads: `ceil(kernel / stride)`.
const U0_MAX_IN_PLANES: usize =
    (LAYERS[U0].kernel[0] as usize).div_ceil(LAYERS[U0].stride[0] as usize);
/// One output plane of u0 `[O][1][H][W]` (which first holds the cost-volume plane of its skip),
/// and u0's input planes gathered for it `[I][U0_MAX_IN_PLANES][H_in][W_in]`.
const U0_PLANE_LEN: usize =
    LAYERS[U0].out_channels * LAYERS[U0].out_size[1] * LAYERS[U0].out_size[2];
const U0_GATHER_LEN: usize =
    LAYERS[U0].in_channels * U0_MAX_IN_PLANES * LAYERS[U0].in_size[1] * LAYERS[U0].in_size[2];

/// `(first input plane, input planes, padding, output padding)` on the plane axis of the
/// transposed convolution that gives exactly output plane `t` of u0 from input planes
/// `first..first + planes` (planes past the end read as zeros): the input planes `i` with a tap
/// `k = t + pad − stride·i` inside the kernel.
const fn u0_plane(t: usize) -> (usize, usize, usize, usize) {
    let l = &LAYERS[U0];
    let (k, s, p) = (
        l.kernel[0] as usize,
        l.stride[0] as usize,
        l.padding[0] as usize,
    );
    let last = (t + p) / s;
    let first = if t + p + 1 >= k {
        (t + p + 1 - k).div_ceil(s)
    } else {
        0
    };
    let planes = last + 1 - first;
    let pad = t + p - s * first;
    // One output plane: (planes − 1)·s + k + out_pad − 2·pad = 1.
    let out_pad = 1 + 2 * pad - k - (planes - 1) * s;
    (first, planes, pad, out_pad)
}

/// Whether the head is fused with the soft-argmax ([`head_soft_argmax_s8`]: kernel == stride,
/// no padding, one output channel, so each logit depends on one input voxel). Otherwise the
/// streamed path computes it a step at a time (`stream_u0_head`) with the overlapping head
/// fused with the soft-argmax ([`head_step_s8`]).
const HEAD_FUSED: bool = {
    let h = &LAYERS[HEAD];
    let mut fused = h.out_channels == 1;
    let mut a = 0;
    while a < 3 {
        fused = fused && h.kernel[a] == h.stride[a] && h.padding[a] == 0;
        fused = fused && h.output_padding[a] == 0;
        a += 1;
    }
    fused
};
/// u0 planes a step of the general head reads: `P = ceil(kernel / stride)` on the plane axis
/// (as [`crate::kernels::head_s8::head_step_planes`]).
const HEAD_IN_PLANES: usize =
    (LAYERS[HEAD].kernel[0] as usize).div_ceil(LAYERS[HEAD].stride[0] as usize);
/// u0's output planes in the streamed path: one plane for the fused head; for the general
/// head the ring of the last [`HEAD_IN_PLANES`] planes `[P][C][H][W]` (plane `t` in slot
/// `t mod P`) that u0 writes into and the head reads.
const U0_OUT_LEN: usize = if HEAD_FUSED {
    U0_PLANE_LEN
} else {
    HEAD_IN_PLANES * U0_PLANE_LEN
};

/// The soft-argmax shape of `rows` depth rows.
const fn head_soft_shape(rows: usize) -> SoftArgmaxShape {
    SoftArgmaxShape {
        rows,
        bins: config::DEPTH_RANGE_BINS,
        columns: config::DEPTH_COLUMNS,
    }
}

/// Where the d1/u1 tensor lives: the streamed phases' scratch starts after it.
const LIVE_END: usize = match (PLAN.0[D1], PLAN.0[U0 - 1]) {
    (Region::Unet { start, len }, Region::Unet { start: s2, len: l2 }) => {
        if start + len > s2 + l2 {
            start + len
        } else {
            s2 + l2
        }
    }
    _ => 0,
};

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Bytes of the streamed [`Workspace`]: the largest of the feature net's line buffers, the
/// UNet buffer, and the d1/u1 tensor plus the larger of d1's window and u0's plane buffers.
pub const WORKSPACE_LEN: usize = max(
    max(FEATURE_STREAMS.1, UNET_BUFFER_LEN),
    LIVE_END + max(D1_WINDOW_LEN + D1_TILE_LEN, U0_GATHER_LEN + U0_OUT_LEN),
);

// The streamed plan's assumptions about the network, checked against the spec at compile time.
const _: () = {
    let mut i = 0;
    while i < FEATURE_LAYERS {
        let l = &LAYERS[i];
        let s = &FEATURE_STREAMS.0[i];
        assert!(s.rows > 0 && s.rows * FEATURE_CHUNKS == l.out_size[0]);
        assert!(l.in_size[2] == 1 && l.out_size[2] == 1 && l.kernel[2] == 1);
        assert!(l.padding[0] < l.kernel[0]);
        if i > 0 {
            let p = &LAYERS[i - 1];
            assert!(p.out_channels == l.in_channels);
            assert!(p.out_size[0] == l.in_size[0] && p.out_size[1] == l.in_size[1]);
        }
        i += 1;
    }
    assert!(LAYERS[0].input_len() == config::INPUT_LEN);
    assert!(LAYERS[FEATURE_LAYERS - 1].output_len() == config::FEATURE_LEN);
    // Padding of the network input is the value −INPUT_OFFSET, which must be an int8.
    assert!(INPUT_OFFSET == 128);
    // d1 reads the cost volume and writes to the UNet buffer, one output plane per step.
    let d1 = &LAYERS[D1];
    assert!(matches!(d1.kind, LayerKind::Conv3d) && d1.skip.is_none());
    assert!(d1.in_channels == config::FEATURE_CHANNELS);
    assert!(d1.input_len() == config::COST_VOLUME_LEN);
    assert!(d1.in_size[0] == config::PLANES && d1.in_size[1] == config::FEATURE_RANGE_BINS);
    assert!(D1_ROWS > 0 && D1_ROWS * COST_ROW_CHUNKS == d1.out_size[1]);
    assert!(d1.padding[0] < d1.kernel[0] && d1.padding[1] < d1.kernel[1]);
    assert!(matches!(PLAN.0[D1], Region::Unet { .. }));
    // u0 adds the cost volume and feeds the head; nothing else reads the cost volume.
    let u0 = &LAYERS[U0];
    assert!(matches!(u0.kind, LayerKind::ConvTranspose3d));
    assert!(matches!(PLAN.0[U0], Region::Cost { .. }));
    assert!(
        u0.out_channels == config::FEATURE_CHANNELS && u0.output_len() == config::COST_VOLUME_LEN
    );
    assert!(u0.out_size[0] == config::PLANES && u0.out_size[1] == config::FEATURE_RANGE_BINS);
    assert!(matches!(PLAN.0[U0 - 1], Region::Unet { .. }));
    let mut j = D1;
    while j < U0 {
        assert!(matches!(PLAN.0[j], Region::Unet { .. }));
        j += 1;
    }
    let mut t = 0;
    while t < u0.out_size[0] {
        let (_, planes, _, out_pad) = u0_plane(t);
        assert!(planes > 0 && planes <= U0_MAX_IN_PLANES);
        assert!(out_pad < u0.stride[0] as usize);
        t += 1;
    }
    // The fused head turns one u0 plane into `kernel[0]` whole depth rows; the general head
    // (head_step_s8) turns the last `P` u0 planes into the `stride[0]` depth rows
    // `stride·t − padding + 0..stride` of step t.
    let head = &LAYERS[HEAD];
    assert!(matches!(head.kind, LayerKind::ConvTranspose3d) && head.out_channels == 1);
    assert!(head.in_size[0] == u0.out_size[0] && head.in_channels == u0.out_channels);
    assert!(head.in_size[1] == u0.out_size[1] && head.in_size[2] == u0.out_size[2]);
    assert!(head.out_size[0] == config::DEPTH_ROWS);
    assert!(head.out_size[1] == config::DEPTH_RANGE_BINS);
    assert!(head.out_size[2] == config::DEPTH_COLUMNS);
    assert!(head.out_size[0] * head.out_size[2] == config::DEPTH_LEN);
    assert!(HEAD_IN_PLANES * (head.stride[0] as usize) >= head.kernel[0] as usize);
    assert!(LIVE_END > 0);
};

/// Scratch memory of one streamed inference ([`WORKSPACE_LEN`] bytes): put it in a `static`
/// (firmware) or a `Box` (host). Only scratch: nothing in it survives from one call to the
/// next.
pub struct Workspace {
    buf: [i8; WORKSPACE_LEN],
    /// The line engine's weights, line and accumulators, reused by every kernel call.
    scratch: LineScratch,
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
            buf: [0; WORKSPACE_LEN],
            scratch: LineScratch::new(),
        }
    }

    /// Bytes of RAM the workspace occupies.
    pub const BYTES: usize = core::mem::size_of::<Self>();
}

/// What a feature layer's line buffers hold: input rows `lo..lo + filled` (virtual rows:
/// negative or past the end are padding) and which output chunk.
#[derive(Clone, Copy)]
struct StreamState {
    lo: isize,
    filled: usize,
    chunk: Option<usize>,
}

/// `(&buf[a], &mut buf[b])` for disjoint ranges; empty slices (which the kernels refuse with
/// a length error) if they overlap or leave `buf`, which the compile-time plan rules out.
fn disjoint(buf: &mut [i8], a: Range<usize>, b: Range<usize>) -> (&[i8], &mut [i8]) {
    if a.end <= b.start && b.end <= buf.len() {
        let (x, y) = buf.split_at_mut(b.start);
        match (x.get(a), y.get_mut(..b.end - b.start)) {
            (Some(x), Some(y)) => (x, y),
            _ => (&[], &mut []),
        }
    } else if b.end <= a.start && a.end <= buf.len() {
        let (x, y) = buf.split_at_mut(a.start);
        match (y.get(..a.end - a.start), x.get_mut(b)) {
            (Some(y), Some(x)) => (y, x),
            _ => (&[], &mut []),
        }
    } else {
        (&[], &mut [])
    }
}

/// `name` of a fused stage, e.g. "f0+f1+f2+f3" (cut at 32 bytes).
fn stage_name(prefix: &str, layers: Range<usize>) -> heapless::String<32> {
    let mut s = heapless::String::new();
    let _ = s.push_str(prefix);
    for (n, l) in LAYERS[layers].iter().enumerate() {
        if n > 0 || !prefix.is_empty() {
            let _ = s.push('+');
        }
        let _ = s.push_str(l.name);
    }
    s
}

impl<'a> Model<'a> {
    /// Layer `index`'s parameters with the accumulator bound verified in
    /// [`Model::from_blob`], for the kernels' checked entries.
    fn checked(&self, index: usize) -> CheckedParams<'_> {
        let l = &LAYERS[index];
        let p = &self.layers[index];
        CheckedParams::verified(
            &ConvShape::from(l),
            layer_params(l, p, index),
            matches!(l.kind, LayerKind::ConvTranspose3d),
            p.bound,
        )
    }

    fn soft(&self) -> SoftArgmaxParams<'_> {
        SoftArgmaxParams {
            exp: &self.exp,
            r_min16: U16F16::from_bits(config::R_MIN_Q16),
            step16: U16F16::from_bits(config::DEPTH_STEP_Q16),
            end_offset: config::END_BIN_OFFSET as u16,
        }
    }

    /// Features of one view (`[C][H][W]`, `config::FEATURE_LEN` elements) from its u8 polar
    /// image (`config::INPUT_LEN`), streamed: each layer computes [`FEATURE_CHUNKS`] chunks of
    /// output rows from a line buffer of input rows that the layer before fills on demand, so
    /// no intermediate activation is ever whole. `probe` sees the features once, under the
    /// name of the fused stage ("f0+f1+f2+f3").
    pub fn features_probed(
        &self,
        image: &[u8],
        ws: &mut Workspace,
        features: &mut [i8],
        mut probe: impl FnMut(&str, &[i8]),
    ) -> Result<(), Error> {
        expect_len(config::INPUT_LEN, image.len())?;
        expect_len(config::FEATURE_LEN, features.len())?;
        let mut state = [StreamState {
            lo: 0,
            filled: 0,
            chunk: None,
        }; FEATURE_LAYERS];
        let last = FEATURE_LAYERS - 1;
        let l = &LAYERS[last];
        let s = FEATURE_STREAMS.0[last];
        let plane = l.out_size[0] * l.out_size[1];
        let n = s.rows * l.out_size[1];
        for j in 0..FEATURE_CHUNKS {
            self.feature_chunk(last, j, image, &mut ws.buf, &mut ws.scratch, &mut state)?;
            for (c, dst) in features.chunks_exact_mut(plane).enumerate() {
                let src = s.chunk_start + c * n;
                dst[j * n..(j + 1) * n].copy_from_slice(&ws.buf[src..src + n]);
            }
        }
        probe(&stage_name("", 0..FEATURE_LAYERS), features);
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

    /// Computes output chunk `j` of feature layer `l` into its chunk buffer, first filling the
    /// layer's input window with the rows it needs (from the image, padding, or the previous
    /// layer's chunks, computed on demand).
    fn feature_chunk(
        &self,
        l: usize,
        j: usize,
        image: &[u8],
        buf: &mut [i8],
        scratch: &mut LineScratch,
        state: &mut [StreamState; FEATURE_LAYERS],
    ) -> Result<(), Error> {
        let layer = &LAYERS[l];
        let s = FEATURE_STREAMS.0[l];
        let (c_in, h_in, w_in) = (layer.in_channels, layer.in_size[0], layer.in_size[1]);
        let r = s.window_rows;
        let need_lo = (layer.stride[0] as usize * j * s.rows) as isize - layer.padding[0] as isize;
        // Slide the window: keep the rows this chunk shares with the previous one.
        let st = state[l];
        let drop = need_lo - st.lo;
        let mut filled = if drop < 0 || drop as usize >= st.filled {
            0
        } else {
            let d = drop as usize;
            for c in 0..c_in {
                let base = s.window_start + c * r * w_in;
                buf.copy_within(base + d * w_in..base + st.filled * w_in, base);
            }
            st.filled - d
        };
        let params = layer_params(layer, &self.layers[l], l);
        let checked = self.checked(l);
        // Padding is the value that the input offset turns into 0.
        let pad = (-params.input_offset) as i8;
        while filled < r {
            let row = need_lo + filled as isize;
            if row < 0 || row as usize >= h_in {
                for c in 0..c_in {
                    let at = s.window_start + (c * r + filled) * w_in;
                    buf[at..at + w_in].fill(pad);
                }
                filled += 1;
                continue;
            }
            let row = row as usize;
            let n = if l == 0 {
                let n = (r - filled).min(h_in - row);
                for c in 0..c_in {
                    let at = s.window_start + (c * r + filled) * w_in;
                    let from = (c * h_in + row) * w_in;
                    for (q, &u) in buf[at..at + n * w_in]
                        .iter_mut()
                        .zip(&image[from..from + n * w_in])
                    {
                        *q = (u ^ 0x80) as i8; // u − INPUT_OFFSET
                    }
                }
                n
            } else {
                let p = FEATURE_STREAMS.0[l - 1];
                let jj = row / p.rows;
                if state[l - 1].chunk != Some(jj) {
                    self.feature_chunk(l - 1, jj, image, buf, scratch, state)?;
                }
                let n = (r - filled).min((jj + 1) * p.rows - row);
                for c in 0..c_in {
                    let from = p.chunk_start + (c * p.rows + row - jj * p.rows) * w_in;
                    let at = s.window_start + (c * r + filled) * w_in;
                    buf.copy_within(from..from + n * w_in, at);
                }
                n
            };
            filled += n;
        }
        state[l] = StreamState {
            lo: need_lo,
            filled,
            chunk: Some(j),
        };
        let mut shape = ConvShape::from(layer);
        shape.in_size[0] = r;
        shape.out_size[0] = s.rows;
        shape.padding[0] = 0;
        let window = s.window_start..s.window_start + c_in * r * w_in;
        let chunk = s.chunk_start..s.chunk_start + layer.out_channels * s.rows * layer.out_size[1];
        let (src, dst) = disjoint(buf, window, chunk);
        conv2d_s8_checked(&shape, src, &checked, dst, scratch)?;
        Ok(())
    }

    /// The front depth map (`[E][A]`, metres) from the reference view's features and one or
    /// two source views' features (view k rolled by k × the baseline), streamed: the cost
    /// volume is never whole. d1 is computed tile by tile from windows of cost-volume planes
    /// and rows computed on the fly; d2, m0 and u1 run whole (they are small); u0 is computed
    /// one output plane at a time, its skip (a cost-volume plane) recomputed into that plane,
    /// and each plane goes straight through the fused head into its depth rows. `probe` sees
    /// d1 (as "cost+d1"), d2, m0 and u1; the last stage (cost+u0+head) is not probed.
    pub fn depth_from_features_probed(
        &self,
        reference: &[i8],
        sources: &[&[i8]],
        ws: &mut Workspace,
        depth: &mut [U16F16],
        mut probe: impl FnMut(&str, &[i8]),
    ) -> Result<(), Error> {
        if sources.is_empty() || sources.len() > config::MAX_VIEWS - 1 {
            return Err(Error::SourceCount(sources.len()));
        }
        expect_len(config::FEATURE_LEN, reference.len())?;
        expect_len(config::DEPTH_LEN, depth.len())?;
        for s in sources {
            expect_len(config::FEATURE_LEN, s.len())?;
        }
        let mut views = [SourceView {
            features: &[],
            warp: &[],
        }; config::MAX_VIEWS - 1];
        for (k, (v, s)) in views.iter_mut().zip(sources).enumerate() {
            *v = SourceView {
                features: s,
                warp: &config::WARP_TABLES[k],
            };
        }
        // Validated once; d1 and u0 each compute the whole volume from it piece by piece.
        let cost = CostVolume::new(
            &CostShape::EPSSN,
            reference,
            &views[..sources.len()],
            self.cost[sources.len() - 1],
        )?;
        let Workspace { buf, scratch } = ws;
        self.stream_d1(&cost, buf, scratch)?;
        let (s, l) = unet_range(PLAN.0[D1]);
        probe(&stage_name("cost", D1..D1 + 1), &buf[s..s + l]);
        // The small middle of the UNet, whole tensors in the UNet buffer as planned.
        let mut input = PLAN.0[D1];
        for (i, l) in LAYERS.iter().enumerate().take(U0).skip(D1 + 1) {
            let p = &self.layers[i];
            let checked = self.checked(i);
            let shape = ConvShape::from(l);
            let out = PLAN.0[i];
            let (a, b) = (unet_range(input), unet_range(out));
            let (src, dst) = if input == out {
                (&[][..], &mut [][..])
            } else {
                disjoint(buf, a.0..a.0 + a.1, b.0..b.0 + b.1)
            };
            match l.kind {
                LayerKind::Conv3d => conv3d_s8_checked(&shape, src, &checked, dst, scratch)?,
                LayerKind::ConvTranspose3d => {
                    let skip = if l.skip.is_some() {
                        Skip::InPlace { requant: p.skip }
                    } else {
                        Skip::None
                    };
                    conv_transpose3d_s8_checked(&shape, src, &checked, skip, dst, scratch)?
                }
                LayerKind::Conv2d => return Err(Error::Kernel(KernelError::NotTwoDimensional)),
            }
            probe(l.name, dst);
            input = out;
        }
        self.stream_u0_head(&cost, buf, scratch, depth)
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

    /// The front depth map of a view set, streamed: the one place that turns u8 polar images
    /// (`views[0]` the reference, `views[1..]` the sources, view k rolled by k × the baseline)
    /// into depth. `features` receives each view's features (`views.len() ×
    /// config::FEATURE_LEN`, view by view) so callers can check or cache them. A single view
    /// is its own source (the single-view baseline).
    pub fn depth(
        &self,
        views: &[&[u8]],
        features: &mut [i8],
        ws: &mut Workspace,
        depth: &mut [U16F16],
    ) -> Result<(), Error> {
        if views.is_empty() || views.len() > config::MAX_VIEWS {
            return Err(Error::SourceCount(views.len().saturating_sub(1)));
        }
        expect_len(views.len() * config::FEATURE_LEN, features.len())?;
        for (view, f) in views
            .iter()
            .zip(features.chunks_exact_mut(config::FEATURE_LEN))
        {
            self.features(view, ws, f)?;
        }
        let mut chunks = features.chunks_exact(config::FEATURE_LEN);
        let reference = chunks.next().unwrap_or(&[]);
        let mut sources: [&[i8]; config::MAX_VIEWS - 1] = [&[]; config::MAX_VIEWS - 1];
        let mut n = 0;
        for (s, f) in sources.iter_mut().zip(chunks) {
            *s = f;
            n += 1;
        }
        if n == 0 {
            sources[0] = reference;
            n = 1;
        }
        self.depth_from_features(reference, &sources[..n], ws, depth)
    }

    /// d1 into its UNet region, [`COST_ROW_CHUNKS`] row tiles at a time: per tile, the window
    /// of `kd` cost-volume planes slides along the planes (the planes two output planes share
    /// are kept), and new planes are computed channel by channel for just the tile's rows.
    fn stream_d1(
        &self,
        cost: &CostVolume<'_>,
        buf: &mut [i8],
        scratch: &mut LineScratch,
    ) -> Result<(), Error> {
        let l = &LAYERS[D1];
        let (kd, sd, pd) = (
            l.kernel[0] as usize,
            l.stride[0] as usize,
            l.padding[0] as isize,
        );
        let (sh, ph) = (l.stride[1] as usize, l.padding[1] as isize);
        let [planes, height, width] = l.in_size;
        let [out_planes, out_rows, out_width] = l.out_size;
        let rows = D1_WINDOW_ROWS;
        let slot = rows * width;
        let window = LIVE_END..LIVE_END + D1_WINDOW_LEN;
        let tile = window.end..window.end + D1_TILE_LEN;
        let (d1_start, _) = unet_range(PLAN.0[D1]);
        let checked = self.checked(D1);
        let mut shape = ConvShape::from(l);
        shape.in_size = [kd, rows, width];
        shape.out_size = [1, D1_ROWS, out_width];
        shape.padding[0] = 0;
        shape.padding[1] = 0;
        for y in 0..COST_ROW_CHUNKS {
            let row_lo = (sh * y * D1_ROWS) as isize - ph;
            // Cost-volume rows of this tile that exist (the rest is padding: zeros).
            let r0 = row_lo.max(0) as usize;
            let r1 = ((row_lo + rows as isize).max(0) as usize).min(height);
            let (mut lo, mut held) = (0isize, 0usize);
            for d in 0..out_planes {
                let need = (sd * d) as isize - pd;
                let drop = need - lo;
                held = if drop < 0 || drop as usize >= held {
                    0
                } else {
                    let k = drop as usize;
                    for c in 0..l.in_channels {
                        let base = window.start + c * kd * slot;
                        buf.copy_within(base + k * slot..base + held * slot, base);
                    }
                    held - k
                };
                lo = need;
                while held < kd {
                    let j = lo + held as isize;
                    for c in 0..l.in_channels {
                        let at = window.start + (c * kd + held) * slot;
                        let out = &mut buf[at..at + slot];
                        if j < 0 || j as usize >= planes || r1 <= r0 {
                            out.fill(0);
                            continue;
                        }
                        let top = r0 as isize - row_lo;
                        let (pad_top, rest) = out.split_at_mut(top as usize * width);
                        pad_top.fill(0);
                        let (real, pad_bottom) = rest.split_at_mut((r1 - r0) * width);
                        pad_bottom.fill(0);
                        cost.rows(c, j as usize, r0..r1, real)?;
                    }
                    held += 1;
                }
                let (src, dst) = disjoint(buf, window.clone(), tile.clone());
                conv3d_s8_checked(&shape, src, &checked, dst, scratch)?;
                let n = D1_ROWS * out_width;
                for o in 0..l.out_channels {
                    let at = d1_start + ((o * out_planes + d) * out_rows + y * D1_ROWS) * out_width;
                    buf.copy_within(tile.start + o * n..tile.start + (o + 1) * n, at);
                }
            }
        }
        Ok(())
    }

    /// u0 one output plane at a time: the plane's buffer first receives the cost-volume plane
    /// (u0's skip), then u0's transposed convolution of just the input planes that reach this
    /// output plane adds onto it in place, then the head turns it into depth rows: the fused
    /// head its `kernel[0]` rows at once, the general head (an overlapping kernel) the
    /// `stride[0]` rows whose last input plane this is, from the ring of the last
    /// `P = ceil(kernel / stride)` planes that u0 writes into (plane `t` in slot `t mod P`).
    fn stream_u0_head(
        &self,
        cost: &CostVolume<'_>,
        buf: &mut [i8],
        scratch: &mut LineScratch,
        depth: &mut [U16F16],
    ) -> Result<(), Error> {
        let l = &LAYERS[U0];
        let [in_planes, in_rows, in_width] = l.in_size;
        let in_plane = in_rows * in_width;
        let (u1_start, _) = unet_range(PLAN.0[U0 - 1]);
        let out = LIVE_END + U0_GATHER_LEN..LIVE_END + U0_GATHER_LEN + U0_OUT_LEN;
        let checked = self.checked(U0);
        let skip = Skip::InPlace {
            requant: self.layers[U0].skip,
        };
        let head = &LAYERS[HEAD];
        let head_params = layer_params(head, &self.layers[HEAD], HEAD);
        let mut head_shape = ConvShape::from(head);
        head_shape.in_size[0] = 1;
        head_shape.out_size[0] = head.kernel[0] as usize;
        let depth_rows = head_shape.out_size[0] * head.out_size[2];
        let soft = self.soft();
        let cost_plane = config::FEATURE_RANGE_BINS * config::FEATURE_COLUMNS;
        // One step per u0 *output* plane (the head's input planes).
        let out_planes = l.out_size[0];
        for t in 0..out_planes {
            let slot = if HEAD_FUSED { 0 } else { t % HEAD_IN_PLANES };
            let plane = out.start + slot * U0_PLANE_LEN..out.start + (slot + 1) * U0_PLANE_LEN;
            for (c, o) in buf[plane.clone()].chunks_exact_mut(cost_plane).enumerate() {
                cost.rows(c, t, 0..config::FEATURE_RANGE_BINS, o)?;
            }
            let (first, planes, pad, out_pad) = u0_plane(t);
            let gather = LIVE_END..LIVE_END + l.in_channels * planes * in_plane;
            for c in 0..l.in_channels {
                for q in 0..planes {
                    let at = gather.start + (c * planes + q) * in_plane;
                    if first + q < in_planes {
                        let from = u1_start + (c * in_planes + first + q) * in_plane;
                        buf.copy_within(from..from + in_plane, at);
                    } else {
                        buf[at..at + in_plane].fill(0);
                    }
                }
            }
            let mut shape = ConvShape::from(l);
            shape.in_size[0] = planes;
            shape.out_size[0] = 1;
            shape.padding[0] = pad;
            shape.output_padding[0] = out_pad;
            let (src, dst) = disjoint(buf, gather, plane.clone());
            conv_transpose3d_s8_checked(&shape, src, &checked, skip, dst, scratch)?;
            if HEAD_FUSED {
                let rows = t * depth_rows..(t + 1) * depth_rows;
                let actual = depth.len();
                let depth_t = depth.get_mut(rows).ok_or(Error::InputLength {
                    expected: config::DEPTH_LEN,
                    actual,
                })?;
                head_soft_argmax_s8(
                    &head_shape,
                    &buf[plane.clone()],
                    &head_params,
                    &soft,
                    depth_t,
                )?;
            } else {
                self.head_step(&buf[out.clone()], t, depth)?;
            }
        }
        if !HEAD_FUSED {
            // Rows whose last input plane lies past u0's last (the kernel reads no plane
            // outside the map, so the ring's stale slots are not read).
            for t in out_planes..head_steps(&ConvShape::from(&LAYERS[HEAD])) {
                self.head_step(&buf[out.clone()], t, depth)?;
            }
        }
        Ok(())
    }

    /// Step `t` of the general (non-fused) head: [`head_step_s8`] turns the ring of the last
    /// `P` u0 planes into the `stride[0]` depth rows whose last input plane is `t` (those
    /// inside the map), fused with the soft-argmax.
    fn head_step(&self, ring: &[i8], t: usize, depth: &mut [U16F16]) -> Result<(), Error> {
        let head = &LAYERS[HEAD];
        let params = layer_params(head, &self.layers[HEAD], HEAD);
        let shape = ConvShape::from(head);
        head_step_s8(&shape, ring, t, &params, &self.soft(), depth)?;
        Ok(())
    }
}

/// `(start, len)` of a UNet region (an empty range for any other region).
const fn unet_range(r: Region) -> (usize, usize) {
    match r {
        Region::Unet { start, len } => (start, len),
        _ => (0, 0),
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

fn region(ws: &WholeWorkspace, r: Region) -> &[i8] {
    match r {
        Region::Cost { start, len } => &ws.cost[start..start + len],
        Region::Unet { start, len } => &ws.unet[start..start + len],
        Region::Depth => &[],
    }
}

/// A layer's input and output slices; the plan never makes them overlap.
fn regions(ws: &mut WholeWorkspace, input: Region, output: Region) -> (&[i8], &mut [i8]) {
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
