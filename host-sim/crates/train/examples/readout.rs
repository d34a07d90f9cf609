//! Study of the depth readout: the float model's head logits read out by the full soft-argmax
//! (what the network and the firmware compute) and by a soft-argmax restricted to a window of
//! ±w bins around each ray's most likely bin, scored with the paper's all-pixel MAE.
//!
//! `cargo build --release -p epssn-train -p host-sim --example readout`, then
//! `target/release/examples/readout WEIGHTS VIEWS DATA...` (each DATA a test folder).

use anyhow::Result;
use std::path::Path;

fn readout(
    logits: &[f32],
    bins: &[f32],
    e: usize,
    a: usize,
    w: Option<usize>,
    lo: f32,
    hi: f32,
) -> Vec<f32> {
    let r = bins.len();
    let mut depth = vec![0f32; e * a];
    for ei in 0..e {
        for ai in 0..a {
            let l = |i: usize| logits[(ei * r + i) * a + ai];
            let best = (0..r).max_by(|&x, &y| l(x).total_cmp(&l(y))).unwrap_or(0);
            let (from, to) = match w {
                Some(w) => (best.saturating_sub(w), (best + w).min(r - 1)),
                None => (0, r - 1),
            };
            let m = l(best);
            let (mut num, mut den) = (0f64, 0f64);
            for (i, &bin) in bins.iter().enumerate().take(to + 1).skip(from) {
                let p = f64::from(l(i) - m).exp();
                num += p * f64::from(bin);
                den += p;
            }
            depth[ei * a + ai] = ((num / den) as f32).clamp(lo, hi);
        }
    }
    depth
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(args.len() >= 3, "usage: readout WEIGHTS VIEWS DATA...");
    let model = epssn_train::FloatModel::load(Path::new(&args[0]))?;
    let views: usize = args[1].parse()?;
    let st = &model.model.statics;
    let (e, a) = st.output_size();
    let windows = [None, Some(8), Some(5), Some(3), Some(2), Some(1), Some(0)];
    for data in &args[2..] {
        let set = epssn_train::data::load_dir(
            Path::new(data),
            views,
            st.input_size(),
            st.output_size(),
            None,
        )?;
        let mut sums = vec![Vec::new(); windows.len()];
        for chunk in set.chunks(16) {
            let refs: Vec<&[Vec<u8>]> = chunk.iter().map(|s| s.views.as_slice()).collect();
            let logits = model.logits_batch(&refs)?;
            for (s, l) in chunk.iter().zip(&logits) {
                let mask = epssn_sim::metrics::mask_from_f32(&s.mask);
                for (k, w) in windows.iter().enumerate() {
                    let d = readout(l, &st.depth_bins, e, a, *w, st.r_min, st.r_max);
                    sums[k].push(epssn_sim::metrics::evaluate(&d, &s.depth, &mask)?);
                }
            }
        }
        for (k, w) in windows.iter().enumerate() {
            let n = sums[k].len() as f64;
            let mae = sums[k].iter().map(|m| m.mae).sum::<f64>() / n;
            let masked = sums[k]
                .iter()
                .map(|m| m.mae_masked)
                .filter(|m| m.is_finite())
                .sum::<f64>()
                / n;
            println!("{data} window {w:?}: MAE {mae:.2} mm, masked {masked:.2} mm");
        }
    }
    Ok(())
}
