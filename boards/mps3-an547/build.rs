//! Build-time work of the Cortex-M55 firmware: puts this board's `memory/memory.x` (the
//! MPS3-AN547 memory map; `memory/memory-<spec stem>.x` for another configuration) on the linker search path.
//! The weight blob and the golden vectors come from the shared self-test crate.

use epssn_spec::load::{build_spec_path, per_spec_file};
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    println!("cargo:rerun-if-env-changed=EPSSN_SPEC");
    let spec = build_spec_path(&manifest.join("../.."));
    let spec_file = spec
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    // In `memory/`, not beside Cargo.toml: the linker looks for `memory.x` in its working
    // directory (the crate's) before the search path, so a file there would shadow the
    // configuration's map.
    let memory = per_spec_file(&manifest.join("memory"), "memory", "x", spec_file);
    std::fs::copy(&memory, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("{}: {e}", memory.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
}
