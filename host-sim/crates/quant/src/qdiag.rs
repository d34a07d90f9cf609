//! `host-sim qdiag`: where does the int8 model lose accuracy?
//!
//! The float reference ([`epssn_reference::floatref`]) is run with chosen tensors rounded to the int8 grid
//! the quantiser gave them (`round(x / s)` clamped to `[-128, 127]`, the cost volume's to its
//! codes `[0, 127 − zero point]`, times `s`), and with the
//! weights rounded to their per-channel int8 grid. Each row quantises one thing alone, and the
//! whole model with everything but that one thing, so the table shows both what a tensor costs
//! on its own and what fixing it would buy. The last row is the real int8 library. Figures are
//! depth differences from the float model and MAE against ground truth, both over the mask.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, ensure, Context, Result};
use epssn::config::LAYERS;
use rayon::prelude::*;

use crate::calibration::SearchPixels;
use crate::quantiser::quantise_weights;
use epssn_reference::float::WeightLayout;
use epssn_reference::floatref::{fold_all, run_folded, FoldedWeights};

/// `host-sim qdiag`.
#[derive(Debug)]
pub struct QdiagOptions {
    /// Weights folder: `model.safetensors`, `quantisation.json` (the activation scales) and the
    /// blob `epssn-s.q8.bin`.
    pub weights: PathBuf,
    /// Simulated data folder; its `test/` split is used (held out from training and calibration).
    pub data: PathBuf,
    /// Samples to use (evenly spread over the split).
    pub limit: usize,
    /// Print JSON instead of a table.
    pub json: bool,
}

/// Rounds `x` to the int8 grid of scale `s` whose codes (real value / `s`) span `codes`.
pub fn fake_quant(x: &mut [f32], s: f64, codes: (f32, f32)) {
    let s = s as f32;
    for v in x {
        *v = (*v / s).round().clamp(codes.0, codes.1) * s;
    }
}

/// Weights and biases rounded as the quantiser rounds them (per-channel int8 weights; int32
/// biases at the accumulator scale), returned in float.
pub fn fake_quant_weights(folded: &FoldedWeights, scales: &BTreeMap<String, f64>) -> FoldedWeights {
    let nf = epssn::model::FEATURE_LAYERS;
    let mut input = "input";
    LAYERS
        .iter()
        .zip(folded)
        .enumerate()
        .map(|(i, (l, (w, b)))| {
            if i == nf {
                input = "cost";
            }
            let layout = WeightLayout::of(l);
            let (q, ws) = quantise_weights(w, &layout);
            let mut wq = vec![0f64; w.len()];
            for (o, &s) in ws.iter().enumerate() {
                for k in layout.channel_indices(o) {
                    wq[k] = q[k] as f64 * s;
                }
            }
            let s_in = scales.get(input).copied().unwrap_or(1.0);
            let bq = b
                .iter()
                .zip(&ws)
                .map(|(&b, &s)| (b / (s_in * s)).round() * s_in * s)
                .collect();
            input = l.name;
            (wq, bq)
        })
        .collect()
}

/// One configuration: which tensors are rounded and whether the weights are.
#[derive(Clone, Debug)]
struct Config {
    label: String,
    tensors: Vec<String>,
    weights: bool,
}

