//! The stack paint every board reports (the boot self-test's high-water line, the link's
//! status replies): one implementation for all boards, the only code of this crate with raw
//! memory access. A board names its RAM region's origin; the rest comes from cortex-m-rt's
//! linker symbols, which every epssn board links with (through flip-link).

use core::ptr::{addr_of, read_volatile, write_volatile};

extern "C" {
    /// Initial stack pointer (top of the stack), from cortex-m-rt's link.x.
    static _stack_start: u32;
    /// End of the static RAM sections; the stack's lower limit without flip-link.
    static _stack_end: u32;
}

/// What an unused stack word holds after [`Stack::paint`].
const PAINT: u32 = 0xDEAD_C0DE;

/// Bytes left unpainted under the frame of [`Stack::paint`] itself.
const MARGIN: usize = 64;

/// The stack region `[bottom, top)` of the running image, word-aligned.
#[derive(Clone, Copy, Debug)]
pub struct Stack {
    bottom: usize,
    top: usize,
}

impl Stack {
    /// The stack of an image linked by cortex-m-rt whose RAM region (memory.x) starts at
    /// `ram_origin`: below the statics with cortex-m-rt's default layout, from the start of
    /// RAM up to the statics with flip-link (which moves the stack down).
    ///
    /// # Safety
    ///
    /// `ram_origin` must be the origin of the RAM region this image was linked with, the one
    /// cortex-m-rt puts the stack in: [`Stack::paint`] writes from there (with flip-link) up to
    /// the stack pointer.
    pub unsafe fn new(ram_origin: usize) -> Self {
        let top = addr_of!(_stack_start) as usize;
        let end = addr_of!(_stack_end) as usize;
        let bottom = if end < top { end } else { ram_origin };
        Self {
            bottom: (bottom + 3) & !3,
            top: top & !3,
        }
    }

    /// Paints the unused stack below the current stack pointer, for [`Stack::high_water`].
    /// Call first thing in `main`. Not inlined: its margin is measured from its own frame.
    #[inline(never)]
    pub fn paint(&self) {
        let sp = cortex_m::register::msp::read() as usize & !3;
        let end = sp.saturating_sub(MARGIN);
        let mut addr = self.bottom;
        while addr < end {
            // SAFETY: `[bottom, sp − MARGIN)` is stack below every live frame (`new`'s
            // contract makes `bottom` the stack's lower end), so no live data is there: an
            // interrupt handler runs on this stack below the interrupted frame and is done
            // before this loop resumes. The addresses are word-aligned RAM.
            unsafe { write_volatile(addr as *mut u32, PAINT) };
            addr += 4;
        }
    }

    /// Bytes of stack ever used since [`Stack::paint`]: the top minus the lowest word that no
    /// longer holds the paint.
    pub fn high_water(&self) -> u32 {
        let mut addr = self.bottom;
        // SAFETY: reads only, of word-aligned stack RAM from the bottom up to the first word
        // that lost its paint: at or below the deepest frame ever used, never past the top.
        while addr < self.top && unsafe { read_volatile(addr as *const u32) } == PAINT {
            addr += 4;
        }
        (self.top - addr) as u32
    }

    /// Bytes of the stack region.
    pub fn size(&self) -> u32 {
        (self.top - self.bottom) as u32
    }
}
