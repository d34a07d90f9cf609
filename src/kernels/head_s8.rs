//! The head: a transposed convolution with one output channel whose kernel may overlap
//! (kernel ≥ stride, any padding), fused with the soft-argmax along range
//! ([`super::soft_argmax_s8`]), computed a step at a time and never storing the logits.
//!
//! Shape `[D][H][W]` → `[E][R][A]` (input planes, range rows, columns → elevation rows, range
//! bins, azimuth columns). Step `t` gives the `sd` depth rows `e = sd·t − pd + ψ`
//! (`ψ < sd`) whose last input plane is `t`: they read the `P = ceil(kd / sd)` planes
//! `t − P + 1 ..= t` (tap `kz = ψ + sd·j` for plane `t − j`), which the streamed model keeps in
//! a ring of `P` planes `[P][C][H][W]`, plane `z` in slot `z mod P` ([`head_step_s8`]: nothing
//! is shifted, and u0 writes each new plane straight into its slot); [`head_s8`] runs every step on a
//! whole `[C][D][H][W]` input. Planes outside `0..D` read as absent (no contribution).
//!
//! On the column axis an output column `a = sw·g − pw + φ` (`φ < sw`) reads the
//! `Q = ceil(kw / sw)` input columns `g − Q + 1 ..= g` (tap `kx = φ + sw·j` for column
//! `g − j`), so every ray of "column position" `g` and step `t` reads the same `P × Q × C`
//! inputs per range row. The optimised kernel gathers them once per `(t, g)` as i16 pairs
//! (`[y][column slot][plane][channel]`, one new column per position: column `x` lives in slot
//! `x mod Q` and the weights are prepared for each rotation), computes every ray phase
//! `(ψ, φ)` of the position two rays × two range bins per [`crate::arch::dot2x2`], requantises
//! with one `SMMULR` (`RowRequant`) when the accumulator bound allows, tracks each ray's maximum while
//! producing its logits, and reduces the ray at once (single-pass soft-argmax).
//!
//! With Helium (`mve`) the optimised kernel gathers the inputs raw, one byte per entry, and
//! folds the input offset into each ray's bias (`int8`: 16 MACs per instruction, the same
//! accumulators); an offset whose zero point is not an int8 runs the plain twin there.
//!
//! The range axis must have kernel == stride, no padding and no output padding for the
//! optimised kernel (bin `y·kh + ky` reads only range row `y`); other shapes, and shapes too
//! large for its stack buffers, run the plain twin.
//!
//! MACs per logit: `C · ceil(kd / sd) · ceil(kw / sw)` (zero taps included), plus the
//! soft-argmax.

use super::line::RowRequant;
use super::soft_argmax_s8::{
    check_params, soft_argmax_s8_plain, SoftArgmaxParams, SoftArgmaxShape, MAX_BINS,
};
use super::{
    check_conv_transpose, check_conv_transpose_shape, finish, mul3, CheckedParams, ConvParams,
    ConvShape, KernelError, Operand,
};
use crate::config::{LayerKind, LayerShape};
use crate::requant::Apply;
use fixed::types::U16F16;

#[cfg(all(feature = "mve", target_arch = "arm"))]
mod int8;

/// The line the optimised kernel's weights are laid out for: with Helium the int8 line
/// (`int8`: raw bytes, the offset folded into the biases), elsewhere the i16 gather.
#[cfg(all(feature = "mve", target_arch = "arm"))]
type Line = int8::Line;
/// The line the optimised kernel's weights are laid out for: the i16 gather.
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
type Line = ();

/// Lays out the optimised kernel's weights for the build's line; `None` (the plain kernel
/// runs) where the int8 line does not take the shape or the offset.
fn prepare_line(
    shape: &ConvShape,
    f: &Fast,
    params: &ConvParams<'_>,
    wbuf: &mut [u32; HEAD_W_WORDS],
) -> Option<Line> {
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    {
        int8::prepare(shape, f, params, wbuf)
    }
    #[cfg(not(all(feature = "mve", target_arch = "arm")))]
    {
        prepare_weights(shape, f, params, wbuf);
        Some(())
    }
}

/// One optimised step on the build's line.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn step_line<R: LogitRequant>(
    shape: &ConvShape,
    (f, line): (&Fast, &Line),
    src: &Planes<'_>,
    params: &ConvParams<'_>,
    rq: R,
    wbuf: &[u32; HEAD_W_WORDS],
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) {
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    int8::step(shape, f, line, src, params, rq, wbuf, soft, depth);
    #[cfg(not(all(feature = "mve", target_arch = "arm")))]
    {
        // The i16 gather keeps no state of its own: its layout is `Fast`'s.
        let _ = line;
        step_fast(shape, f, src, params, rq, wbuf, soft, depth);
    }
}

/// Most input range rows of the optimised kernel (its accumulator rows).
pub const MAX_FAST_ROWS: usize = 128;
/// Most words of the gathered inputs of one column position (`H` range rows of
/// `Q · P · up4(C) / 2` words): what the build's head needs, from its compiled shape
/// ([`layers_head_col_words`]), so that it takes the optimised kernel (EPSSN-S: 64 rows × 16,
/// EPSSN-P: 128 × 16). Exact, not rounded up: the buffer is on the stack at every step.
pub const HEAD_COL_WORDS: usize = layers_head_col_words(&crate::config::LAYERS);
/// Most words of the prepared weights (`Q` rotations × ray pairs × `kh` × two rays' words).
pub const HEAD_W_WORDS: usize = 512;

/// Input planes one step reads: `P = ceil(kd / sd)` (1 for a zero stride, which the kernels
/// refuse anyway).
pub const fn head_step_planes(shape: &ConvShape) -> usize {
    if shape.stride[0] == 0 {
        1
    } else {
        shape.kernel[0].div_ceil(shape.stride[0])
    }
}

