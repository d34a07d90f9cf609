//! Training: the paper's recipe (masked L1 with λ, Adam, lr halved at mid-training).
//!
//! Loss (exact formula): with prediction `d̂`, label `d` clamped to `[r_min, r_max]` and mask
//! `m ∈ {0, 1}` per pixel, `w = 1 + (λ − 1)·m` (λ on in-window pixels, 1 elsewhere) and
//! `loss = mean over all B·E·A pixels of w · |d̂ − clamp(d)|` (metres).
//!
//! With `--ce-weight c > 0` the training loss adds `c · mean over pixels of w · CE(q, p)`: the
//! cross-entropy between the soft-argmax's distribution `p` over the range bins and the label's
//! two-hot `q` (the two bins around `clamp(d)`, weighted so that `Σ q_r · bin_r = clamp(d)`).
//! The L1 term alone is met by any distribution with the right mean, e.g. one spread over
//! several surfaces; the CE term asks for the mass at the labelled range. Validation loss stays
//! the L1 term, so curves with and without it compare.
//!
//! With `--no-return-weight μ > 0` it adds `μ · mean over pixels of w · (BCE(p_{R−1}, y_far) +
//! BCE(p_0, y_near))`: the binary cross-entropy of each ray's last-bin mass against
//! `y_far = [d ≥ r_max]` (the ray met nothing in the window) and of its first-bin mass against
//! `y_near = [d ≤ r_min]` (it met something nearer). That is what the device's no-return
//! decision reads (spec `no_return_mass`, QUANTISATION.md). The two-hot labels then put an
//! out-of-window label wholly on its end bin, so the two terms ask for the same mass.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{anyhow, ensure, Context, Result};
use burn::module::Module;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::activation::log_softmax;
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
    ((pred - target).abs() * pixel_weights(mask, lambda)).mean()
}

/// The loss's pixel weights `w = 1 + (λ − 1)·m` (λ on in-window pixels, 1 elsewhere), `[B][E][A]`.
fn pixel_weights(mask: Tensor<3>, lambda: f32) -> Tensor<3> {
    mask.mul_scalar(lambda - 1.0).add_scalar(1.0)
}

/// Two-hot labels `[B][E][R][A]` of the depth maps `depths` (`[E][A]` each, metres) over the
/// soft-argmax bins `bins` (ascending centres, metres): per pixel the two bins around the
/// clamped label, weighted so that their mean is the label; with `ends`, a label at or beyond
/// an end of the window is one-hot on that end's bin (the no-return classes).
pub fn two_hot_labels(
    depths: &[&[f32]],
    (e, a): (usize, usize),
    bins: &[f32],
    (r_min, r_max): (f32, f32),
    ends: bool,
) -> Vec<f32> {
    let r = bins.len();
    let mut q = vec![0f32; depths.len() * e * r * a];
    if r < 2 {
        return q;
    }
    for (i, depth) in depths.iter().enumerate() {
        for (p, &d) in depth.iter().enumerate().take(e * a) {
            let (row, col) = (p / a, p % a);
            let at = |bin: usize| ((i * e + row) * r + bin) * a + col;
            if ends && (d >= r_max || d <= r_min) {
                q[at(if d >= r_max { r - 1 } else { 0 })] = 1.0;
                continue;
            }
            let d = d.clamp(r_min, r_max);
            let hi = bins.partition_point(|&x| x <= d).clamp(1, r - 1);
            let (b0, b1) = (bins[hi - 1], bins[hi]);
            let t = ((d - b0) / (b1 - b0)).clamp(0.0, 1.0);
            q[at(hi - 1)] = 1.0 - t;
            q[at(hi)] = t;
        }
    }
    q
}

/// The cross-entropy term (see the module docs), a scalar tensor: `logits` `[B][1][E][R][A]`,
/// two-hot labels `q` of the same shape, mask `[B][E][A]`.
pub fn masked_two_hot_ce(
    logits: Tensor<5>,
    q: Tensor<5>,
    mask: Tensor<3>,
    lambda: f32,
) -> Tensor<1> {
    let [b, _, e, _, a] = logits.dims();
    let w = pixel_weights(mask, lambda).reshape([b, 1, e, 1, a]);
    ((q * log_softmax(logits, 3)).sum_dim(3).neg() * w).mean()
}

/// The no-return term (see the module docs), a scalar tensor: `logits` `[B][1][E][R][A]`,
/// `far`/`near` the labels' `[d ≥ r_max]`/`[d ≤ r_min]` as 0/1, and mask, `[B][E][A]`.
pub fn no_return_bce(
    logits: Tensor<5>,
    far: Tensor<3>,
    near: Tensor<3>,
    mask: Tensor<3>,
    lambda: f32,
) -> Tensor<1> {
    let [b, _, e, r, a] = logits.dims();
    let log_p = log_softmax(logits, 3);
    let bce = |bin: usize, y: Tensor<3>| {
        let lp = log_p.clone().narrow(3, bin, 1).reshape([b, e, a]);
        // log(1 − p), kept finite where p rounds to 1.
        let lq = lp.clone().exp().neg().add_scalar(1.0).clamp_min(1e-7).log();
        (y.clone() * lp + y.neg().add_scalar(1.0) * lq).neg()
    };
    ((bce(r - 1, far) + bce(0, near)) * pixel_weights(mask, lambda)).mean()
}

