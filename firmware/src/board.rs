//! The MPS2-AN500 peripherals the firmware uses (Arm CMSDK APB timer, UART and the FPGA LED
//! register), its stack region and the semihosting command line: the only place with raw
//! register and memory access (the stack paint itself is `epssn_selftest::Stack`, shared with
//! the other boards). A port to another board (an STM32H7 module, say) replaces this file: see
//! `firmware/README.md`. The rest of the firmware sees the UART through
//! `embedded_io::{Read, Write, ReadReady}` and the LED through `embedded_hal::digital::OutputPin`.

use core::ptr::{read_volatile, write_volatile};

use embedded_hal::digital::{ErrorType, OutputPin};
use epssn_selftest::Stack;

/// CMSDK APB timer 0: a 32-bit down-counter clocked at the 25 MHz peripheral clock.
const TIMER0: usize = 0x4000_0000;
/// FPGA system control: LED register (bit 0 = LED0).
const FPGAIO_LED: usize = 0x4002_8000;
/// CMSDK APB UART 0 (QEMU connects it to the first `-serial`).
const UART0: usize = 0x4000_4000;
const UART_DATA: usize = 0x0;
const UART_STATE: usize = 0x4;
const UART_CTRL: usize = 0x8;
const UART_BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
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
pub struct BusyLed;

impl ErrorType for BusyLed {
    type Error = core::convert::Infallible;
}

impl OutputPin for BusyLed {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        write_reg(FPGAIO_LED, read_reg(FPGAIO_LED) & !1);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Self::Error> {
        write_reg(FPGAIO_LED, read_reg(FPGAIO_LED) | 1);
        Ok(())
    }
}

/// UART0 of the board (CMSDK APB UART), polled: one byte in each direction at a time.
pub struct Uart0;

impl Uart0 {
    /// Enables transmitter and receiver. The baud divisor is the smallest the CMSDK UART
    /// accepts (16); QEMU does not model the bit rate.
    pub fn new() -> Self {
        write_reg(UART0 + UART_BAUDDIV, 16);
        write_reg(UART0 + UART_CTRL, CTRL_TX_EN | CTRL_RX_EN);
        Uart0
    }

    fn rx_full() -> bool {
        read_reg(UART0 + UART_STATE) & STATE_RX_FULL != 0
    }
}

impl embedded_io::ErrorType for Uart0 {
    type Error = core::convert::Infallible;
}

impl embedded_io::Read for Uart0 {
    /// Blocks until a byte arrives, then takes what is already there.
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        if buf.is_empty() {
            return Ok(0);
        }
        while !Self::rx_full() {}
        let mut n = 0;
        for slot in buf.iter_mut() {
            if !Self::rx_full() {
                break;
            }
            *slot = read_reg(UART0 + UART_DATA) as u8;
            n += 1;
        }
        Ok(n)
    }
}

impl embedded_io::ReadReady for Uart0 {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(Self::rx_full())
    }
}

impl embedded_io::Write for Uart0 {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            while read_reg(UART0 + UART_STATE) & STATE_TX_FULL != 0 {}
            write_reg(UART0 + UART_DATA, u32::from(b));
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        while read_reg(UART0 + UART_STATE) & STATE_TX_FULL != 0 {}
        Ok(())
    }
}

/// The stack, for its paint and high-water mark (the implementation every board shares).
pub fn stack() -> Stack {
    // SAFETY: RAM_ORIGIN is the origin of memory.x's RAM region, which cortex-m-rt (through
    // flip-link) puts this image's stack in.
    unsafe { Stack::new(RAM_ORIGIN) }
}

/// True when the semihosting command line (QEMU `-semihosting-config ...,arg=...`) has the
/// word `word`.
pub fn command_line_has(word: &str) -> bool {
    let mut buf = [0u8; 128];
    let mut block = [buf.as_mut_ptr() as usize, buf.len()];
    // SAFETY: SYS_GET_CMDLINE writes at most `buf.len()` bytes into `buf` and the length
    // into `block[1]`; both outlive the call.
    let r = unsafe {
        cortex_m_semihosting::syscall1(
            cortex_m_semihosting::nr::GET_CMDLINE,
            block.as_mut_ptr() as usize,
        )
    };
    if r != 0 {
        return false;
    }
    let n = block[1].min(buf.len());
    core::str::from_utf8(&buf[..n])
        .map(|s| s.split_ascii_whitespace().any(|w| w == word))
        .unwrap_or(false)
}
