//! The types both instruction-set backends and the portable loops share: a channel's
//! requantisation words ([`RowWords`]), the two cost-volume combinations ([`Combine`]), the
//! shape checks the row loops and the line fills make, and on ARM with `dsp` the rows of a line
//! fill as the assembly reads them (`LineRows`, `ChannelTaps`, `ZERO_ROW`). Nothing here
//! names an instruction set; `arch` and its backends import from here, never the reverse.

/// Each channel's requantisation as the five words the row loops take (multiplier, left1,
/// right, half, neg: the tuple of `requant_row_s8`), every shift checked below 32 once, when
/// a layer starts, rather than on every row.
#[derive(Clone, Copy, Debug)]
pub struct RowWords<'a>(&'a [[i32; 5]]);

impl<'a> RowWords<'a> {
    /// The words of `words.len()` channels; `None` if a `left1` or `right` is outside 0..32.
    pub fn new(words: &'a [[i32; 5]]) -> Option<Self> {
        let shifts = |p: &[i32; 5]| (0..32).contains(&p[1]) && (0..32).contains(&p[2]);
        words.iter().all(shifts).then_some(RowWords(words))
    }

    /// Channels `range` of these.
    #[inline(always)]
    pub fn get(self, range: core::ops::Range<usize>) -> Option<Self> {
        self.0.get(range).map(RowWords)
    }

    /// How many channels.
    #[inline(always)]
    pub fn len(self) -> usize {
        self.0.len()
    }

    /// True for no channels.
    #[inline(always)]
    pub fn is_empty(self) -> bool {
        self.0.is_empty()
    }

    /// The words themselves, one `[multiplier, left1, right, half, neg]` per channel.
    #[inline(always)]
    pub fn words(self) -> &'a [[i32; 5]] {
        self.0
    }
}

/// How the one-column cost-volume loops combines the reference value with the warped source value.
#[derive(Clone, Copy)]
pub enum Combine {
    /// `reference − w`, read at table offset 255 (the variance of two views).
    Difference,
    /// `reference + w`, read at table offset 256 (the mean of two views).
    Sum,
}

/// The line engine's whole-line fills on ARM (`dsp`, and with `mve` Helium): the rows of a
/// line as a table the assembly reads, and the fill itself.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
mod line_rows {
    /// One input row of a line fill and the offset its entries get, as `arch::pack_line_quads`
    /// reads them: the row's address and the offset widened to a word.
    #[repr(C)]
    #[derive(Clone, Copy)]
    pub(crate) struct LineRow {
        ptr: *const i8,
        off: i32,
    }

