//! Generates, from the model spec in `weights/`, everything the library needs at compile time:
//! size constants, the sonar's angle grids and the warp tables for the fixed roll baseline.
//! The spec's rules and the generated text are `epssn-spec`'s (`check`, `codegen`, with their
//! unit tests), the very crate the library runs, so build-time tables and run-time code cannot
//! disagree; this script only reads the files, calls it and writes `config.rs`.

use epssn_spec::codegen::{config_source, spec_file_source};
use epssn_spec::load::{beam_table_path, build_spec_path, load_beam_table, load_spec};
use std::path::PathBuf;

fn main() {
    check_mve_target();
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let spec_path = build_spec_path(&root);
    println!("cargo:rerun-if-changed={}", spec_path.display());
    println!("cargo:rerun-if-env-changed=EPSSN_SPEC");
    let loaded = load_spec(&spec_path).unwrap_or_else(|e| panic!("{e}"));
    let table = loaded.spec.sonar.beam_table.as_str();
    println!(
        "cargo:rerun-if-changed={}",
        beam_table_path(&root, table).display()
    );
    let beam_deg = load_beam_table(&root, table)
        .unwrap_or_else(|e| panic!("{e}"))
        .centre_deg;
    let mut out =
        config_source(&loaded.spec, &beam_deg, loaded.hash).unwrap_or_else(|e| panic!("{e}"));
    // Absolute, so that `include_str!` finds the file from `OUT_DIR`.
    let spec_file = spec_path.canonicalize().unwrap_or_else(|e| panic!("{e}"));
    out += &spec_file_source(&spec_file);
    let out_path = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("config.rs");
    std::fs::write(&out_path, out).unwrap();
}

/// The `mve` feature's assembly needs a core with Helium; rustc does not report ARM target
/// features to `cfg`, so the build checks the flags it compiles with and names the fix.
fn check_mve_target() {
    if std::env::var_os("CARGO_FEATURE_MVE").is_none()
        || std::env::var("CARGO_CFG_TARGET_ARCH").as_deref() != Ok("arm")
    {
        return;
    }
    let flags = std::env::var("CARGO_ENCODED_RUSTFLAGS").unwrap_or_default();
    let helium = ["cortex-m55", "cortex-m85", "+mve"]
        .iter()
        .any(|f| flags.contains(f));
    assert!(
        helium,
        "the `mve` feature needs a Helium core: build with `-C target-cpu=cortex-m55` (or \
         cortex-m85, or `-C target-feature=+mve`) for thumbv8m.main-none-eabihf"
    );
}
