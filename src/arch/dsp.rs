//! The ARMv7E-M DSP backend (Cortex-M4/M7, and the DSP loops a Cortex-M55 keeps where it has
//! no Helium one): short hand-scheduled `SMLAD` / `SXTB16` / `SMMULR` loops through
//! `core::arch::asm!`. Each function computes what the `arch` function of the same name
//! computes, for the shapes it takes, and declines the rest (`None`, `false`, or 0 values
//! done), leaving them to the portable loops; it checks every slice its assembly reads or
//! writes itself, so that it is sound on its own. `arch` chooses when it runs; this module
//! imports only the shared pieces (`super::insn`, `super::rows`), never the Helium backend.

// With Helium the table takes some operations from `mve` instead: these stay unused there.
#![cfg_attr(feature = "mve", allow(dead_code))]

use super::insn::pack;
use super::rows::{column_fits, row_fits, tap_fits, Combine, LineRows};

/// Two channels × two positions over an even number `n` of words (`arch::dot2x2`), the
/// loop unrolled twice; `None` for an odd `n` or slices too short. LLVM spills the 4
/// accumulators of the Rust version to the stack (12 live registers are needed, exactly what
/// Thumb-2 leaves to inline assembly), which costs about 2 instructions per MAC instead of 1.
#[inline(always)]
pub fn dot2x2(x: &[u32], step: usize, w: &[u32], n: usize, acc: [i32; 4]) -> Option<[i32; 4]> {
    let (Some(xe), Some(we)) = (step.checked_add(n), n.checked_mul(2)) else {
        return None;
    };
    if x.len() < xe || x.len() < n || w.len() < we || !n.is_multiple_of(2) {
        return None;
    }
    if n == 0 {
        return Some(acc);
    }
    let [mut a00, mut a01, mut a10, mut a11] = acc;
    let mut xp = x.as_ptr();
    let mut wp = w.as_ptr();
    // SAFETY: the loop reads x[0..n], x[step..step + n] and w[0..2n], all checked above;
    // n is even and non-zero, so the two-words-per-iteration loop ends exactly at `end`.
    #[allow(unsafe_code)]
    unsafe {
        let end = xp.add(n);
        core::arch::asm!(
            "2:",
            "ldr   {xa}, [{xp}, {sb}]",
            "ldr   {xb}, [{xp}], #4",
            "ldrd  {wa}, {wb}, [{wp}], #8",
            "smlad {a00}, {xb}, {wa}, {a00}",
            "smlad {a01}, {xa}, {wa}, {a01}",
            "smlad {a10}, {xb}, {wb}, {a10}",
            "smlad {a11}, {xa}, {wb}, {a11}",
            "ldr   {xa}, [{xp}, {sb}]",
            "ldr   {xb}, [{xp}], #4",
            "ldrd  {wa}, {wb}, [{wp}], #8",
            "smlad {a00}, {xb}, {wa}, {a00}",
            "smlad {a01}, {xa}, {wa}, {a01}",
            "smlad {a10}, {xb}, {wb}, {a10}",
            "smlad {a11}, {xa}, {wb}, {a11}",
            "cmp   {xp}, {end}",
            "bne   2b",
            xp = inout(reg) xp,
            wp = inout(reg) wp,
            sb = in(reg) step * 4,
            end = in(reg) end,
            a00 = inout(reg) a00,
            a01 = inout(reg) a01,
            a10 = inout(reg) a10,
            a11 = inout(reg) a11,
            xa = out(reg) _,
            xb = out(reg) _,
            wa = out(reg) _,
            wb = out(reg) _,
            options(nostack, readonly),
        );
    }
    let _ = (xp, wp);
    Some([a00, a01, a10, a11])
}

