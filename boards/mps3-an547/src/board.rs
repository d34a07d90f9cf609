//! The MPS3-AN547 peripherals the Cortex-M55 firmware uses (the SSE-300 system counter, the
//! CMSDK APB UART and the FPGA IO LED register), its stack region and the semihosting command
//! line: the only place with raw register and memory access. Addresses from QEMU 7.2's
//! `hw/arm/mps2-tz.c` (AN547 PPC ports) and `hw/arm/armsse.c` (SSE-300): the SAU is off, so
//! every access is Secure and the Non-secure aliases (0x4xxx_xxxx) reach the devices, which the
//! PPCs leave Secure at reset. The rest of the firmware is `firmware/`'s, unchanged.

use core::ptr::{read_volatile, write_volatile};

use embedded_hal::digital::{ErrorType, OutputPin};
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
const UART_DATA: usize = 0x0;
const UART_STATE: usize = 0x4;
const UART_CTRL: usize = 0x8;
const UART_BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;
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
