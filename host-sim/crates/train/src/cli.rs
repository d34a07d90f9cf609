//! `host-sim train` and `host-sim eval`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use super::data::{load_dir, split_dir, Sample};
use super::train::{lr_at, Trainer};
use super::{
    load_safetensors, parse_spec, save_safetensors, FloatModel, SplitMix64, SPEC_FILE, WEIGHTS_FILE,
};

/// Arguments of `host-sim train`.
#[derive(Args, Debug, Clone)]
pub struct TrainArgs {
    /// Scene name (sphere, terrain, artificial); names the default output folder.
    #[arg(long)]
    pub scene: String,
    /// Simulated data folder with `train/` (and optionally `val/`) sample folders.
    #[arg(long)]
    pub data: PathBuf,
    /// Epochs over the training split.
    #[arg(long, default_value_t = 60)]
    pub epochs: usize,
    /// Batch size (default: the spec's).
    #[arg(long)]
    pub batch: Option<usize>,
    /// Continue from `OUT/checkpoint/`, or, when a finished run left none, from `OUT`'s weights
    /// and loss history with a fresh optimizer state (to train a finished run further).
    #[arg(long)]
    pub resume: bool,
    /// Output folder (default `weights/<scene>`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Model spec (default: the one this build was generated from, `weights/epssn-s.json`
    /// unless `EPSSN_SPEC` named another; the quantiser and the library follow the build's).
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Views (default: the spec's; 1 = reference as its own source).
    #[arg(long)]
    pub views: Option<usize>,
    /// Seed of weight initialisation and shuffling.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Minutes between checkpoints inside an epoch (a checkpoint is also written every epoch).
    #[arg(long, default_value_t = 5.0)]
    pub checkpoint_minutes: f64,
    /// Use at most this many training samples.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Use at most this many validation samples.
    #[arg(long, default_value_t = 200)]
    pub val_limit: usize,
    /// Only time this many training steps (after one warm-up step) and exit without saving.
    #[arg(long)]
    pub bench_steps: Option<usize>,
    /// Start from the weights of another trained model (its `model.safetensors`) with the same
    /// layers: convolution weights do not depend on the image size, so a model of EPSSN-S
    /// starts EPSSN-P (docs/PAPER.md). Fresh optimizer state and schedule; ignored on --resume
    /// from a checkpoint.
    #[arg(long, conflicts_with = "bench_steps")]
    pub init_from: Option<PathBuf>,
    /// Learning rate before the halving (default: the spec's `training.lr`). A lower rate
    /// fine-tunes a trained model (`--init-from`) without first undoing it; the manifest records
    /// the rate used, and a resumed run must pass the same one.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Weight of a two-hot cross-entropy term on the range bins beside the paper's L1 loss
    /// (train.rs; 0: L1 alone). Validation loss stays the L1 term. A resumed run must pass the
    /// same weight.
    #[arg(long, default_value_t = 0.0)]
    pub ce_weight: f64,
}

/// Arguments of `host-sim eval`.
#[derive(Args, Debug, Clone)]
pub struct EvalArgs {
    /// Weights folder (`model.safetensors`, `spec.json`); default: the model the firmware ships
    /// (`weights/FIRMWARE_WEIGHTS`).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Simulated data folder (its `test/` split if present, else the folder itself).
    #[arg(long)]
    pub data: PathBuf,
    /// Views fed to the model (1 = the reference as its own source); default: the views it was
    /// trained on (`views` in the weights folder's `manifest.json`, else the spec's).
    #[arg(long)]
    pub views: Option<usize>,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Use at most this many samples.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Also run the int8 library on the blob in the weights folder (`epssn-s.q8.bin`): its
    /// accuracy and its mean absolute depth difference from the float model.
    #[arg(long)]
    pub int8: bool,
    /// Compute the float depth maps with the f64 reference network on folded weights
    /// (`epssn_reference::floatref`, no burn) instead of the burn model: the same network, independent
    /// of the training backend and of the build profile.
    #[arg(long)]
    pub float_reference: bool,
    /// Also report where the all-pixel error comes from: surface, silhouette, empty far and
    /// empty near rays, pooled over the maps (`epssn_sim::metrics::ErrorBreakdown`).
    #[arg(long)]
    pub breakdown: bool,
}

/// One row of the loss history.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LossRow {
    /// Epoch (1-based, completed).
    pub epoch: usize,
    /// Global step at the end of the epoch.
    pub step: usize,
    /// Mean training loss over the epoch.
    pub train_loss: f32,
    /// Validation loss at the end of the epoch (NaN without a validation split).
    pub val_loss: f32,
}