/// The pairs of positions of a row of `arch::dot2x2_row` (positions `2p`, `2p + 1` for
/// `p < positions / 2`; an odd last one is the caller's) for an even `n > 0`: the pair loop
/// in assembly too, its state read back from memory after each dot product. False, writing
/// nothing, for an odd or zero `n` or a row that does not fit its slices.
#[inline(always)]
pub fn row_pairs(
    x: &[u32],
    (step, positions, n): (usize, usize, usize),
    w: &[u32],
    bias: [i32; 2],
    (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
) -> bool {
    let shape = (x.len(), step, positions, n);
    if !(n.is_multiple_of(2) && n > 0 && row_fits(shape, w.len(), (acc0.len(), acc1.len(), astep)))
    {
        return false;
    }
    let pairs = positions / 2;
    if pairs > 0 {
        // The pair loop's state, read back after each dot product (the inner loop needs
        // all 12 allocatable registers): accumulator pointers, accumulator step (bytes),
        // biases, weights, the advance from one pair's end to the next pair's start,
        // the bytes of one dot product, pairs left.
        let mut st = [
            acc0.as_mut_ptr() as u32,
            acc1.as_mut_ptr() as u32,
            (astep * 4) as u32,
            bias[0] as u32,
            bias[1] as u32,
            w.as_ptr() as u32,
            (2 * step * 4).wrapping_sub(n * 4) as u32,
            (n * 4) as u32,
            pairs as u32,
        ];
        // SAFETY (last = positions − 1, row_fits checked above): pair p covers positions
        // q = 2p and q + 1 ≤ last: they start at
        // x[q·step] and x[(q + 1)·step] and read n words each, and
        // (q + 1)·step + n ≤ last·step + n ≤ x.len() (checked above); every dot product
        // reads 2n words of w (checked above); n is even and non-zero, so the
        // two-words-per-iteration loop ends exactly at `end`. The stores go to
        // acc[q·astep] and acc[(q + 1)·astep] with (q + 1)·astep ≤ last·astep, in
        // bounds of both accumulator slices (checked above). `st` is a live local
        // array of 9 words; the asm keeps its address in an 8-byte stack slot that it
        // pushes first and pops last.
        #[allow(unsafe_code)]
        unsafe {
            let xp = x.as_ptr();
            core::arch::asm!(
                "str   {xa}, [sp, #-8]!",
                "2:",
                "ldr   {xa}, [{xp}, {sb}]",
                "ldr   {xb}, [{xp}], #4",
                "ldrd  {wa}, {wb}, [{wp}], #8",
                "smlad {a00}, {xb}, {wa}, {a00}",
                "smlad {a01}, {xa}, {wa}, {a01}",
                "smlad {a10}, {xb}, {wb}, {a10}",
                "smlad {a11}, {xa}, {wb}, {a11}",
                "ldr   {xa}, [{xp}, {sb}]",
                "ldr   {xb}, [{xp}], #4",
                "ldrd  {wa}, {wb}, [{wp}], #8",
                "smlad {a00}, {xb}, {wa}, {a00}",
                "smlad {a01}, {xa}, {wa}, {a01}",
                "smlad {a10}, {xb}, {wb}, {a10}",
                "smlad {a11}, {xa}, {wb}, {a11}",
                "cmp   {xp}, {end}",
                "bne   2b",
                "ldr   {xa}, [sp]",
                "ldrd  {wa}, {wb}, [{xa}]",
                "str   {a00}, [{wa}]",
                "str   {a10}, [{wb}]",
                "ldr   {xb}, [{xa}, #8]",
                "str   {a01}, [{wa}, {xb}]",
                "str   {a11}, [{wb}, {xb}]",
                "add   {wa}, {wa}, {xb}, lsl #1",
                "add   {wb}, {wb}, {xb}, lsl #1",
                "strd  {wa}, {wb}, [{xa}]",
                "ldrd  {a00}, {a10}, [{xa}, #12]",
                "mov   {a01}, {a00}",
                "mov   {a11}, {a10}",
                "ldr   {wp}, [{xa}, #20]",
                "ldrd  {wa}, {wb}, [{xa}, #24]",
                "add   {xp}, {xp}, {wa}",
                "add   {end}, {xp}, {wb}",
                "ldr   {wa}, [{xa}, #32]",
                "subs  {wa}, {wa}, #1",
                "str   {wa}, [{xa}, #32]",
                "bne   2b",
                "add   sp, sp, #8",
                xp = inout(reg) xp => _,
                wp = inout(reg) w.as_ptr() => _,
                sb = in(reg) step * 4,
                end = inout(reg) xp.add(n) => _,
                a00 = inout(reg) bias[0] => _,
                a01 = inout(reg) bias[0] => _,
                a10 = inout(reg) bias[1] => _,
                a11 = inout(reg) bias[1] => _,
                xa = inout(reg) st.as_mut_ptr() => _,
                xb = out(reg) _,
                wa = out(reg) _,
                wb = out(reg) _,
            );
        }
    }
    true
}

/// `arch::requant_max_row` in one loop, 14 instructions per value (the Rust loop takes 24:
/// LLVM spills and sign-extends around two compare-and-move clamps). Returns the values done
/// (all, or none for a shift of 32 or more) and the maximum.
#[inline(always)]
pub fn requant_max_row(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    max: i8,
) -> (usize, i8) {
    let len = acc.len().min(out.len());
    if !(len > 0 && left1 < 32 && right < 32) {
        return (0, max);
    }
    let mut mx = max as i32;
    // SAFETY: reads acc[..len] and writes out[..len], both in bounds (len is the smaller
    // length, > 0); the loop ends exactly at acc[len]. Shifts by registers < 32.
    #[allow(unsafe_code)]
    unsafe {
        let ap = acc.as_ptr();
        let end = ap.add(len);
        macro_rules! row {
            ($sat:literal) => {
                core::arch::asm!(
                    "2:",
                    "ldr    {t}, [{ap}], #4",
                    "lsl    {t}, {t}, {l1}",
                    "smmulr {t}, {t}, {m}",
                    "and    {u}, {neg}, {t}, asr #31",
                    "add    {t}, {t}, {half}",
                    "add    {t}, {t}, {u}",
                    "asr    {t}, {t}, {r}",
                    $sat,
                    "strb   {t}, [{op}], #1",
                    "cmp    {t}, {mx}",
                    "it     gt",
                    "movgt  {mx}, {t}",
                    "cmp    {ap}, {end}",
                    "bne    2b",
                    ap = inout(reg) ap => _,
                    op = inout(reg) out.as_mut_ptr() => _,
                    end = in(reg) end,
                    l1 = in(reg) left1,
                    m = in(reg) multiplier,
                    neg = in(reg) neg,
                    half = in(reg) half,
                    r = in(reg) right,
                    mx = inout(reg) mx,
                    t = out(reg) _,
                    u = out(reg) _,
                    options(nostack),
                )
            };
        }
        if relu {
            row!("usat   {t}, #7, {t}");
        } else {
            row!("ssat   {t}, #8, {t}");
        }
    }
    (len, mx as i8)
}

/// `arch::requant_row_s8` in one loop: 11 instructions per value (15 with the skip; `QADD` is
/// the saturating add, `BIC … ASR #31` the ReLU), against 13–19 for the Rust loop. Returns the
/// values done (all, or none for a shift of 32 or more).
#[inline(always)]
pub fn requant_row(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    skip: Option<&[i32; 256]>,
) -> usize {
    let len = acc.len().min(out.len());
    if !(len > 0 && left1 < 32 && right < 32) {
        return 0;
    }
    // SAFETY: reads acc[..len], reads and writes out[..len] (len is the smaller length,
    // > 0; the loop ends exactly at acc[len]); the skip table is read at an unsigned
    // byte index < 256. Shifts by registers < 32.
    #[allow(unsafe_code)]
    unsafe {
        let ap = acc.as_ptr();
        let end = ap.add(len);
        let op = out.as_mut_ptr();
        let lut = skip.map_or(core::ptr::null(), |l| l.as_ptr());
        macro_rules! row {
            ($relu:literal, $skip1:literal, $skip2:literal, $skip3:literal) => {
                core::arch::asm!(
                    "2:",
                    "ldr    {t}, [{ap}], #4",
                    "lsl    {t}, {t}, {l1}",
                    "smmulr {t}, {t}, {m}",
                    "and    {u}, {neg}, {t}, asr #31",
                    "add    {t}, {t}, {half}",
                    "add    {t}, {t}, {u}",
                    "asr    {t}, {t}, {r}",
                    $relu,
                    $skip1,
                    $skip2,
                    $skip3,
                    "ssat   {t}, #8, {t}",
                    "@ {lut}",
                    "strb   {t}, [{op}], #1",
                    "cmp    {ap}, {end}",
                    "bne    2b",
                    ap = inout(reg) ap => _,
                    op = inout(reg) op => _,
                    end = in(reg) end,
                    l1 = in(reg) left1,
                    m = in(reg) multiplier,
                    neg = in(reg) neg,
                    half = in(reg) half,
                    r = in(reg) right,
                    lut = in(reg) lut,
                    t = out(reg) _,
                    u = out(reg) _,
                    options(nostack),
                )
            };
        }
        // ReLU: `BIC t, t, t ASR #31`; the in-place skip: the old value as an unsigned
        // byte indexes the table, `QADD` adds with saturation.
        match (relu, skip.is_some()) {
            (false, false) => row!("", "", "", ""),
            (true, false) => row!("bic {t}, {t}, {t}, asr #31", "", "", ""),
            (false, true) => row!(
                "",
                "ldrb {u}, [{op}]",
                "ldr {u}, [{lut}, {u}, lsl #2]",
                "qadd {t}, {t}, {u}"
            ),
            (true, true) => row!(
                "bic {t}, {t}, {t}, asr #31",
                "ldrb {u}, [{op}]",
                "ldr {u}, [{lut}, {u}, lsl #2]",
                "qadd {t}, {t}, {u}"
            ),
        }
    }
    len
}

/// `arch::pack_strided` in one loop: 8 instructions per word without offsets (10 with),
/// against about 12.5 for the Rust loop. False, writing nothing, when a slice is too short
/// for `count ≥ 1` and the strides.
#[inline(always)]
pub fn pack_strided(
    dst: &mut [u32],
    dstride: usize,
    (a, b, sstride): (&[i8], &[i8], usize),
    count: usize,
    (oa, ob): (i16, i16),
) -> bool {
    let Some(last) = count.checked_sub(1) else {
        return false;
    };
    let fits = |len: usize, stride: usize| last.checked_mul(stride).is_some_and(|e| e < len);
    if !(fits(dst.len(), dstride) && fits(a.len(), sstride) && fits(b.len(), sstride))
        || dstride > usize::MAX / 8
    {
        return false;
    }
    // SAFETY: reads a[j·sstride] and b[j·sstride] and writes dst[j·dstride] for
    // j ≤ last, all in bounds (checked above); count ≥ 1.
    #[allow(unsafe_code)]
    unsafe {
        macro_rules! column {
            ($add_a:literal, $add_b:literal) => {
                core::arch::asm!(
                    "2:",
                    "ldrsb  {x}, [{ap}, {i}]",
                    "ldrsb  {y}, [{bp}, {i}]",
                    "add    {i}, {i}, {ss}",
                    $add_a,
                    $add_b,
                    "pkhbt  {x}, {x}, {y}, lsl #16",
                    "str    {x}, [{dp}]",
                    "add    {dp}, {dp}, {ds}",
                    "subs   {n}, {n}, #1",
                    "bne    2b",
                    "@ {oa} {ob}",
                    ap = in(reg) a.as_ptr(),
                    bp = in(reg) b.as_ptr(),
                    i = inout(reg) 0usize => _,
                    dp = inout(reg) dst.as_mut_ptr() => _,
                    n = inout(reg) count => _,
                    ss = in(reg) sstride,
                    ds = in(reg) dstride * 4,
                    oa = in(reg) oa as i32,
                    ob = in(reg) ob as i32,
                    x = out(reg) _,
                    y = out(reg) _,
                    options(nostack),
                )
            };
        }
        // Layers without an input offset (all but the first and a d1 reading an unsigned cost
        // volume): two adds fewer per word.
        if oa == 0 && ob == 0 {
            column!("", "");
        } else {
            column!("add {x}, {x}, {oa}", "add {y}, {y}, {ob}");
        }
    }
    true
}

/// `arch::exp_sums` for a non-zero multiple of 4 logits: `USUB8` forms four table indices at
/// once and `T = n·S − Σ_i S_i` (the prefix sums) replaces the multiply-accumulate, 5
/// instructions per logit instead of 7. `None` for other lengths.
#[inline(always)]
pub fn exp_sums(logits: &[i8], m: i8, exp: &[u16; 256]) -> Option<(u32, u32)> {
    if logits.is_empty() || !logits.len().is_multiple_of(4) {
        return None;
    }
    let (mut s, mut u) = (0u32, 0u32);
    // SAFETY: reads logits[..len] word by word (unaligned LDR is allowed on ARMv7-M;
    // len is a non-zero multiple of 4, so the loop ends exactly at the end) and exp at
    // byte indices < 256.
    #[allow(unsafe_code)]
    unsafe {
        let lp = logits.as_ptr();
        core::arch::asm!(
            "2:",
            "ldr    {q}, [{lp}], #4",
            "usub8  {q}, {m4}, {q}",
            "uxtb   {x}, {q}",
            "ldrh   {x}, [{ex}, {x}, lsl #1]",
            "add    {s}, {s}, {x}",
            "add    {u}, {u}, {s}",
            "uxtb   {x}, {q}, ror #8",
            "ldrh   {x}, [{ex}, {x}, lsl #1]",
            "add    {s}, {s}, {x}",
            "add    {u}, {u}, {s}",
            "uxtb   {x}, {q}, ror #16",
            "ldrh   {x}, [{ex}, {x}, lsl #1]",
            "add    {s}, {s}, {x}",
            "add    {u}, {u}, {s}",
            "lsr    {x}, {q}, #24",
            "ldrh   {x}, [{ex}, {x}, lsl #1]",
            "add    {s}, {s}, {x}",
            "add    {u}, {u}, {s}",
            "cmp    {lp}, {end}",
            "bne    2b",
            lp = inout(reg) lp => _,
            end = in(reg) lp.add(logits.len()),
            m4 = in(reg) (m as u8 as u32) * 0x0101_0101,
            ex = in(reg) exp.as_ptr(),
            s = inout(reg) s,
            u = inout(reg) u,
            q = out(reg) _,
            x = out(reg) _,
            options(nostack, readonly),
        );
    }
    let n = logits.len() as u32;
    Some((s, n.wrapping_mul(s).wrapping_sub(u)))
}

/// One column of a two-view cost-volume piece (`arch::cost_column`, `arch::mean_column`): 12
/// instructions per value (the two source values are one halfword load, `SMUAD` weighs
/// them); one audited `asm!` template, the combining instruction its only difference. False,
/// doing nothing, where those refuse or for no rows.
#[inline(always)]
pub fn table_column(
    out: &mut [i8],
    [reference, src]: [&[i8]; 2],
    (width, col, c): (usize, usize, usize),
    (wl, wr): (i16, i16),
    table: &[i8; 512],
    combine: Combine,
) -> bool {
    let n = out.len();
    if !(column_fits(&[reference.len(), src.len()], n, (width, col))
        && tap_fits((c, wl, wr), width)
        && n > 0)
    {
        return false;
    }
    // SAFETY: i runs over col, col + width, … < n: reference[i], out[i] are in bounds,
    // and src[i − col + c], src[i − col + c + 1] too (c + 1 < width, so both lie in the
    // row of i). The table index is reference ∓ w + 255 (or + 256) with reference in
    // −128..=127 and w in −128..=127 (a weighted mean of two int8 values with weights
    // summing to at most 256, rounded), so 0..=510 < 512.
    macro_rules! column_loop {
        ($combine:literal, $offset:literal) => {{
            #[allow(unsafe_code)]
            unsafe {
                core::arch::asm!(
                    "2:",
                    "ldrsb  {v}, [{rp}, {i}]",
                    "ldrh   {t}, [{sp_}, {i}]",
                    "orr    {t}, {t}, {t}, lsl #8",
                    "sxtb16 {t}, {t}",
                    "smuad  {t}, {t}, {wp}",
                    "add    {t}, {t}, #128",
                    $combine,
                    "ldrb   {t}, [{tb}, {t}]",
                    "strb   {t}, [{op}, {i}]",
                    "add    {i}, {i}, {st}",
                    "cmp    {i}, {n}",
                    "blo    2b",
                    rp = in(reg) reference.as_ptr(),
                    sp_ = in(reg) src.as_ptr().wrapping_add(c).wrapping_sub(col),
                    op = in(reg) out.as_mut_ptr(),
                    tb = in(reg) table.as_ptr().add($offset),
                    wp = in(reg) pack(wl, wr),
                    st = in(reg) width,
                    n = in(reg) n,
                    i = inout(reg) col => _,
                    v = out(reg) _,
                    t = out(reg) _,
                    options(nostack),
                )
            };
        }};
    }
    match combine {
        Combine::Difference => column_loop!("sub    {t}, {v}, {t}, asr #8", 255),
        Combine::Sum => column_loop!("add    {t}, {v}, {t}, asr #8", 256),
    }
    true
}

/// One column of a three-view cost-volume piece (`arch::cost_column3`), 33 instructions per
/// value (the portable loop: about 55); `right` and `half` the requantisation's shift and
/// rounding half. False, doing nothing, where that refuses or for no rows.
#[inline(always)]
pub fn cost_column3(
    out: &mut [i8],
    reference: &[i8],
    sources: [&[i8]; 2],
    (width, col): (usize, usize),
    taps: [(usize, i16, i16); 2],
    requant: crate::requant::Requant,
    (right, half): (u32, i32),
) -> bool {
    let n = out.len();
    let lens = [reference.len(), sources[0].len(), sources[1].len()];
    if !(column_fits(&lens, n, (width, col))
        && taps.iter().all(|&t| tap_fits(t, width))
        && requant.multiplier >= 0
        && n > 0)
    {
        return false;
    }
    // The loop's constants in memory: twelve registers hold the pointers, the index, the
    // packed weights and the temporaries.
    let params: [u32; 5] = [
        requant.multiplier as u32,
        half as u32,
        right,
        width as u32,
        n as u32,
    ];
    let [(c0, wl0, wr0), (c1, wl1, wr1)] = taps;
    // SAFETY: i runs over col, col + width, … < n: reference[i], out[i] are in bounds,
    // and src_s[i − col + c_s], src_s[i − col + c_s + 1] too (c_s + 1 < width, so both lie
    // in the row of i). `params` outlives the loop, which reads its five words only.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrsb  {v}, [{rp}, {i}]",
            "ldrh   {t}, [{s0}, {i}]",
            "orr    {t}, {t}, {t}, lsl #8",
            "sxtb16 {t}, {t}",
            "smuad  {t}, {t}, {w0}",
            "add    {t}, {t}, #128",
            "ldrh   {u}, [{s1}, {i}]",
            "orr    {u}, {u}, {u}, lsl #8",
            "sxtb16 {u}, {u}",
            "smuad  {u}, {u}, {w1}",
            "add    {u}, {u}, #128",
            "asr    {t}, {t}, #8",
            "asr    {u}, {u}, #8",
            "sub    {x}, {v}, {t}",
            "mul    {x}, {x}, {x}",
            "sub    {v}, {v}, {u}",
            "mla    {x}, {v}, {v}, {x}",
            "sub    {t}, {t}, {u}",
            "mla    {x}, {t}, {t}, {x}",
            "lsl    {x}, {x}, #1",
            "ldr    {t}, [{pm}]",
            "ldr    {u}, [{pm}, #4]",
            "smmlar {x}, {x}, {t}, {u}",
            "ldr    {t}, [{pm}, #8]",
            "asr    {x}, {x}, {t}",
            "usat   {x}, #8, {x}",
            "eor    {x}, {x}, #128",
            "strb   {x}, [{op}, {i}]",
            "ldr    {t}, [{pm}, #12]",
            "add    {i}, {i}, {t}",
            "ldr    {t}, [{pm}, #16]",
            "cmp    {i}, {t}",
            "blo    2b",
            rp = in(reg) reference.as_ptr(),
            s0 = in(reg) sources[0].as_ptr().wrapping_add(c0).wrapping_sub(col),
            s1 = in(reg) sources[1].as_ptr().wrapping_add(c1).wrapping_sub(col),
            op = in(reg) out.as_mut_ptr(),
            w0 = in(reg) pack(wl0, wr0),
            w1 = in(reg) pack(wl1, wr1),
            pm = in(reg) params.as_ptr(),
            i = inout(reg) col => _,
            v = out(reg) _,
            t = out(reg) _,
            u = out(reg) _,
            x = out(reg) _,
            options(nostack),
        );
    }
    true
}

