//! Redraws a weights folder's `loss.png` from its `loss.csv` (the training writes both; this
//! serves when the plot's style changes).
//!
//! `cargo build --release -p epssn-train -p host-sim --example loss_plot` (host-sim's features,
//! so burn is not built again), then `target/release/examples/loss_plot DIR...`.

fn main() -> anyhow::Result<()> {
    let dirs: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(!dirs.is_empty(), "usage: loss_plot DIR...");
    for dir in dirs {
        epssn_train::cli::redraw_loss_plot(std::path::Path::new(&dir))?;
        println!("{dir}/loss.png");
    }
    Ok(())
}
