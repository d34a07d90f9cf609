//! Requantisation by an integer multiplier and shift: TFLite's `MultiplyByQuantizedMultiplier`
//! (CMSIS-NN's `arm_nn_requantize`), exactly as `docs/QUANTISATION.md` defines it.
//!
//! A real multiplier `m` is stored as `(M, shift)` with `M` in `[2^30, 2^31)` (or `0` for
//! `m = 0`) and `m ≈ M · 2^(shift − 31)`.

/// Integer form of one real requantisation multiplier: `m ≈ multiplier · 2^(shift − 31)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Requant {
    /// `M`, in `[2^30, 2^31)`, or 0 for a zero multiplier.
    pub multiplier: i32,
    /// Power-of-two exponent; positive shifts the accumulator left before the multiply.
    pub shift: i32,
}

/// Smallest shift the kernels accept (a right shift by 31).
pub const MIN_SHIFT: i32 = -31;
/// Largest shift the kernels accept (a left shift by 30).
pub const MAX_SHIFT: i32 = 30;

impl Requant {
    /// `MBQM(acc, M, shift)`.
    #[inline(always)]
    pub fn apply(self, acc: i32) -> i32 {
        multiply_by_quantized_multiplier(acc, self.multiplier, self.shift)
    }

    /// Left shift applied to the accumulator before the multiply.
    pub const fn left_shift(self) -> u32 {
        if self.shift > 0 {
            self.shift as u32
        } else {
            0
        }
    }

    /// True when `shift` lies in [`MIN_SHIFT`]`..=`[`MAX_SHIFT`].
    pub const fn shift_in_range(self) -> bool {
        self.shift >= MIN_SHIFT && self.shift <= MAX_SHIFT
    }

    /// True when every accumulator of magnitude at most `bound` survives the left shift
    /// (`bound · 2^left < 2^31`), so `MBQM` computes exactly the contract's value.
    pub const fn fits(self, bound: i64) -> bool {
        if bound < 0 || bound >= (1i64 << 31) {
            return false;
        }
        let left = self.left_shift();
        if left >= 32 {
            return bound == 0;
        }
        (bound << left) < (1i64 << 31)
    }

    /// TFLite's `QuantizeMultiplier`: the integer form of a real multiplier `m ≥ 0`.
    ///
    /// Returns `None` for negative, non-finite or too large multipliers (shift above
    /// [`MAX_SHIFT`]). Multipliers too small for a shift of [`MIN_SHIFT`] become zero, as in
    /// TFLite. Host-side only: the library never builds multipliers at run time.
    #[cfg(any(test, feature = "std"))]
    pub fn from_real(m: f64) -> Option<Requant> {
        if !m.is_finite() || m < 0.0 {
            return None;
        }
        if m == 0.0 {
            return Some(Requant::default());
        }
        let (q, e) = libm::frexp(m);
        // q in [0.5, 1): M = round(q · 2^31) in [2^30, 2^31]; round is half away from zero.
        let mut fixed = libm::round(q * (1u64 << 31) as f64) as i64;
        let mut shift = e;
        if fixed == 1i64 << 31 {
            fixed /= 2;
            shift += 1;
        }
        if shift < MIN_SHIFT {
            return Some(Requant::default());
        }
        if shift > MAX_SHIFT {
            return None;
        }
        Some(Requant {
            multiplier: fixed as i32,
            shift,
        })
    }
}

/// Saturating rounding doubling high multiply: `a · b / 2^31` rounded to nearest with ties
/// toward +∞ (the nudge `1 − 2^30` on negatives plus truncation toward zero gives that), and
/// the single overflow case `i32::MIN · i32::MIN` saturating to `i32::MAX`.
#[inline(always)]
pub fn srdhm(a: i32, b: i32) -> i32 {
    if a == i32::MIN && b == i32::MIN {
        return i32::MAX;
    }
    let ab = a as i64 * b as i64;
    let nudge = if ab >= 0 {
        1i64 << 30
    } else {
        1 - (1i64 << 30)
    };
    // |ab| ≤ 2^62 so the sum cannot overflow; the quotient fits i32 (MIN·MIN excluded).
    ((ab + nudge) / (1i64 << 31)) as i32
}

