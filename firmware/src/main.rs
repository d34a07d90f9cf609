//! epssn co-processor firmware.
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
#[cfg(feature = "defmt")]
mod defmt_logger;

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use epssn::config;
use epssn::link::Decoder;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;
use static_cell::ConstStaticCell;

use board::{TickCounter, Watchdog};
use epssn::fault::{Record, ResetCause};

/// Scratch of one inference, in .bss (const-initialised: never built on the stack).
static WORKSPACE: ConstStaticCell<Workspace> = ConstStaticCell::new(Workspace::new());
/// Cached features of recent frames, for pairing by roll.
static CACHE: ConstStaticCell<FeatureCache> = ConstStaticCell::new(FeatureCache::new());
/// The link decoder's buffer (one whole message).
static DECODER: ConstStaticCell<Decoder> = ConstStaticCell::new(Decoder::new());
/// The depth map.
static DEPTH: ConstStaticCell<[U16F16; config::DEPTH_LEN]> =
    ConstStaticCell::new([U16F16::ZERO; config::DEPTH_LEN]);

/// Records the panic (message, location) in the fault record and resets: never a halt.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    epssn_selftest::reset::panic(info)
}

/// Prints why the device last reset and its fault record, if any.
fn report_reset(cause: ResetCause, record: &Option<Record>) {
    hprintln!("reset cause: {}", cause.name());
    if let Some(r) = record {
        hprintln!(
            "fault record: pc {:#010x} lr {:#010x} xpsr {:#010x} cfsr {:#010x} hfsr {:#010x} \
             mmfar {:#010x} bfar {:#010x} at {}:{}: {}",
            r.pc,
            r.lr,
            r.xpsr,
            r.cfsr,
            r.hfsr,
            r.mmfar,
            r.bfar,
            r.line,
            r.column,
            r.text()
        );
    }
}

/// Test builds (`reset-faults`): the faults `host-sim sil --reset-faults` provokes.
#[cfg(feature = "reset-faults")]
fn inject(what: u16) {
    use epssn::fault::inject;
    match what {
        // Spins without returning to the serving loop: the watchdog is no longer fed.
        inject::HANG => loop {
            cortex_m::asm::nop();
        },
        inject::PANIC => panic!("injected panic"),
        inject::STACK_OVERFLOW => {
            core::hint::black_box(recurse(u32::MAX));
        }
        _ => {}
    }
}

/// Recursion with a 1 KiB frame: deep enough to overflow any stack this RAM holds.
#[cfg(feature = "reset-faults")]
#[inline(never)]
fn recurse(n: u32) -> u32 {
    let frame = core::hint::black_box([n as u8; 1024]);
    if n == 0 {
        return u32::from(frame[0]);
    }
    recurse(n - 1).wrapping_add(u32::from(frame[1023]))
}

#[entry]
fn main() -> ! {
    // First: arm the watchdog (it covers the boot self-test too: each log line feeds it) and
    // read the record the last reset left.
    let watchdog = Watchdog::start();
    let fault = epssn_selftest::reset::stored();
    let cause = fault.map_or(ResetCause::PowerOn, |r| r.cause);
    let mut log = |a: core::fmt::Arguments<'_>| {
        watchdog.feed();
        hprintln!("{}", a)
    };
    epssn_selftest::banner(&mut log);
    report_reset(cause, &fault);
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
    let serve = board::command_line_has("serve");
    if fault.is_some() && !serve {
        // A self-test run (no host to report to) after a fault: fail, or a fault at boot
        // would reset and rerun forever.
        hprintln!("self-test: FAIL (reset by a fault)");
        debug::exit(debug::EXIT_FAILURE);
    } else if failures == 0 {
        hprintln!("self-test: PASS");
        if let (Ok(model), true) = (&model, serve) {
            hprintln!("serving the link on UART0");
            let high_water = || stack.high_water();
            let mut server = epssn::server::Server::new(
                model,
                ws,
                cache,
                depth,
                &now,
                TickCounter::INSTRUCTIONS_PER_TICK,
                // 100 ms of line silence (virtual time) abandons a partial message.
                2_500_000,
                &high_water,
            );
            let feed = || watchdog.feed();
            server.feed = &feed;
            server.reset = cause;
            server.fault = fault;
            server.clear_fault = &epssn_selftest::reset::clear;
            #[cfg(feature = "reset-faults")]
            {
                server.inject = &inject;
            }
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
