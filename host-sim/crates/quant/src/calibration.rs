//! Choosing each activation's int8 range: a per-tensor search over calibration percentiles,
//! scored by the real int8 library.
//!
//! One percentile for every tensor is a poor fit: the variance cost volume has a long, thin tail
//! (a squared quantity) while the feature maps are compact, so the range that serves one wastes
//! the other's resolution (`host-sim qdiag` shows the cost volume alone costs more than half of
//! the int8 error). The search starts from one percentile everywhere and then, tensor by tensor
//! in network order, keeps the candidate percentile whose blob gives the smallest mean
//! |int8 − float| depth over the scored pixels of the calibration samples (the ground-truth
//! mask, or every pixel: `quantise --search-pixels`). Every candidate is
//! a complete blob that the library accepts (accumulator bounds included), run by the library
//! itself, so the score is what the firmware will do. Calibration samples come from the training
//! split only.

use std::collections::BTreeMap;

use anyhow::{anyhow, Result};
use epssn::config::{self, LAYERS};
use rayon::prelude::*;
use serde::Serialize;

use crate::quantiser::{quantise, ActivationRanges, Quantised};
use epssn_reference::float::FloatWeights;
use epssn_reference::floatref::FloatTrace;

/// One calibration input with what the search scores against.
#[derive(Clone, Debug)]
pub struct CalibSample {
    /// u8 polar views, reference first.
    pub views: Vec<Vec<u8>>,
    /// Pixels `[E][A]` the search scores: the ground-truth mask, or all of them.
    pub scored: Vec<bool>,
    /// The float model's depth, metres.
    pub float_depth: Vec<f32>,
}

/// Which depth pixels the per-tensor search scores.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SearchPixels {
    /// The ground-truth mask: rays that meet a surface inside the window.
    Mask,
    /// Every pixel of the depth map, as the paper's MAE: on sphere scenes 90 % of the rays
    /// meet nothing and read r_max, and their int8 error counts as much.
    All,
}

impl SearchPixels {
    /// The pixels scored, from a sample's ground-truth mask (1 = surface in the window).
    pub fn scored(self, mask: &[f32]) -> Vec<bool> {
        match self {
            SearchPixels::Mask => epssn_sim::metrics::mask_from_f32(mask),
            SearchPixels::All => vec![true; mask.len()],
        }
    }
}

/// Sorted |x| of every activation tensor over the calibration traces.
pub struct SortedMagnitudes(BTreeMap<String, Vec<f32>>);

impl SortedMagnitudes {
    /// Collects and sorts |x| of every tensor of `traces`.
    pub fn new(traces: &[FloatTrace]) -> Self {
        let mut values: BTreeMap<String, Vec<f32>> = BTreeMap::new();
        for t in traces {
            for (k, v) in t.features.iter().flatten().chain(t.cost_net.iter()) {
                values
                    .entry(k.clone())
                    .or_default()
                    .extend(v.iter().map(|x| x.abs()));
            }
        }
        for v in values.values_mut() {
            v.sort_unstable_by(f32::total_cmp);
        }
        Self(values)
    }

    /// The `percentile`-th percentile of |x| of `tensor` (100 = the maximum).
    pub fn at(&self, tensor: &str, percentile: f64) -> Option<f64> {
        let v = self.0.get(tensor)?;
        let q = (percentile.clamp(0.0, 100.0) / 100.0 * (v.len().max(1) - 1) as f64).round();
        v.get(q as usize).map(|&x| x as f64)
    }

    /// Every tensor's range at one percentile.
    pub fn ranges(&self, percentile: f64) -> ActivationRanges {
        self.0
            .keys()
            .filter_map(|k| Some((k.clone(), self.at(k, percentile)?)))
            .collect()
    }
}

/// The search's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct Search {
    /// Chosen percentile per tensor.
    pub percentiles: BTreeMap<String, f64>,
    /// Mean |int8 − float| depth over the scored pixels of the calibration samples with one percentile
    /// everywhere, mm.
    pub start_mm: f64,
    /// The same after the search, mm.
    pub final_mm: f64,
    /// Candidate blobs scored.
    pub evaluations: usize,
}