/// Rounding divide by `2^e`, ties away from zero (`>>` is arithmetic).
///
/// `e` outside `0..=31` is clamped to that range so no input can panic; the contract only
/// uses `0..=31`.
#[inline(always)]
pub fn rounding_divide_by_pot(x: i32, e: i32) -> i32 {
    let e = e.clamp(0, 31) as u32;
    let mask = ((1u32 << e) - 1) as i32;
    let rem = x & mask;
    let threshold = (mask >> 1) + i32::from(x < 0);
    (x >> e) + i32::from(rem > threshold)
}

/// `MBQM(acc, M, shift)`: `acc · M · 2^(shift − 31)` with TFLite's rounding.
///
/// The caller guarantees `acc · 2^max(shift, 0)` fits i32 (the kernels check it through
/// [`Requant::fits`]); if it does not, the product wraps instead of panicking.
#[inline(always)]
pub fn multiply_by_quantized_multiplier(acc: i32, multiplier: i32, shift: i32) -> i32 {
    let left = if shift > 0 { shift as u32 } else { 0 };
    let right = if shift < 0 { shift.wrapping_neg() } else { 0 };
    let x = srdhm(acc.wrapping_shl(left.min(31)), multiplier);
    rounding_divide_by_pot(x, right)
}

/// Largest `|acc · 2^left|` for which [`FastRequant`] equals [`Requant::apply`] (exclusive).
pub const FAST_LIMIT: i64 = 1 << 30;

/// A [`Requant`] prepared for inner loops: the same result as [`Requant::apply`] for every
/// accumulator with `|acc · 2^left| < `[`FAST_LIMIT`] (the kernels prove that from their
/// worst-case accumulator, see [`Requant::fits_fast`]), in about 10 instructions on
/// Cortex-M7 instead of about 25.
///
/// Why it is exact: `SRDHM(a, b) = floor((a·b + 2^30) / 2^31)` for every `(a, b)` but
/// `(MIN, MIN)` (for `a·b < 0` truncating `(a·b + 1 − 2^30) / 2^31` toward zero is the same
/// ceiling), and `RDBPOT(x, e) = floor((x + 2^(e−1) − [x < 0]) / 2^e)` for `e ≥ 1` (the
/// remainder test of the contract, folded into the floor). With `|a| < 2^30` and
/// `M < 2^31`, `|x| < 2^30`, so `x + 2^(e−1)` cannot overflow.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FastRequant {
    multiplier: i32,
    left: u32,
    right: u32,
    half: i32,
    /// −1 when `right > 0` (ties of negative values round away from zero), else 0.
    neg: i32,
}

impl FastRequant {
    /// Prepares `rq` (any shift; shifts are clamped like [`multiply_by_quantized_multiplier`]).
    #[inline(always)]
    pub const fn new(rq: Requant) -> Self {
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
        FastRequant {
            multiplier: rq.multiplier,
            left: if left > 31 { 31 } else { left },
            right,
            half: if right > 0 { 1 << (right - 1) } else { 0 },
            neg: if right > 0 { -1 } else { 0 },
        }
    }

    /// `MBQM(acc, M, shift)` for `|acc · 2^left| < FAST_LIMIT`; wraps (never panics) outside.
    #[inline(always)]
    pub fn apply(self, acc: i32) -> i32 {
        let a = acc.wrapping_shl(self.left);
        let x = ((a as i64 * self.multiplier as i64 + (1 << 30)) >> 31) as i32;
        x.wrapping_add(self.half).wrapping_add((x >> 31) & self.neg) >> self.right
    }
}

/// A requantisation the kernels can apply per output: [`Requant`] (always exact) or
/// [`FastRequant`] (exact within its proven range).
pub trait Apply: Copy {
    /// `MBQM(acc, M, shift)`.
    fn apply(self, acc: i32) -> i32;

    /// Whether [`Apply::words`] can be `Some`: a constant, so that the code of the whole-line
    /// paths is left out where it cannot run.
    const HAS_WORDS: bool = false;

