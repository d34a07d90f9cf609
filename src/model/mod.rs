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
//! are whole. Sub-volumes carry explicit padding rows/planes where the whole tensor has
//! padding (the stored form of a zero: 0, or the cost volume's zero point, which d1's input
//! offset turns into 0), which adds exactly 0, so the bits equal those of the plain
//! whole-tensor twin ([`WholeWorkspace`], [`Model::depth_from_features_whole_probed`]) that
//! tests compare with.
//!
//! Modules: `plan` (the memory plan: regions, line buffers, tiles, workspace sizes, checked at
//! compile time), `stream` (the streamed path the firmware runs, [`Workspace`]) and `whole` (the
//! whole-tensor twin, [`WholeWorkspace`]); this module holds the verified weights ([`Model`]).

use core::ops::Range;

use fixed::types::U16F16;

use crate::blob::{Blob, BlobError};
use crate::config::{self, LayerKind, LayerShape, LAYERS};
use crate::kernels::LineScratch;
use crate::kernels::{
    check_layer_bounds, conv2d_s8::conv2d_s8, conv2d_s8::conv2d_s8_checked, conv3d_s8::conv3d_s8,
    conv3d_s8::conv3d_s8_checked, conv_transpose3d_s8::conv_transpose3d_s8,
    conv_transpose3d_s8::conv_transpose3d_s8_checked, cost_volume_s8::cost_volume_s8,
    cost_volume_s8::CostRequant, cost_volume_s8::CostShape, cost_volume_s8::CostVolume,
    cost_volume_s8::SourceView, head_s8::head_steps, head_s8::HeadPlan, head_s8::HeadWeights,
    skip_value_bound, soft_argmax_s8::head_soft_argmax_s8, soft_argmax_s8::soft_argmax_s8,
    soft_argmax_s8::SoftArgmaxParams, soft_argmax_s8::SoftArgmaxShape,
    soft_argmax_s8::MAX_NO_RETURN16, CheckedParams, ConvParams, ConvShape, KernelError, Skip,
};
use crate::requant::Requant;

mod plan;
mod stream;
mod whole;

use plan::*;
pub use plan::{
    COST_BUFFER_LEN, COST_ROW_CHUNKS, FEATURE_CHUNKS, FEATURE_LAYERS, MAX_CHANNELS,
    UNET_BUFFER_LEN, WORKSPACE_LEN,
};
pub use stream::Workspace;
pub use whole::WholeWorkspace;

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
    /// The blob's view count (its [`VIEWS_TENSOR`]) is outside `2..=MAX_VIEWS`.
    Views {
        /// The value the blob holds.
        views: i32,
    },
    /// The blob's no-return threshold (its [`NO_RETURN_TENSOR`]) is outside `0..=2^16`.
    NoReturn {
        /// The value the blob holds.
        tau16: i32,
    },
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

/// Parameters of one layer: int8 weights borrowed from the blob, the rest copied to RAM
/// (the blob's alignment in memory is not guaranteed).
#[derive(Clone, Copy, Debug)]
struct LayerParams<'a> {
    weights: &'a [i8],
    bias: [i32; MAX_CHANNELS],
    requant: [Requant; MAX_CHANNELS],
    skip: Requant,
    /// Added to every input value: 128 for the network input and for d1 when the cost volume
    /// is unsigned (zero point −128), else 0.
    input_offset: i32,
    /// Added to every skip value: 128 when the skip is an unsigned cost volume, else 0.
    skip_offset: i32,
    /// Worst-case accumulator ([`check_layer_bounds`]), verified in [`Model::from_blob`].
    bound: i64,
}

/// A verified int8 EPSSN.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    layers: [LayerParams<'a>; config::LAYER_COUNT],
    /// Cost-volume requantisation for 2 and 3 views (one zero point).
    cost: [CostRequant; 2],
    /// Views the model was trained and calibrated for.
    views: usize,
    /// The no-return decision's threshold `round(τ · 2^16)` (0 decides nothing).
    no_return16: u32,
    exp: [u16; 256],
}

/// The blob tensor holding the cost volume's zero point (optional: 0 when absent).
pub const COST_ZERO_POINT_TENSOR: &str = "cost.zp";

/// The blob tensor holding the mean channels' requantisation `[M'2, s'2, M'3, s'3]`
/// (`m'_n = s_f / (n · s_cost)`), present when the spec has `features.mean_channels`.
pub const COST_MEAN_TENSOR: &str = "cost.mean";

