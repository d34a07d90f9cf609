//! The paper's depth metrics, point clouds from depth maps, and PLY export.
//!
//! - MAE = β / (H·W) · Σ |D̂ − D| with β = 1000 (metres → millimetres), exactly as the paper's
//!   formula reads: the sum runs over **all** H × W = E × A pixels, with the labels D clamped
//!   to `[r_min, r_max]` (a ray that meets nothing reads r_max) ([`Metrics::mae`]; this is the
//!   figure comparable with the paper's Table I). The mean over the ground-truth mask only
//!   (in-window pixels) is reported alongside ([`Metrics::mae_masked`]), so that neither
//!   reading is hidden.
//! - CD = γ · (mean over p ∈ P of min over q ∈ Q of ‖p − q‖² + mean over q ∈ Q of min over
//!   p ∈ P of ‖p − q‖²) with γ = 500, in m² × 500: the symmetric chamfer distance between two
//!   point sets, as the paper has it: P the prediction's own points (the rays where it reports
//!   a return, [`prediction_mask`]), Q the ground truth's (its mask), so a phantom point where
//!   the truth is empty and a surface the prediction missed both count ([`Metrics::cd`]).
//!   Pixels become points through `epssn::geometry::polar_to_cartesian`; nearest neighbours
//!   come from a `kiddo` k-d tree. The older figure, both clouds through the ground-truth
//!   mask, is reported beside it as [`Metrics::cd_gt_masked`] so the change can be read.
//! - The prediction's return mask against the ground-truth mask: precision (of the rays it
//!   reports a return on, the share that has one) and recall (of the rays with a return, the
//!   share it reports).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use epssn::config::{
    DEPTH_COLUMNS, DEPTH_LEN, DEPTH_ROWS, DEPTH_ROW_ELEVATION_RAD, INPUT_COLUMN_AZIMUTH_RAD,
    R_MAX_M, R_MIN_M,
};
use epssn::geometry::{polar_to_cartesian, Polar};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use serde::Serialize;

/// β of the paper's MAE.
pub const MAE_SCALE: f64 = 1000.0;
/// γ of the paper's CD.
pub const CD_SCALE: f64 = 500.0;

/// Metrics of one predicted depth map against its ground truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Metrics {
    /// The paper's MAE: over every pixel, labels clamped to the window, mm.
    pub mae: f64,
    /// MAE over the ground-truth mask only, mm (NaN for an empty mask).
    pub mae_masked: f64,
    /// The paper's chamfer distance (γ = 500) between the prediction's own points (its
    /// [`prediction_mask`]) and the ground truth's (its mask).
    pub cd: f64,
    /// The chamfer distance with both clouds taken through the ground-truth mask (the figure
    /// reported as `cd` before 2026-12): blind to phantom points and missed surfaces.
    pub cd_gt_masked: f64,
    /// Of the rays the prediction reports a return on, the share the ground truth has one on
    /// (NaN when it reports none).
    pub mask_precision: f64,
    /// Of the rays the ground truth has a return on, the share the prediction reports (NaN for
    /// an empty ground-truth mask).
    pub mask_recall: f64,
    /// Pixels in the mask.
    pub valid_pixels: usize,
    /// Pixels the prediction reports a return on.
    pub predicted_pixels: usize,
    /// Pixels both report a return on (the true returns).
    pub true_returns: usize,
    /// Pixels in the map.
    pub pixels: usize,
}