/// Per pixel of `depths` (`[E][A]` each), 1 where `hit(d)` holds, else 0, as `[B][E][A]`.
fn indicator(
    depths: &[&[f32]],
    (e, a): (usize, usize),
    hit: impl Fn(f32) -> bool,
    device: &Device,
) -> Tensor<3> {
    let v: Vec<f32> = depths
        .iter()
        .flat_map(|d| d.iter().map(|&x| f32::from(u8::from(hit(x)))))
        .collect();
    Tensor::from_data(TensorData::new(v, [depths.len(), e, a]), device)
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
    /// Weight of the two-hot cross-entropy term (0: the paper's L1 loss alone).
    pub ce_weight: f32,
    /// Weight of the no-return term (0: none).
    pub no_return_weight: f32,
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
            ce_weight: 0.0,
            no_return_weight: 0.0,
            device,
        })
    }

    /// One Adam step on `batch` with learning rate `lr`; returns the loss before the step.
    pub fn step(&mut self, batch: &[&Sample], lr: f64) -> Result<f32> {
        let (views, depth, mask) = batch_tensors(&self.model, batch, self.views, &self.device)?;
        let st = &self.model.statics;
        let out = self.model.forward(&views, None)?;
        let mut loss = masked_l1(
            out.depth,
            depth,
            mask.clone(),
            self.lambda,
            st.r_min,
            st.r_max,
        );
        let [b, _, e, r, a] = out.logits.dims();
        let depths: Vec<&[f32]> = batch.iter().map(|s| s.depth.as_slice()).collect();
        let ends = self.no_return_weight > 0.0;
        if self.ce_weight > 0.0 {
            let window = (st.r_min, st.r_max);
            let q = two_hot_labels(&depths, (e, a), &st.depth_bins, window, ends);
            let q = Tensor::<5>::from_data(TensorData::new(q, [b, 1, e, r, a]), &self.device);
            let ce = masked_two_hot_ce(out.logits.clone(), q, mask.clone(), self.lambda);
            loss = loss + ce.mul_scalar(self.ce_weight);
        }
        if ends {
            let (r_min, r_max) = (st.r_min, st.r_max);
            let far = indicator(&depths, (e, a), |d| d >= r_max, &self.device);
            let near = indicator(&depths, (e, a), |d| d <= r_min, &self.device);
            let nr = no_return_bce(out.logits, far, near, mask, self.lambda);
            loss = loss + nr.mul_scalar(self.no_return_weight);
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_hot_labels_sum_to_one_and_mean_the_clamped_label() {
        let bins: Vec<f32> = (0..10).map(|i| 1.9 + 0.2 * i as f32).collect();
        let (r_min, r_max) = (2.0, 3.5);
        let depth = [1.5f32, 2.0, 2.37, 3.1, 3.5, 9.0];
        let q = two_hot_labels(&[&depth, &depth[..]], (2, 3), &bins, (r_min, r_max), false);
        assert_eq!(q.len(), 2 * 2 * 10 * 3);
        for i in 0..2 {
            for (p, &d) in depth.iter().enumerate() {
                let (row, col) = (p / 3, p % 3);
                let at = |bin: usize| ((i * 2 + row) * 10 + bin) * 3 + col;
                let sum: f32 = (0..10).map(|k| q[at(k)]).sum();
                let mean: f32 = (0..10).map(|k| q[at(k)] * bins[k]).sum();
                let nonzero = (0..10).filter(|&k| q[at(k)] != 0.0).count();
                assert!((sum - 1.0).abs() < 1e-6, "pixel {p}: sum {sum}");
                assert!(
                    (mean - d.clamp(r_min, r_max)).abs() < 1e-5,
                    "pixel {p}: {mean}"
                );
                assert!((1..=2).contains(&nonzero), "pixel {p}: {nonzero} bins");
            }
        }
    }

    #[test]
    fn end_labels_sit_on_the_end_bins_with_the_no_return_classes() {
        let bins: Vec<f32> = (0..10).map(|i| 1.9 + 0.2 * i as f32).collect();
        let depth = [1.5f32, 2.0, 2.37, 3.1, 3.5, 9.0];
        let q = two_hot_labels(&[&depth], (2, 3), &bins, (2.0, 3.5), true);
        let at = |p: usize, bin: usize| ((p / 3) * 10 + bin) * 3 + p % 3;
        for p in [0, 1] {
            assert_eq!(q[at(p, 0)], 1.0, "pixel {p} is nearer than the window");
        }
        for p in [4, 5] {
            assert_eq!(q[at(p, 9)], 1.0, "pixel {p} met nothing");
        }
        for p in [2, 3] {
            assert_eq!(q[at(p, 0)] + q[at(p, 9)], 0.0, "pixel {p} is inside");
            let mean: f32 = (0..10).map(|k| q[at(p, k)] * bins[k]).sum();
            assert!((mean - depth[p]).abs() < 1e-5);
        }
    }

    #[test]
    fn no_return_term_falls_as_the_end_mass_follows_the_label() {
        let device = Device::flex();
        // One pixel that met nothing, one inside the window: logits over 4 bins.
        let loss = |far_logit: f32| {
            // [B=1][1][E=1][R=4][A=2], bin-major: pixel 0's last bin rises with `far_logit`,
            // pixel 1's falls.
            let mut l = vec![0f32; 8];
            l[3 * 2] = far_logit;
            l[3 * 2 + 1] = -far_logit;
            let logits = Tensor::<5>::from_data(TensorData::new(l, [1, 1, 1, 4, 2]), &device);
            let t = |v: Vec<f32>| Tensor::<3>::from_data(TensorData::new(v, [1, 1, 2]), &device);
            let nr = no_return_bce(
                logits,
                t(vec![1.0, 0.0]),
                t(vec![0.0, 0.0]),
                t(vec![0.0, 1.0]),
                3.0,
            );
            scalar(nr).unwrap()
        };
        let (lo, mid, hi) = (loss(-4.0), loss(0.0), loss(4.0));
        assert!(lo > mid && mid > hi, "{lo} {mid} {hi}");
        assert!(hi.is_finite() && hi > 0.0);
    }
}