    /// Up to [`LineRows::CAPACITY`] input rows of one line fill, in line-entry order (entries
    /// `2k` and `2k + 1` fill line word `k` of every column), every one at least `need` bytes
    /// long: [`LineRows::push`] refuses a shorter row, so `arch::pack_line_quads` may read `need`
    /// bytes of each.
    pub struct LineRows<'a> {
        /// `rows[..len]` are written (the rest is never read: no clearing per fill).
        pub(crate) rows: [core::mem::MaybeUninit<LineRow>; LineRows::CAPACITY],
        pub(crate) len: usize,
        pub(crate) need: usize,
        _rows: core::marker::PhantomData<&'a [i8]>,
    }

    impl<'a> LineRows<'a> {
        /// Rows one call takes (16 line words: 256 bytes of stack).
        pub const CAPACITY: usize = 32;

        /// No rows yet; every row must hold `need` entries.
        #[inline(always)]
        pub fn new(need: usize) -> Self {
            LineRows {
                rows: [const { core::mem::MaybeUninit::uninit() }; LineRows::CAPACITY],
                len: 0,
                need,
                _rows: core::marker::PhantomData,
            }
        }

        /// Forgets the rows (the next call's rows follow).
        #[inline(always)]
        pub fn clear(&mut self) {
            self.len = 0;
        }

        /// The pairs of rows and the blocks of four columns of a fill of a `dst_len`-word
        /// line `vw` words wide: `Some((0, 0))` for no rows; `None` for an odd number of
        /// rows, `need` not a positive multiple of 4, or a line too short for the last row's
        /// last column. The check both fills (`arch::pack_line_quads` and its Helium twin) make.
        #[inline(always)]
        pub(crate) fn fill_shape(&self, dst_len: usize, vw: usize) -> Option<(usize, usize)> {
            let (pairs, need) = (self.len / 2, self.need);
            if self.len == 0 {
                return Some((0, 0));
            }
            let fits = self.len.is_multiple_of(2)
                && need >= 4
                && need.is_multiple_of(4)
                && vw <= usize::MAX / 16
                && (need - 1)
                    .checked_mul(vw)
                    .and_then(|e| e.checked_add(pairs - 1))
                    .is_some_and(|last| last < dst_len);
            fits.then_some((pairs, need / 4))
        }

        /// Replaces the rows with `count` rows from `next` (each row and the offset its entries
        /// get); false, keeping those before it, at the first row shorter than `need` or when
        /// `count` exceeds [`LineRows::CAPACITY`].
        #[inline(always)]
        pub fn fill_with(
            &mut self,
            count: usize,
            mut next: impl FnMut() -> (&'a [i8], i16),
        ) -> bool {
            // The count stays in a register: stores into `rows` cannot reach it.
            let mut len = 0;
            let mut ok = count <= LineRows::CAPACITY;
            for slot in self.rows.iter_mut().take(count) {
                let (row, off) = next();
                if row.len() < self.need {
                    ok = false;
                    break;
                }
                slot.write(LineRow {
                    ptr: row.as_ptr(),
                    off: off as i32,
                });
                len += 1;
            }
            self.len = len;
            ok
        }

        /// Appends `row`, whose entries get `off`; false, appending nothing, when it is full or
        /// `row` is shorter than `need`.
        #[inline(always)]
        pub fn push(&mut self, row: &'a [i8], off: i16) -> bool {
            if row.len() < self.need {
                return false;
            }
            let Some(slot) = self.rows.get_mut(self.len) else {
                return false;
            };
            slot.write(LineRow {
                ptr: row.as_ptr(),
                off: off as i32,
            });
            self.len += 1;
            true
        }
    }

    /// The rows of a whole line as the line engines name them: entry `v = i · T + t` (channel
    /// `i < channels`, tap `t < T`) reads `need` bytes of `input` from `at[t] + i · cs` when
    /// tap `t` is inside the input (`at[t] != usize::MAX`), the zero row without offset
    /// otherwise; after the `channels · T` entries, zero rows up to `entries`. Built once per
    /// line ([`ChannelTaps::new`] checks every channel's row against `input`), it hands the rows
    /// out in order, a chunk at a time ([`ChannelTaps::next_rows`]), at about 7 instructions
    /// per row: each tap's row for the next channel is its row plus `cs`.
    pub struct ChannelTaps<'a> {
        /// The next channel's row of each tap, and the address step to the channel after.
        row: [LineRow; ChannelTaps::MAX_TAPS],
        step: [usize; ChannelTaps::MAX_TAPS],
        taps: usize,
        channels: usize,
        need: usize,
        /// Zero rows after the channels.
        pad: usize,
        /// Where the next row is: channel, tap, zero rows handed out.
        channel: usize,
        tap: usize,
        padded: usize,
        _rows: core::marker::PhantomData<&'a [i8]>,
    }

    /// The zero row of padding entries (rows of at most 256 entries).
    pub(crate) static ZERO_ROW: [i8; 256] = [0; 256];

    impl<'a> ChannelTaps<'a> {
        /// Most taps per channel (3 × 3 in the EPSSN layers).
        pub const MAX_TAPS: usize = 16;

        /// The rows of one line (see the type), entries of channel rows offset by `off`; none at
        /// all ([`ChannelTaps::next_rows`] refuses every call) when more than
        /// [`ChannelTaps::MAX_TAPS`] taps, `need` over 256, `entries` under `channels · T`, or a
        /// row of a tap inside the input not wholly in `input`. Returned by value, not in an
        /// `Option`: inlined, it is built in place instead of copied out.
        #[inline(always)]
        pub fn new(
            input: &'a [i8],
            at: &[usize],
            (channels, cs): (usize, usize),
            (need, off): (usize, i16),
            entries: usize,
        ) -> Self {
            let zero = LineRow {
                ptr: ZERO_ROW.as_ptr(),
                off: 0,
            };
            let mut taps = ChannelTaps {
                row: [zero; Self::MAX_TAPS],
                step: [0; Self::MAX_TAPS],
                taps: at.len(),
                channels,
                need,
                pad: 0,
                channel: 0,
                tap: 0,
                padded: 0,
                _rows: core::marker::PhantomData,
            };
            let last = channels.saturating_sub(1).checked_mul(cs);
            let pad = channels
                .checked_mul(at.len())
                .and_then(|n| entries.checked_sub(n));
            let fits = at.len() <= Self::MAX_TAPS && need <= ZERO_ROW.len();
            let mut ok = fits;
            if let (Some(last), Some(pad), true) = (last, pad, fits) {
                taps.pad = pad;
                for ((r, s), &a) in taps.row.iter_mut().zip(taps.step.iter_mut()).zip(at) {
                    if a == usize::MAX {
                        continue;
                    }
                    // Every channel's row lies in `input`: the last channel's ends within it.
                    let end = a.checked_add(last).and_then(|e| e.checked_add(need));
                    if end.is_none_or(|e| e > input.len()) {
                        ok = false;
                        break;
                    }
                    *r = LineRow {
                        ptr: input.as_ptr().wrapping_add(a),
                        off: off as i32,
                    };
                    *s = cs;
                }
            } else {
                ok = false;
            }
            // Refused: no rows, every `next_rows` call refuses. One exit, so that the table is
            // built where the caller keeps it rather than copied there (220 bytes per line).
            if !ok {
                taps.taps = 0;
                taps.channels = 0;
                taps.pad = 0;
            }
            taps
        }

        /// Replaces `rows` with the next `count` rows (at most [`LineRows::CAPACITY`], and no more
        /// than are left); false, leaving `rows` empty, otherwise or when `rows` wants longer
        /// rows than these (`count` 0 of a refused line is refused too).
        #[inline(never)]
        pub fn next_rows(&mut self, rows: &mut LineRows<'a>, count: usize) -> bool {
            rows.len = 0;
            if count > LineRows::CAPACITY || rows.need > self.need || self.channels == 0 {
                return false;
            }
            let mut n = 0;
            while n < count && self.channel < self.channels && self.taps > 0 {
                let k = (self.taps - self.tap).min(count - n);
                let (t0, t1) = (self.tap, self.tap + k);
                for ((slot, r), &s) in rows.rows[n..n + k]
                    .iter_mut()
                    .zip(&mut self.row[t0..t1])
                    .zip(&self.step[t0..t1])
                {
                    slot.write(*r);
                    // The next channel's row (never formed past the last channel's: the address
                    // is only used for channels < channels, checked in `new`).
                    r.ptr = r.ptr.wrapping_add(s);
                }
                n += k;
                self.tap = t1;
                if self.tap == self.taps {
                    self.tap = 0;
                    self.channel += 1;
                }
            }
            if n < count {
                let k = count - n;
                if self.padded + k > self.pad {
                    return false;
                }
                let zero = LineRow {
                    ptr: ZERO_ROW.as_ptr(),
                    off: 0,
                };
                for slot in &mut rows.rows[n..count] {
                    slot.write(zero);
                }
                self.padded += k;
            }
            rows.len = count;
            true
        }
    }
}
#[cfg(all(feature = "mve", target_arch = "arm"))]
pub(crate) use line_rows::ZERO_ROW;
#[cfg(all(feature = "dsp", target_arch = "arm"))]
pub use line_rows::{ChannelTaps, LineRows};

