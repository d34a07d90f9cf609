//! epssn co-processor firmware for a Cortex-M55 (QEMU `mps3-an547`): the QEMU boards' shared
//! main (`epssn_cmsdk::boot`: the boot self-test, then the link server) on this board's
//! peripherals and clock (`board.rs`).

#![no_std]
#![no_main]

mod board;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};

use board::{Peripherals, TickCounter};

/// Reports the panic and exits QEMU with a failure (this board keeps no fault record yet).
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("firmware panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

#[entry]
fn main() -> ! {
    let clock = TickCounter::start();
    // SAFETY: the MPS3-AN547's UART 0 and FPGA IO LED register, driven by nothing else;
    // memory.x's RAM region (DTCM) starts at 0x2000_0000.
    let io = unsafe { Peripherals::new() };
    epssn_cmsdk::boot::run(&clock, io)
}
