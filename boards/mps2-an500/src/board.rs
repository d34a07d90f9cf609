//! What the MPS2-AN500 has of its own under the QEMU boards' shared main
//! (`epssn_cmsdk::boot`): the addresses of its CMSDK peripherals, its clock (CMSDK APB timer
//! 0) and its watchdog (CMSDK APB watchdog, the NMI into the shared fault entry). A port to
//! another board replaces this file: see `README.md`.

use epssn_cmsdk::Registers;

/// CMSDK APB timer 0: a 32-bit down-counter clocked at the 25 MHz peripheral clock.
// SAFETY: 0x4000_0000 is the MPS2-AN500's CMSDK APB timer 0 (CTRL 0x0, VALUE 0x4, RELOAD
// 0x8); only `TickCounter` drives it.
const TIMER0: Registers<0x4000_0000> = unsafe { Registers::new() };
const TIMER_CTRL: usize = 0x0;
const TIMER_VALUE: usize = 0x4;
const TIMER_RELOAD: usize = 0x8;
/// FPGA system control: LED register (bit 0 = LED0).
const FPGAIO_LED: usize = 0x4002_8000;
/// CMSDK APB UART 0 (QEMU connects it to the first `-serial`).
const UART0: usize = 0x4000_4000;
/// CMSDK APB watchdog (QEMU's mps2-an500 maps `cmsdk-apb-watchdog` here, clocked by the
/// 25 MHz system clock, its interrupt wired to the NMI).
// SAFETY: 0x4000_8000 is the MPS2-AN500's CMSDK APB watchdog (the offsets below); only
// `Watchdog` drives it.
const WDOG: Registers<0x4000_8000> = unsafe { Registers::new() };
const WDOG_LOAD: usize = 0x000;
const WDOG_CTRL: usize = 0x008;
const WDOG_INTCLR: usize = 0x00C;
const WDOG_LOCK: usize = 0xC00;
const WDOG_UNLOCK_KEY: u32 = 0x1ACC_E551;
const WDOG_CTRL_INTEN: u32 = 1 << 0;
const WDOG_CTRL_RESEN: u32 = 1 << 1;

/// The peripherals the shared main drives, at this board's addresses.
pub type Peripherals = epssn_cmsdk::boot::Peripherals<UART0, FPGAIO_LED>;

/// A free-running tick counter on CMSDK timer 0.
///
/// Under `qemu-system-arm -icount shift=0` one guest instruction is one nanosecond of virtual
/// time, so one 25 MHz tick is 40 instructions: the cost figures of this firmware are
/// repeatable instruction counts, not wall-clock times.
pub struct TickCounter;

impl TickCounter {
    /// Starts the timer from its maximum value.
    pub fn start() -> Self {
        TIMER0.write(TIMER_CTRL, 0); // stop
        TIMER0.write(TIMER_RELOAD, u32::MAX);
        TIMER0.write(TIMER_VALUE, u32::MAX);
        TIMER0.write(TIMER_CTRL, 1); // enable
        TickCounter
    }

    /// Ticks since start (wraps after 2^32 ticks, about 170 s of virtual time).
    pub fn now(&self) -> u32 {
        u32::MAX - TIMER0.read(TIMER_VALUE)
    }
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
        WDOG.write(WDOG_LOCK, WDOG_UNLOCK_KEY);
        WDOG.write(WDOG_LOAD, Self::TIMEOUT_TICKS);
        WDOG.write(WDOG_CTRL, WDOG_CTRL_INTEN | WDOG_CTRL_RESEN);
        WDOG.write(WDOG_LOCK, 0);
        Watchdog
    }

    /// Restarts the count from the timeout (INTCLR reloads the counter).
    pub fn feed(&self) {
        WDOG.write(WDOG_LOCK, WDOG_UNLOCK_KEY);
        WDOG.write(WDOG_INTCLR, 1);
        WDOG.write(WDOG_LOCK, 0);
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

/// The board under the shared main: its clock and its watchdog.
pub struct Mps2An500 {
    /// Armed first thing at boot.
    pub watchdog: Watchdog,
    /// The instruction clock.
    pub clock: TickCounter,
}

impl epssn_cmsdk::boot::Board for Mps2An500 {
    /// QEMU instructions per timer tick under `-icount shift=0` at the 25 MHz timer clock.
    const INSTRUCTIONS_PER_TICK: u32 = 40;
    /// 100 ms of virtual time at 25 MHz.
    const IDLE_TICKS: u32 = 2_500_000;
    /// The panic handler, the HardFault entry and the watchdog's NMI write the record.
    const FAULT_RECORD: bool = true;

    fn now(&self) -> u32 {
        self.clock.now()
    }

    fn feed(&self) {
        self.watchdog.feed();
    }

    fn update_partition(&self) -> Option<(epssn_cmsdk::update::Sram, fn() -> !)> {
        extern "C" {
            // The memory map's `UPDATE` region (memory.x): RAM that nothing loads.
            static mut _update_start: u8;
            static _update_end: u8;
        }
        let start = &raw mut _update_start;
        let len = (&raw const _update_end as usize).saturating_sub(start as usize);
        // SAFETY: `UPDATE` is a region of the code SRAM that no section is placed in and
        // nothing but this partition uses; this is called once, at boot.
        let sram = unsafe { epssn_cmsdk::update::Sram::new(start, len) };
        Some((sram, cortex_m::peripheral::SCB::sys_reset))
    }
}
