//! `host-sim train`: resumable training with loss curves, checkpoints and a manifest.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use super::train::{lr_at, Trainer};
use super::{
    load_safetensors, parse_spec, save_safetensors, Grid, SplitMix64, SPEC_FILE, WEIGHTS_FILE,
};
use epssn_eval::data::{load_dir, split_dir, Sample};
use epssn_eval::summary::data_summary;

/// Options of `host-sim train`.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// Scene name (sphere, terrain, artificial); names the default output folder.
    pub scene: String,
    /// Simulated data folder with `train/` (and optionally `val/`) sample folders.
    pub data: PathBuf,
    /// Epochs over the training split.
    pub epochs: usize,
    /// Batch size (default: the spec's).
    pub batch: Option<usize>,
    /// Continue from `OUT/checkpoint/`, or, when a finished run left none, from `OUT`'s weights
    /// and loss history with a fresh optimizer state (to train a finished run further).
    pub resume: bool,
    /// Output folder (default `weights/<scene>`).
    pub out: Option<PathBuf>,
    /// Model spec (default: the one this build was generated from, `weights/epssn-s.json`
    /// unless `EPSSN_SPEC` named another; the quantiser and the library follow the build's).
    pub spec: Option<PathBuf>,
    /// Views (default: the spec's; 1 = reference as its own source).
    pub views: Option<usize>,
    /// Seed of weight initialisation and shuffling.
    pub seed: u64,
    /// Minutes between checkpoints inside an epoch (a checkpoint is also written every epoch).
    pub checkpoint_minutes: f64,
    /// Use at most this many training samples.
    pub limit: Option<usize>,
    /// Use at most this many validation samples.
    pub val_limit: usize,
    /// Only time this many training steps (after one warm-up step) and exit without saving.
    pub bench_steps: Option<usize>,
    /// Start from the weights of another trained model (its `model.safetensors`) with the same
    /// layers: convolution weights do not depend on the image size, so a model of EPSSN-S
    /// starts EPSSN-P (docs/PAPER.md). Fresh optimizer state and schedule; ignored on --resume
    /// from a checkpoint.
    pub init_from: Option<PathBuf>,
    /// Learning rate before the halving (default: the spec's `training.lr`). A lower rate
    /// fine-tunes a trained model (`--init-from`) without first undoing it; the manifest records
    /// the rate used, and a resumed run must pass the same one.
    pub lr: Option<f64>,
    /// Weight of a two-hot cross-entropy term on the range bins beside the paper's L1 loss
    /// (train.rs; 0: L1 alone). Validation loss stays the L1 term. A resumed run must pass the
    /// same weight.
    pub ce_weight: f64,
    /// Weight of the no-return term (train.rs): the binary cross-entropy of each ray's last
    /// (first) bin mass against "met nothing" ("met something nearer") in its label; with it
    /// the two-hot labels of out-of-window pixels sit on the end bins. 0: no such term. A
    /// resumed run must pass the same weight.
    pub no_return_weight: f64,
    /// Quantisation-aware training: round every activation, in each forward pass, to the int8
    /// grid of the activation scales in this folder's `quantisation.json` (a quantised model of
    /// the same spec, usually the one `--init-from` names), the gradient passing the rounding
    /// unchanged. A resumed run must pass the same scales.
    pub fake_quant: Option<PathBuf>,
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
    /// The no-return term's weight; 0 in checkpoints written before `--no-return-weight`.
    #[serde(default)]
    no_return_weight: f64,
    /// The activation scales of `--fake-quant`; empty without it (and in checkpoints written
    /// before it).
    #[serde(default)]
    fake_quant: BTreeMap<String, f64>,
}

