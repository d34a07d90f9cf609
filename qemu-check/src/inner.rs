//! The `epssn::arch` inner loops (with `dsp` their SMLAD assembly, with `mve` their Helium
//! assembly) against plain loops written here, on random lengths, strides, offsets and
//! values, every tail included (lengths not a multiple of 4, an odd last position, `n` of
//! 2, 4 and 6 words): one function per kernel, run in the order of [`CASES`].

use epssn::arch::{
    dot2x2, dot2x2_row, pack, pack_rows, requant_max_row, requant_row_s8, smmulr, RowPlan,
};

use crate::{Rng, Tally};

/// Random cases of each kernel.
const ROUNDS: u32 = 600;

/// The kernels' checks, in the order they run. Every one draws from the same generator, so
/// the order is part of the test: each round draws exactly what it drew when this was one
/// loop, and some checks read what an earlier one drew ([`Operands`]).
const CASES: [fn(&mut Rng, &mut Operands, &mut Tally); 19] = [
    dot2x2_case,
    dot2x2_row_case,
    row_plan,
    run_channels,
    pack_rows_case,
    pack_strided,
    requant_row,
    requant_rows,
    requant_max,
    table_columns4,
    table_columns8,
    line_fill,
    channel_taps,
    channel_pairs,
    fill_bytes,
    pair_rows_s8,
    exp_sums,
    gather_bytes,
    pair_short,
];

/// Every kernel's checks on `ROUNDS` rounds of random operands: (cases, mismatches).
pub fn run(rng: &mut Rng) -> (u32, u32) {
    let mut o = Operands::new();
    let mut t = Tally::default();
    for round in 0..ROUNDS {
        o.draw(rng, round);
        for case in CASES {
            case(rng, &mut o, &mut t);
        }
    }
    (t.checked, t.failures)
}

/// A round's operands: the words and bytes, the dot products' shape (drawn first), and what
/// later checks read of the draws of earlier ones.
struct Operands {
    round: u32,
    x: [u32; 2048],
    w: [u32; 512],
    bytes: [i8; 512],
    /// Words per dot product.
    n: usize,
    /// Words from one position's operands to the next.
    step: usize,
    positions: usize,
    /// Accumulator stride.
    astep: usize,
    bias: [i32; 2],
    /// The offset into `x` of the RowPlan checks (drawn by [`row_plan`]).
    shift: usize,
    /// The row length of the packing, requantisation and exp checks (drawn by
    /// [`pack_rows_case`]).
    len: usize,
    /// The requantisation operands (drawn by [`requant_row`]).
    rq: RequantOperands,
}

/// The requantisation checks' operands.
#[derive(Clone, Copy)]
struct RequantOperands {
    acc: [i32; 70],
    table: [i32; 256],
    /// (multiplier, left shift, right shift, rounding half, negative rounding mask).
    words: (i32, u32, u32, i32, i32),
    relu: bool,
    skip: bool,
    /// The output row before the kernel wrote it.
    old: [i8; 70],
}

impl RequantOperands {
    /// The skip table, in half the rounds.
    fn skip(&self) -> Option<&[i32; 256]> {
        self.skip.then_some(&self.table)
    }

    /// The expected int8 of the requantisation `(m, left, right, half, neg)` of `acc`, without
    /// the skip.
    fn scaled(acc: i32, (m, left, right, half, neg): (i32, u32, u32, i32, i32)) -> i32 {
        let x = smmulr(acc.wrapping_shl(left), m);
        x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right
    }
}

impl Operands {
    fn new() -> Self {
        Operands {
            round: 0,
            x: [0; 2048],
            w: [0; 512],
            bytes: [0; 512],
            n: 0,
            step: 0,
            positions: 0,
            astep: 0,
            bias: [0; 2],
            shift: 0,
            len: 0,
            rq: RequantOperands {
                acc: [0; 70],
                table: [0; 256],
                words: (0, 0, 0, 0, 0),
                relu: false,
                skip: false,
                old: [0; 70],
            },
        }
    }

    /// The round's words, bytes and dot-product shape.
    fn draw(&mut self, rng: &mut Rng, round: u32) {
        self.round = round;
        for v in self.x.iter_mut().chain(self.w.iter_mut()) {
            *v = rng.next() as u32;
        }
        rng.fill(&mut self.bytes);
        self.n = 1 + (rng.next() % 40) as usize;
        self.step = self.n + (rng.next() % 8) as usize;
        self.positions = 1 + (rng.next() % 9) as usize;
        self.astep = 1 + (rng.next() % 3) as usize;
        self.bias = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
    }