/// Steps that cover every depth row: `t` in `0..head_steps(shape)`, the last one the first
/// step whose rows reach row `E − 1` (steps past `D − 1` read only absent planes but the
/// bias and the earlier planes' taps).
/// Saturates instead of overflowing on shapes the kernels would refuse.
pub const fn head_steps(shape: &ConvShape) -> usize {
    if shape.stride[0] == 0 || shape.out_size[0] == 0 {
        0
    } else {
        let last = (shape.out_size[0] - 1).saturating_add(shape.padding[0]) / shape.stride[0];
        last.saturating_add(1)
    }
}

/// Where the planes of step `t` are: a ring `[P][C][H][W]` (slot `z mod P` holds plane `z`)
/// or the whole input `[C][D][H][W]`.
#[derive(Clone, Copy)]
struct Planes<'a> {
    data: &'a [i8],
    /// Elements between channels.
    channel: usize,
    /// `H · W`.
    plane: usize,
    /// `Some((P, C·H·W))` for a ring.
    ring: Option<(usize, usize)>,
    /// `D`.
    depth: usize,
    t: usize,
}

impl Planes<'_> {
    /// Offset within a channel of plane `t − j`, or `None` if it lies outside `0..D`.
    #[inline(always)]
    fn at(&self, j: usize) -> Option<usize> {
        let z = self.t.checked_sub(j)?;
        if z >= self.depth {
            return None;
        }
        Some(match self.ring {
            Some((p, slot)) => (z % p) * slot,
            None => z * self.plane,
        })
    }
}

/// Validates the head (shape, parameters, soft-argmax, depth map); returns the worst-case
/// accumulator.
fn check(
    shape: &ConvShape,
    input_len: usize,
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &[U16F16],
) -> Result<i64, KernelError> {
    if shape.out_channels != 1 {
        return Err(KernelError::NotStreamableHead);
    }
    let out_len = mul3(shape.out_size)?;
    let bound = check_conv_transpose(shape, input_len, params, out_len)?;
    let [rows, bins, columns] = shape.out_size;
    check_params(soft, bins)?;
    super::expect(Operand::Depth, rows * columns, depth.len())?;
    Ok(bound)
}

/// Length of the ring `[P][C][H][W]` of [`head_step_s8`].
fn ring_len(shape: &ConvShape) -> Result<usize, KernelError> {
    let [_, h, w] = shape.in_size;
    mul3([shape.in_channels, head_step_planes(shape), h])?
        .checked_mul(w)
        .ok_or(KernelError::SizeOverflow)
}

/// The whole-input length, which [`check_conv_transpose`] expects, for a ring.
fn whole_len(shape: &ConvShape) -> Result<usize, KernelError> {
    mul3(shape.in_size)?
        .checked_mul(shape.in_channels)
        .ok_or(KernelError::SizeOverflow)
}

fn ring_planes<'a>(shape: &ConvShape, ring: &'a [i8], t: usize) -> Planes<'a> {
    let [d, h, w] = shape.in_size;
    let p = head_step_planes(shape);
    Planes {
        data: ring,
        channel: h * w,
        plane: h * w,
        ring: Some((p, shape.in_channels * h * w)),
        depth: d,
        t,
    }
}

fn whole_planes<'a>(shape: &ConvShape, input: &'a [i8], t: usize) -> Planes<'a> {
    let [d, h, w] = shape.in_size;
    Planes {
        data: input,
        channel: d * h * w,
        plane: h * w,
        ring: None,
        depth: d,
        t,
    }
}

/// Step `t` of the head, plain reference: the depth rows `sd·t − pd + 0..sd` inside the map,
/// from the ring `[P][C][H][W]` of input planes `t − P + 1 ..= t` (plane `z` in slot `z mod P`, `P` from
/// [`head_step_planes`]; slots of planes outside `0..D` are not read). Each logit straight
/// from the transposed convolution's definition, then [`soft_argmax_s8_plain`] per ray.
/// `shape` is the whole head, `depth` the whole `[E][A]` map.
pub fn head_step_s8_plain(
    shape: &ConvShape,
    ring: &[i8],
    t: usize,
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    check(shape, whole_len(shape)?, params, soft, depth)?;
    super::expect(Operand::Input, ring_len(shape)?, ring.len())?;
    step_plain(shape, &ring_planes(shape, ring, t), params, soft, depth);
    Ok(())
}

/// Step `t` of the head, optimised (see the module documentation); same arguments and bits
/// as [`head_step_s8_plain`].
pub fn head_step_s8(
    shape: &ConvShape,
    ring: &[i8],
    t: usize,
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    let bound = check(shape, whole_len(shape)?, params, soft, depth)?;
    super::expect(Operand::Input, ring_len(shape)?, ring.len())?;
    let planes = ring_planes(shape, ring, t);
    run(shape, bound, params, soft, depth, |_| planes);
    Ok(())
}

/// The head prepared once for the steps of a depth map: shape, parameters and soft-argmax
/// validated (the weight bound taken from [`CheckedParams`], verified once per model) and the
/// optimised kernel's weights laid out, so each [`HeadPlan::step`] only checks the ring and
/// depth lengths. Same bits as [`head_step_s8`] step by step. The laid-out weights live in
/// the caller's [`HeadWeights`] (2 KiB: a plan is cheap to move).
pub struct HeadPlan<'a> {
    shape: ConvShape,
    params: ConvParams<'a>,
    soft: SoftArgmaxParams<'a>,
    fast: Option<(Fast, bool, Line)>,
    wbuf: &'a [u32; HEAD_W_WORDS],
}

