//! ARMv7E-M DSP instructions (Cortex-M4/M7) for the convolution inner loops, with portable
//! fallbacks that give the same bits.
//!
//! With the `dsp` cargo feature on an ARM target the functions are single `SMLAD` /
//! `SXTB16` instructions, or short hand-scheduled loops ([`dot2x2`], [`pack_rows`]), through
//! `core::arch::asm!` (with the `mve` module, the only `unsafe` in the crate; the intrinsics
//! in `core::arch::arm` are unstable). Everywhere else they are plain Rust with the
//! instructions' exact semantics, so the host tests exercise the same data flow. With the
//! `mve` feature (a Cortex-M55/M85) the loops that have a Helium version call the `mve`
//! module (`src/mve.rs`) instead; the rest stay `SMLAD`.

/// `SMLAD`: `acc + lo(x)·lo(y) + hi(x)·hi(y)` on signed 16-bit halves, wrapping like the
/// instruction (the kernels' accumulator bounds exclude overflow anyway).
#[inline(always)]
pub fn smlad(x: u32, y: u32, acc: i32) -> i32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let r: i32;
        // SAFETY: a pure register-to-register instruction of ARMv7E-M; no memory access.
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "smlad {r}, {x}, {y}, {a}",
                r = lateout(reg) r,
                x = in(reg) x,
                y = in(reg) y,
                a = in(reg) acc,
                options(pure, nomem, nostack),
            );
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        let lo = (x as u16 as i16 as i32) * (y as u16 as i16 as i32);
        let hi = ((x >> 16) as u16 as i16 as i32) * ((y >> 16) as u16 as i16 as i32);
        acc.wrapping_add(lo).wrapping_add(hi)
    }
}

/// `SXTB16`: sign-extends bytes 0 and 2 of `x` into the two 16-bit halves.
#[inline(always)]
pub fn sxtb16(x: u32) -> u32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let r: u32;
        // SAFETY: a pure register-to-register instruction of ARMv7E-M; no memory access.
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "sxtb16 {r}, {x}",
                r = lateout(reg) r,
                x = in(reg) x,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        let b0 = x as u8 as i8 as i16 as u16 as u32;
        let b2 = (x >> 16) as u8 as i8 as i16 as u16 as u32;
        b0 | (b2 << 16)
    }
}

/// `SXTB16 …, ROR #8`: sign-extends bytes 1 and 3 of `x` into the two 16-bit halves.
#[inline(always)]
pub fn sxtb16_ror8(x: u32) -> u32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let r: u32;
        // SAFETY: a pure register-to-register instruction of ARMv7E-M; no memory access.
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "sxtb16 {r}, {x}, ror #8",
                r = lateout(reg) r,
                x = in(reg) x,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        sxtb16(x.rotate_right(8))
    }
}

/// `SMMULR`: `(x·y + 2^31) >> 32`, the high word of the product rounded (signed).
#[inline(always)]
pub fn smmulr(x: i32, y: i32) -> i32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let r: i32;
        // SAFETY: a pure register-to-register instruction of ARMv7E-M; no memory access.
        #[allow(unsafe_code)]
        unsafe {
            core::arch::asm!(
                "smmulr {r}, {x}, {y}",
                r = lateout(reg) r,
                x = in(reg) x,
                y = in(reg) y,
                options(pure, nomem, nostack, preserves_flags),
            );
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        ((x as i64 * y as i64 + (1 << 31)) >> 32) as i32
    }
}

/// Two i16 values as one word, `a` in the low half.
#[inline(always)]
pub fn pack(a: i16, b: i16) -> u32 {
    (a as u16 as u32) | ((b as u16 as u32) << 16)
}

