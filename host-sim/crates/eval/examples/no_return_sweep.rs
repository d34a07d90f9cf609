//! The no-return decision's threshold against accuracy: for each threshold τ on a ray's
//! end-bin mass (the spec's `output.no_return_mass`), the all-pixel MAE, the return mask's
//! precision and recall (each map's averaged, and pooled over every ray) and the chamfer distance between the prediction's own points and the
//! ground truth's, from the float reference network on held-out samples.
//!
//! ```sh
//! cargo run --release -p epssn-eval --example no_return_sweep -- weights/general DATA/sphere [LIMIT]
//! ```
//!
//! τ = 0 is the soft-argmax without a decision. The rule is the device's (QUANTISATION.md
//! "No-return decision"): last-bin mass ≥ τ reads r_max, else first-bin mass ≥ τ reads r_min.
//! Run on a validation split, it chooses the threshold a model's blob carries (`host-sim
//! quantise --no-return-mass τ`, or `--restamp DIR --no-return-mass τ` for a blob made).

use std::path::PathBuf;

use anyhow::{Context, Result};
use epssn_eval::data::{load_dir, split_dir};
use epssn_reference::floatref;
use epssn_sim::metrics;

const THRESHOLDS: [f64; 13] = [
    0.0, 0.05, 0.1, 0.15, 0.2, 0.225, 0.25, 0.275, 0.3, 0.4, 0.5, 0.6, 0.8,
];

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: WEIGHTS DATA [LIMIT]";
    let weights = PathBuf::from(args.next().context(usage)?);
    let data = PathBuf::from(args.next().context(usage)?);
    let limit = args.next().map(|l| l.parse()).transpose()?;
    let views = epssn_reference::weights::trained_views(&weights)?;
    // The float weights alone: a training checkpoint has no blob yet.
    let float =
        epssn_reference::safetensors_io::load_float_weights(&weights.join("model.safetensors"))?;
    let folded = floatref::fold_all(&float)?;
    let dir = split_dir(&data, "test").unwrap_or(data);
    let size_in = (
        epssn::config::INPUT_RANGE_BINS,
        epssn::config::INPUT_COLUMNS,
    );
    let size_out = (epssn::config::DEPTH_ROWS, epssn::config::DEPTH_COLUMNS);
    let set = load_dir(&dir, views, size_in, size_out, limit)?;
    let mut scores = vec![Vec::new(); THRESHOLDS.len()];
    for s in &set {
        let v: Vec<&[u8]> = s.views.iter().map(Vec::as_slice).collect();
        let t = floatref::run_folded(&folded, &v, &mut |_, _| {})?;
        let mask = metrics::mask_from_f32(&s.mask);
        for (tau, out) in THRESHOLDS.iter().zip(&mut scores) {
            let depth: Vec<f32> = (0..t.soft_depth.len())
                .map(|i| floatref::decide(t.soft_depth[i], t.near_mass[i], t.far_mass[i], *tau))
                .collect();
            out.push(metrics::evaluate(&depth, &s.depth, &mask)?);
        }
    }
    println!("{} maps of {}", set.len(), dir.display());
    println!(
        "| τ | MAE mm | precision % | recall % | pooled precision % | pooled recall % | CD (own points) | CD (GT-masked) |"
    );
    println!("| --- | --- | --- | --- | --- | --- | --- | --- |");
    for (tau, m) in THRESHOLDS.iter().zip(&scores) {
        let mean = |f: &dyn Fn(&metrics::Metrics) -> f64| {
            let v: Vec<f64> = m.iter().map(f).filter(|x| x.is_finite()).collect();
            metrics::mean_std(&v).0.unwrap_or(f64::NAN)
        };
        let acc = metrics::Accuracy::of(m);
        let pct = |v: Option<f64>| 100.0 * v.unwrap_or(f64::NAN);
        println!(
            "| {tau} | {:.2} | {:.1} | {:.1} | {:.1} | {:.1} | {:.3} | {:.3} |",
            mean(&|x| x.mae),
            100.0 * mean(&|x| x.mask_precision),
            100.0 * mean(&|x| x.mask_recall),
            pct(acc.mask_precision_pooled),
            pct(acc.mask_recall_pooled),
            mean(&|x| x.cd),
            mean(&|x| x.cd_gt_masked),
        );
    }
    Ok(())
}
