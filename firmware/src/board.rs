//! The MPS2-AN500 peripherals the firmware uses (Arm CMSDK APB timer, UART and the FPGA LED
//! register), the only place with raw register access. A port to another board (an STM32H7
//! module, say) replaces this file: see `firmware/README.md`.

use core::ptr::{read_volatile, write_volatile};

use embedded_hal::digital::{ErrorType, OutputPin};

/// CMSDK APB timer 0: a 32-bit down-counter clocked at the 25 MHz peripheral clock.
const TIMER0: usize = 0x4000_0000;
/// FPGA system control: LED register (bit 0 = LED0).
const FPGAIO_LED: usize = 0x4002_8000;

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
