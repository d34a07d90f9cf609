//! The Helium (M-profile Vector Extension, MVE) backend for the Cortex-M55/M85, behind the
//! `mve` feature: the same bits as the portable loops of `arch` and the `dsp` backend's; the
//! table of operations in `arch` says which of these run in their place. This module imports
//! only the shared pieces (`super::insn`, `super::rows`), never the DSP backend.
//!
//! One 128-bit instruction handles four words: `VMLAVA.S16` adds eight i16 products to a
//! general-purpose register (four `SMLAD`s), `VLD20`/`VLD21` split the line engine's
//! channel-interleaved weight words into one vector per channel, a scatter store
//! (`VSTRW.32 … [Rn, Qm, UXTW #2]`) writes four line-buffer columns at once, and the loops
//! are the low-overhead `DLS`/`LE` loops (one loop instruction per iteration, no compare).
//!
//! The module only builds for an ARM target with MVE: the build script refuses the feature
//! unless the compiler targets a Cortex-M55/M85 (or `+mve`). `VMLAVA` needs its accumulators
//! in even registers (r0, r2, r4, r8 here), hence the explicit register operands; the vector
//! registers are declared clobbered through their `d` halves (q_n = d_2n:d_2n+1).
//!
//! The wrapping of the accumulators is the same as `SMLAD`'s and the Rust loops': sums
//! modulo 2^32 (the kernels' accumulator bounds exclude overflow anyway).

use super::insn::smlad;
use super::rows::{LineRows, ZERO_ROW};

/// `arch::dot2x2` with Helium: the same result for the same arguments (two output
/// channels × two positions over `n` words of i16 pairs, channel words interleaved in `w`).
/// Four words per iteration (32 MACs in 9 instructions); a last pair of words (`n ≡ 2 mod 4`)
/// or a last word (odd `n`) goes through `SMLAD`. Slices too short for `n` and `step` give
/// `acc` unchanged.
#[inline(always)]
pub fn dot2x2(x: &[u32], step: usize, w: &[u32], n: usize, acc: [i32; 4]) -> [i32; 4] {
    let (Some(xe), Some(we)) = (step.checked_add(n), n.checked_mul(2)) else {
        return acc;
    };
    if x.len() < xe || x.len() < n || w.len() < we {
        return acc;
    }
    let quads = n / 4;
    let [mut a00, mut a01, mut a10, mut a11] = acc;
    if quads > 0 {
        // SAFETY: the loop reads x[..4·quads], x[step..step + 4·quads] and w[..8·quads]
        // (4·quads ≤ n; in bounds, checked above); quads ≥ 1, so `DLS`/`LE` run it exactly
        // quads times. Vector loads of words need only word alignment, which &[u32] has.
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "dls   lr, {quads}",
                "2:",
                "vldrw.u32    q0, [{x0}], #16",
                "vldrw.u32    q1, [{x1}], #16",
                "vld20.32     {{q2, q3}}, [{w}]",
                "vld21.32     {{q2, q3}}, [{w}]!",
                "vmlava.s16   r0, q0, q2",
                "vmlava.s16   r2, q1, q2",
                "vmlava.s16   r4, q0, q3",
                "vmlava.s16   r8, q1, q3",
                "le    lr, 2b",
                quads = in(reg) quads,
                x0 = inout(reg) x.as_ptr() => _,
                x1 = inout(reg) x.as_ptr().add(step) => _,
                w = inout(reg) w.as_ptr() => _,
                inout("r0") a00,
                inout("r2") a01,
                inout("r4") a10,
                inout("r8") a11,
                out("lr") _,
                out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                options(nostack, readonly),
            );
        }
    }
    for k in 4 * quads..n {
        let (x0, x1) = (x[k], x[step + k]);
        let (w0, w1) = (w[2 * k], w[2 * k + 1]);
        a00 = smlad(x0, w0, a00);
        a01 = smlad(x1, w0, a01);
        a10 = smlad(x0, w1, a10);
        a11 = smlad(x1, w1, a11);
    }
    [a00, a01, a10, a11]
}

/// The four-entry blocks of `arch::pack_rows`: `dst[j · stride] = pack(a[j] + oa,
/// b[j] + ob)` for `j < 4 · quads`, 8 instructions per block (the `dsp` loop takes 22). The
/// caller has checked that `dst` holds index `(4 · quads − 1) · stride`, that `a` and `b`
/// hold `4 · quads` entries and that `stride ≤ usize::MAX / 16`; anything else does nothing.
#[inline(always)]
pub fn pack_row_quads(
    dst: &mut [u32],
    stride: usize,
    (a, b): (&[i8], &[i8]),
    quads: usize,
    (oa, ob): (i16, i16),
) {
    let n = quads.saturating_mul(4);
    let fits = n
        .checked_sub(1)
        .and_then(|m| m.checked_mul(stride))
        .is_some_and(|last| last < dst.len());
    if !fits || a.len() < n || b.len() < n || stride > usize::MAX / 16 {
        return;
    }
    // SAFETY: block i reads a[4i..4i + 4] and b[4i..4i + 4] (byte loads widened to words)
    // and writes dst[(4i + l) · stride] for l < 4, all in bounds for i < quads (checked
    // above); quads ≥ 1 (n ≥ 1), so `DLS`/`LE` run the loop exactly quads times.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            // Scatter offsets in words, columns j .. j + 4 of a block: [0, 1, 2, 3] · stride.
            "vidup.u32    q2, r0, #1",
            "vmul.i32     q2, q2, {s}",
            "dls   lr, {quads}",
            "2:",
            "vldrb.s32    q0, [r1], #4",
            "vldrb.s32    q1, [r3], #4",
            "vadd.i32     q0, q0, {oa}",
            "vadd.i32     q1, q1, {ob}",
            "vsli.32      q0, q1, #16",
            "vstrw.32     q0, [{dp}, q2, uxtw #2]",
            "add   {dp}, {dp}, {sb}",
            "le    lr, 2b",
            // `VIDUP` takes its start in an even register.
            inout("r0") 0u32 => _,
            s = in(reg) stride,
            quads = in(reg) quads,
            // The widening byte loads take only low registers as their base.
            inout("r1") a.as_ptr() => _,
            inout("r3") b.as_ptr() => _,
            dp = inout(reg) dst.as_mut_ptr() => _,
            sb = in(reg) stride * 16,
            oa = in(reg) oa as i32,
            ob = in(reg) ob as i32,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _,
            options(nostack),
        );
    }
}

/// The four-entry blocks of `arch::pack_strided`: `dst[j · dstride] = pack(a[j ·
/// sstride] + oa, b[j · sstride] + ob)` for `j < 4 · quads`, byte gathers for the two
/// columns and a scatter store, 10 instructions per block (the `dsp` loop takes 40). Does
/// nothing unless `dst` holds index `(4 · quads − 1) · dstride`, `a` and `b` index `(4 · quads
/// − 1) · sstride`, and both strides are at most `usize::MAX / 16`.
#[inline(always)]
pub fn pack_strided_quads(
    dst: &mut [u32],
    dstride: usize,
    (a, b, sstride): (&[i8], &[i8], usize),
    quads: usize,
    (oa, ob): (i16, i16),
) {
    let Some(last) = quads.checked_mul(4).and_then(|n| n.checked_sub(1)) else {
        return;
    };
    let fits = |len: usize, stride: usize| last.checked_mul(stride).is_some_and(|e| e < len);
    if dstride > usize::MAX / 16
        || sstride > usize::MAX / 16
        || !(fits(dst.len(), dstride) && fits(a.len(), sstride) && fits(b.len(), sstride))
    {
        return;
    }
    // SAFETY: block i reads a[(4i + l) · sstride] and b[(4i + l) · sstride] and writes
    // dst[(4i + l) · dstride] for l < 4, all in bounds for i < quads (checked above); quads ≥
    // 1, so `DLS`/`LE` run the loop exactly quads times.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            // Gather offsets in bytes and scatter offsets in words: [0, 1, 2, 3] · stride.
            "vidup.u32    q2, r0, #1",
            "vmul.i32     q3, q2, {ss}",
            "vmul.i32     q2, q2, {ds}",
            "dls   lr, {quads}",
            "2:",
            "vldrb.s32    q0, [r1, q3]",
            "vldrb.s32    q1, [r3, q3]",
            "vadd.i32     q0, q0, {oa}",
            "vadd.i32     q1, q1, {ob}",
            "vsli.32      q0, q1, #16",
            "vstrw.32     q0, [{dp}, q2, uxtw #2]",
            "add   r1, r1, {sb}",
            "add   r3, r3, {sb}",
            "add   {dp}, {dp}, {db}",
            "le    lr, 2b",
            // `VIDUP` takes its start in an even register.
            inout("r0") 0u32 => _,
            inout("r1") a.as_ptr() => _,
            inout("r3") b.as_ptr() => _,
            dp = inout(reg) dst.as_mut_ptr() => _,
            ss = in(reg) sstride,
            ds = in(reg) dstride,
            sb = in(reg) sstride * 4,
            db = in(reg) dstride * 16,
            quads = in(reg) quads,
            oa = in(reg) oa as i32,
            ob = in(reg) ob as i32,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
            options(nostack, preserves_flags),
        );
    }
}

/// The eight-column pass of the Helium line fills ([`pack_line_quads`],
/// [`fill_channel_pairs`]), one body for both: eight bytes of the rows at `r1` and `r3` widened
/// to 16-bit lanes, the offsets `$oa` and `$ob` (registers, or a vector) added, `VSRI`/`VSLI`
/// pair the two rows' odd and even columns into words (word lane i of q0 holds columns 2i,
/// 2i + 1 of the first row, of q1 those of the second), two scatter stores at `{dp}` with the
/// word offsets in q2 (even columns) and q3 (odd), `{dp}` on by `{sb}` bytes. Clobbers q0, q1
/// and q4.
macro_rules! eight_columns {
    ($oa:literal, $ob:literal) => {
        concat!(
            "vldrb.s16    q0, [r1], #8\n",
            "vldrb.s16    q1, [r3], #8\n",
            "vadd.i16     q0, q0, ",
            $oa,
            "\n",
            "vadd.i16     q1, q1, ",
            $ob,
            "\n",
            "vmov         q4, q1\n",
            "vsri.32      q1, q0, #16\n",
            "vsli.32      q0, q4, #16\n",
            "vstrw.32     q0, [{dp}, q2, uxtw #2]\n",
            "vstrw.32     q1, [{dp}, q3, uxtw #2]\n",
            "add   {dp}, {dp}, {sb}"
        )
    };
}

