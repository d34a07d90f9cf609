//! The firmware's budgets (`weights/budgets.json` for EPSSN-S, `weights/budgets-<spec>.json`
//! for another configuration: the one place they are written): the instructions of one
//! streamed depth map, RAM and flash. `host-sim sil` enforces them; the linker enforces RAM and
//! flash through `memory.x` (`memory-<spec>.x`), which must agree (tested below).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use epssn_spec::load::per_spec_file;
use serde::{Deserialize, Serialize};

/// The budgets of the build's spec: `weights/budgets.json` (EPSSN-S) or
/// `weights/budgets-<spec stem>.json`.
pub fn default_path() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../..");
    per_spec_file(
        &root.join("weights"),
        "budgets",
        "json",
        epssn::config::SPEC_FILE_NAME,
    )
}

/// The memory map the firmware of the build's spec links with: `memory.x` (EPSSN-S) or
/// `memory-<spec stem>.x`.
pub fn memory_x_path() -> PathBuf {
    crate::target::Target::M7.memory_x_path()
}

/// The budgets.
#[derive(Serialize, Deserialize, Debug, Clone, Copy, PartialEq, Eq)]
pub struct Budgets {
    /// Instructions of one streamed depth map (the newest frame's features plus the depth
    /// map) on the QEMU Cortex-M7 under `-icount shift=0`.
    pub instructions_per_depth_map: u64,
    /// RAM: `.data + .bss + .uninit` plus the measured stack high-water mark, bytes.
    pub ram_bytes: u64,
    /// Flash: `.vector_table + .text + .rodata + .data`, bytes.
    pub flash_bytes: u64,
}

impl Budgets {
    /// Reads a budgets file.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes =
            std::fs::read(path).with_context(|| format!("reading budgets {}", path.display()))?;
        serde_json::from_slice(&bytes)
            .with_context(|| format!("parsing budgets {}", path.display()))
    }

    /// What exceeds the budgets (empty when everything fits).
    pub fn violations(&self, instructions: &[u32], ram: u64, flash: u64) -> Vec<String> {
        let mut v = Vec::new();
        if let Some(&worst) = instructions.iter().max() {
            if u64::from(worst) > self.instructions_per_depth_map {
                v.push(format!(
                    "a depth map took {worst} instructions, budget {}",
                    self.instructions_per_depth_map
                ));
            }
        }
        if ram > self.ram_bytes {
            v.push(format!("RAM {ram} bytes, budget {}", self.ram_bytes));
        }
        if flash > self.flash_bytes {
            v.push(format!("flash {flash} bytes, budget {}", self.flash_bytes));
        }
        v
    }
}

/// `(FLASH, RAM)` lengths in bytes from a `memory.x` (`LENGTH = 256K`, `2M`, or bytes).
pub fn memory_x_lengths(text: &str) -> Result<(u64, u64)> {
    let length = |region: &str| -> Result<u64> {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(region) && l.contains("LENGTH"))
            .with_context(|| format!("memory.x has no {region} region"))?;
        let value = line
            .split("LENGTH")
            .nth(1)
            .and_then(|r| r.split('=').nth(1))
            .map(str::trim)
            .context("LENGTH without a value")?;
        let (digits, scale) = match value.chars().last() {
            Some('K') => (&value[..value.len() - 1], 1024),
            Some('M') => (&value[..value.len() - 1], 1024 * 1024),
            _ => (value, 1),
        };
        let n: u64 = digits
            .trim()
            .parse()
            .with_context(|| format!("memory.x {region} LENGTH {value}"))?;
        Ok(n * scale)
    };
    let (flash, ram) = (length("FLASH")?, length("RAM")?);
    if flash == 0 || ram == 0 {
        bail!("memory.x: zero-length region");
    }
    Ok((flash, ram))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn memory_x_agrees_with_the_budgets() {
        let b = Budgets::load(&default_path()).unwrap();
        let memory = memory_x_path();
        let (flash, ram) = memory_x_lengths(&std::fs::read_to_string(&memory).unwrap()).unwrap();
        let what = format!("{} vs {}", memory.display(), default_path().display());
        assert_eq!(flash, b.flash_bytes, "FLASH: {what}");
        assert_eq!(ram, b.ram_bytes, "RAM: {what}");
        if epssn::config::SPEC_FILE_NAME == epssn_spec::load::DEFAULT_SPEC_FILE {
            // EPSSN-S's goals: RAM ≤ 128 KiB, flash ≤ 256 KiB (a Cortex-M7 with 128 KiB).
            assert!(b.ram_bytes <= 128 * 1024 && b.flash_bytes <= 256 * 1024);
        }
    }

    #[test]
    fn m55_memory_x_agrees_with_its_budgets() {
        let t = crate::target::Target::M55;
        let b = Budgets::load(&t.budgets_path()).unwrap();
        let memory = t.memory_x_path();
        let (flash, ram) = memory_x_lengths(&std::fs::read_to_string(&memory).unwrap()).unwrap();
        let what = format!("{} vs {}", memory.display(), t.budgets_path().display());
        assert_eq!(flash, b.flash_bytes, "FLASH: {what}");
        assert_eq!(ram, b.ram_bytes, "RAM: {what}");
    }

    #[test]
    fn parses_lengths_and_reports_violations() {
        let text = "MEMORY\n{\n  FLASH : ORIGIN = 0x0, LENGTH = 256K\n  RAM   : ORIGIN = 0x20000000, LENGTH = 2M\n}\n";
        assert_eq!(
            memory_x_lengths(text).unwrap(),
            (256 * 1024, 2 * 1024 * 1024)
        );
        let b = Budgets {
            instructions_per_depth_map: 100,
            ram_bytes: 10,
            flash_bytes: 20,
        };
        assert!(b.violations(&[100, 99], 10, 20).is_empty());
        assert_eq!(b.violations(&[101], 11, 21).len(), 3);
    }
}