/// Two output channels × two positions of a dot product over i16 pairs (`SMLAD`):
/// with `x0 = x[..n]`, `x1 = x[step..step + n]` and the channels' weights interleaved
/// word by word in `w` (`w[2k]` channel 0, `w[2k + 1]` channel 1), returns `acc` plus
/// `[x0·w_0, x1·w_0, x0·w_1, x1·w_1]` (each word two i16 products), wrapping like the
/// instruction.
///
/// Slices too short for `n`, `step` give `acc` unchanged (the kernels never pass them).
/// With the `dsp` feature on ARM and even `n` it is a hand-scheduled loop: LLVM spills
/// the 4 accumulators of the Rust version to the stack (12 live registers are needed,
/// exactly what Thumb-2 leaves to inline assembly), which costs about 2 instructions per
/// MAC instead of 1.
#[inline(always)]
// With Helium the function is `mve::dot2x2`; the loops below stay for the other builds.
#[cfg_attr(all(feature = "mve", target_arch = "arm"), allow(unreachable_code))]
pub fn dot2x2(x: &[u32], step: usize, w: &[u32], n: usize, acc: [i32; 4]) -> [i32; 4] {
    let (Some(xe), Some(we)) = (step.checked_add(n), n.checked_mul(2)) else {
        return acc;
    };
    if x.len() < xe || x.len() < n || w.len() < we {
        return acc;
    }
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    return crate::mve::dot2x2(x, step, w, n, acc);
    #[cfg(all(feature = "dsp", not(feature = "mve"), target_arch = "arm"))]
    if n.is_multiple_of(2) {
        if n == 0 {
            return acc;
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
        return [a00, a01, a10, a11];
    }
    let [mut a00, mut a01, mut a10, mut a11] = acc;
    for ((&x0, &x1), w) in x[..n].iter().zip(&x[step..xe]).zip(w[..we].chunks_exact(2)) {
        a00 = smlad(x0, w[0], a00);
        a01 = smlad(x1, w[0], a01);
        a10 = smlad(x0, w[1], a10);
        a11 = smlad(x1, w[1], a11);
    }
    [a00, a01, a10, a11]
}

/// A row of [`dot2x2`]s: for every position `q < positions`, with `x_q = x[q·step ..
/// q·step + n]`, `acc0[q·astep] = bias[0] + x_q·w_0` and `acc1[q·astep] = bias[1] + x_q·w_1`
/// (channel words interleaved in `w` as for [`dot2x2`]), two positions per inner loop.
///
/// Returns false, leaving the accumulators alone, when a slice is too short for `positions`,
/// `step` and `n` (the kernels never pass such slices). The slices are validated once per
/// row, so a pair of positions costs the inner loop and about 12 instructions.
pub fn dot2x2_row(
    x: &[u32],
    step: usize,
    positions: usize,
    w: &[u32],
    n: usize,
    bias: [i32; 2],
    (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
) -> bool {
    RowPlan::new(step, positions, n, astep).run(x, w, bias, (acc0, acc1))
}

/// The shape of a [`dot2x2_row`] call (`step`, `positions`, `n`, `astep`), prepared once for
/// the many rows that share it: with Helium and an even number of positions, the pair loop's
/// shape checked up front (`mve::PairRows`), so a row's call only compares slice
/// lengths. [`RowPlan::run`] computes exactly what [`dot2x2_row`] does.
#[derive(Clone, Copy, Debug)]
pub struct RowPlan {
    step: usize,
    positions: usize,
    n: usize,
    astep: usize,
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    pairs: Option<crate::mve::PairRows>,
}

impl RowPlan {
    /// The plan of rows of `positions` dot products of `n` words, `step` words apart, into
    /// accumulators `astep` words apart.
    #[inline(always)]
    pub fn new(step: usize, positions: usize, n: usize, astep: usize) -> Self {
        RowPlan {
            step,
            positions,
            n,
            astep,
            // The pair loop checks exactly the slices `dot2x2_row_checked` checks (and refuses
            // what they refuse), so where it applies it runs alone.
            #[cfg(all(feature = "mve", target_arch = "arm"))]
            pairs: if positions.is_multiple_of(2) && n.is_multiple_of(2) {
                crate::mve::PairRows::new(step, n, positions / 2, astep)
            } else {
                None
            },
        }
    }

    /// One row, as [`dot2x2_row`] with this plan's shape.
    #[inline(always)]
    pub fn run(
        &self,
        x: &[u32],
        w: &[u32],
        bias: [i32; 2],
        (acc0, acc1): (&mut [i32], &mut [i32]),
    ) -> bool {
        #[cfg(all(feature = "mve", target_arch = "arm"))]
        if let Some(pairs) = &self.pairs {
            return pairs.run(x, w, bias, (acc0, acc1));
        }
        let (step, positions, n) = (self.step, self.positions, self.n);
        dot2x2_row_checked(x, step, positions, w, n, bias, (acc0, acc1, self.astep))
    }

    /// Every channel pair `k < bias.len()` of a line: [`RowPlan::run`] with the weights
    /// `w[k·wstride ..]`, biases `bias[k]` and accumulator rows `acc[2k·rstride + first ..]`
    /// and `acc[(2k + 1)·rstride + first ..]`; with Helium one call for every pair
    /// (`mve::PairRows::run_channels`). Returns false when a slice is too short for
    /// a pair (earlier pairs may have been written). Not inlined: the line engines share it.
    #[inline(never)]
    pub fn run_channels(
        &self,
        x: &[u32],
        (w, wstride): (&[u32], usize),
        bias: &[[i32; 2]],
        acc: &mut [i32],
        (rstride, first): (usize, usize),
    ) -> bool {
        // Helium's register loop takes every pair at once; other shapes run pair by pair.
        #[cfg(all(feature = "mve", target_arch = "arm"))]
        if let Some(pairs) = self.pairs.filter(|p| p.in_registers()) {
            return pairs.run_channels(x, (w, wstride), bias, acc, (rstride, first));
        }
        for (k, &b) in bias.iter().enumerate() {
            let Some((head, tail)) = acc.split_at_mut_checked((2 * k + 1) * rstride + first) else {
                return false;
            };
            let a0 = head.get_mut(2 * k * rstride + first..).unwrap_or(&mut []);
            let wk = w.get(k * wstride..).unwrap_or(&[]);
            if !self.run(x, wk, b, (a0, tail)) {
                return false;
            }
        }
        true
    }
}

/// [`dot2x2_row`] for the shapes [`RowPlan`] does not hand to Helium's pair loop alone: the
/// shape and the slices checked here, every row. Not inlined: each kernel's row loop calls it
/// from one place, and its code stays out of the kernels' hot loops.
#[inline(never)]
fn dot2x2_row_checked(
    x: &[u32],
    step: usize,
    positions: usize,
    w: &[u32],
    n: usize,
    bias: [i32; 2],
    (acc0, acc1, astep): (&mut [i32], &mut [i32], usize),
) -> bool {
    let last = match positions.checked_sub(1) {
        None => return true,
        Some(l) => l,
    };
    let fits = last
        .checked_mul(step)
        .and_then(|a| a.checked_add(n))
        .is_some_and(|e| e <= x.len())
        && n.checked_mul(2).is_some_and(|e| e <= w.len())
        && last
            .checked_mul(astep)
            .is_some_and(|a| a < acc0.len() && a < acc1.len())
        && step <= usize::MAX / 8;
    if !fits {
        return false;
    }
    // With Helium: its row loop over the pairs, then the pair loop below for an odd last
    // position (or every pair, for odd `n` or `n = 2`), which calls its `dot2x2`.
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    if n.is_multiple_of(2) && n >= 4 && positions >= 2 {
        let pairs = positions / 2;
        if crate::mve::dot2x2_row_pairs(x, (step, n), pairs, w, bias, (acc0, acc1, astep)) {
            if positions % 2 == 1 {
                let q = positions - 1;
                let bias4 = [bias[0], bias[0], bias[1], bias[1]];
                let r = dot2x2(x.get(q * step..).unwrap_or(&[]), 0, w, n, bias4);
                store_pair(acc0, acc1, astep, q, false, r);
            }
            return true;
        }
    }
    #[cfg(all(feature = "dsp", not(feature = "mve"), target_arch = "arm"))]
    if n.is_multiple_of(2) && n > 0 {
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
            // SAFETY: pair p covers positions q = 2p and q + 1 ≤ last: they start at
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
        if positions % 2 == 1 {
            let q = positions - 1;
            let r = dot2x2(
                &x[q * step..],
                0,
                w,
                n,
                [bias[0], bias[0], bias[1], bias[1]],
            );
            store_pair(acc0, acc1, astep, q, false, r);
        }
        return true;
    }
    for p in 0..positions.div_ceil(2) {
        let q = 2 * p;
        let pair = q + 1 < positions;
        let second = if pair { step } else { 0 };
        let bias4 = [bias[0], bias[0], bias[1], bias[1]];
        let r = dot2x2(x.get(q * step..).unwrap_or(&[]), second, w, n, bias4);
        store_pair(acc0, acc1, astep, q, pair, r);
    }
    true
}

/// `r(a)` of the requantising row functions: `x = SMMULR(a << left1, multiplier)`, then
/// `(x + half + (x >> 31 & neg)) >> right` (`right < 32`). One definition for their portable
/// loops and the kernels' `RowRequant::apply`, so the three cannot drift apart.
#[inline(always)]
pub(crate) fn row_requant(
    a: i32,
    multiplier: i32,
    left1: u32,
    right: u32,
    half: i32,
    neg: i32,
) -> i32 {
    let x = smmulr(a.wrapping_shl(left1), multiplier);
    x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right
}

/// A row of requantised int8 values and their maximum: `out[i] = sat(r(acc[i]))` for the
/// first `min(acc.len(), out.len())` values, with `x = SMMULR(acc << left1, multiplier)`,
/// `r = (x + half + (x >> 31 & neg)) >> right` (the kernels' `RowRequant`) and `sat` the int8
/// clamp (`SSAT #8`), or with `relu` the clamp to `0..=127` (`USAT #7`). Returns the larger
/// of `max` and every value written. With the `dsp` feature on ARM: 14 instructions per
/// value (the Rust loop takes 24: LLVM spills and sign-extends around two compare-and-move
/// clamps).
pub fn requant_max_row(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    max: i8,
) -> i8 {
    #[allow(unused_mut)]
    let (mut acc, mut out, mut max) = (acc, out, max);
    // With Helium: the blocks of four values, then the loop below for the rest.
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    if left1 < 32 && right < 32 {
        let quads = acc.len().min(out.len()) / 4;
        if quads > 0 {
            let rq = (multiplier, left1, right, half, neg);
            max = crate::mve::requant_max_row_quads(acc, out, rq, relu, max, quads);
            acc = &acc[4 * quads..];
            out = &mut out[4 * quads..];
        }
    }
    let len = acc.len().min(out.len());
    // With Helium only the last 1 to 3 values are left: the plain loop below, in less code.
    #[cfg(all(feature = "dsp", not(feature = "mve"), target_arch = "arm"))]
    if len > 0 && left1 < 32 && right < 32 {
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
        return mx as i8;
    }
    let mut mx = max as i32;
    for (d, &a) in out[..len].iter_mut().zip(&acc[..len]) {
        let t = row_requant(a, multiplier, left1, right.min(31), half, neg);
        let t = if relu {
            t.clamp(0, 127)
        } else {
            t.clamp(-128, 127)
        };
        *d = t as i8;
        mx = mx.max(t);
    }
    mx as i8
}

/// Each channel's requantisation as the five words the row loops take (multiplier, left1,
/// right, half, neg: the tuple of [`requant_row_s8`]), every shift checked below 32 once, when
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
}

/// Rows of [`requant_row_s8`], one per channel of a line: row `c < params.len()` turns
/// `acc[c·width ..][..width]` into `out[c·plane ..][..width]` with channel `c`'s words. With
/// Helium and a width that is a multiple of 4, one call for every row
/// (`mve::requant_rows_quads`). Returns false, writing nothing, when a row's slices
/// do not fit.
pub fn requant_rows_s8(
    acc: &[i32],
    out: &mut [i8],
    params: RowWords<'_>,
    (width, plane): (usize, usize),
    relu: bool,
    skip: Option<&[i32; 256]>,
) -> bool {
    let (rows, params) = (params.len(), params.0);
    let fits = rows.checked_mul(width).is_some_and(|n| n <= acc.len())
        && rows.checked_sub(1).is_none_or(|r| {
            r.checked_mul(plane)
                .and_then(|a| a.checked_add(width))
                .is_some_and(|n| n <= out.len())
        });
    if !fits {
        return false;
    }
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    if width.is_multiple_of(4)
        && width > 0
        && crate::mve::requant_rows_quads(acc, out, params, (width / 4, plane), relu, skip)
    {
        return true;
    }
    for (c, p) in params.iter().enumerate() {
        let f = (p[0], p[1] as u32, p[2] as u32, p[3], p[4]);
        let dst = &mut out[c * plane..][..width];
        requant_row_s8(&acc[c * width..][..width], dst, f, relu, skip);
    }
    true
}

/// A row of a layer's int8 outputs from its accumulators: for the first
/// `min(acc.len(), out.len())` values, `t = r(acc[i])` as in [`requant_max_row`], then with
/// `relu` `t = max(t, 0)`, then with a skip table `t = t +sat skip[out[i] as u8]` (the value
/// `out[i]` held before: an in-place skip), and `out[i] = clamp(t, −128, 127)`. With the
/// `dsp` feature on ARM: 11 instructions per value (15 with the skip; `QADD` is the
/// saturating add, `BIC … ASR #31` the ReLU), against 13–19 for the Rust loop.
pub fn requant_row_s8(
    acc: &[i32],
    out: &mut [i8],
    (multiplier, left1, right, half, neg): (i32, u32, u32, i32, i32),
    relu: bool,
    skip: Option<&[i32; 256]>,
) {
    #[allow(unused_mut)]
    let (mut acc, mut out) = (acc, out);
    // With Helium: the blocks of four values, then the loop below for the rest.
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    if left1 < 32 && right < 32 {
        let quads = acc.len().min(out.len()) / 4;
        if quads > 0 {
            // One row of the whole-line loop (shifts below 32, checked here).
            let words = [[multiplier, left1 as i32, right as i32, half, neg]];
            crate::mve::requant_rows_quads(acc, out, &words, (quads, 0), relu, skip);
            acc = &acc[4 * quads..];
            out = &mut out[4 * quads..];
        }
    }
    let len = acc.len().min(out.len());
    // With Helium only the last 1 to 3 values are left: the plain loop below, in less code.
    #[cfg(all(feature = "dsp", not(feature = "mve"), target_arch = "arm"))]
    if len > 0 && left1 < 32 && right < 32 {
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
        return;
    }
    for (d, &a) in out[..len].iter_mut().zip(&acc[..len]) {
        let t = row_requant(a, multiplier, left1, right.min(31), half, neg);
        let t = if relu { t.max(0) } else { t };
        let t = match skip {
            Some(l) => t.saturating_add(l[*d as u8 as usize]),
            None => t,
        };
        *d = t.clamp(-128, 127) as i8;
    }
}

/// Strided pairs: `dst[j·dstride] = pack(a[j·sstride] + oa, b[j·sstride] + ob)` for
/// `j < count` (a column of two int8 planes into i16 pairs). Does nothing when a slice is too
/// short for `count` and the strides (the kernels never pass such slices). With the `dsp`
/// feature on ARM: 8 instructions per word without offsets (10 with), against about 12.5 for
/// the Rust loop; with Helium 2.5 per word (`mve::pack_strided_quads`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn pack_strided(
    dst: &mut [u32],
    dstride: usize,
    (a, b, sstride): (&[i8], &[i8], usize),
    count: usize,
    oa: i16,
    ob: i16,
) {
    let Some(last) = count.checked_sub(1) else {
        return;
    };
    let fits = |len: usize, stride: usize| last.checked_mul(stride).is_some_and(|e| e < len);
    if !(fits(dst.len(), dstride) && fits(a.len(), sstride) && fits(b.len(), sstride)) {
        return;
    }
    // With Helium: blocks of four by gathers, then the rest below.
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    let (dst, a, b, count) = {
        let quads = count / 4;
        let done = 4 * quads;
        if quads > 0 {
            crate::mve::pack_strided_quads(dst, dstride, (a, b, sstride), quads, (oa, ob));
        }
        if done == count {
            return;
        }
        // done < count: the indices below are at most last · stride, in bounds.
        let (Some(d), Some(a), Some(b)) = (
            dst.get_mut(done * dstride..),
            a.get(done * sstride..),
            b.get(done * sstride..),
        ) else {
            return;
        };
        (d, a, b, count - done)
    };
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    if dstride <= usize::MAX / 8 {
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
        return;
    }
    for j in 0..count {
        dst[j * dstride] = pack(a[j * sstride] as i16 + oa, b[j * sstride] as i16 + ob);
    }
}

