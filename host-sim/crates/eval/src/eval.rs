//! `host-sim eval`: the accuracy of a weights folder on held-out simulated samples, float (the
//! f64 reference network) and, with `--int8`, the int8 library on the folder's blob.

use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, ensure, Context, Result};
use epssn_reference::{floatref, weights};
use epssn_sim::metrics::{self, Accuracy, ErrorBreakdown, Metrics};

use crate::data::{load_dir, split_dir, Sample};
use crate::summary::data_summary;

/// Options of `host-sim eval`.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// Weights folder (`model.safetensors`, `spec.json`); default: the model the firmware ships
    /// (`weights/FIRMWARE_WEIGHTS`).
    pub weights: Option<PathBuf>,
    /// Simulated data folder (its `test/` split if present, else the folder itself).
    pub data: PathBuf,
    /// Views fed to the model (1 = the reference as its own source); default: the views it was
    /// trained on (`views` in the weights folder's `manifest.json`, else the spec's).
    pub views: Option<usize>,
    /// Print JSON instead of a table.
    pub json: bool,
    /// Use at most this many samples.
    pub limit: Option<usize>,
    /// Also run the int8 library on the blob in the weights folder (`epssn-s.q8.bin`): its
    /// accuracy and its mean absolute depth difference from the float model.
    pub int8: bool,
    /// Also report where the all-pixel error comes from: surface, silhouette, empty far and
    /// empty near rays, pooled over the maps (`epssn_sim::metrics::ErrorBreakdown`).
    pub breakdown: bool,
    /// Also write each sample's float depth map (the f64 reference network's) to
    /// `<DIR>/<sample>/depth_float.npy`: f32 metres, elevation rows × azimuth columns, the
    /// layout `epssn-train predict` writes, so the two float networks can be compared.
    pub save_depth: Option<PathBuf>,
}

/// The metric's exact definition, as `eval --json` states it.
pub const METRIC: &str = "mae: 1000/(E*A) * sum over all E*A pixels of |pred - clamp(label, r_min, r_max)| (the paper's formula, mm); mae_masked: the same mean over the ground-truth mask; cd: 500 * symmetric chamfer (m^2) between the prediction's own points (rays whose depth reads more than 1 mm inside (r_min, r_max)) and the ground truth's mask points; cd_gt_masked: the same with both clouds through the ground-truth mask (the figure reported as cd before 2026-12); mask_precision / mask_recall: the prediction's returns against the ground-truth mask, each map's ratio averaged over the maps; mask_precision_pooled / mask_recall_pooled: the same ratios over every ray of every map (true returns over all reported, over all ground-truth returns)";

const BREAKDOWN_CLASSES: &str = "surface: mask pixels with every 4-neighbour in the mask; silhouette: mask pixels with one outside; empty_far / empty_near: rays outside the mask labelled r_max / r_min. pixel_share and error_share in % (pooled over the maps), mae in mm";

/// Runs `host-sim eval`.
pub fn run(args: &EvalOptions) -> Result<()> {
    let weights = match &args.weights {
        Some(w) => w.clone(),
        None => weights::firmware_weights_dir()?,
    };
    ensure_built_for(&weights)?;
    // By default the view count the model was trained on: a model is far worse on another.
    let views = match args.views {
        Some(v) => v,
        None => weights::trained_views(&weights)?,
    };
    if !(1..=3).contains(&views) {
        bail!("--views must be 1, 2 or 3");
    }
    let dir = split_dir(&args.data, "test").unwrap_or_else(|| args.data.clone());
    use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS, INPUT_COLUMNS, INPUT_RANGE_BINS};
    let set = load_dir(
        &dir,
        views,
        (INPUT_RANGE_BINS, INPUT_COLUMNS),
        (DEPTH_ROWS, DEPTH_COLUMNS),
        args.limit,
    )?;
    ensure!(!set.is_empty(), "no samples in {}", dir.display());
    let looks = Looks::of(&dir, &weights);
    for w in &looks.warnings {
        eprintln!("warning: {w}");
    }
    let scores = score(
        &weights,
        &set,
        args.int8,
        args.breakdown,
        args.save_depth.as_deref(),
    )?;
    let ctx = Report {
        weights: &weights,
        dir: &dir,
        views,
        samples: set.len(),
    };
    if args.json {
        let j = report_json(&ctx, &looks, &scores, args)?;
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        print_table(&ctx, &scores, args);
    }
    Ok(())
}

