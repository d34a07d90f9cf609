//! The boot self-test every epssn board runs (the QEMU boards `boards/mps2-an500/` and
//! `boards/mps3-an547/`, the STM32H743 module in `boards/stm32h743/`), board-independent: the
//! board hands in a log sink, its clock and its busy LED.
//!
//! It checks, on the target, what the host already checked at build time (`build.rs`):
//! - the warp tables in flash equal a recomputation from the same geometry code;
//! - the weight blob in flash passes the library's loader (CRC, spec hash, shapes, bounds);
//! - a fixed pair of images, run through the serving path (feature cache, pairing by roll),
//!   gives exactly the depth map the library computed on x86 (the golden vector);
//!
//! and reports the cost of each layer in the board's clock unit (instructions under QEMU
//! `-icount`, core cycles on silicon). It also holds the boards' stack paint ([`Stack`]) and,
//! with feature `updates`, the link server's model updates over a board's partition
//! ([`updates::BoardUpdates`]).

#![no_std]
// Denied, not forbidden: the stack paint needs raw memory access, allowed in its module only.
#![deny(unsafe_code)]

use core::fmt::Arguments;

use embedded_hal::digital::OutputPin;
use epssn::config;
use epssn::geometry;
use epssn::model::{Model, Workspace};
use epssn::pairing::FeatureCache;
use fixed::types::U16F16;

#[allow(unsafe_code)]
pub mod reset;
#[allow(unsafe_code)]
mod stack;
pub use stack::Stack;
#[cfg(feature = "updates")]
pub mod updates;

/// The bytes of the compiled-in blob, 4-byte aligned like a slot's.
#[repr(C, align(4))]
struct Aligned<T>(T);

/// The blob's bytes; with `weights-section` in the linker section `.weights`, which the board's
/// memory map puts in its weight region, outside the image's flash budget (docs/UPDATE.md).
// Only where the linker puts read-only bytes (the `unsafe_code` lint counts `link_section`).
#[allow(unsafe_code)]
#[cfg_attr(feature = "weights-section", link_section = ".weights")]
static BLOB: Aligned<[u8; include_bytes!(concat!(env!("OUT_DIR"), "/weights.bin")).len()]> =
    Aligned(*include_bytes!(concat!(env!("OUT_DIR"), "/weights.bin")));

/// The weight blob the firmware serves with unless an update serves, checked on the host at
/// build time.
pub static WEIGHTS: &[u8] = &BLOB.0;
/// The public key a model update's signature must verify against (`EPSSN_UPDATE_KEY` at
/// build time, `build.rs`).
pub const UPDATE_KEY: [u8; 32] = *include_bytes!(concat!(env!("OUT_DIR"), "/update_key.bin"));
static SELFTEST_REFERENCE: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/selftest_reference.bin"));
static SELFTEST_SOURCE: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/selftest_source.bin"));
/// CRC-32 of the golden depth map (U16F16 bits, u32 LE) of [`WEIGHTS`]: 4 bytes of flash, not
/// the 8 KiB of the map, and any differing value changes it (a collision is a 2^-32 chance).
/// An update carries its own in its signed header.
pub const SELFTEST_DEPTH_CRC: u32 = include!(concat!(env!("OUT_DIR"), "/selftest_depth_crc.rs"));

/// Where the self-test writes its report, one line per call.
pub type Log<'a> = &'a mut dyn FnMut(Arguments<'_>);
/// The busy LED, on or off (one copy of the golden test for every pin type: flash).
type Led<'a> = &'a mut dyn FnMut(bool);

/// The board's free-running counter and what one tick of it is worth.
pub struct Clock<'a> {
    /// Ticks of a free-running counter (wrapping).
    pub now: &'a dyn Fn() -> u32,
    /// Units (below) per tick.
    pub units_per_tick: u32,
    /// What the figures count: "instructions" (QEMU `-icount`), "cycles" (DWT CYCCNT).
    pub unit: &'static str,
}

impl Clock<'_> {
    fn now(&self) -> u32 {
        (self.now)()
    }

    fn units(&self, ticks: u32) -> u32 {
        ticks.saturating_mul(self.units_per_tick)
    }
}