/// Mean |int8 − float| depth (mm) over the scored pixels of the blob quantised with `ranges`; `None` if the
/// quantiser or the library refuses it.
pub fn score(
    weights: &FloatWeights,
    ranges: &ActivationRanges,
    samples: &[CalibSample],
) -> Result<Option<(f64, Quantised)>> {
    // The blob's view count does not change its arithmetic: the samples' own views are scored.
    let views = samples.first().map_or(config::VIEWS, |s| s.views.len());
    let Ok(q) = quantise(weights, ranges, views) else {
        return Ok(None);
    };
    let model = epssn::model::Model::from_blob(&q.blob)
        .map_err(|e| anyhow!("the library refuses a quantised blob: {e:?}"))?;
    let per: Vec<f64> = samples
        .par_iter()
        .map_init(
            || Box::new(epssn::model::Workspace::new()),
            |ws, s| -> Result<f64> {
                let d = epssn_reference::int8::depth_metres(&model, &s.views, ws)?;
                let (mut sum, mut n) = (0f64, 0usize);
                for ((a, b), &m) in d.iter().zip(&s.float_depth).zip(&s.scored) {
                    if m {
                        sum += (a - b).abs() as f64;
                        n += 1;
                    }
                }
                Ok(if n == 0 { 0.0 } else { 1000.0 * sum / n as f64 })
            },
        )
        .collect::<Result<_>>()?;
    Ok(Some((per.iter().sum::<f64>() / per.len().max(1) as f64, q)))
}

/// Tensors in network order: the feature layers, the cost volume, the cost-net layers.
fn network_order() -> Vec<String> {
    let nf = epssn::model::FEATURE_LAYERS;
    let mut names: Vec<String> = LAYERS[..nf].iter().map(|l| l.name.to_string()).collect();
    names.push("cost".into());
    names.extend(LAYERS[nf..].iter().map(|l| l.name.to_string()));
    names
}

/// Coordinate search over `candidates` (percentiles), starting from `start` everywhere, for
/// `passes` sweeps in network order.
pub fn search(
    weights: &FloatWeights,
    magnitudes: &SortedMagnitudes,
    samples: &[CalibSample],
    start: f64,
    candidates: &[f64],
    passes: usize,
) -> Result<(ActivationRanges, Search)> {
    let names = network_order();
    let mut chosen: BTreeMap<String, f64> = names.iter().map(|n| (n.clone(), start)).collect();
    let ranges_of = |chosen: &BTreeMap<String, f64>| -> ActivationRanges {
        chosen
            .iter()
            .filter_map(|(k, &p)| Some((k.clone(), magnitudes.at(k, p)?)))
            .collect()
    };
    let (start_mm, _) = score(weights, &ranges_of(&chosen), samples)?
        .ok_or_else(|| anyhow!("the starting percentile {start} gives no valid blob"))?;
    let mut best = start_mm;
    let mut evaluations = 1;
    for _ in 0..passes {
        for name in &names {
            for &p in candidates {
                if chosen[name] == p {
                    continue;
                }
                let mut trial = chosen.clone();
                trial.insert(name.clone(), p);
                evaluations += 1;
                if let Some((mm, _)) = score(weights, &ranges_of(&trial), samples)? {
                    if mm < best {
                        best = mm;
                        chosen = trial;
                    }
                }
            }
        }
    }
    let ranges = ranges_of(&chosen);
    Ok((
        ranges,
        Search {
            percentiles: chosen,
            start_mm,
            final_mm: best,
            evaluations,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use epssn_reference::float::random_float_weights;
    use epssn_sim::synthetic::{synthetic_image, Rng};

    #[test]
    fn search_scores_the_mask_or_every_pixel() {
        let mask = [1.0, 0.0, 1.0, 0.0];
        assert_eq!(SearchPixels::Mask.scored(&mask), [true, false, true, false]);
        assert_eq!(SearchPixels::All.scored(&mask), [true; 4]);
    }

    #[test]
    fn search_keeps_its_books_and_never_ends_worse_than_it_starts() -> Result<()> {
        let weights = random_float_weights(5);
        let mut rng = Rng(11);
        let views = vec![
            synthetic_image(&mut rng, 0.2),
            synthetic_image(&mut rng, 0.3),
        ];
        let refs: Vec<&[u8]> = views.iter().map(|v| v.as_slice()).collect();
        let trace = epssn_reference::floatref::run(&weights, &refs)?;
        let sample = CalibSample {
            scored: vec![true; trace.depth.len()],
            float_depth: trace.depth.clone(),
            views,
        };
        let magnitudes = SortedMagnitudes::new(std::slice::from_ref(&trace));
        let samples = [sample];
        let (ranges, s) = search(&weights, &magnitudes, &samples, 100.0, &[100.0, 99.0], 1)?;
        assert!(s.final_mm <= s.start_mm);
        assert_eq!(s.evaluations, 1 + network_order().len());
        // The reported figure is the chosen blob's own score.
        let (again, _) = score(&weights, &ranges, &samples)?.expect("chosen blob is valid");
        assert_eq!(again, s.final_mm);
        for (name, p) in &s.percentiles {
            assert_eq!(
                ranges[name],
                magnitudes.at(name, *p).expect("tensor exists")
            );
        }
        Ok(())
    }
}