/// The float reference network is compiled for this build's spec (`EPSSN_SPEC`): a folder of
/// another spec is refused here rather than misread.
fn ensure_built_for(dir: &Path) -> Result<()> {
    let spec = dir.join("spec.json");
    let folder = epssn_spec::load::load_spec(&spec)
        .map_err(|e| anyhow!("{}: {e}", spec.display()))?
        .hash;
    let built = epssn::config::SPEC_HASH;
    ensure!(
        folder == built,
        "{} holds a model of spec {folder:#010x}; this build of host-sim is for spec {built:#010x}: \
         rebuild it with EPSSN_SPEC naming that model's spec file to evaluate it",
        dir.display()
    );
    Ok(())
}

/// Speckle looks of the test data and of the model, and the warning when they differ.
struct Looks {
    data: Vec<u64>,
    model: Option<u32>,
    warnings: Vec<String>,
}

impl Looks {
    fn of(dir: &Path, weights: &Path) -> Self {
        let data: Vec<u64> = data_summary(dir)["speckle_looks"]
            .as_array()
            .map(|a| a.iter().filter_map(|v| v.as_u64()).collect())
            .unwrap_or_default();
        let model = weights::trained_pings_per_view(weights);
        // A model trained on averaged pings reads single pings badly and the reverse (measured,
        // docs/ACCURACY.md): say so beside the figures rather than score silently.
        let mut warnings = Vec::new();
        if let (Some(m), [d]) = (model, data.as_slice()) {
            if u64::from(m) != *d {
                warnings.push(format!(
                    "the model was trained on {m} speckle look(s) per view and these data have {d}: \
                     its figures here are not its accuracy on the data it was made for"
                ));
            }
        }
        Looks {
            data,
            model,
            warnings,
        }
    }
}

/// Per-map metrics of the float and int8 networks and their differences.
#[derive(Default)]
struct Scores {
    float: Vec<Metrics>,
    int8: Vec<Metrics>,
    int8_vs_float: Vec<f64>,
    int8_vs_float_mask: Vec<f64>,
    float_breakdown: ErrorBreakdown,
    int8_breakdown: ErrorBreakdown,
}

/// Scores every sample: the float map from the f64 reference network, the int8 map from the
/// library on the folder's blob when `int8`.
/// With `save_depth`, each sample's float map is also written there (`save_depth`, below) from
/// the same forward pass that scores it.
fn score(
    weights_dir: &Path,
    set: &[Sample],
    int8: bool,
    breakdown: bool,
    save_depth_to: Option<&Path>,
) -> Result<Scores> {
    let (float_weights, _) = weights::load_float(weights_dir)?;
    let folded = floatref::fold_all(&float_weights)?;
    // The float network is decided at the blob's no-return threshold too, so that float and
    // int8 figures differ by the quantisation alone. A folder not yet quantised (a fit's
    // output, a kept epoch) is read in float at the spec's threshold.
    let blob = if int8 || weights_dir.join(weights::BLOB_FILE).exists() {
        Some(weights::read_blob(weights_dir)?)
    } else {
        None
    };
    let int8_model = blob
        .as_deref()
        .map(|b| epssn::model::Model::from_blob(b).map_err(|e| anyhow!("int8 blob refused: {e:?}")))
        .transpose()?;
    let tau16 = int8_model
        .as_ref()
        .map_or(epssn::config::NO_RETURN_MASS_Q16, |m| m.no_return16());
    let model = if int8 { int8_model } else { None };
    let mut ws = Box::new(epssn::model::Workspace::new());
    let mut s = Scores::default();
    for sample in set {
        let float = float_depth(&folded, sample, tau16)?;
        if let Some(out) = save_depth_to {
            save_depth(out, sample, &float)?;
        }
        let mask = metrics::mask_from_f32(&sample.mask);
        // The paper's MAE (all pixels, labels clamped), the masked MAE and the CD
        // (epssn_sim::metrics documents the exact formulas).
        s.float
            .push(metrics::evaluate(&float, &sample.depth, &mask)?);
        if breakdown {
            s.float_breakdown.add(&float, &sample.depth, &mask)?;
        }
        if let Some(q) = &model {
            let dq = epssn_reference::int8::depth_metres(q, &sample.views, &mut ws)?;
            s.int8.push(metrics::evaluate(&dq, &sample.depth, &mask)?);
            if breakdown {
                s.int8_breakdown.add(&dq, &sample.depth, &mask)?;
            }
            // The MAE's own formula with the float map in place of the labels.
            s.int8_vs_float.push(metrics::mae(&dq, &float, None)?);
            if mask.iter().any(|&m| m) {
                s.int8_vs_float_mask
                    .push(metrics::mae(&dq, &float, Some(&mask))?);
            }
        }
    }
    Ok(s)
}