    /// The plain dot product of position `q`, channel `c`, from word `shift` of `x` (weights
    /// `k * wstride` words in, bias `bias`), wrapping as the instructions do.
    fn dot(
        &self,
        shift: usize,
        q: usize,
        (k, wstride): (usize, usize),
        c: usize,
        bias: i32,
    ) -> i32 {
        let mut a = bias;
        for j in 0..self.n {
            let (xv, wv) = (
                self.x[shift + q * self.step + j],
                self.w[k * wstride + 2 * j + c],
            );
            let lo = (xv as u16 as i16 as i32).wrapping_mul(wv as u16 as i16 as i32);
            let hi =
                ((xv >> 16) as u16 as i16 as i32).wrapping_mul((wv >> 16) as u16 as i16 as i32);
            a = a.wrapping_add(lo).wrapping_add(hi);
        }
        a
    }

    /// [`Operands::dot`] of the round's weights and bias.
    fn plain(&self, shift: usize, q: usize, c: usize) -> i32 {
        self.dot(shift, q, (0, 0), c, self.bias[c])
    }

    /// The row of the RowPlan checks.
    fn plan(&self) -> RowPlan {
        RowPlan::new(self.step, self.positions, self.n, self.astep)
    }
}

fn dot2x2_case(_: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let b = o.bias;
    let d = dot2x2(&o.x, o.step, &o.w, o.n, [b[0], b[0], b[1], b[1]]);
    t.check(
        d == [
            o.plain(0, 0, 0),
            o.plain(0, 1, 0),
            o.plain(0, 0, 1),
            o.plain(0, 1, 1),
        ],
    );
}

fn dot2x2_row_case(_: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let (mut acc0, mut acc1) = ([0i32; 32], [0i32; 32]);
    let ok = dot2x2_row(
        &o.x,
        o.step,
        o.positions,
        &o.w,
        o.n,
        o.bias,
        (&mut acc0, &mut acc1, o.astep),
    );
    let a = o.astep;
    t.check(
        ok && (0..o.positions)
            .all(|q| acc0[q * a] == o.plain(0, q, 0) && acc1[q * a] == o.plain(0, q, 1)),
    );
}

/// RowPlan: the shape prepared once, then a row at another offset of x (as the kernels run
/// every row of a layer), and a too-short x refused with the accumulators untouched.
fn row_plan(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let plan = o.plan();
    o.shift = (rng.next() % 64) as usize;
    let (mut acc0, mut acc1) = ([0i32; 32], [0i32; 32]);
    let ok = plan.run(&o.x[o.shift..], &o.w, o.bias, (&mut acc0, &mut acc1));
    let (a, s) = (o.astep, o.shift);
    t.check(
        ok && (0..o.positions)
            .all(|q| acc0[q * a] == o.plain(s, q, 0) && acc1[q * a] == o.plain(s, q, 1)),
    );
    let need = (o.positions - 1) * o.step + o.n;
    let (mut s0, mut s1) = ([7i32; 32], [7i32; 32]);
    let refused = !plan.run(&o.x[..need - 1], &o.w, o.bias, (&mut s0, &mut s1));
    t.check(refused && s0 == [7; 32] && s1 == [7; 32]);
}

/// RowPlan::run_channels: every channel pair of a line in one call (weights `wstride` apart,
/// rows `rstride` apart from `first`), against the plain dot products; the words it must not
/// write keep their value.
fn run_channels(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let pairs_c = 1 + (rng.next() % 4) as usize;
    let wstride = 2 * o.n + (rng.next() % 3) as usize;
    let first = (rng.next() % 3) as usize;
    let rstride = first + (o.positions - 1) * o.astep + 1 + (rng.next() % 3) as usize;
    let mut biases = [[0i32; 2]; 4];
    for b in biases.iter_mut() {
        *b = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
    }
    if (pairs_c - 1) * wstride + 2 * o.n > o.w.len() || 2 * pairs_c * rstride > 256 {
        return;
    }
    let mut rows = [0x5a5a_5a5ai32; 256];
    let ok = o.plan().run_channels(
        &o.x[o.shift..],
        (&o.w, wstride),
        &biases[..pairs_c],
        &mut rows,
        (rstride, first),
    );
    let plain_c = |k: usize, q: usize, c: usize| o.dot(o.shift, q, (k, wstride), c, biases[k][c]);
    let at = |k: usize, c: usize, q: usize| (2 * k + c) * rstride + first + q * o.astep;
    let right = (0..pairs_c)
        .all(|k| (0..o.positions).all(|q| (0..2).all(|c| rows[at(k, c, q)] == plain_c(k, q, c))));
    let touched =
        |i: usize| (0..pairs_c).any(|k| (0..2).any(|c| (0..o.positions).any(|q| at(k, c, q) == i)));
    let rest = (0..256).all(|i| touched(i) || rows[i] == 0x5a5a_5a5a);
    t.check(ok && right && rest);
}