/// The optimised head kernel's weights, as [`HeadPlan::new`] lays them out.
pub struct HeadWeights([u32; HEAD_W_WORDS]);

impl HeadWeights {
    /// Zeroed.
    pub const fn new() -> Self {
        Self([0; HEAD_W_WORDS])
    }
}

impl Default for HeadWeights {
    fn default() -> Self {
        Self::new()
    }
}

impl<'a> HeadPlan<'a> {
    /// Validates the head `shape` (the whole head: `depth` is the whole `[E][A]` map) with
    /// `checked` (verified for its kernel and channels, transposed) and `soft`, and prepares
    /// the optimised kernel's weights when the shape suits it.
    pub fn new(
        shape: &ConvShape,
        checked: &CheckedParams<'a>,
        soft: &SoftArgmaxParams<'a>,
        weights: &'a mut HeadWeights,
    ) -> Result<Self, KernelError> {
        checked.check_shape(shape, true)?;
        if shape.out_channels != 1 {
            return Err(KernelError::NotStreamableHead);
        }
        check_conv_transpose_shape(shape, whole_len(shape)?, mul3(shape.out_size)?)?;
        check_params(soft, shape.out_size[1])?;
        Ok(Self::prepare(shape, checked, soft, weights))
    }

    /// The plan of a validated head: the one place that chooses between the optimised
    /// kernel (with `SMMULR` requantisation when the bound allows) and the plain one, and
    /// lays out the optimised kernel's weights.
    fn prepare(
        shape: &ConvShape,
        checked: &CheckedParams<'a>,
        soft: &SoftArgmaxParams<'a>,
        weights: &'a mut HeadWeights,
    ) -> Self {
        let params = *checked.params();
        let fast = fast_sizes(shape).and_then(|f| {
            let fits = params.requant[0].fits_fast(checked.bound());
            prepare_line(shape, &f, &params, &mut weights.0).map(|line| (f, fits, line))
        });
        Self {
            shape: *shape,
            params,
            soft: *soft,
            fast,
            wbuf: &weights.0,
        }
    }

    /// Step `t` (as [`head_step_s8`]) from the ring `[P][C][H][W]` of its input planes.
    pub fn step(&self, ring: &[i8], t: usize, depth: &mut [U16F16]) -> Result<(), KernelError> {
        let shape = &self.shape;
        super::expect(Operand::Input, ring_len(shape)?, ring.len())?;
        let [rows, _, columns] = shape.out_size;
        super::expect(Operand::Depth, rows * columns, depth.len())?;
        self.run_step(&ring_planes(shape, ring, t), depth);
        Ok(())
    }

    /// One step from `src` with the kernel [`HeadPlan::prepare`] chose (`depth` validated).
    /// Inlined so [`HeadPlan::step`] compiles as it did before [`run`] shared it.
    #[inline(always)]
    fn run_step(&self, src: &Planes<'_>, depth: &mut [U16F16]) {
        let (shape, p, soft) = (&self.shape, &self.params, &self.soft);
        match &self.fast {
            Some((f, true, line)) => {
                let rq = RowRequant::new(p.requant[0]);
                step_line(shape, (f, line), src, p, rq, self.wbuf, soft, depth);
            }
            Some((f, false, line)) => {
                step_line(
                    shape,
                    (f, line),
                    src,
                    p,
                    p.requant[0],
                    self.wbuf,
                    soft,
                    depth,
                );
            }
            None => step_plain(shape, src, p, soft, depth),
        }
    }
}

/// The whole head on a whole input `[C][D][H][W]` → depth `[E][A]`, plain reference (every
/// step of [`head_step_s8_plain`]).
pub fn head_s8_plain(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    check(shape, input.len(), params, soft, depth)?;
    for t in 0..head_steps(shape) {
        step_plain(shape, &whole_planes(shape, input, t), params, soft, depth);
    }
    Ok(())
}

/// The whole head on a whole input, optimised; same bits as [`head_s8_plain`].
pub fn head_s8(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) -> Result<(), KernelError> {
    let bound = check(shape, input.len(), params, soft, depth)?;
    run(shape, bound, params, soft, depth, |t| {
        whole_planes(shape, input, t)
    });
    Ok(())
}

/// Depth row of phase `ψ` of step `t`, if inside the map.
#[inline(always)]
fn row_of(shape: &ConvShape, t: usize, psi: usize) -> Option<usize> {
    let e = shape.stride[0].checked_mul(t)?.checked_add(psi)?;
    let e = e.checked_sub(shape.padding[0])?;
    (e < shape.out_size[0]).then_some(e)
}

/// One step, plain (validated shape; any range-axis geometry).
fn step_plain(
    shape: &ConvShape,
    src: &Planes<'_>,
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) {
    let [_, ih, iw] = shape.in_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [_, ph, pw] = shape.padding;
    let [_, bins, columns] = shape.out_size;
    let taps = kd * kh * kw;
    let (bias, rq) = (params.bias[0], params.requant[0]);
    let planes = head_step_planes(shape);
    let ss = SoftArgmaxShape {
        rows: 1,
        bins,
        columns: 1,
    };
    let mut logits = [0i8; MAX_BINS];
    for psi in 0..sd {
        let Some(e) = row_of(shape, src.t, psi) else {
            continue;
        };
        for a in 0..columns {
            for (i, l) in logits[..bins].iter_mut().enumerate() {
                let mut acc = bias;
                for j in 0..planes {
                    // Plane t − j reaches row e through tap kz = ψ + sd·j.
                    let kz = psi + sd * j;
                    let Some(poff) = src.at(j) else { continue };
                    if kz >= kd {
                        continue;
                    }
                    for y in 0..ih {
                        let Some(ky) = (i + ph).checked_sub(sh * y).filter(|&k| k < kh) else {
                            continue;
                        };
                        for x in 0..iw {
                            let Some(kx) = (a + pw).checked_sub(sw * x).filter(|&k| k < kw) else {
                                continue;
                            };
                            for c in 0..shape.in_channels {
                                let v = src.data[c * src.channel + poff + y * iw + x] as i32
                                    + params.input_offset;
                                let w = params.weights[c * taps + (kz * kh + ky) * kw + kx];
                                acc += v * w as i32;
                            }
                        }
                    }
                }
                *l = finish(rq.apply(acc), params.relu, None);
            }
            let at = e * columns + a;
            // The shape is validated (bins ≤ MAX_BINS), so this cannot fail.
            let _ = soft_argmax_s8_plain(&ss, &logits[..bins], soft, &mut depth[at..at + 1]);
        }
    }
}

