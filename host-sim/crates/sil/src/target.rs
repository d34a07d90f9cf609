//! The emulated cores the firmware runs on: the Cortex-M7 (`boards/mps2-an500`, QEMU `mps2-an500`,
//! the default) and the Cortex-M55 (`boards/mps3-an547`, QEMU `mps3-an547`). Each has its
//! firmware crate, ELF, QEMU machine and budgets file; `sil` and `bench` take `--target`.

use std::path::{Path, PathBuf};
use std::process::Command;

use epssn_spec::load::per_spec_file;

/// A core and its board under QEMU.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Target {
    /// Cortex-M7 on QEMU `mps2-an500` (`boards/mps2-an500`).
    #[default]
    M7,
    /// Cortex-M55 on QEMU `mps3-an547` (`boards/mps3-an547`).
    M55,
}

impl Target {
    /// The firmware crate, relative to the repository root.
    pub fn crate_dir(self) -> &'static str {
        match self {
            Target::M7 => "boards/mps2-an500",
            Target::M55 => "boards/mps3-an547",
        }
    }

    /// The release ELF inside a target directory of the firmware crate.
    pub fn elf_in(self, target_dir: &Path) -> PathBuf {
        match self {
            Target::M7 => target_dir.join("thumbv7em-none-eabihf/release/epssn-mps2-an500"),
            Target::M55 => target_dir.join("thumbv8m.main-none-eabihf/release/epssn-mps3-an547"),
        }
    }

    /// `qemu-system-arm` on the target's board, no display or monitor; callers add the
    /// serial, semihosting and timing options.
    pub fn qemu(self) -> Command {
        let (machine, cpu) = match self {
            Target::M7 => ("mps2-an500", "cortex-m7"),
            Target::M55 => ("mps3-an547", "cortex-m55"),
        };
        let mut c = Command::new("qemu-system-arm");
        c.args([
            "-machine",
            machine,
            "-cpu",
            cpu,
            "-nographic",
            "-monitor",
            "none",
        ]);
        c
    }

    /// The budgets of the build's spec on this target: `weights/budgets.json` (M7, EPSSN-S),
    /// `weights/budgets-m55.json` (M55), `-<spec stem>` before `.json` for another spec.
    pub fn budgets_path(self) -> PathBuf {
        let weights = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../weights");
        let name = match self {
            Target::M7 => "budgets",
            Target::M55 => "budgets-m55",
        };
        per_spec_file(&weights, name, "json", epssn::config::SPEC_FILE_NAME)
    }

    /// The memory map the target's firmware links with for the build's spec: the repository's
    /// `memory.x` for the Cortex-M7 image, the board's `memory/` for the others.
    pub fn memory_x_path(self) -> PathBuf {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../..");
        let dir = match self {
            Target::M7 => root,
            Target::M55 => root.join(self.crate_dir()).join("memory"),
        };
        per_spec_file(&dir, "memory", "x", epssn::config::SPEC_FILE_NAME)
    }
}