/// The offsets of the packing checks: 128 on both rows in even rounds, none in odd ones.
fn pack_offsets(round: u32) -> (i16, i16) {
    if round.is_multiple_of(2) {
        (128, 128)
    } else {
        (0, 0)
    }
}

/// pack_rows: a line column of two rows, with and without offsets.
fn pack_rows_case(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    o.len = (rng.next() % 70) as usize;
    let (len, stride) = (o.len, 1 + (rng.next() % 5) as usize);
    let (oa, ob) = pack_offsets(o.round);
    let (ra, rb) = (&o.bytes[..len], &o.bytes[100..100 + len]);
    let mut dst = [0u32; 512];
    pack_rows(&mut dst, stride, ra, rb, oa, ob);
    t.check((0..len).all(|j| dst[j * stride] == pack(ra[j] as i16 + oa, rb[j] as i16 + ob)));
}

/// pack_strided: a column of two planes, any count (passes of eight, blocks of four and the
/// rest), the two columns' offsets different or equal.
fn pack_strided(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let count = (rng.next() % 24) as usize;
    let (sstride, dstride) = (1 + (rng.next() % 8) as usize, 1 + (rng.next() % 7) as usize);
    let mut dst = [0u32; 512];
    let (pa, pb) = (&o.bytes[..200], &o.bytes[250..450]);
    let (oa, ob) = if o.round.is_multiple_of(3) {
        (128, -3)
    } else {
        pack_offsets(o.round)
    };
    epssn::arch::pack_strided(&mut dst, dstride, (pa, pb, sstride), count, oa, ob);
    let column = (0..count).all(|j| {
        dst[j * dstride] == pack(pa[j * sstride] as i16 + oa, pb[j * sstride] as i16 + ob)
    });
    let untouched = (0..512).all(|i| i % dstride == 0 && i / dstride < count || dst[i] == 0);
    t.check(column && untouched);
}

/// requant_row_s8 with each of ReLU and the skip table.
fn requant_row(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let (len, round) = (o.len, o.round);
    let rq = &mut o.rq;
    for a in rq.acc.iter_mut() {
        *a = rng.next() as i32 >> (rng.next() % 16);
    }
    for e in rq.table.iter_mut() {
        *e = (rng.next() % 300) as i32 - 150;
    }
    let multiplier = (1 << 30) + (rng.next() % (1 << 30)) as i32;
    let (left1, right) = ((rng.next() % 3) as u32, (rng.next() % 12) as u32);
    let half = if right == 0 { 0 } else { 1 << (right - 1) };
    let neg = -((rng.next() % 2) as i32);
    rq.words = (multiplier, left1, right, half, neg);
    rq.relu = round % 3 == 0;
    rq.skip = round % 4 < 2;
    let mut out = [0i8; 70];
    rng.fill(&mut out[..len]);
    rq.old = out;
    let rq = o.rq;
    requant_row_s8(
        &rq.acc[..len],
        &mut out[..len],
        rq.words,
        rq.relu,
        rq.skip(),
    );
    let expect = |i: usize| -> i8 {
        let v = RequantOperands::scaled(rq.acc[i], rq.words);
        let v = if rq.relu { v.max(0) } else { v };
        let v = match rq.skip() {
            Some(l) => v.saturating_add(l[rq.old[i] as u8 as usize]),
            None => v,
        };
        v.clamp(-128, 127) as i8
    };
    t.check((0..len).all(|i| out[i] == expect(i)) && out[len..] == rq.old[len..]);
}

/// requant_rows_s8: rows of their own parameters, `plane` apart (the bytes between rows
/// untouched), the width a multiple of 4 or not; shifts of 32 refused up front.
fn requant_rows(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let rq = o.rq;
    let rows = 1 + (rng.next() % 4) as usize;
    let width = 1 + (rng.next() % 13) as usize;
    let plane = width + (rng.next() % 4) as usize;
    let mut words = [[0i32; 5]; 5];
    for p in words.iter_mut() {
        let (l, r) = ((rng.next() % 3) as i32, (rng.next() % 12) as i32);
        let m = (1 << 30) + (rng.next() % (1 << 30)) as i32;
        let n = -((rng.next() % 2) as i32);
        *p = [m, l, r, if r == 0 { 0 } else { 1 << (r - 1) }, n];
    }
    let params = epssn::arch::RowWords::new(&words[..rows]);
    let mut out = rq.old;
    let ok = params.is_some_and(|p| {
        epssn::arch::requant_rows_s8(&rq.acc, &mut out, p, (width, plane), rq.relu, rq.skip())
    });
    let expect_row = |c: usize, i: usize| -> i8 {
        let [m, l, r, h, n] = words[c];
        let v = RequantOperands::scaled(rq.acc[c * width + i], (m, l as u32, r as u32, h, n));
        let v = if rq.relu { v.max(0) } else { v };
        let v = match rq.skip() {
            Some(lut) => v.saturating_add(lut[rq.old[c * plane + i] as u8 as usize]),
            None => v,
        };
        v.clamp(-128, 127) as i8
    };
    let written = |j: usize| j / plane < rows && j % plane < width;
    t.check(
        ok && (0..rows).all(|c| (0..width).all(|i| out[c * plane + i] == expect_row(c, i)))
            && (0..70).all(|j| written(j) || out[j] == rq.old[j]),
    );
    let mut wide = words;
    wide[rows - 1][1 + (o.round % 2) as usize] = 32;
    t.check(epssn::arch::RowWords::new(&wide[..rows]).is_none());
}