/// Everything needed to continue training exactly where it stopped.
#[derive(Clone, Debug, Serialize, Deserialize)]
struct TrainState {
    epoch: usize,
    batch_in_epoch: usize,
    global_step: usize,
    epoch_loss_sum: f64,
    epoch_loss_count: usize,
    history: Vec<LossRow>,
    elapsed_s: f64,
    seed: u64,
    batch: usize,
    epochs: usize,
    views: usize,
    /// The learning rate before the halving; absent in checkpoints written before `--lr`.
    #[serde(default)]
    lr: Option<f64>,
    /// The cross-entropy term's weight; 0 in checkpoints written before `--ce-weight`.
    #[serde(default)]
    ce_weight: f64,
}

fn write_csv(path: &Path, rows: &[LossRow]) -> Result<()> {
    let mut s = String::from("epoch,step,train_loss,val_loss\n");
    for r in rows {
        s += &format!("{},{},{},{}\n", r.epoch, r.step, r.train_loss, r.val_loss);
    }
    std::fs::write(path, s)?;
    Ok(())
}

/// The rows of a `loss.csv` that [`write_curves`] wrote.
fn read_loss_csv(path: &Path) -> Result<Vec<LossRow>> {
    let csv = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let mut history = Vec::new();
    for line in csv.lines().skip(1).filter(|l| !l.trim().is_empty()) {
        let f: Vec<&str> = line.split(',').collect();
        ensure!(f.len() == 4, "bad loss.csv line `{line}`");
        history.push(LossRow {
            epoch: f[0].parse()?,
            step: f[1].parse()?,
            train_loss: f[2].parse()?,
            val_loss: f[3].parse()?,
        });
    }
    Ok(history)
}

/// Redraws `dir/loss.png` from `dir/loss.csv` (e.g. after the plot's style changed); the CSV
/// is left as it is.
pub fn redraw_loss_plot(dir: &Path) -> Result<()> {
    plot_curves(dir, &read_loss_csv(&dir.join("loss.csv"))?)
}

fn write_curves(out: &Path, rows: &[LossRow]) -> Result<()> {
    write_csv(&out.join("loss.csv"), rows)?;
    plot_curves(out, rows)
}

fn plot_curves(out: &Path, rows: &[LossRow]) -> Result<()> {
    let t: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.epoch as f64, r.train_loss as f64))
        .collect();
    let v: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.epoch as f64, r.val_loss as f64))
        .collect();
    super::plot::plot_losses(&out.join("loss.png"), &t, &v)
}

/// The training state at the end of the finished run in `out` (its manifest and `loss.csv`).
fn finished_run_state(out: &Path, seed: u64, batch: usize, views: usize) -> Result<TrainState> {
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("manifest.json"))?)
            .with_context(|| format!("{}/manifest.json", out.display()))?;
    let field = |k: &str| {
        manifest[k]
            .as_u64()
            .with_context(|| format!("{}/manifest.json has no `{k}`", out.display()))
    };
    ensure!(
        field("seed")? == seed
            && field("batch")? as usize == batch
            && field("views")? as usize == views,
        "the run in {} was made with seed {}, batch {}, views {}: pass the same settings",
        out.display(),
        field("seed")?,
        field("batch")?,
        field("views")?
    );
    let history = read_loss_csv(&out.join("loss.csv"))?;
    let epoch = field("epochs")? as usize;
    ensure!(
        history.len() == epoch,
        "{}/loss.csv has {} epochs, the manifest {epoch}",
        out.display(),
        history.len()
    );
    Ok(TrainState {
        epoch,
        batch_in_epoch: 0,
        global_step: field("steps")? as usize,
        epoch_loss_sum: 0.0,
        epoch_loss_count: 0,
        history,
        elapsed_s: manifest["wall_time_s"].as_f64().unwrap_or(0.0),
        seed,
        batch,
        epochs: epoch,
        views,
        lr: None,
        ce_weight: 0.0,
    })
}

