//! epssn co-processor firmware.
//!
//! Boot self-test: the warp tables that `build.rs` generated on the host and placed in flash
//! are recomputed on the target from the same geometry code and must agree entry for entry.
//! The result goes out through semihosting, with exit code 0 only when every check passed.

#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use epssn::{config, geometry};

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("firmware panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// Recomputes the warp table of view `k` on the target and counts differing entries.
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
    if failures == 0 {
        hprintln!("self-test: PASS");
        debug::exit(debug::EXIT_SUCCESS);
    } else {
        hprintln!("self-test: FAIL ({} checks)", failures);
        debug::exit(debug::EXIT_FAILURE);
    }
    loop {
        cortex_m::asm::wfi();
    }
}