/// requant_max_row: the same arithmetic, the int8 (or ReLU) clamp, and the maximum.
fn requant_max(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let (rq, len) = (o.rq, o.len);
    let max0 = (rng.next() % 256) as u8 as i8;
    let mut out = rq.old;
    let got = requant_max_row(&rq.acc[..len], &mut out[..len], rq.words, rq.relu, max0);
    let plain_max = |i: usize| -> i8 {
        let v = RequantOperands::scaled(rq.acc[i], rq.words);
        if rq.relu {
            v.clamp(0, 127) as i8
        } else {
            v.clamp(-128, 127) as i8
        }
    };
    let want = (0..len).map(plain_max).fold(max0, i8::max);
    t.check(got == want && (0..len).all(|i| out[i] == plain_max(i)) && out[len..] == rq.old[len..]);
}

fn table_columns4(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    t.check(table_columns_agree(rng, &o.bytes, 4));
}

fn table_columns8(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    t.check(table_columns_agree(rng, &o.bytes, 8));
}

fn line_fill(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    t.check(line_fill_agrees(rng, &o.bytes));
}

fn channel_taps(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    t.check(channel_taps_agree(rng, &o.bytes));
}

/// The Helium channel-pair fill (`mve` only: no case on the Cortex-M7).
#[cfg_attr(not(feature = "mve"), allow(unused_variables))]
fn channel_pairs(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    #[cfg(feature = "mve")]
    t.check(channel_pairs_agree(rng, &o.bytes));
}

/// The Helium byte fill (`mve` only).
#[cfg_attr(not(feature = "mve"), allow(unused_variables))]
fn fill_bytes(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    #[cfg(feature = "mve")]
    t.check(fill_bytes_agree(rng, &o.bytes));
}

/// The Helium s8 pair rows (`mve` only).
#[cfg_attr(not(feature = "mve"), allow(unused_variables))]
fn pair_rows_s8(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    #[cfg(feature = "mve")]
    t.check(pair_rows_s8_agree(rng, &o.bytes));
}

/// The Helium head gather (`mve` only).
#[cfg_attr(not(feature = "mve"), allow(unused_variables))]
fn gather_bytes(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    #[cfg(feature = "mve")]
    t.check(gather_bytes_agree(rng, &o.bytes));
}

/// The Helium s8 pair rows with the weights in registers (`mve` only).
#[cfg_attr(not(feature = "mve"), allow(unused_variables))]
fn pair_short(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    #[cfg(feature = "mve")]
    t.check(pair_short_agree(rng, &o.bytes));
}

/// exp_sums: any m (the sums wrap the index mod 256 as the table lookup does).
fn exp_sums(rng: &mut Rng, o: &mut Operands, t: &mut Tally) {
    let mut exp = [0u16; 256];
    for e in exp.iter_mut() {
        *e = rng.next() as u16;
    }
    let logits = &o.bytes[..o.len];
    let m = if o.round.is_multiple_of(2) {
        logits.iter().copied().max().unwrap_or(0)
    } else {
        rng.next() as i8
    };
    let (mut ps, mut pt) = (0u32, 0u32);
    for (i, &q) in logits.iter().enumerate() {
        let e = exp[(m as i32 - q as i32) as u8 as usize] as u32;
        ps = ps.wrapping_add(e);
        pt = pt.wrapping_add(e.wrapping_mul(i as u32));
    }
    t.check(epssn::arch::exp_sums(logits, m, &exp) == (ps, pt));
}

