//! Build-time work of the QEMU firmware: puts the repository's `memory.x` (the MPS2-AN500
//! memory map; `memory-<spec stem>.x` for another configuration) on the linker search path.
//! The weight blob and the golden vectors of the boot self-test are embedded by the shared
//! self-test crate (`../boards/selftest/build.rs`).

use epssn_spec::load::{build_spec_path, per_spec_file};
use std::path::PathBuf;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    // The memory map of the build's configuration: the root `memory.x` for EPSSN-S, e.g.
    // `memory-epssn-p.x` for the paper's size (`EPSSN_SPEC`).
    println!("cargo:rerun-if-env-changed=EPSSN_SPEC");
    let root = manifest.join("..");
    let spec = build_spec_path(&root);
    let spec_file = spec
        .file_name()
        .and_then(|n| n.to_str())
        .unwrap_or_default();
    let memory = per_spec_file(&root, "memory", "x", spec_file);
    std::fs::copy(&memory, out.join("memory.x"))
        .unwrap_or_else(|e| panic!("{}: {e}", memory.display()));
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", memory.display());
    if std::env::var_os("CARGO_FEATURE_DEFMT").is_some() {
        // defmt's interned strings need its linker script.
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