/// A whole line fill with Helium (the line engine's, `kernels::line`): for each pair `k` of
/// `rows` (entries `2k`, `2k + 1`: rows `a`, `b` with offsets `oa`, `ob`), `dst[k + j · vw]
/// = pack(a[j] + oa, b[j] + ob)` for `j < need`, `need` a multiple of 4: what
/// `arch::pack_rows` does for one word, for up to 16 words in one call. Eight columns
/// per pass: byte loads widened to 16-bit lanes, the offsets added in them, `VSRI`/`VSLI`
/// pair the two rows' values of the odd and the even columns into words, two scatter stores
/// write the eight line words (11 instructions per eight columns; a tail-predicated loop, so
/// the last pass of a fill of `8m + 4` columns loads and stores four; a fill of four columns
/// takes one 4-column block instead, 10 instructions per line word). The pair loop is
/// assembly too: 6 instructions per line word (the Rust loop around [`pack_row_quads`] spent
/// about 100 per word choosing the rows and checking slices). Returns false, doing nothing,
/// for an odd number of rows, `need` not a positive multiple of 4, or a `dst` too short.
pub fn pack_line_quads(dst: &mut [u32], vw: usize, rows: &LineRows<'_>) -> bool {
    let Some((pairs, quads)) = rows.fill_shape(dst.len(), vw) else {
        return false;
    };
    if pairs == 0 {
        return true;
    }
    // SAFETY: pair k reads rows[2k] and rows[2k + 1] (k < pairs, 2·pairs = rows.len ≤
    // CAPACITY, written; MaybeUninit<LineRow> has LineRow's layout), need = 4·quads bytes of
    // each from its address (every pushed row holds at least need bytes, and the borrow 'a
    // keeps them alive; the tail predication of `DLSTP.16` with need elements stops the loads
    // there), and writes dst[k + j·vw] for j < need (the last index, checked by fill_shape, is
    // in bounds; a word lane of the stores is enabled exactly when its column is below need,
    // the predicate of its low halfword's element). need ≥ 4 and pairs ≥ 1, so each pair's
    // loop runs ceil(need / 8) times and the pair loop pairs times. With need = 4 (quads 1),
    // each pair's block reads 4 bytes of each row and writes dst[k + j·vw] for j < 4.
    #[allow(unsafe_code)]
    unsafe {
        // Four columns: one block of four, no inner loop (10 instructions per line word; the
        // eight-column loop would take 17).
        if quads == 1 {
            core::arch::asm!(
                // Scatter offsets in words, columns j .. j + 4 of a block: [0, 1, 2, 3] · vw.
                "vidup.u32    q2, r2, #1",
                "vmul.i32     q2, q2, {dp}",
                "2:",
                "ldm   {tbl}!, {{r1, r2, r3, r4}}",
                "vldrb.s32    q0, [r1]",
                "vldrb.s32    q1, [r3]",
                "vadd.i32     q0, q0, r2",
                "vadd.i32     q1, q1, r4",
                "vsli.32      q0, q1, #16",
                "vstrw.32     q0, [{dk}, q2, uxtw #2]",
                "add   {dk}, {dk}, #4",
                "subs  r0, r0, #1",
                "bne   2b",
                inout("r0") pairs => _,
                out("r1") _,
                inout("r2") 0u32 => _,
                out("r3") _,
                out("r4") _,
                tbl = inout(reg) rows.rows.as_ptr() => _,
                dk = inout(reg) dst.as_mut_ptr() => _,
                dp = inout(reg) vw => _,
                out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                out("d4") _, out("d5") _,
                options(nostack),
            );
        } else {
            core::arch::asm!(
                // Scatter offsets in words: the even columns [0, 2, 4, 6] · vw, the odd ones vw on.
                "vidup.u32    q2, r2, #2",
                "vmul.i32     q2, q2, {dp}",
                "vadd.i32     q3, q2, {dp}",
                "2:",
                "ldm   {tbl}!, {{r1, r2, r3, r4}}",
                "mov   {dp}, {dk}",
                "dlstp.16     lr, {need}",
                "3:",
                eight_columns!("r2", "r4"),
                "letp  lr, 3b",
                "add   {dk}, {dk}, #4",
                "subs  r0, r0, #1",
                "bne   2b",
                inout("r0") pairs => _,
                // The widening byte loads take only low registers as their base; `VIDUP` takes
                // its start in an even register.
                out("r1") _,
                inout("r2") 0u32 => _,
                out("r3") _,
                out("r4") _,
                tbl = inout(reg) rows.rows.as_ptr() => _,
                dk = inout(reg) dst.as_mut_ptr() => _,
                dp = inout(reg) vw => _,
                // Used from a second pass on: then 8 · vw words lie within dst.
                sb = in(reg) vw.wrapping_mul(32),
                need = in(reg) 4 * quads,
                out("lr") _,
                out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                out("d8") _, out("d9") _,
                options(nostack),
            );
        }
    }
    true
}

/// A channel-minor line fill (the `mve` line engine's, `kernels::line`): tap `t` (channel
/// 0's row at `input[at[t] ..]`, channel `i`'s `i · cs` bytes on; `usize::MAX`: outside the
/// input, zeros) fills words `t · channels / 2 ..` of every column, channels `2k` and `2k + 1`
/// in word `k` of the tap: `dst[t · channels / 2 + k + j · vw] = pack(row_{2k}[j] + off,
/// row_{2k+1}[j] + off)` for `j < need` (zero rows add no offset). The row addresses are
/// computed here, so no table of rows is built (the channel-major fill hands each row out
/// through one, about 7 instructions per row); the slices are checked once per line. Eight
/// columns per pass as [`pack_line_quads`] (11 instructions), a fill of four columns in one
/// block (11 instructions per word). Returns false, doing nothing, for an odd or zero
/// `channels`, `need` not a positive multiple of 4 or over 256, a tap's last channel's row
/// not within `input`, or a `dst` too short.
pub fn fill_channel_pairs(
    dst: &mut [u32],
    vw: usize,
    need: usize,
    (input, at): (&[i8], &[usize]),
    (channels, cs): (usize, usize),
    off: i16,
) -> bool {
    let pairs = channels / 2;
    let words = at.len().checked_mul(pairs);
    let rows_fit = rows_within(input.len(), at, (channels, cs), need);
    let dst_fits = columns_within(dst.len(), need, vw, words);
    if pairs == 0
        || !channels.is_multiple_of(2)
        || need == 0
        || !need.is_multiple_of(4)
        || need > ZERO_ROW.len()
        || !rows_fit
        || !dst_fits
        || vw > u32::MAX as usize / 32
        || cs > i32::MAX as usize / 2
    {
        return false;
    }
    let passes = 8 * need.div_ceil(8) as i32;
    for (t, &a) in at.iter().enumerate() {
        let (row, step, off) = if a == usize::MAX {
            (ZERO_ROW.as_ptr(), 0, 0)
        } else {
            (input.as_ptr().wrapping_add(a), cs, off)
        };
        let dk = dst.as_mut_ptr().wrapping_add(t * pairs);
        // The first row's address after the passes of the eight-column loop, to the next
        // pair's: the loads moved it on 8 bytes per pass.
        let adv = (2 * step as i32).wrapping_sub(passes);
        // SAFETY (checked above): pair k of tap t reads need bytes from row + 2k·step and
        // row + (2k + 1)·step, within input (the last channel's row ends by input.len()) or
        // the zero row (step 0, need ≤ 256), and writes dst[t·pairs + k + j·vw] for j < need,
        // at most (need − 1)·vw + at.len()·pairs − 1, in bounds. In the eight-column loop the
        // tail predication of `DLSTP.16` with need elements stops the loads at need bytes and
        // enables a store's word lane exactly when its column is below need (as in
        // pack_line_quads); it runs ceil(need / 8) passes, after which `adv` takes the first
        // row's pointer to the next pair's. pairs ≥ 1, so the pair loop runs pairs times.
        #[allow(unsafe_code)]
        unsafe {
            if need == 4 {
                core::arch::asm!(
                    // Scatter offsets in words, the four columns: [0, 1, 2, 3] · vw.
                    "vidup.u32    q2, r2, #1",
                    "vmul.i32     q2, q2, {vw}",
                    "2:",
                    "add   r3, r1, {cs}",
                    "vldrb.s32    q0, [r1]",
                    "vldrb.s32    q1, [r3]",
                    "vadd.i32     q0, q0, {off}",
                    "vadd.i32     q1, q1, {off}",
                    "vsli.32      q0, q1, #16",
                    "vstrw.32     q0, [{dk}, q2, uxtw #2]",
                    "add   r1, r1, {cs}, lsl #1",
                    "add   {dk}, {dk}, #4",
                    "subs  r0, r0, #1",
                    "bne   2b",
                    inout("r0") pairs => _,
                    // The widening byte loads take only low registers as their base; `VIDUP`
                    // takes its start in an even register.
                    inout("r1") row => _,
                    inout("r2") 0u32 => _,
                    out("r3") _,
                    dk = inout(reg) dk => _,
                    vw = in(reg) vw,
                    cs = in(reg) step,
                    off = in(reg) off as i32,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _,
                    options(nostack),
                );
            } else {
                core::arch::asm!(
                    // Scatter offsets in words: the even columns [0, 2, 4, 6] · vw, the odd
                    // ones vw on; the offset in every 16-bit lane.
                    "vidup.u32    q2, r2, #2",
                    "vmul.i32     q2, q2, {dp}",
                    "vadd.i32     q3, q2, {dp}",
                    "vdup.16      q5, {off}",
                    "2:",
                    "add   r3, r1, {cs}",
                    "mov   {dp}, {dk}",
                    "dlstp.16     lr, {need}",
                    "3:",
                    eight_columns!("q5", "q5"),
                    "letp  lr, 3b",
                    "add   r1, r1, {adv}",
                    "add   {dk}, {dk}, #4",
                    "subs  r0, r0, #1",
                    "bne   2b",
                    inout("r0") pairs => _,
                    inout("r1") row => _,
                    inout("r2") 0u32 => _,
                    out("r3") _,
                    dk = inout(reg) dk => _,
                    dp = inout(reg) vw => _,
                    // Used from a second pass on: then 8 · vw words lie within dst.
                    sb = in(reg) vw * 32,
                    need = in(reg) need,
                    cs = in(reg) step,
                    adv = in(reg) adv,
                    off = in(reg) off as i32,
                    out("lr") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                    out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                    options(nostack),
                );
            }
        }
    }
    true
}