/// Mean and (population) standard deviation of per-sample figures, as the paper reports them;
/// `None` for no values.
pub fn mean_std(v: &[f64]) -> (Option<f64>, Option<f64>) {
    if v.is_empty() {
        return (None, None);
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let s = (v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64).sqrt();
    (Some(m), Some(s))
}

/// `β / n · Σ |a − b|` over the pixels where `mask` is set (all pixels without a mask).
/// NaN when no pixel counts.
pub fn mae(pred: &[f32], gt: &[f32], mask: Option<&[bool]>) -> Result<f64> {
    ensure!(
        pred.len() == gt.len(),
        "MAE: prediction has {} pixels, ground truth {}",
        pred.len(),
        gt.len()
    );
    if let Some(m) = mask {
        ensure!(m.len() == gt.len(), "MAE: mask size differs from the map");
    }
    let mut sum = 0.0;
    let mut n = 0usize;
    for i in 0..gt.len() {
        if mask.is_none_or(|m| m[i]) {
            sum += (pred[i] as f64 - gt[i] as f64).abs();
            n += 1;
        }
    }
    Ok(if n == 0 {
        f64::NAN
    } else {
        MAE_SCALE * sum / n as f64
    })
}

/// Symmetric chamfer distance `γ · (mean_p min_q ‖p−q‖² + mean_q min_p ‖p−q‖²)`.
/// 0 for two empty clouds, NaN when exactly one is empty.
pub fn chamfer(a: &[[f64; 3]], b: &[[f64; 3]]) -> Result<f64> {
    match (a.is_empty(), b.is_empty()) {
        (true, true) => return Ok(0.0),
        (true, false) | (false, true) => return Ok(f64::NAN),
        _ => {}
    }
    Ok(CD_SCALE * (mean_nearest_sq(a, b)? + mean_nearest_sq(b, a)?))
}

/// Mean over `from` of the squared distance to the nearest point of `to` (non-empty).
fn mean_nearest_sq(from: &[[f64; 3]], to: &[[f64; 3]]) -> Result<f64> {
    let tree: ImmutableKdTree<f64, 3> = ImmutableKdTree::new_from_slice(to)
        .map_err(|e| anyhow::anyhow!("building the k-d tree: {e:?}"))?;
    let sum: f64 = from
        .iter()
        .map(|p| {
            tree.query(p)
                .nearest_one::<SquaredEuclidean<f64>>()
                .execute()
                .distance
        })
        .sum();
    Ok(sum / from.len() as f64)
}

/// Points (sonar frame, metres) of the pixels of an E × A depth map where `mask` is set.
pub fn depth_points(depth: &[f32], mask: &[bool]) -> Result<Vec<[f64; 3]>> {
    ensure!(
        depth.len() == DEPTH_LEN && mask.len() == DEPTH_LEN,
        "depth map must have {DEPTH_ROWS} × {DEPTH_COLUMNS} = {DEPTH_LEN} pixels (got {}, mask {})",
        depth.len(),
        mask.len()
    );
    let mut pts = Vec::new();
    for (e, &elevation) in DEPTH_ROW_ELEVATION_RAD.iter().enumerate() {
        for (a, &azimuth) in INPUT_COLUMN_AZIMUTH_RAD.iter().enumerate() {
            let i = e * DEPTH_COLUMNS + a;
            if mask[i] {
                pts.push(polar_to_cartesian(Polar {
                    range: depth[i] as f64,
                    azimuth,
                    elevation,
                }));
            }
        }
    }
    Ok(pts)
}

/// The ground-truth mask as booleans from its stored f32 form (`mask.npy`: 1 = the ray meets a
/// surface inside the window, 0 = it does not): the one reading every tool uses.
pub fn mask_from_f32(mask: &[f32]) -> Vec<bool> {
    mask.iter().map(|&m| m > 0.5).collect()
}

/// How far inside the window a depth must read to count as a return: a ray that meets nothing
/// reads r_max, one whose surface is nearer than the window r_min, up to this rounding.
pub const RETURN_MARGIN_M: f64 = 1e-3;

/// The rays a depth map reports a return on: depth more than [`RETURN_MARGIN_M`] inside
/// `(r_min, r_max)`. The points a prediction's cloud and its chamfer distance are made of.
pub fn prediction_mask(depth: &[f32]) -> Vec<bool> {
    depth
        .iter()
        .map(|&d| {
            let d = d as f64;
            d > R_MIN_M + RETURN_MARGIN_M && d < R_MAX_M - RETURN_MARGIN_M
        })
        .collect()
}

/// Mask derived from a ground-truth map when none is given: pixels strictly inside the window
/// (a label of exactly r_min or r_max means "nearer" or "nothing").
pub fn derived_mask(gt: &[f32]) -> Vec<bool> {
    gt.iter()
        .map(|&d| (d as f64) > R_MIN_M && (d as f64) < R_MAX_M)
        .collect()
}

/// All maps' true returns over all maps' `of` (reported or ground-truth returns); `None`
/// when there are none.
fn pooled(ms: &[Metrics], of: fn(&Metrics) -> usize) -> Option<f64> {
    let (n, d) = ms.iter().fold((0usize, 0usize), |(n, d), m| {
        (n + m.true_returns, d + of(m))
    });
    (d > 0).then(|| n as f64 / d as f64)
}

/// Accuracy of one model over a set of depth maps: each figure's mean and (population)
/// standard deviation over the maps (NaN figures of a map, e.g. an empty mask, are left out).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Accuracy {
    /// Maps scored.
    pub maps: usize,
    /// Mean of the paper's MAE (all pixels, labels clamped), mm.
    pub mae: Option<f64>,
    /// Its standard deviation.
    pub mae_std: Option<f64>,
    /// Mean of the MAE over the ground-truth mask, mm.
    pub mae_masked: Option<f64>,
    /// Its standard deviation.
    pub mae_masked_std: Option<f64>,
    /// Mean of the paper's chamfer distance (the prediction's own points).
    pub cd: Option<f64>,
    /// Its standard deviation.
    pub cd_std: Option<f64>,
    /// Mean of the chamfer distance through the ground-truth mask (the older figure).
    pub cd_gt_masked: Option<f64>,
    /// Mean precision of the prediction's return mask.
    pub mask_precision: Option<f64>,
    /// Mean recall of the prediction's return mask.
    pub mask_recall: Option<f64>,
    /// Precision of the return mask over every ray of every map (true returns over reported
    /// ones, all maps pooled): the share of the set's reported points that are real.
    pub mask_precision_pooled: Option<f64>,
    /// Recall over every ray of every map (true returns over the ground truth's, pooled).
    pub mask_recall_pooled: Option<f64>,
}

