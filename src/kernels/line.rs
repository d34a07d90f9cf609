//! The convolution engines the kernels share: the line-buffer engine of the forward and
//! transposed convolutions, and the im2col engine of the forward ones.
//!
//! For one output row (fixed plane and row of a forward convolution, or of one output phase
//! of a transposed one) the engine gathers, once, every input value the row reads into a
//! line buffer laid out `[column][v]`, where `v` runs over (input channel, plane tap, row
//! tap). The taps of one output position are then one contiguous window of the buffer
//! (`kw` consecutive columns), and the windows of neighbouring positions overlap instead of
//! being copied per position (im2col). The weights are reordered once per call (per phase)
//! to `[O][column tap][v]`, so every output is a dot product of two contiguous arrays.
//!
//! The inner loop computes 2 output channels × 2 positions at once
//! ([`crate::arch::dot2x2`]): the line holds i16 values (offset added, 0 at padding) two
//! per word, the weights are expanded once to i16 pairs with the two channels' words
//! interleaved, so per 2 taps one load of each position's word, one `LDRD` of the weights
//! and 4 `SMLAD` give 8 MACs. `v` is padded with zeros (and zero weights) to a multiple of
//! 4 so every window is an even number of words.
//!
//! With Helium (`mve`) the forward engine's line holds int8 instead (`conv_s8`): the raw
//! inputs, the zero point at padding, the offset's products folded into the biases, so that
//! `VMLADAV.S8` takes 16 MACs per instruction; the accumulators are the i16 line's exactly.
//!
//! Cost on the QEMU Cortex-M7 (EPSSN-S, whole layers including the fill and the
//! requantisation): f1 2.0, d1 2.2, u0 4.4 instructions per MAC; the inner loop alone is
//! about 1.1.
//!
//! Requantisation uses [`FastRequant`] when the layer's worst-case accumulator allows it
//! (always, for the EPSSN layers), else the exact [`Requant`] path, and a skip add reads a
//! 256-entry table of `MBQM(q_skip)`.
//!
//! The im2col engine at the end of the file is the forward convolutions' path for layers the
//! line engine does not take but whose taps of one output (`I · kd · kh · kw`) fit
//! [`COL_LEN`]: the inputs of two output positions are gathered once into i16 columns on the
//! stack (offset added, padding 0; CMSIS-NN's im2col), packed two per word, and every output
//! channel's contiguous weights `[K]` run one dot product over both positions, so each weight
//! load feeds two MACs and there is no index arithmetic in the inner loop (thumbv7em release:
//! about 2.4 instructions per MAC portable, 1.9 with the `dsp` feature's SMLAD). A 2D layer
//! runs it as a 3D one with a trivial third axis (same memory layout).
//!
//! Both engines serve the kernel files ([`super::conv2d_s8`], [`super::conv3d_s8`],
//! [`super::conv_transpose3d_s8`], [`super::head_s8`]), which import from here; nothing here
//! imports from them.

use super::{finish, tap_range, ConvParams, ConvShape, Skip};
use crate::arch::RowPlan;
use crate::config::{LayerKind, LayerShape};
use crate::requant::{Apply, Requant};

/// Words (two i16 entries each) of the line buffer: the most any layer of the build's spec
/// needs ([`layers_line_words`], the fit formulas of [`conv_fits`] and [`transposed_fits`]
/// over the compiled shapes), so every layer takes the engine; rounded up to whole 1024 words
/// (4 KiB), the steps the scratch has been sized and budgeted in. EPSSN-S: d1's lines (72
/// entries × 17 columns) are the longest at 612 words, its scratch stays at the 1024 it was
/// measured with; EPSSN-P: d1's 72 × 33, 1188 words, 2048.
pub const LINE_WORDS: usize = layers_line_words(&crate::config::LAYERS).div_ceil(1024) * 1024;
/// Words (two i16 weights each) of the reordered weights of one call or phase.
pub const WEIGHT_WORDS: usize = 3456;
/// Most line entries per column (`v`, padded to a multiple of 4).
pub const MAX_V: usize = 256;
/// Largest column stride of a transposed convolution the engine takes.
pub const MAX_STRIDE: usize = 8;
/// Most output channels with prepared [`FastRequant`]s.
pub const MAX_FAST_CHANNELS: usize = 32;

/// `x` rounded up to a multiple of 4.
#[inline(always)]
pub(crate) const fn up4(x: usize) -> usize {
    x.div_ceil(4) * 4
}

/// [`crate::requant::FastRequant`]'s arithmetic with one `SMMULR` ([`crate::arch::smmulr`]):
/// for `a = acc · 2^left` with `|a| < 2^30`, `SRDHM(a, M) = ⌊(a·M + 2^30) / 2^31⌋ =
/// ⌊(2a·M + 2^31) / 2^32⌋`, and `2a` fits i32; then the same rounding right shift. Exact
/// wherever `FastRequant` is ([`Requant::fits_fast`]), in 6 instructions instead of 10.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct RowRequant {
    multiplier: i32,
    /// `left + 1`.
    left1: u32,
    right: u32,
    half: i32,
    /// −1 when `right > 0` (ties of negative values round away from zero), else 0.
    neg: i32,
}

impl RowRequant {
    /// Prepares `rq` (shifts clamped like [`crate::requant::FastRequant::new`]).
    pub(crate) const fn new(rq: Requant) -> Self {
        let left = if rq.shift > 0 { rq.shift as u32 } else { 0 };
        let right = if rq.shift < 0 {
            let r = rq.shift.wrapping_neg();
            if r > 31 || r < 0 {
                31
            } else {
                r as u32
            }
        } else {
            0
        };
        RowRequant {
            multiplier: rq.multiplier,
            left1: if left > 30 { 31 } else { left + 1 },
            right,
            half: if right > 0 { 1 << (right - 1) } else { 0 },
            neg: if right > 0 { -1 } else { 0 },
        }
    }
}

impl RowRequant {
    /// `out[i]` = `acc[i]` requantised, ReLU'd if `relu` and clamped to int8 (as
    /// [`super::finish`] without a skip), and the larger of `max` and those values
    /// ([`crate::arch::requant_max_row`]).
    #[inline(always)]
    pub(crate) fn row_max(self, acc: &[i32], out: &mut [i8], relu: bool, max: i8) -> i8 {
        let f = (self.multiplier, self.left1, self.right, self.half, self.neg);
        crate::arch::requant_max_row(acc, out, f, relu, max)
    }
}

impl Apply for RowRequant {
    #[inline(always)]
    fn apply(self, acc: i32) -> i32 {
        // `right` ≤ 31 by construction (`new`).
        crate::arch::row_requant(
            acc,
            self.multiplier,
            self.left1,
            self.right,
            self.half,
            self.neg,
        )
    }

    const HAS_WORDS: bool = true;

    #[inline(always)]
    fn words(self) -> Option<[i32; 5]> {
        // left1 ≤ 31 and right ≤ 31 by construction (`new`).
        let (l, r) = (self.left1 as i32, self.right as i32);
        Some([self.multiplier, l, r, self.half, self.neg])
    }

    #[inline(always)]
    fn row_s8(self, acc: &[i32], out: &mut [i8], relu: bool, skip: Option<&[i32; 256]>) -> bool {
        let f = (self.multiplier, self.left1, self.right, self.half, self.neg);
        crate::arch::requant_row_s8(acc, out, f, relu, skip);
        true
    }
}

/// Prepared requantisations of `params` when every channel fits the fast path for the
/// layer's worst-case accumulator `bound`.
pub(crate) fn fast_requants(
    requant: &[Requant],
    bound: i64,
) -> Option<[RowRequant; MAX_FAST_CHANNELS]> {
    if requant.len() > MAX_FAST_CHANNELS || !requant.iter().all(|r| r.fits_fast(bound)) {
        return None;
    }
    let mut f = [RowRequant::default(); MAX_FAST_CHANNELS];
    for (f, &r) in f.iter_mut().zip(requant) {
        *f = RowRequant::new(r);
    }
    Some(f)
}

/// The skip operand, with `MBQM(q_skip)` tabulated over the 256 int8 values.
#[derive(Clone, Copy)]
pub(crate) enum SkipLut<'a> {
    None,
    Separate(&'a [i8], &'a [i32; 256]),
    InPlace(&'a [i32; 256]),
}

/// `MBQM(q + offset, skip multiplier)` for every int8 `q` (index `q as u8`).
pub(crate) fn skip_table(skip: &Skip<'_>) -> Option<[i32; 256]> {
    let (rq, offset) = skip.requant()?;
    Some(core::array::from_fn(|u| {
        rq.apply(u as u8 as i8 as i32 + offset)
    }))
}

pub(crate) fn skip_lut<'a>(skip: &Skip<'a>, table: &'a Option<[i32; 256]>) -> SkipLut<'a> {
    match (skip, table) {
        (Skip::Separate { skip, .. }, Some(t)) => SkipLut::Separate(skip, t),
        (Skip::InPlace { .. }, Some(t)) => SkipLut::InPlace(t),
        _ => SkipLut::None,
    }
}

/// Requantises one row of one channel's accumulators and stores it: output `q` at
/// `out[start + q · step]` = ReLU, skip add (table), int8 clamp, as [`super::finish`]. The
/// skip kind and the ReLU are decided once per row, so each output costs the requantisation
/// and about 8 instructions more. Not inlined: in its own function the loop keeps its
/// operands in registers instead of reloading them from the engine's stack frame.
#[inline(never)]
fn requant_row<R: Apply>(
    acc: &[i32],
    rq: R,
    relu: bool,
    skip: SkipLut<'_>,
    out: &mut [i8],
    start: usize,
    step: usize,
) {
    let Some(len) = acc.len().checked_sub(1).map(|l| l * step + 1) else {
        return;
    };
    let Some(end) = start.checked_add(len) else {
        return;
    };
    let Some(dst) = out.get_mut(start..end) else {
        return;
    };
    if step == 1 {
        let lut = match skip {
            SkipLut::None => Some(None),
            SkipLut::InPlace(lut) => Some(Some(lut)),
            SkipLut::Separate(..) => None,
        };
        if let Some(lut) = lut {
            if rq.row_s8(acc, dst, relu, lut) {
                return;
            }
        }
    }
    // One loop for every case: the hot rows take `row_s8` above or, a whole line at a time,
    // [`requant_rows`]; this serves the rest (strided stores, a separate skip operand, the
    // exact requantisation) in little code.
    let separate = match skip {
        SkipLut::Separate(s, _) => s.get(start..end).unwrap_or(&[]),
        _ => &[],
    };
    // A step of 0 names one output, the first accumulator's.
    let count = if step == 0 { 1 } else { acc.len() };
    for (q, &a) in acc.iter().take(count).enumerate() {
        let i = q * step;
        let Some(d) = dst.get_mut(i) else {
            break;
        };
        let t = rq.apply(a);
        let t = if relu { t.max(0) } else { t };
        let t = match skip {
            SkipLut::None => t,
            SkipLut::InPlace(lut) => t.saturating_add(lut[*d as u8 as usize]),
            SkipLut::Separate(_, lut) => {
                t.saturating_add(separate.get(i).map_or(0, |&v| lut[v as u8 as usize]))
            }
        };
        *d = t.clamp(-128, 127) as i8;
    }
}

