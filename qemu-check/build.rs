//! Links against the repository's memory map (`memory.x` at the root) with the RAM region
//! widened to the board's 4 MiB of data SRAM: this harness keeps three whole activations of
//! up to 128 KiB on its stack, which the firmware's RAM budget (weights/budgets.json, the
//! root memory.x) is not meant to hold. FLASH, origins and everything else are the root's.
fn main() {
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let root = std::fs::read_to_string("../memory.x").unwrap();
    let widened: String = root
        .lines()
        .map(|l| {
            if l.trim_start().starts_with("RAM") && l.contains("LENGTH") {
                let (head, _) = l.split_once("LENGTH").unwrap();
                format!("{head}LENGTH = 4M\n")
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    assert!(
        widened.contains("LENGTH = 4M"),
        "memory.x has no RAM region"
    );
    std::fs::write(out.join("memory.x"), widened).unwrap();
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=../memory.x");
}
