//! Host throughput of the streamed path the firmware runs: per depth map, the newest frame's
//! features plus the depth map from it and the cached partner's features (what `host-sim sil`
//! counts on the Cortex-M7), on one x86 thread, with the firmware's weight blob.
//!
//! `cargo run --release --example throughput [-- SECONDS]`
//!
//! Reports maps per second of this thread's CPU time (Linux `/proc/thread-self/stat`; wall
//! time elsewhere), so a busy machine does not distort the figure, and the wall-clock rate.

use std::time::{Duration, Instant};

use epssn::config;
use epssn::model::{Model, Workspace};
use fixed::types::U16F16;

/// An LCG speckle over a bright arc (the firmware self-test's kind of image).
fn image(seed: u32) -> Vec<u8> {
    let mut s = seed.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let (r, b) = (config::INPUT_RANGE_BINS, config::INPUT_COLUMNS);
    let mut img = vec![0u8; r * b];
    for k in 0..b {
        let centre = r as f64 * (0.35 + 0.25 * (k as f64 * 0.11 + seed as f64 * 0.3).sin().abs());
        for i in 0..r {
            s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let d = (i as f64 - centre) / 5.0;
            img[i * b + k] = (210.0 * (-d * d).exp() + (s >> 27) as f64).clamp(0.0, 255.0) as u8;
        }
    }
    img
}

fn main() {
    let seconds: f64 = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(3.0);
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let blob_path = epssn_spec::load::firmware_blob(root, config::SPEC_FILE_NAME).unwrap();
    let blob = std::fs::read(blob_path).unwrap();
    let model = Model::from_blob(&blob).expect("weight blob");
    let mut ws = Box::new(Workspace::new());
    let images = [image(1), image(2)];
    let mut cached = vec![0i8; config::FEATURE_LEN];
    let mut newest = vec![0i8; config::FEATURE_LEN];
    model.features(&images[0], &mut ws, &mut cached).unwrap();
    let mut depth = vec![U16F16::ZERO; config::DEPTH_LEN];
    let (mut maps, mut checksum) = (0u64, 0u32);
    let start = Instant::now();
    let cpu0 = thread_cpu_seconds();
    while start.elapsed() < Duration::from_secs_f64(seconds) {
        let img = &images[(maps % 2) as usize];
        model.features(img, &mut ws, &mut newest).unwrap();
        model
            .depth_from_features(&cached, &[&newest], &mut ws, &mut depth)
            .unwrap();
        checksum = checksum.wrapping_add(depth[(maps as usize * 7) % depth.len()].to_bits());
        maps += 1;
    }
    let t = start.elapsed().as_secs_f64();
    let cpu = cpu0.zip(thread_cpu_seconds()).map(|(a, z)| z - a);
    let c = cpu.unwrap_or(t);
    println!(
        "{maps} streamed depth maps on one thread: {:.1} per CPU second ({:.2} ms CPU each; \
         {c:.2} s CPU, {t:.2} s wall, {:.1} per wall second; checksum {checksum:08x})",
        maps as f64 / c,
        1e3 * c / maps as f64,
        maps as f64 / t
    );
}

/// User + system CPU time of this thread (`/proc/thread-self/stat`, 100 ticks per second).
fn thread_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}