/// Where a row's outputs go: output `(o, q)` at `o · plane + base + q · step`.
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
#[derive(Clone, Copy)]
pub(crate) struct RowOut {
    pub plane: usize,
    pub base: usize,
    pub step: usize,
}

/// The packed-line geometry of one row: position `q` reads words
/// `line[q · step .. q · step + words]`, dotted with `words / 2` weight words per channel.
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
#[derive(Clone, Copy)]
pub(crate) struct RowIn {
    positions: usize,
    words: usize,
    /// The dot products' shape, checked once for every row of the layer.
    plan: crate::arch::RowPlan,
}

#[cfg(not(all(feature = "mve", target_arch = "arm")))]
impl RowIn {
    /// `positions` (at most [`MAX_POSITIONS`]) dot products of `words` words, `step` words
    /// apart.
    pub(crate) fn new(positions: usize, step: usize, words: usize) -> Self {
        let positions = positions.min(MAX_POSITIONS);
        let step = if words == 0 { 0 } else { step };
        RowIn {
            positions,
            words,
            plan: crate::arch::RowPlan::new(step, positions, words, 1),
        }
    }
}

/// Most positions of one row (a row is at most [`MAX_ROW`] input columns).
const MAX_POSITIONS: usize = MAX_ROW;

/// Accumulators of one line: a row per channel, `width` apart, when every channel's row fits
/// ([`AccRows::flat`]); else two rows of [`MAX_POSITIONS`] + 1, reused by each channel pair.
pub(crate) type RowAcc = [i32; 2 * (MAX_POSITIONS + 1)];

/// How a line's channel pairs use the accumulators: one row per channel, so that a single
/// call requantises every channel of the line ([`requant_rows`]), or the two shared rows.
#[derive(Clone, Copy)]
struct AccRows {
    width: usize,
    flat: bool,
}

impl AccRows {
    /// Rows of `width` for `oc` channels (an odd last channel's pair partner is a spare row):
    /// flat when they fit and the row loop can take every channel at once (Helium, the fast
    /// requantisation's words, step-1 stores, a skip read in place or none).
    fn new(oc: usize, width: usize, words: bool, step: usize, skip: SkipLut<'_>) -> Self {
        let fits = oc.div_ceil(2) * 2 * width <= 2 * (MAX_POSITIONS + 1);
        let whole = matches!(skip, SkipLut::None | SkipLut::InPlace(_));
        // Only Helium has a row loop that takes many rows in one call; elsewhere a row per
        // call measured faster (the Cortex-M7's SMLAD build: 0.9 M instructions a map).
        let one_call = cfg!(all(feature = "mve", target_arch = "arm"));
        AccRows {
            width,
            flat: one_call && fits && words && step == 1 && whole,
        }
    }

    /// Channel `o`'s and channel `o + 1`'s rows (empty if out of range: the dot-product
    /// calls then refuse them).
    #[inline(always)]
    fn pair(self, acc: &mut RowAcc, o: usize) -> (&mut [i32], &mut [i32]) {
        let (w, o) = if self.flat {
            (self.width, o)
        } else {
            (MAX_POSITIONS + 1, 0)
        };
        match acc.split_at_mut_checked((o + 1) * w) {
            Some((a, b)) => {
                let b_len = w.min(b.len());
                (a.get_mut(o * w..).unwrap_or(&mut []), &mut b[..b_len])
            }
            None => (&mut [], &mut []),
        }
    }
}

/// The five-word fast requantisation of every channel of `rq`, if each has one.
#[inline(always)]
fn row_words<R: Apply>(rq: &[R]) -> Option<[[i32; 5]; MAX_FAST_CHANNELS]> {
    if !R::HAS_WORDS || rq.len() > MAX_FAST_CHANNELS {
        return None;
    }
    let mut t = [[0; 5]; MAX_FAST_CHANNELS];
    for (t, &r) in t.iter_mut().zip(rq) {
        *t = r.words()?;
    }
    Some(t)
}

/// Each channel pair's biases (an odd last channel paired with itself), as the pair loop
/// takes them.
#[inline(always)]
fn bias_pairs(bias: &[i32]) -> [[i32; 2]; MAX_FAST_CHANNELS / 2] {
    let mut t = [[0; 2]; MAX_FAST_CHANNELS / 2];
    for (t, b) in t.iter_mut().zip(bias.chunks(2)) {
        *t = [b[0], *b.get(1).unwrap_or(&b[0])];
    }
    t
}

/// The first `channels` rows of a flat line of accumulators ([`AccRows`]) requantised, row
/// `c` into `out[c·plane + base ..]`: one call for all of them where the row loop takes it,
/// else a [`requant_row`] per channel.
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn requant_rows<R: Apply>(
    acc: &[i32],
    (width, channels): (usize, usize),
    rq: &[R],
    words: crate::arch::RowWords<'_>,
    relu: bool,
    skip: SkipLut<'_>,
    out: &mut [i8],
    (base, plane): (usize, usize),
) {
    let lut = match skip {
        SkipLut::InPlace(lut) => Some(lut),
        _ => None,
    };
    if let (Some(acc), Some(words), Some(dst)) = (
        acc.get(..channels * width),
        words.get(0..channels),
        out.get_mut(base..),
    ) {
        if crate::arch::requant_rows_s8(acc, dst, words, (width, plane), relu, lut) {
            return;
        }
    }
    for (c, &r) in rq.iter().take(channels).enumerate() {
        let row = acc.get(c * width..(c + 1) * width).unwrap_or(&[]);
        requant_row(row, r, relu, skip, out, base + c * plane, 1);
    }
}

/// The line engine's scratch (expanded weights, line buffer, accumulator rows, about 20 KiB):
/// a kernel call writes every word of it that it reads, so one scratch serves any number of
/// calls and nothing is zeroed per call. The public kernels make one on the stack; the
/// streamed model keeps one in its workspace and passes it to the `*_checked` kernels.
pub struct LineScratch {
    wbuf: [u32; WEIGHT_WORDS],
    line: [u32; LINE_WORDS],
    acc: RowAcc,
    kept: KeptWeights,
}

/// The model's layer index ([`super::CheckedParams`], which fix its kernel and channels) and
/// the stride (a transposed convolution's layout depends on it).
type WeightsKey = (usize, [usize; 3]);

/// Most layers whose laid-out weights `wbuf` holds side by side (the four feature layers).
const MAX_KEPT: usize = 4;

/// One layer's laid-out weights in `wbuf`.
#[derive(Clone, Copy, Default)]
struct KeptSlot {
    key: WeightsKey,
    /// First word.
    base: usize,
    /// Bit `fz · MAX_STRIDE + fy`: the phase's weights are laid out (bit 0 for a forward
    /// convolution, which has one phase).
    ready: u64,
}

/// Which layers' weights `wbuf` still holds, while the caller allows keeping them
/// ([`LineScratch::keep_weights`]): up to [`MAX_KEPT`] layers packed from word 0 on.
#[derive(Clone, Copy, Default)]
struct KeptWeights {
    on: bool,
    slots: [KeptSlot; MAX_KEPT],
    /// Slots in use (`slots[..len]`) and the words they take.
    len: usize,
    used: usize,
}

impl Default for LineScratch {
    fn default() -> Self {
        Self::new()
    }
}

impl LineScratch {
    /// A zeroed scratch.
    pub const fn new() -> Self {
        Self {
            wbuf: [0; WEIGHT_WORDS],
            line: [0; LINE_WORDS],
            acc: [0; 2 * (MAX_POSITIONS + 1)],
            kept: KeptWeights {
                on: false,
                slots: [KeptSlot {
                    key: (0, [0; 3]),
                    base: 0,
                    ready: 0,
                }; MAX_KEPT],
                len: 0,
                used: 0,
            },
        }
    }

    /// From now on, a convolution of a model layer whose weights (same layer, kernel, stride
    /// and channels) were laid out by an earlier call skips laying them out again, as long as
    /// they fit the weight buffer beside the other kept layers' (a transposed convolution's
    /// phase by phase; a forward one's when its output channels form one group). For the
    /// model, which runs a layer many times in pieces (the streamed features, d1 and u0):
    /// the layer is identified by its index in the model ([`super::CheckedParams`] carry it),
    /// not by the weights' address, which other weights could occupy later; parameters not
    /// from a model are never kept. The model's weights must not change until
    /// [`LineScratch::forget_weights`].
    pub fn keep_weights(&mut self) {
        // Slots past `len` are never read.
        self.kept.on = true;
        self.kept.len = 0;
        self.kept.used = 0;
    }

    /// Ends [`LineScratch::keep_weights`]: every call lays its weights out again.
    pub fn forget_weights(&mut self) {
        self.kept.on = false;
        self.kept.len = 0;
        self.kept.used = 0;
    }
}

