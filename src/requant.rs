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
}