fn save_checkpoint(out: &Path, trainer: &Trainer, state: &TrainState) -> Result<()> {
    let tmp = out.join("checkpoint.tmp");
    let dst = out.join("checkpoint");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp)?;
    }
    std::fs::create_dir_all(&tmp)?;
    save_safetensors(&tmp.join(WEIGHTS_FILE), &trainer.tensors(), HashMap::new())?;
    trainer.save_optim(&tmp.join("optim.bpk"))?;
    std::fs::write(tmp.join("state.json"), serde_json::to_vec_pretty(state)?)?;
    if dst.exists() {
        std::fs::remove_dir_all(&dst)?;
    }
    std::fs::rename(&tmp, &dst)?;
    Ok(())
}

/// Runs `host-sim train`.
pub fn train(args: &TrainArgs) -> Result<()> {
    let started = Instant::now();
    let spec_path = args
        .spec
        .clone()
        .unwrap_or_else(|| PathBuf::from("weights").join(epssn::config::SPEC_FILE_NAME));
    let spec_bytes = std::fs::read(&spec_path)
        .with_context(|| format!("cannot read spec {}", spec_path.display()))?;
    let spec = parse_spec(&spec_bytes)?;
    let views = args.views.unwrap_or(spec.baseline.views as usize);
    ensure!((1..=3).contains(&views), "--views must be 1, 2 or 3");
    let batch = args.batch.unwrap_or(spec.training.batch as usize);
    ensure!(batch >= 2, "batch norm needs a batch of at least 2");
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("weights").join(&args.scene));
    let io = (
        spec.input.range_bins as usize,
        spec.input.beam_columns as usize,
    );
    let oo = (
        spec.output.elevation_rows as usize,
        spec.output.azimuth_columns as usize,
    );
    let train_dir = split_dir(&args.data, "train").unwrap_or_else(|| args.data.clone());
    let load_views = views.max(1);
    let train_set = load_dir(&train_dir, load_views, io, oo, args.limit)?;
    ensure!(
        train_set.len() >= 2,
        "{} has fewer than 2 samples",
        train_dir.display()
    );
    let val_set = match split_dir(&args.data, "val") {
        Some(d) => load_dir(&d, load_views, io, oo, Some(args.val_limit))?,
        None => Vec::new(),
    };
    let n = train_set.len();
    // A last batch of one sample would break batch norm; it is dropped.
    let steps_per_epoch = n / batch + usize::from(n % batch >= 2);
    let total = args.epochs * steps_per_epoch;
    let lr = args.lr.unwrap_or(spec.training.lr);
    ensure!(
        lr.is_finite() && lr > 0.0,
        "--lr must be a positive number, not {lr}"
    );
    ensure!(
        args.ce_weight.is_finite() && args.ce_weight >= 0.0,
        "--ce-weight must be 0 or positive, not {}",
        args.ce_weight
    );
    let frac = spec.training.lr_halved_at_fraction;

    if let Some(steps) = args.bench_steps {
        return bench(&spec, args.seed, views, &train_set, batch, steps);
    }

    std::fs::create_dir_all(&out)?;
    let ckpt = out.join("checkpoint");
    let (mut trainer, mut state) = if args.resume && ckpt.join("state.json").exists() {
        let state: TrainState = serde_json::from_slice(&std::fs::read(ckpt.join("state.json"))?)?;
        ensure!(
            state.seed == args.seed && state.batch == batch && state.views == views,
            "checkpoint was made with seed {}, batch {}, views {}: pass the same settings",
            state.seed,
            state.batch,
            state.views
        );
        let ckpt_lr = state.lr.unwrap_or(spec.training.lr);
        ensure!(
            ckpt_lr == lr,
            "checkpoint was made with --lr {ckpt_lr}: pass the same rate"
        );
        ensure!(
            state.ce_weight == args.ce_weight,
            "checkpoint was made with --ce-weight {}: pass the same weight",
            state.ce_weight
        );
        let tensors = load_safetensors(&ckpt.join(WEIGHTS_FILE))?;
        let t = Trainer::from_checkpoint(&spec, &tensors, Some(&ckpt.join("optim.bpk")), views)?;
        eprintln!(
            "resuming at epoch {} batch {} (step {})",
            state.epoch, state.batch_in_epoch, state.global_step
        );
        (
            t,
            TrainState {
                epochs: args.epochs,
                lr: Some(lr),
                ce_weight: args.ce_weight,
                ..state
            },
        )
    } else if args.resume && out.join("manifest.json").exists() {
        // A finished run keeps no checkpoint: continue from its weights and loss history with
        // a fresh Adam state (the moments rebuild within a few hundred steps).
        let state = finished_run_state(&out, args.seed, batch, views)?;
        let tensors = load_safetensors(&out.join(WEIGHTS_FILE))?;
        let t = Trainer::from_checkpoint(&spec, &tensors, None, views)?;
        eprintln!(
            "continuing the finished run in {} after epoch {} (step {}), fresh optimizer state",
            out.display(),
            state.epoch,
            state.global_step
        );
        (
            t,
            TrainState {
                epochs: args.epochs,
                lr: Some(lr),
                ce_weight: args.ce_weight,
                ..state
            },
        )
    } else {
        if args.resume {
            eprintln!("no checkpoint in {}: starting fresh", ckpt.display());
        }
        let t = match &args.init_from {
            Some(dir) => {
                let tensors = load_safetensors(&dir.join(WEIGHTS_FILE))
                    .with_context(|| format!("--init-from {}", dir.display()))?;
                eprintln!("starting from the weights of {}", dir.display());
                Trainer::from_checkpoint(&spec, &tensors, None, views)?
            }
            None => Trainer::new(&spec, args.seed, views)?,
        };
        let s = TrainState {
            epoch: 0,
            batch_in_epoch: 0,
            global_step: 0,
            epoch_loss_sum: 0.0,
            epoch_loss_count: 0,
            history: Vec::new(),
            elapsed_s: 0.0,
            seed: args.seed,
            batch,
            epochs: args.epochs,
            views,
            lr: Some(lr),
            ce_weight: args.ce_weight,
        };
        (t, s)
    };
    trainer.ce_weight = args.ce_weight as f32;
    let elapsed_before = state.elapsed_s;
    let pb = ProgressBar::new(total as u64);
    pb.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:40}] {pos}/{len} eta {eta} {msg}")?
            .progress_chars("=> "),
    );
    pb.set_position(state.global_step as u64);
    let interval = Duration::from_secs_f64(args.checkpoint_minutes.max(0.1) * 60.0);
    let mut last_ckpt = Instant::now();
    while state.epoch < args.epochs {
        let mut order: Vec<usize> = (0..n).collect();
        SplitMix64::new(args.seed ^ (state.epoch as u64 + 1).wrapping_mul(0x9E37_79B9))
            .shuffle(&mut order);
        while state.batch_in_epoch < steps_per_epoch {
            let s = state.batch_in_epoch * batch;
            let idx = &order[s..(s + batch).min(n)];
            let b: Vec<&Sample> = idx.iter().map(|&i| &train_set[i]).collect();
            let loss = trainer.step(&b, lr_at(lr, frac, state.global_step, total))?;
            state.epoch_loss_sum += loss as f64;
            state.epoch_loss_count += 1;
            state.global_step += 1;
            state.batch_in_epoch += 1;
            pb.set_position(state.global_step as u64);
            pb.set_message(format!("epoch {} loss {loss:.4}", state.epoch + 1));
            if last_ckpt.elapsed() >= interval {
                state.elapsed_s = elapsed_before + started.elapsed().as_secs_f64();
                save_checkpoint(&out, &trainer, &state)?;
                last_ckpt = Instant::now();
            }
        }
        let val = trainer.eval_loss(&val_set, batch)?;
        let row = LossRow {
            epoch: state.epoch + 1,
            step: state.global_step,
            train_loss: (state.epoch_loss_sum / state.epoch_loss_count.max(1) as f64) as f32,
            val_loss: val,
        };
        pb.println(format!(
            "epoch {} step {} train {:.5} val {:.5}",
            row.epoch, row.step, row.train_loss, row.val_loss
        ));
        state.history.push(row);
        state.epoch += 1;
        state.batch_in_epoch = 0;
        state.epoch_loss_sum = 0.0;
        state.epoch_loss_count = 0;
        state.elapsed_s = elapsed_before + started.elapsed().as_secs_f64();
        write_curves(&out, &state.history)?;
        save_checkpoint(&out, &trainer, &state)?;
        last_ckpt = Instant::now();
    }
    pb.finish();

    let mut meta = HashMap::new();
    meta.insert("spec_name".to_string(), spec.name.to_string());
    meta.insert("scene".to_string(), args.scene.clone());
    save_safetensors(&out.join(WEIGHTS_FILE), &trainer.tensors(), meta)?;
    std::fs::write(out.join(SPEC_FILE), &spec_bytes)?;
    write_curves(&out, &state.history)?;
    let data_manifest = serde_json::json!({
        "train": data_summary(&train_dir),
        "val": split_dir(&args.data, "val").as_deref().map(data_summary),
    });
    let last = state.history.last();
    let manifest = serde_json::json!({
        "scene": args.scene,
        "spec_name": spec.name.as_str(),
        "spec_file": spec_path.display().to_string(),
        "spec_crc32": format!("0x{:08x}", epssn::crc32::crc32(&spec_bytes)),
        "data_dir": args.data.display().to_string(),
        "data": data_manifest,
        "train_samples": n,
        "val_samples": val_set.len(),
        "views": views,
        "seed": args.seed,
        "init_from": args.init_from.as_ref().map(|p| p.display().to_string()),
        "batch": batch,
        "epochs": args.epochs,
        "steps": state.global_step,
        "lr": lr,
        "lr_halved_at_step": (frac * total as f64).ceil() as usize,
        "loss": if args.ce_weight > 0.0 {
            "mean over pixels of w*|d_hat - clamp(d, r_min, r_max)| + ce_weight * mean over pixels of w*CE(two-hot(clamp(d)), softmax over range bins), w = lambda on mask pixels, 1 elsewhere; val_loss is the first term"
        } else {
            "mean over pixels of w*|d_hat - clamp(d, r_min, r_max)|, w = lambda on mask pixels, 1 elsewhere"
        },
        "lambda": spec.training.lambda,
        "ce_weight": args.ce_weight,
        "final_train_loss": last.map(|r| r.train_loss),
        "final_val_loss": last.map(|r| r.val_loss),
        "wall_time_s": state.elapsed_s,
        "weights": WEIGHTS_FILE,
    });
    std::fs::write(
        out.join("manifest.json"),
        serde_json::to_vec_pretty(&manifest)?,
    )?;
    eprintln!("wrote {}", out.display());
    Ok(())
}

