//! The single ARMv7E-M DSP instructions the kernels name (`SMLAD`, `SXTB16`, `SMMULR`): with
//! the `dsp` feature on ARM each is its one instruction through `core::arch::asm!` (the
//! intrinsics in `core::arch::arm` are unstable), everywhere else plain Rust with the
//! instruction's exact semantics. One macro writes them all, so the choice between the two is
//! made in one place; both backends and the portable loops use them.

/// `instructions! { doc fn name(args) -> T = "template" [options] else { plain Rust } … }`:
/// each `name` is the template's one instruction (operands `{r}` for the result, the
/// arguments by name, all in registers) in `dsp` builds on ARM, the plain block elsewhere.
/// Every template is a register-to-register instruction: no memory access, no stack.
macro_rules! instructions {
    ($(
        $(#[$doc:meta])*
        fn $name:ident($($arg:ident: $ty:ty),*) -> $ret:ty
            = $insn:literal [$($opt:ident),*] else $plain:block
    )*) => {$(
        $(#[$doc])*
        #[inline(always)]
        pub fn $name($($arg: $ty),*) -> $ret {
            #[cfg(all(feature = "dsp", target_arch = "arm"))]
            {
                let r: $ret;
                // SAFETY: a pure register-to-register instruction of ARMv7E-M; no memory access.
                #[allow(unsafe_code)]
                unsafe {
                    core::arch::asm!(
                        $insn,
                        r = lateout(reg) r,
                        $($arg = in(reg) $arg,)*
                        options(pure, nomem, nostack $(, $opt)*),
                    );
                }
                r
            }
            #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
            $plain
        }
    )*};
}

instructions! {
    /// `SMLAD`: `acc + lo(x)·lo(y) + hi(x)·hi(y)` on signed 16-bit halves, wrapping like the
    /// instruction (the kernels' accumulator bounds exclude overflow anyway). It sets the Q
    /// flag on overflow, so the flags are not preserved.
    fn smlad(x: u32, y: u32, acc: i32) -> i32 = "smlad {r}, {x}, {y}, {acc}" [] else {
        let lo = (x as u16 as i16 as i32) * (y as u16 as i16 as i32);
        let hi = ((x >> 16) as u16 as i16 as i32) * ((y >> 16) as u16 as i16 as i32);
        acc.wrapping_add(lo).wrapping_add(hi)
    }

    /// `SXTB16`: sign-extends bytes 0 and 2 of `x` into the two 16-bit halves.
    fn sxtb16(x: u32) -> u32 = "sxtb16 {r}, {x}" [preserves_flags] else {
        let b0 = x as u8 as i8 as i16 as u16 as u32;
        let b2 = (x >> 16) as u8 as i8 as i16 as u16 as u32;
        b0 | (b2 << 16)
    }

    /// `SXTB16 …, ROR #8`: sign-extends bytes 1 and 3 of `x` into the two 16-bit halves.
    fn sxtb16_ror8(x: u32) -> u32 = "sxtb16 {r}, {x}, ror #8" [preserves_flags] else {
        sxtb16(x.rotate_right(8))
    }

    /// `SMMULR`: `(x·y + 2^31) >> 32`, the high word of the product rounded (signed).
    fn smmulr(x: i32, y: i32) -> i32 = "smmulr {r}, {x}, {y}" [preserves_flags] else {
        ((x as i64 * y as i64 + (1 << 31)) >> 32) as i32
    }
}

/// Two i16 values as one word, `a` in the low half.
#[inline(always)]
pub fn pack(a: i16, b: i16) -> u32 {
    (a as u16 as u32) | ((b as u16 as u32) << 16)
}