impl Accuracy {
    /// Mean and standard deviation of every figure of `ms`.
    pub fn of(ms: &[Metrics]) -> Self {
        let stat = |f: fn(&Metrics) -> f64| {
            mean_std(
                &ms.iter()
                    .map(f)
                    .filter(|x| x.is_finite())
                    .collect::<Vec<_>>(),
            )
        };
        let (mae, mae_std) = stat(|m| m.mae);
        let (mae_masked, mae_masked_std) = stat(|m| m.mae_masked);
        let (cd, cd_std) = stat(|m| m.cd);
        Self {
            maps: ms.len(),
            mae,
            mae_std,
            mae_masked,
            mae_masked_std,
            cd,
            cd_std,
            cd_gt_masked: stat(|m| m.cd_gt_masked).0,
            mask_precision: stat(|m| m.mask_precision).0,
            mask_recall: stat(|m| m.mask_recall).0,
            mask_precision_pooled: pooled(ms, |m| m.predicted_pixels),
            mask_recall_pooled: pooled(ms, |m| m.valid_pixels),
        }
    }

    /// One line: `MAE m ± s mm (masked m ± s mm), CD c ± s (GT-masked g), returns P p % R r %
    /// (pooled P p % R r %)`.
    pub fn line(&self) -> String {
        let f = |v: Option<f64>, d: usize| v.map_or("–".to_string(), |x| format!("{x:.d$}"));
        if self.mae.is_none() {
            return "no ground truth".to_string();
        }
        let pct = |v: Option<f64>| f(v.map(|x| 100.0 * x), 1);
        format!(
            "MAE {} ± {} mm (masked {} ± {} mm), CD {} ± {} (GT-masked {}), returns P {} % R {} % (pooled P {} % R {} %)",
            f(self.mae, 2),
            f(self.mae_std, 2),
            f(self.mae_masked, 2),
            f(self.mae_masked_std, 2),
            f(self.cd, 4),
            f(self.cd_std, 4),
            f(self.cd_gt_masked, 4),
            pct(self.mask_precision),
            pct(self.mask_recall),
            pct(self.mask_precision_pooled),
            pct(self.mask_recall_pooled),
        )
    }
}