/// One row of outputs for all channels: 2 channels × 2 positions per inner loop
/// ([`crate::arch::dot2x2`]) into a row of accumulators per channel, then each channel's row
/// requantised and stored ([`requant_row`]). `weights` holds, per channel pair, the two
/// channels' words interleaved (`rin.words` words per channel; an odd last channel is paired
/// with itself).
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn row<R: Apply>(
    line: &[u32],
    rin: RowIn,
    weights: &[u32],
    bias: &[i32],
    rq: &[R],
    relu: bool,
    skip: SkipLut<'_>,
    out: &mut [i8],
    rout: RowOut,
    acc: &mut RowAcc,
    (words, biases): (Option<crate::arch::RowWords<'_>>, &[[i32; 2]]),
) {
    let (n, positions) = (rin.words, rin.positions);
    let oc = bias.len().min(rq.len());
    let rows = AccRows::new(oc, positions, words.is_some(), rout.step, skip);
    // A row per channel: every channel pair's dot products in one call, then every row's
    // requantisation in one.
    if let (true, Some(words)) = (rows.flat, words) {
        let lines = (positions, oc);
        let at = (rout.base, rout.plane);
        let all = (weights, 2 * n);
        let pairs = biases.get(..oc.div_ceil(2)).unwrap_or(&[]);
        if rin.plan.run_channels(line, all, pairs, acc, (positions, 0)) {
            requant_rows(acc, lines, rq, words, relu, skip, out, at);
        }
        return;
    }
    let mut o = 0;
    while o < oc {
        let two = o + 1 < oc;
        let Some(w) = weights.get(o * n..(o + 2) * n) else {
            break;
        };
        let b = biases.get(o / 2).copied().unwrap_or([0, 0]);
        let (acc0, acc1) = rows.pair(acc, o);
        if !rin.plan.run(line, w, b, (&mut *acc0, &mut *acc1)) {
            break;
        }
        let at = |o: usize| o * rout.plane + rout.base;
        requant_row(&acc0[..positions], rq[o], relu, skip, out, at(o), rout.step);
        if two {
            requant_row(
                &acc1[..positions],
                rq[o + 1],
                relu,
                skip,
                out,
                at(o + 1),
                rout.step,
            );
        }
        o += 2;
    }
}

/// Two i16 weights as one word, `a` in the low half.
#[inline(always)]
fn word(a: i8, b: i8) -> u32 {
    crate::arch::pack(a as i16, b as i16)
}

/// Index of word `k` of channel `o` in the pair-interleaved weight buffer (`n` words per
/// channel).
#[inline(always)]
fn wslot(o: usize, k: usize, n: usize) -> usize {
    (o / 2) * 2 * n + 2 * k + o % 2
}

/// Pads an odd channel count's last pair by copying the last channel's words.
fn pad_pairs(wbuf: &mut [u32], oc: usize, n: usize) {
    if oc % 2 == 1 {
        for k in 0..n {
            wbuf[wslot(oc, k, n)] = wbuf[wslot(oc - 1, k, n)];
        }
    }
}

/// Longest input row the line engine reads (the zero row stands in for padding rows).
pub const MAX_ROW: usize = 256;
static ZEROS: [i8; MAX_ROW] = [0; MAX_ROW];

/// Fills the line: `src()`, called once for each `v` in `0..vp` in order, is the input
/// offset of the row that entry `v` reads (`None` → all zeros); line columns `lo..hi` read that row from input
/// column `in0` on, the other columns are 0 (padding).
///
/// Word by word: entries `2k`, `2k + 1` of every column come from two rows read in step
/// ([`crate::arch::pack_rows`]).
#[inline(always)]
fn fill(
    line: &mut [u32],
    vp: usize,
    cols: usize,
    (lo, hi, in0): (usize, usize, usize),
    input: &[i8],
    off: i16,
    mut src: impl FnMut() -> Option<usize>,
) {
    let vw = vp / 2;
    if vw == 0 {
        return;
    }
    let words = &mut line[..vw * cols];
    let len = hi.saturating_sub(lo).min(MAX_ROW);
    // Padding rows read zeros and add nothing (padding contributes 0, not the offset).
    #[inline(always)]
    fn row(input: &[i8], base: Option<usize>, in0: usize, len: usize, off: i16) -> (&[i8], i16) {
        match base {
            Some(base) => (&input[base + in0..base + in0 + len], off),
            None => (&ZEROS[..len], 0),
        }
    }
    // Columns are `vw` consecutive words, so the padding columns left of `lo` and from
    // `lo + len` on are two contiguous blocks, zeroed once instead of word by word.
    let (head, tail) = (lo.min(cols), (lo + len).min(cols));
    words[..head * vw].fill(0);
    words[tail * vw..].fill(0);
    if len == 0 {
        return;
    }
    for k in 0..vw {
        let (ra, oa) = row(input, src(), in0, len, off);
        let (rb, ob) = row(input, src(), in0, len, off);
        crate::arch::pack_rows(&mut words[lo * vw + k..], vw, ra, rb, oa, ob);
    }
}

/// On ARM (`dsp`, `mve`), the input rows one line reads, as a description rather than a closure, so
/// that a plain loop names them ([`TapCursor`]): entry `v = (i, a, b)` (`b` fastest; channel
/// `i < channels`, plane tap `a < na`, row tap `b < nb`) reads the input row at offset `i ·
/// cs + origin + a · da + b · db` when `a` is in `a_ok` and `b` in `b_ok`, and zeros
/// otherwise (padding); entries from `channels · na · nb` on are zeros too (the line's
/// multiple of 4). Offsets wrap (the transposed engine's taps step backwards); only those of
/// taps inside the input are used. The same entries as the closures of [`conv`] and
/// [`transposed`] (a test compares them).
#[cfg(any(test, all(feature = "dsp", target_arch = "arm")))]
#[derive(Clone, Copy)]
struct LineTaps {
    channels: usize,
    cs: usize,
    na: usize,
    nb: usize,
    origin: usize,
    da: usize,
    db: usize,
    a_ok: (usize, usize),
    b_ok: (usize, usize),
}

#[cfg(any(test, all(feature = "dsp", target_arch = "arm")))]
impl LineTaps {
    /// The taps of a forward convolution's output row `(z, y)`: input plane `z·sd + a − pd`
    /// and row `y·sh + b − ph`.
    #[inline(always)]
    fn forward(shape: &ConvShape, z: usize, y: usize) -> Self {
        let [id, ih, iw] = shape.in_size;
        let [kd, kh, _] = shape.kernel;
        let [sd, sh, _] = shape.stride;
        let [pd, ph, _] = shape.padding;
        let (z0, y0) = (z * sd, y * sh);
        LineTaps {
            channels: shape.in_channels,
            cs: id * ih * iw,
            na: kd,
            nb: kh,
            origin: z0
                .wrapping_sub(pd)
                .wrapping_mul(ih * iw)
                .wrapping_add(y0.wrapping_sub(ph).wrapping_mul(iw)),
            da: ih * iw,
            db: iw,
            a_ok: (pd.saturating_sub(z0), (id + pd).saturating_sub(z0).min(kd)),
            b_ok: (ph.saturating_sub(y0), (ih + ph).saturating_sub(y0).min(kh)),
        }
    }

    /// The taps of a transposed convolution's phase row that reads input plane `bz − a` and
    /// row `by − b` (`tz` plane and `ty` row taps).
    #[inline(always)]
    fn transposed(shape: &ConvShape, (bz, by): (usize, usize), (tz, ty): (usize, usize)) -> Self {
        let [id, ih, iw] = shape.in_size;
        LineTaps {
            channels: shape.in_channels,
            cs: id * ih * iw,
            na: tz,
            nb: ty,
            origin: bz * ih * iw + by * iw,
            da: (ih * iw).wrapping_neg(),
            db: iw.wrapping_neg(),
            a_ok: ((bz + 1).saturating_sub(id), (bz + 1).min(tz)),
            b_ok: ((by + 1).saturating_sub(ih), (by + 1).min(ty)),
        }
    }
}

/// The entries of [`LineTaps`] in order, counted up without multiplications.
#[cfg(any(test, all(feature = "dsp", target_arch = "arm")))]
struct TapCursor {
    taps: LineTaps,
    v_len: usize,
    v: usize,
    a: usize,
    b: usize,
    /// Offsets of the next entry, of its (i, a, 0) and of its (i, 0, 0).
    at: usize,
    plane: usize,
    channel: usize,
    /// Whether plane tap `a` is inside the input.
    a_in: bool,
}

#[cfg(any(test, all(feature = "dsp", target_arch = "arm")))]
impl TapCursor {
    fn new(taps: LineTaps) -> Self {
        TapCursor {
            taps,
            v_len: taps.channels * taps.na * taps.nb,
            v: 0,
            a: 0,
            b: 0,
            at: taps.origin,
            plane: taps.origin,
            channel: taps.origin,
            a_in: taps.a_ok.0 == 0 && taps.a_ok.1 > 0,
        }
    }

    /// The input offset of the next entry's row, `None` for zeros.
    #[inline(always)]
    fn next_row(&mut self) -> Option<usize> {
        let t = &self.taps;
        let inside = self.v < self.v_len && self.a_in && self.b >= t.b_ok.0 && self.b < t.b_ok.1;
        let row = inside.then_some(self.at);
        self.v += 1;
        self.b += 1;
        self.at = self.at.wrapping_add(t.db);
        if self.b == t.nb {
            self.b = 0;
            self.a += 1;
            self.plane = self.plane.wrapping_add(t.da);
            if self.a == t.na {
                self.a = 0;
                self.channel = self.channel.wrapping_add(t.cs);
                self.plane = self.channel;
            }
            self.a_in = self.a >= t.a_ok.0 && self.a < t.a_ok.1;
            self.at = self.plane;
        }
        row
    }
}

/// [`fill`] on ARM (`dsp`, `mve`): the same line, its rows named by `taps`, handed out 16 line words at
/// a time by [`crate::arch::ChannelTaps`] and packed by [`crate::arch::pack_line_quads`]. One
/// copy for every engine and layer (flash), called once per line. Rows whose length is
/// not a multiple of 4, or more than [`MAX_ROW_TAPS`] taps per channel, go through [`fill`].
/// `padded`: the padding columns hold zeros already (an earlier line of the same `vp` and
/// `cols` wrote them), so only the input columns are written.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
#[inline(never)]
fn fill_taps(
    line: &mut [u32],
    (vp, cols, padded): (usize, usize, bool),
    span: (usize, usize, usize),
    input: &[i8],
    off: i16,
    taps: LineTaps,
) {
    use crate::arch::{ChannelTaps, LineRows};
    let (lo, hi, in0) = span;
    let vw = vp / 2;
    let len = hi.saturating_sub(lo).min(MAX_ROW);
    let per_channel = taps.na * taps.nb;
    let minor = channel_minor(taps.channels, per_channel);
    if len == 0 || !len.is_multiple_of(4) || per_channel > MAX_ROW_TAPS {
        if minor {
            // The channel-minor entries one by one: tap t's row of channel i is channel 0's
            // plus i · cs.
            let at = channel0_rows(taps, per_channel, 0);
            let (ic, cs) = (taps.channels, taps.cs);
            let (mut t, mut i) = (0, 0);
            fill(line, vp, cols, span, input, off, || {
                let (ti, ii) = (t, i);
                i += 1;
                if i == ic {
                    i = 0;
                    t += 1;
                }
                let a = *at.get(ti).filter(|_| ti < per_channel)?;
                (a != usize::MAX).then(|| a + ii * cs)
            });
            return;
        }
        let mut cursor = TapCursor::new(taps);
        fill(line, vp, cols, span, input, off, || cursor.next_row());
        return;
    }
    let Some(words) = line.get_mut(..vw * cols) else {
        return;
    };
    // The padding columns, as in `fill`, unless an earlier line of the same layout zeroed
    // them (`padded`): no fill writes there.
    if !padded {
        let (head, tail) = (lo.min(cols), (lo + len).min(cols));
        words[..head * vw].fill(0);
        words[tail * vw..].fill(0);
    }
    // Channel 0's row of every tap (a, b) from column in0 on, `usize::MAX` outside the
    // input; channel i's is that plus i · cs.
    let at = channel0_rows(taps, per_channel, in0);
    #[cfg(feature = "mve")]
    if minor {
        let chans = (taps.channels, taps.cs);
        fill_channel_pairs(words, vw, (lo, len), input, off, &at[..per_channel], chans);
        return;
    }
    let chans = (taps.channels, taps.cs);
    let mut entries = ChannelTaps::new(input, &at[..per_channel], chans, (len, off), vp);
    let mut rows = LineRows::new(len);
    let mut k0 = 0;
    while k0 < vw {
        let kn = (vw - k0).min(LineRows::CAPACITY / 2);
        if !entries.next_rows(&mut rows, 2 * kn) {
            return;
        }
        let Some(dst) = words.get_mut(lo * vw + k0..) else {
            return;
        };
        if !crate::arch::pack_line_quads(dst, vw, &rows) {
            return;
        }
        k0 += kn;
    }
}

/// Channel 0's input row of each of the first `taps` taps of a line, plus `in0`;
/// `usize::MAX` for a tap outside the input (and past `taps`).
#[cfg(all(feature = "dsp", target_arch = "arm"))]
#[inline(always)]
fn channel0_rows(taps: LineTaps, count: usize, in0: usize) -> [usize; MAX_ROW_TAPS] {
    let mut at = [usize::MAX; MAX_ROW_TAPS];
    let mut cursor = TapCursor::new(LineTaps {
        channels: 1,
        ..taps
    });
    for slot in at.iter_mut().take(count) {
        if let Some(o) = cursor.next_row() {
            *slot = o + in0;
        }
    }
    at
}

/// The channel-minor fill of a whole line ([`channel_minor`]) with Helium: the taps' channel
/// pairs (`arch::fill_channel_pairs`), then the line's padding entries read zeros. `at`:
/// channel 0's row of each tap ([`channel0_rows`]), `cs` the step to the next channel's; the
/// columns `lo .. lo + len` are filled.
#[cfg(all(feature = "mve", target_arch = "arm"))]
#[inline(always)]
fn fill_channel_pairs(
    words: &mut [u32],
    vw: usize,
    (lo, len): (usize, usize),
    input: &[i8],
    off: i16,
    at: &[usize],
    chans: (usize, usize),
) {
    let Some(dst) = words.get_mut(lo * vw..) else {
        return;
    };
    if !crate::arch::fill_channel_pairs(dst, vw, len, (input, at), chans, off) {
        return;
    }
    // Most layers have none: channels · taps is a multiple of 4.
    let k0 = at.len() * (chans.0 / 2);
    if k0 < vw {
        for j in lo..lo + len {
            for w in words.iter_mut().skip(j * vw + k0).take(vw - k0) {
                *w = 0;
            }
        }
    }
}

/// Most taps per channel (`na · nb`) [`fill_taps`] tabulates: 3 × 3 forward and 2 × 2
/// transposed ones in the EPSSN layers.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
const MAX_ROW_TAPS: usize = crate::arch::ChannelTaps::MAX_TAPS;

/// Whether a line's entries go channel-minor, `v = (tap, i)` (two channels of one tap fill a
/// word, and the Helium fill computes their rows' addresses itself: `arch::fill_channel_pairs`),
/// rather than channel-major, `v = (i, tap)`: with Helium, for an even number of `channels`
/// whose `taps` per channel [`fill_taps`] tabulates. Each engine lays its weights out in the
/// order its lines are filled in, so this one function decides both.
#[inline(always)]
const fn channel_minor(channels: usize, taps: usize) -> bool {
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    {
        channels >= 2 && channels.is_multiple_of(2) && taps <= MAX_ROW_TAPS
    }
    #[cfg(not(all(feature = "mve", target_arch = "arm")))]
    {
        let _ = (channels, taps);
        false
    }
}

/// Line words of a row of `cols` columns of `vp` entries (two i16 per word). This and the
/// helpers below are the fit formulas, shared by the run-time fit checks and the const
/// [`LINE_WORDS`]; the checks evaluate them in the order they always had (`vp` and the
/// columns first), so the compiled kernels are unchanged.
#[inline(always)]
const fn line_words(vp: usize, cols: usize) -> usize {
    vp * cols / 2
}

/// Line entries per column of a forward convolution, `v` = (input channel, plane tap, row
/// tap), padded to a multiple of 4.
#[inline(always)]
const fn conv_v(shape: &ConvShape) -> usize {
    let [kd, kh, _] = shape.kernel;
    up4(shape.in_channels * kd * kh)
}

/// Input columns one output row of a forward convolution reads.
#[inline(always)]
const fn conv_cols(shape: &ConvShape) -> usize {
    (shape.out_size[2] - 1) * shape.stride[2] + shape.kernel[2]
}

/// Line words a forward convolution fills per output row.
pub(crate) const fn conv_line_words(shape: &ConvShape) -> usize {
    line_words(conv_v(shape), conv_cols(shape))
}

/// Whether the forward convolution fits the engine's buffers.
pub(crate) fn conv_fits(shape: &ConvShape) -> bool {
    let kw = shape.kernel[2];
    let vp = conv_v(shape);
    let cols = conv_cols(shape);
    vp <= MAX_V
        && shape.in_size[2] <= MAX_ROW
        && line_words(vp, cols) <= LINE_WORDS
        && 2 * kw * vp / 2 <= WEIGHT_WORDS
        && shape.out_channels.div_ceil(conv_group(kw * vp / 2)) <= MAX_GROUPS
        && shape.out_channels <= MAX_FAST_CHANNELS
}

/// Most weight groups of a forward convolution: each further group refills the lines.
const MAX_GROUPS: usize = 2;

/// Output channels per weight group: an even number whose `n` words each fit
/// [`WEIGHT_WORDS`]. More than two groups refill the lines too often to beat im2col.
fn conv_group(n: usize) -> usize {
    (WEIGHT_WORDS / n.max(1) / 2 * 2).max(2)
}

/// Forward convolution (validated shape that [`conv_fits`]), requantising with `rq`.
/// Output channels go in groups whose expanded weights fit [`WEIGHT_WORDS`] (one group for
/// most layers; each further group refills the lines). `layer`: the model's index of the
/// layer, under which its laid-out weights may be kept when they form one group
/// ([`LineScratch::keep_weights`]); `None` lays them out at every call. Not in a Helium
/// build, whose forward line engine is [`conv_s8`].
#[cfg(not(all(feature = "mve", target_arch = "arm")))]
pub(crate) fn conv<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    layer: Option<usize>,
    rq: &[R],
    output: &mut [i8],
    scratch: &mut LineScratch,
) {
    let [_, _, iw] = shape.in_size;
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [_, _, sw] = shape.stride;
    let [_, _, pw] = shape.padding;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let v_len = ic * kd * kh;
    let vp = up4(v_len);
    let cols = (ow - 1) * sw + kw;
    // Line column c reads input column c − pw.
    let (lo, hi) = (pw.min(cols), (iw + pw).min(cols));
    let span = (lo, hi, lo.saturating_sub(pw));
    let off = params.input_offset as i16;
    let n = kw * vp / 2;
    let group = conv_group(n);
    // Line entry v is (i, kz, ky), or (kz, ky, i) where the line goes channel-minor.
    let minor = channel_minor(ic, kd * kh);
    let wv = |o: usize, kx: usize, v: usize| {
        if v >= v_len {
            return 0;
        }
        let v = if minor {
            v % ic * (kd * kh) + v / ic
        } else {
            v
        };
        params.weights[(o * v_len + v) * kw + kx]
    };
    // One group's weights may be kept; more groups take turns in the buffer.
    let key = layer.filter(|_| group >= oc).map(|l| (l, shape.stride));
    let slot = scratch.kept.claim(key, oc.div_ceil(2) * 2 * n, 1, 1);
    let base = scratch.kept.base(slot);
    let laid_out = scratch.kept.laid_out(slot, 1);
    let LineScratch {
        wbuf, line, acc, ..
    } = scratch;
    let out_plane = od * oh * ow;
    let rin = RowIn::new(ow, sw * vp / 2, n);
    let table = row_words(rq);
    let words = table
        .as_ref()
        .and_then(|t| crate::arch::RowWords::new(t.get(..oc)?));
    let mut o0 = 0;
    while o0 < oc {
        let g = group.min(oc - o0);
        let wb = &mut wbuf[base..base + g.div_ceil(2) * 2 * n];
        if !laid_out {
            // Weights [o][kx][v] (v = (i, kz, ky)) as i16 pairs, zero for the padding entries.
            for o in 0..g {
                for kx in 0..kw {
                    for j in 0..vp / 2 {
                        let k = kx * vp / 2 + j;
                        wb[wslot(o, k, n)] = word(wv(o0 + o, kx, 2 * j), wv(o0 + o, kx, 2 * j + 1));
                    }
                }
            }
            pad_pairs(wb, g, n);
        }
        // The group's channel pairs' biases, for every row of the layer.
        let biases = bias_pairs(params.bias.get(o0..o0 + g).unwrap_or(&[]));
        for z in 0..od {
            for y in 0..oh {
                // Lines after the call's first keep its zero padding columns.
                #[cfg(all(feature = "dsp", target_arch = "arm"))]
                fill_taps(
                    line,
                    (vp, cols, o0 > 0 || z > 0 || y > 0),
                    span,
                    input,
                    off,
                    LineTaps::forward(shape, z, y),
                );
                #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
                fill_forward(line, (vp, cols), span, input, off, shape, (z, y));
                row(
                    line,
                    rin,
                    wb,
                    &params.bias[o0..o0 + g],
                    &rq[o0..o0 + g],
                    params.relu,
                    SkipLut::None,
                    output,
                    RowOut {
                        plane: out_plane,
                        base: o0 * out_plane + (z * oh + y) * ow,
                        step: 1,
                    },
                    acc,
                    (words.and_then(|w| w.get(o0..o0 + g)), &biases),
                );
            }
        }
        o0 += g;
    }
}