/// Whether every tap's rows lie within an input of `input_len` bytes: tap `t`'s channel `i`
/// reads `len` bytes from `at[t] + i·cs` (`usize::MAX`: a tap outside the input, which reads
/// no row). The line fills' check of their sources.
#[inline(always)]
fn rows_within(input_len: usize, at: &[usize], (channels, cs): (usize, usize), len: usize) -> bool {
    let last_row = channels.checked_sub(1).and_then(|c| c.checked_mul(cs));
    at.iter().all(|&a| {
        a == usize::MAX
            || last_row
                .and_then(|r| r.checked_add(a))
                .and_then(|r| r.checked_add(len))
                .is_some_and(|e| e <= input_len)
    })
}

/// Whether `count` entries in each of `len` columns `stride` apart (`count` `None`: it
/// overflowed) lie within a line of `dst_len` elements. The line fills' check of their
/// destination.
#[inline(always)]
fn columns_within(dst_len: usize, len: usize, stride: usize, count: Option<usize>) -> bool {
    len.checked_sub(1)
        .and_then(|j| j.checked_mul(stride))
        .zip(count)
        .and_then(|(e, n)| e.checked_add(n.checked_sub(1)?))
        .is_some_and(|last| last < dst_len)
}

/// The pair loop's inner loop on the i16 line: two positions' four words and two channels'
/// (`VLD20`/`VLD21` split their interleaved words), `VMLAVA.S16` eight products each.
macro_rules! i16_quad {
    () => {
        concat!(
            "vldrw.u32    q0, [{x0}], #16\n",
            "vldrw.u32    q1, [{x1}], #16\n",
            "vld20.32     {{q2, q3}}, [{w}]\n",
            "vld21.32     {{q2, q3}}, [{w}]!\n",
            "vmlava.s16   r0, q0, q2\n",
            "vmlava.s16   r2, q1, q2\n",
            "vmlava.s16   r4, q0, q3\n",
            "vmlava.s16   r8, q1, q3"
        )
    };
}

/// The pair loop's inner loop on the int8 line: two positions' 16 bytes and two channels'
/// 16-byte blocks, `VMLADAVA.S8` sixteen products each.
macro_rules! s8_block {
    () => {
        concat!(
            "vldrb.u8     q0, [{x0}], #16\n",
            "vldrb.u8     q1, [{x1}], #16\n",
            "vldrb.u8     q2, [{w}], #16\n",
            "vldrb.u8     q3, [{w}], #16\n",
            "vmladava.s8  r0, q0, q2\n",
            "vmladava.s8  r2, q1, q2\n",
            "vmladava.s8  r4, q0, q3\n",
            "vmladava.s8  r8, q1, q3"
        )
    };
}

/// The register-state pair loop of [`PairRows`] and [`PairRowsS8`]: for each channel pair,
/// for each pair of positions, the inner loop (`$start` with the count from `st[2]`, the body,
/// `$end`) into the biases' accumulators r0, r2 (first channel) and r4, r8 (second), then
/// `$store`; the state array `st` as `PairRows::pairs_in_registers` documents it. `$regs`:
/// (st, x0, x1, w, a0, a1, position pairs, first bias, second bias).
macro_rules! pair_loop {
    ($regs:expr, [$start:literal], [$body:ident], $end:literal, [$($store:literal),*]) => {{
        let (st, x0, x1, w, a0, a1, pairs, b0, b1) = $regs;
        core::arch::asm!(
            "2:",
            "ldr   lr, [{st}, #8]",
            $start,
            "3:",
            pair_loop!(@body $body),
            $end,
            $($store,)*
            // Weights back to the pair's start, inputs on to the next pair's.
            "ldrd  r0, r2, [{st}, #12]",
            "sub   {w}, {w}, r0",
            "add   {x0}, {x0}, r2",
            "add   {x1}, {x1}, r2",
            "ldrd  r0, r4, [{st}]",
            "mov   r2, r0",
            "mov   r8, r4",
            "subs  {pairs}, {pairs}, #1",
            "bne   2b",
            // The next channel pair: its weights, rows and biases; the row again.
            "ldr   r0, [{st}, #20]",
            "subs  r0, r0, #1",
            "beq   4f",
            "str   r0, [{st}, #20]",
            "ldrd  {x0}, {x1}, [{st}, #24]",
            "ldr   r0, [{st}, #32]",
            "add   {w}, {w}, r0",
            "ldrd  {a0}, r0, [{st}, #36]",
            "add   {a0}, {a0}, r0, lsl #1",
            "str   {a0}, [{st}, #36]",
            "add   {a1}, {a0}, r0",
            "ldr   r2, [{st}, #44]",
            "ldrd  r0, r4, [r2], #8",
            "str   r2, [{st}, #44]",
            "strd  r0, r4, [{st}]",
            "mov   r2, r0",
            "mov   r8, r4",
            "ldr   {pairs}, [{st}, #48]",
            "b     2b",
            "4:",
            st = in(reg) st,
            x0 = inout(reg) x0 => _,
            x1 = inout(reg) x1 => _,
            w = inout(reg) w => _,
            a0 = inout(reg) a0 => _,
            a1 = inout(reg) a1 => _,
            pairs = inout(reg) pairs => _,
            inout("r0") b0 => _,
            inout("r2") b0 => _,
            inout("r4") b1 => _,
            inout("r8") b1 => _,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
            options(nostack),
        )
    }};
    (@body I16_QUAD) => { i16_quad!() };
    (@body S8_BLOCK) => { s8_block!() };
}

/// `arch::dot2x2_row`'s pairs of positions with Helium, for an even `n ≥ 4` words: for each pair `p < pairs`, positions `q = 2p` and `q + 1` get
/// `acc0[q·astep] = bias[0] + x_q·w_0`, `acc0[(q + 1)·astep] = bias[0] + x_{q+1}·w_0` and the
/// same with `acc1`, `bias[1]` and `w_1`, where `x_q = x[q·step .. q·step + n]` and the
/// channels' words are interleaved in `w`. The pair loop is assembly too: 13 instructions per
/// pair around the 9-instruction, 32-MAC inner loop when `n ≡ 0 mod 4` and the accumulators
/// are one or two words apart (`astep` 1 or 2: the line engines' rows and stride-2 phases),
/// its state in registers; otherwise about 22, the state on the stack, and 16 more for the
/// last two words when `n ≡ 2 mod 4`. Returns false, doing nothing, for any other `n` or a slice too
/// short for `pairs`: [`PairRows::new`] and [`PairRows::run`] in one call.
pub fn dot2x2_row_pairs(
    x: &[u32],
    (step, n): (usize, usize),
    pairs: usize,
    w: &[u32],
    bias: [i32; 2],
    (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
) -> bool {
    if pairs == 0 {
        return true;
    }
    PairRows::new(step, n, pairs, astep).is_some_and(|rows| rows.run(x, w, bias, (acc0, acc1)))
}

/// The shape of a [`dot2x2_row_pairs`] call, checked once: a layer runs every row of a phase
/// with one shape, so each row's call compares four slice lengths with the ones computed
/// here instead of checking the whole shape again (about 50 instructions a call).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairRows {
    step: usize,
    n: usize,
    pairs: usize,
    astep: usize,
    /// The slice lengths a row needs: x, w and each accumulator row.
    x_len: usize,
    w_len: usize,
    acc_len: usize,
}

impl PairRows {
    /// The shape of `pairs ≥ 1` pairs of positions `step` words apart, `n` words each
    /// (`n ≥ 4`, `n ≡ 0` or `2 mod 4`), accumulators `astep` words apart; `None` for any
    /// other shape or one whose extent overflows.
    pub fn new(step: usize, n: usize, pairs: usize, astep: usize) -> Option<Self> {
        if pairs == 0
            || !matches!(n % 4, 0 | 2)
            || n < 4
            || pairs > usize::MAX / 4
            || step > usize::MAX / 8
            || astep > usize::MAX / 8
        {
            return None;
        }
        let last = 2 * pairs - 1;
        Some(PairRows {
            step,
            n,
            pairs,
            astep,
            x_len: last.checked_mul(step)?.checked_add(n)?,
            w_len: n.checked_mul(2)?,
            acc_len: last.checked_mul(astep)?.checked_add(1)?,
        })
    }

    /// Whether the loop keeps its state in registers: `n ≡ 0 mod 4` and accumulators one or
    /// two words apart.
    #[inline(always)]
    pub fn in_registers(&self) -> bool {
        self.n.is_multiple_of(4) && (self.astep == 1 || self.astep == 2)
    }

    /// The pair loop with its state in registers, for every channel pair `k < bias.len()`:
    /// weights from `w + k·wstep` bytes, biases `bias[k]`, accumulators from `a0` and `a1`
    /// for the first pair and `a0 + 2k·rstep`, `a0 + (2k + 1)·rstep` bytes after it.
    ///
    /// # Safety
    ///
    /// `in_registers()`, `bias` not empty, and for every pair `k`: `x` readable for
    /// `x_len` words, the weights for `w_len` words and both accumulator rows writable for
    /// `acc_len` words (in the caller's allocations).
    #[allow(unsafe_code)]
    #[inline(never)]
    unsafe fn pairs_in_registers(
        &self,
        x: *const u32,
        w: *const u32,
        bias: &[[i32; 2]],
        (a0, a1): (*mut i32, *mut i32),
        (wstep, rstep): (usize, usize),
    ) {
        let [b0, b1] = bias.first().copied().unwrap_or([0, 0]);
        // The loop's state (words): biases, inner iterations, weight bytes per pair (8n), the
        // advance from a pair's end to the next pair's start, channel pairs left, the x
        // pointers' start, the weight step, the first row's start, the row step, the next
        // pair's biases, position pairs.
        let mut st = [
            b0 as u32,
            b1 as u32,
            (self.n / 4) as u32,
            (self.n * 8) as u32,
            (2 * self.step * 4).wrapping_sub(self.n * 4) as u32,
            bias.len() as u32,
            x as u32,
            x.wrapping_add(self.step) as u32,
            wstep as u32,
            a0 as u32,
            rstep as u32,
            bias.as_ptr().wrapping_add(1) as u32,
            self.pairs as u32,
        ];
        // SAFETY (the caller's conditions): pair p of a channel pair reads x[2p·step ..][..n]
        // and x[(2p + 1)·step ..][..n] (within x_len words; n / 4 ≥ 1 inner iterations leave
        // the x pointers n words and the weight pointer 2n words on, undone by the 8n-byte
        // step back and the 2·step − n word advance) and stores to acc[2p·astep] and
        // acc[(2p + 1)·astep] of its two rows (within acc_len words). A next channel pair
        // starts again from the saved x pointers, its weights wstep bytes on, its rows 2·rstep
        // bytes on and its biases from the next entry of `bias` (the count in `st` stops the
        // loop after bias.len() pairs). `st` is a live local array of 13 words.
        unsafe {
            let regs = (
                st.as_mut_ptr(),
                x,
                x.add(self.step),
                w,
                a0,
                a1,
                self.pairs,
                b0,
                b1,
            );
            if self.astep == 1 {
                pair_loop!(
                    regs,
                    ["dls   lr, lr"],
                    [I16_QUAD],
                    "le    lr, 3b",
                    ["strd  r0, r2, [{a0}], #8", "strd  r4, r8, [{a1}], #8"]
                );
            } else {
                pair_loop!(
                    regs,
                    ["dls   lr, lr"],
                    [I16_QUAD],
                    "le    lr, 3b",
                    [
                        "str   r0, [{a0}], #8",
                        "str   r2, [{a0}], #8",
                        "str   r4, [{a1}], #8",
                        "str   r8, [{a1}], #8"
                    ]
                );
            }
        }
    }

