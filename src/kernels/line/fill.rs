//! The line fills: gathering the input rows one output row reads into the line buffer, by a
//! closure naming each entry's row ([`fill`]) or, on ARM, by a tap description ([`LineTaps`],
//! [`fill_taps`]).

use super::*;

/// Fills the line: `src()`, called once for each `v` in `0..vp` in order, is the input
/// offset of the row that entry `v` reads (`None` → all zeros); line columns `lo..hi` read that row from input
/// column `in0` on, the other columns are 0 (padding).
///
/// Word by word: entries `2k`, `2k + 1` of every column come from two rows read in step
/// ([`crate::arch::pack_rows`]).
#[inline(always)]
pub(super) fn fill(
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
pub(super) struct LineTaps {
    channels: usize,
    pub(super) cs: usize,
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
    pub(super) fn forward(shape: &ConvShape, z: usize, y: usize) -> Self {
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
    pub(super) fn transposed(
        shape: &ConvShape,
        (bz, by): (usize, usize),
        (tz, ty): (usize, usize),
    ) -> Self {
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
pub(super) fn fill_taps(
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
pub(super) fn channel0_rows(taps: LineTaps, count: usize, in0: usize) -> [usize; MAX_ROW_TAPS] {
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
pub(super) fn fill_channel_pairs(
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

/// The portable fill of output row `(z, y)`'s line of a forward convolution ([`conv`]):
/// entry `v = (i, kz, ky)`, counted up without divisions; taps outside the input read zeros.
#[cfg(not(all(feature = "dsp", target_arch = "arm")))]
pub(super) fn fill_forward(
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
pub(super) fn fill_transposed(
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

#[cfg(test)]
mod tests {
    use super::*;

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
        use crate::kernels::testutil::Rng;
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