/// Labels clamped to the range window, as the paper's loss and MAE read them.
pub fn clamp_labels(gt: &[f32]) -> Vec<f32> {
    gt.iter()
        .map(|&d| d.clamp(R_MIN_M as f32, R_MAX_M as f32))
        .collect()
}

/// MAE (all pixels and masked, labels clamped), CD and the return mask's precision and recall
/// of `pred` against `gt` with its mask `mask`.
pub fn evaluate(pred: &[f32], gt: &[f32], mask: &[bool]) -> Result<Metrics> {
    let gt = clamp_labels(gt);
    let mae_masked = mae(pred, &gt, Some(mask))?;
    let mae_all = mae(pred, &gt, None)?;
    let own = prediction_mask(pred);
    let gt_points = depth_points(&gt, mask)?;
    let cd = chamfer(&depth_points(pred, &own)?, &gt_points)?;
    let cd_gt_masked = chamfer(&depth_points(pred, mask)?, &gt_points)?;
    let count = |m: &[bool]| m.iter().filter(|&&b| b).count();
    let (valid, predicted) = (count(mask), count(&own));
    let both = own.iter().zip(mask).filter(|(&p, &g)| p && g).count();
    let ratio = |n: usize, d: usize| {
        if d == 0 {
            f64::NAN
        } else {
            n as f64 / d as f64
        }
    };
    Ok(Metrics {
        mae: mae_all,
        mae_masked,
        cd,
        cd_gt_masked,
        mask_precision: ratio(both, predicted),
        mask_recall: ratio(both, valid),
        valid_pixels: valid,
        predicted_pixels: predicted,
        true_returns: both,
        pixels: gt.len(),
    })
}

/// Pixel classes of [`ErrorBreakdown`], in its order.
pub const ERROR_CLASSES: [&str; 4] = ["surface", "silhouette", "empty_far", "empty_near"];

/// Where the paper's MAE comes from: the absolute depth error of a set of maps pooled by pixel
/// class. `surface`: mask pixels whose four neighbours are all in the mask; `silhouette`: mask
/// pixels with a neighbour outside it (the map's border does not count); `empty_far`: rays
/// outside the mask whose label reads r_max (they meet nothing inside the window);
/// `empty_near`: rays outside the mask whose label reads r_min. Labels are clamped as in
/// [`evaluate`], so the four classes' errors add up to the all-pixel MAE's sum.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ErrorBreakdown {
    /// Pixels per class.
    pub pixels: [usize; 4],
    /// Sum of |prediction − clamped label| per class, metres.
    pub error_m: [f64; 4],
}

/// One class of an [`ErrorBreakdown`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ClassError {
    /// The class ([`ERROR_CLASSES`]).
    pub class: &'static str,
    /// Its share of the pixels, %.
    pub pixel_share: f64,
    /// MAE over its pixels, mm (NaN without pixels).
    pub mae: f64,
    /// Its share of the all-pixel error, %.
    pub error_share: f64,
}

