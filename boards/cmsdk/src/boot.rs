//! The QEMU boards' main, written once. At boot it runs the board-independent self-test of
//! `epssn-selftest` (`../selftest`): warp tables recomputed, the blob verified, the golden
//! depth map from the x86 library reproduced bit for bit, instruction counts per layer. The
//! result and exit code go out through semihosting. With the semihosting argument `serve`
//! (QEMU `-semihosting-config enable=on,target=native,arg=serve`) it then serves the link
//! protocol (`epssn::link`) on UART0 until a shutdown message, through the library's
//! board-independent server (`epssn::server`).
//!
//! A board's crate holds its entry, its panic handler and what differs between the boards
//! ([`Board`]: the clock, and where there is one, the watchdog and the fault record); the
//! CMSDK peripherals come in as [`Peripherals`] at the board's addresses.

use cortex_m_semihosting::{debug, hprintln};
use epssn::config;
use epssn::fault::{Record, ResetCause};
use epssn::link::Decoder;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use epssn_selftest::Stack;
use fixed::types::U16F16;
use static_cell::ConstStaticCell;

#[cfg(feature = "updates")]
use crate::update::Sram;
use crate::{command_line_has, FpgaLed, Uart};

/// Scratch of one inference, in .bss (const-initialised: never built on the stack).
static WORKSPACE: ConstStaticCell<Workspace> = ConstStaticCell::new(Workspace::new());
/// Cached features of recent frames, for pairing by roll.
static CACHE: ConstStaticCell<FeatureCache> = ConstStaticCell::new(FeatureCache::new());
/// The link decoder's buffer (one whole message).
static DECODER: ConstStaticCell<Decoder> = ConstStaticCell::new(Decoder::new());
/// The depth map.
static DEPTH: ConstStaticCell<[U16F16; config::DEPTH_LEN]> =
    ConstStaticCell::new([U16F16::ZERO; config::DEPTH_LEN]);

/// What differs between the QEMU boards under the shared main.
pub trait Board {
    /// QEMU instructions per tick of [`Board::now`] under `-icount shift=0`.
    const INSTRUCTIONS_PER_TICK: u32;
    /// Ticks of 100 ms of virtual time: line silence this long abandons a partial message.
    const IDLE_TICKS: u32;

    /// Whether the board keeps the fault record across resets (`epssn_selftest::reset`: its
    /// panic handler, fault entry and watchdog write it) and so reports why it last reset.
    const FAULT_RECORD: bool = false;

    /// Ticks of the board's free-running counter (wrapping).
    fn now(&self) -> u32;

    /// Feeds the watchdog, on a board that has one: at each log line of the self-test and
    /// each pass of the serving loop.
    fn feed(&self) {}

    /// On a board that takes model updates (feature `updates`): its update partition (the
    /// memory map's `UPDATE` region) and the reset that makes a committed model serve.
    #[cfg(feature = "updates")]
    fn update_partition(&self) -> Option<(Sram, fn() -> !)> {
        None
    }
}

/// A QEMU board's CMSDK APB UART 0 at `UART0`, its FPGA IO LED register at `FPGAIO_LED`, and
/// its stack: the peripherals the shared main drives.
pub struct Peripherals<const UART0: usize, const FPGAIO_LED: usize>(());

impl<const UART0: usize, const FPGAIO_LED: usize> Peripherals<UART0, FPGAIO_LED> {
    /// # Safety
    ///
    /// `UART0` is the address of this board's CMSDK APB UART 0 and `FPGAIO_LED` that of its
    /// FPGA IO LED register, which nothing but the holder drives; the image's RAM region
    /// (memory.x), in which cortex-m-rt (through flip-link) puts the stack, starts at
    /// [`epssn_selftest::reset::STACK_ORIGIN`].
    pub const unsafe fn new() -> Self {
        Peripherals(())
    }

    /// LED0 of the board, lit while the co-processor is computing a depth map.
    fn busy_led(&self) -> FpgaLed<FPGAIO_LED> {
        // SAFETY: `new`'s contract: FPGAIO_LED is this board's LED register, ours alone.
        unsafe { FpgaLed::new() }
    }