/// The int8 grids of `scales`: codes 0..=255 for the unsigned cost volume, −128..=127 for
/// every other tensor (docs/QUANTISATION.md "Numbers").
fn grids(scales: &BTreeMap<String, f64>) -> BTreeMap<String, Grid> {
    scales
        .iter()
        .map(|(name, &scale)| {
            let (lo, hi) = if name == "cost" {
                (0.0, 255.0)
            } else {
                (-128.0, 127.0)
            };
            let scale = scale as f32;
            (name.clone(), Grid { scale, lo, hi })
        })
        .collect()
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
        no_return_weight: 0.0,
        fake_quant: BTreeMap::new(),
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

/// A training run's settings and data, resolved from the arguments and the spec.
struct Plan {
    spec: epssn::spec::ModelSpec,
    spec_path: PathBuf,
    spec_bytes: Vec<u8>,
    views: usize,
    batch: usize,
    out: PathBuf,
    train_dir: PathBuf,
    train_set: Vec<Sample>,
    val_set: Vec<Sample>,
    steps_per_epoch: usize,
    total_steps: usize,
    lr: f64,
    /// `--fake-quant`'s activation scales (empty without it).
    fake_quant: BTreeMap<String, f64>,
}

impl Plan {
    fn of(args: &TrainOptions) -> Result<Self> {
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
        ensure!(
            args.no_return_weight.is_finite() && args.no_return_weight >= 0.0,
            "--no-return-weight must be 0 or positive, not {}",
            args.no_return_weight
        );
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
        let train_set = load_dir(&train_dir, views, io, oo, args.limit)?;
        ensure!(
            train_set.len() >= 2,
            "{} has fewer than 2 samples",
            train_dir.display()
        );
        let val_set = match split_dir(&args.data, "val") {
            Some(d) => load_dir(&d, views, io, oo, Some(args.val_limit))?,
            None => Vec::new(),
        };
        let n = train_set.len();
        // A last batch of one sample would break batch norm; it is dropped.
        let steps_per_epoch = n / batch + usize::from(n % batch >= 2);
        Ok(Plan {
            total_steps: args.epochs * steps_per_epoch,
            spec,
            spec_path,
            spec_bytes,
            views,
            batch,
            out,
            train_dir,
            train_set,
            val_set,
            steps_per_epoch,
            lr,
            fake_quant: match &args.fake_quant {
                Some(dir) => {
                    epssn_reference::weights::activation_scales(dir).context("--fake-quant")?
                }
                None => BTreeMap::new(),
            },
        })
    }
}

/// Runs `host-sim train`.
pub fn train(args: &TrainOptions) -> Result<()> {
    let started = Instant::now();
    let plan = Plan::of(args)?;
    if let Some(steps) = args.bench_steps {
        let (spec, seed, views) = (&plan.spec, args.seed, plan.views);
        return bench(spec, seed, views, &plan.train_set, plan.batch, steps);
    }
    std::fs::create_dir_all(&plan.out)?;
    let (mut trainer, mut state) = start_or_resume(args, &plan)?;
    trainer.ce_weight = args.ce_weight as f32;
    trainer.no_return_weight = args.no_return_weight as f32;
    trainer
        .model
        .statics
        .set_fake_quant(grids(&plan.fake_quant))?;
    run_epochs(args, &plan, &mut trainer, &mut state, started)?;

    let mut meta = HashMap::new();
    meta.insert("spec_name".to_string(), plan.spec.name.to_string());
    meta.insert("scene".to_string(), args.scene.clone());
    save_safetensors(&plan.out.join(WEIGHTS_FILE), &trainer.tensors(), meta)?;
    std::fs::write(plan.out.join(SPEC_FILE), &plan.spec_bytes)?;
    write_curves(&plan.out, &state.history)?;
    std::fs::write(
        plan.out.join("manifest.json"),
        serde_json::to_vec_pretty(&manifest(args, &plan, &state))?,
    )?;
    eprintln!("wrote {}", plan.out.display());
    Ok(())
}

/// The trainer and its state: from `OUT/checkpoint/` or a finished run in `OUT` with
/// `--resume`, else fresh (from `--init-from`'s weights or a seeded initialisation).
fn start_or_resume(args: &TrainOptions, plan: &Plan) -> Result<(Trainer, TrainState)> {
    let (spec, views, batch, lr) = (&plan.spec, plan.views, plan.batch, plan.lr);
    let ckpt = plan.out.join("checkpoint");
    // A resumed run keeps its counters and history and takes this run's epochs and rates.
    let continued = |state: TrainState| TrainState {
        epochs: args.epochs,
        lr: Some(lr),
        ce_weight: args.ce_weight,
        no_return_weight: args.no_return_weight,
        fake_quant: plan.fake_quant.clone(),
        ..state
    };
    if args.resume && ckpt.join("state.json").exists() {
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
        ensure!(
            state.no_return_weight == args.no_return_weight,
            "checkpoint was made with --no-return-weight {}: pass the same weight",
            state.no_return_weight
        );
        ensure!(
            state.fake_quant == plan.fake_quant,
            "checkpoint was made with other --fake-quant scales ({:?}): pass the same folder",
            state.fake_quant
        );
        let tensors = load_safetensors(&ckpt.join(WEIGHTS_FILE))?;
        let t = Trainer::from_checkpoint(spec, &tensors, Some(&ckpt.join("optim.bpk")), views)?;
        eprintln!(
            "resuming at epoch {} batch {} (step {})",
            state.epoch, state.batch_in_epoch, state.global_step
        );
        return Ok((t, continued(state)));
    }
    if args.resume && plan.out.join("manifest.json").exists() {
        // A finished run keeps no checkpoint: continue from its weights and loss history with
        // a fresh Adam state (the moments rebuild within a few hundred steps).
        let state = finished_run_state(&plan.out, args.seed, batch, views)?;
        let tensors = load_safetensors(&plan.out.join(WEIGHTS_FILE))?;
        let t = Trainer::from_checkpoint(spec, &tensors, None, views)?;
        eprintln!(
            "continuing the finished run in {} after epoch {} (step {}), fresh optimizer state",
            plan.out.display(),
            state.epoch,
            state.global_step
        );
        return Ok((t, continued(state)));
    }
    if args.resume {
        eprintln!("no checkpoint in {}: starting fresh", ckpt.display());
    }
    let t = match &args.init_from {
        Some(dir) => {
            let tensors = load_safetensors(&dir.join(WEIGHTS_FILE))
                .with_context(|| format!("--init-from {}", dir.display()))?;
            eprintln!("starting from the weights of {}", dir.display());
            Trainer::from_checkpoint(spec, &tensors, None, views)?
        }
        None => Trainer::new(spec, args.seed, views)?,
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
        no_return_weight: args.no_return_weight,
        fake_quant: plan.fake_quant.clone(),
    };
    Ok((t, s))
}

/// Trains until `args.epochs`, validating and checkpointing at every epoch's end and every
/// `--checkpoint-minutes` inside one.
fn run_epochs(
    args: &TrainOptions,
    plan: &Plan,
    trainer: &mut Trainer,
    state: &mut TrainState,
    started: Instant,
) -> Result<()> {
    let (n, batch, total) = (plan.train_set.len(), plan.batch, plan.total_steps);
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
        while state.batch_in_epoch < plan.steps_per_epoch {
            let s = state.batch_in_epoch * batch;
            let idx = &order[s..(s + batch).min(n)];
            let b: Vec<&Sample> = idx.iter().map(|&i| &plan.train_set[i]).collect();
            let rate = lr_at(
                plan.lr,
                plan.spec.training.lr_halved_at_fraction,
                state.global_step,
                total,
            );
            let loss = trainer.step(&b, rate)?;
            state.epoch_loss_sum += loss as f64;
            state.epoch_loss_count += 1;
            state.global_step += 1;
            state.batch_in_epoch += 1;
            pb.set_position(state.global_step as u64);
            pb.set_message(format!("epoch {} loss {loss:.4}", state.epoch + 1));
            if last_ckpt.elapsed() >= interval {
                state.elapsed_s = elapsed_before + started.elapsed().as_secs_f64();
                save_checkpoint(&plan.out, trainer, state)?;
                last_ckpt = Instant::now();
            }
        }
        let val = trainer.eval_loss(&plan.val_set, batch)?;
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
        write_curves(&plan.out, &state.history)?;
        save_checkpoint(&plan.out, trainer, state)?;
        last_ckpt = Instant::now();
    }
    pb.finish();
    Ok(())
}