/// Runs `host-sim qdiag`.
pub fn run(args: &QdiagOptions) -> Result<()> {
    let weights = epssn_reference::safetensors_io::load_float_weights(
        &args.weights.join("model.safetensors"),
    )?;
    let scales = activation_scales(&args.weights)?;
    let blob = std::fs::read(args.weights.join(epssn_reference::weights::BLOB_FILE))
        .with_context(|| format!("reading the blob in {}", args.weights.display()))?;
    let model =
        epssn::model::Model::from_blob(&blob).map_err(|e| anyhow!("int8 blob refused: {e:?}"))?;
    let dirs = epssn_sim::dataset::sample_dirs(&args.data, epssn_sim::scene::Split::Test)?;
    ensure!(!dirs.is_empty(), "no samples under {}", args.data.display());
    let step = (dirs.len() / args.limit.max(1)).max(1);
    let dirs: Vec<_> = dirs.into_iter().step_by(step).take(args.limit).collect();
    let names: Vec<String> = scales.keys().filter(|k| *k != "input").cloned().collect();
    let configs = configs(&names);
    let folded = fold_all(&weights)?;
    let folded_q = fake_quant_weights(&folded, &scales);
    let views_n = epssn_reference::weights::int8_views(&args.weights)?;
    let ctx = SampleRun {
        configs: &configs,
        folded: &folded,
        folded_q: &folded_q,
        scales: &scales,
        model: &model,
        views: views_n,
    };
    let per_sample: Vec<Vec<(f64, f64, f64)>> = dirs
        .par_iter()
        .map(|d| ctx.rows(d))
        .collect::<Result<_>>()?;
    let labels = configs
        .iter()
        .map(|c| c.label.clone())
        .chain(["int8 library".to_string()]);
    let table = mean_rows(labels, &per_sample);
    print_table(args, &table, per_sample.len())
}

/// The activation scales in the folder's `quantisation.json`.
fn activation_scales(weights: &Path) -> Result<BTreeMap<String, f64>> {
    let qpath = weights.join("quantisation.json");
    let qjson: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&qpath).with_context(|| format!("reading {}", qpath.display()))?,
    )
    .with_context(|| format!("parsing {}", qpath.display()))?;
    serde_json::from_value(qjson["quantisation"]["activation_scales"].clone())
        .map_err(|e| anyhow!("{}: no activation_scales ({e})", qpath.display()))
}

/// The table's rows: float, weights only, each tensor alone, all but each tensor, all but
/// the weights, and everything (the float emulation of the int8 model).
fn configs(names: &[String]) -> Vec<Config> {
    let mut configs = vec![Config {
        label: "float".into(),
        tensors: vec![],
        weights: false,
    }];
    configs.push(Config {
        label: "weights only".into(),
        tensors: vec![],
        weights: true,
    });
    for n in names {
        configs.push(Config {
            label: format!("{n} only"),
            tensors: vec![n.clone()],
            weights: false,
        });
    }
    for n in names {
        configs.push(Config {
            label: format!("all but {n}"),
            tensors: names.iter().filter(|m| *m != n).cloned().collect(),
            weights: true,
        });
    }
    configs.push(Config {
        label: "all but weights".into(),
        tensors: names.to_vec(),
        weights: false,
    });
    configs.push(Config {
        label: "all (float emulation)".into(),
        tensors: names.to_vec(),
        weights: true,
    });
    configs
}

/// What every sample is run with.
struct SampleRun<'a> {
    configs: &'a [Config],
    folded: &'a FoldedWeights,
    folded_q: &'a FoldedWeights,
    scales: &'a BTreeMap<String, f64>,
    model: &'a epssn::model::Model<'a>,
    views: usize,
}

impl SampleRun<'_> {
    /// One sample's (diff from float, MAE vs GT, MAE over all pixels) per config, then the
    /// library's.
    fn rows(&self, dir: &Path) -> Result<Vec<(f64, f64, f64)>> {
        // The codes a tensor's int8 values stand for: the cost volume's follow the blob's zero
        // point.
        let cost_zero = self.model.cost_zero_point();
        let codes = |name: &str| {
            let (lo, hi) = crate::quantiser::codes(name, cost_zero);
            (lo as f32, hi as f32)
        };
        let s = epssn_sim::dataset::Sample::load(dir)?;
        let views = s.polar_views_u8();
        let refs: Vec<&[u8]> = views
            .iter()
            .take(self.views)
            .map(|v| v.as_slice())
            .collect();
        let mask = SearchPixels::Mask.scored(&s.mask);
        let mut float_depth = Vec::new();
        let mut rows = Vec::new();
        for c in self.configs {
            let w = if c.weights {
                self.folded_q
            } else {
                self.folded
            };
            let mut hook = |name: &str, x: &mut [f32]| {
                if c.tensors.iter().any(|t| t == name) {
                    if let Some(&sc) = self.scales.get(name) {
                        fake_quant(x, sc, codes(name));
                    }
                }
            };
            let t = run_folded(w, &refs, &mut hook)?;
            if float_depth.is_empty() {
                float_depth = t.depth.clone();
            }
            rows.push(diff_and_mae(&t.depth, &float_depth, &s.depth, &mask)?);
        }
        let mut ws = Box::new(epssn::model::Workspace::new());
        let dq = epssn_reference::int8::depth_metres(self.model, &refs, &mut ws)?;
        rows.push(diff_and_mae(&dq, &float_depth, &s.depth, &mask)?);
        Ok(rows)
    }
}