    /// UART0, enabled (QEMU connects it to the first `-serial`).
    fn uart0(&self) -> Uart<UART0> {
        // SAFETY: `new`'s contract: UART0 is this board's UART 0, ours alone.
        unsafe { Uart::new() }
    }

    /// The stack, for its paint and high-water mark.
    fn stack(&self) -> Stack {
        // SAFETY: `new`'s contract: the RAM region holding the stack starts at STACK_ORIGIN.
        unsafe { Stack::new(epssn_selftest::reset::STACK_ORIGIN as usize) }
    }
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

/// Test builds (`fault-injection`): the faults `host-sim sil --reset-faults` provokes.
#[cfg(feature = "fault-injection")]
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
#[cfg(feature = "fault-injection")]
#[inline(never)]
fn recurse(n: u32) -> u32 {
    let frame = core::hint::black_box([n as u8; 1024]);
    if n == 0 {
        return u32::from(frame[0]);
    }
    recurse(n - 1).wrapping_add(u32::from(frame[1023]))
}

/// The boot self-test, then (argument `serve`) the link server; exits QEMU through
/// semihosting with the result. A board with the fault record calls it first thing after
/// arming its watchdog: it reads the record the last reset left before anything else.
pub fn run<B: Board, const UART0: usize, const FPGAIO_LED: usize>(
    board: &B,
    io: Peripherals<UART0, FPGAIO_LED>,
) -> ! {
    // Why the device last reset, and the record (on the boards that keep one).
    let resets = B::FAULT_RECORD.then(|| {
        let fault = epssn_selftest::reset::stored();
        (fault.map_or(ResetCause::PowerOn, |r| r.cause), fault)
    });
    let mut log = |a: core::fmt::Arguments<'_>| {
        board.feed();
        hprintln!("{}", a)
    };
    epssn_selftest::banner(&mut log);
    if let Some((cause, fault)) = &resets {
        report_reset(*cause, fault);
    }
    let stack = io.stack();
    stack.paint();
    let mut led = io.busy_led();
    let ws = WORKSPACE.take();
    let cache = CACHE.take();
    let depth = DEPTH.take();
    // The model updates (feature `updates`, on a board with an update partition) and the blob
    // that serves: the committed update's, in place in its slot, else the compiled-in one.
    let feed = || board.feed();
    let now = || board.now();
    #[cfg(feature = "updates")]
    let (mut updates, served) = match board.update_partition().and_then(|(mem, reset)| {
        crate::update::open(mem, &feed, reset, (&now, B::INSTRUCTIONS_PER_TICK))
    }) {
        Some((u, served)) => (Some(u), served),
        None => (None, None),
    };
    #[cfg(not(feature = "updates"))]
    let served: Option<(&[u8], u32)> = None;
    let (blob, golden) =
        served.unwrap_or((epssn_selftest::WEIGHTS, epssn_selftest::SELFTEST_DEPTH_CRC));
    #[cfg(feature = "updates")]
    if let Some(u) = &updates {
        let s = epssn::server::Updates::serving(u);
        hprintln!("model: version {} (slot {:?})", s.version, s.slot);
    }
    // One `Model` for the whole run, borrowed below: moving it into an `Option` would keep
    // extra copies of its 2.7 KiB in `run`'s frame for good.
    let model = Model::from_blob(blob);
    let self_test_clock = epssn_selftest::Clock {
        now: &now,
        units_per_tick: B::INSTRUCTIONS_PER_TICK,
        unit: "instructions",
    };
    let served = epssn_selftest::Served {
        blob_len: blob.len(),
        golden,
    };
    let failures = epssn_selftest::run_served(
        &mut log,
        &model,
        served,
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
    let serve = command_line_has("serve");
    if resets.as_ref().is_some_and(|(_, fault)| fault.is_some()) && !serve {
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
                B::INSTRUCTIONS_PER_TICK,
                B::IDLE_TICKS,
                &high_water,
            );
            #[cfg(feature = "updates")]
            if let Some(u) = updates.as_mut() {
                server.updates = Some(u);
            }
            if let Some((cause, fault)) = resets {
                server.feed = &feed;
                server.reset = cause;
                server.fault = fault;
                server.clear_fault = &epssn_selftest::reset::clear;
                #[cfg(feature = "fault-injection")]
                {
                    server.inject = &inject;
                }
            }
            let mut uart = io.uart0();
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
