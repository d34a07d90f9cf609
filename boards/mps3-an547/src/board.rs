//! The MPS3-AN547 peripherals the Cortex-M55 firmware uses (the SSE-300 system counter, the
//! CMSDK APB UART and the FPGA IO LED register), its stack region and the semihosting command
//! line: the only place with raw register and memory access. Addresses from QEMU 7.2's
//! `hw/arm/mps2-tz.c` (AN547 PPC ports) and `hw/arm/armsse.c` (SSE-300): the SAU is off, so
//! every access is Secure and the Non-secure aliases (0x4xxx_xxxx) reach the devices, which the
//! PPCs leave Secure at reset. The rest of the firmware is `firmware/`'s, unchanged.

use core::ptr::{read_volatile, write_volatile};

use epssn_selftest::Stack;

/// SSE-300 system counter, control frame (Secure only): CNTCR, CNTCV, CNTSCR.
const SYSCTR: usize = 0x5810_0000;
const CNTCR: usize = 0x0;
const CNTCV_LO: usize = 0x8;
const CNTSCR: usize = 0x10;
const CNTCR_EN: u32 = 1 << 0;
const CNTCR_SCEN: u32 = 1 << 2;
/// The counter's increment per MAINCLK tick, 8.24 fixed point: MAINCLK is 32 MHz (31.25 ns),
/// so 31.25 makes CNTCV count nanoseconds of virtual time (31.25 · 2^24 = 0x1F40_0000).
const NS_PER_MAINCLK_8_24: u32 = 0x1F40_0000;
/// FPGA IO: LED register (bit 0 = LED0).
const FPGAIO_LED: usize = 0x4930_2000;
/// CMSDK APB UART 0 (QEMU connects it to the first `-serial`).
const UART0: usize = 0x4930_3000;
/// Start of the DTCM (the RAM region of memory.x).
const RAM_ORIGIN: usize = 0x2000_0000;

fn write_reg(addr: usize, value: u32) {
    // SAFETY: `addr` is one of the fixed, aligned MMIO registers above, present on the
    // MPS3-AN547; the firmware is single-threaded and owns every peripheral.
    unsafe { write_volatile(addr as *mut u32, value) }
}

fn read_reg(addr: usize) -> u32 {
    // SAFETY: as in `write_reg`.
    unsafe { read_volatile(addr as *const u32) }
}

/// A free-running instruction counter on the SSE-300 system counter.
///
/// Under `qemu-system-arm -icount shift=0` one guest instruction is one nanosecond of virtual
/// time; scaled by 31.25 per 32 MHz tick the counter counts nanoseconds, so its readings are
/// instruction counts (to within one tick, 31.25 instructions), not wall-clock times.
pub struct TickCounter;

impl TickCounter {
    /// Starts the counter from zero with the nanosecond scale (the scale is written while
    /// the counter is stopped, as the SSE-300 requires).
    pub fn start() -> Self {
        write_reg(SYSCTR + CNTCR, 0);
        write_reg(SYSCTR + CNTSCR, NS_PER_MAINCLK_8_24);
        write_reg(SYSCTR + CNTCV_LO, 0);
        write_reg(SYSCTR + CNTCV_LO + 4, 0);
        write_reg(SYSCTR + CNTCR, CNTCR_EN | CNTCR_SCEN);
        TickCounter
    }

    /// Instructions since start (the low word of the count: wraps after 2^32, about 4.3 s of
    /// virtual time; the callers take wrapping differences over far shorter spans).
    pub fn now(&self) -> u32 {
        read_reg(SYSCTR + CNTCV_LO)
    }

    /// Instructions per tick of [`TickCounter::now`]: the counter is scaled to count them.
    pub const INSTRUCTIONS_PER_TICK: u32 = 1;
}

/// LED0 of the board, lit while the co-processor is computing a depth map.
pub type BusyLed = epssn_cmsdk::FpgaLed<FPGAIO_LED>;

/// The busy LED.
pub fn busy_led() -> BusyLed {
    // SAFETY: FPGAIO_LED is this board's FPGA IO LED register; only this firmware drives it.
    unsafe { BusyLed::new() }
}

/// UART0 of the board (CMSDK APB UART; QEMU connects it to the first `-serial`).
pub type Uart0 = epssn_cmsdk::Uart<UART0>;

/// UART0, enabled.
pub fn uart0() -> Uart0 {
    // SAFETY: UART0 is this board's CMSDK APB UART 0; only the serving loop drives it.
    unsafe { Uart0::new() }
}

pub use epssn_cmsdk::command_line_has;

/// The stack, for its paint and high-water mark (the implementation every board shares).
pub fn stack() -> Stack {
    // SAFETY: RAM_ORIGIN is the origin of memory.x's RAM region, which cortex-m-rt (through
    // flip-link) puts this image's stack in.
    unsafe { Stack::new(RAM_ORIGIN) }
}