/// The banner line: spec name and sizes.
pub fn banner(log: Log<'_>) {
    log(format_args!(
        "epssn firmware: {} ({}x{} input, {} planes, {}x{} depth)",
        config::SPEC_NAME,
        config::INPUT_RANGE_BINS,
        config::INPUT_COLUMNS,
        config::PLANES,
        config::DEPTH_ROWS,
        config::DEPTH_COLUMNS
    ));
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

/// Runs the golden pair through the serving path (feature cache, pairing by roll) and logs
/// per-layer costs; true when bit-exact.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn golden_self_test(
    log: Log<'_>,
    model: &Model<'_>,
    clock: &Clock<'_>,
    led: Led<'_>,
    ws: &mut Workspace,
    cache: &mut FeatureCache,
    depth: &mut [U16F16; config::DEPTH_LEN],
    golden: u32,
) -> bool {
    let unit = clock.unit;
    led(true);
    let start = clock.now();
    let mut last = start;
    let mut ok = true;
    let mut newest = None;
    for (v, image) in [SELFTEST_REFERENCE, SELFTEST_SOURCE].iter().enumerate() {
        let roll = (config::ROLL_STEP_DEG * v as f64) as f32;
        let r = cache.insert(v as u32, roll, |f| {
            model.features_probed(image, ws, f, |name, _| {
                let now = clock.now();
                log(format_args!(
                    "layer {} (view {}): {} {}",
                    name,
                    v,
                    clock.units(now - last),
                    unit
                ));
                last = clock.now();
            })
        });
        match r {
            Ok(f) => newest = Some(f),
            Err(e) => {
                log(format_args!("features failed: {:?}", e));
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
        log(format_args!(
            "self-test pairing: no pair for rolls 0 and step"
        ));
        return false;
    };
    if reference_seq != 0 {
        log(format_args!(
            "self-test pairing: reference is frame {}",
            reference_seq
        ));
        ok = false;
    }
    let r = model.depth_from_features_probed(reference, &[source], ws, depth, |name, _| {
        let now = clock.now();
        log(format_args!(
            "layer {}: {} {}",
            name,
            clock.units(now - last),
            unit
        ));
        last = clock.now();
    });
    let end = clock.now();
    led(false);
    if let Err(e) = r {
        log(format_args!("depth failed: {:?}", e));
        ok = false;
    }
    // The last streamed stage: each u0 output plane (its cost-volume skip plane recomputed)
    // straight into the fused head and soft-argmax.
    log(format_args!(
        "layer cost+u0+head+soft-argmax: {} {}",
        clock.units(end - last),
        unit
    ));
    let crc = epssn::golden::depth_crc(&depth[..]);
    let exact = crc == golden;
    log(format_args!(
        "self-test depth map: CRC-32 {:08x}, x86 library {:08x} ({} values): {}",
        crc,
        golden,
        config::DEPTH_LEN,
        if exact { "bit-exact" } else { "DIFFERS" }
    ));
    log(format_args!(
        "{}: features per view {}, depth from features {}, full pair {}",
        unit,
        clock.units(features_done - start) / 2,
        clock.units(end - features_done),
        clock.units(end - start)
    ));
    cache.clear();
    ok && exact
}

/// The whole boot self-test after the banner: warp tables, the blob (already parsed by the
/// caller into `model`, which the board keeps for serving), the golden depth map. Returns the
/// number of failed checks (0: pass). Leaves the cache empty.
#[allow(clippy::too_many_arguments)]
pub fn run<E: core::fmt::Debug>(
    log: Log<'_>,
    model: &Result<Model<'_>, E>,
    clock: &Clock<'_>,
    led: &mut impl OutputPin,
    ws: &mut Workspace,
    cache: &mut FeatureCache,
    depth: &mut [U16F16; config::DEPTH_LEN],
) -> u32 {
    let served = Served {
        blob_len: WEIGHTS.len(),
        golden: SELFTEST_DEPTH_CRC,
    };
    run_served(log, model, served, clock, led, ws, cache, depth)
}

/// The blob a board serves, for [`run_served`]: its length and its golden depth map's CRC.
#[derive(Clone, Copy, Debug)]
pub struct Served {
    /// Bytes of the blob.
    pub blob_len: usize,
    /// CRC-32 of the depth map it must give for the golden pair.
    pub golden: u32,
}

/// [`run`] for a model that may be an update's: `served` says which golden CRC it must give.
#[allow(clippy::too_many_arguments)]
pub fn run_served<E: core::fmt::Debug>(
    log: Log<'_>,
    model: &Result<Model<'_>, E>,
    served: Served,
    clock: &Clock<'_>,
    led: &mut impl OutputPin,
    ws: &mut Workspace,
    cache: &mut FeatureCache,
    depth: &mut [U16F16; config::DEPTH_LEN],
) -> u32 {
    let mut failures = 0;
    for k in 1..config::MAX_VIEWS {
        let bad = warp_table_mismatches(k);
        let visible = config::WARP_TABLES[k - 1]
            .iter()
            .filter(|e| e.visible)
            .count();
        log(format_args!(
            "self-test warp table view {}: {} visible entries, {} mismatches",
            k, visible, bad
        ));
        if bad != 0 || visible == 0 {
            failures += 1;
        }
    }
    match model {
        Ok(model) => {
            log(format_args!(
                "weights: {} bytes, blob verified",
                served.blob_len
            ));
            let mut led = |on: bool| {
                let _ = if on { led.set_high() } else { led.set_low() };
            };
            if !golden_self_test(log, model, clock, &mut led, ws, cache, depth, served.golden) {
                failures += 1;
            }
        }
        Err(e) => {
            log(format_args!("weights refused: {:?}", e));
            failures += 1;
        }
    }
    failures
}

/// The self-test of an update before it serves: its blob `blob` in place passes the library's
/// loader, and the golden pair through the serving path gives the depth map of CRC `golden`
/// (its signed header's). Silent; leaves the cache empty.
#[inline(never)]
pub fn check_update(
    blob: &[u8],
    golden: u32,
    ws: &mut Workspace,
    cache: &mut FeatureCache,
    depth: &mut [U16F16; config::DEPTH_LEN],
) -> bool {
    let Ok(model) = Model::from_blob(blob) else {
        return false;
    };
    let clock = Clock {
        now: &|| 0,
        units_per_tick: 0,
        unit: "",
    };
    cache.clear();
    golden_self_test(
        &mut |_| {},
        &model,
        &clock,
        &mut |_| {},
        ws,
        cache,
        depth,
        golden,
    )
}