/// Whether a row of `dot2x2_row` fits its slices: `positions` dot products of `n` words
/// `step` words apart within `x_len` words, the two channels' `2n` weight words within
/// `w_len`, the last position's accumulator (`astep` words apart) within both rows, and a
/// step the assembly can scale to bytes. True for no positions.
#[inline(always)]
pub fn row_fits(
    (x_len, step, positions, n): (usize, usize, usize, usize),
    w_len: usize,
    (acc0_len, acc1_len, astep): (usize, usize, usize),
) -> bool {
    let Some(last) = positions.checked_sub(1) else {
        return true;
    };
    last.checked_mul(step)
        .and_then(|a| a.checked_add(n))
        .is_some_and(|e| e <= x_len)
        && n.checked_mul(2).is_some_and(|e| e <= w_len)
        && last
            .checked_mul(astep)
            .is_some_and(|a| a < acc0_len && a < acc1_len)
        && step <= usize::MAX / 8
}

/// Whether a tap `(c, wl, wr)` of a cost-volume column reads inside rows of `width` values
/// (`c + 1 < width`) with weights that keep the warped value between its two int8 sources:
/// `wl, wr ≥ 0` with `wl + wr = 256`, or both 0 (an invisible entry).
#[inline(always)]
pub fn tap_fits((c, wl, wr): (usize, i16, i16), width: usize) -> bool {
    c.checked_add(1).is_some_and(|c1| c1 < width)
        && ((wl >= 0 && wr >= 0 && wl as i32 + wr as i32 == 256) || (wl, wr) == (0, 0))
}

/// Whether the slices of a cost-volume column have one common length `n` that is a multiple
/// of `width > 0` (at most `i32::MAX`, the loops' index range), with `col < width`.
#[inline(always)]
pub fn column_fits(lens: &[usize], n: usize, (width, col): (usize, usize)) -> bool {
    lens.iter().all(|&l| l == n)
        && width > 0
        && n.is_multiple_of(width)
        && col < width
        && n <= i32::MAX as usize
}