/// Each row's means over the samples; samples with an empty mask (NaN) do not count.
fn mean_rows(
    labels: impl Iterator<Item = String>,
    per_sample: &[Vec<(f64, f64, f64)>],
) -> Vec<(String, f64, f64, f64)> {
    labels
        .enumerate()
        .map(|(i, label)| {
            let valid: Vec<(f64, f64, f64)> = per_sample
                .iter()
                .map(|rows| rows[i])
                .filter(|(d, m, _)| d.is_finite() && m.is_finite())
                .collect();
            let k = valid.len().max(1) as f64;
            let (d, m, a) = valid.iter().fold((0.0, 0.0, 0.0), |(d, m, a), (x, y, z)| {
                (d + x / k, m + y / k, a + z / k)
            });
            (label, d, m, a)
        })
        .collect()
}

/// The table as text or JSON (`--json`).
fn print_table(
    args: &QdiagOptions,
    table: &[(String, f64, f64, f64)],
    samples: usize,
) -> Result<()> {
    if args.json {
        let rows: Vec<_> = table
            .iter()
            .map(|(l, d, m, a)| {
                serde_json::json!({"config": l, "vs_float_mm": d, "mae_mm": m, "mae_all_pixels_mm": a})
            })
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&serde_json::json!({
                "weights": args.weights.display().to_string(),
                "samples": samples,
                "rows": rows,
            }))?
        );
    } else {
        println!(
            "{} samples of {}; depth |int8 − float| and MAE vs ground truth over the mask, and the paper's MAE over all pixels, mm",
            samples,
            args.data.join("test").display()
        );
        println!(
            "{:<24} {:>10} {:>10} {:>10}",
            "quantised", "vs float", "MAE", "MAE all"
        );
        for (l, d, m, a) in table {
            println!("{l:<24} {d:>10.2} {m:>10.2} {a:>10.2}");
        }
    }
    Ok(())
}

/// Mean |a − float| and mean |a − gt| over the mask (NaN for an empty mask), and the paper's
/// MAE over every pixel, in mm.
fn diff_and_mae(a: &[f32], float: &[f32], gt: &[f32], mask: &[bool]) -> Result<(f64, f64, f64)> {
    ensure!(a.len() == float.len() && a.len() == gt.len() && a.len() == mask.len());
    let (mut d, mut e, mut n) = (0f64, 0f64, 0usize);
    for i in 0..a.len() {
        if mask[i] {
            d += (a[i] - float[i]).abs() as f64;
            e += (a[i] - gt[i]).abs() as f64;
            n += 1;
        }
    }
    let k = 1000.0 / n as f64;
    let clamped = epssn_sim::metrics::clamp_labels(gt);
    Ok((d * k, e * k, epssn_sim::metrics::mae(a, &clamped, None)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fake_quant_rounds_to_the_grid_and_saturates() {
        let mut x = [0.26f32, -0.24, 100.0, -100.0, 0.0];
        fake_quant(&mut x, 0.5, (-128.0, 127.0));
        assert_eq!(x, [0.5, -0.0, 63.5, -64.0, 0.0]);
        // The unsigned cost volume's codes.
        let mut x = [0.26f32, -0.24, 100.0, 200.0];
        fake_quant(&mut x, 0.5, (0.0, 255.0));
        assert_eq!(x, [0.5, 0.0, 100.0, 127.5]);
    }
}
