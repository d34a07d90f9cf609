//! The MPS2-AN500 peripherals the firmware uses (Arm CMSDK APB timer, UART and the FPGA LED
//! register), its stack region and the semihosting command line: the only place with raw
//! register and memory access (the stack paint itself is `epssn_selftest::Stack`, shared with
//! the other boards). A port to another board (an STM32H7 module, say) replaces this file: see
//! `firmware/README.md`. The rest of the firmware sees the UART through
//! `embedded_io::{Read, Write, ReadReady}` and the LED through `embedded_hal::digital::OutputPin`.

use core::ptr::{read_volatile, write_volatile};

use epssn_selftest::Stack;

/// CMSDK APB timer 0: a 32-bit down-counter clocked at the 25 MHz peripheral clock.
const TIMER0: usize = 0x4000_0000;
/// FPGA system control: LED register (bit 0 = LED0).
const FPGAIO_LED: usize = 0x4002_8000;
/// CMSDK APB UART 0 (QEMU connects it to the first `-serial`).
const UART0: usize = 0x4000_4000;
/// Start of the data SRAM (the RAM region of memory.x).
const RAM_ORIGIN: usize = 0x2000_0000;
/// CMSDK APB watchdog (QEMU's mps2-an500 maps `cmsdk-apb-watchdog` here, clocked by the
/// 25 MHz system clock, its interrupt wired to the NMI).
const WDOG: usize = 0x4000_8000;
const WDOG_LOAD: usize = 0x000;
const WDOG_CTRL: usize = 0x008;
const WDOG_INTCLR: usize = 0x00C;
const WDOG_LOCK: usize = 0xC00;
const WDOG_UNLOCK_KEY: u32 = 0x1ACC_E551;
const WDOG_CTRL_INTEN: u32 = 1 << 0;
const WDOG_CTRL_RESEN: u32 = 1 << 1;

fn write_reg(addr: usize, value: u32) {
    // SAFETY: `addr` is one of the fixed, aligned MMIO registers above, present on the
    // MPS2-AN500; the firmware is single-threaded and owns every peripheral.
    unsafe { write_volatile(addr as *mut u32, value) }
}

fn read_reg(addr: usize) -> u32 {
    // SAFETY: as in `write_reg`.
    unsafe { read_volatile(addr as *const u32) }
}

/// A free-running tick counter on CMSDK timer 0.
///
/// Under `qemu-system-arm -icount shift=0` one guest instruction is one nanosecond of virtual
/// time, so one 25 MHz tick is 40 instructions: the cost figures of this firmware are
/// repeatable instruction counts, not wall-clock times.
pub struct TickCounter;

impl TickCounter {
    /// Starts the timer from its maximum value.
    pub fn start() -> Self {
        write_reg(TIMER0, 0); // CTRL: stop
        write_reg(TIMER0 + 0x8, u32::MAX); // RELOAD
        write_reg(TIMER0 + 0x4, u32::MAX); // VALUE
        write_reg(TIMER0, 1); // CTRL: enable
        TickCounter
    }

    /// Ticks since start (wraps after 2^32 ticks, about 170 s of virtual time).
    pub fn now(&self) -> u32 {
        u32::MAX - read_reg(TIMER0 + 0x4)
    }

    /// QEMU instructions per timer tick under `-icount shift=0` at the 25 MHz timer clock.
    pub const INSTRUCTIONS_PER_TICK: u32 = 40;
}

/// The CMSDK watchdog: an NMI at the first timeout (the firmware records `watchdog` and
/// resets), a hardware reset at the second (RESEN: should the NMI itself not get to run).
///
/// Timeout: a depth map costs at most 48,000,000 instructions (weights/budgets.json), 48 ms of
/// virtual time under `-icount shift=0` (1 ns per instruction), and the serving loop feeds the
/// watchdog once per pass, so one pass takes at most one frame's map plus its reply. The first
/// timeout is 4 times that, 200 ms (5,000,000 ticks at 25 MHz); the reset follows 200 ms later.
pub struct Watchdog;

impl Watchdog {
    /// Ticks of the 25 MHz watchdog clock to the first timeout.
    pub const TIMEOUT_TICKS: u32 = 5_000_000;

    /// Arms the watchdog and locks its registers.
    pub fn start() -> Self {
        write_reg(WDOG + WDOG_LOCK, WDOG_UNLOCK_KEY);
        write_reg(WDOG + WDOG_LOAD, Self::TIMEOUT_TICKS);
        write_reg(WDOG + WDOG_CTRL, WDOG_CTRL_INTEN | WDOG_CTRL_RESEN);
        write_reg(WDOG + WDOG_LOCK, 0);
        Watchdog
    }

    /// Restarts the count from the timeout (INTCLR reloads the counter).
    pub fn feed(&self) {
        write_reg(WDOG + WDOG_LOCK, WDOG_UNLOCK_KEY);
        write_reg(WDOG + WDOG_INTCLR, 1);
        write_reg(WDOG + WDOG_LOCK, 0);
    }
}

// The watchdog's NMI: the shared fault entry with cause `watchdog` (it takes the stacked PC of
// the loop that stopped feeding, then resets; `epssn_selftest::reset`).
core::arch::global_asm!(
    ".section .text.NonMaskableInt,\"ax\",%progbits",
    ".global NonMaskableInt",
    ".type NonMaskableInt,%function",
    ".thumb_func",
    "NonMaskableInt:",
    "    movs r0, #{watchdog}",
    "    b epssn_fault_entry",
    ".size NonMaskableInt, . - NonMaskableInt",
    watchdog = const epssn::fault::ResetCause::Watchdog as u32,
);

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
