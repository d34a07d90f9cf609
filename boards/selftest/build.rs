//! Build-time work of the boot self-test every board runs:
//! - embeds the weight blob named by `weights/FIRMWARE_WEIGHTS` (or `EPSSN_BLOB`) after
//!   checking it with the library's own loader on the host: CRC, spec hash, shapes and every
//!   accumulator bound, so a bad blob fails the build, not the vehicle;
//! - runs the library on the host on the fixed pair of synthetic images (`epssn::golden`) and
//!   stores the depth map as the golden vector of the boot self-test: the firmware on the target must reproduce the
//!   x86 bits exactly (flash holds the map's CRC-32);
//! - embeds the public key that signed model updates must verify against, from
//!   `EPSSN_UPDATE_KEY` (a 32-byte file, `host-sim keygen`'s DIR/public; absolute or from the
//!   repository root). A release build without it fails: the test key is taken only when named
//!   (`EPSSN_UPDATE_KEY=update/test-key/public`); a debug build falls back to it.

use std::path::{Path, PathBuf};

use epssn::config;
use epssn::model::Model;

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let root = manifest.join("../..");
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap());

    println!(
        "cargo:rerun-if-changed={}",
        root.join("weights/FIRMWARE_WEIGHTS").display()
    );
    println!("cargo:rerun-if-env-changed=EPSSN_BLOB");
    let blob_path = match std::env::var("EPSSN_BLOB") {
        Ok(p) => PathBuf::from(p),
        Err(_) => epssn_spec::load::firmware_blob(&root, config::SPEC_FILE_NAME)
            .unwrap_or_else(|e| panic!("{e}")),
    };
    println!("cargo:rerun-if-changed={}", blob_path.display());
    let blob = std::fs::read(&blob_path)
        .unwrap_or_else(|e| panic!("weight blob {}: {e}", blob_path.display()));
    let model = Model::from_blob(&blob)
        .unwrap_or_else(|e| panic!("weight blob {} refused: {e:?}", blob_path.display()));
    std::fs::write(out.join("weights.bin"), &blob).unwrap();
    write(&out, "update_key.bin", &update_key(&root));

    // The golden pair and its depth map's CRC, from the library's one definition
    // (`epssn::golden`, which `host-sim sign` also runs on an update's blob).
    let depth = epssn::golden::depth(&model).unwrap();
    write(&out, "selftest_reference.bin", &epssn::golden::image(1));
    write(&out, "selftest_source.bin", &epssn::golden::image(2));
    // Only its CRC goes into flash (the target compares CRCs).
    let crc = epssn::golden::depth_crc(&depth);
    write(
        &out,
        "selftest_depth_crc.rs",
        format!("0x{crc:08x}").as_bytes(),
    );
}

/// The test key pair's public half (its private half signs the tests' and the SIL's images).
const TEST_KEY: &str = "update/test-key/public";

/// The update key of this build: `EPSSN_UPDATE_KEY`, else (debug builds only) the test key.
fn update_key(root: &Path) -> [u8; 32] {
    println!("cargo:rerun-if-env-changed=EPSSN_UPDATE_KEY");
    let release = std::env::var("PROFILE").is_ok_and(|p| p == "release");
    let path = match std::env::var("EPSSN_UPDATE_KEY") {
        Ok(p) => root.join(p),
        Err(_) if release => panic!(
            "a release firmware needs the public key model updates are signed with: \
             EPSSN_UPDATE_KEY=DIR/public (host-sim keygen --out DIR), or the test key named \
             explicitly, EPSSN_UPDATE_KEY={TEST_KEY}"
        ),
        Err(_) => root.join(TEST_KEY),
    };
    println!("cargo:rerun-if-changed={}", path.display());
    let bytes =
        std::fs::read(&path).unwrap_or_else(|e| panic!("update key {}: {e}", path.display()));
    bytes.as_slice().try_into().unwrap_or_else(|_| {
        panic!(
            "update key {}: {} bytes, a public key has 32",
            path.display(),
            bytes.len()
        )
    })
}

fn write(dir: &Path, name: &str, bytes: &[u8]) {
    std::fs::write(dir.join(name), bytes).unwrap();
}