/// A block routine of [`pack_rows`]: `dst[j · stride] = pack(a[j] + oa, b[j] + ob)` for `j <
/// 4 · quads` (this backend's [`pack_row_quads`], or Helium's).
pub type RowQuads = fn(&mut [u32], usize, (&[i8], &[i8]), usize, (i16, i16));

/// The four-entry blocks of `arch::pack_rows`: one word of each row per iteration,
/// `SXTB16` / `SXTB16 ROR 8` split it into even and odd bytes as i16 pairs, `SADD16` adds the
/// offsets, `PKHBT` / `PKHTB` pair the rows (5.5 instructions per entry instead of 9). Does
/// nothing unless `dst` holds index `(4 · quads − 1) · stride`, `a` and `b` hold `4 · quads`
/// entries and `stride ≤ usize::MAX / 16`.
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
    let (mut dp, mut ap, mut bp) = (dst.as_mut_ptr(), a.as_ptr(), b.as_ptr());
    let pair = |o: i16| (o as u16 as u32) | ((o as u16 as u32) << 16);
    // SAFETY: reads a[..4·quads] and b[..4·quads] (unaligned word loads, which
    // ARMv7-M allows for LDR), writes dst[j · stride] for j < 4·quads ≤ n, all in
    // bounds (checked above); quads ≥ 1. The pointers end at entry 4·quads.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "2:",
            "ldr    {x}, [{ap}], #4",
            "ldr    {y}, [{bp}], #4",
            "sxtb16 {z}, {x}",
            "sxtb16 {x}, {x}, ror #8",
            "sxtb16 {w}, {y}",
            "sxtb16 {y}, {y}, ror #8",
            "sadd16 {z}, {z}, {oa}",
            "sadd16 {x}, {x}, {oa}",
            "sadd16 {w}, {w}, {ob}",
            "sadd16 {y}, {y}, {ob}",
            "pkhbt  {t}, {z}, {w}, lsl #16",
            "str    {t}, [{dp}]",
            "pkhbt  {t}, {x}, {y}, lsl #16",
            "str    {t}, [{dp}, {sb}]",
            "pkhtb  {t}, {w}, {z}, asr #16",
            "str    {t}, [{dp}, {sb}, lsl #1]",
            "add    {dp}, {dp}, {sb}, lsl #1",
            "pkhtb  {t}, {y}, {x}, asr #16",
            "str    {t}, [{dp}, {sb}]",
            "add    {dp}, {dp}, {sb}, lsl #1",
            "subs   {n}, {n}, #1",
            "bne    2b",
            dp = inout(reg) dp,
            ap = inout(reg) ap,
            bp = inout(reg) bp,
            n = inout(reg) quads => _,
            sb = in(reg) stride * 4,
            oa = in(reg) pair(oa),
            ob = in(reg) pair(ob),
            x = out(reg) _,
            y = out(reg) _,
            z = out(reg) _,
            w = out(reg) _,
            t = out(reg) _,
            options(nostack),
        );
    }
    let _ = (dp, ap, bp);
}