/// The soft-argmax sums of one ray: with `e_i = exp[(m − q_i) mod 256]`, returns
/// `(S, T) = (Σ e_i, Σ i·e_i)` (wrapping u32, as the kernels' exact sums never wrap). With the
/// `dsp` feature on ARM and a multiple of 4 logits: `USUB8` forms four table indices at once
/// and `T = n·S − Σ_i S_i` (the prefix sums) replaces the multiply-accumulate, 5 instructions
/// per logit instead of 7.
#[inline(always)]
pub fn exp_sums(logits: &[i8], m: i8, exp: &[u16; 256]) -> (u32, u32) {
    #[cfg(all(feature = "mve", target_arch = "arm"))]
    if let Some(sums) = crate::mve::exp_sums(logits, m, exp) {
        return sums;
    }
    #[cfg(all(feature = "dsp", not(feature = "mve"), target_arch = "arm"))]
    if !logits.is_empty() && logits.len().is_multiple_of(4) {
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
        return (s, n.wrapping_mul(s).wrapping_sub(u));
    }
    let (mut s, mut t) = (0u32, 0u32);
    for (i, &q) in logits.iter().enumerate() {
        let e = exp[(m as i32 - q as i32) as u8 as usize] as u32;
        s = s.wrapping_add(e);
        t = t.wrapping_add(e.wrapping_mul(i as u32));
    }
    (s, t)
}