/// The portable fill of output row `(z, y)`'s line of a forward convolution ([`conv`]):
/// entry `v = (i, kz, ky)`, counted up without divisions; taps outside the input read zeros.
#[cfg(not(all(feature = "dsp", target_arch = "arm")))]
fn fill_forward(
    line: &mut [u32],
    (vp, cols): (usize, usize),
    span: (usize, usize, usize),
    input: &[i8],
    off: i16,
    shape: &ConvShape,
    (z, y): (usize, usize),
) {
    let [id, ih, iw] = shape.in_size;
    let [kd, kh, _] = shape.kernel;
    let [sd, sh, _] = shape.stride;
    let [pd, ph, _] = shape.padding;
    let v_len = shape.in_channels * kd * kh;
    let (mut v, mut i, mut kz, mut ky) = (0, 0, 0, 0);
    fill(line, vp, cols, span, input, off, || {
        let (vi, ii, zi, yi) = (v, i, kz, ky);
        v += 1;
        ky += 1;
        if ky == kh {
            ky = 0;
            kz += 1;
            if kz == kd {
                kz = 0;
                i += 1;
            }
        }
        if vi >= v_len {
            return None;
        }
        let iz = (z * sd + zi).checked_sub(pd).filter(|&a| a < id)?;
        let iy = (y * sh + yi).checked_sub(ph).filter(|&a| a < ih)?;
        Some(((ii * id + iz) * ih + iy) * iw)
    });
}

