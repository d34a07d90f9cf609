//! What the QEMU boards share: the Arm CMSDK peripherals at the addresses each board gives
//! (the APB UART, polled, through `embedded_io`; an FPGA IO LED bit, through `embedded_hal`;
//! any peripheral's registers by offset, [`Registers`]), the semihosting command line, and
//! their main ([`boot::run`]: the boot self-test, then the link server). `boards/mps2-an500`
//! (Cortex-M7) and `boards/mps3-an547` (Cortex-M55) have the same peripherals at different
//! addresses; this crate is their one copy, and their crates hold only what differs (clock,
//! watchdog, addresses).

#![no_std]
#![deny(missing_docs)]
#![deny(unsafe_op_in_unsafe_fn)]

pub mod boot;
#[cfg(feature = "updates")]
pub mod update;

use core::ptr::{read_volatile, write_volatile};

use embedded_hal::digital::{ErrorType, OutputPin};

const UART_DATA: usize = 0x0;
const UART_STATE: usize = 0x4;
const UART_CTRL: usize = 0x8;
const UART_BAUDDIV: usize = 0x10;
const STATE_TX_FULL: u32 = 1 << 0;
const STATE_RX_FULL: u32 = 1 << 1;
const CTRL_TX_EN: u32 = 1 << 0;
const CTRL_RX_EN: u32 = 1 << 1;

fn write_reg(addr: usize, value: u32) {
    // SAFETY: every caller passes a register of a peripheral whose constructor's contract
    // (`Registers::new`, `Uart::new`, `FpgaLed::new`) says it is present, aligned and owned by
    // this firmware alone.
    unsafe { write_volatile(addr as *mut u32, value) }
}

fn read_reg(addr: usize) -> u32 {
    // SAFETY: as in `write_reg`.
    unsafe { read_volatile(addr as *const u32) }
}

/// The 32-bit registers of a peripheral block at `BASE`, by offset from it: volatile reads and
/// writes, at the fixed addresses a hand-written driver would use.
pub struct Registers<const BASE: usize>(());

impl<const BASE: usize> Registers<BASE> {
    /// # Safety
    ///
    /// `BASE` is the address of a peripheral block of this board that nothing else drives, and
    /// every offset its owner passes to [`Registers::read`] and [`Registers::write`] is one of
    /// that block's registers (present and word-aligned).
    pub const unsafe fn new() -> Self {
        Registers(())
    }

    /// Writes `value` to the register at `offset`.
    pub fn write(&self, offset: usize, value: u32) {
        write_reg(BASE + offset, value);
    }

    /// Reads the register at `offset`.
    pub fn read(&self, offset: usize) -> u32 {
        read_reg(BASE + offset)
    }
}

/// A CMSDK APB UART at `BASE`, polled: one byte in each direction at a time. The base is a
/// type parameter, so the driver compiles to the fixed addresses a hand-written one would.
pub struct Uart<const BASE: usize>(());

impl<const BASE: usize> Uart<BASE> {
    /// Enables transmitter and receiver. The baud divisor is the smallest the CMSDK UART
    /// accepts (16); QEMU does not model the bit rate.
    ///
    /// # Safety
    ///
    /// `BASE` is the address of a CMSDK APB UART of this board that nothing else drives.
    pub unsafe fn new() -> Self {
        write_reg(BASE + UART_BAUDDIV, 16);
        write_reg(BASE + UART_CTRL, CTRL_TX_EN | CTRL_RX_EN);
        Uart(())
    }

    fn rx_full() -> bool {
        read_reg(BASE + UART_STATE) & STATE_RX_FULL != 0
    }

    fn tx_full() -> bool {
        read_reg(BASE + UART_STATE) & STATE_TX_FULL != 0
    }
}

impl<const BASE: usize> embedded_io::ErrorType for Uart<BASE> {
    type Error = core::convert::Infallible;
}

impl<const BASE: usize> embedded_io::Read for Uart<BASE> {
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
            *slot = read_reg(BASE + UART_DATA) as u8;
            n += 1;
        }
        Ok(n)
    }
}

impl<const BASE: usize> embedded_io::ReadReady for Uart<BASE> {
    fn read_ready(&mut self) -> Result<bool, Self::Error> {
        Ok(Self::rx_full())
    }
}

impl<const BASE: usize> embedded_io::Write for Uart<BASE> {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &b in buf {
            while Self::tx_full() {}
            write_reg(BASE + UART_DATA, u32::from(b));
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        while Self::tx_full() {}
        Ok(())
    }
}

/// Bit 0 of the FPGA IO LED register at `REG` (LED0), as an output pin.
pub struct FpgaLed<const REG: usize>(());

impl<const REG: usize> FpgaLed<REG> {
    /// # Safety
    ///
    /// `REG` is the address of this board's FPGA IO LED register, which nothing else drives.
    pub const unsafe fn new() -> Self {
        FpgaLed(())
    }
}

impl<const REG: usize> ErrorType for FpgaLed<REG> {
    type Error = core::convert::Infallible;
}

impl<const REG: usize> OutputPin for FpgaLed<REG> {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        write_reg(REG, read_reg(REG) & !1);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Self::Error> {
        write_reg(REG, read_reg(REG) | 1);
        Ok(())
    }
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