    /// Every channel pair `k < bias.len()` of a line in one call: what [`PairRows::run`]
    /// computes with weights `w[k·wstride ..]`, biases `bias[k]` and accumulator rows
    /// `acc[2k·rstride + first ..]` and `acc[(2k + 1)·rstride + first ..]`. One call per
    /// line instead of one per channel pair (about 25 instructions per further pair against
    /// 90). Returns false, doing nothing, for a shape whose loop keeps its state on the stack
    /// ([`PairRows::in_registers`] false: the caller runs its pairs one by one) or a slice too
    /// short for every pair.
    pub fn run_channels(
        &self,
        x: &[u32],
        (w, wstride): (&[u32], usize),
        bias: &[[i32; 2]],
        acc: &mut [i32],
        (rstride, first): (usize, usize),
    ) -> bool {
        let Some(last) = bias.len().checked_sub(1) else {
            return true;
        };
        let fits = self.in_registers()
            && x.len() >= self.x_len
            && wstride <= usize::MAX / 8
            && rstride <= usize::MAX / 8
            && last
                .checked_mul(wstride)
                .and_then(|a| a.checked_add(self.w_len))
                .is_some_and(|e| e <= w.len())
            && (2 * last + 1)
                .checked_mul(rstride)
                .and_then(|a| a.checked_add(first))
                .and_then(|a| a.checked_add(self.acc_len))
                .is_some_and(|e| e <= acc.len());
        if !fits {
            return false;
        }
        let a0 = acc.as_mut_ptr().wrapping_add(first);
        let a1 = a0.wrapping_add(rstride);
        // SAFETY: in_registers() (checked above); for every pair k ≤ last the weights from
        // k·wstride run w_len words within w, the rows from 2k·rstride + first and
        // (2k + 1)·rstride + first run acc_len words within acc, and x holds x_len words
        // (checked above); the steps are in bytes.
        #[allow(unsafe_code)]
        unsafe {
            self.pairs_in_registers(
                x.as_ptr(),
                w.as_ptr(),
                bias,
                (a0, a1),
                (wstride * 4, rstride * 4),
            );
        }
        true
    }

    /// One row: what [`dot2x2_row_pairs`] computes for this shape. Returns false, doing
    /// nothing, when a slice is shorter than the shape needs.
    #[inline(never)]
    pub fn run(
        &self,
        x: &[u32],
        w: &[u32],
        bias: [i32; 2],
        (acc0, acc1): (&mut [i32], &mut [i32]),
    ) -> bool {
        if x.len() < self.x_len
            || w.len() < self.w_len
            || acc0.len() < self.acc_len
            || acc1.len() < self.acc_len
        {
            return false;
        }
        // Accumulators one or two words apart (the line engine's rows, the transposed
        // engine's x phases of stride 2), `n` a multiple of 4: the loop with its state in
        // registers, about 13 instructions per pair around the inner loop.
        if self.in_registers() {
            let (a0, a1) = (acc0.as_mut_ptr(), acc1.as_mut_ptr());
            // SAFETY: the slices are at least as long as `new` computed (checked above), one
            // channel pair (no step to a next pair's weights or rows).
            #[allow(unsafe_code)]
            unsafe {
                self.pairs_in_registers(x.as_ptr(), w.as_ptr(), &[bias], (a0, a1), (0, 0));
            }
            return true;
        }
        // SAFETY: the slices are at least as long as `new` computed (checked above).
        #[allow(unsafe_code)]
        unsafe {
            self.pairs_on_stack(
                x.as_ptr(),
                w.as_ptr(),
                bias,
                (acc0.as_mut_ptr(), acc1.as_mut_ptr()),
            );
        }
        true
    }

    /// The pair loop of [`PairRows::run`] for the shapes whose state does not fit the
    /// registers (`astep` other than 1 or 2, or `n ≡ 2 mod 4`): its state read back from the
    /// stack after each pair, the last two words of `n ≡ 2 mod 4` by `SMLAD`s.
    ///
    /// # Safety
    ///
    /// `x` readable for `x_len` words, `w` for `w_len` words, both accumulator rows writable
    /// for `acc_len` words (in the caller's allocations).
    #[allow(unsafe_code)]
    #[inline(always)]
    unsafe fn pairs_on_stack(
        &self,
        x: *const u32,
        w: *const u32,
        bias: [i32; 2],
        (acc0, acc1): (*mut i32, *mut i32),
    ) {
        let PairRows {
            step,
            n,
            pairs,
            astep,
            ..
        } = *self;
        // The pair loop's state, read back after each pair: accumulator pointers, accumulator
        // step (bytes), biases, weights, the advance from one pair's end to the next pair's
        // start (bytes), the inner loop's count, pairs left.
        let mut st = [
            acc0 as u32,
            acc1 as u32,
            (astep * 4) as u32,
            bias[0] as u32,
            bias[1] as u32,
            w as u32,
            (2 * step * 4).wrapping_sub(n * 4) as u32,
            (n / 4) as u32,
            pairs as u32,
        ];
        // The last two words of a pair (`n ≡ 2 mod 4`): per word, its two positions' words and
        // the two channels' weights through four `SMLAD`s.
        macro_rules! pairs {
            ($($tail:literal),*) => {
                core::arch::asm!(
                    "2:",
                    "ldr   {t}, [{st}, #28]",
                    "dls   lr, {t}",
                    "3:",
                    "vldrw.u32    q0, [{x0}], #16",
                    "vldrw.u32    q1, [{x1}], #16",
                    "vld20.32     {{q2, q3}}, [{w}]",
                    "vld21.32     {{q2, q3}}, [{w}]!",
                    "vmlava.s16   r0, q0, q2",
                    "vmlava.s16   r2, q1, q2",
                    "vmlava.s16   r4, q0, q3",
                    "vmlava.s16   r8, q1, q3",
                    "le    lr, 3b",
                    $($tail,)*
                    "ldrd  {t}, {u}, [{st}]",
                    "ldr   {w}, [{st}, #8]",
                    "str   r0, [{t}]",
                    "str   r2, [{t}, {w}]",
                    "str   r4, [{u}]",
                    "str   r8, [{u}, {w}]",
                    "add   {t}, {t}, {w}, lsl #1",
                    "add   {u}, {u}, {w}, lsl #1",
                    "strd  {t}, {u}, [{st}]",
                    "ldrd  r0, r4, [{st}, #12]",
                    "mov   r2, r0",
                    "mov   r8, r4",
                    "ldrd  {w}, {t}, [{st}, #20]",
                    "add   {x0}, {x0}, {t}",
                    "add   {x1}, {x1}, {t}",
                    "ldr   {t}, [{st}, #32]",
                    "subs  {t}, {t}, #1",
                    "str   {t}, [{st}, #32]",
                    "bne   2b",
                    st = in(reg) st.as_mut_ptr(),
                    x0 = inout(reg) x => _,
                    x1 = inout(reg) x.add(step) => _,
                    w = inout(reg) w => _,
                    t = out(reg) _,
                    u = out(reg) _,
                    v = out(reg) _,
                    inout("r0") bias[0] => _,
                    inout("r2") bias[0] => _,
                    inout("r4") bias[1] => _,
                    inout("r8") bias[1] => _,
                    out("lr") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                    options(nostack),
                )
            };
        }
        // SAFETY (the caller's conditions): pair p reads x[2p·step ..][..n] and x[(2p + 1)·step ..][..n], both ending at
        // most at last·step + n ≤ x.len(), and w[..2n] (the lengths `new` computed, checked
        // above); n / 4 ≥ 1, so the inner
        // `DLS`/`LE` loop runs exactly n / 4 times, and with the tail (n mod 4 = 2) leaves both
        // x pointers n words on and the weight pointer 2n words on; the advance (2·step − n
        // words) brings the x pointers to the next pair's start. The stores go to
        // acc[q·astep] and acc[(q + 1)·astep] with q + 1 ≤ last, in bounds of both accumulator
        // slices (checked above). `st` is a live local array of 9 words.
        #[allow(unsafe_code)]
        unsafe {
            if n % 4 == 0 {
                pairs!("@ {v}");
            } else {
                pairs!(
                    "ldr   {t}, [{x0}], #4",
                    "ldr   {u}, [{x1}], #4",
                    "ldr   {v}, [{w}], #4",
                    "smlad r0, {t}, {v}, r0",
                    "smlad r2, {u}, {v}, r2",
                    "ldr   {v}, [{w}], #4",
                    "smlad r4, {t}, {v}, r4",
                    "smlad r8, {u}, {v}, r8",
                    "ldr   {t}, [{x0}], #4",
                    "ldr   {u}, [{x1}], #4",
                    "ldr   {v}, [{w}], #4",
                    "smlad r0, {t}, {v}, r0",
                    "smlad r2, {u}, {v}, r2",
                    "ldr   {v}, [{w}], #4",
                    "smlad r4, {t}, {v}, r4",
                    "smlad r8, {u}, {v}, r8"
                );
            }
        }
    }
}

