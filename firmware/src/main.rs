//! epssn co-processor firmware.
//!
//! At boot it checks, on the target, what the host already checked at build time:
//! - the weight blob in flash passes the library's loader (CRC, spec hash, shapes, bounds);
//! - the warp tables in flash equal a recomputation from the same geometry code;
//! - a fixed pair of images gives exactly the depth map the library computed on x86
//!   (the golden vector from `build.rs`).
//!
//! It reports instruction counts per layer. The result and exit code go out through
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
use embedded_hal::digital::OutputPin;
use epssn::config;
use epssn::geometry;
use epssn::link::Decoder;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;
use static_cell::ConstStaticCell;

use board::{BusyLed, TickCounter, Uart0};

static WEIGHTS: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/weights.bin"));
static SELFTEST_REFERENCE: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/selftest_reference.bin"));
static SELFTEST_SOURCE: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/selftest_source.bin"));
static SELFTEST_DEPTH: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/selftest_depth.bin"));

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

/// Recomputes the warp table of view `k` on the target and counts differing entries.
// Not inlined (nor the self-test below): their stack frames then only exist while they run,
// instead of adding to `main`'s frame under every later inference.
#[inline(never)]
fn warp_table_mismatches(k: usize) -> usize {
    let mut table = [geometry::WarpEntry::default(); config::PLANES * config::FEATURE_COLUMNS];
    let transform = geometry::RigidTransform::rolled_about_axis(
        config::ROLL_STEP_DEG * k as f64,
        config::LEVER_ARM_M,
    );
    if geometry::warp_table_pure_roll(
        &transform,
        &config::FEATURE_COLUMN_AZIMUTH_RAD,
        &config::PLANE_ELEVATION_RAD,
        config::HALF_ELEVATION_RAD,
        config::WARP_FRACTION_BITS,
        &mut table,
    )
    .is_err()
    {
        return table.len();
    }
    table
        .iter()
        .zip(config::WARP_TABLES[k - 1].iter())
        .filter(|(a, b)| a != b)
        .count()
}

fn instructions(ticks: u32) -> u32 {
    ticks.saturating_mul(TickCounter::INSTRUCTIONS_PER_TICK)
}

/// Runs the golden pair through the serving path (feature cache, pairing by roll) and prints
/// per-layer instruction counts; true when bit-exact.
#[inline(never)]
fn golden_self_test(
    model: &Model<'_>,
    clock: &TickCounter,
    ws: &mut Workspace,
    cache: &mut FeatureCache,
    depth: &mut [U16F16; config::DEPTH_LEN],
) -> bool {
    let mut led = BusyLed;
    let _ = led.set_high();
    let start = clock.now();
    let mut last = start;
    let mut ok = true;
    let mut newest = None;
    for (v, image) in [SELFTEST_REFERENCE, SELFTEST_SOURCE].iter().enumerate() {
        let roll = (config::ROLL_STEP_DEG * v as f64) as f32;
        let r = cache.insert(v as u32, roll, |f| {
            model.features_probed(image, ws, f, |name, _| {
                let now = clock.now();
                hprintln!(
                    "layer {} (view {}): {} instructions",
                    name,
                    v,
                    instructions(now - last)
                );
                last = clock.now();
            })
        });
        match r {
            Ok(f) => newest = Some(f),
            Err(e) => {
                hprintln!("features failed: {:?}", e);
                ok = false;
            }
        }
    }
    let features_done = clock.now();
    let set = newest.and_then(|n| cache.find(&n, 2));
    let pair = set.as_ref().and_then(|s| {
        let r = cache.features(s.reference()?)?;
        let src = cache.features(s.sources().first()?)?;
        Some((s.reference()?.seq, r, src))
    });
    let Some((reference_seq, reference, source)) = pair else {
        hprintln!("self-test pairing: no pair for rolls 0 and step");
        return false;
    };
    if reference_seq != 0 {
        hprintln!("self-test pairing: reference is frame {}", reference_seq);
        ok = false;
    }
    let r = model.depth_from_features_probed(reference, &[source], ws, depth, |name, _| {
        let now = clock.now();
        hprintln!("layer {}: {} instructions", name, instructions(now - last));
        last = clock.now();
    });
    let end = clock.now();
    let _ = led.set_low();
    if let Err(e) = r {
        hprintln!("depth failed: {:?}", e);
        ok = false;
    }
    // The last streamed stage: each u0 output plane (its cost-volume skip plane recomputed)
    // straight into the fused head and soft-argmax.
    hprintln!(
        "layer cost+u0+head+soft-argmax: {} instructions",
        instructions(end - last)
    );
    let mismatches = depth
        .iter()
        .zip(SELFTEST_DEPTH.chunks_exact(4))
        .filter(|(d, g)| d.to_bits() != u32::from_le_bytes([g[0], g[1], g[2], g[3]]))
        .count();
    hprintln!(
        "self-test depth map: {} of {} values differ from the x86 library",
        mismatches,
        config::DEPTH_LEN
    );
    hprintln!(
        "instructions: features per view {}, depth from features {}, full pair {}",
        instructions(features_done - start) / 2,
        instructions(end - features_done),
        instructions(end - start)
    );
    cache.clear();
    ok && mismatches == 0
}

#[entry]
fn main() -> ! {
    hprintln!(
        "epssn firmware: {} ({}x{} input, {} planes, {}x{} depth)",
        config::SPEC_NAME,
        config::INPUT_RANGE_BINS,
        config::INPUT_COLUMNS,
        config::PLANES,
        config::DEPTH_ROWS,
        config::DEPTH_COLUMNS
    );
    board::paint_stack();
    let clock = TickCounter::start();
    let ws = WORKSPACE.take();
    let cache = CACHE.take();
    let depth = DEPTH.take();
    let mut failures = 0;
    for k in 1..config::MAX_VIEWS {
        let bad = warp_table_mismatches(k);
        let visible = config::WARP_TABLES[k - 1]
            .iter()
            .filter(|e| e.visible)
            .count();
        hprintln!(
            "self-test warp table view {}: {} visible entries, {} mismatches",
            k,
            visible,
            bad
        );
        if bad != 0 || visible == 0 {
            failures += 1;
        }
    }
    // One `Model` for the whole run, borrowed below: moving it into an `Option` would keep
    // extra copies of its 2.7 KiB in `main`'s frame for good.
    let model = Model::from_blob(WEIGHTS);
    match &model {
        Ok(model) => {
            hprintln!("weights: {} bytes, blob verified", WEIGHTS.len());
            if !golden_self_test(model, &clock, ws, cache, depth) {
                failures += 1;
            }
        }
        Err(e) => {
            hprintln!("weights refused: {:?}", e);
            failures += 1;
        }
    }
    hprintln!(
        "stack high-water mark: {} of {} bytes",
        board::stack_high_water(),
        board::stack_size()
    );
    if failures == 0 {
        hprintln!("self-test: PASS");
        if let (Ok(model), true) = (&model, board::command_line_has("serve")) {
            hprintln!("serving the link on UART0");
            let now = || clock.now();
            let high_water = board::stack_high_water;
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
            let mut uart = Uart0::new();
            let r = server.serve(&mut uart, &mut BusyLed, DECODER.take());
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