impl ErrorBreakdown {
    /// Adds one `[DEPTH_ROWS][DEPTH_COLUMNS]` map.
    pub fn add(&mut self, pred: &[f32], gt: &[f32], mask: &[bool]) -> Result<()> {
        ensure!(
            pred.len() == DEPTH_LEN && gt.len() == DEPTH_LEN && mask.len() == DEPTH_LEN,
            "breakdown: maps must have {DEPTH_LEN} pixels (prediction {}, label {}, mask {})",
            pred.len(),
            gt.len(),
            mask.len()
        );
        let gt = clamp_labels(gt);
        let r_mid = ((R_MIN_M + R_MAX_M) / 2.0) as f32;
        for e in 0..DEPTH_ROWS {
            for a in 0..DEPTH_COLUMNS {
                let i = e * DEPTH_COLUMNS + a;
                let class = if mask[i] {
                    let outside = |de: isize, da: isize| {
                        let (y, x) = (e as isize + de, a as isize + da);
                        (0..DEPTH_ROWS as isize).contains(&y)
                            && (0..DEPTH_COLUMNS as isize).contains(&x)
                            && !mask[y as usize * DEPTH_COLUMNS + x as usize]
                    };
                    if outside(-1, 0) || outside(1, 0) || outside(0, -1) || outside(0, 1) {
                        1
                    } else {
                        0
                    }
                } else if gt[i] >= r_mid {
                    2
                } else {
                    3
                };
                self.pixels[class] += 1;
                self.error_m[class] += (pred[i] as f64 - gt[i] as f64).abs();
            }
        }
        Ok(())
    }

    /// The classes' shares and MAEs.
    pub fn rows(&self) -> Vec<ClassError> {
        let pixels: usize = self.pixels.iter().sum();
        let error: f64 = self.error_m.iter().sum();
        let pct = |a: f64, b: f64| if b > 0.0 { 100.0 * a / b } else { f64::NAN };
        ERROR_CLASSES
            .iter()
            .enumerate()
            .map(|(k, &class)| ClassError {
                class,
                pixel_share: pct(self.pixels[k] as f64, pixels as f64),
                mae: if self.pixels[k] > 0 {
                    MAE_SCALE * self.error_m[k] / self.pixels[k] as f64
                } else {
                    f64::NAN
                },
                error_share: pct(self.error_m[k], error),
            })
            .collect()
    }
}

/// Writes an ASCII PLY point cloud (MeshLab opens it), optionally coloured.
pub fn write_ply(path: &Path, points: &[[f64; 3]], colour: Option<[u8; 3]>) -> Result<()> {
    let mut s = String::new();
    s.push_str("ply\nformat ascii 1.0\ncomment epssn host-sim, sonar frame: x forward, y left, z up, metres\n");
    s.push_str(&format!("element vertex {}\n", points.len()));
    s.push_str("property float x\nproperty float y\nproperty float z\n");
    if colour.is_some() {
        s.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
    }
    s.push_str("end_header\n");
    for p in points {
        s.push_str(&format!("{:.6} {:.6} {:.6}", p[0], p[1], p[2]));
        if let Some(c) = colour {
            s.push_str(&format!(" {} {} {}", c[0], c[1], c[2]));
        }
        s.push('\n');
    }
    std::fs::File::create(path)
        .and_then(|mut f| f.write_all(s.as_bytes()))
        .with_context(|| format!("writing {}", path.display()))
}

/// `host-sim metrics`: compare two depth maps.
#[derive(Debug)]
pub struct MetricsOptions {
    /// Predicted depth map (.npy float32, E × A metres).
    pub pred: PathBuf,
    /// Ground-truth depth map (.npy float32, E × A metres).
    pub gt: PathBuf,
    /// Mask (.npy float32 0/1); default: ground-truth pixels strictly inside the window.
    pub mask: Option<PathBuf>,
    /// Print JSON instead of text.
    pub json: bool,
    /// Also write the predicted map's masked points as PLY.
    pub ply_pred: Option<PathBuf>,
    /// Also write the ground truth's masked points as PLY.
    pub ply_gt: Option<PathBuf>,
}