/// The portable fill of output row `(bz, by)`'s line of a transposed phase with `(tz, ty)`
/// taps ([`transposed`]): entry `v = (i, a, b)` reads input plane `bz − a`, row `by − b`,
/// counted up without divisions; taps outside the input read zeros.
#[cfg(not(all(feature = "dsp", target_arch = "arm")))]
#[allow(clippy::too_many_arguments)]
fn fill_transposed(
    line: &mut [u32],
    (vp, cols): (usize, usize),
    span: (usize, usize, usize),
    input: &[i8],
    off: i16,
    shape: &ConvShape,
    (bz, by): (usize, usize),
    (tz, ty): (usize, usize),
) {
    let [id, ih, iw] = shape.in_size;
    let v_len = shape.in_channels * tz * ty;
    let (mut v, mut i, mut a, mut b) = (0, 0, 0, 0);
    fill(line, vp, cols, span, input, off, || {
        let (vi, ii, ai, bi) = (v, i, a, b);
        v += 1;
        b += 1;
        if b == ty {
            b = 0;
            a += 1;
            if a == tz {
                a = 0;
                i += 1;
            }
        }
        if vi >= v_len {
            return None;
        }
        let iz = bz.checked_sub(ai).filter(|&c| c < id)?;
        let iy = by.checked_sub(bi).filter(|&c| c < ih)?;
        Some(((ii * id + iz) * ih + iy) * iw)
    });
}

/// [`conv`] with the fast requantisation, when the worst-case accumulator `bound` allows it;
/// false (nothing written) otherwise, for the caller's engine that takes any requantisation.
/// The line engine is built for the fast requantisation alone: a second build of it for the
/// exact one would cost flash the firmware does not have.
pub(crate) fn run_conv(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    (bound, layer): (i64, Option<usize>),
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> bool {
    let oc = shape.out_channels;
    let Some(f) = fast_requants(params.requant, bound) else {
        return false;
    };
    // With Helium the int8 line takes every shape it can, and the caller's im2col engine
    // the others: one forward line engine in the flash, not two.
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    return conv_s8(shape, input, params, layer, &f[..oc], output, scratch);
    #[cfg(not(all(feature = "mve", target_arch = "arm")))]
    {
        conv(shape, input, params, layer, &f[..oc], output, scratch);
        true
    }
}

/// The forward line engine of a Helium build (the other builds' is `conv`), on an int8 line,
/// for the shapes it takes (false, nothing written, for the others, which the caller's im2col
/// engine runs): the line holds the raw inputs, entry `v = (tap,
/// channel)` of column `c` at byte `c·vp + v` (`arch::fill_bytes`), padding entries hold the
/// input's zero point `−input_offset`, and `input_offset · Σ w` is folded into each
/// channel's bias, so that `bias + Σ w·x` over the line is exactly the i16 line's `bias +
/// Σ w·(x + input_offset)` (padding adding nothing in both; modulo 2^32 like every
/// accumulator). The dot products take 16 int8 MACs per instruction (`arch::PairRowsS8`)
/// where the i16 line takes 8. Its shapes: an even output width whose accumulator rows all
/// fit (one call per line), one weight group, at most [`MAX_ROW_TAPS`] taps per channel, an
/// offset whose zero point is an int8, the fast requantisation's words.
#[cfg(all(feature = "mve", target_arch = "arm"))]
#[inline(never)]
fn conv_s8<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    layer: Option<usize>,
    rq: &[R],
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> bool {
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let sw = shape.stride[2];
    let (pw, iw) = (shape.padding[2], shape.in_size[2]);
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let per_channel = kd * kh;
    let (vp, cols) = (conv_v(shape), conv_cols(shape));
    let (lo, hi) = (pw.min(cols), (iw + pw).min(cols));
    let len = hi.saturating_sub(lo).min(MAX_ROW);
    let in0 = lo.saturating_sub(pw);
    let n = kw * vp;
    let pairs = oc.div_ceil(2);
    let table = row_words(rq);
    let words = table
        .as_ref()
        .and_then(|t| crate::arch::RowWords::new(t.get(..oc)?));
    let (Ok(pad), Some(plan), Some(words)) = (
        i8::try_from(-params.input_offset),
        crate::arch::PairRowsS8::new(sw * vp, n, ow / 2),
        words,
    ) else {
        return false;
    };
    let wpair = plan.pair_bytes();
    // The kept slot: the channel pairs' folded biases, then their weight blocks.
    let slot_words = 2 * pairs + pairs * wpair / 4;
    if !ow.is_multiple_of(2)
        || len == 0
        || per_channel > MAX_ROW_TAPS
        || vp > MAX_V
        || oc > MAX_FAST_CHANNELS
        || params.bias.len() < oc
        || slot_words > WEIGHT_WORDS
        || vp * cols > 4 * LINE_WORDS
        || 2 * pairs * ow > 2 * (MAX_POSITIONS + 1)
    {
        return false;
    }
    let key = layer.map(|l| (l, shape.stride));
    let slot = scratch.kept.claim(key, slot_words, 1, 1);
    let base = scratch.kept.base(slot);
    let laid_out = scratch.kept.laid_out(slot, 1);
    let LineScratch {
        wbuf, line, acc, ..
    } = scratch;
    let Some(kept) = wbuf.get_mut(base..base + slot_words) else {
        return false;
    };
    let (bias_words, weight_words) = kept.split_at_mut(2 * pairs);
    if !laid_out {
        lay_out_s8(shape, params, (n, vp, wpair), bias_words, weight_words);
    }
    let biases: &[[i32; 2]] = bytemuck::cast_slice(&*bias_words);
    let weights: &[u8] = bytemuck::cast_slice(&*weight_words);
    let line: &mut [u8] = bytemuck::cast_slice_mut(&mut line[..]);
    let pad_row = [pad; MAX_ROW];
    let out_plane = od * oh * ow;
    for z in 0..od {
        for y in 0..oh {
            if z == 0 && y == 0 {
                // The padding columns, once per call: no fill writes there.
                let right = line.get_mut((lo + len) * vp..cols * vp).unwrap_or(&mut []);
                right.fill(pad as u8);
                line.get_mut(..lo * vp).unwrap_or(&mut []).fill(pad as u8);
            }
            let taps = LineTaps::forward(shape, z, y);
            let at = channel0_rows(taps, per_channel, in0);
            let filled = line.get_mut(lo * vp..).is_some_and(|dst| {
                let rows = (input, &at[..per_channel]);
                crate::arch::fill_bytes(dst, vp, len, rows, (ic, taps.cs), &pad_row)
            });
            if !(filled && plan.run_channels(line, (weights, wpair), biases, acc, (ow, 0))) {
                return true;
            }
            let at = ((z * oh + y) * ow, out_plane);
            requant_rows(
                acc,
                (ow, oc),
                rq,
                words,
                params.relu,
                SkipLut::None,
                output,
                at,
            );
        }
    }
    true
}

/// [`conv_s8`]'s weights and folded biases: channel pair `k`'s bytes from `k · wpair`,
/// 16-byte blocks of the window's entries `e = kx·vp + v` (`v = (tap, channel)`), the pair's
/// first channel's block then its second's, zero past the window and for an odd count's
/// missing channel; bias `b + input_offset · Σ w`, wrapping as the accumulators do.
#[cfg(all(feature = "mve", target_arch = "arm"))]
fn lay_out_s8(
    shape: &ConvShape,
    params: &ConvParams<'_>,
    (n, vp, wpair): (usize, usize, usize),
    bias_words: &mut [u32],
    weight_words: &mut [u32],
) {
    let [kd, kh, kw] = shape.kernel;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let per_channel = kd * kh;
    let v_len = ic * per_channel;
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(weight_words);
    bytes.fill(0);
    for o in 0..oc {
        let mut sum = 0i32;
        for e in 0..n {
            let (kx, v) = (e / vp, e % vp);
            if v >= v_len {
                continue;
            }
            let tap_major = v % ic * per_channel + v / ic;
            let w = params.weights[(o * v_len + tap_major) * kw + kx];
            sum += w as i32;
            let at = (o / 2) * wpair + (e / 16) * 32 + (o % 2) * 16 + e % 16;
            if let Some(b) = bytes.get_mut(at) {
                *b = w as u8;
            }
        }
        let folded = params.bias[o].wrapping_add(params.input_offset.wrapping_mul(sum));
        if let Some(b) = bias_words.get_mut(o) {
            *b = folded as u32;
        }
        // An odd count's last pair: its second channel repeats the first's bias (its row is
        // computed, never requantised).
        if o % 2 == 0 && o + 1 == oc {
            if let Some(b) = bias_words.get_mut(o + 1) {
                *b = folded as u32;
            }
        }
    }
}

/// Taps of phase `f` on an axis with kernel `k`, stride `s`: `k = f + t·s`, `t < count`.
#[inline(always)]
pub(crate) fn phase_taps(k: usize, s: usize, f: usize) -> usize {
    if f >= k {
        0
    } else {
        (k - f).div_ceil(s)
    }
}

/// Line columns the transposed engine needs at most: input columns `−(⌈kw/sw⌉ − 1)` to
/// the last one any output reaches.
const fn transposed_cols(shape: &ConvShape) -> usize {
    let (sw, pw) = (shape.stride[2], shape.padding[2]);
    (shape.out_size[2] - 1 + pw) / sw + shape.kernel[2].div_ceil(sw)
}

/// Line entries per column of a transposed convolution (phase 0 has the most taps), padded
/// to a multiple of 4.
const fn transposed_v(shape: &ConvShape) -> usize {
    // One `div_ceil` call site (it is `#[track_caller]`) for both axes: their divide-by-zero
    // panics share one location, which keeps `transposed_fits` compiled as tightly as before.
    const fn taps(shape: &ConvShape, a: usize) -> usize {
        shape.kernel[a].div_ceil(shape.stride[a])
    }
    up4(shape.in_channels * taps(shape, 0) * taps(shape, 1))
}

/// Line words a transposed convolution fills per (plane, row) of a phase.
pub(crate) const fn transposed_line_words(shape: &ConvShape) -> usize {
    line_words(transposed_v(shape), transposed_cols(shape))
}

/// Whether the transposed convolution fits the engine's buffers (phase 0 has the most taps;
/// the x phases' weights, `kw` column taps in all, are held together).
pub(crate) fn transposed_fits(shape: &ConvShape) -> bool {
    let vp = transposed_v(shape);
    vp <= MAX_V
        && shape.in_size[2] <= MAX_ROW
        && line_words(vp, transposed_cols(shape)) <= LINE_WORDS
        && shape.out_channels.div_ceil(2) * 2 * shape.kernel[2] * vp / 2 <= WEIGHT_WORDS
        && shape.out_channels <= MAX_FAST_CHANNELS
        && shape.stride[2] <= MAX_STRIDE
        && shape.out_size[2] <= MAX_POSITIONS
}

/// A 2D shape as the line engine runs it: axes [H, W, 1] as [1, H, W], so that the engine's
/// rows run along W (same memory layout).
pub(crate) const fn line_shape(shape: &ConvShape) -> ConvShape {
    ConvShape {
        kernel: [1, shape.kernel[0], shape.kernel[1]],
        stride: [1, shape.stride[0], shape.stride[1]],
        padding: [0, shape.padding[0], shape.padding[1]],
        in_size: [1, shape.in_size[0], shape.in_size[1]],
        out_size: [1, shape.out_size[0], shape.out_size[1]],
        ..*shape
    }
}

/// The most line words ([`conv_line_words`], [`transposed_line_words`]) any layer of
/// `layers` needs, each by the formula of the engine its kind runs on: 2D layers as
/// [`super::conv2d_s8`] hands them to the engine, every transposed layer (the head too,
/// though its kernel has its own buffers: an upper bound).
pub(crate) const fn layers_line_words(layers: &[LayerShape]) -> usize {
    let mut most = 0;
    let mut i = 0;
    while i < layers.len() {
        let shape = ConvShape::of(&layers[i]);
        let words = match layers[i].kind {
            LayerKind::Conv2d => conv_line_words(&line_shape(&shape)),
            LayerKind::Conv3d => conv_line_words(&shape),
            LayerKind::ConvTranspose3d => transposed_line_words(&shape),
        };
        if words > most {
            most = words;
        }
        i += 1;
    }
    most
}

/// First output coordinate of phase `f` on an axis with stride `s`, padding `p` and `n`
/// outputs, and how many outputs the phase has.
#[inline(always)]
fn phase_first(f: usize, s: usize, p: usize, n: usize) -> (usize, usize) {
    let z0 = (f + s - p % s) % s;
    (z0, if z0 < n { (n - z0).div_ceil(s) } else { 0 })
}

/// What the weight layout of one `(fz, fy)` phase of a transposed convolution needs.
#[derive(Clone, Copy)]
struct Phase {
    fz: usize,
    fy: usize,
    /// Plane and row taps of the phase.
    tz: usize,
    ty: usize,
    /// Line entries per column (`ic · tz · ty`), and their words once padded to a multiple
    /// of 4.
    v_len: usize,
    vw: usize,
}

impl Phase {
    /// Phase `(fz, fy)` with `(tz, ty)` plane and row taps of `ic` input channels.
    fn new(ic: usize, (fz, fy): (usize, usize), (tz, ty): (usize, usize)) -> Self {
        let v_len = ic * tz * ty;
        let vw = up4(v_len) / 2;
        Phase {
            fz,
            fy,
            tz,
            ty,
            v_len,
            vw,
        }
    }
}

/// Each x phase's dot products have one shape for every row of the phase: their plans.
fn phase_plans(xs: &[XPhase; MAX_STRIDE], vw: usize, sw: usize) -> [RowPlan; MAX_STRIDE] {
    xs.map(|(_, nx, tx, _, _)| {
        let n = tx * vw;
        RowPlan::new(if n == 0 { 0 } else { vw }, nx, n, sw)
    })
}

/// One output row of a transposed phase with a row per channel ([`AccRows`] flat): each x
/// phase's dot products for every channel pair in one call (phase `fx` at `x0, x0 + sw, …` of
/// rows `width` words apart). `line`: the line and its filled words.
#[inline(always)]
fn run_phases(
    xs: &[XPhase; MAX_STRIDE],
    plans: &[RowPlan; MAX_STRIDE],
    (wbuf, vw): (&[u32; WEIGHT_WORDS], usize),
    (line, filled): (&[u32], usize),
    biases: &[[i32; 2]],
    (acc, width): (&mut RowAcc, usize),
    sw: usize,
) {
    let phases = xs.iter().zip(plans).take(sw.min(MAX_STRIDE));
    for (&(x0, nx, tx, wofs, start), plan) in phases {
        if nx == 0 {
            continue;
        }
        let w = (wbuf.get(wofs..).unwrap_or(&[]), 2 * tx * vw);
        let x = line.get(start..filled).unwrap_or(&[]);
        plan.run_channels(x, w, biases, acc, (width, x0));
    }
}

/// One x phase of a phase: (first output x, count, column taps, offset of its weights in the
/// weight buffer, first line word its first output reads).
type XPhase = (usize, usize, usize, usize, usize);

/// `vbase[v]`: weight index of line entry `v = (i, a, b)` of phase `(fz, fy)` for output
/// channel 0 and column tap 0 (`v = (a, b, i)` where the line goes channel-minor).
#[inline(always)]
fn phase_vbase(shape: &ConvShape, phase: &Phase, vbase: &mut [usize; MAX_V]) {
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, _] = shape.stride;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let Phase { fz, fy, tz, ty, .. } = *phase;
    // ((i·oc·kd + kz)·kh + ky)·kw with kz = fz + a·sd, ky = fy + b·sh (counted up).
    let taps_o = kd * kh * kw;
    // Line entry v is (i, a, b), or (a, b, i) where the line goes channel-minor.
    let minor = channel_minor(ic, tz * ty);
    let mut v = 0;
    for i in 0..ic {
        for a in 0..tz {
            for b in 0..ty {
                let at = if minor { (a * ty + b) * ic + i } else { v };
                if let Some(slot) = vbase.get_mut(at) {
                    *slot = i * oc * taps_o + ((fz + a * sd) * kh + fy + b * sh) * kw;
                }
                v += 1;
            }
        }
    }
}

