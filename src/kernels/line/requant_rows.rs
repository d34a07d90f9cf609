//! The rows of accumulators the line engines fill and their requantisation: the per-channel
//! [`RowRequant`] words, the skip table, and the row stores shared by every engine.

use super::*;

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
    /// [`crate::kernels::finish`] without a skip), and the larger of `max` and those values
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
/// `out[start + q · step]` = ReLU, skip add (table), int8 clamp, as
/// [`crate::kernels::finish`]. The skip kind and the ReLU are decided once per row, so each
/// output costs the requantisation and about 8 instructions more. Not inlined: in its own
/// function the loop keeps its operands in registers instead of reloading them from the
/// engine's stack frame.
#[inline(never)]
pub(super) fn requant_row<R: Apply>(
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
    pub(super) positions: usize,
    pub(super) words: usize,
    /// The dot products' shape, checked once for every row of the layer.
    pub(super) plan: crate::arch::RowPlan,
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
pub(super) const MAX_POSITIONS: usize = MAX_ROW;

/// Accumulators of one line: a row per channel, `width` apart, when every channel's row fits
/// ([`AccRows::flat`]); else two rows of [`MAX_POSITIONS`] + 1, reused by each channel pair.
pub(crate) type RowAcc = [i32; 2 * (MAX_POSITIONS + 1)];

/// How a line's channel pairs use the accumulators: one row per channel, so that a single
/// call requantises every channel of the line ([`requant_rows`]), or the two shared rows.
#[derive(Clone, Copy)]
pub(super) struct AccRows {
    width: usize,
    pub(super) flat: bool,
}

impl AccRows {
    /// Rows of `width` for `oc` channels (an odd last channel's pair partner is a spare row):
    /// flat when they fit and the row loop can take every channel at once (Helium, the fast
    /// requantisation's words, step-1 stores, a skip read in place or none).
    pub(super) fn new(
        oc: usize,
        width: usize,
        words: bool,
        step: usize,
        skip: SkipLut<'_>,
    ) -> Self {
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
    pub(super) fn pair(self, acc: &mut RowAcc, o: usize) -> (&mut [i32], &mut [i32]) {
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
pub(super) fn row_words<R: Apply>(rq: &[R]) -> Option<[[i32; 5]; MAX_FAST_CHANNELS]> {
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
pub(super) fn bias_pairs(bias: &[i32]) -> [[i32; 2]; MAX_FAST_CHANNELS / 2] {
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
pub(super) fn requant_rows<R: Apply>(
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