/// Runs `host-sim metrics`.
pub fn run(args: &MetricsOptions) -> Result<()> {
    let pred = epssn_aris::npy::read_f32(&args.pred)?.data;
    let gt = epssn_aris::npy::read_f32(&args.gt)?.data;
    let mask = match &args.mask {
        Some(p) => mask_from_f32(&epssn_aris::npy::read_f32(p)?.data),
        None => derived_mask(&gt),
    };
    let m = evaluate(&pred, &gt, &mask)?;
    if let Some(p) = &args.ply_pred {
        write_ply(
            p,
            &depth_points(&pred, &prediction_mask(&pred))?,
            Some([230, 80, 40]),
        )?;
    }
    if let Some(p) = &args.ply_gt {
        write_ply(p, &depth_points(&gt, &mask)?, Some([40, 140, 230]))?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&m)?);
    } else {
        println!(
            "MAE {:.3} mm (paper: all {} pixels, labels clamped; masked, {} pixels: {:.3} mm)   \
             CD {:.5} ({} predicted points; {:.5} through the ground-truth mask)   returns: \
             precision {:.3}, recall {:.3}",
            m.mae,
            m.pixels,
            m.valid_pixels,
            m.mae_masked,
            m.cd,
            m.predicted_pixels,
            m.cd_gt_masked,
            m.mask_precision,
            m.mask_recall
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mae_by_hand() {
        // 2 × 2 maps: errors 0.01, 0.02, 0, 0.1 m.
        let gt = [2.0f32, 2.5, 3.0, 3.5];
        let pred = [2.01f32, 2.48, 3.0, 3.4];
        let all = mae(&pred, &gt, None).unwrap();
        assert!((all - 1000.0 * 0.13 / 4.0).abs() < 1e-3, "{all}");
        let m = mae(&pred, &gt, Some(&[true, true, false, false])).unwrap();
        assert!((m - 1000.0 * 0.03 / 2.0).abs() < 1e-3, "{m}");
        assert!(mae(&pred, &gt, Some(&[false; 4])).unwrap().is_nan());
        assert!(mae(&pred[..3], &gt, None).is_err());
    }

    #[test]
    fn chamfer_by_hand() {
        // A = {(0,0,0), (1,0,0)}, B = {(0,0,0.1)}.
        // A→B: 0.01 and 1 + 0.01 = 1.01, mean 0.51. B→A: 0.01. CD = 500 · 0.52 = 260.
        let a = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let b = [[0.0, 0.0, 0.1]];
        assert!((chamfer(&a, &b).unwrap() - 260.0).abs() < 1e-9);
        assert!((chamfer(&b, &a).unwrap() - 260.0).abs() < 1e-9);
        assert_eq!(chamfer(&a, &a).unwrap(), 0.0);
        assert!(chamfer(&a, &[]).unwrap().is_nan());
    }

    #[test]
    fn breakdown_classes_by_hand() {
        // A 2 × 2 block of surface in the middle of an empty map: its 4 pixels are silhouette
        // (each has an outside neighbour); one row of near rays; the rest far.
        let mut gt = vec![R_MAX_M as f32 + 1.0; DEPTH_LEN];
        let mut mask = vec![false; DEPTH_LEN];
        for (e, a) in [(10, 20), (10, 21), (11, 20), (11, 21)] {
            gt[e * DEPTH_COLUMNS + a] = 2.5;
            mask[e * DEPTH_COLUMNS + a] = true;
        }
        for v in &mut gt[..DEPTH_COLUMNS] {
            *v = R_MIN_M as f32 - 0.5;
        }
        let mut pred = clamp_labels(&gt);
        pred[10 * DEPTH_COLUMNS + 20] += 0.1; // silhouette error 0.1
        pred[DEPTH_COLUMNS] -= 0.2; // a far ray read 0.2 short
        let mut b = ErrorBreakdown::default();
        b.add(&pred, &gt, &mask).unwrap();
        assert_eq!(
            b.pixels,
            [0, 4, DEPTH_LEN - 4 - DEPTH_COLUMNS, DEPTH_COLUMNS]
        );
        let rows = b.rows();
        assert!(rows[0].mae.is_nan());
        assert!((rows[1].mae - 1000.0 * 0.1 / 4.0).abs() < 1e-3);
        assert!((rows[1].error_share - 100.0 / 3.0).abs() < 1e-3);
        assert!((rows[2].error_share - 200.0 / 3.0).abs() < 1e-3);
        // The classes add up to the all-pixel MAE.
        let all = mae(&pred, &clamp_labels(&gt), None).unwrap();
        let sum: f64 = b.error_m.iter().sum::<f64>() * 1000.0 / DEPTH_LEN as f64;
        assert!((all - sum).abs() < 1e-6);
        // A 4 × 4 block has a 2 × 2 interior.
        let mut mask = vec![false; DEPTH_LEN];
        for e in 4..8 {
            for a in 4..8 {
                mask[e * DEPTH_COLUMNS + a] = true;
            }
        }
        let mut b = ErrorBreakdown::default();
        b.add(&pred, &gt, &mask).unwrap();
        assert_eq!(b.pixels[..2], [4, 12]);
        assert!(b.add(&pred[1..], &gt, &mask).is_err());
    }

    #[test]
    fn points_follow_the_geometry_module() {
        let mut depth = vec![R_MAX_M as f32; DEPTH_LEN];
        let mut mask = vec![false; DEPTH_LEN];
        let (e, a) = (3, 40);
        depth[e * DEPTH_COLUMNS + a] = 2.5;
        mask[e * DEPTH_COLUMNS + a] = true;
        let pts = depth_points(&depth, &mask).unwrap();
        assert_eq!(pts.len(), 1);
        let p = epssn::geometry::cartesian_to_polar(pts[0]);
        assert!((p.range - 2.5).abs() < 1e-6);
        assert!((p.azimuth - INPUT_COLUMN_AZIMUTH_RAD[a]).abs() < 1e-9);
        assert!((p.elevation - DEPTH_ROW_ELEVATION_RAD[e]).abs() < 1e-9);
        // A shifted map: every point moves radially by 0.01 m, so CD = 500 · 2 · 0.0001.
        let shifted: Vec<f32> = depth.iter().map(|d| d + 0.01).collect();
        let m = evaluate(&shifted, &depth, &mask).unwrap();
        assert!((m.cd - 0.1).abs() < 1e-4, "{}", m.cd);
        assert!((m.mae - 10.0).abs() < 1e-3);
        assert!((m.mae_masked - 10.0).abs() < 1e-3);
    }

    #[test]
    fn pooled_precision_weighs_every_ray_where_the_mean_weighs_every_map() {
        // Map 1: 9 true returns and 1 phantom; map 2: 1 true return and 1 phantom.
        let gt_of = |n: usize| {
            let mut gt = vec![R_MAX_M as f32; DEPTH_LEN];
            let mut mask = vec![false; DEPTH_LEN];
            for i in 0..n {
                gt[i] = 2.5;
                mask[i] = true;
            }
            (gt, mask)
        };
        let with_phantom = |gt: &[f32]| {
            let mut pred = gt.to_vec();
            pred[DEPTH_LEN - 1] = 2.7;
            pred
        };
        let (g1, m1) = gt_of(9);
        let (g2, m2) = gt_of(1);
        let ms = [
            evaluate(&with_phantom(&g1), &g1, &m1).unwrap(),
            evaluate(&with_phantom(&g2), &g2, &m2).unwrap(),
        ];
        let acc = Accuracy::of(&ms);
        let mean = acc.mask_precision.unwrap();
        let pooled = acc.mask_precision_pooled.unwrap();
        assert!((mean - (0.9 + 0.5) / 2.0).abs() < 1e-12, "{mean}");
        assert!((pooled - 10.0 / 12.0).abs() < 1e-12, "{pooled}");
        assert_eq!(acc.mask_recall_pooled, Some(1.0));
        assert_eq!(Accuracy::of(&[]).mask_precision_pooled, None);
    }

    #[test]
    fn cd_counts_phantom_points_and_missed_surfaces() {
        let (e, a) = (3, 40);
        let mut gt = vec![R_MAX_M as f32; DEPTH_LEN];
        let mut mask = vec![false; DEPTH_LEN];
        gt[e * DEPTH_COLUMNS + a] = 2.5;
        mask[e * DEPTH_COLUMNS + a] = true;
        // The truth exactly, plus one phantom return on a ray that meets nothing.
        let mut pred = gt.clone();
        pred[(e + 1) * DEPTH_COLUMNS + a + 10] = 2.7;
        let m = evaluate(&pred, &gt, &mask).unwrap();
        assert_eq!(
            m.cd_gt_masked, 0.0,
            "the ground-truth mask hides the phantom"
        );
        let pts = depth_points(&pred, &prediction_mask(&pred)).unwrap();
        let want = CD_SCALE * 0.5 * {
            let (p, q) = (pts[0], pts[1]);
            (0..3).map(|i| (p[i] - q[i]).powi(2)).sum::<f64>()
        };
        assert!(
            (m.cd - want).abs() < 1e-9 && m.cd > 0.0,
            "{} vs {want}",
            m.cd
        );
        assert_eq!((m.predicted_pixels, m.valid_pixels), (2, 1));
        assert!((m.mask_precision - 0.5).abs() < 1e-12);
        assert!((m.mask_recall - 1.0).abs() < 1e-12);
        // A missed surface: no predicted points at all, recall 0, precision undefined.
        let missed = vec![R_MAX_M as f32; DEPTH_LEN];
        let m = evaluate(&missed, &gt, &mask).unwrap();
        assert_eq!((m.predicted_pixels, m.mask_recall), (0, 0.0));
        assert!(m.mask_precision.is_nan() && m.cd.is_nan());
        // Depths at the window's ends are no returns.
        let ends = [R_MIN_M as f32, R_MAX_M as f32, (R_MAX_M - 5e-4) as f32, 2.5];
        assert_eq!(prediction_mask(&ends), [false, false, false, true]);
    }

    #[test]
    fn paper_mae_clamps_labels_and_counts_every_pixel() {
        // Two pixels: one in the window (error 0.1 m), one whose label lies beyond r_max
        // (a ray that meets nothing), predicted at r_max: no error once the label is clamped.
        let gt = [2.5f32, 9.0];
        let pred = [2.6f32, R_MAX_M as f32];
        let mut depth = vec![R_MAX_M as f32; DEPTH_LEN];
        let mut label = vec![R_MAX_M as f32; DEPTH_LEN];
        let mut mask = vec![false; DEPTH_LEN];
        depth[..2].copy_from_slice(&pred);
        label[..2].copy_from_slice(&gt);
        mask[0] = true;
        let m = evaluate(&depth, &label, &mask).unwrap();
        assert!((m.mae_masked - 100.0).abs() < 1e-3, "{}", m.mae_masked);
        assert!((m.mae - 100.0 / DEPTH_LEN as f64).abs() < 1e-4, "{}", m.mae);
    }

    #[test]
    fn ply_header() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.ply");
        write_ply(&p, &[[1.0, 2.0, 3.0]], Some([1, 2, 3])).unwrap();
        let s = std::fs::read_to_string(&p).unwrap();
        assert!(s.starts_with("ply\nformat ascii 1.0\n"));
        assert!(s.contains("element vertex 1\n"));
        assert!(s.ends_with("end_header\n1.000000 2.000000 3.000000 1 2 3\n"));
    }
}