/// The x phases of `phase`, their weights laid out in `wbuf` from word `base` on unless
/// `laid_out` (kept there by an earlier call).
#[inline(always)]
fn x_phases(
    shape: &ConvShape,
    params: &ConvParams<'_>,
    phase: &Phase,
    (ixlo, base, laid_out): (isize, usize, bool),
    wbuf: &mut [u32; WEIGHT_WORDS],
) -> [XPhase; MAX_STRIDE] {
    let [_, _, ow] = shape.out_size;
    let [kd, kh, kw] = shape.kernel;
    let [_, _, sw] = shape.stride;
    let [_, _, pw] = shape.padding;
    let oc = shape.out_channels;
    let Phase { v_len, vw, .. } = *phase;
    let mut xs = [(0usize, 0usize, 0usize, 0usize, 0usize); MAX_STRIDE];
    let mut wofs = base;
    let taps_o = kd * kh * kw;
    let mut vbase = [0usize; MAX_V];
    phase_vbase(shape, phase, &mut vbase);
    for (fx, x) in xs.iter_mut().enumerate().take(sw.min(MAX_STRIDE)) {
        let (tx, (x0, nx)) = (phase_taps(kw, sw, fx), phase_first(fx, sw, pw, ow));
        // Output x reads input columns bx − (tx − 1) ..= bx, bx = (x + pw) / sw.
        let bx0 = (x0 + pw) / sw;
        let start = (bx0 as isize + 1 - tx as isize - ixlo).max(0) as usize * vw;
        *x = (x0, nx, tx, wofs, start);
        // Weights [O][c'][v] as i16 pairs: column tap c' reads input column
        // bx − (tx − 1 − c').
        let n = tx * vw;
        if laid_out {
            wofs += oc.div_ceil(2) * 2 * n;
            continue;
        }
        let wv = |o: usize, cp: usize, v: usize| {
            if v >= v_len {
                return 0;
            }
            let kx = fx + (tx - 1 - cp) * sw;
            params.weights[vbase[v] + o * taps_o + kx]
        };
        let wb = &mut wbuf[wofs..wofs + oc.div_ceil(2) * 2 * n];
        for o in 0..oc {
            for cp in 0..tx {
                for j in 0..vw {
                    let k = cp * vw + j;
                    wb[wslot(o, k, n)] = word(wv(o, cp, 2 * j), wv(o, cp, 2 * j + 1));
                }
            }
        }
        pad_pairs(wb, oc, n);
        wofs += oc.div_ceil(2) * 2 * n;
    }
    xs
}

impl KeptWeights {
    /// A transposed convolution's slot ([`KeptWeights::claim`] under `layer`): each `(fz, fy)`
    /// phase at its own offset, when they all fit; the slot and its first word.
    fn claim_phases(&mut self, shape: &ConvShape, layer: Option<usize>) -> (Option<usize>, usize) {
        let [sd, sh, _] = shape.stride;
        let all: usize = (0..sd * sh)
            .map(|f| transposed_phase_words(shape, f / sh, f % sh))
            .sum();
        let slot = self.claim(layer.map(|l| (l, shape.stride)), all, sd, sh);
        (slot, self.base(slot))
    }

    /// The slot that keeps the `words` weight words of `key` (plane and row strides `sd`,
    /// `sh` index its ready bits): the one that holds them already, or a new one after the
    /// kept layers (all forgotten first when the buffer or the slots are full). `None` when
    /// this call cannot keep its weights: it lays them out from word 0, over whatever was
    /// kept, so every kept layer is forgotten.
    #[inline(never)]
    fn claim(
        &mut self,
        key: Option<WeightsKey>,
        words: usize,
        sd: usize,
        sh: usize,
    ) -> Option<usize> {
        let keepable = self.on && words <= WEIGHT_WORDS && sd <= MAX_STRIDE && sh <= MAX_STRIDE;
        let Some(key) = key.filter(|_| keepable) else {
            self.len = 0;
            self.used = 0;
            return None;
        };
        let held = self.slots.get(..self.len).unwrap_or(&[]);
        if let Some(i) = held.iter().position(|s| s.key == key) {
            return Some(i);
        }
        if self.len >= MAX_KEPT || self.used + words > WEIGHT_WORDS {
            self.len = 0;
            self.used = 0;
        }
        let slot = self.slots.get_mut(self.len)?;
        *slot = KeptSlot {
            key,
            base: self.used,
            ready: 0,
        };
        self.len += 1;
        self.used += words;
        Some(self.len - 1)
    }

    /// First word of `slot`'s weights (0 without a slot).
    #[inline(always)]
    fn base(&self, slot: Option<usize>) -> usize {
        slot.and_then(|i| self.slots.get(i)).map_or(0, |s| s.base)
    }

    /// Whether `slot` holds the weights of ready bit `bit` laid out already; marks them laid
    /// out from now on. Always false without a slot.
    #[inline(always)]
    fn laid_out(&mut self, slot: Option<usize>, bit: u64) -> bool {
        match slot.and_then(|i| self.slots.get_mut(i)) {
            Some(s) => {
                let was = s.ready & bit != 0;
                s.ready |= bit;
                was
            }
            None => false,
        }
    }
}