/// `arch::pack_rows` for rows that fit `dst`: the blocks of four entries by `quads` (a
/// [`RowQuads`]), the last 1 to 3 entries by a 9-instruction loop (`PKHBT` packs the pair; the
/// Rust version costs about 20 instructions per word on Cortex-M7, iterator bookkeeping).
/// False, writing nothing, when the last entry's column is outside `dst`.
#[inline(always)]
pub fn pack_rows(
    dst: &mut [u32],
    stride: usize,
    (a, b): (&[i8], &[i8]),
    (oa, ob): (i16, i16),
    quads: RowQuads,
) -> bool {
    let n = a.len().min(b.len());
    let fits = n
        .checked_sub(1)
        .and_then(|m| m.checked_mul(stride))
        .is_some_and(|last| last < dst.len());
    if !fits || stride > usize::MAX / 16 {
        return false;
    }
    let blocks = n / 4;
    if blocks > 0 {
        quads(dst, stride, (a, b), blocks, (oa, ob));
    }
    let mut dp = dst.as_mut_ptr().wrapping_add(4 * blocks * stride);
    let mut ap = a.as_ptr().wrapping_add(4 * blocks);
    let mut bp = b.as_ptr().wrapping_add(4 * blocks);
    let mut left = n - 4 * blocks;
    if left == 0 {
        return true;
    }
    // SAFETY: writes dst[j · stride] for 4·quads ≤ j < n, the last of which is in
    // bounds (checked above); reads a[4·quads..n] and b[4·quads..n]; left ≥ 1.
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrsb {x}, [{ap}], #1",
            "ldrsb {y}, [{bp}], #1",
            "add   {x}, {x}, {oa}",
            "add   {y}, {y}, {ob}",
            "pkhbt {x}, {x}, {y}, lsl #16",
            "str   {x}, [{dp}]",
            "add   {dp}, {dp}, {sb}",
            "subs  {n}, {n}, #1",
            "bne   2b",
            dp = inout(reg) dp,
            ap = inout(reg) ap,
            bp = inout(reg) bp,
            n = inout(reg) left,
            sb = in(reg) stride * 4,
            oa = in(reg) oa as i32,
            ob = in(reg) ob as i32,
            x = out(reg) _,
            y = out(reg) _,
            options(nostack),
        );
    }
    let _ = (dp, ap, bp, left);
    true
}

