//! The firmware the SIL runs: built for the host build's spec (and the update key it embeds),
//! its weight blob, and its flash and RAM from the ELF's sections.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{anyhow, bail, Context, Result};

use crate::target::Target;

/// The weight blob the firmware embeds.
pub(crate) fn firmware_blob() -> Result<Vec<u8>> {
    let path = epssn_reference::weights::firmware_blob_path()?;
    std::fs::read(&path).with_context(|| format!("reading weight blob {}", path.display()))
}

/// Builds the firmware (release; cargo decides whether anything changed) for the spec this
/// host build was generated from, and returns the ELF path. The target directory is
/// `epssn_spec::load::per_spec_dir` of `boards/mps2-an500/target` (EPSSN-S there, any other
/// configuration in `boards/mps2-an500/target/<spec stem>`), so the two never rebuild each
/// other's artefacts.
pub fn build_firmware() -> Result<PathBuf> {
    build_firmware_with(Target::M7, None)
}

/// The test key pair's public half, from the repository root (`update/test-key/`).
pub const TEST_UPDATE_KEY: &str = "update/test-key/public";

/// [`build_firmware`] for `target_core`'s firmware crate (`boards/mps3-an547` for the M55, in
/// its own `target/`, per spec the same way), with a cargo feature of it if given (a test
/// build, in a target directory of its own, `<target>/<feature>`, so it never replaces the
/// shipped build).
pub fn build_firmware_with(target_core: Target, feature: Option<&str>) -> Result<PathBuf> {
    let dir = epssn_spec::load::repo_root().join(target_core.crate_dir());
    let spec_file = epssn::config::SPEC_FILE_NAME;
    let mut target = epssn_spec::load::per_spec_dir(&dir.join("target"), spec_file);
    let mut cargo = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
    cargo.args(["build", "--release", "--quiet"]);
    if let Some(f) = feature {
        target = target.join(f);
        cargo.args(["--features", f]);
    }
    // The update key the firmware embeds: the caller's `EPSSN_UPDATE_KEY` (the key the
    // images it pushes are signed with), else the test key, named here explicitly (the
    // firmware's release build takes no key by default).
    if std::env::var_os("EPSSN_UPDATE_KEY").is_none() {
        cargo.env("EPSSN_UPDATE_KEY", TEST_UPDATE_KEY);
    }
    let status = cargo
        .arg("--target-dir")
        .arg(&target)
        .current_dir(&dir)
        // The firmware is built from the same spec as this host tool (specs live in weights/).
        .env("EPSSN_SPEC", Path::new("weights").join(spec_file))
        // The host build's variables must not leak into the cross build.
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("RUSTFLAGS")
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env_remove("CARGO_BUILD_TARGET")
        .stdout(Stdio::null())
        .status()
        .context("running cargo build for the firmware")?;
    if !status.success() {
        bail!("firmware build failed ({status})");
    }
    Ok(target_core.elf_in(&target))
}

/// Flash and static RAM of the ELF, from its section sizes.
pub fn elf_sizes(elf: &Path) -> Result<(u64, u64)> {
    use object::{Object, ObjectSection};
    let bytes = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let file = object::File::parse(&*bytes).map_err(|e| anyhow!("parsing ELF: {e}"))?;
    let size = |name: &str| {
        file.section_by_name(name)
            .map(|s| s.size())
            .unwrap_or_default()
    };
    let flash = size(".vector_table") + size(".text") + size(".rodata") + size(".data");
    // .axisram: the STM32H743 board's buffers in AXI SRAM (absent in the QEMU build).
    let ram = size(".data") + size(".bss") + size(".uninit") + size(".axisram");
    if flash == 0 || ram == 0 {
        bail!(
            "{}: no .text/.bss sections (not the firmware?)",
            elf.display()
        );
    }
    Ok((flash, ram))
}