/// Transposed convolution (validated shape that [`transposed_fits`]) in the gather form,
/// phase by phase: outputs with the same `(z + pad) mod stride` on every axis use the same
/// taps, and along a row of one phase output `bx` reads input columns `bx − c`, a window
/// of the line buffer like a forward convolution's. The `sw` x phases of a (plane, row)
/// read the same input rows, so they share one line fill. `layer`: the model's index of the
/// layer `params` belong to, under which their laid-out weights may be kept
/// ([`LineScratch::keep_weights`]); `None` lays them out at every call.
#[allow(clippy::too_many_arguments)]
pub(crate) fn transposed<R: Apply>(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    layer: Option<usize>,
    rq: &[R],
    skip: SkipLut<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) {
    let [od, oh, ow] = shape.out_size;
    let [kd, kh, _] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, _] = shape.padding;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let out_plane = od * oh * ow;
    let off = params.input_offset as i16;
    let cols = transposed_cols(shape);
    let (ixlo, span) = transposed_span(shape);
    let (slot, mut phase_base) = scratch.kept.claim_phases(shape, layer);
    let table = row_words(rq);
    let words = table
        .as_ref()
        .and_then(|t| crate::arch::RowWords::new(t.get(..oc)?));
    let rows = AccRows::new(oc, ow, words.is_some(), 1, skip);
    let bias_table = bias_pairs(params.bias.get(..oc).unwrap_or(&[]));
    let biases = bias_table.get(..oc.div_ceil(2)).unwrap_or(&[]);
    let LineScratch {
        wbuf,
        line,
        acc,
        kept,
    } = scratch;
    for fz in 0..sd {
        let (tz, (z0, nz)) = (phase_taps(kd, sd, fz), phase_first(fz, sd, pd, od));
        for fy in 0..sh {
            let (ty, (y0, ny)) = (phase_taps(kh, sh, fy), phase_first(fy, sh, ph, oh));
            let base = if slot.is_some() { phase_base } else { 0 };
            phase_base += transposed_phase_words(shape, fz, fy);
            if nz * ny == 0 {
                continue;
            }
            let laid_out = kept.laid_out(slot, 1u64 << ((fz * MAX_STRIDE + fy) % 64));
            let phase = Phase::new(ic, (fz, fy), (tz, ty));
            let (vw, vp) = (phase.vw, 2 * phase.vw);
            let xs = x_phases(shape, params, &phase, (ixlo, base, laid_out), wbuf);
            let plans = phase_plans(&xs, vw, sw);
            // The hot loop stays in this body: moved into an `#[inline(always)]` helper it
            // cost about 95 k instructions per pair more on the QEMU Cortex-M7.
            for qz in 0..nz {
                let z = z0 + qz * sd;
                let bz = (z + pd) / sd;
                for qy in 0..ny {
                    let y = y0 + qy * sh;
                    let by = (y + ph) / sh;
                    #[cfg(all(feature = "dsp", target_arch = "arm"))]
                    {
                        // Lines after the phase's first keep its zero padding columns.
                        let taps = LineTaps::transposed(shape, (bz, by), (tz, ty));
                        let padded = qz > 0 || qy > 0;
                        fill_taps(line, (vp, cols, padded), span, input, off, taps);
                    }
                    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
                    fill_transposed(
                        line,
                        (vp, cols),
                        span,
                        input,
                        off,
                        shape,
                        (bz, by),
                        (tz, ty),
                    );
                    // Every x phase's dot products into one row of accumulators per
                    // channel (phase fx at x0, x0 + sw, …), then one requantisation pass
                    // over the whole output row.
                    let base = (z * oh + y) * ow;
                    if let (true, Some(words)) = (rows.flat, words) {
                        // A row per channel: each x phase's dot products for every channel
                        // pair in one call, then every row's requantisation in one.
                        let x = (&line[..], vw * cols);
                        run_phases(&xs, &plans, (wbuf, vw), x, biases, (acc, ow), sw);
                        let at = (base, out_plane);
                        requant_rows(acc, (ow, oc), rq, words, params.relu, skip, output, at);
                        continue;
                    }
                    let mut o = 0;
                    while o < oc {
                        let two = o + 1 < oc;
                        let b = biases.get(o / 2).copied().unwrap_or([0, 0]);
                        let (acc0, acc1) = rows.pair(acc, o);
                        let phases = xs.iter().zip(&plans).take(sw.min(MAX_STRIDE));
                        for (&(x0, nx, tx, wofs, start), plan) in phases {
                            if nx == 0 {
                                continue;
                            }
                            let n = tx * vw;
                            let w = wbuf.get(wofs + o * n..wofs + (o + 2) * n).unwrap_or(&[]);
                            let x = line.get(start..vw * cols).unwrap_or(&[]);
                            let a0 = acc0.get_mut(x0..).unwrap_or(&mut []);
                            let a1 = acc1.get_mut(x0..).unwrap_or(&mut []);
                            plan.run(x, w, b, (a0, a1));
                        }
                        let mut req = |a: &[i32], o: usize| {
                            let at = o * out_plane + base;
                            requant_row(&a[..ow], rq[o], params.relu, skip, output, at, 1);
                        };
                        req(acc0, o);
                        if two {
                            req(acc1, o + 1);
                        }
                        o += 2;
                    }
                }
            }
        }
    }
}

/// Where a transposed convolution's line lies: it holds input columns `ixlo..` (`ixlo ≤ 0`:
/// the taps left of column 0 are zeros), the input's columns at line columns `lo..hi`.
fn transposed_span(shape: &ConvShape) -> (isize, (usize, usize, usize)) {
    let (iw, kw, sw) = (shape.in_size[2], shape.kernel[2], shape.stride[2]);
    let ixlo = 1 - kw.div_ceil(sw) as isize;
    let cols = transposed_cols(shape);
    let (lo, hi) = (
        (-ixlo).clamp(0, cols as isize) as usize,
        (iw as isize - ixlo).clamp(0, cols as isize) as usize,
    );
    (ixlo, (lo, hi.max(lo), 0))
}

/// Words of the laid-out weights of a transposed convolution's phase `(fz, fy)`: every x
/// phase's `[O][c'][v]` pairs.
fn transposed_phase_words(shape: &ConvShape, fz: usize, fy: usize) -> usize {
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let (ic, oc) = (shape.in_channels, shape.out_channels);
    let vw = up4(ic * phase_taps(kd, sd, fz) * phase_taps(kh, sh, fy)) / 2;
    (0..sw.min(MAX_STRIDE))
        .map(|fx| oc.div_ceil(2) * 2 * phase_taps(kw, sw, fx) * vw)
        .sum::<usize>()
}

/// [`transposed`] with the fast requantisation and the skip table, when `bound` allows the
/// fast requantisation; false (nothing written) otherwise, as [`run_conv`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn run_transposed(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    bound: i64,
    layer: Option<usize>,
    skip: &Skip<'_>,
    output: &mut [i8],
    scratch: &mut LineScratch,
) -> bool {
    let oc = shape.out_channels;
    let Some(f) = fast_requants(params.requant, bound) else {
        return false;
    };
    let table = skip_table(skip);
    let lut = skip_lut(skip, &table);
    transposed(shape, input, params, layer, &f[..oc], lut, output, scratch);
    true
}

// The im2col engine: the forward convolutions' path for layers the line engine above does not
// take (`conv_fits`) but whose taps of one output fit `COL_LEN`.

/// Most taps per output the im2col path gathers (two i16 columns and their packed copy:
/// 4 KiB of stack).
pub const COL_LEN: usize = 512;

/// Fills `col[..K]` with the offset inputs of output position `(z, y, x)`, 0 at padding.
#[inline(always)]
fn gather(
    shape: &ConvShape,
    input: &[i8],
    off: i16,
    (z, y, x): (usize, usize, usize),
    col: &mut [i16],
) {
    let [id, ih, iw] = shape.in_size;
    let [kd, kh, kw] = shape.kernel;
    let [sd, sh, sw] = shape.stride;
    let [pd, ph, pw] = shape.padding;
    let (kz_lo, kz_hi) = tap_range(z, sd, pd, kd, id);
    let (ky_lo, ky_hi) = tap_range(y, sh, ph, kh, ih);
    let (kx_lo, kx_hi) = tap_range(x, sw, pw, kw, iw);
    let interior =
        kz_lo == 0 && ky_lo == 0 && kx_lo == 0 && kz_hi == kd && ky_hi == kh && kx_hi == kw;
    if !interior {
        col.fill(0);
    }
    if kx_lo >= kx_hi {
        return;
    }
    let len = kx_hi - kx_lo;
    let ix0 = x * sw + kx_lo - pw;
    for i in 0..shape.in_channels {
        for kz in kz_lo..kz_hi {
            let iz = z * sd + kz - pd;
            for ky in ky_lo..ky_hi {
                let iy = y * sh + ky - ph;
                let src = &input[((i * id + iz) * ih + iy) * iw + ix0..][..len];
                let dst = &mut col[((i * kd + kz) * kh + ky) * kw + kx_lo..][..len];
                for (d, &s) in dst.iter_mut().zip(src) {
                    *d = s as i16 + off;
                }
            }
        }
    }
}

/// `acc[n] += Σ_t col[t] · ws[n][t]` (all slices of equal length): one position.
#[inline(always)]
fn dot<const N: usize>(col: &[i16], ws: [&[i8]; N], mut acc: [i32; N]) -> [i32; N] {
    for (a, w) in acc.iter_mut().zip(ws) {
        for (&c, &w) in col.iter().zip(w) {
            *a += c as i32 * w as i32;
        }
    }
    acc
}

/// The gathered columns of two output positions (`k ≤ COL_LEN` taps each), laid out for
/// the build's dot product.
///
/// Portable build: one word per tap holding both positions' values (`lo` = position 0), so
/// one word load and one weight load feed two MACs (SMLABB/SMLATB on Cortex-M7; two
/// accumulators leave LLVM's 4× unroll enough registers).
///
/// `dsp` build (CMSIS-NN style): per position and per group of 4 taps the words
/// `(c0, c2)` and `(c1, c3)`, matching `SXTB16` / `SXTB16 ROR 8` of 4 weight bytes, so
/// one weight word and two `SMLAD` give 4 MACs of one position; the last `k mod 4` taps
/// stay scalar.
pub(crate) struct PairColumns {
    k: usize,
    #[cfg(not(feature = "dsp"))]
    words: [u32; COL_LEN],
    #[cfg(feature = "dsp")]
    pairs: [[u32; COL_LEN / 2]; 2],
    #[cfg(feature = "dsp")]
    tail: [[i16; 4]; 2],
}

impl PairColumns {
    pub(crate) fn new() -> Self {
        PairColumns {
            k: 0,
            #[cfg(not(feature = "dsp"))]
            words: [0; COL_LEN],
            #[cfg(feature = "dsp")]
            pairs: [[0; COL_LEN / 2]; 2],
            #[cfg(feature = "dsp")]
            tail: [[0; 4]; 2],
        }
    }

    /// Packs the columns `c0`, `c1` (equal lengths, at most [`COL_LEN`]).
    #[inline(always)]
    pub(crate) fn pack(&mut self, c0: &[i16], c1: &[i16]) {
        self.k = c0.len().min(c1.len()).min(COL_LEN);
        #[cfg(not(feature = "dsp"))]
        for ((w, &a), &b) in self.words[..self.k].iter_mut().zip(c0).zip(c1) {
            *w = crate::arch::pack(a, b);
        }
        #[cfg(feature = "dsp")]
        for (p, c) in [c0, c1].into_iter().enumerate() {
            let groups = self.k / 4;
            let (head, tail) = c[..self.k].split_at(groups * 4);
            for (g, w) in head.chunks_exact(4).zip(self.pairs[p].chunks_exact_mut(2)) {
                w[0] = crate::arch::pack(g[0], g[2]);
                w[1] = crate::arch::pack(g[1], g[3]);
            }
            self.tail[p] = [0; 4];
            self.tail[p][..tail.len()].copy_from_slice(tail);
        }
    }

