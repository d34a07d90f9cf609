//! How far the burn model (what training optimises) and the f64 reference network (what
//! `host-sim eval` and `run` score with) read apart on the same weights and images.
//!
//! ```sh
//! cargo run --release -p epssn-train --example float_agreement -- weights/general DATA [LIMIT]
//! ```
//!
//! Prints the largest and mean per-pixel difference (mm) and the two models' all-pixel MAE,
//! both on the soft-argmax before the no-return decision (the burn model's training output).

use std::path::PathBuf;

use anyhow::{Context, Result};
use epssn_eval::data::{load_dir, split_dir};
use epssn_train::FloatModel;

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let weights = PathBuf::from(args.next().context("usage: WEIGHTS DATA [LIMIT]")?);
    let data = PathBuf::from(args.next().context("usage: WEIGHTS DATA [LIMIT]")?);
    let limit = args.next().map(|l| l.parse()).transpose()?;
    let model = FloatModel::load(&weights)?;
    let st = model.statics();
    let views = epssn_reference::weights::trained_views(&weights)?;
    let dir = split_dir(&data, "test").unwrap_or(data);
    let set = load_dir(&dir, views, st.input_size(), st.output_size(), limit)?;
    let bundle = epssn_reference::weights::load(&weights)?;
    let folded = epssn_reference::floatref::fold_all(&bundle.float)?;
    let (mut largest, mut sum, mut n) = (0f64, 0f64, 0usize);
    let (mut mae_burn, mut mae_ref) = (0f64, 0f64);
    for s in &set {
        let burn = model.predict_batch(&[s.views.as_slice()])?.remove(0);
        let views: Vec<&[u8]> = s.views.iter().map(Vec::as_slice).collect();
        let reference = epssn_reference::floatref::run_folded(&folded, &views, &mut |_, _| {})?;
        for (a, b) in burn.iter().zip(&reference.soft_depth) {
            let d = 1000.0 * (a - b).abs() as f64;
            largest = largest.max(d);
            sum += d;
            n += 1;
        }
        let mask = epssn_sim::metrics::mask_from_f32(&s.mask);
        mae_burn += epssn_sim::metrics::evaluate(&burn, &s.depth, &mask)?.mae;
        mae_ref += epssn_sim::metrics::evaluate(&reference.soft_depth, &s.depth, &mask)?.mae;
    }
    let maps = set.len().max(1) as f64;
    println!(
        "{} maps: burn vs f64 reference: largest {largest:.4} mm, mean {:.5} mm per pixel; \
         all-pixel MAE burn {:.4} mm, reference {:.4} mm",
        set.len(),
        sum / n.max(1) as f64,
        mae_burn / maps,
        mae_ref / maps
    );
    Ok(())
}
