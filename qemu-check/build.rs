//! Links against the board's memory map (the repository's `memory.x`; for the
//! Cortex-M55, `boards/mps3-an547/memory/memory.x`) with the RAM region widened to the board's
//! data memory (4 MiB of SRAM on the MPS2-AN500, 512 KiB of DTCM on the MPS3-AN547): this
//! harness keeps three whole activations of up to 128 KiB on its stack, which the firmware's
//! RAM budget (weights/budgets.json, the board's memory.x) is not meant to hold. FLASH, origins
//! and everything else are the board's.
fn main() {
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").unwrap());
    // The Cortex-M55 build (`--target thumbv8m.main-none-eabihf --features mve`) links against
    // the MPS3-AN547 board's map, its RAM widened to the board's 512 KiB of DTCM.
    let m55 = std::env::var("TARGET").is_ok_and(|t| t.starts_with("thumbv8m"));
    let (map, ram) = if m55 {
        ("../boards/mps3-an547/memory/memory.x", "512K")
    } else {
        ("../memory.x", "4M")
    };
    let root = std::fs::read_to_string(map).unwrap();
    let widened: String = root
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("RAM") && l.contains("LENGTH") {
                let (head, _) = l.split_once("LENGTH").unwrap();
                format!("{head}LENGTH = {ram}\n")
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    assert!(
        widened.contains(&format!("LENGTH = {ram}")),
        "{map} has no RAM region"
    );
    std::fs::write(out.join("memory.x"), widened).unwrap();
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={map}");
}
