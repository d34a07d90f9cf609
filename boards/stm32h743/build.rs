//! Puts this board's `memory.x` (STM32H743: flash, DTCM, AXI SRAM) on the linker search path.
//! The weight blob and the golden vectors come from the shared self-test crate.

use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let memory = manifest.join("memory.x");
    std::fs::copy(&memory, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
}