/// The float depth map of one sample, decided at the blob's no-return threshold `tau16`; one
/// view is fed as its own source, as training's single-view ablation does.
fn float_depth(folded: &floatref::FoldedWeights, sample: &Sample, tau16: u32) -> Result<Vec<f32>> {
    let views: Vec<&[u8]> = if sample.views.len() == 1 {
        vec![&sample.views[0], &sample.views[0]]
    } else {
        sample.views.iter().map(|v| v.as_slice()).collect()
    };
    Ok(floatref::run_folded(folded, &views, &mut |_, _| {})
        .with_context(|| format!("float network on {}", sample.dir.display()))?
        .decided(tau16))
}

/// Writes a sample's float depth map to `<out>/<sample folder name>/depth_float.npy`.
fn save_depth(out: &Path, sample: &Sample, depth: &[f32]) -> Result<()> {
    use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS};
    let name = sample
        .dir
        .file_name()
        .ok_or_else(|| anyhow!("{} has no folder name", sample.dir.display()))?;
    let dir = out.join(name);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    epssn_aris::npy::write_f32(
        &dir.join("depth_float.npy"),
        &[DEPTH_ROWS, DEPTH_COLUMNS],
        depth,
    )
}

/// Mean of a list (NaN for none: JSON null, a table's NaN).
fn mean_or_nan(v: &[f64]) -> f64 {
    metrics::mean_std(v).0.unwrap_or(f64::NAN)
}

/// What a report names besides the scores.
struct Report<'a> {
    weights: &'a Path,
    dir: &'a Path,
    views: usize,
    samples: usize,
}

fn report_json(
    ctx: &Report,
    looks: &Looks,
    s: &Scores,
    args: &EvalOptions,
) -> Result<serde_json::Value> {
    let int8 = if args.int8 {
        let mut j = serde_json::to_value(Accuracy::of(&s.int8))?;
        j["int8_vs_float_mae"] = mean_or_nan(&s.int8_vs_float).into();
        j["int8_vs_float_mae_mask"] = mean_or_nan(&s.int8_vs_float_mask).into();
        j
    } else {
        serde_json::Value::Null
    };
    let mut j = serde_json::json!({
        "weights": ctx.weights.display().to_string(),
        "data": ctx.dir.display().to_string(),
        "views": ctx.views,
        "samples": ctx.samples,
        "float_network": "f64 reference network on batch-norm-folded weights (epssn_reference::floatref)",
        "speckle_looks": { "data": looks.data, "model": looks.model },
        "warnings": looks.warnings,
        "metric": METRIC,
        "float": Accuracy::of(&s.float),
        "int8": int8,
    });
    if args.breakdown {
        j["breakdown"] = serde_json::json!({
            "classes": BREAKDOWN_CLASSES,
            "float": s.float_breakdown.rows(),
            "int8": args.int8.then(|| s.int8_breakdown.rows()),
        });
    }
    Ok(j)
}

fn print_table(ctx: &Report, s: &Scores, args: &EvalOptions) {
    println!(
        "weights {}  data {}  views {}  samples {}",
        ctx.weights.display(),
        ctx.dir.display(),
        ctx.views,
        ctx.samples
    );
    println!("float: {}", Accuracy::of(&s.float).line());
    if args.int8 {
        println!(
            "int8:  {}   int8 vs float {:.2} mm ({:.2} mm on the mask)",
            Accuracy::of(&s.int8).line(),
            mean_or_nan(&s.int8_vs_float),
            mean_or_nan(&s.int8_vs_float_mask),
        );
    }
    if args.breakdown {
        let models = [
            ("float", Some(&s.float_breakdown)),
            ("int8", args.int8.then_some(&s.int8_breakdown)),
        ];
        for (name, b) in models {
            let Some(b) = b else { continue };
            println!("{name} error by pixel class (pooled): class, pixels %, MAE mm, error %");
            for r in b.rows() {
                println!(
                    "  {:<11} {:>6.1} {:>8.2} {:>6.1}",
                    r.class, r.pixel_share, r.mae, r.error_share
                );
            }
        }
    }
}
