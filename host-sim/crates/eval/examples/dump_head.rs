//! The float network's head logits of every sample of a split, with the ground truth, as one
//! raw little-endian f32 file for analysis outside Rust (`scripts/no-return-ceiling.py`):
//! per sample the logits `[E][R][A]`, then the ground-truth mask `[E][A]` (1 = a return inside
//! the window) and depth `[E][A]` (metres).
//!
//! ```sh
//! cargo run --release -p epssn-eval --example dump_head -- weights/general DATA/sphere-val OUT.f32
//! ```

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use epssn::config::{DEPTH_COLUMNS, DEPTH_RANGE_BINS, DEPTH_ROWS, INPUT_COLUMNS, INPUT_RANGE_BINS};
use epssn_eval::data::{load_dir, split_dir};
use epssn_reference::floatref;

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: WEIGHTS DATA OUT";
    let weights = PathBuf::from(args.next().context(usage)?);
    let data = PathBuf::from(args.next().context(usage)?);
    let out = PathBuf::from(args.next().context(usage)?);
    let views = epssn_reference::weights::trained_views(&weights)?;
    let float =
        epssn_reference::safetensors_io::load_float_weights(&weights.join("model.safetensors"))?;
    let folded = floatref::fold_all(&float)?;
    let dir = split_dir(&data, "test").unwrap_or(data);
    let set = load_dir(
        &dir,
        views,
        (INPUT_RANGE_BINS, INPUT_COLUMNS),
        (DEPTH_ROWS, DEPTH_COLUMNS),
        None,
    )?;
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(&out).with_context(|| format!("creating {}", out.display()))?,
    );
    for s in &set {
        let v: Vec<&[u8]> = s.views.iter().map(Vec::as_slice).collect();
        let t = floatref::run_folded(&folded, &v, &mut |_, _| {})?;
        let head = t
            .cost_net
            .get("head")
            .context("no head logits in the trace")?;
        for x in head.iter().chain(&s.mask).chain(&s.depth) {
            f.write_all(&x.to_le_bytes())?;
        }
    }
    f.flush()?;
    println!(
        "{} samples of {} × {} × {} logits, mask and depth to {}",
        set.len(),
        DEPTH_ROWS,
        DEPTH_RANGE_BINS,
        DEPTH_COLUMNS,
        out.display()
    );
    Ok(())
}
