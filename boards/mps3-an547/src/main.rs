//! epssn co-processor firmware for a Cortex-M55 (QEMU `mps3-an547`): `firmware/`'s main with
//! this board's peripherals (`board.rs`).
//!
//! At boot it runs the board-independent self-test of `epssn-selftest`
//! (`../boards/selftest`, shared with the STM32H743 board): warp tables recomputed, the blob
//! verified, the golden depth map from the x86 library reproduced bit for bit, instruction
//! counts per layer. The result and exit code go out through
//! semihosting. With the semihosting argument `serve` (QEMU
//! `-semihosting-config enable=on,target=native,arg=serve`) it then serves the link protocol
//! (`epssn::link`) on UART0 until a shutdown message, through the library's board-independent
//! server (`epssn::server`); this crate only holds the board (`board.rs`) and the boot self-test.

#![no_std]
#![no_main]

mod board;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use epssn::config;
use epssn::link::Decoder;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;
use static_cell::ConstStaticCell;

use board::TickCounter;

/// Scratch of one inference, in .bss (const-initialised: never built on the stack).
static WORKSPACE: ConstStaticCell<Workspace> = ConstStaticCell::new(Workspace::new());
/// Cached features of recent frames, for pairing by roll.
static CACHE: ConstStaticCell<FeatureCache> = ConstStaticCell::new(FeatureCache::new());
/// The link decoder's buffer (one whole message).
static DECODER: ConstStaticCell<Decoder> = ConstStaticCell::new(Decoder::new());
/// The depth map.
static DEPTH: ConstStaticCell<[U16F16; config::DEPTH_LEN]> =
    ConstStaticCell::new([U16F16::ZERO; config::DEPTH_LEN]);

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
    let mut log = |a: core::fmt::Arguments<'_>| hprintln!("{}", a);
    epssn_selftest::banner(&mut log);
    let stack = board::stack();
    stack.paint();
    let clock = TickCounter::start();
    let mut led = board::busy_led();
    let ws = WORKSPACE.take();
    let cache = CACHE.take();
    let depth = DEPTH.take();
    // One `Model` for the whole run, borrowed below: moving it into an `Option` would keep
    // extra copies of its 2.7 KiB in `main`'s frame for good.
    let model = Model::from_blob(epssn_selftest::WEIGHTS);
    let now = || clock.now();
    let self_test_clock = epssn_selftest::Clock {
        now: &now,
        units_per_tick: TickCounter::INSTRUCTIONS_PER_TICK,
        unit: "instructions",
    };
    let failures = epssn_selftest::run(
        &mut log,
        &model,
        &self_test_clock,
        &mut led,
        ws,
        cache,
        depth,
    );
    hprintln!(
        "stack high-water mark: {} of {} bytes",
        stack.high_water(),
        stack.size()
    );
    if failures == 0 {
        hprintln!("self-test: PASS");
        if let (Ok(model), true) = (&model, board::command_line_has("serve")) {
            hprintln!("serving the link on UART0");
            let high_water = || stack.high_water();
            let mut server = epssn::server::Server::new(
                model,
                ws,
                cache,
                depth,
                &now,
                TickCounter::INSTRUCTIONS_PER_TICK,
                // 100 ms of line silence (virtual time, one tick per nanosecond) abandons a
                // partial message.
                100_000_000,
                &high_water,
            );
            let mut uart = board::uart0();
            let r = server.serve(&mut uart, &mut led, DECODER.take());
            hprintln!("link shut down: {:?}", r);
        }
        debug::exit(debug::EXIT_SUCCESS);
    } else {
        hprintln!("self-test: FAIL ({} checks)", failures);
        debug::exit(debug::EXIT_FAILURE);
    }
    loop {
        cortex_m::asm::wfi();
    }
}