fn bench(
    spec: &epssn::spec::ModelSpec,
    seed: u64,
    views: usize,
    set: &[Sample],
    batch: usize,
    steps: usize,
) -> Result<()> {
    let mut trainer = Trainer::new(spec, seed, views)?;
    let b: Vec<&Sample> = set.iter().cycle().take(batch).collect();
    trainer.step(&b, 1e-3)?;
    let t = Instant::now();
    let cpu0 = process_cpu_seconds();
    for _ in 0..steps {
        trainer.step(&b, 1e-3)?;
    }
    let per = t.elapsed().as_secs_f64() / steps.max(1) as f64;
    let cpu = cpu0
        .zip(process_cpu_seconds())
        .map(|(a, z)| (z - a) / steps.max(1) as f64);
    println!(
        "batch {batch}: {per:.3} s/step wall, {} s/step CPU (all threads)",
        cpu.map_or("?".into(), |c| format!("{c:.3}"))
    );
    for samples in [set.len(), 1000] {
        let spe = samples / batch + usize::from(samples % batch >= 2);
        println!(
            "  {samples} samples: {spe} steps/epoch = {:.1} s/epoch wall; {:.1} epochs in 90 min",
            per * spe as f64,
            90.0 * 60.0 / (per * spe as f64)
        );
    }
    Ok(())
}

