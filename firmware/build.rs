//! Build-time work of the QEMU firmware: puts the repository's `memory.x` (the MPS2-AN500
//! memory map) on the linker search path. The weight blob and the golden vectors of the boot
//! self-test are embedded by the shared self-test crate (`../boards/selftest/build.rs`).

use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let memory = manifest.join("../memory.x");
    std::fs::copy(&memory, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
    if std::env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        // defmt's interned strings need its linker script.
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
