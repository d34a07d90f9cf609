//! What the MPS3-AN547 has of its own under the QEMU boards' shared main
//! (`epssn_cmsdk::boot`): the addresses of its CMSDK peripherals and its clock (the SSE-300
//! system counter). Addresses from QEMU 7.2's `hw/arm/mps2-tz.c` (AN547 PPC ports) and
//! `hw/arm/armsse.c` (SSE-300): the SAU is off, so every access is Secure and the Non-secure
//! aliases (0x4xxx_xxxx) reach the devices, which the PPCs leave Secure at reset.

use epssn_cmsdk::Registers;

/// SSE-300 system counter, control frame (Secure only): CNTCR, CNTCV, CNTSCR.
// SAFETY: 0x5810_0000 is the SSE-300 system counter's control frame (the offsets below);
// only `TickCounter` drives it.
const SYSCTR: Registers<0x5810_0000> = unsafe { Registers::new() };
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

/// The peripherals the shared main drives, at this board's addresses.
pub type Peripherals = epssn_cmsdk::boot::Peripherals<UART0, FPGAIO_LED>;

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
        SYSCTR.write(CNTCR, 0);
        SYSCTR.write(CNTSCR, NS_PER_MAINCLK_8_24);
        SYSCTR.write(CNTCV_LO, 0);
        SYSCTR.write(CNTCV_LO + 4, 0);
        SYSCTR.write(CNTCR, CNTCR_EN | CNTCR_SCEN);
        TickCounter
    }
}

/// The board under the shared main: no watchdog or fault record (yet), only its clock.
impl epssn_cmsdk::boot::Board for TickCounter {
    /// The counter is scaled to count instructions.
    const INSTRUCTIONS_PER_TICK: u32 = 1;
    /// 100 ms of virtual time, one tick per nanosecond.
    const IDLE_TICKS: u32 = 100_000_000;

    /// Instructions since start (the low word of the count: wraps after 2^32, about 4.3 s of
    /// virtual time; the callers take wrapping differences over far shorter spans).
    fn now(&self) -> u32 {
        SYSCTR.read(CNTCV_LO)
    }
}