/// User + system CPU time of this process (Linux `/proc/self/stat`, 100 ticks/s).
fn process_cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// What a simulated split holds, from its samples' `scene.json` and their split's
/// `sim_params.json`: scene kinds, dataset seeds, sample count, views per sample and speckle
/// looks per view (the record a trained model keeps of its data).
pub fn data_summary(dir: &Path) -> serde_json::Value {
    let mut kinds = std::collections::BTreeSet::new();
    let mut seeds = std::collections::BTreeSet::new();
    let mut views = std::collections::BTreeSet::new();
    let mut splits = std::collections::BTreeSet::new();
    let mut samples = 0usize;
    for d in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let Ok(text) = std::fs::read_to_string(d.path().join("scene.json")) else {
            continue;
        };
        let Ok(j) = serde_json::from_str::<serde_json::Value>(&text) else {
            continue;
        };
        samples += 1;
        kinds.insert(j["kind"].as_str().unwrap_or("?").to_string());
        seeds.insert(j["seed"].as_u64().unwrap_or(u64::MAX));
        views.insert(j["view_rolls_deg"].as_array().map_or(0, |v| v.len()));
        splits.extend(split_of_sample(&d.path()));
    }
    // Each split's sim_params.json once, not once per sample linked from it.
    let looks: std::collections::BTreeSet<u64> = splits
        .iter()
        .filter_map(|s| speckle_looks_of_split(s))
        .collect();
    serde_json::json!({
        "dir": dir.display().to_string(),
        "scenes": kinds,
        "seeds": seeds,
        "samples": samples,
        "views": views,
        "speckle_looks": looks,
    })
}