/// `arch::pack_line_quads` (a line fill of up to 16 words; with `mve` its Helium loop) against
/// `pack_rows` word by word:
/// random rows (some the zero row without offset), lengths a multiple of 4, line widths and
/// fills shorter than the capacity; a row shorter than the fill's length is refused.
fn line_fill_agrees(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::{pack_line_quads, LineRows};
    static ZEROS: [i8; 64] = [0; 64];
    let len = 4 * (1 + (rng.next() % 12) as usize);
    let words = 1 + (rng.next() % 16) as usize;
    let vw = words + (rng.next() % 3) as usize;
    let mut rows = LineRows::new(len);
    let mut want = [0u32; 1024];
    let mut got = [0u32; 1024];
    let mut picked: [(usize, i16); 32] = [(0, 0); 32];
    for p in picked[..2 * words].iter_mut() {
        *p = if rng.next().is_multiple_of(5) {
            (usize::MAX, 0)
        } else {
            (
                (rng.next() as usize) % (512 - len),
                if rng.next().is_multiple_of(2) {
                    128
                } else {
                    -3
                },
            )
        };
    }
    let row = |(at, off): (usize, i16)| -> (&[i8], i16) {
        if at == usize::MAX {
            (&ZEROS[..len], 0)
        } else {
            (&bytes[at..at + len], off)
        }
    };
    let ok = rows.fill_with(2 * words, {
        let mut i = 0;
        move || {
            i += 1;
            row(picked[i - 1])
        }
    });
    if !ok || rows.push(&bytes[..len - 1], 0) {
        return false;
    }
    if !pack_line_quads(&mut got[..len * vw], vw, &rows) {
        return false;
    }
    for k in 0..words {
        let ((ra, oa), (rb, ob)) = (row(picked[2 * k]), row(picked[2 * k + 1]));
        pack_rows(&mut want[k..len * vw], vw, ra, rb, oa, ob);
    }
    got == want
}

/// `arch::fill_channel_pairs` (a channel-minor line fill: each tap's channel pairs from
/// channel 0's row and the channel step) against `pack_rows` on the rows it names, zero
/// rows for taps outside the input; words it must not write keep their value; a tap whose
/// last channel's row leaves the input, or an odd channel count, is refused.
#[cfg(feature = "mve")]
fn channel_pairs_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::fill_channel_pairs;
    static ZEROS: [i8; 64] = [0; 64];
    let need = 4 * (1 + (rng.next() % 12) as usize);
    let taps = 1 + (rng.next() % 9) as usize;
    let channels = 2 * (1 + (rng.next() % 4) as usize);
    // Every channel's row within the 512 bytes.
    let cs = (need + (rng.next() % 20) as usize).min((512 - need) / (channels - 1));
    let span = (channels - 1) * cs + need;
    let off = if rng.next().is_multiple_of(2) {
        128
    } else {
        -3
    };
    let mut at = [usize::MAX; 9];
    for a in at[..taps].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let words = taps * channels / 2;
    let vw = words + (rng.next() % 3) as usize;
    let fill = rng.next() as u32;
    let (mut got, mut want) = ([fill; 48 * 40], [fill; 48 * 40]);
    let len = (need - 1) * vw + words;
    if !fill_channel_pairs(
        &mut got[..len],
        vw,
        need,
        (bytes, &at[..taps]),
        (channels, cs),
        off,
    ) {
        return false;
    }
    for (t, &a) in at[..taps].iter().enumerate() {
        for k in 0..channels / 2 {
            let row = |c: usize| -> (&[i8], i16) {
                if a == usize::MAX {
                    (&ZEROS[..need], 0)
                } else {
                    (&bytes[a + c * cs..a + c * cs + need], off)
                }
            };
            let ((ra, oa), (rb, ob)) = (row(2 * k), row(2 * k + 1));
            pack_rows(&mut want[t * channels / 2 + k..len], vw, ra, rb, oa, ob);
        }
    }
    // Refused: a row past the input, an odd channel count, a destination one word short.
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut spare = [0u32; 48 * 40];
    if fill_channel_pairs(
        &mut spare[..len],
        vw,
        need,
        (bytes, &past[..taps]),
        (channels, cs),
        off,
    ) || fill_channel_pairs(
        &mut spare[..len],
        vw,
        need,
        (bytes, &at[..taps]),
        (3, cs),
        off,
    ) || fill_channel_pairs(
        &mut spare[..len - 1],
        vw,
        need,
        (bytes, &at[..taps]),
        (channels, cs),
        off,
    ) {
        return false;
    }
    got == want
}