/// The finished run's record: spec, data, settings, schedule, loss and final losses.
fn manifest(args: &TrainOptions, plan: &Plan, state: &TrainState) -> serde_json::Value {
    let spec = &plan.spec;
    let last = state.history.last();
    serde_json::json!({
        "scene": args.scene,
        "spec_name": spec.name.as_str(),
        "spec_file": plan.spec_path.display().to_string(),
        "spec_crc32": format!("0x{:08x}", epssn::crc32::crc32(&plan.spec_bytes)),
        "data_dir": args.data.display().to_string(),
        "data": {
            "train": data_summary(&plan.train_dir),
            "val": split_dir(&args.data, "val").as_deref().map(data_summary),
        },
        "train_samples": plan.train_set.len(),
        "val_samples": plan.val_set.len(),
        "views": plan.views,
        "seed": args.seed,
        "init_from": args.init_from.as_ref().map(|p| p.display().to_string()),
        "batch": plan.batch,
        "epochs": args.epochs,
        "steps": state.global_step,
        "lr": plan.lr,
        "lr_halved_at_step": (spec.training.lr_halved_at_fraction * plan.total_steps as f64).ceil() as usize,
        "loss": loss_text(args),
        "lambda": spec.training.lambda,
        "ce_weight": args.ce_weight,
        "no_return_weight": args.no_return_weight,
        "fake_quant": args.fake_quant.as_ref().map(|d| serde_json::json!({
            "from": d.display().to_string(),
            "activation_scales": plan.fake_quant,
        })),
        "final_train_loss": last.map(|r| r.train_loss),
        "final_val_loss": last.map(|r| r.val_loss),
        "wall_time_s": state.elapsed_s,
        "weights": WEIGHTS_FILE,
    })
}

/// The training loss's formula as the manifest states it.
fn loss_text(args: &TrainOptions) -> String {
    let mut s = String::from("mean over pixels of w*|d_hat - clamp(d, r_min, r_max)|");
    if args.ce_weight > 0.0 {
        s += " + ce_weight * mean over pixels of w*CE(two-hot(clamp(d)), softmax over range bins)";
    }
    if args.no_return_weight > 0.0 {
        s += " + no_return_weight * mean over pixels of w*(BCE(p_last, d >= r_max) + BCE(p_first, d <= r_min)), the two-hot of an out-of-window label on its end bin";
    }
    s += ", w = lambda on mask pixels, 1 elsewhere";
    if args.fake_quant.is_some() {
        s += "; every activation rounded to its int8 grid in the forward pass (fake_quant), straight-through gradient";
    }
    if args.ce_weight > 0.0 || args.no_return_weight > 0.0 {
        s += "; val_loss is the first term";
    }
    s
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

#[cfg(test)]
mod tests {
    use super::*;

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