/// `x` rounded up to a multiple of 4.
const fn up4(x: usize) -> usize {
    x.div_ceil(4) * 4
}

/// Sizes of the optimised kernel.
#[derive(Clone, Copy)]
struct Fast {
    /// `P`, `Q`.
    planes: usize,
    cols: usize,
    /// Channels padded to a multiple of 4 (the i16 gather's; the int8 line packs them).
    #[cfg_attr(all(feature = "mve", target_arch = "arm"), allow(dead_code))]
    vp: usize,
    /// Words per range row: `Q · P · vp / 2` (even).
    #[cfg_attr(all(feature = "mve", target_arch = "arm"), allow(dead_code))]
    n: usize,
    /// Ray phases `sd · sw` and their pairs.
    rays: usize,
    pairs: usize,
}

/// The optimised kernel's sizes, if the shape suits it and fits its buffers.
fn fast_sizes(shape: &ConvShape) -> Option<Fast> {
    let (fast, w_words, col_words) = fast_layout(shape)?;
    let fits =
        w_words <= HEAD_W_WORDS && col_words <= HEAD_COL_WORDS && shape.in_size[1] <= MAX_FAST_ROWS;
    fits.then_some(fast)
}

/// The optimised kernel's sizes and the words of its prepared weights and of its gathered
/// inputs, if the shape suits it (buffers not checked; `None` also where a size overflows).
/// A const fn: [`HEAD_COL_WORDS`] is this evaluated over the compiled layers.
const fn fast_layout(shape: &ConvShape) -> Option<(Fast, usize, usize)> {
    let [_, ih, _] = shape.in_size;
    let [_, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    if kh != sh || shape.padding[1] != 0 || shape.output_padding[1] != 0 || sw == 0 || sd == 0 {
        return None;
    }
    let planes = head_step_planes(shape);
    let cols = kw.div_ceil(sw);
    let vp = up4(shape.in_channels);
    // `?` is not available in const fns.
    let Some(n) = cols.checked_mul(planes) else {
        return None;
    };
    let Some(n) = n.checked_mul(vp / 2) else {
        return None;
    };
    let Some(rays) = sd.checked_mul(sw) else {
        return None;
    };
    let pairs = rays.div_ceil(2);
    let Some(w_words) = cols.checked_mul(pairs) else {
        return None;
    };
    let Some(w_words) = w_words.checked_mul(kh) else {
        return None;
    };
    let Some(w_words) = w_words.checked_mul(2 * n) else {
        return None;
    };
    let Some(col_words) = ih.checked_mul(n) else {
        return None;
    };
    let fast = Fast {
        planes,
        cols,
        vp,
        n,
        rays,
        pairs,
    };
    Some((fast, w_words, col_words))
}

/// The most gathered-input words (`H · Q · P · up4(C) / 2`, as the optimised kernel's fit
/// check computes them) of any layer in `layers` that the head kernels take (transposed, one
/// output channel) and whose shape suits the optimised kernel; 0 when none does.
pub const fn layers_head_col_words(layers: &[LayerShape]) -> usize {
    let mut most = 0;
    let mut i = 0;
    while i < layers.len() {
        let l = &layers[i];
        if matches!(l.kind, LayerKind::ConvTranspose3d) && l.out_channels == 1 {
            if let Some((_, _, col_words)) = fast_layout(&ConvShape::of(l)) {
                if col_words > most {
                    most = col_words;
                }
            }
        }
        i += 1;
    }
    most
}

/// Runs every step `planes_of` gives (one, or all of them) through a [`HeadPlan`] prepared
/// here, so the one-shot functions take the same kernel as the plan. Shape, parameters and
/// `depth` are validated; `bound` is the worst-case accumulator [`check`] computed.
fn run<'a>(
    shape: &ConvShape,
    bound: i64,
    params: &ConvParams<'_>,
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
    planes_of: impl Fn(usize) -> Planes<'a>,
) {
    let one = planes_of(0).ring.is_some();
    let steps = if one { 0..1 } else { 0..head_steps(shape) };
    // `bound` is check_layer_bounds' on these parameters (through check_conv_transpose).
    let checked = CheckedParams::verified(shape, *params, true, bound, None);
    let mut weights = HeadWeights::new();
    let plan = HeadPlan::prepare(shape, &checked, soft, &mut weights);
    for t in steps {
        plan.run_step(&planes_of(t), depth);
    }
}