    /// The five words [`crate::arch::requant_rows_s8`] takes (multiplier, left1, right, half,
    /// neg), if this requantisation is that row loop's arithmetic.
    #[inline(always)]
    fn words(self) -> Option<[i32; 5]> {
        None
    }

    /// A whole row of int8 outputs with step 1 (`out[i] = clamp(ReLU?(apply(acc[i]))
    /// +sat skip[out[i]])`) through a specialised loop, if this requantisation has one:
    /// returns false (nothing written) otherwise.
    #[inline(always)]
    fn row_s8(
        self,
        _acc: &[i32],
        _out: &mut [i8],
        _relu: bool,
        _skip: Option<&[i32; 256]>,
    ) -> bool {
        false
    }
}

impl Apply for Requant {
    #[inline(always)]
    fn apply(self, acc: i32) -> i32 {
        Requant::apply(self, acc)
    }
}

impl Apply for FastRequant {
    #[inline(always)]
    fn apply(self, acc: i32) -> i32 {
        FastRequant::apply(self, acc)
    }
}

impl Requant {
    /// True when every accumulator of magnitude at most `bound` keeps
    /// `|acc · 2^left| < `[`FAST_LIMIT`], so [`FastRequant`] gives this multiplier's exact
    /// results.
    pub const fn fits_fast(self, bound: i64) -> bool {
        if bound < 0 || bound >= FAST_LIMIT {
            return false;
        }
        let left = self.left_shift();
        if left >= 31 {
            return bound == 0;
        }
        (bound << left) < FAST_LIMIT
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The real-valued result of `acc · m`, rounded half away from zero, for exact
    /// power-of-two multipliers where SRDHM + RDBPOT must equal it.
    fn round_half_away(x: f64) -> i64 {
        libm::round(x) as i64
    }

    #[test]
    fn srdhm_rounds_half_away_and_saturates() {
        assert_eq!(srdhm(i32::MIN, i32::MIN), i32::MAX);
        // 2^30 · 2^30 / 2^31 = 2^29 exactly.
        assert_eq!(srdhm(1 << 30, 1 << 30), 1 << 29);
        // Ties go toward +∞: 1.5 → 2, −1.5 → −1, 0.5 → 1, −0.5 → 0.
        assert_eq!(srdhm(3, 1 << 30), 2);
        assert_eq!(srdhm(-3, 1 << 30), -1);
        assert_eq!(srdhm(1, 1 << 30), 1);
        assert_eq!(srdhm(-1, 1 << 30), 0);
        // Non-ties round to nearest: −1.75 → −2, −1.25 → −1.
        assert_eq!(srdhm(-7, 1 << 29), -2);
        assert_eq!(srdhm(-5, 1 << 29), -1);
    }

    #[test]
    fn rdbpot_matches_real_rounding() {
        for x in -1000..1000 {
            for e in 0..6 {
                let want = round_half_away(x as f64 / (1u32 << e) as f64);
                assert_eq!(rounding_divide_by_pot(x, e) as i64, want, "x={x} e={e}");
            }
        }
        assert_eq!(rounding_divide_by_pot(i32::MIN, 31), -1);
        assert_eq!(rounding_divide_by_pot(i32::MAX, 31), 1);
        assert_eq!(rounding_divide_by_pot(5, 99), rounding_divide_by_pot(5, 31));
    }

    #[test]
    fn mbqm_with_half_multiplier_is_halving_ties_up() {
        // m = 0.5 → M = 2^30, shift 0.
        let r = Requant::from_real(0.5).unwrap();
        assert_eq!(
            r,
            Requant {
                multiplier: 1 << 30,
                shift: 0
            }
        );
        for acc in -5000..5000 {
            // SRDHM alone: ties toward +∞.
            assert_eq!(
                r.apply(acc) as i64,
                libm::floor(acc as f64 * 0.5 + 0.5) as i64
            );
        }
    }

    #[test]
    fn from_real_round_trips_within_precision() {
        let mut m = 1.0e-6;
        while m < 1000.0 {
            let r = Requant::from_real(m).unwrap();
            assert!((1 << 30..=i32::MAX).contains(&r.multiplier), "m={m}");
            let back = r.multiplier as f64 * libm::pow(2.0, (r.shift - 31) as f64);
            assert!((back - m).abs() <= m * 1e-9, "m={m} back={back}");
            m *= 1.37;
        }
        assert_eq!(Requant::from_real(0.0), Some(Requant::default()));
        assert_eq!(Requant::from_real(-1.0), None);
        assert_eq!(Requant::from_real(f64::NAN), None);
        assert_eq!(Requant::from_real(1e30), None);
        assert_eq!(Requant::from_real(1e-30), Some(Requant::default()));
    }

    #[test]
    fn mbqm_close_to_real_product() {
        let mut m = 1.0e-4;
        while m < 8.0 {
            let r = Requant::from_real(m).unwrap();
            for acc in (-100_000..100_000).step_by(977) {
                if !r.fits(acc as i64 * if acc < 0 { -1 } else { 1 }) {
                    continue;
                }
                let want = acc as f64 * m;
                let got = r.apply(acc) as f64;
                // Two roundings (SRDHM, then RDBPOT): within one unit of the real product.
                assert!((got - want).abs() <= 1.0, "m={m} acc={acc} got={got}");
            }
            m *= 1.9;
        }
    }

    #[test]
    fn fits_checks_the_left_shift() {
        let r = Requant {
            multiplier: 1 << 30,
            shift: 4,
        };
        assert!(r.fits((1 << 27) - 1));
        assert!(!r.fits(1 << 27));
        assert!(!r.fits(-1));
        assert!(Requant::default().fits(i32::MAX as i64));
    }

    #[test]
    fn fast_requant_equals_mbqm_in_its_range() {
        let mut s = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            s.wrapping_mul(0x2545_f491_4f6c_dd1d)
        };
        let limit = FAST_LIMIT as i32;
        let edge_accs = [
            0,
            1,
            -1,
            limit - 1,
            -(limit - 1),
            1 << 20,
            -(1 << 20),
            3,
            -3,
        ];
        let edge_mults = [0, 1 << 30, i32::MAX, (1 << 30) + 1, i32::MAX - 1];
        for shift in MIN_SHIFT..=MAX_SHIFT {
            for &m in &edge_mults {
                let rq = Requant {
                    multiplier: m,
                    shift,
                };
                let f = FastRequant::new(rq);
                for &acc in &edge_accs {
                    if rq.fits_fast((acc as i64).abs()) {
                        assert_eq!(f.apply(acc), rq.apply(acc), "{rq:?} acc={acc}");
                    }
                }
            }
        }
        for _ in 0..2_000_000 {
            let r = next();
            let shift = (r % 62) as i32 - 31;
            let m = if r & (1 << 40) != 0 {
                (1 << 30) + ((r >> 8) % (1 << 30)) as i32
            } else {
                0
            };
            let rq = Requant {
                multiplier: m,
                shift,
            };
            // Accumulators of every magnitude up to the limit, ties included.
            let bits = (next() % 31) as u32;
            let mut acc = (next() % (1u64 << bits)) as i32;
            if r & (1 << 50) != 0 {
                acc = -acc;
            }
            if next() % 4 == 0 {
                acc &= !((1i32 << (next() % 12)) - 1); // many trailing zeros: ties
            }
            if !rq.fits_fast((acc as i64).abs()) {
                continue;
            }
            assert_eq!(
                FastRequant::new(rq).apply(acc),
                rq.apply(acc),
                "{rq:?} acc={acc}"
            );
        }
    }

    #[test]
    fn fits_fast_is_stricter_than_fits() {
        let r = Requant {
            multiplier: 1 << 30,
            shift: 2,
        };
        assert!(r.fits_fast((1 << 28) - 1));
        assert!(!r.fits_fast(1 << 28));
        assert!(r.fits(1 << 28));
        assert!(!Requant::default().fits_fast(FAST_LIMIT));
        assert!(Requant::default().fits_fast(FAST_LIMIT - 1));
    }
}