/// The blob tensor holding the number of views the model was trained and calibrated for
/// (optional: the spec's `views` when absent). A model is best on its own view count (a 3-view
/// model fed 2 views is far worse than a 2-view one, docs/ACCURACY.md), so the server pairs
/// frames into sets of this size.
pub const VIEWS_TENSOR: &str = "views";

/// The blob tensor holding the model's no-return threshold `round(τ · 2^16)`, `0..=2^16`
/// (optional: the spec's `no_return_mass` when absent). A calibration of the trained model,
/// chosen on validation data: how much of a ray's mass its end bin must hold before the ray
/// reads "nothing there" depends on how the model spreads its mass, so one spec's models may
/// need different thresholds (0: no decision).
pub const NO_RETURN_TENSOR: &str = "no_return";

/// The offset layer `index` adds to every input value (QUANTISATION.md): 128 for the network
/// input ([`INPUT_OFFSET`]), `−cost_zero_point` for d1, which reads the cost volume, else 0.
/// The model and the quantiser (its accumulator bounds) both take it from here.
pub const fn layer_input_offset(index: usize, cost_zero_point: i32) -> i32 {
    if index == 0 {
        INPUT_OFFSET
    } else if index == D1 {
        -cost_zero_point
    } else {
        0
    }
}

/// The offset a layer adds to every skip value before requantising it: `−cost_zero_point`
/// when its skip is the cost volume (u0), else 0.
pub const fn layer_skip_offset(l: &LayerShape, cost_zero_point: i32) -> i32 {
    match l.skip {
        Some(s) if str_eq(s, "cost") => -cost_zero_point,
        _ => 0,
    }
}

/// A one-element int32 tensor the blob may lack (added after the format's first blobs):
/// `default` when it is absent; any other defect of the blob is an error.
fn read_optional_i32(blob: &Blob<'_>, name: &str, default: i32) -> Result<i32, Error> {
    let mut v = [default];
    match blob.read_i32(name, &mut v) {
        Ok(()) | Err(BlobError::MissingTensor) => Ok(v[0]),
        Err(e) => Err(e.into()),
    }
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
/// shift]` of a skip, `cost.rq` int32 `[M2, s2, M3, s3]`, `cost.zp` int32 `[zero point]`
/// (0 or −128; a blob without it has zero point 0, as every blob before it), `views` int32
/// `[views trained for]` (2..=MAX_VIEWS; a blob without it has the spec's), `no_return` int32
/// `[round(τ · 2^16)]` (0..=2^16; a blob without it has the spec's), `exp` u16 `[256]`;
/// with mean channels also `cost.mean` int32 `[M'2, s'2, M'3, s'3]`.
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
    f(COST_ZERO_POINT_TENSOR, Dtype::I32, 1);
    if config::MEAN_CHANNELS > 0 {
        f(COST_MEAN_TENSOR, Dtype::I32, 4);
    }
    f(VIEWS_TENSOR, Dtype::I32, 1);
    f(NO_RETURN_TENSOR, Dtype::I32, 1);
    f("exp", Dtype::U16, 256);
}

