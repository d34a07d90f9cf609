//! docs/POSE.md's plot: int8 MAE against the source's pose error, from the
//! `eval-<scene>-<deg>.json` files of the measurement (terrain blue, sphere orange), 0 to 1°, with the tolerance marked.
//!
//! `cargo build --release -p epssn-train -p host-sim --example pose_plot` (host-sim's features, so
//! burn is not built again), then `target/release/examples/pose_plot DIR OUT.png`.

use anyhow::{Context, Result};

fn series(dir: &std::path::Path, scene: &str) -> Result<Vec<(f64, f64)>> {
    let mut pts = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let name = entry?.file_name().to_string_lossy().into_owned();
        let Some(deg) = name
            .strip_prefix(&format!("eval-{scene}-"))
            .and_then(|s| s.strip_suffix(".json"))
        else {
            continue;
        };
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(&name))?)?;
        let mae = v["int8"]["mae"].as_f64().context("int8.mae")?;
        pts.push((deg.parse::<f64>()?, mae));
    }
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(pts)
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (dir, out) = match args.as_slice() {
        [_, dir, out] => (std::path::PathBuf::from(dir), std::path::PathBuf::from(out)),
        _ => anyhow::bail!("usage: pose_plot DIR OUT.png"),
    };
    let terrain = series(&dir, "terrain")?;
    let sphere = series(&dir, "sphere")?;
    // The gate's region: beyond 1° both scenes are long past any usable error (the table in
    // docs/POSE.md goes on to 4°).
    let near = |s: &[(f64, f64)]| s.iter().copied().filter(|p| p.0 <= 1.0).collect::<Vec<_>>();
    let labels = epssn_train::plot::Labels {
        x: "source pose residual (deg)",
        y: "int8 MAE (mm)",
        curves: ["terrain", "sphere"],
        marker: Some((0.05, "tolerance 0.05 deg")),
    };
    epssn_train::plot::plot_two(&out, &near(&terrain), &near(&sphere), &labels)?;
    for (t, s) in terrain.iter().zip(&sphere) {
        println!("{:>6} {:>8.2} {:>8.2}", t.0, t.1, s.1);
    }
    Ok(())
}
