//! epssn co-processor firmware for an STM32H743/H753 module (pinout of the Nucleo-H743ZI).
//!
//! Board code only: clocks, caches, the link UART, the busy LED, the DWT cycle counter, the
//! memory map (`memory.x`: the image in flash bank 1, the update partition in bank 2, statics
//! and stack in DTCM, the link buffers in AXI SRAM). The boot self-test is the QEMU firmware's
//! (`epssn-selftest`), the link server the library's (`epssn::server`), the model updates the
//! boards' shared ones over bank 2 (`update`). Logs go out as defmt over RTT (`probe-rs run`).
//!
//! Boot: clocks at 480 MHz, I- and D-cache on, cycle counter on, stack painted, the update
//! partition opened (the committed model, if any, serves from its slot in bank 2; else the
//! compiled-in one), self-test (warp tables, blob, golden depth map reproduced bit for bit,
//! cycles per layer). On a pass it serves the link (docs/LINK.md) on USART3, model updates
//! included, until a `shutdown` message, then resets (the next session starts with fresh
//! sequence numbers and an empty feature cache); a commit resets it into the new model. On a
//! failure it does not serve: the busy LED stays lit and the log says why.

#![no_std]
#![no_main]

mod board;
mod update;

use core::mem::MaybeUninit;

use cortex_m_rt::entry;
use defmt_rtt as _;
use epssn::config;
use epssn::link::Decoder;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;
/// Logs the panic, records it in the fault record and resets: never a halt.
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    epssn_selftest::reset::panic(info)
}

/// Scratch of one inference, in DTCM .bss (const-initialised: never built on the stack).
static mut WORKSPACE: Workspace = Workspace::new();
/// Cached features of recent frames, for pairing by roll (DTCM: read by every cost plane).
static mut CACHE: FeatureCache = FeatureCache::new();
/// The depth map (DTCM).
static mut DEPTH: [U16F16; config::DEPTH_LEN] = [U16F16::ZERO; config::DEPTH_LEN];
/// The link decoder's buffer (one whole message): AXI SRAM, written once per received byte.
#[link_section = ".axisram.decoder"]
static mut DECODER: MaybeUninit<Decoder> = MaybeUninit::uninit();

/// 100 ms of line silence abandons a partial message (docs/LINK.md, `Truncated`).
const IDLE_CYCLES: u32 = board::CPU_HZ / 10;

fn console(args: core::fmt::Arguments<'_>) {
    defmt::info!("{}", defmt::Display2Format(&args));
}

#[entry]
fn main() -> ! {
    let board = board::init();
    let fault = epssn_selftest::reset::stored();
    let cause = epssn::fault::stm32h7_reset_cause(board.reset_flags, fault.as_ref());
    // A record is only reported with the reset it explains.
    let fault = fault.filter(|r| r.cause == cause);
    let board::Board {
        mut busy_led,
        mut link,
        watchdog,
        reset_flags,
        bank2,
        scb,
    } = board;
    let watchdog = core::cell::RefCell::new(watchdog);
    // Fed from the serving loop and at each self-test line; `try_borrow_mut` has no panic path
    // (nothing else borrows it).
    let feed = || {
        if let Ok(mut w) = watchdog.try_borrow_mut() {
            w.pet();
        }
    };
    let mut log = |args: core::fmt::Arguments<'_>| {
        feed();
        console(args);
    };
    epssn_selftest::banner(&mut log);
    defmt::info!(
        "reset: {} (RCC_RSR {=u32:#x}); fault record: {}",
        cause.name(),
        reset_flags,
        defmt::Debug2Format(&fault)
    );
    defmt::info!(
        "board: STM32H743, {=u32} Hz core, I/D-cache on, link on USART3 at {=u32} baud",
        board::CPU_HZ,
        board::LINK_BAUD
    );
    // SAFETY: `main` runs once and never returns; these are the only references to the
    // statics, taken before anything else can reach them (no interrupt handler uses them).
    let (ws, cache, depth, decoder) = unsafe {
        (
            &mut *core::ptr::addr_of_mut!(WORKSPACE),
            &mut *core::ptr::addr_of_mut!(CACHE),
            &mut *core::ptr::addr_of_mut!(DEPTH),
            // .axisram is NOLOAD: nothing initialised it; write the decoder in place.
            (*core::ptr::addr_of_mut!(DECODER)).write(Decoder::new()),
        )
    };
    let stack = board::stack();
    stack.paint();
    let now = board::cycles;
    let clock = || epssn_selftest::Clock {
        now: &now,
        units_per_tick: 1,
        unit: "cycles",
    };
    // The model updates over bank 2 and the blob that serves: the committed update's, in
    // place in its slot, else the compiled-in one.
    let flash = update::Bank2::new(bank2, scb, &feed);
    let (mut updates, served) = match update::open(flash, &feed, clock(), &console) {
        Some((u, served)) => (Some(u), served),
        None => (None, None),
    };
    if let Some(u) = &updates {
        let s = epssn::server::Updates::serving(u);
        defmt::info!(
            "model: version {=u32} (slot {})",
            s.version,
            defmt::Debug2Format(&s.slot)
        );
    }
    let (blob, golden) =
        served.unwrap_or((epssn_selftest::WEIGHTS, epssn_selftest::SELFTEST_DEPTH_CRC));
    let model = Model::from_blob(blob);
    let served = epssn_selftest::Served {
        blob_len: blob.len(),
        golden,
    };
    let failures = epssn_selftest::run_served(
        &mut log,
        &model,
        served,
        &clock(),
        &mut busy_led,
        ws,
        cache,
        depth,
    );
    defmt::info!(
        "stack high-water mark: {=u32} of {=u32} bytes",
        stack.high_water(),
        stack.size()
    );
    let model = match (failures, model) {
        (0, Ok(model)) => model,
        _ => {
            defmt::error!("self-test: FAIL ({=u32} checks); not serving", failures);
            busy_led.set_high();
            // Not serving: the watchdog, no longer fed, resets the board and the self-test
            // runs again.
            loop {
                cortex_m::asm::wfi();
            }
        }
    };
    defmt::info!("self-test: PASS");
    defmt::info!("serving the link on USART3");
    let high_water = || stack.high_water();
    let mut server = epssn::server::Server::new(
        &model,
        ws,
        cache,
        depth,
        &now,
        // `now` counts core cycles: the `instr` field of depth replies carries cycles here.
        1,
        IDLE_CYCLES,
        &high_water,
    );
    server.feed = &feed;
    server.reset = cause;
    server.fault = fault;
    server.clear_fault = &epssn_selftest::reset::clear;
    if let Some(u) = updates.as_mut() {
        server.updates = Some(u);
    }
    let r = server.serve(&mut link, &mut busy_led, decoder);
    defmt::info!(
        "link shut down ({=u32} line errors): {}; resetting",
        server.line_errors,
        defmt::Debug2Format(&r)
    );
    cortex_m::peripheral::SCB::sys_reset()
}