/// The four-value blocks of `arch::requant_rows_s8` (and of
/// `arch::requant_row_s8`, one row): row `c < params.len()` requantises
/// `acc[c·4·quads ..][..4·quads]` with `params[c] = [multiplier, left1, right, half, neg]`
/// into `out[c·plane ..][..4·quads]`: `t = r(acc[i])` with `x = VRMULH(acc << left1,
/// multiplier)` (= `SMMULR`) and `r = (x + half + (x >> 31 & neg)) >> right`, then with
/// `relu` `t = max(t, 0)`, with a skip table `t = t +sat skip[out[i] as u8]` (the old value,
/// gathered by `VLDRW … UXTW #2`), and `out[i] = clamp(t, −128, 127)`: about 3.5
/// instructions per value and 12 per row (a call per row took about 60). Returns false, writing nothing, unless `quads ≥ 1` and every
/// row's slices fit. A `left1` or `right` of 32 or more shifts as `VSHL` does (the callers
/// pass `arch::RowWords`, whose shifts are below 32).
pub fn requant_rows_quads(
    acc: &[i32],
    out: &mut [i8],
    params: &[[i32; 5]],
    (quads, plane): (usize, usize),
    relu: bool,
    skip: Option<&[i32; 256]>,
) -> bool {
    let rows = params.len();
    let width = quads.saturating_mul(4);
    let fits = rows > 0
        && quads > 0
        && quads < usize::MAX / 16
        && rows.checked_mul(width).is_some_and(|n| n <= acc.len())
        && (rows - 1)
            .checked_mul(plane)
            .and_then(|a| a.checked_add(width))
            .is_some_and(|n| n <= out.len())
        && plane <= i32::MAX as usize;
    if !fits {
        return false;
    }
    let lut = skip.map_or(core::ptr::null(), |l| l.as_ptr());
    // Per row: its quads, then the step from the row's end to the next row's start (bytes).
    let st = [quads as u32, plane.wrapping_sub(width) as u32];
    // Without a skip table the ReLU is the clamp's lower bound (0 for −128); with one it
    // comes before the skip's add, a `VMAX` with 0 (with i32::MIN, no ReLU).
    let low: i32 = if relu && skip.is_none() { 0 } else { -128 };
    let floor: i32 = if relu { 0 } else { i32::MIN };
    // SAFETY: row c reads acc[c·width ..][..width] (rows are contiguous: the accumulator
    // pointer runs on from one row to the next) and reads and writes out[c·plane ..][..width],
    // in bounds for c < rows (checked above); the output pointer moves on by plane − width
    // bytes after a row's width bytes. Each row's five words are read from params[c] (in
    // bounds: the loop runs rows times, rows ≥ 1); `VSHL` by a register is defined for any
    // shift. The skip table is gathered at unsigned byte indices < 256 (only in the skip
    // variant). quads ≥ 1, so `DLS`/`LE` run each row's loop exactly quads times; `st` is a
    // live local array.
    #[allow(unsafe_code)]
    unsafe {
        macro_rules! rows {
            ($relu:literal, $skip1:literal, $skip2:literal, $skip3:literal) => {
                core::arch::asm!(
                    "vmov.i32     q6, #127",
                    "vdup.32      q7, {t}",
                    "vdup.32      q2, {half}",
                    "2:",
                    "ldr   {t}, [{pp}]",
                    "vdup.32      q4, {t}",
                    "ldr   {t}, [{pp}, #16]",
                    "vdup.32      q5, {t}",
                    "ldrd  {l1}, {nr}, [{pp}, #4]",
                    "ldr   {half}, [{pp}, #12]",
                    "add   {pp}, {pp}, #20",
                    "rsb   {nr}, {nr}, #0",
                    "ldr   {t}, [{st}]",
                    "dls   lr, {t}",
                    "3:",
                    "vldrw.u32    q0, [{ap}], #16",
                    "vshl.s32     q0, {l1}",
                    "vrmulh.s32   q0, q0, q4",
                    "vshr.s32     q1, q0, #31",
                    "vand         q1, q1, q5",
                    "vadd.i32     q0, q0, {half}",
                    "vadd.i32     q0, q0, q1",
                    "vshl.s32     q0, {nr}",
                    $relu,
                    $skip1,
                    $skip2,
                    $skip3,
                    "vmin.s32     q0, q0, q6",
                    "vmax.s32     q0, q0, q7",
                    "vstrb.32     q0, [r1], #4",
                    "le    lr, 3b",
                    "ldr   {t}, [{st}, #4]",
                    "add   r1, r1, {t}",
                    "cmp   {pp}, {pe}",
                    "bne   2b",
                    "@ {lut}",
                    ap = inout(reg) acc.as_ptr() => _,
                    // The narrowing byte store takes only a low register as its base.
                    inout("r1") out.as_mut_ptr() => _,
                    pp = inout(reg) params.as_ptr() => _,
                    pe = in(reg) params.as_ptr().add(rows),
                    st = in(reg) st.as_ptr(),
                    lut = in(reg) lut,
                    // The clamp's lower bound and the ReLU's floor, read before the rows.
                    t = inout(reg) low => _,
                    half = inout(reg) floor => _,
                    l1 = out(reg) _,
                    nr = out(reg) _,
                    out("lr") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                    out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                    out("d12") _, out("d13") _, out("d14") _, out("d15") _,
                    options(nostack),
                )
            };
        }
        if skip.is_some() {
            rows!(
                "vmax.s32 q0, q0, q2",
                "vldrb.u32 q1, [r1]",
                "vldrw.u32 q3, [{lut}, q1, uxtw #2]",
                "vqadd.s32 q0, q0, q3"
            );
        } else {
            rows!("", "", "", "");
        }
    }
    true
}

/// The four-value blocks of `arch::requant_max_row`: `out[i] = sat(r(acc[i]))` for
/// `i < 4 · quads` (`r` as in [`requant_rows_quads`], `sat` the int8 clamp or, with `relu`,
/// the clamp to `0..=127`), returning the larger of `max` and every value written (`VMAXV`
/// across each block): about 3.5 instructions per value (the `dsp` loop takes 14). Returns
/// `max` and does nothing unless `acc` and `out` hold `4 · quads` values and `left1`, `right`
/// are below 32.
#[inline(always)]
pub fn requant_max_row_quads(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    max: i8,
    quads: usize,
) -> i8 {
    let n = quads.saturating_mul(4);
    if quads == 0 || acc.len() < n || out.len() < n || left1 >= 32 || right >= 32 {
        return max;
    }
    // The clamp's bounds: 0..=127 with ReLU, −128..=127 without.
    let low: i32 = if relu { 0 } else { -128 };
    let mut mx = max as i32;
    // SAFETY: block i reads acc[4i..4i + 4] and writes out[4i..4i + 4], in bounds for
    // i < quads (checked above). Shifts by registers whose magnitude is below 32. quads ≥ 1,
    // so `DLS`/`LE` run the loop exactly quads times.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "vdup.32      q4, {m}",
            "vdup.32      q5, {neg}",
            "vmov.i32     q6, #127",
            "vdup.32      q7, {low}",
            "dls   lr, {quads}",
            "2:",
            "vldrw.u32    q0, [{ap}], #16",
            "vshl.s32     q0, {l1}",
            "vrmulh.s32   q0, q0, q4",
            "vshr.s32     q1, q0, #31",
            "vand         q1, q1, q5",
            "vadd.i32     q0, q0, {half}",
            "vadd.i32     q0, q0, q1",
            "vshl.s32     q0, {nr}",
            "vmin.s32     q0, q0, q6",
            "vmax.s32     q0, q0, q7",
            "vmaxv.s32    {mx}, q0",
            "vstrb.32     q0, [r1], #4",
            "le    lr, 2b",
            ap = inout(reg) acc.as_ptr() => _,
            // The narrowing byte store takes only a low register as its base.
            inout("r1") out.as_mut_ptr() => _,
            quads = in(reg) quads,
            l1 = in(reg) left1,
            nr = in(reg) -(right as i32),
            m = in(reg) multiplier,
            neg = in(reg) neg,
            half = in(reg) half,
            low = in(reg) low,
            mx = inout(reg) mx,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d8") _, out("d9") _, out("d10") _, out("d11") _,
            out("d12") _, out("d13") _, out("d14") _, out("d15") _,
            options(nostack),
        );
    }
    mx as i8
}