/// `arch::fill_bytes` (the int8 line: each tap's channels' rows, raw, the pad row for taps
/// outside the input) against a plain loop; bytes it must not write keep their value; a row
/// past the input, a column of too few entries or a destination one byte short is refused.
#[cfg(feature = "mve")]
fn fill_bytes_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::fill_bytes;
    let len = 1 + (rng.next() % 40) as usize;
    let taps = 1 + (rng.next() % 9) as usize;
    let channels = 1 + (rng.next() % 8) as usize;
    let cs = len + (rng.next() % 20) as usize;
    let span = (channels - 1) * cs + len;
    let pad = [rng.next() as i8; 64];
    let mut at = [usize::MAX; 9];
    for a in at[..taps].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let entries = taps * channels;
    // An even column for an even channel count (the halfword stores' alignment).
    let vp = entries + 2 * (rng.next() % 3) as usize;
    let fill = rng.next() as u8;
    // Word-aligned, as the line is (the halfword stores need their alignment).
    let (mut got, mut want) = (Aligned([fill; 80 * 40]), [fill; 80 * 40]);
    let got = &mut got.0;
    let n = (len - 1) * vp + entries;
    if !fill_bytes(
        &mut got[..n],
        vp,
        len,
        (bytes, &at[..taps]),
        (channels, cs),
        &pad,
    ) {
        return false;
    }
    for (t, &a) in at[..taps].iter().enumerate() {
        for i in 0..channels {
            for j in 0..len {
                let x = if a == usize::MAX {
                    pad[j]
                } else {
                    bytes[a + i * cs + j]
                };
                want[t * channels + i + j * vp] = x as u8;
            }
        }
    }
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut spare = Aligned([0u8; 80 * 40]);
    let spare = &mut spare.0;
    if fill_bytes(
        &mut spare[..n],
        vp,
        len,
        (bytes, &past[..taps]),
        (channels, cs),
        &pad,
    ) || fill_bytes(
        &mut spare[..n],
        entries - 1,
        len,
        (bytes, &at[..taps]),
        (channels, cs),
        &pad,
    ) || fill_bytes(
        &mut spare[..n - 1],
        vp,
        len,
        (bytes, &at[..taps]),
        (channels, cs),
        &pad,
    ) {
        return false;
    }
    *got == want
}

/// `arch::PairRowsS8::run_channels` (int8 dot products, 16 per instruction, the tail by
/// predication) against a plain loop: random lengths 1 to 80 bytes, 1 to 6 pairs of
/// positions, 1 to 4 channel pairs, the rows' spare words untouched; slices one short
/// refused.
#[cfg(feature = "mve")]
fn pair_rows_s8_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::PairRowsS8;
    let n = 1 + (rng.next() % 80) as usize;
    let pairs = 1 + (rng.next() % 6) as usize;
    let step = 1 + (rng.next() % 24) as usize;
    let chans = 1 + (rng.next() % 4) as usize;
    let Some(plan) = PairRowsS8::new(step, n, pairs) else {
        return false;
    };
    let x_len = (2 * pairs - 1) * step + n;
    let x: &[u8] = &bytemuck_bytes(bytes)[..x_len];
    let wpair = plan.pair_bytes();
    let wstride = wpair + 4 * (rng.next() % 3) as usize;
    let mut w = [0u8; 4 * 112 * 2];
    for (k, b) in w.iter_mut().enumerate() {
        // Zero past the window in each block, as the engine lays it out.
        let (pair_at, block_at) = (k % wstride, k % wstride % 32);
        let e = (pair_at / 32) * 16 + block_at % 16;
        *b = if pair_at < wpair && e < n {
            rng.next() as u8
        } else {
            0
        };
    }
    let mut bias = [[0i32; 2]; 4];
    for b in bias[..chans].iter_mut() {
        *b = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
    }
    let rstride = 2 * pairs + (rng.next() % 3) as usize;
    let fill = rng.next() as i32;
    let acc_len = (2 * chans - 1) * rstride + 2 * pairs;
    let (mut got, mut want) = ([fill; 8 * 16], [fill; 8 * 16]);
    let w_len = (chans - 1) * wstride + wpair;
    if !plan.run_channels(
        x,
        (&w[..w_len], wstride),
        &bias[..chans],
        &mut got[..acc_len],
        (rstride, 0),
    ) {
        return false;
    }
    for k in 0..chans {
        for c in 0..2 {
            for q in 0..2 * pairs {
                let mut a = bias[k][c];
                for e in 0..n {
                    let wb = w[k * wstride + (e / 16) * 32 + c * 16 + e % 16] as i8;
                    a = a.wrapping_add(wb as i32 * x[q * step + e] as i8 as i32);
                }
                want[(2 * k + c) * rstride + q] = a;
            }
        }
    }
    let mut spare = [0i32; 8 * 16];
    if plan.run_channels(
        &x[..x_len - 1],
        (&w[..w_len], wstride),
        &bias[..chans],
        &mut spare[..acc_len],
        (rstride, 0),
    ) || plan.run_channels(
        x,
        (&w[..w_len - 1], wstride),
        &bias[..chans],
        &mut spare[..acc_len],
        (rstride, 0),
    ) || plan.run_channels(
        x,
        (&w[..w_len], wstride),
        &bias[..chans],
        &mut spare[..acc_len - 1],
        (rstride, 0),
    ) {
        return false;
    }
    got == want
}

