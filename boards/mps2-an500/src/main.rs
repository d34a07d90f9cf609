//! epssn co-processor firmware for a Cortex-M7 (QEMU `mps2-an500`): the QEMU boards' shared
//! main (`epssn_cmsdk::boot`: the boot self-test, then the link server) on this board's
//! peripherals, clock and watchdog (`board.rs`).

#![no_std]
#![no_main]

mod board;
#[cfg(feature = "defmt")]
mod defmt_logger;

use cortex_m_rt::entry;

use board::{Mps2An500, Peripherals, TickCounter, Watchdog};

/// Records the panic (message, location) in the fault record and resets: never a halt.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    epssn_selftest::reset::panic(info)
}

#[entry]
fn main() -> ! {
    // First: arm the watchdog (it covers the boot self-test too: each log line feeds it);
    // the shared main then reads the record the last reset left.
    let board = Mps2An500 {
        watchdog: Watchdog::start(),
        clock: TickCounter::start(),
    };
    // SAFETY: the MPS2-AN500's UART 0 and LED register, driven by nothing else; memory.x's
    // RAM region starts at 0x2000_0000.
    let io = unsafe { Peripherals::new() };
    epssn_cmsdk::boot::run(&board, io)
}