/// `table_columns!(name, lanes, offset type, weight type, bits, offset load)`: the cost
/// volume's columns `col .. col + lanes` in one pass down the rows, in lanes of `bits` bits
/// (see [`table_columns4`]); one body for both widths.
macro_rules! table_columns {
    ($(#[$doc:meta])* $name:ident, $lanes:literal, $off:ty, $wt:ty, $b:literal, $ld:literal) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        #[inline(always)]
        pub fn $name(
            out: &mut [i8],
            reference: &[i8],
            src: &[i8],
            (width, col): (usize, usize),
            cs: [usize; $lanes],
            weights: [(i16, i16); $lanes],
            table: &[i8; 512],
            sum: bool,
        ) -> bool {
            let n = out.len();
            let lanes_ok = cs.iter().zip(&weights).all(|(&c, &(wl, wr))| {
                c.checked_add(1).is_some_and(|c1| c1 < width)
                    && ((wl >= 0 && wr >= 0 && wl as i32 + wr as i32 == 256) || (wl, wr) == (0, 0))
            });
            let ok = lanes_ok
                && n > 0
                && reference.len() == n
                && src.len() == n
                && width > 0
                && width - 1 <= <$off>::MAX as usize
                && n.is_multiple_of(width)
                && col.checked_add($lanes).is_some_and(|e| e <= width)
                && n <= i32::MAX as usize;
            if !ok {
                return false;
            }
            let rows = n / width;
            // Gather offsets (bytes from the row's start: the left columns, then the right
            // ones) and the lanes' weights, loaded into vector registers once.
            let offsets: [$off; 2 * $lanes] =
                core::array::from_fn(|k| (cs[k % $lanes] + k / $lanes) as $off);
            let w: [$wt; 2 * $lanes] = core::array::from_fn(|k| {
                let (wl, wr) = weights[k % $lanes];
                (if k < $lanes { wl } else { wr }) as $wt
            });
            // SAFETY: row k (k < rows, `DLS`/`LE` run exactly rows ≥ 1 times) reads reference
            // and writes out at k·width + col .. + lanes (col + lanes ≤ width), and gathers
            // src at k·width + c_l and + c_l + 1 (c_l + 1 < width, so the offsets' type holds
            // them): all below n = rows·width, the slices' length. The lanes' sums are exact
            // in `bits` bits (weights ≥ 0 summing to 256 or both 0, values in −128..=127, so
            // −32768..=32512) and `VRSHR` rounds without overflow; the table index is
            // reference ∓ w + 255 (or + 256), 0..=510.
            macro_rules! columns_loop {
                ($combine:literal, $offset:literal) => {{
                    #[allow(unsafe_code)]
                    unsafe {
                        core::arch::asm!(
                            concat!("vldr", $ld, "    q4, [{op}]"),
                            concat!("vldr", $ld, "    q5, [{op}, #16]"),
                            concat!("vldr", $ld, "    q2, [{wp}]"),
                            concat!("vldr", $ld, "    q3, [{wp}, #16]"),
                            "dls   lr, {rows}",
                            "2:",
                            concat!("vldrb.s", $b, "    q0, [{sp}, q4]"),
                            concat!("vldrb.s", $b, "    q1, [{sp}, q5]"),
                            concat!("vmul.i", $b, "     q0, q0, q2"),
                            concat!("vmul.i", $b, "     q1, q1, q3"),
                            concat!("vadd.i", $b, "     q0, q0, q1"),
                            concat!("vrshr.s", $b, "    q0, q0, #8"),
                            concat!("vldrb.s", $b, "    q1, [r1]"),
                            concat!($combine, ".i", $b, "     q1, q1, q0"),
                            concat!("vadd.i", $b, "     q1, q1, {base}"),
                            concat!("vldrb.u", $b, "    q0, [{tb}, q1]"),
                            concat!("vstrb.", $b, "     q0, [r3]"),
                            "add   {sp}, {sp}, {st}",
                            "add   r1, r1, {st}",
                            "add   r3, r3, {st}",
                            "le    lr, 2b",
                            op = in(reg) offsets.as_ptr(),
                            wp = in(reg) w.as_ptr(),
                            rows = in(reg) rows,
                            sp = inout(reg) src.as_ptr() => _,
                            // The widening load and the narrowing store take only low
                            // registers.
                            inout("r1") reference.as_ptr().wrapping_add(col) => _,
                            inout("r3") out.as_mut_ptr().wrapping_add(col) => _,
                            base = in(reg) $offset,
                            tb = in(reg) table.as_ptr(),
                            st = in(reg) width,
                            out("lr") _,
                            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                            out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                            options(nostack),
                        )
                    };
                }};
            }
            if sum {
                columns_loop!("vadd", 256u32);
            } else {
                columns_loop!("vsub", 255u32);
            }
            true
        }
    };
}

table_columns!(
    /// Four adjacent columns `col .. col + 4` of `arch::cost_column` (`sum` false) or
    /// `arch::mean_column` (`sum` true) with Helium, one row of four values per
    /// iteration: for every row `k` and lane `l`, with `i = k·width + col + l`, the warped
    /// value `w = (src[k·width + c_l]·wl_l + src[k·width + c_l + 1]·wr_l + 128) >> 8` (two byte
    /// gathers, `VRSHR` for the rounding) and `out[i] = table[reference[i] − w + 255]` (or
    /// `reference[i] + w + 256`), the table read by a third gather: 15 instructions per four
    /// values where the `SMUAD` loop takes 12 per value. The same conditions as the one-column
    /// loop for each lane, and `col + 4 ≤ width`; anything else writes nothing and gives
    /// false.
    table_columns4, 4, u32, i32, "32", "w.u32"
);

table_columns!(
    /// Eight adjacent columns `col .. col + 8` of [`table_columns4`]'s loop, in 16-bit lanes:
    /// the warped value's products fit i16 (|src| ≤ 128 times weights summing to 256), the
    /// byte gathers take 16-bit offsets (rows of at most 65,536 columns, the table's 512
    /// entries), so one pass does eight columns in the 15 instructions four took. The same
    /// conditions as [`table_columns4`] for each lane, and `col + 8 ≤ width`; anything else
    /// writes nothing and gives false.
    table_columns8, 8, u16, i16, "16", "h.u16"
);

/// `arch::exp_sums` with Helium for a non-zero multiple of 4 logits: four logits per
/// iteration, the table read by a halfword gather, `VADDVA` adding the four weights to `S`
/// and `VMLADAVA` their products with the bins' indices to `T` (7 instructions per four
/// logits; the `DSP` loop takes 5 per logit). Returns `None` for other lengths.
#[inline(always)]
pub fn exp_sums(logits: &[i8], m: i8, exp: &[u16; 256]) -> Option<(u32, u32)> {
    let n = logits.len();
    if n == 0 || !n.is_multiple_of(4) || n > u32::MAX as usize {
        return None;
    }
    let (s, t): (u32, u32);
    // SAFETY: iteration k (exactly n/4 ≥ 1 of them, by `DLS`/`LE`) reads logits[4k..4k + 4]
    // and gathers exp at (m − q) & 0xff < 256, the portable loop's `(m − q) as u8`.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "vdup.32      q3, {m}",
            "vmov.i32     q4, #0xff",
            "vidup.u32    q2, r4, #1",
            "dls   lr, {quads}",
            "2:",
            "vldrb.s32    q0, [r1], #4",
            "vsub.i32     q0, q3, q0",
            "vand         q0, q0, q4",
            "vldrh.u32    q1, [{ex}, q0, uxtw #1]",
            "vaddva.u32   r0, q1",
            "vmladava.u32 r2, q1, q2",
            "vadd.i32     q2, q2, {four}",
            "le    lr, 2b",
            m = in(reg) m as i32,
            quads = in(reg) n / 4,
            inout("r1") logits.as_ptr() => _,
            // `VIDUP` starts from an even register; the sums' accumulators must be even too.
            inout("r4") 0u32 => _,
            inout("r0") 0u32 => s,
            inout("r2") 0u32 => t,
            ex = in(reg) exp.as_ptr(),
            four = in(reg) 4u32,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
            out("d8") _, out("d9") _,
            options(nostack, readonly),
        );
    }
    Some((s, t))
}

/// The int8 line fill of the forward line engine with Helium (`kernels::line::conv_s8`):
/// for each tap `t < at.len()` and channel `i < channels`, `dst[t·channels + i + j·vp] =
/// row[j]` for `j < len`, where `row` is `input[at[t] + i·cs ..]`, or `pad` (the input's
/// zero point, `len` bytes of it) where `at[t]` is `usize::MAX` (a tap outside the input).
/// The line holds the raw int8 inputs, entry `v = (tap, channel)` of column `j` at byte
/// `j·vp + v`; the offset is folded into the biases, so a padding entry holds the zero point
/// and adds nothing. Eight columns per pass: byte loads widened to 16-bit lanes and a
/// scatter store with 16-bit byte offsets; for an even channel count two channels of one tap
/// at once (`VSLI` pairs their bytes into halfwords: 6 instructions per 16 entries), else
/// one (4 per 8). Tail-predicated (`DLSTP.16`), so any `len` from 1 to 256. Returns false,
/// writing nothing, when a row or `dst` is too short, or for a shape outside those bounds.
pub fn fill_bytes(
    dst: &mut [u8],
    vp: usize,
    len: usize,
    (input, at): (&[i8], &[usize]),
    (channels, cs): (usize, usize),
    pad: &[i8],
) -> bool {
    if !fill_bytes_fits(
        dst.len(),
        (vp, len),
        (input.len(), at),
        (channels, cs),
        pad.len(),
    ) {
        return false;
    }
    let passes = 8 * len.div_ceil(8) as i32;
    let pairs = channels / 2;
    for (t, &a) in at.iter().enumerate() {
        let (row, step) = if a == usize::MAX {
            (pad.as_ptr(), 0)
        } else {
            (input.as_ptr().wrapping_add(a), cs)
        };
        let dk = dst.as_mut_ptr().wrapping_add(t * channels);
        if channels.is_multiple_of(2) {
            // SAFETY (checked above): pair k of tap t reads len bytes from row + 2k·step and
            // row + (2k + 1)·step (within input, or the pad row with step 0), and writes
            // the halfwords dst[t·channels + 2k + j·vp ..][..2] for j < len, within dst
            // (t·channels + 2k + 1 < at.len()·channels ≤ vp). The halfword stores are
            // aligned: dst is the word-aligned line at an even offset (vp is even, as is
            // the channel count here). `DLSTP.16` with len elements stops the loads at len
            // bytes and the stores at len columns, after ceil(len / 8) passes, after which
            // the first row's pointer moves on to the next pair's.
            #[allow(unsafe_code)]
            unsafe {
                core::arch::asm!(
                    // Scatter offsets in bytes: [0, 1, …, 7] · vp.
                    "vidup.u16    q2, r2, #1",
                    "vmul.i16     q2, q2, {vp}",
                    "2:",
                    "add   r3, r1, {cs}",
                    "mov   {dp}, {dk}",
                    "dlstp.16     lr, {len}",
                    "3:",
                    "vldrb.u16    q0, [r1], #8",
                    "vldrb.u16    q1, [r3], #8",
                    "vsli.16      q0, q1, #8",
                    "vstrh.16     q0, [{dp}, q2]",
                    "add   {dp}, {dp}, {sb}",
                    "letp  lr, 3b",
                    "add   r1, r1, {adv}",
                    "add   {dk}, {dk}, #2",
                    "subs  r0, r0, #1",
                    "bne   2b",
                    inout("r0") pairs => _,
                    // The widening byte loads take only low registers as their base; `VIDUP`
                    // takes its start in an even register.
                    inout("r1") row => _,
                    inout("r2") 0u32 => _,
                    out("r3") _,
                    dk = inout(reg) dk => _,
                    dp = out(reg) _,
                    vp = in(reg) vp,
                    sb = in(reg) 8 * vp,
                    len = in(reg) len,
                    cs = in(reg) step,
                    adv = in(reg) (2 * step as i32).wrapping_sub(passes),
                    out("lr") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _,
                    options(nostack),
                );
            }
        } else {
            // SAFETY (checked above): channel i of tap t reads len bytes from row + i·step
            // (within input, or the pad row with step 0) and writes the bytes
            // dst[t·channels + i + j·vp] for j < len, within dst; `DLSTP.16` as above, after
            // which the row pointer moves on to the next channel's.
            #[allow(unsafe_code)]
            unsafe {
                core::arch::asm!(
                    "vidup.u16    q2, r2, #1",
                    "vmul.i16     q2, q2, {vp}",
                    "2:",
                    "mov   {dp}, {dk}",
                    "dlstp.16     lr, {len}",
                    "3:",
                    "vldrb.u16    q0, [r1], #8",
                    "vstrb.16     q0, [{dp}, q2]",
                    "add   {dp}, {dp}, {sb}",
                    "letp  lr, 3b",
                    "add   r1, r1, {adv}",
                    "add   {dk}, {dk}, #1",
                    "subs  r0, r0, #1",
                    "bne   2b",
                    inout("r0") channels => _,
                    inout("r1") row => _,
                    inout("r2") 0u32 => _,
                    dk = inout(reg) dk => _,
                    dp = out(reg) _,
                    vp = in(reg) vp,
                    sb = in(reg) 8 * vp,
                    len = in(reg) len,
                    adv = in(reg) (step as i32).wrapping_sub(passes),
                    out("lr") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                    out("d4") _, out("d5") _,
                    options(nostack),
                );
            }
        }
    }
    true
}