impl<'a> Model<'a> {
    /// Builds the model from a blob: magic, version, length, CRC-32, model-spec hash, every
    /// tensor's dtype and size, every multiplier and every layer's worst-case accumulator are
    /// checked; any failure is an error and nothing is half-built.
    pub fn from_blob(bytes: &'a [u8]) -> Result<Self, Error> {
        let blob = Blob::parse(bytes, config::SPEC_HASH)?;
        let mut c = [0i32; 4];
        blob.read_i32("cost.rq", &mut c)?;
        let zero_point = read_optional_i32(&blob, COST_ZERO_POINT_TENSOR, 0)?;
        // Read only when the compiled spec has mean channels (its hash is the blob's).
        let mut mean = [0i32; 4];
        if config::MEAN_CHANNELS > 0 {
            blob.read_i32(COST_MEAN_TENSOR, &mut mean)?;
        }
        let cost = [0, 1].map(|v| CostRequant {
            requant: Requant {
                multiplier: c[2 * v],
                shift: c[2 * v + 1],
            },
            mean: Requant {
                multiplier: mean[2 * v],
                shift: mean[2 * v + 1],
            },
            zero_point,
        });
        if !cost[0].zero_point_valid() {
            return Err(Error::Kernel(KernelError::CostZeroPoint { zero_point }));
        }
        let views = read_optional_i32(&blob, VIEWS_TENSOR, config::VIEWS as i32)?;
        if !(2..=config::MAX_VIEWS as i32).contains(&views) {
            return Err(Error::Views { views });
        }
        let tau16 = read_optional_i32(&blob, NO_RETURN_TENSOR, config::NO_RETURN_MASS_Q16 as i32)?;
        let no_return16 = match u32::try_from(tau16) {
            Ok(t) if t <= MAX_NO_RETURN16 => t,
            _ => return Err(Error::NoReturn { tau16 }),
        };
        // X ≤ 3·3·128² < 2^18 and |Σv| ≤ 3·128 for any int8 features.
        let valid =
            |r: Requant, bound: i64| valid_multiplier(r) && r.shift_in_range() && r.fits(bound);
        if !cost
            .iter()
            .all(|r| valid(r.requant, 1 << 18) && valid(r.mean, 3 * 128))
        {
            return Err(Error::BadMultiplier { index: usize::MAX });
        }
        let empty = LayerParams {
            weights: &[],
            bias: [0; MAX_CHANNELS],
            requant: [Requant::default(); MAX_CHANNELS],
            skip: Requant::default(),
            input_offset: 0,
            skip_offset: 0,
            bound: 0,
        };
        let mut layers = [empty; config::LAYER_COUNT];
        for (index, (l, p)) in LAYERS.iter().zip(layers.iter_mut()).enumerate() {
            let oc = l.out_channels;
            p.input_offset = layer_input_offset(index, zero_point);
            p.skip_offset = layer_skip_offset(l, zero_point);
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
                // The skip input is int8 plus its offset: |q + offset| · 2^left must stay
                // below 2^31.
                let bound = skip_value_bound(p.skip_offset);
                if !valid_multiplier(p.skip) || !p.skip.shift_in_range() || !p.skip.fits(bound) {
                    return Err(Error::BadMultiplier { index });
                }
            }
            let params = layer_params(l, p);
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
        let mut exp = [0u16; 256];
        blob.read_u16("exp", &mut exp)?;
        if exp[0] == 0 {
            return Err(Error::Blob(BlobError::ShapeMismatch));
        }
        Ok(Self {
            layers,
            cost,
            views: views as usize,
            no_return16,
            exp,
        })
    }

    /// The cost volume's zero point: the stored value of a zero variance (0, or −128 for the
    /// unsigned cost volume the quantiser writes; QUANTISATION.md "Warp and cost volume").
    pub fn cost_zero_point(&self) -> i32 {
        self.cost[0].zero_point
    }

    /// The number of views the model was trained and calibrated for (the blob's
    /// [`VIEWS_TENSOR`], else the spec's `views`): the view-set size the server pairs.
    /// The kernels run 2 or 3 views with any model; other counts are out of its domain.
    pub fn views(&self) -> usize {
        self.views
    }

    /// Layer `index`'s parameters with the accumulator bound verified in
    /// [`Model::from_blob`], for the kernels' checked entries.
    fn checked(&self, index: usize) -> CheckedParams<'_> {
        let l = &LAYERS[index];
        let p = &self.layers[index];
        CheckedParams::verified(
            &ConvShape::from(l),
            layer_params(l, p),
            matches!(l.kind, LayerKind::ConvTranspose3d),
            p.bound,
            Some(index),
        )
    }

    /// The no-return decision's threshold `round(τ · 2^16)` the model runs (the blob's
    /// [`NO_RETURN_TENSOR`], else the spec's `no_return_mass`; 0: no decision).
    pub fn no_return16(&self) -> u32 {
        self.no_return16
    }

    fn soft(&self) -> SoftArgmaxParams<'_> {
        SoftArgmaxParams {
            exp: &self.exp,
            r_min16: U16F16::from_bits(config::R_MIN_Q16),
            step16: U16F16::from_bits(config::DEPTH_STEP_Q16),
            end_offset: config::END_BIN_OFFSET as u16,
            no_return16: self.no_return16,
        }
    }
}

fn layer_params<'p>(l: &LayerShape, p: &'p LayerParams<'_>) -> ConvParams<'p> {
    ConvParams {
        weights: p.weights,
        bias: &p.bias[..l.out_channels],
        requant: &p.requant[..l.out_channels],
        input_offset: p.input_offset,
        relu: l.relu,
    }
}

/// A layer's skip operand, in place in its output buffer.
fn skip_in_place(p: &LayerParams<'_>) -> Skip<'static> {
    Skip::InPlace {
        requant: p.skip,
        offset: p.skip_offset,
    }
}

fn expect_len(expected: usize, actual: usize) -> Result<(), Error> {
    if expected == actual {
        Ok(())
    } else {
        Err(Error::InputLength { expected, actual })
    }
}
