//! Puts the repository's `memory.x` (the one memory map) on the linker search path.
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let memory = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap()).join("../memory.x");
    std::fs::copy(&memory, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
}