/// A whole line fill (the line engine's, `kernels::line`): for each pair `k` of `rows`
/// (entries `2k`, `2k + 1`: rows `a`, `b` with offsets `oa`, `ob`), `dst[k + j · vw] =
/// pack(a[j] + oa, b[j] + ob)` for `j < need`, `need` a multiple of 4: what `arch::pack_rows`
/// does for one word, for up to 16 words in one call. The `SXTB16` loop of
/// [`pack_row_quads`] (5.5 instructions per entry) with the pair loop in assembly too (about 16
/// instructions per line word, where the Rust loop around `arch::pack_rows` spent about 100
/// choosing the rows and checking slices).
/// Returns false, doing nothing, for an odd number of rows, `need` not a positive multiple of
/// 4, or a `dst` too short.
pub fn pack_line_quads(dst: &mut [u32], vw: usize, rows: &LineRows<'_>) -> bool {
    let Some((pairs, quads)) = rows.fill_shape(dst.len(), vw) else {
        return false;
    };
    if pairs == 0 {
        return true;
    }
    // SAFETY: pair k reads rows[2k] and rows[2k + 1] (k < pairs, 2·pairs = rows.len ≤
    // CAPACITY, written; MaybeUninit<LineRow> has LineRow's layout), need bytes of each
    // from its address by unaligned word loads, which ARMv7-M allows for LDR (every row
    // holds at least need bytes, and the borrow 'a keeps them alive), and writes
    // dst[k + j·vw] for j < need (the last index, checked above, is in bounds); need / 4
    // ≥ 1 and pairs ≥ 1, so the inner loop runs need / 4 times per pair and the pair
    // loop pairs times. The asm keeps its pair loop's state in a 16-byte frame it pushes
    // and pops (the inner loop needs all twelve registers).
    #[allow(unsafe_code)]
    unsafe {
        core::arch::asm!(
            "sub    sp, sp, #16",
            "str    r0, [sp, #0]",
            "str    r1, [sp, #4]",
            "str    r2, [sp, #8]",
            "str    r3, [sp, #12]",
            "2:",
            // The pair's rows and offsets; each offset to both halfwords for SADD16.
            "ldr    r4, [sp, #0]",
            "ldm    r4!, {{r5, r8, r12, lr}}",
            "str    r4, [sp, #0]",
            "pkhbt  r8, r8, r8, lsl #16",
            "pkhbt  lr, lr, lr, lsl #16",
            "ldr    r9, [sp, #4]",
            "add    r4, r9, #4",
            "str    r4, [sp, #4]",
            "ldr    r10, [sp, #12]",
            "3:",
            "ldr    r0, [r5], #4",
            "ldr    r1, [r12], #4",
            "sxtb16 r2, r0",
            "sxtb16 r0, r0, ror #8",
            "sxtb16 r3, r1",
            "sxtb16 r1, r1, ror #8",
            "sadd16 r2, r2, r8",
            "sadd16 r0, r0, r8",
            "sadd16 r3, r3, lr",
            "sadd16 r1, r1, lr",
            "pkhbt  r4, r2, r3, lsl #16",
            "str    r4, [r9]",
            "pkhbt  r4, r0, r1, lsl #16",
            "str    r4, [r9, r11]",
            "pkhtb  r4, r3, r2, asr #16",
            "str    r4, [r9, r11, lsl #1]",
            "add    r9, r9, r11, lsl #1",
            "pkhtb  r4, r1, r0, asr #16",
            "str    r4, [r9, r11]",
            "add    r9, r9, r11, lsl #1",
            "subs   r10, r10, #1",
            "bne    3b",
            "ldr    r4, [sp, #8]",
            "subs   r4, r4, #1",
            "str    r4, [sp, #8]",
            "bne    2b",
            "add    sp, sp, #16",
            inout("r0") rows.rows.as_ptr() => _,
            inout("r1") dst.as_mut_ptr() => _,
            inout("r2") pairs => _,
            inout("r3") quads => _,
            out("r4") _,
            out("r5") _,
            out("r8") _,
            out("r9") _,
            out("r10") _,
            in("r11") vw * 4,
            out("r12") _,
            out("lr") _,
        );
    }
    true
}