/// The results of positions `q` and (with `pair`) `q + 1` of [`dot2x2_row`].
#[inline(always)]
fn store_pair(acc0: &mut [i32], acc1: &mut [i32], astep: usize, q: usize, pair: bool, r: [i32; 4]) {
    let i = q * astep;
    if let (Some(a), Some(b)) = (acc0.get_mut(i), acc1.get_mut(i)) {
        *a = r[0];
        *b = r[2];
    }
    if pair {
        let i = i + astep;
        if let (Some(a), Some(b)) = (acc0.get_mut(i), acc1.get_mut(i)) {
            *a = r[1];
            *b = r[3];
        }
    }
}

/// One column of a two-view cost-volume piece (rows of `width` values): for every row
/// `k`, with `i = k·width + col`, the warped source value
/// `w = (src[k·width + c]·wl + src[k·width + c + 1]·wr + 128) >> 8` and
/// `out[i] = table[reference[i] − w + 255]`.
///
/// Returns false, doing nothing, when the slices do not have one common length that is a
/// multiple of `width`, `col` or `c + 1` is not below `width`, or the weights are not
/// `wl, wr ≥ 0` with `wl + wr = 256` or both 0 (an invisible entry). Then `w` lies between
/// the two int8 source values (or is 0), `reference − w + 255` in `0..=510`, inside the
/// 512-entry table. With the `dsp` feature on ARM: 12 instructions per value (the two
/// source values are one halfword load, `SMUAD` weighs them).
#[allow(clippy::too_many_arguments)]
pub fn cost_column(
    out: &mut [i8],
    reference: &[i8],
    src: &[i8],
    width: usize,
    col: usize,
    c: usize,
    taps: (i16, i16),
    table: &[i8; 512],
) -> bool {
    table_column(
        out,
        [reference, src],
        (width, col, c),
        taps,
        table,
        Combine::Difference,
    )
}