/// `arch::gather_bytes` (the head's int8 column gather: each entry's column of rows, raw,
/// the pad for entries outside the input) against a plain loop; bytes it must not write keep
/// their value; a row past the input, a destination one byte short or no rows is refused.
#[cfg(feature = "mve")]
fn gather_bytes_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::gather_bytes;
    let rows = 1 + (rng.next() % 40) as usize;
    let entries = 1 + (rng.next() % 32) as usize;
    let sstride = (rng.next() % 12) as usize;
    let dstride = entries + (rng.next() % 5) as usize;
    let span = (rows - 1) * sstride + 1;
    let pad = rng.next() as i8;
    let mut at = [usize::MAX; 32];
    for a in at[..entries].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let fill = rng.next() as u8;
    let (mut got, mut want) = ([fill; 40 * 36], [fill; 40 * 36]);
    let n = (rows - 1) * dstride + entries;
    if !gather_bytes(
        &mut got[..n],
        (dstride, rows),
        (bytes, &at[..entries]),
        sstride,
        pad,
    ) {
        return false;
    }
    for (k, &a) in at[..entries].iter().enumerate() {
        for y in 0..rows {
            let x = if a == usize::MAX {
                pad
            } else {
                bytes[a + y * sstride]
            };
            want[k + y * dstride] = x as u8;
        }
    }
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut spare = [0u8; 40 * 36];
    if gather_bytes(
        &mut spare[..n],
        (dstride, rows),
        (bytes, &past[..entries]),
        sstride,
        pad,
    ) || gather_bytes(
        &mut spare[..n - 1],
        (dstride, rows),
        (bytes, &at[..entries]),
        sstride,
        pad,
    ) || gather_bytes(
        &mut spare[..n],
        (dstride, 0),
        (bytes, &at[..entries]),
        sstride,
        pad,
    ) {
        return false;
    }
    got == want
}

/// `arch::PairRowsS8::run_pair_short` (one channel pair, a 17 to 32 byte window, the weights
/// in registers) against a plain loop: random windows, 1 to 6 pairs of positions, steps of
/// 1 to 40 bytes, the rows' spare words untouched; an `x` of 32 bytes per position one short,
/// or a window of 16 bytes, refused.
#[cfg(feature = "mve")]
fn pair_short_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::PairRowsS8;
    let n = 17 + (rng.next() % 16) as usize;
    let pairs = 1 + (rng.next() % 6) as usize;
    let step = 1 + (rng.next() % 40) as usize;
    let x_len = (2 * pairs - 1) * step + 32;
    let Some(plan) = PairRowsS8::new(step, n, pairs) else {
        return false;
    };
    let x: &[u8] = &bytemuck_bytes(bytes)[..x_len];
    let mut w = [0u8; 64];
    for (k, b) in w.iter_mut().enumerate() {
        // Zero past the window in each block, as the head lays it out.
        let e = (k / 32) * 16 + k % 16;
        *b = if e < n { rng.next() as u8 } else { 0 };
    }
    let bias = [rng.next() as i32 >> 8, rng.next() as i32 >> 8];
    let rstride = 2 * pairs + (rng.next() % 3) as usize;
    let fill = rng.next() as i32;
    let acc_len = rstride + 2 * pairs;
    let (mut got, mut want) = ([fill; 72], [fill; 72]);
    if !plan.run_pair_short(x, &w, bias, (&mut got[..acc_len], rstride)) {
        return false;
    }
    for c in 0..2 {
        for q in 0..2 * pairs {
            let mut a = bias[c];
            for e in 0..n {
                let wb = w[(e / 16) * 32 + c * 16 + e % 16] as i8;
                a = a.wrapping_add(wb as i32 * x[q * step + e] as i8 as i32);
            }
            want[c * rstride + q] = a;
        }
    }
    let mut spare = [0i32; 72];
    let short = PairRowsS8::new(step, 16, pairs);
    if plan.run_pair_short(&x[..x_len - 1], &w, bias, (&mut spare[..acc_len], rstride))
        || plan.run_pair_short(x, &w, bias, (&mut spare[..acc_len - 1], rstride))
        || short.is_some_and(|p| p.run_pair_short(x, &w, bias, (&mut spare[..acc_len], rstride)))
    {
        return false;
    }
    got == want
}

/// A word-aligned byte array.
#[cfg(feature = "mve")]
#[repr(align(4))]
struct Aligned([u8; 80 * 40]);

/// The bytes of an int8 array, as the int8 line engine reads them.
#[cfg(feature = "mve")]
fn bytemuck_bytes(b: &[i8; 512]) -> [u8; 512] {
    b.map(|x| x as u8)
}

