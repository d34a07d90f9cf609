//! The build script of both QEMU boards (their Cargo.toml: `build = "../cmsdk/board-build.rs"`):
//! puts the board's memory map on the linker search path: `memory/memory.x` beside its
//! Cargo.toml (`memory/memory-<spec stem>.x` for another configuration) or, for the Cortex-M7
//! image, which has no `memory/`, the repository's top-level `memory.x`, the product's map, and `defmt.x` with the `defmt` feature. The weight
//! blob and the golden vectors of the boot self-test are embedded by the shared self-test crate
//! (`../selftest/build.rs`).

use epssn_spec::load::{build_spec_path, per_spec_file};
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    // The memory map of the build's configuration: `memory.x` for EPSSN-S, e.g.
    // `memory-epssn-p.x` for the paper's size (`EPSSN_SPEC`).
    println!("cargo:rerun-if-env-changed=EPSSN_SPEC");
    let root = manifest.join("../..");
    let spec = build_spec_path(&root);
    let spec_file = spec
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    // In `memory/`, not beside Cargo.toml: the linker looks for `memory.x` in its working
    // directory (the crate's) before the search path, so a file there would shadow the
    // configuration's map.
    let own = manifest.join("memory");
    let dir = if own.is_dir() { own } else { root };
    let memory = per_spec_file(&dir, "memory", "x", spec_file);
    std::fs::copy(&memory, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("{}: {e}", memory.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
    if std::env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        // defmt's interned strings need its linker script.
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
