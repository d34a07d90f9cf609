//! docs/POSE.md's plot: int8 MAE against the source's pose error, from the
//! `eval-<scene>-<deg>.json` files of the measurement (terrain blue, sphere orange).
//!
//! `cargo run --release -p epssn-train --example pose_plot -- DIR OUT.png`

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
    epssn_train::plot::plot_losses(&out, &terrain, &sphere)?;
    for (t, s) in terrain.iter().zip(&sphere) {
        println!("{:>6} {:>8.2} {:>8.2}", t.0, t.1, s.1);
    }
    Ok(())
}