/// `arch::ChannelTaps` (a whole line's rows, channel by channel and tap by tap, then zero
/// rows) through `pack_line_quads`, chunk by chunk, against `pack_rows` on the rows the
/// definition names; a tap whose last channel's row leaves the input is refused.
fn channel_taps_agree(rng: &mut Rng, bytes: &[i8; 512]) -> bool {
    use epssn::arch::{pack_line_quads, ChannelTaps, LineRows};
    static ZEROS: [i8; 16] = [0; 16];
    let len = 4 * (1 + (rng.next() % 4) as usize);
    let taps = 1 + (rng.next() % 9) as usize;
    let channels = 1 + (rng.next() % 4) as usize;
    let cs = len + (rng.next() % 40) as usize;
    let span = (channels - 1) * cs + len;
    let off = if rng.next().is_multiple_of(2) { 128 } else { 0 };
    let mut at = [usize::MAX; 9];
    for a in at[..taps].iter_mut() {
        if !rng.next().is_multiple_of(4) {
            *a = (rng.next() as usize) % (512 - span + 1);
        }
    }
    let entries = (channels * taps).div_ceil(4) * 4 + 4 * (rng.next() % 2) as usize;
    let mut rows_of = ChannelTaps::new(bytes, &at[..taps], (channels, cs), (len, off), entries);
    // The same taps with one row past the end are refused.
    let mut past = at;
    past[0] = 512 - span + 1;
    let mut rows = LineRows::new(len);
    let mut refused = ChannelTaps::new(bytes, &past[..taps], (channels, cs), (len, off), entries);
    if refused.next_rows(&mut rows, 2) || refused.next_rows(&mut rows, 0) {
        return false;
    }
    let vw = entries / 2;
    let (mut got, mut want) = ([0u32; 16 * 64], [0u32; 16 * 64]);
    let mut k0 = 0;
    while k0 < vw {
        let kn = (vw - k0).min(LineRows::CAPACITY / 2);
        if !rows_of.next_rows(&mut rows, 2 * kn)
            || !pack_line_quads(&mut got[k0..len * vw], vw, &rows)
        {
            return false;
        }
        k0 += kn;
    }
    // Nothing is left.
    if rows_of.next_rows(&mut rows, 2) {
        return false;
    }
    let row = |v: usize| -> (&[i8], i16) {
        let (i, t) = (v / taps, v % taps);
        if i < channels && at[t] != usize::MAX {
            (&bytes[at[t] + i * cs..][..len], off)
        } else {
            (&ZEROS[..len], 0)
        }
    };
    for k in 0..vw {
        let ((ra, oa), (rb, ob)) = (row(2 * k), row(2 * k + 1));
        pack_rows(&mut want[k..len * vw], vw, ra, rb, oa, ob);
    }
    got == want
}

/// `arch::table_columns4` or `arch::table_columns8` (`lanes` cost-volume columns of two views in
/// one pass) against the one-column formula on a random piece: Helium builds must take it,
/// the others refuse it and leave `out` alone. Extreme values (−128, 127 and weights of 256)
/// come often, the edges of the eight-lane version's 16-bit sums.
fn table_columns_agree(rng: &mut Rng, bytes: &[i8; 512], lanes: usize) -> bool {
    let width = lanes + (rng.next() % 13) as usize;
    let rows = 1 + (rng.next() as usize) % (256 / width);
    let n = rows * width;
    let col = (rng.next() as usize) % (width - lanes + 1);
    let taps: [(usize, i16, i16); 8] = core::array::from_fn(|_| {
        let c = (rng.next() as usize) % (width - 1);
        let wr = match rng.next() % 4 {
            0 => 0,
            1 => 256,
            _ => (rng.next() % 257) as i16,
        };
        if rng.next().is_multiple_of(8) {
            (c, 0, 0)
        } else {
            (c, 256 - wr, wr)
        }
    });
    let mut table = [0i8; 512];
    rng.fill(&mut table);
    let sum = rng.next().is_multiple_of(2);
    let mut piece = [0i8; 512];
    piece.copy_from_slice(bytes);
    for v in piece.iter_mut() {
        match rng.next() % 4 {
            0 => *v = -128,
            1 => *v = 127,
            _ => {}
        }
    }
    let (reference, src) = (&piece[..n], &piece[256..256 + n]);
    let mut out = [0i8; 256];
    rng.fill(&mut out);
    let old = out;
    let cols = (width, col);
    let took = if lanes == 8 {
        epssn::arch::table_columns8(&mut out[..n], reference, src, cols, taps, &table, sum)
    } else {
        let four = [taps[0], taps[1], taps[2], taps[3]];
        epssn::arch::table_columns4(&mut out[..n], reference, src, cols, four, &table, sum)
    };
    if took != cfg!(feature = "mve") {
        return false;
    }
    (0..n).all(|i| {
        let (k, b) = (i / width, i % width);
        if !took || b < col || b >= col + lanes {
            return out[i] == old[i];
        }
        let (c, wl, wr) = taps[b - col];
        let s = &src[k * width..];
        let w = (s[c] as i32 * wl as i32 + s[c + 1] as i32 * wr as i32 + 128) >> 8;
        let index = if sum {
            reference[i] as i32 + w + 256
        } else {
            reference[i] as i32 - w + 255
        };
        out[i] == table[index as usize]
    })
}
