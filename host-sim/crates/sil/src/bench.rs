//! `host-sim bench`: boots the firmware's self-test in QEMU (Cortex-M7, `-icount shift=0`) and
//! prints, per layer, the multiply-accumulates (from the compiled layer shapes) next to the
//! instructions the target spent (CMSDK timer ticks × 40, printed by the firmware), the
//! instructions per MAC and their ratio to the ISA limit of 0.5 (one `SMLAD` per two MACs).

use std::io::Write;

use anyhow::{bail, Context, Result};
use epssn::config::LAYERS;

/// Options of `host-sim bench`.
#[derive(Debug)]
pub struct BenchOptions {
    /// Firmware ELF (default: build the target's firmware crate in release).
    pub firmware: Option<std::path::PathBuf>,
    /// The core: `m7` (QEMU mps2-an500) or `m55` (QEMU mps3-an547).
    pub target: crate::target::Target,
}

/// Instructions per MAC of the ISA limit: one `SMLAD` does two MACs.
const SMLAD_LIMIT: f64 = 0.5;

/// Instruction count of one `layer NAME[ (view V)]: N instructions` line.
fn parse_line(line: &str) -> Option<(String, u64)> {
    let rest = line.strip_prefix("layer ")?;
    let (name, count) = rest.split_once(": ")?;
    let n = count.strip_suffix(" instructions")?.trim().parse().ok()?;
    Some((name.to_string(), n))
}

/// Runs `host-sim bench`.
pub fn run(args: &BenchOptions, out: &mut impl Write) -> Result<()> {
    let elf = match &args.firmware {
        Some(p) => p.clone(),
        None => crate::firmware::build_firmware_with(args.target, None)?,
    };
    let o = args
        .target
        .qemu()
        .args([
            "-serial",
            "null",
            "-semihosting-config",
            "enable=on,target=native",
        ])
        .args(["-icount", "shift=0", "-kernel"])
        .arg(&elf)
        .output()
        .context("starting qemu-system-arm (is QEMU installed?)")?;
    let console = String::from_utf8_lossy(&o.stdout);
    if !o.status.success() {
        bail!("firmware self-test failed:\n{console}");
    }
    let counts: Vec<(String, u64)> = console.lines().filter_map(parse_line).collect();
    writeln!(
        out,
        "{:<24} {:>12} {:>14} {:>10} {:>9}",
        "layer", "MACs", "instructions", "instr/MAC", "/ 0.5"
    )?;
    let (mut macs_total, mut instr_total) = (0u64, 0u64);
    for (name, instr) in &counts {
        let base = name.split(' ').next().unwrap_or(name);
        // A fused stage ("f0+f1+f2+f3", "cost+d1", "cost+u0+head+soft-argmax") counts the MACs
        // of every layer it names.
        let macs: u64 = base
            .split('+')
            .filter_map(|part| LAYERS.iter().find(|l| l.name == part))
            .map(|l| l.macs() as u64)
            .sum();
        macs_total += macs;
        instr_total += instr;
        let (per, ratio) = if macs > 0 {
            let per = *instr as f64 / macs as f64;
            (format!("{per:.2}"), format!("{:.1}", per / SMLAD_LIMIT))
        } else {
            ("-".into(), "-".into())
        };
        writeln!(
            out,
            "{name:<24} {macs:>12} {instr:>14} {per:>10} {ratio:>9}"
        )?;
    }
    let per = instr_total as f64 / macs_total.max(1) as f64;
    writeln!(
        out,
        "{:<24} {:>12} {:>14} {:>10.2} {:>9.1}",
        "total (full pair)",
        macs_total,
        instr_total,
        per,
        per / SMLAD_LIMIT
    )?;
    for line in console
        .lines()
        .filter(|l| l.starts_with("instructions:") || l.starts_with("stack"))
    {
        writeln!(out, "{line}")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn parses_firmware_lines() {
        assert_eq!(
            super::parse_line("layer f0 (view 1): 6939320 instructions"),
            Some(("f0 (view 1)".into(), 6939320))
        );
        assert_eq!(
            super::parse_line("layer cost+u0+head+soft-argmax: 12 instructions"),
            Some(("cost+u0+head+soft-argmax".into(), 12))
        );
        assert_eq!(super::parse_line("self-test: PASS"), None);
    }
}