/// The checks of [`fill_bytes`]: 1 to 256 columns, a pad row as long, every tap's rows within
/// the input, `at.len()·channels ≤ vp ≤ 4096` entries and every column's within the line.
#[inline(always)]
fn fill_bytes_fits(
    dst_len: usize,
    (vp, len): (usize, usize),
    (input_len, at): (usize, &[usize]),
    (channels, cs): (usize, usize),
    pad_len: usize,
) -> bool {
    let entries = at.len().checked_mul(channels);
    channels > 0
        && len > 0
        && len <= 256
        && pad_len >= len
        && entries.is_some_and(|n| n <= vp)
        && vp <= 4096
        && rows_within(input_len, at, (channels, cs), len)
        && columns_within(dst_len, len, vp, entries)
        && cs <= i32::MAX as usize / 2
}

/// Most entries of one [`gather_bytes`] call.
pub const GATHER_ENTRIES: usize = 32;

/// The head's int8 column gather with Helium (`kernels::head_s8`'s int8 line): for each
/// entry `k < at.len()`, `dst[k + y·dstride] = input[at[k] + y·sstride]` for `y < rows`, or
/// `pad` where `at[k]` is `usize::MAX` (a plane or column outside the input). Eight rows per
/// pass: a byte gather widened to 16-bit lanes (`VLDRB.U16` with 16-bit byte offsets) and a
/// byte scatter store (`VSTRB.16`): 5 instructions per eight rows of an entry, about 6 per
/// entry around them, every entry in one call (the i16 gather's `pack_strided` took 10 per
/// four words of two channels and a call per word column). Tail-predicated (`DLSTP.16`), so
/// any `rows` from 1 on. Returns false, writing nothing, for no rows, more than
/// [`GATHER_ENTRIES`] entries, seven strides past 16-bit offsets, or a row or `dst` too short.
pub fn gather_bytes(
    dst: &mut [u8],
    (dstride, rows): (usize, usize),
    (input, at): (&[i8], &[usize]),
    sstride: usize,
    pad: i8,
) -> bool {
    let Some(last) = rows.checked_sub(1) else {
        return false;
    };
    let fits = at.len() <= GATHER_ENTRIES
        && !at.is_empty()
        && sstride
            .checked_mul(7)
            .is_some_and(|s| s <= u16::MAX as usize)
        && dstride
            .checked_mul(7)
            .is_some_and(|s| s <= u16::MAX as usize)
        && last
            .checked_mul(sstride)
            .and_then(|s| s.checked_add(1))
            .is_some_and(|span| rows_within(input.len(), at, (1, 0), span))
        && columns_within(dst.len(), rows, dstride, Some(at.len()));
    if !fits {
        return false;
    }
    // The gather offsets [0, 1, …, 7] · sstride, the scatter offsets · dstride and the pad in
    // every lane (16-bit lanes, two to a word), then each entry's first byte as an address,
    // 0 for the pad (`rows_within` kept the others in `input`, whose addresses are not 0).
    let lane = |i: usize| match i / 8 {
        0 => (i % 8) * sstride,
        1 => (i % 8) * dstride,
        _ => pad as u8 as usize,
    } as u32;
    let mut state = [0u32; 12 + GATHER_ENTRIES];
    for (i, w) in state.iter_mut().take(12).enumerate() {
        *w = lane(2 * i) | lane(2 * i + 1) << 16;
    }
    for (r, &a) in state[12..].iter_mut().zip(at) {
        if a != usize::MAX {
            *r = input.as_ptr().wrapping_add(a) as u32;
        }
    }
    // SAFETY (checked above): entry k reads input[at[k] + y·sstride] for y < rows (within
    // input: at[k] + last·sstride < input.len()), or nothing (the pad); it writes
    // dst[k + y·dstride] for y < rows, within dst (k < at.len(), (rows − 1)·dstride +
    // at.len() ≤ dst.len()). `DLSTP.16` with `rows` elements runs ceil(rows / 8) passes of
    // eight lanes, the last one predicated to what is left, so the gathers and scatters stop
    // at `rows`; the offsets fit 16-bit lanes (7·stride ≤ 65535). `state` is a live local array (the
    // lanes, then at.len() ≥ 1 addresses).
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "vldrh.u16    q1, [{st}]",
            "vldrh.u16    q2, [{st}, #16]",
            "vldrh.u16    q3, [{st}, #32]",
            "add   {st}, {st}, #48",
            "2:",
            "ldr   {src}, [{st}], #4",
            "mov   {dp}, {dk}",
            "dlstp.16     lr, {rows}",
            "cmp   {src}, #0",
            "beq   4f",
            "3:",
            "vldrb.u16    q0, [{src}, q1]",
            "vstrb.16     q0, [{dp}, q2]",
            "add   {src}, {src}, {sb}",
            "add   {dp}, {dp}, {db}",
            "letp  lr, 3b",
            "b     5f",
            "4:",
            "vstrb.16     q3, [{dp}, q2]",
            "add   {dp}, {dp}, {db}",
            "letp  lr, 4b",
            "5:",
            "add   {dk}, {dk}, #1",
            "subs  {n}, {n}, #1",
            "bne   2b",
            st = inout(reg) state.as_ptr() => _,
            n = inout(reg) at.len() => _,
            dk = inout(reg) dst.as_mut_ptr() => _,
            src = out(reg) _,
            dp = out(reg) _,
            rows = in(reg) rows,
            sb = in(reg) 8 * sstride,
            db = in(reg) 8 * dstride,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
            options(nostack),
        );
    }
    true
}

/// The int8 twin of [`PairRows`] (`kernels::line::conv_s8`): pairs of positions `step`
/// bytes apart, each a dot product of `n` int8 line bytes with two channels' int8 weights,
/// `VMLADAVA.S8` adding 16 products at a time: 64 MACs in 9 instructions, the last
/// `n mod 16` bytes by tail predication. A channel pair's weights are 16-byte blocks, the
/// first channel's block then the second's (`32 · ceil(n / 16)` bytes, zero past `n`). The
/// accumulators of one channel are one word apart; the loop around the pairs is
/// [`PairRows::run_channels`]'s, its state in registers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PairRowsS8 {
    step: usize,
    n: usize,
    pairs: usize,
    x_len: usize,
    w_len: usize,
}

impl PairRowsS8 {
    /// The shape of `pairs ≥ 1` pairs of positions, `n ≥ 1` bytes each; `None` for any
    /// other shape or one whose extent overflows.
    pub fn new(step: usize, n: usize, pairs: usize) -> Option<Self> {
        if pairs == 0 || n == 0 || pairs > usize::MAX / 4 || step > i32::MAX as usize / 4 {
            return None;
        }
        let blocks = n.div_ceil(16);
        Some(PairRowsS8 {
            step,
            n,
            pairs,
            x_len: (2 * pairs - 1).checked_mul(step)?.checked_add(n)?,
            w_len: blocks.checked_mul(32)?,
        })
    }

    /// Weight bytes of one channel pair.
    pub fn pair_bytes(&self) -> usize {
        self.w_len
    }

    /// For every channel pair `k < bias.len()`: positions `q = 2p`, `q + 1` (`p < pairs`)
    /// get `acc[2k·rstride + first + q] = bias[k][0] + x_q·w_{2k}` and the same in row
    /// `2k + 1` with `bias[k][1]` and `w_{2k+1}`, where `x_q = x[q·step ..][..n]` and the
    /// pair's weights start at `w[k·wstride]`. Returns false, doing nothing, for a slice too
    /// short for every pair.
    pub fn run_channels(
        &self,
        x: &[u8],
        (w, wstride): (&[u8], usize),
        bias: &[[i32; 2]],
        acc: &mut [i32],
        (rstride, first): (usize, usize),
    ) -> bool {
        let Some(last) = bias.len().checked_sub(1) else {
            return true;
        };
        let fits = x.len() >= self.x_len
            && wstride <= i32::MAX as usize
            && rstride <= usize::MAX / 8
            && last
                .checked_mul(wstride)
                .and_then(|a| a.checked_add(self.w_len))
                .is_some_and(|e| e <= w.len())
            && (2 * last + 1)
                .checked_mul(rstride)
                .and_then(|a| a.checked_add(first))
                .and_then(|a| a.checked_add(2 * self.pairs))
                .is_some_and(|e| e <= acc.len());
        if !fits {
            return false;
        }
        let [b0, b1] = bias[0];
        let a0 = acc.as_mut_ptr().wrapping_add(first);
        let blocks = self.w_len / 32;
        // The loop's state (words), as PairRows::pairs_in_registers keeps it: biases, the
        // bytes of a dot product, weight bytes per pair, the advance from a pair's end to the
        // next pair's start, channel pairs left, the x pointers' start, the weight step, the
        // first row's start, the row step, the next pair's biases, position pairs.
        let mut st = [
            b0 as u32,
            b1 as u32,
            self.n as u32,
            self.w_len as u32,
            (2 * self.step).wrapping_sub(16 * blocks) as u32,
            bias.len() as u32,
            x.as_ptr() as u32,
            x.as_ptr().wrapping_add(self.step) as u32,
            wstride as u32,
            a0 as u32,
            (rstride * 4) as u32,
            bias.as_ptr().wrapping_add(1) as u32,
            self.pairs as u32,
        ];
        // SAFETY: pair p of channel pair k reads x[2p·step ..][..n] and x[(2p + 1)·step ..]
        // [..n] (the tail predication of `DLSTP.8` with n elements stops the loads at n
        // bytes; within x_len ≤ x.len()), the weights w[k·wstride ..][..32·blocks] (within w,
        // checked above) and stores acc[(2k)·rstride + first + 2p ..][..2] and the same in
        // row 2k + 1 (within acc, checked above). After a pair the x pointers have moved
        // 16·blocks bytes and the weight pointer 32·blocks, undone by the state's advance
        // and step back; a next channel pair starts again from the saved x pointers, its
        // weights wstride bytes on, its rows 2·rstride words on and its biases from the next
        // entry of `bias` (the count in `st` stops the loop after bias.len() pairs). `st` is
        // a live local array of 13 words.
        #[allow(unsafe_code)]
        unsafe {
            let regs = (
                st.as_mut_ptr(),
                x.as_ptr(),
                x.as_ptr().add(self.step),
                w.as_ptr(),
                a0,
                a0.add(rstride),
                self.pairs,
                b0,
                b1,
            );
            pair_loop!(
                regs,
                ["dlstp.8      lr, lr"],
                [S8_BLOCK],
                "letp  lr, 3b",
                ["strd  r0, r2, [{a0}], #8", "strd  r4, r8, [{a1}], #8"]
            );
        }
        true
    }
}