/// Weights of rotation `r` (column position `g ≡ r mod Q`), ray pair `p`, range tap `ky`:
/// the two rays' words interleaved (an odd last ray paired with itself), word `k` covering
/// slot `s`, plane tap `j` and channels `2m, 2m + 1` with `k = (s·P + j)·vp/2 + m`; slot `s`
/// holds column tap `(r − s) mod Q`. Taps outside the kernel are zero.
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
fn prepare_weights(shape: &ConvShape, f: &Fast, params: &ConvParams<'_>, wbuf: &mut [u32]) {
    let [kd, kh, kw] = shape.kernel;
    let [sd, _, sw] = shape.stride;
    let taps = kd * kh * kw;
    let ic = shape.in_channels;
    let half_vp = f.vp / 2;
    for r in 0..f.cols {
        for p in 0..f.pairs {
            for ky in 0..kh {
                let base = ((r * f.pairs + p) * kh + ky) * 2 * f.n;
                for half in 0..2 {
                    let ray = (2 * p + half).min(f.rays - 1);
                    let (psi, phi) = (ray / sw, ray % sw);
                    for s in 0..f.cols {
                        let jx = (r + f.cols - s) % f.cols;
                        let kx = phi + sw * jx;
                        for j in 0..f.planes {
                            let kz = psi + sd * j;
                            let w = |c: usize| {
                                if c < ic && kz < kd && kx < kw {
                                    params.weights[c * taps + (kz * kh + ky) * kw + kx] as i16
                                } else {
                                    0
                                }
                            };
                            for m in 0..half_vp {
                                let k = (s * f.planes + j) * half_vp + m;
                                wbuf[base + 2 * k + half] =
                                    crate::arch::pack(w(2 * m), w(2 * m + 1));
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Gathers input column `x` (if inside `0..W`, else zeros) of every plane tap and channel
/// into slot `s` of the range rows' words (offset added), a channel pair per word.
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
#[inline(always)]
fn gather_column(
    shape: &ConvShape,
    f: &Fast,
    src: &Planes<'_>,
    off: i16,
    x: Option<usize>,
    s: usize,
    col: &mut [u32; HEAD_COL_WORDS],
) {
    let [_, ih, iw] = shape.in_size;
    let ic = shape.in_channels;
    let n = f.n;
    let half_vp = f.vp / 2;
    let rows = &mut col[..ih * n];
    let hw = ih * iw;
    for j in 0..f.planes {
        let poff = src.at(j);
        for m in 0..half_vp {
            let k = (s * f.planes + j) * half_vp + m;
            // Channel c's plane, if it exists and the column is inside.
            let plane = |c: usize| match (x, poff) {
                (Some(_), Some(poff)) if c < ic => Some(&src.data[c * src.channel + poff..][..hw]),
                _ => None,
            };
            let x = x.unwrap_or(0);
            match (plane(2 * m), plane(2 * m + 1)) {
                (Some(pa), Some(pb)) => {
                    let (a, b) = (&pa[x..], &pb[x..]);
                    crate::arch::pack_strided(&mut rows[k..], n, (a, b, iw), ih, off, off);
                }
                (Some(pa), None) => {
                    for (d, ra) in rows.chunks_exact_mut(n).zip(pa.chunks_exact(iw)) {
                        d[k] = crate::arch::pack(ra[x] as i16 + off, 0);
                    }
                }
                _ => {
                    for d in rows.chunks_exact_mut(n) {
                        d[k] = 0;
                    }
                }
            }
        }
    }
}

/// Logits `out[y·kh + ky] = clamp(ReLU?(rq(acc[y])))` of one ray and range tap, and the
/// running maximum `max` updated with them.
trait LogitRequant: Apply {
    #[inline(always)]
    fn logits(self, acc: &[i32], relu: bool, out: &mut [i8], tap: (usize, usize), max: i8) -> i8 {
        requant_logits(acc, self, relu, out, tap, max)
    }
}

impl LogitRequant for crate::requant::Requant {}

impl LogitRequant for RowRequant {
    #[inline(always)]
    fn logits(self, acc: &[i32], relu: bool, out: &mut [i8], tap: (usize, usize), max: i8) -> i8 {
        match tap {
            (0, 1) => self.row_max(acc, out, relu, max),
            _ => requant_logits(acc, self, relu, out, tap, max),
        }
    }
}

#[inline(always)]
fn requant_logits<R: Apply>(
    acc: &[i32],
    rq: R,
    relu: bool,
    out: &mut [i8],
    (ky, kh): (usize, usize),
    mut max: i8,
) -> i8 {
    let q = |a: i32| finish(rq.apply(a), relu, None);
    for (d, &a) in out.iter_mut().skip(ky).step_by(kh.max(1)).zip(acc) {
        *d = q(a);
        max = max.max(*d);
    }
    max
}

/// One step, optimised (validated shape that [`fast_sizes`] accepts, weights prepared).
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
#[allow(clippy::too_many_arguments)]
fn step_fast<R: LogitRequant>(
    shape: &ConvShape,
    f: &Fast,
    src: &Planes<'_>,
    params: &ConvParams<'_>,
    rq: R,
    wbuf: &[u32; HEAD_W_WORDS],
    soft: &SoftArgmaxParams<'_>,
    depth: &mut [U16F16],
) {
    let [_, ih, iw] = shape.in_size;
    let kh = shape.kernel[1];
    let [sd, _, sw] = shape.stride;
    let pw = shape.padding[2];
    let [_, bins, columns] = shape.out_size;
    let n = f.n;
    let t = src.t;
    if (0..sd).all(|psi| row_of(shape, t, psi).is_none()) {
        return;
    }
    // |offset| ≤ 255 is validated, so offset inputs fit i16.
    let (bias, off) = (params.bias[0], params.input_offset as i16);
    // Column positions g with a column a = sw·g − pw + φ inside 0..A.
    let g_lo = pw / sw;
    let g_hi = (columns - 1 + pw) / sw;
    let mut col = [0u32; HEAD_COL_WORDS];
    let mut logits = [[0i8; MAX_BINS]; 2];
    let mut acc = [[0i32; MAX_FAST_ROWS]; 2];
    // Every range tap's dot products: the `ih` range rows of a column, `n` words each.
    let plan = crate::arch::RowPlan::new(n, ih, n, 1);
    let inside = |x: usize| (x < iw).then_some(x);
    for j in 0..f.cols {
        // Columns g_lo − j, in slot (g_lo − j) mod Q.
        let x = g_lo.checked_sub(j).and_then(inside);
        let s = (g_lo % f.cols + f.cols - j) % f.cols;
        gather_column(shape, f, src, off, x, s, &mut col);
    }
    for g in g_lo..=g_hi {
        if g > g_lo {
            gather_column(shape, f, src, off, inside(g), g % f.cols, &mut col);
        }
        let r = g % f.cols;
        for p in 0..f.pairs {
            // Depth index of each ray of the pair, if inside the map.
            let target = |half: usize| {
                let ray = 2 * p + half;
                if ray >= f.rays {
                    return None;
                }
                let e = row_of(shape, t, ray / sw)?;
                let a = (sw * g + ray % sw).checked_sub(pw)?;
                (a < columns).then_some(e * columns + a)
            };
            let targets = [target(0), target(1)];
            if targets == [None, None] {
                continue;
            }
            // Both rays' accumulators over the range rows at once (one validated call per
            // range tap), then each ray's logits requantised in a tight loop.
            let mut max = [i8::MIN; 2];
            for ky in 0..kh {
                let w = &wbuf[((r * f.pairs + p) * kh + ky) * 2 * n..][..2 * n];
                let [aa, ab] = &mut acc;
                plan.run(&col[..ih * n], w, [bias; 2], (&mut aa[..ih], &mut ab[..ih]));
                for half in 0..2 {
                    max[half] = rq.logits(
                        &acc[half][..ih],
                        params.relu,
                        &mut logits[half][..bins],
                        (ky, kh),
                        max[half],
                    );
                }
            }
            for (half, at) in targets.iter().enumerate() {
                if let Some(at) = *at {
                    depth[at] = super::soft_argmax_s8::ray_depth_max(
                        &logits[half][..bins],
                        max[half],
                        soft,
                    );
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::conv_transpose3d_s8::conv_transpose3d_s8_plain;
    use super::super::soft_argmax_s8::soft_argmax_s8_plain;
    use super::super::testutil::{exp_table, params, soft_params, Rng};
    use super::super::Skip;
    use super::*;
    use crate::config;
    use std::vec;
    use std::vec::Vec;

    #[test]
    fn head_col_words_come_from_the_head_layers_fit_formula() {
        // The build's head (its last layer) takes the optimised kernel, and the gather buffer
        // is exactly its `H` range rows of `Q · P · up4(C) / 2` words.
        let head = ConvShape::of(&config::LAYERS[config::LAYER_COUNT - 1]);
        let f = fast_sizes(&head).expect("the head takes the optimised kernel");
        let q_p_c = head.kernel[2].div_ceil(head.stride[2])
            * head.kernel[0].div_ceil(head.stride[0])
            * up4(head.in_channels)
            / 2;
        assert_eq!(f.n, q_p_c);
        assert_eq!(HEAD_COL_WORDS, head.in_size[1] * f.n);
        assert_eq!(HEAD_COL_WORDS, layers_head_col_words(&config::LAYERS));
    }

    /// The ring of step `t`: planes `t − P + 1 ..= t` of `input` (zeros outside `0..D`, which
    /// the kernels must not read anyway: filled with a pattern instead).
    fn ring_of(shape: &ConvShape, input: &[i8], t: usize) -> Vec<i8> {
        let [d, h, w] = shape.in_size;
        let p = head_step_planes(shape);
        let (hw, ic) = (h * w, shape.in_channels);
        let mut ring = vec![77i8; ic * p * hw];
        for z in (t + 1).saturating_sub(p)..=t {
            for c in 0..ic {
                let dst = &mut ring[((z % p) * ic + c) * hw..][..hw];
                if z < d {
                    dst.copy_from_slice(&input[(c * d + z) * hw..][..hw]);
                }
            }
        }
        ring
    }

    fn random_shape(rng: &mut Rng) -> ConvShape {
        let stride = [1 + rng.below(3), 1 + rng.below(3), 1 + rng.below(4)];
        let mut kernel = [0; 3];
        let mut padding = [0; 3];
        let mut output_padding = [0; 3];
        for a in 0..3 {
            kernel[a] = stride[a] + rng.below(2 * stride[a] + 1);
            padding[a] = rng.below(kernel[a]);
            if rng.below(3) == 0 {
                output_padding[a] = rng.below(stride[a]);
            }
        }
        if rng.below(3) > 0 {
            // Mostly range axes the optimised kernel takes.
            kernel[1] = stride[1];
            padding[1] = 0;
            output_padding[1] = 0;
        }
        loop {
            let in_size = [1 + rng.below(5), 1 + rng.below(9), 1 + rng.below(7)];
            let out = |a: usize| {
                ((in_size[a] - 1) * stride[a] + kernel[a] + output_padding[a])
                    .checked_sub(2 * padding[a])
                    .filter(|&o| o > 0)
            };
            if let (Some(e), Some(r), Some(c)) = (out(0), out(1), out(2)) {
                if r <= MAX_BINS {
                    return ConvShape {
                        in_channels: 1 + rng.below(11),
                        out_channels: 1,
                        kernel,
                        stride,
                        padding,
                        output_padding,
                        in_size,
                        out_size: [e, r, c],
                    };
                }
            }
        }
    }

    fn epssn_head() -> ConvShape {
        ConvShape {
            in_channels: 8,
            out_channels: 1,
            kernel: [4, 1, 8],
            stride: [2, 1, 4],
            padding: [1, 0, 2],
            output_padding: [0; 3],
            in_size: [16, 64, 16],
            out_size: [32, 64, 64],
        }
    }

    #[test]
    fn head_equals_conv_transpose_then_soft_argmax() {
        let mut rng = Rng(4242);
        let mut shapes = vec![epssn_head(), ConvShape::from(&config::LAYER_HEAD)];
        // The old non-overlapping head.
        shapes.push(ConvShape {
            kernel: [2, 1, 4],
            padding: [0; 3],
            ..epssn_head()
        });
        // Too large for the column buffer: the plain path.
        shapes.push(ConvShape {
            in_channels: 30,
            kernel: [3, 1, 3],
            stride: [2, 1, 2],
            padding: [1, 0, 1],
            in_size: [2, 40, 3],
            out_size: [3, 40, 5],
            ..epssn_head()
        });
        for _ in 0..150 {
            shapes.push(random_shape(&mut rng));
        }
        let mut fast_cases = 0;
        for (case, shape) in shapes.iter().enumerate() {
            let (w, mut b, r) = params(&mut rng, shape);
            if case % 5 == 4 {
                // Beyond the fast requantisation's range: the exact path.
                b[0] = 1 << 30;
            }
            let input = rng.i8s(shape.in_channels * shape.in_size.iter().product::<usize>());
            let cp = ConvParams {
                weights: &w,
                bias: &b,
                requant: &r,
                input_offset: if case % 4 == 2 { 128 } else { 0 },
                relu: case % 3 == 1,
            };
            let exp = exp_table(0.01 + rng.below(100) as f64 * 0.01);
            let mut soft = soft_params(&exp, rng.below(6) as u16);
            if case % 2 == 1 {
                soft.no_return16 = 1 + rng.below(1 << 16) as u32;
            }
            let [rows, bins, columns] = shape.out_size;
            let mut logits = vec![0i8; rows * bins * columns];
            conv_transpose3d_s8_plain(shape, &input, &cp, Skip::None, &mut logits).unwrap();
            let ss = SoftArgmaxShape {
                rows,
                bins,
                columns,
            };
            let mut want = vec![U16F16::ZERO; rows * columns];
            soft_argmax_s8_plain(&ss, &logits, &soft, &mut want).unwrap();
            let run = |f: &dyn Fn(&mut [U16F16])| {
                let mut d = vec![U16F16::ONE; rows * columns];
                f(&mut d);
                d
            };
            let whole = run(&|d| head_s8(shape, &input, &cp, &soft, d).unwrap());
            assert_eq!(whole, want, "case {case} {shape:?} whole");
            let plain = run(&|d| head_s8_plain(shape, &input, &cp, &soft, d).unwrap());
            assert_eq!(plain, want, "case {case} {shape:?} whole plain");
            let steps = |plain: bool| {
                run(&|d| {
                    for t in 0..head_steps(shape) {
                        let ring = ring_of(shape, &input, t);
                        if plain {
                            head_step_s8_plain(shape, &ring, t, &cp, &soft, d).unwrap();
                        } else {
                            head_step_s8(shape, &ring, t, &cp, &soft, d).unwrap();
                        }
                    }
                })
            };
            assert_eq!(steps(false), want, "case {case} {shape:?} steps");
            assert_eq!(steps(true), want, "case {case} {shape:?} steps plain");
            fast_cases += usize::from(fast_sizes(shape).is_some());
        }
        assert!(fast_cases > 60, "{fast_cases}");
    }

    #[test]
    fn extreme_inputs_are_exact() {
        // All-127 and all-−128 inputs with ±127 weights: the largest accumulators.
        let shape = epssn_head();
        let taps = shape.in_channels * shape.kernel.iter().product::<usize>();
        let exp = exp_table(0.05);
        let soft = soft_params(&exp, 4);
        for (v, wv) in [(127i8, 127i8), (-128, 127), (127, -128), (-128, -128)] {
            let w = vec![wv; taps];
            let cp = ConvParams {
                weights: &w,
                bias: &[-12345],
                requant: &[crate::requant::Requant {
                    multiplier: 1 << 30,
                    shift: -12,
                }],
                input_offset: 0,
                relu: false,
            };
            let input = vec![v; shape.in_channels * shape.in_size.iter().product::<usize>()];
            let [rows, bins, columns] = shape.out_size;
            let mut logits = vec![0i8; rows * bins * columns];
            conv_transpose3d_s8_plain(&shape, &input, &cp, Skip::None, &mut logits).unwrap();
            let ss = SoftArgmaxShape {
                rows,
                bins,
                columns,
            };
            let mut want = vec![U16F16::ZERO; rows * columns];
            soft_argmax_s8_plain(&ss, &logits, &soft, &mut want).unwrap();
            let mut got = vec![U16F16::ZERO; rows * columns];
            head_s8(&shape, &input, &cp, &soft, &mut got).unwrap();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn no_panics_on_random_arguments() {
        let mut rng = Rng(99);
        let exp = exp_table(0.1);
        for _ in 0..3000 {
            let dim = |rng: &mut Rng| rng.below(5);
            let shape = ConvShape {
                in_channels: dim(&mut rng),
                out_channels: rng.below(3),
                kernel: [dim(&mut rng), dim(&mut rng), dim(&mut rng)],
                stride: [dim(&mut rng), dim(&mut rng), dim(&mut rng)],
                padding: [dim(&mut rng), dim(&mut rng), dim(&mut rng)],
                output_padding: [dim(&mut rng), dim(&mut rng), dim(&mut rng)],
                in_size: [dim(&mut rng), dim(&mut rng), dim(&mut rng)],
                out_size: [
                    rng.below(12),
                    if rng.below(50) == 0 {
                        usize::MAX
                    } else {
                        rng.below(12)
                    },
                    rng.below(12),
                ],
            };
            let nw = rng.below(200);
            let w = rng.i8s(nw);
            let b = [rng.range(-(1 << 31), (1 << 31) - 1) as i32];
            let r = [crate::requant::Requant {
                multiplier: rng.next() as i32,
                shift: rng.range(-40, 40) as i32,
            }];
            let cp = ConvParams {
                weights: &w,
                bias: &b[..rng.below(2)],
                requant: &r[..rng.below(2)],
                input_offset: rng.range(-300, 300) as i32,
                relu: rng.below(2) == 0,
            };
            let soft = SoftArgmaxParams {
                exp: &exp,
                r_min16: U16F16::from_bits(rng.next() as u32 >> rng.below(32)),
                step16: U16F16::from_bits(rng.next() as u32 >> rng.below(32)),
                end_offset: rng.below(300) as u16,
                no_return16: rng.next() as u32 >> rng.below(32),
            };
            let ni = rng.below(300);
            let input = rng.i8s(ni);
            let mut depth = vec![U16F16::ZERO; rng.below(40)];
            let t = if rng.below(10) == 0 {
                usize::MAX
            } else {
                rng.below(8)
            };
            let _ = head_s8(&shape, &input, &cp, &soft, &mut depth);
            let _ = head_s8_plain(&shape, &input, &cp, &soft, &mut depth);
            let _ = head_step_s8(&shape, &input, t, &cp, &soft, &mut depth);
            let _ = head_step_s8_plain(&shape, &input, t, &cp, &soft, &mut depth);
            let _ = (head_steps(&shape), head_step_planes(&shape));
        }
        let huge = ConvShape {
            padding: [usize::MAX; 3],
            out_size: [usize::MAX; 3],
            stride: [1; 3],
            ..epssn_head()
        };
        assert_eq!(head_steps(&huge), usize::MAX);
    }

    #[test]
    fn plan_steps_equal_head_step_s8() {
        let mut rng = Rng(0x5eed_4ead);
        let exp = exp_table(0.05);
        let soft = soft_params(&exp, 4);
        for k in [[4, 1, 8], [2, 1, 4], [3, 1, 5]] {
            let padding = [(k[0] - 2) / 2, 0, (k[2] - 4) / 2];
            let (rows, columns) = (
                15 * 2 + k[0] - 2 * padding[0],
                15 * 4 + k[2] - 2 * padding[2],
            );
            let shape = ConvShape {
                in_channels: 8,
                out_channels: 1,
                in_size: [16, 64, 16],
                out_size: [rows, 64, columns],
                kernel: k,
                stride: [2, 1, 4],
                padding,
                output_padding: [0, 0, 0],
            };
            let (w, b, rq) = params(&mut rng, &shape);
            let cp = ConvParams {
                weights: &w,
                bias: &b,
                requant: &rq,
                input_offset: 0,
                relu: false,
            };
            let checked = CheckedParams::new(&shape, cp, true).unwrap();
            let mut weights = HeadWeights::new();
            let plan = HeadPlan::new(&shape, &checked, &soft, &mut weights).unwrap();
            let input = rng.i8s(8 * 16 * 64 * 16);
            let mut a = vec![U16F16::ZERO; rows * columns];
            let mut b2 = a.clone();
            for t in 0..head_steps(&shape) {
                let ring = ring_of(&shape, &input, t);
                plan.step(&ring, t, &mut a).unwrap();
                head_step_s8(&shape, &ring, t, &cp, &soft, &mut b2).unwrap();
            }
            assert_eq!(a, b2, "kernel {k:?}");
            assert!(matches!(
                plan.step(&input[..10], 0, &mut a),
                Err(KernelError::Length { .. })
            ));
        }
    }

    #[test]
    fn errors_and_odd_steps() {
        let shape = epssn_head();
        let exp = exp_table(0.05);
        let soft = soft_params(&exp, 0);
        let w = vec![1i8; 8 * 32];
        let rq = [crate::requant::Requant {
            multiplier: 1 << 30,
            shift: -4,
        }];
        let cp = ConvParams {
            weights: &w,
            bias: &[0],
            requant: &rq,
            input_offset: 0,
            relu: false,
        };
        let ring = vec![0i8; 8 * 2 * 64 * 16];
        let mut depth = vec![U16F16::ZERO; 32 * 64];
        assert!(matches!(
            head_step_s8(&shape, &ring[1..], 0, &cp, &soft, &mut depth),
            Err(KernelError::Length {
                operand: Operand::Input,
                ..
            })
        ));
        assert!(matches!(
            head_step_s8(&shape, &ring, 0, &cp, &soft, &mut depth[1..]),
            Err(KernelError::Length {
                operand: Operand::Depth,
                ..
            })
        ));
        let two = ConvShape {
            out_channels: 2,
            ..shape
        };
        assert_eq!(
            head_step_s8(&two, &ring, 0, &cp, &soft, &mut depth),
            Err(KernelError::NotStreamableHead)
        );
        // Steps far past the map write nothing and do not panic.
        for t in [40, usize::MAX / 2, usize::MAX] {
            head_step_s8(&shape, &ring, t, &cp, &soft, &mut depth).unwrap();
            head_step_s8_plain(&shape, &ring, t, &cp, &soft, &mut depth).unwrap();
        }
        assert!(depth.iter().all(|d| *d == U16F16::ZERO));
        assert_eq!(head_steps(&shape), 17);
        assert_eq!(head_step_planes(&shape), 2);
    }
}
