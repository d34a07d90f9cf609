//! Training: the paper's recipe (masked L1 with λ, Adam, lr halved at mid-training).
//!
//! Loss (exact formula): with prediction `d̂`, label `d` clamped to `[r_min, r_max]` and mask
//! `m ∈ {0, 1}` per pixel, `w = 1 + (λ − 1)·m` (λ on in-window pixels, 1 elsewhere) and
//! `loss = mean over all B·E·A pixels of w · |d̂ − clamp(d)|` (metres).

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, ensure, Context, Result};
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::{Device, Tensor, TensorData};
use epssn::spec::ModelSpec;

use super::data::Sample;
use super::{images_tensor, EpssnModel, NamedTensor};

/// Masked L1 loss (see the module docs), a scalar tensor.
pub fn masked_l1(
    pred: Tensor<3>,
    depth: Tensor<3>,
    mask: Tensor<3>,
    lambda: f32,
    r_min: f32,
    r_max: f32,
) -> Tensor<1> {
    let target = depth.clamp(r_min, r_max);
    let w = mask.mul_scalar(lambda - 1.0).add_scalar(1.0);
    ((pred - target).abs() * w).mean()
}

/// Batch tensors: views (`views` of them; one view is repeated as its own source), depth, mask.
pub fn batch_tensors(
    model: &EpssnModel,
    batch: &[&Sample],
    views: usize,
    device: &Device,
) -> Result<(Vec<Tensor<4>>, Tensor<3>, Tensor<3>)> {
    let (r, w) = model.statics.input_size();
    let (e, a) = model.statics.output_size();
    let mut vt = Vec::new();
    for k in 0..views.max(2) {
        let k = if views == 1 { 0 } else { k };
        let imgs: Vec<&[u8]> = batch
            .iter()
            .map(|s| {
                s.views
                    .get(k)
                    .map(|v| v.as_slice())
                    .ok_or_else(|| anyhow!("sample {} has no view {k}", s.dir.display()))
            })
            .collect::<Result<_>>()?;
        vt.push(images_tensor(&imgs, r, w, device)?);
    }
    let stack = |f: &dyn Fn(&Sample) -> &Vec<f32>| -> Result<Tensor<3>> {
        let mut d = Vec::with_capacity(batch.len() * e * a);
        for s in batch {
            let v = f(s);
            ensure!(
                v.len() == e * a,
                "label of {} has {} values",
                s.dir.display(),
                v.len()
            );
            d.extend_from_slice(v);
        }
        Ok(Tensor::from_data(
            TensorData::new(d, [batch.len(), e, a]),
            device,
        ))
    };
    Ok((vt, stack(&|s| &s.depth)?, stack(&|s| &s.mask)?))
}

/// Model + Adam on the autodiff flex device.
pub struct Trainer {
    /// The model being trained.
    pub model: EpssnModel,
    /// Adam state.
    pub optim: ModuleOptimizer,
    /// Loss weight of in-window pixels.
    pub lambda: f32,
    /// Views fed to the model (1 = reference as its own source).
    pub views: usize,
    device: Device,
}

fn scalar(t: Tensor<1>) -> Result<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow!("{e:?}"))?
        .first()
        .copied()
        .ok_or_else(|| anyhow!("empty loss"))
}

impl Trainer {
    /// A fresh model initialised from `seed`.
    pub fn new(spec: &ModelSpec, seed: u64, views: usize) -> Result<Self> {
        let device = Device::flex().autodiff();
        device.seed(seed);
        let model = EpssnModel::init(spec, seed, &device)?;
        Self::with_model(model, views, device)
    }

    /// Continues from saved tensors (parameter ids restored) and optional optimizer state.
    pub fn from_checkpoint(
        spec: &ModelSpec,
        tensors: &BTreeMap<String, NamedTensor>,
        optim_file: Option<&Path>,
        views: usize,
    ) -> Result<Self> {
        let device = Device::flex().autodiff();
        let model = EpssnModel::from_tensors(spec, tensors, &device)?;
        let mut t = Self::with_model(model, views, device)?;
        if let Some(p) = optim_file {
            t.optim = t
                .optim
                .load(p)
                .map_err(|e| anyhow!("cannot load optimizer state {}: {e:?}", p.display()))?;
        }
        Ok(t)
    }

    fn with_model(model: EpssnModel, views: usize, device: Device) -> Result<Self> {
        ensure!((1..=3).contains(&views), "views must be 1, 2 or 3");
        let lambda = model.statics.spec.training.lambda as f32;
        Ok(Self {
            model,
            optim: AdamConfig::new().init(),
            lambda,
            views,
            device,
        })
    }

    /// One Adam step on `batch` with learning rate `lr`; returns the loss before the step.
    pub fn step(&mut self, batch: &[&Sample], lr: f64) -> Result<f32> {
        let (views, depth, mask) = batch_tensors(&self.model, batch, self.views, &self.device)?;
        let st = &self.model.statics;
        let out = self.model.forward(&views, None)?;
        let loss = masked_l1(out.depth, depth, mask, self.lambda, st.r_min, st.r_max);
        let value = scalar(loss.clone().detach())?;
        ensure!(value.is_finite(), "loss is {value}");
        let grads = loss.backward();
        let grads = GradientsParams::from_grads(grads, &self.model.net);
        let net = self.model.net.clone();
        self.model.net = self.optim.step(lr, net, grads);
        Ok(value)
    }

    /// Mean loss over `samples` in inference mode (batch norm uses running statistics).
    pub fn eval_loss(&self, samples: &[Sample], batch: usize) -> Result<f32> {
        if samples.is_empty() {
            return Ok(f32::NAN);
        }
        let device = Device::flex();
        let model = EpssnModel {
            net: self.model.net.valid(),
            statics: self.model.statics.clone(),
        };
        let st = &model.statics;
        let mut sum = 0f64;
        for chunk in samples.chunks(batch.max(1)) {
            let refs: Vec<&Sample> = chunk.iter().collect();
            let (views, depth, mask) = batch_tensors(&model, &refs, self.views, &device)?;
            let out = model.forward(&views, None)?;
            let l = masked_l1(out.depth, depth, mask, self.lambda, st.r_min, st.r_max);
            sum += scalar(l)? as f64 * chunk.len() as f64;
        }
        Ok((sum / samples.len() as f64) as f32)
    }

    /// The current weights by name (with parameter ids).
    pub fn tensors(&self) -> BTreeMap<String, NamedTensor> {
        self.model.to_tensors()
    }

    /// Saves the optimizer state (burnpack).
    pub fn save_optim(&self, path: &Path) -> Result<()> {
        self.optim
            .save(path)
            .map_err(|e| anyhow!("cannot save optimizer state: {e:?}"))
            .with_context(|| path.display().to_string())
    }
}

/// Learning rate at `step` of `total`: `lr` before `fraction·total`, `lr/2` from there on.
pub fn lr_at(lr: f64, fraction: f64, step: usize, total: usize) -> f64 {
    if (step as f64) < fraction * total as f64 {
        lr
    } else {
        lr * 0.5
    }
}