    /// `acc[p] += Σ_t column_p[t] · w[t]` for the two positions (`w` has `k` weights).
    #[inline(always)]
    pub(crate) fn dot(&self, w: &[i8], acc: [i32; 2]) -> [i32; 2] {
        let [mut a0, mut a1] = acc;
        #[cfg(not(feature = "dsp"))]
        for (&c, &w) in self.words[..self.k].iter().zip(w) {
            let w = w as i32;
            a0 += (c as u16 as i16 as i32) * w;
            a1 += ((c as i32) >> 16) * w;
        }
        #[cfg(feature = "dsp")]
        {
            use crate::arch::{smlad, sxtb16, sxtb16_ror8};
            let groups = self.k / 4;
            let (wg, wt) = w[..self.k.min(w.len())].split_at(groups * 4);
            let (p0, p1) = (&self.pairs[0][..2 * groups], &self.pairs[1][..2 * groups]);
            for ((w4, x0), x1) in wg
                .chunks_exact(4)
                .zip(p0.chunks_exact(2))
                .zip(p1.chunks_exact(2))
            {
                let word = u32::from_le_bytes([w4[0] as u8, w4[1] as u8, w4[2] as u8, w4[3] as u8]);
                let (even, odd) = (sxtb16(word), sxtb16_ror8(word));
                a0 = smlad(x0[1], odd, smlad(x0[0], even, a0));
                a1 = smlad(x1[1], odd, smlad(x1[0], even, a1));
            }
            for ((&w, &t0), &t1) in wt.iter().zip(&self.tail[0]).zip(&self.tail[1]) {
                a0 += t0 as i32 * w as i32;
                a1 += t1 as i32 * w as i32;
            }
        }
        [a0, a1]
    }
}

/// Convolution of a validated shape whose taps per output fit [`COL_LEN`], two output
/// positions at a time (an odd last position alone, two channels at a time).
pub(crate) fn im2col_engine(
    shape: &ConvShape,
    input: &[i8],
    params: &ConvParams<'_>,
    output: &mut [i8],
) {
    let [_, oh, ow] = shape.out_size;
    let k = shape.in_channels * shape.kernel.iter().product::<usize>();
    let positions = shape.out_size.iter().product::<usize>();
    let oc = shape.out_channels;
    // |offset| ≤ 255 is validated, so offset inputs fit i16.
    let off = params.input_offset as i16;
    let mut col0 = [0i16; COL_LEN];
    let mut col1 = [0i16; COL_LEN];
    let mut packed = PairColumns::new();
    let at = |p: usize| (p / (oh * ow), (p / ow) % oh, p % ow);
    let mut p = 0;
    while p < positions {
        let pair = p + 1 < positions;
        gather(shape, input, off, at(p), &mut col0[..k]);
        if pair {
            gather(shape, input, off, at(p + 1), &mut col1[..k]);
        }
        let (c0, c1) = (&col0[..k], &col1[..k]);
        if pair {
            packed.pack(c0, c1);
            let out_pos = &mut output[p..];
            for o in 0..oc {
                let w = &params.weights[o * k..(o + 1) * k];
                let b = params.bias[o];
                let acc = packed.dot(w, [b, b]);
                for (q, &a) in acc.iter().enumerate() {
                    let t = params.requant[o].apply(a);
                    out_pos[o * positions + q] = finish(t, params.relu, None);
                }
            }
        } else {
            // The last, unpaired position: two channels at a time.
            let mut o = 0;
            while o < oc {
                let n = if o + 1 < oc { 2 } else { 1 };
                let w0 = &params.weights[o * k..(o + 1) * k];
                let acc = if n == 2 {
                    let w1 = &params.weights[(o + 1) * k..(o + 2) * k];
                    dot::<2>(c0, [w0, w1], [params.bias[o], params.bias[o + 1]])
                } else {
                    [dot::<1>(c0, [w0], [params.bias[o]])[0], 0]
                };
                for (m, &a) in acc.iter().enumerate().take(n) {
                    let t = params.requant[o + m].apply(a);
                    output[(o + m) * positions + p] = finish(t, params.relu, None);
                }
                o += n;
            }
        }
        p += if pair { 2 } else { 1 };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config;

    #[test]
    fn kept_weights_pack_layers_and_forget_them_when_overwritten() {
        let mut k = KeptWeights::default();
        let s2 = [2; 3];
        // Not keeping: no slot.
        assert_eq!(k.claim(Some((0, s2)), 100, 2, 2), None);
        k.on = true;
        let a = k.claim(Some((0, s2)), 100, 2, 2);
        let b = k.claim(Some((1, s2)), 200, 2, 2);
        assert_eq!((a, b), (Some(0), Some(1)));
        assert_eq!((k.base(a), k.base(b)), (0, 100));
        // The same layer again: its slot, ready bits kept.
        assert!(!k.laid_out(b, 1));
        assert_eq!(k.claim(Some((1, s2)), 200, 2, 2), b);
        assert!(k.laid_out(b, 1));
        assert!(!k.laid_out(b, 2));
        // Another stride is another layout.
        assert_eq!(k.claim(Some((1, [1; 3])), 200, 1, 1), Some(2));
        // Too big for what is left: everything forgotten, the new layer from word 0.
        let c = k.claim(Some((3, s2)), WEIGHT_WORDS - 100, 2, 2);
        assert_eq!((c, k.base(c)), (Some(0), 0));
        assert!(!k.laid_out(c, 1));
        assert_eq!(k.claim(Some((1, s2)), 200, 2, 2), Some(0));
        assert!(
            !k.laid_out(Some(0), 1),
            "layer 1 was laid out again over layer 3"
        );
        // A call that cannot keep (no layer) writes from word 0: nothing stays kept.
        assert_eq!(k.claim(None, 10, 1, 1), None);
        assert_eq!(k.claim(Some((1, s2)), 200, 2, 2), Some(0));
        assert!(!k.laid_out(Some(0), 1));
        // More layers than slots: the first slot again.
        k.on = true;
        k.len = 0;
        k.used = 0;
        for l in 0..MAX_KEPT {
            assert_eq!(k.claim(Some((l, s2)), 10, 2, 2), Some(l));
        }
        assert_eq!(k.claim(Some((MAX_KEPT, s2)), 10, 2, 2), Some(0));
        assert_eq!(k.base(Some(0)), 0);
        // Too large to keep at all, or strides past the ready bits.
        assert_eq!(k.claim(Some((9, s2)), WEIGHT_WORDS + 1, 2, 2), None);
        assert_eq!(k.claim(Some((9, s2)), 10, MAX_STRIDE + 1, 1), None);
        assert_eq!(k.len, 0);
    }

    #[test]
    fn line_words_come_from_the_layers_fit_formulas() {
        // Every layer of the build's spec takes the engine its kind runs on (the head, the last
        // layer, has its own kernel).
        for l in &config::LAYERS[..config::LAYER_COUNT - 1] {
            let shape = ConvShape::of(l);
            let fits = match l.kind {
                LayerKind::Conv2d => conv_fits(&line_shape(&shape)),
                LayerKind::Conv3d => conv_fits(&shape),
                LayerKind::ConvTranspose3d => transposed_fits(&shape),
            };
            assert!(fits, "{} does not take the line engine", l.name);
        }
        // The buffer is the longest lines rounded up to whole 1024 words, no more.
        let need = layers_line_words(&config::LAYERS);
        assert!(
            need <= LINE_WORDS && LINE_WORDS < need + 1024,
            "{need} {LINE_WORDS}"
        );
        // In EPSSN-S and EPSSN-P d1 has the longest lines (S: 612 words, so 1024 as measured).
        let d1 = conv_line_words(&ConvShape::of(&config::LAYER_D1));
        assert_eq!(need, d1);
        assert_eq!(LINE_WORDS, d1.div_ceil(1024) * 1024);
    }

    /// The entries the forward engine's closure names for output row (z, y).
    fn forward_entries(
        shape: &ConvShape,
        z: usize,
        y: usize,
        vp: usize,
    ) -> std::vec::Vec<Option<usize>> {
        let [id, ih, iw] = shape.in_size;
        let [kd, kh, _] = shape.kernel;
        let [sd, sh, _] = shape.stride;
        let [pd, ph, _] = shape.padding;
        let v_len = shape.in_channels * kd * kh;
        (0..vp)
            .map(|v| {
                if v >= v_len {
                    return None;
                }
                let (i, zi, yi) = (v / (kd * kh), v / kh % kd, v % kh);
                let iz = (z * sd + zi).checked_sub(pd).filter(|&a| a < id)?;
                let iy = (y * sh + yi).checked_sub(ph).filter(|&a| a < ih)?;
                Some(((i * id + iz) * ih + iy) * iw)
            })
            .collect()
    }

    #[test]
    fn tap_cursor_names_the_engines_rows() {
        use super::super::testutil::Rng;
        let mut rng = Rng(0x5eed_cafe);
        for case in 0..400 {
            let dims = [1 + rng.below(6), 1 + rng.below(6), 1 + rng.below(6)];
            let shape = ConvShape {
                in_channels: 1 + rng.below(5),
                out_channels: 1,
                kernel: [1 + rng.below(4), 1 + rng.below(4), 1],
                stride: [1 + rng.below(3), 1 + rng.below(3), 1],
                padding: [rng.below(3), rng.below(3), 0],
                output_padding: [0; 3],
                in_size: dims,
                out_size: [8, 8, 1],
            };
            let [kd, kh, _] = shape.kernel;
            let v_len = shape.in_channels * kd * kh;
            let vp = up4(v_len);
            let (z, y) = (rng.below(8), rng.below(8));
            let mut cursor = TapCursor::new(LineTaps::forward(&shape, z, y));
            let got: std::vec::Vec<_> = (0..vp).map(|_| cursor.next_row()).collect();
            assert_eq!(
                got,
                forward_entries(&shape, z, y, vp),
                "forward case {case}"
            );
            // The transposed engine's closure: plane bz − a, row by − b.
            let [id, ih, iw] = shape.in_size;
            let (tz, ty) = (1 + rng.below(3), 1 + rng.below(3));
            let (bz, by) = (rng.below(id + 3), rng.below(ih + 3));
            let v_len = shape.in_channels * tz * ty;
            let vp = up4(v_len);
            let want: std::vec::Vec<_> = (0..vp)
                .map(|v| {
                    if v >= v_len {
                        return None;
                    }
                    let (i, a, b) = (v / (tz * ty), v / ty % tz, v % ty);
                    let iz = bz.checked_sub(a).filter(|&c| c < id)?;
                    let iy = by.checked_sub(b).filter(|&c| c < ih)?;
                    Some(((i * id + iz) * ih + iy) * iw)
                })
                .collect();
            let mut cursor = TapCursor::new(LineTaps::transposed(&shape, (bz, by), (tz, ty)));
            let got: std::vec::Vec<_> = (0..vp).map(|_| cursor.next_row()).collect();
            assert_eq!(got, want, "transposed case {case}");
        }
    }
}