impl PairRowsS8 {
    /// [`PairRowsS8::run_channels`] for one channel pair (biases `bias`, accumulator rows at
    /// `acc[0 ..]` and `acc[rstride ..]`) of a window of 17 to 32 bytes, two 16-byte
    /// blocks: the pair's four weight blocks stay in q2–q5 for every pair of positions, 20
    /// instructions a pair (the inner loop's 33). Each position reads 32 bytes (the weights
    /// past `n` are zero): `x` must hold them. Returns false, doing nothing, for another
    /// window or a slice too short.
    pub fn run_pair_short(
        &self,
        x: &[u8],
        w: &[u8],
        bias: [i32; 2],
        (acc, rstride): (&mut [i32], usize),
    ) -> bool {
        let x_len = (2 * self.pairs - 1)
            .checked_mul(self.step)
            .and_then(|a| a.checked_add(32));
        let fits = self.n > 16
            && self.w_len == 64
            && w.len() >= 64
            && self.step <= i32::MAX as usize / 4
            && x_len.is_some_and(|e| e <= x.len())
            && rstride <= usize::MAX / 8
            && rstride
                .checked_add(2 * self.pairs)
                .is_some_and(|e| e <= acc.len());
        if !fits {
            return false;
        }
        // The biases, the weights' address and the second row's offset in bytes.
        let st = [
            bias[0] as u32,
            bias[1] as u32,
            w.as_ptr() as u32,
            (rstride * 4) as u32,
        ];
        // SAFETY (checked above): pair p reads x[2p·step ..][..32] and x[(2p + 1)·step ..]
        // [..32] (within x_len ≤ x.len()) and w[..64], and stores acc[2p ..][..2] and
        // acc[rstride + 2p ..][..2] (within acc). pairs ≥ 1 (`new`), so `DLS`/`LE` run the
        // loop exactly pairs times. `st` is a live local array of 4 words.
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "ldr   {a1}, [{st}, #8]",
                "vldrb.u8     q2, [{a1}]",
                "vldrb.u8     q3, [{a1}, #16]",
                "vldrb.u8     q4, [{a1}, #32]",
                "vldrb.u8     q5, [{a1}, #48]",
                "ldr   {a1}, [{st}, #12]",
                "add   {a1}, {a0}, {a1}",
                "add   {x1}, {x0}, {adv}, lsr #1",
                "dls   lr, lr",
                "2:",
                "ldrd  r0, r4, [{st}]",
                "mov   r2, r0",
                "mov   r8, r4",
                "vldrb.u8     q0, [{x0}]",
                "vldrb.u8     q1, [{x0}, #16]",
                "vldrb.u8     q6, [{x1}]",
                "vldrb.u8     q7, [{x1}, #16]",
                "add   {x0}, {x0}, {adv}",
                "add   {x1}, {x1}, {adv}",
                "vmladava.s8  r0, q0, q2",
                "vmladava.s8  r0, q1, q4",
                "vmladava.s8  r2, q6, q2",
                "vmladava.s8  r2, q7, q4",
                "vmladava.s8  r4, q0, q3",
                "vmladava.s8  r4, q1, q5",
                "vmladava.s8  r8, q6, q3",
                "vmladava.s8  r8, q7, q5",
                "strd  r0, r2, [{a0}], #8",
                "strd  r4, r8, [{a1}], #8",
                "le    lr, 2b",
                st = in(reg) st.as_ptr(),
                x0 = inout(reg) x.as_ptr() => _,
                x1 = out(reg) _,
                adv = in(reg) 2 * self.step,
                a0 = inout(reg) acc.as_mut_ptr() => _,
                a1 = out(reg) _,
                inout("lr") self.pairs => _,
                out("r0") _, out("r2") _, out("r4") _, out("r8") _,
                out("d0") _, out("d1") _, out("d2") _, out("d3") _,
                out("d4") _, out("d5") _, out("d6") _, out("d7") _,
                out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                out("d12") _, out("d13") _, out("d14") _, out("d15") _,
                options(nostack),
            );
        }
        true
    }
}

/// The operations `arch` takes from this backend in the uniform form of its table (what each
/// computes: the `arch` function of the same name): the prefix done here and the rest left to
/// the portable loops, or the whole call declined.
pub mod ops {
    use super::{dot2x2_row_pairs, requant_max_row_quads, requant_rows_quads, PairRows};

    /// `arch::dot2x2`: every shape (the last pair of words or word by `SMLAD`).
    #[inline(always)]
    pub fn dot2x2(x: &[u32], step: usize, w: &[u32], n: usize, acc: [i32; 4]) -> Option<[i32; 4]> {
        Some(super::dot2x2(x, step, w, n, acc))
    }

    /// A row plan's pair loop, shape checked once: an even number of positions and of words.
    pub type Pairs = Option<PairRows>;

    /// The pair loop of rows of `positions` dot products of `n` words, where it applies.
    #[inline(always)]
    pub fn pairs(step: usize, positions: usize, n: usize, astep: usize) -> Pairs {
        // The pair loop checks exactly the slices `dot2x2_row_checked` checks (and refuses
        // what they refuse), so where it applies it runs alone.
        if positions.is_multiple_of(2) && n.is_multiple_of(2) {
            PairRows::new(step, n, positions / 2, astep)
        } else {
            None
        }
    }

    /// One row of a plan: `PairRows::run`, or `None` without a pair loop.
    #[inline(always)]
    pub fn run_pairs(
        pairs: &Pairs,
        x: &[u32],
        w: &[u32],
        bias: [i32; 2],
        (acc0, acc1): (&mut [i32], &mut [i32]),
    ) -> Option<bool> {
        pairs.as_ref().map(|p| p.run(x, w, bias, (acc0, acc1)))
    }

    /// Every channel pair of a line in one call when the pair loop keeps its state in
    /// registers (`PairRows::run_channels`); `None` otherwise (the caller goes pair by pair).
    #[inline(always)]
    pub fn run_channel_pairs(
        pairs: &Pairs,
        x: &[u32],
        (w, wstride): (&[u32], usize),
        bias: &[[i32; 2]],
        acc: &mut [i32],
        (rstride, first): (usize, usize),
    ) -> Option<bool> {
        let p = pairs.filter(|p| p.in_registers())?;
        Some(p.run_channels(x, (w, wstride), bias, acc, (rstride, first)))
    }

    /// The pairs of positions of a checked row (`arch::dot2x2_row`) for an even `n ≥ 4`
    /// and at least one pair; an odd last position is the caller's.
    #[inline(always)]
    pub fn row_pairs(
        x: &[u32],
        (step, positions, n): (usize, usize, usize),
        w: &[u32],
        bias: [i32; 2],
        (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
    ) -> bool {
        n.is_multiple_of(2)
            && n >= 4
            && positions >= 2
            && dot2x2_row_pairs(x, (step, n), positions / 2, w, bias, (acc0, acc1, astep))
    }

    /// The blocks of four values of `arch::requant_max_row` (shifts below 32); the values
    /// done and the maximum.
    #[inline(always)]
    pub fn requant_max_row(
        acc: &[i32],
        out: &mut [i8],
        rq: (i32, u32, u32, i32, i32),
        relu: bool,
        max: i8,
    ) -> (usize, i8) {
        let quads = acc.len().min(out.len()) / 4;
        if rq.1 < 32 && rq.2 < 32 && quads > 0 {
            (
                4 * quads,
                requant_max_row_quads(acc, out, rq, relu, max, quads),
            )
        } else {
            (0, max)
        }
    }

    /// The blocks of four values of `arch::requant_row_s8` (shifts below 32): one row of the
    /// whole-line loop. The values done.
    #[inline(always)]
    pub fn requant_row(
        acc: &[i32],
        out: &mut [i8],
        (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
        relu: bool,
        skip: Option<&[i32; 256]>,
    ) -> usize {
        let quads = acc.len().min(out.len()) / 4;
        if left1 < 32 && right < 32 && quads > 0 {
            let words = [[multiplier, left1 as i32, right as i32, half, neg]];
            if requant_rows_quads(acc, out, &words, (quads, 0), relu, skip) {
                return 4 * quads;
            }
        }
        0
    }

    /// `arch::requant_rows_s8` in one call for a width that is a positive multiple of 4.
    #[inline(always)]
    pub fn requant_rows(
        acc: &[i32],
        out: &mut [i8],
        params: &[[i32; 5]],
        (width, plane): (usize, usize),
        relu: bool,
        skip: Option<&[i32; 256]>,
    ) -> bool {
        width.is_multiple_of(4)
            && width > 0
            && requant_rows_quads(acc, out, params, (width / 4, plane), relu, skip)
    }

    /// The blocks of four words of `arch::pack_strided` by gathers; the words done.
    #[inline(always)]
    pub fn pack_strided_quads(
        dst: &mut [u32],
        dstride: usize,
        (a, b, sstride): (&[i8], &[i8], usize),
        count: usize,
        (oa, ob): (i16, i16),
    ) -> usize {
        let quads = count / 4;
        if quads > 0 {
            super::pack_strided_quads(dst, dstride, (a, b, sstride), quads, (oa, ob));
        }
        4 * quads
    }
}