/// [`cost_column`] for a mean channel: `out[i] = table[reference[i] + w + 256]`
/// (`reference + w` in `−256..=254`, so the index lies in `0..=510`). Same conditions, same
/// 12 instructions per value (one `ADD` where the variance has a `SUB`).
#[allow(clippy::too_many_arguments)]
pub fn mean_column(
    out: &mut [i8],
    reference: &[i8],
    src: &[i8],
    width: usize,
    col: usize,
    c: usize,
    taps: (i16, i16),
    table: &[i8; 512],
) -> bool {
    table_column(
        out,
        [reference, src],
        (width, col, c),
        taps,
        table,
        Combine::Sum,
    )
}

/// `table_columns!(name, lanes)`: a dispatcher to `crate::mve`'s kernel of the
/// same name, false in builds without it; one body for both widths.
macro_rules! table_columns {
    ($(#[$doc:meta])* $name:ident, $lanes:literal) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        #[inline(always)]
        pub fn $name(
            out: &mut [i8],
            reference: &[i8],
            src: &[i8],
            (width, col): (usize, usize),
            taps: [(usize, i16, i16); $lanes],
            table: &[i8; 512],
            sum: bool,
        ) -> bool {
            #[cfg(all(feature = "mve", target_arch = "arm"))]
            {
                let cs = taps.map(|t| t.0);
                let weights = taps.map(|t| (t.1, t.2));
                crate::mve::$name(out, reference, src, (width, col), cs, weights, table, sum)
            }
            #[cfg(not(all(feature = "mve", target_arch = "arm")))]
            {
                let _ = (out, reference, src, width, col, taps, table, sum);
                false
            }
        }
    };
}

table_columns!(
    /// Eight adjacent columns `col .. col + 8` of [`cost_column`] (or of [`mean_column`] when
    /// `sum`), as [`table_columns4`] (`mve::table_columns8`, 16-bit lanes). False, and nothing
    /// written, in other builds or where it refuses; the caller then takes four columns or one.
    table_columns8,
    8
);

table_columns!(
    /// Four adjacent columns `col .. col + 4` of [`cost_column`] (or of [`mean_column`] when
    /// `sum`), one tap `(c, wl, wr)` per column: the same values, in one pass down the rows with
    /// Helium (`mve::table_columns4`). False, and nothing written, in other builds or under
    /// conditions either one-column function would refuse; the caller then goes column by
    /// column.
    table_columns4,
    4
);

/// How [`table_column`] combines the reference value with the warped source value.
#[derive(Clone, Copy)]
enum Combine {
    /// `reference − w`, read at table offset 255 (the variance of two views).
    Difference,
    /// `reference + w`, read at table offset 256 (the mean of two views).
    Sum,
}

/// The loop of [`cost_column`] and [`mean_column`]: one audited `asm!` template (the macro
/// below), the combining instruction its only difference.
#[inline(always)]
fn table_column(
    out: &mut [i8],
    [reference, src]: [&[i8]; 2],
    (width, col, c): (usize, usize, usize),
    (wl, wr): (i16, i16),
    table: &[i8; 512],
    combine: Combine,
) -> bool {
    let n = out.len();
    let ok = reference.len() == n
        && src.len() == n
        && width > 0
        && n.is_multiple_of(width)
        && col < width
        && c.checked_add(1).is_some_and(|c1| c1 < width)
        && ((wl >= 0 && wr >= 0 && wl as i32 + wr as i32 == 256) || (wl, wr) == (0, 0))
        && n <= i32::MAX as usize;
    if !ok {
        return false;
    }
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    if n > 0 {
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
        return true;
    }
    for ((o, r), s) in out
        .chunks_exact_mut(width)
        .zip(reference.chunks_exact(width))
        .zip(src.chunks_exact(width))
    {
        let w = (s[c] as i32 * wl as i32 + s[c + 1] as i32 * wr as i32 + 128) >> 8;
        let index = match combine {
            Combine::Difference => r[col] as i32 - w + 255,
            Combine::Sum => r[col] as i32 + w + 256,
        };
        o[col] = table[index.clamp(0, 511) as usize];
    }
    true
}

/// One column of a three-view cost-volume piece (rows of `width` values) with the unsigned
/// cost volume (zero point −128): for every row `k`, with `i = k·width + col`, the warped
/// source values `v_s = (src_s[k·width + c_s]·wl_s + src_s[k·width + c_s + 1]·wr_s + 128) >> 8`,
/// `X = (v0 − v1)² + (v0 − v2)² + (v1 − v2)²` with `v0 = reference[i]`, and
/// `out[i] = clamp(MBQM(X, M, shift), 0, 255) − 128` (QUANTISATION.md; `CostRequant::store`).
///
/// Here `X ≥ 0`, `M ≥ 0` and `shift ≤ 0`, so `MBQM(X) = (((2X·M + 2^31) >> 32) + half) >> right`
/// with `right = −shift` and `half = 2^(right − 1)` (0 when `right = 0`): `SMMLAR` gives the
/// first shift and the rounding half in one instruction (`2X < 2^19` fits, and
/// `(2X·M + 2^31) >> 32 = (X·M + 2^30) >> 31` exactly).
///
/// Returns false, doing nothing, when the slices do not have one common length that is a
/// multiple of `width`, `col` or a `c_s + 1` is not below `width`, a tap's weights are not
/// `wl, wr ≥ 0` with `wl + wr = 256` or both 0, the multiplier is negative, the shift is
/// positive, or the zero point is not −128: the caller's portable loop serves those. With the
/// `dsp` feature on ARM: 33 instructions per value (the caller's loop: about 55).
pub fn cost_column3(
    out: &mut [i8],
    reference: &[i8],
    sources: [&[i8]; 2],
    (width, col): (usize, usize),
    taps: [(usize, i16, i16); 2],
    requant: crate::requant::Requant,
    zero_point: i32,
) -> bool {
    let n = out.len();
    let tap_ok = |(c, wl, wr): (usize, i16, i16)| {
        c.checked_add(1).is_some_and(|c1| c1 < width)
            && ((wl >= 0 && wr >= 0 && wl as i32 + wr as i32 == 256) || (wl, wr) == (0, 0))
    };
    let ok = reference.len() == n
        && sources.iter().all(|s| s.len() == n)
        && width > 0
        && n.is_multiple_of(width)
        && col < width
        && taps.iter().all(|&t| tap_ok(t))
        && requant.multiplier >= 0
        && requant.shift <= 0
        && zero_point == -128
        && n <= i32::MAX as usize;
    if !ok {
        return false;
    }
    let right = requant.shift.unsigned_abs().min(31);
    let half = if right > 0 { 1i32 << (right - 1) } else { 0 };
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    if n > 0 {
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
        return true;
    }
    // The same arithmetic, for hosts (the tests check it against the plain kernel).
    let warp = |row: &[i8], (c, wl, wr): (usize, i16, i16)| {
        (row[c] as i32 * wl as i32 + row[c + 1] as i32 * wr as i32 + 128) >> 8
    };
    let rows = out
        .chunks_exact_mut(width)
        .zip(reference.chunks_exact(width))
        .zip(sources[0].chunks_exact(width))
        .zip(sources[1].chunks_exact(width));
    for (((o, r), s0), s1) in rows {
        let (v0, v1, v2) = (r[col] as i32, warp(s0, taps[0]), warp(s1, taps[1]));
        let x = (v0 - v1).pow(2) + (v0 - v2).pow(2) + (v1 - v2).pow(2);
        let q = ((((2 * x) as i64 * requant.multiplier as i64 + (1 << 31)) >> 32) as i32 + half)
            >> right;
        o[col] = (q.clamp(0, 255) - 128) as i8;
    }
    true
}

/// Interleaves two i8 rows into i16 pairs: `dst[j · stride] = pack(a[j] + oa, b[j] + ob)`
/// for `j < min(a.len(), b.len())` (a line-buffer column of the convolution engines).
///
/// Positions past the end of `dst` are skipped (the kernels never pass them). With the
/// `dsp` feature on ARM it is a 9-instruction loop (`PKHBT` packs the pair); the Rust
/// version costs about 20 instructions per word on Cortex-M7 (iterator bookkeeping).
#[inline(always)]
pub fn pack_rows(dst: &mut [u32], stride: usize, a: &[i8], b: &[i8], oa: i16, ob: i16) {
    let n = a.len().min(b.len());
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let fits = n
            .checked_sub(1)
            .and_then(|m| m.checked_mul(stride))
            .is_some_and(|last| last < dst.len());
        if fits && stride <= usize::MAX / 16 {
            let mut dp = dst.as_mut_ptr();
            let mut ap = a.as_ptr();
            let mut bp = b.as_ptr();
            // Four entries per iteration: one word of each row, SXTB16 / SXTB16 ROR 8 split
            // it into even and odd bytes as i16 pairs, SADD16 adds the offsets, PKHBT /
            // PKHTB pair the rows (5.5 instructions per entry instead of 9).
            let quads = n / 4;
            #[cfg(feature = "mve")]
            if quads > 0 {
                crate::mve::pack_row_quads(dst, stride, (a, b), quads, (oa, ob));
                dp = dp.wrapping_add(4 * quads * stride);
                ap = ap.wrapping_add(4 * quads);
                bp = bp.wrapping_add(4 * quads);
            }
            #[cfg(not(feature = "mve"))]
            if quads > 0 {
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
            }
            let mut left = n - 4 * quads;
            if left == 0 {
                return;
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
            return;
        }
    }
    for (j, (&x, &y)) in a[..n].iter().zip(&b[..n]).enumerate() {
        if let Some(d) = dst.get_mut(j * stride) {
            *d = pack(x as i16 + oa, y as i16 + ob);
        }
    }
}

/// The line engine's whole-line fills on ARM (`dsp`, and with `mve` Helium): the rows of a
/// line as a table the assembly reads, and the fill itself.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
mod line_rows {
    /// One input row of a line fill and the offset its entries get, as [`pack_line_quads`]
    /// reads them: the row's address and the offset widened to a word.
    #[repr(C)]
    #[derive(Clone, Copy)]
    pub(crate) struct LineRow {
        ptr: *const i8,
        off: i32,
    }

    /// Up to [`LineRows::CAPACITY`] input rows of one line fill, in line-entry order (entries
    /// `2k` and `2k + 1` fill line word `k` of every column), every one at least `need` bytes
    /// long: [`LineRows::push`] refuses a shorter row, so [`pack_line_quads`] may read `need`
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
        /// last column. The check both fills ([`pack_line_quads`] and its Helium twin) make.
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
    static ZERO_ROW: [i8; 256] = [0; 256];

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

    /// A whole line fill (the line engine's, `kernels::line`): for each pair `k` of `rows`
    /// (entries `2k`, `2k + 1`: rows `a`, `b` with offsets `oa`, `ob`), `dst[k + j · vw] =
    /// pack(a[j] + oa, b[j] + ob)` for `j < need`, `need` a multiple of 4: what [`super::pack_rows`]
    /// does for one word, for up to 16 words in one call. With Helium it is
    /// `mve::pack_line_quads`; here the `SXTB16` loop of [`super::pack_rows`] (5.5 instructions per
    /// entry) with the pair loop in assembly too (about 16 instructions per line word, where the
    /// Rust loop around [`super::pack_rows`] spent about 100 choosing the rows and checking slices).
    /// Returns false, doing nothing, for an odd number of rows, `need` not a positive multiple of
    /// 4, or a `dst` too short.
    pub fn pack_line_quads(dst: &mut [u32], vw: usize, rows: &LineRows<'_>) -> bool {
        #[cfg(feature = "mve")]
        return crate::mve::pack_line_quads(dst, vw, rows);
        #[cfg(not(feature = "mve"))]
        {
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
    }
}
#[cfg(all(feature = "dsp", target_arch = "arm"))]
pub use line_rows::{pack_line_quads, ChannelTaps, LineRows};

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec;
    use std::vec::Vec;

    #[test]
    fn fallbacks_have_the_instruction_semantics() {
        assert_eq!(sxtb16(0x80_7f_01_ff), 0x007f_ffff); // bytes 0 (−1) and 2 (127)
        assert_eq!(sxtb16_ror8(0x80_7f_01_ff), 0xff80_0001); // bytes 1 (1) and 3 (−128)
        assert_eq!(smlad(pack(-3, 7), pack(100, -2), 5), 5 - 300 - 14);
        assert_eq!(
            smlad(pack(i16::MIN, i16::MIN), pack(i16::MIN, i16::MIN), 0),
            i32::MIN // 2^31 wraps, as SMLAD does (and sets Q)
        );
        let mut s = 0x1234_5678u32;
        for _ in 0..1000 {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let w = s;
            let (e, o) = (sxtb16(w), sxtb16_ror8(w));
            let bytes = w.to_le_bytes().map(|b| b as i8 as i32);
            assert_eq!(e as u16 as i16 as i32, bytes[0]);
            assert_eq!((e >> 16) as u16 as i16 as i32, bytes[2]);
            assert_eq!(o as u16 as i16 as i32, bytes[1]);
            assert_eq!((o >> 16) as u16 as i16 as i32, bytes[3]);
        }
    }

    #[test]
    fn smmulr_rounds_the_high_word() {
        let mut s = 0x9e37_79b9u32;
        for _ in 0..10_000 {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let x = s as i32;
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let y = s as i32;
            let want = ((x as i64 * y as i64 + (1i64 << 31)) >> 32) as i32;
            assert_eq!(smmulr(x, y), want);
        }
        assert_eq!(smmulr(i32::MIN, i32::MIN), 1 << 30);
        assert_eq!(smmulr(-1, 1), 0);
        assert_eq!(smmulr(1 << 30, 2), 1); // 2^31 / 2^32: the tie rounds up
        assert_eq!(smmulr(-(1 << 30), 2), 0);
    }

    #[test]
    fn dot2x2_is_the_sum_of_products() {
        let mut s = 0x1234_5678u32;
        let mut r = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            s
        };
        for n in 0..9 {
            for step in 0..4 {
                let x: std::vec::Vec<u32> = (0..n + step + 2).map(|_| r()).collect();
                let w: std::vec::Vec<u32> = (0..2 * n + 1).map(|_| r()).collect();
                let acc = [r() as i32 >> 4, 5, -7, 11];
                let half = |v: u32, h: u32| (v >> (16 * h)) as u16 as i16 as i64;
                let mut want = acc.map(|a| a as i64);
                for k in 0..n {
                    for h in 0..2 {
                        want[0] += half(x[k], h) * half(w[2 * k], h);
                        want[1] += half(x[k + step], h) * half(w[2 * k], h);
                        want[2] += half(x[k], h) * half(w[2 * k + 1], h);
                        want[3] += half(x[k + step], h) * half(w[2 * k + 1], h);
                    }
                }
                let got = dot2x2(&x, step, &w, n, acc);
                assert_eq!(got, want.map(|v| v as i32), "n={n} step={step}");
            }
        }
        // Too-short slices: nothing happens, no panic.
        assert_eq!(
            dot2x2(&[1, 2], 1, &[1, 2, 3, 4], 2, [1, 2, 3, 4]),
            [1, 2, 3, 4]
        );
    }

    #[test]
    fn dot2x2_row_is_a_row_of_dot2x2() {
        let mut s = 0x5555_1234u32;
        let mut r = || {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            s
        };
        for n in 0..7 {
            for step in 0..4 {
                for positions in 0..6 {
                    let len = positions.max(1) * step + n + 1;
                    let x: Vec<u32> = (0..len).map(|_| r()).collect();
                    let w: Vec<u32> = (0..2 * n).map(|_| r()).collect();
                    let bias = [r() as i32 >> 8, -(r() as i32 >> 9)];
                    let (mut a0, mut a1) = (vec![7i32; positions], vec![9i32; positions]);
                    let accs = (&mut a0[..], &mut a1[..], 1);
                    assert!(dot2x2_row(&x, step, positions, &w, n, bias, accs));
                    for q in 0..positions {
                        let want = dot2x2(&x[q * step..], 0, &w, n, [bias[0], 0, bias[1], 0]);
                        let got = (a0[q], a1[q]);
                        assert_eq!(got, (want[0], want[2]), "n={n} step={step} q={q}");
                    }
                    // Every third accumulator.
                    let (mut b0, mut b1) = (vec![5i32; 3 * positions], vec![6; 3 * positions]);
                    let accs = (&mut b0[..], &mut b1[..], 3);
                    assert!(dot2x2_row(&x, step, positions, &w, n, bias, accs));
                    for q in 0..3 * positions {
                        let want = if q % 3 == 0 {
                            (a0[q / 3], a1[q / 3])
                        } else {
                            (5, 6)
                        };
                        assert_eq!((b0[q], b1[q]), want);
                    }
                }
            }
        }
        // Too short: refused, untouched, no panic.
        let (mut a0, mut a1) = ([1i32; 3], [2i32; 3]);
        let accs = (&mut a0[..], &mut a1[..], 1);
        assert!(!dot2x2_row(&[0; 4], 2, 3, &[0; 4], 2, [0, 0], accs));
        assert_eq!((a0, a1), ([1; 3], [2; 3]));
        let accs = (&mut a0[..2], &mut a1[..], 1);
        assert!(!dot2x2_row(&[0; 8], 1, 3, &[0; 4], 2, [0, 0], accs));
        let accs = (&mut a0[..], &mut a1[..], 2);
        assert!(!dot2x2_row(&[0; 8], 1, 3, &[0; 4], 2, [0, 0], accs));
    }

    #[test]
    fn pack_rows_interleaves_with_offsets() {
        let a = [1i8, -128, 127, 0, -5];
        let b = [-1i8, 127, -128, 9, 3];
        for stride in 1..4 {
            let mut dst = std::vec![0xdead_beefu32; 5 * stride];
            pack_rows(&mut dst, stride, &a, &b[..4], 128, -3);
            for (j, w) in dst.iter().enumerate() {
                let want = if j % stride == 0 && j / stride < 4 {
                    let k = j / stride;
                    pack(a[k] as i16 + 128, b[k] as i16 - 3)
                } else {
                    0xdead_beef
                };
                assert_eq!(*w, want, "stride {stride} word {j}");
            }
        }
        // A destination too short: the words that fit, no panic.
        let mut short = [0u32; 3];
        pack_rows(&mut short, 2, &a, &b, 0, 0);
        assert_eq!(short, [pack(1, -1), 0, pack(-128, 127)]);
    }

    #[test]
    fn pack_strided_packs_a_column() {
        let a: Vec<i8> = (0..20).map(|i| (i * 13 - 100) as i8).collect();
        let b: Vec<i8> = (0..20).map(|i| (50 - i * 7) as i8).collect();
        for (offsets, sstride, dstride) in [((0, 0), 4, 3), ((128, -3), 5, 1), ((7, 0), 1, 2)] {
            let count = (a.len() - 1) / sstride + 1;
            let mut dst = std::vec![0xdead_beefu32; count * dstride];
            let (oa, ob) = offsets;
            pack_strided(&mut dst, dstride, (&a, &b, sstride), count, oa, ob);
            for (j, w) in dst.iter().enumerate() {
                let want = if j % dstride == 0 {
                    let k = j / dstride * sstride;
                    pack(a[k] as i16 + oa, b[k] as i16 + ob)
                } else {
                    0xdead_beef
                };
                assert_eq!(*w, want, "strides {sstride} {dstride} word {j}");
            }
        }
        // Too short for the count: nothing written, no panic.
        let mut dst = [7u32; 4];
        pack_strided(&mut dst, 1, (&a, &b, 4), 6, 0, 0);
        assert_eq!(dst, [7; 4]);
    }

    /// The plain definition of a requantised output (`RowRequant` fields, ReLU, skip, clamp).
    fn requantised(a: i32, f: (i32, u32, u32, i32, i32), relu: bool, skip: Option<i32>) -> i32 {
        let (m, left1, right, half, neg) = f;
        let x = ((a.wrapping_shl(left1) as i64 * m as i64 + (1 << 31)) >> 32) as i32;
        let t = x.wrapping_add(half).wrapping_add((x >> 31) & neg) >> right;
        let t = if relu { t.max(0) } else { t };
        t.saturating_add(skip.unwrap_or(0)).clamp(-128, 127)
    }

    #[test]
    fn requant_rows_match_the_definition() {
        let mut s = 0x2545_f491u32;
        let mut next = || {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            s
        };
        let table: [i32; 256] = core::array::from_fn(|i| (i as i32 - 128) * 3 - 7);
        for round in 0..200 {
            let right = next() % 12;
            let f = (
                (next() >> 1) as i32 | 0x4000_0000,
                1 + next() % 3,
                right,
                if right > 0 { 1 << (right - 1) } else { 0 },
                if right > 0 { -1 } else { 0 },
            );
            let acc: Vec<i32> = (0..37).map(|_| (next() as i32) >> 12).collect();
            let old: Vec<i8> = (0..37).map(|_| next() as i8).collect();
            let relu = round % 2 == 0;
            let skip = (round % 3 == 0).then_some(&table);
            let mut out = old.clone();
            requant_row_s8(&acc, &mut out, f, relu, skip);
            let mut with_max = std::vec![0i8; 37];
            let max = requant_max_row(&acc, &mut with_max, f, relu, -100);
            let mut want_max = -100;
            for i in 0..37 {
                let sk = skip.map(|t| t[old[i] as u8 as usize]);
                assert_eq!(
                    out[i] as i32,
                    requantised(acc[i], f, relu, sk),
                    "round {round} {i}"
                );
                let plain = requantised(acc[i], f, relu, None);
                assert_eq!(with_max[i] as i32, plain, "round {round} {i}");
                want_max = want_max.max(plain);
            }
            assert_eq!(max as i32, want_max);
        }
    }

    #[test]
    fn exp_sums_are_the_sums() {
        let exp: [u16; 256] =
            core::array::from_fn(|d| (65535.0 * (-(d as f64) * 0.03).exp()) as u16);
        let mut x = 0x1234_5678u32;
        for len in [4usize, 8, 64, 256, 3, 13] {
            let logits: Vec<i8> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as i8
                })
                .collect();
            let m = *logits.iter().max().unwrap();
            let (mut s, mut t) = (0u32, 0u32);
            for (i, &q) in logits.iter().enumerate() {
                let e = exp[(m as i32 - q as i32) as usize] as u32;
                s += e;
                t += e * i as u32;
            }
            assert_eq!(exp_sums(&logits, m, &exp), (s, t), "len {len}");
        }
    }
}
