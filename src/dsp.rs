//! ARMv7E-M DSP instructions (Cortex-M4/M7) for the convolution inner loops, with portable
//! fallbacks that give the same bits.
//!
//! With the `dsp` cargo feature on an ARM target the functions are single `SMLAD` /
//! `SXTB16` instructions through `core::arch::asm!` (the only `unsafe` in the crate; the
//! intrinsics in `core::arch::arm` are unstable). Everywhere else they are plain Rust with
//! the instructions' exact semantics, so the host tests exercise the same data flow.

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

/// Two i16 values as one word, `a` in the low half.
#[inline(always)]
pub fn pack(a: i16, b: i16) -> u32 {
    (a as u16 as u32) | ((b as u16 as u32) << 16)
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