/// The split folder a sample lives in, through the general mix's links.
fn split_of_sample(sample: &Path) -> Option<PathBuf> {
    Some(std::fs::canonicalize(sample).ok()?.parent()?.to_path_buf())
}

/// Speckle looks averaged per view in a simulated split (`simulate --params` `speckle_looks`,
/// docs/SIMULATOR.md), from its `sim_params.json`; absent from the file means the default, 1.
/// `None` when there is no such file (not simulated data).
fn speckle_looks_of_split(split: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(split.join("sim_params.json")).ok()?;
    let j: serde_json::Value = serde_json::from_str(&text).ok()?;
    Some(j.get("speckle_looks").and_then(|v| v.as_u64()).unwrap_or(1))
}

/// Speckle looks of the split a sample lives in (its `sim_params.json`; `None` without one).
pub fn speckle_looks_of_sample(sample: &Path) -> Option<u64> {
    speckle_looks_of_split(&split_of_sample(sample)?)
}

/// Mean and standard deviation as numbers (NaN for no values: JSON null, a table's NaN).
fn nan_if_none((m, s): (Option<f64>, Option<f64>)) -> (f64, f64) {
    (m.unwrap_or(f64::NAN), s.unwrap_or(f64::NAN))
}

/// Runs `host-sim eval`.
pub fn eval(args: &EvalArgs) -> Result<()> {
    let weights = match &args.weights {
        Some(w) => w.clone(),
        None => epssn_reference::weights::firmware_weights_dir()?,
    };
    let model = FloatModel::load(&weights)?;
    let st = model.statics();
    // By default the view count the model was trained on: a model is far worse on another.
    let views = match args.views {
        Some(v) => v,
        None => epssn_reference::weights::trained_views(&weights)?,
    };
    if !(1..=3).contains(&views) {
        bail!("--views must be 1, 2 or 3");
    }
    let dir = split_dir(&args.data, "test").unwrap_or_else(|| args.data.clone());
    let set = load_dir(&dir, views, st.input_size(), st.output_size(), args.limit)?;
    ensure!(!set.is_empty(), "no samples in {}", dir.display());
    // A model trained on averaged pings reads single pings badly and the reverse (measured,
    // docs/ACCURACY.md): say so beside the figures rather than score silently.
    let data_looks: Vec<u64> = data_summary(&dir)["speckle_looks"]
        .as_array()
        .map(|a| a.iter().filter_map(|v| v.as_u64()).collect())
        .unwrap_or_default();
    let model_looks = epssn_reference::weights::trained_pings_per_view(&weights);
    let mut warnings = Vec::new();
    if let (Some(m), [d]) = (model_looks, data_looks.as_slice()) {
        if u64::from(m) != *d {
            warnings.push(format!(
                "the model was trained on {m} speckle look(s) per view and these data have {d}: \
                 its figures here are not its accuracy on the data it was made for"
            ));
        }
    }
    for w in &warnings {
        eprintln!("warning: {w}");
    }
    let (mut float_m, mut int8_m, mut q_diff, mut q_diff_mask) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut float_b, mut int8_b) = (
        epssn_sim::metrics::ErrorBreakdown::default(),
        epssn_sim::metrics::ErrorBreakdown::default(),
    );
    let blob = if args.int8 {
        std::fs::read(weights.join(epssn_reference::weights::BLOB_FILE))
            .with_context(|| format!("reading the int8 blob in {}", weights.display()))?
    } else {
        Vec::new()
    };
    let int8 = if args.int8 {
        Some(
            epssn::model::Model::from_blob(&blob)
                .map_err(|e| anyhow::anyhow!("int8 blob refused: {e:?}"))?,
        )
    } else {
        None
    };
    let mut ws = Box::new(epssn::model::Workspace::new());
    let folded = if args.float_reference {
        let bundle = epssn_reference::weights::load(&weights)?;
        Some(epssn_reference::floatref::fold_all(&bundle.float)?)
    } else {
        None
    };
    for chunk in set.chunks(8) {
        let refs: Vec<&[Vec<u8>]> = chunk.iter().map(|s| s.views.as_slice()).collect();
        let float_maps = match &folded {
            Some(f) => chunk
                .iter()
                .map(|s| {
                    // One view is fed as its own source, as the burn model's ablation does.
                    let views: Vec<&[u8]> = if s.views.len() == 1 {
                        vec![&s.views[0], &s.views[0]]
                    } else {
                        s.views.iter().map(|v| v.as_slice()).collect()
                    };
                    Ok(epssn_reference::floatref::run_folded(f, &views, &mut |_, _| {})?.depth)
                })
                .collect::<Result<Vec<_>>>()?,
            None => model.predict_batch(&refs)?,
        };
        for (s, d) in chunk.iter().zip(float_maps) {
            let mask = epssn_sim::metrics::mask_from_f32(&s.mask);
            if let Some(q) = &int8 {
                let dq = epssn_reference::int8::depth_metres(q, &s.views, &mut ws)?;
                int8_m.push(epssn_sim::metrics::evaluate(&dq, &s.depth, &mask)?);
                if args.breakdown {
                    int8_b.add(&dq, &s.depth, &mask)?;
                }
                let diff: f64 = dq.iter().zip(&d).map(|(a, b)| (a - b).abs() as f64).sum();
                q_diff.push(1000.0 * diff / dq.len() as f64);
                let (sum, n) = dq
                    .iter()
                    .zip(&d)
                    .zip(&mask)
                    .filter(|(_, &m)| m)
                    .fold((0f64, 0usize), |(s, n), ((a, b), _)| {
                        (s + (a - b).abs() as f64, n + 1)
                    });
                if n > 0 {
                    q_diff_mask.push(1000.0 * sum / n as f64);
                }
            }
            // The paper's MAE (all pixels, labels clamped), the masked MAE and the CD
            // (epssn_sim::metrics documents the exact formulas).
            float_m.push(epssn_sim::metrics::evaluate(&d, &s.depth, &mask)?);
            if args.breakdown {
                float_b.add(&d, &s.depth, &mask)?;
            }
        }
    }
    let float = epssn_sim::metrics::Accuracy::of(&float_m);
    let int8_json = args.int8.then(|| {
        let (dm, _) = nan_if_none(epssn_sim::metrics::mean_std(&q_diff));
        let (dmm, _) = nan_if_none(epssn_sim::metrics::mean_std(&q_diff_mask));
        serde_json::json!({
            "accuracy": epssn_sim::metrics::Accuracy::of(&int8_m),
            "int8_vs_float_mae": dm, "int8_vs_float_mae_mask": dmm,
        })
    });
    if args.json {
        let mut int8 = serde_json::Value::Null;
        if let Some(j) = &int8_json {
            int8 = serde_json::to_value(&j["accuracy"])?;
            int8["int8_vs_float_mae"] = j["int8_vs_float_mae"].clone();
            int8["int8_vs_float_mae_mask"] = j["int8_vs_float_mae_mask"].clone();
        }
        let mut j = serde_json::json!({
            "weights": weights.display().to_string(),
            "data": dir.display().to_string(),
            "views": views,
            "samples": set.len(),
            "speckle_looks": { "data": data_looks, "model": model_looks },
            "warnings": warnings,
            "metric": "mae: 1000/(E*A) * sum over all E*A pixels of |pred - clamp(label, r_min, r_max)| (the paper's formula, mm); mae_masked: the same mean over the ground-truth mask; cd: 500 * symmetric chamfer (m^2) over the mask's points",
            "float": float,
            "int8": int8,
        });
        if args.breakdown {
            j["breakdown"] = serde_json::json!({
                "classes": "surface: mask pixels with every 4-neighbour in the mask; silhouette: mask pixels with one outside; empty_far / empty_near: rays outside the mask labelled r_max / r_min. pixel_share and error_share in % (pooled over the maps), mae in mm",
                "float": float_b.rows(),
                "int8": args.int8.then(|| int8_b.rows()),
            });
        }
        println!("{}", serde_json::to_string_pretty(&j)?);
    } else {
        println!(
            "weights {}  data {}  views {views}  samples {}",
            weights.display(),
            dir.display(),
            set.len()
        );
        println!("float: {}", float.line());
        if let Some(j) = &int8_json {
            let acc = epssn_sim::metrics::Accuracy::of(&int8_m);
            println!(
                "int8:  {}   int8 vs float {:.2} mm ({:.2} mm on the mask)",
                acc.line(),
                j["int8_vs_float_mae"].as_f64().unwrap_or(f64::NAN),
                j["int8_vs_float_mae_mask"].as_f64().unwrap_or(f64::NAN),
            );
        }
        if args.breakdown {
            let models = [
                ("float", Some(&float_b)),
                ("int8", args.int8.then_some(&int8_b)),
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_summary_records_the_speckle_looks_of_each_split() {
        let root = tempfile::tempdir().unwrap();
        let sample = |split: &str, i: usize, params: Option<&str>| {
            let d = root.path().join(split).join(format!("{i:06}"));
            std::fs::create_dir_all(&d).unwrap();
            std::fs::write(
                d.join("scene.json"),
                r#"{"kind":"terrain","seed":1,"view_rolls_deg":[0.0,7.0]}"#,
            )
            .unwrap();
            if let Some(p) = params {
                std::fs::write(root.path().join(split).join("sim_params.json"), p).unwrap();
            }
            d
        };
        let four = sample("four", 0, Some(r#"{"speckle":true,"speckle_looks":4}"#));
        let one = sample("one", 0, Some(r#"{"speckle":true}"#));
        let recorded = sample("recorded", 0, None);
        assert_eq!(speckle_looks_of_sample(&four), Some(4));
        assert_eq!(
            speckle_looks_of_sample(&one),
            Some(1),
            "absent means the default"
        );
        assert_eq!(speckle_looks_of_sample(&recorded), None);
        // A mix of links to both, as scripts/train-general.sh builds, records both.
        let mix = root.path().join("mix");
        std::fs::create_dir_all(&mix).unwrap();
        std::os::unix::fs::symlink(&four, mix.join("000000")).unwrap();
        std::os::unix::fs::symlink(&one, mix.join("000001")).unwrap();
        let s = data_summary(&mix);
        assert_eq!(s["speckle_looks"], serde_json::json!([1, 4]));
        assert_eq!(s["samples"], 2);
        assert_eq!(
            data_summary(&root.path().join("recorded"))["speckle_looks"],
            serde_json::json!([])
        );
    }

    #[test]
    fn loss_curves_read_back_and_redraw() {
        let dir = tempfile::tempdir().unwrap();
        let rows: Vec<LossRow> = (1..=4)
            .map(|e| LossRow {
                epoch: e,
                step: 10 * e,
                train_loss: 1.0 / e as f32,
                val_loss: if e == 2 { f32::NAN } else { 1.2 / e as f32 },
            })
            .collect();
        write_curves(dir.path(), &rows).unwrap();
        let back = read_loss_csv(&dir.path().join("loss.csv")).unwrap();
        assert_eq!(back.len(), rows.len());
        for (a, b) in back.iter().zip(&rows) {
            assert_eq!(
                (a.epoch, a.step, a.train_loss),
                (b.epoch, b.step, b.train_loss)
            );
            assert!(a.val_loss == b.val_loss || (a.val_loss.is_nan() && b.val_loss.is_nan()));
        }
        std::fs::remove_file(dir.path().join("loss.png")).unwrap();
        redraw_loss_plot(dir.path()).unwrap();
        assert!(dir.path().join("loss.png").exists());
        // A malformed history is an error, not a panic.
        std::fs::write(
            dir.path().join("loss.csv"),
            "epoch,step,train_loss,val_loss\n1,2\n",
        )
        .unwrap();
        assert!(redraw_loss_plot(dir.path()).is_err());
    }
}
