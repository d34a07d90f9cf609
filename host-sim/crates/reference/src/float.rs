//! Float weights of the model in canonical layout, batch-norm folding, and random
//! He-initialised weights for an untrained bring-up model.

use std::collections::BTreeMap;

use crate::rng::Rng;
use epssn::config::{LayerKind, LayerShape, LAYERS};

/// Batch-norm epsilon of every batch-norm layer.
pub const BN_EPSILON: f64 = 1e-5;

/// Batch-norm statistics and affine parameters of one layer.
#[derive(Clone, Debug)]
pub struct BatchNorm {
    /// γ.
    pub gamma: Vec<f32>,
    /// β.
    pub beta: Vec<f32>,
    /// Running mean μ.
    pub mean: Vec<f32>,
    /// Running variance σ².
    pub var: Vec<f32>,
    /// ε.
    pub eps: f64,
}

/// One float layer in canonical layout (conv `[O][I][k…]`, conv-transpose `[I][O][k…]`).
#[derive(Clone, Debug)]
pub struct FloatLayer {
    /// Weights.
    pub weight: Vec<f32>,
    /// Bias (zeros when the convolution has none).
    pub bias: Vec<f32>,
    /// Batch norm applied after the convolution, if any.
    pub bn: Option<BatchNorm>,
}

/// Float weights of the whole model, by layer name.
pub type FloatWeights = BTreeMap<String, FloatLayer>;

/// How the weights of one layer are laid out.
#[derive(Clone, Copy, Debug)]
pub struct WeightLayout {
    /// Input channels.
    pub in_channels: usize,
    /// Output channels.
    pub out_channels: usize,
    /// Taps of one kernel.
    pub kernel_volume: usize,
    /// `[I][O][k…]` (conv-transpose) rather than `[O][I][k…]`.
    pub transposed: bool,
}

impl WeightLayout {
    /// The layout of a compiled layer.
    pub fn of(l: &LayerShape) -> Self {
        Self {
            in_channels: l.in_channels,
            out_channels: l.out_channels,
            kernel_volume: l.kernel.iter().map(|&k| k as usize).product(),
            transposed: matches!(l.kind, LayerKind::ConvTranspose3d),
        }
    }

    /// Indices of every weight of output channel `o`.
    pub fn channel_indices(&self, o: usize) -> impl Iterator<Item = usize> + '_ {
        let k = self.kernel_volume;
        (0..self.in_channels).flat_map(move |i| {
            let start = if self.transposed {
                (i * self.out_channels + o) * k
            } else {
                (o * self.in_channels + i) * k
            };
            start..start + k
        })
    }

    /// Total weights.
    pub fn len(&self) -> usize {
        self.in_channels * self.out_channels * self.kernel_volume
    }

    /// True for a layer without weights.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Folds batch norm into the convolution: `w' = w·γ/√(σ²+ε)`, `b' = (b − μ)·γ/√(σ²+ε) + β`,
/// per output channel.
pub fn fold_batch_norm(layer: &FloatLayer, layout: &WeightLayout) -> (Vec<f64>, Vec<f64>) {
    let mut w: Vec<f64> = layer.weight.iter().map(|&x| x as f64).collect();
    let mut b: Vec<f64> = layer.bias.iter().map(|&x| x as f64).collect();
    if let Some(bn) = &layer.bn {
        for (o, bias) in b.iter_mut().enumerate().take(layout.out_channels) {
            let g = bn.gamma[o] as f64 / (bn.var[o] as f64 + bn.eps).sqrt();
            *bias = (*bias - bn.mean[o] as f64) * g + bn.beta[o] as f64;
            for i in layout.channel_indices(o) {
                w[i] *= g;
            }
        }
    }
    (w, b)
}

/// Random float weights of the compiled configuration, He-initialised, with random batch norms.
pub fn random_float_weights(seed: u64) -> FloatWeights {
    let mut rng = Rng(seed);
    let mut map = BTreeMap::new();
    for l in LAYERS.iter() {
        let fan_in = l.in_channels * l.kernel.iter().map(|&k| k as usize).product::<usize>();
        let fan_in = if l.kind == LayerKind::ConvTranspose3d {
            fan_in
                / l.stride
                    .iter()
                    .map(|&s| s as usize)
                    .product::<usize>()
                    .max(1)
        } else {
            fan_in
        };
        let sd = (2.0 / fan_in.max(1) as f64).sqrt();
        let weight = (0..l.weight_len()).map(|_| rng.normal(sd) as f32).collect();
        let bias = (0..l.out_channels)
            .map(|_| rng.normal(0.05) as f32)
            .collect();
        let oc = l.out_channels;
        let bn = l.relu.then(|| BatchNorm {
            gamma: (0..oc)
                .map(|_| (0.8 + 0.4 * rng.uniform()) as f32)
                .collect(),
            beta: (0..oc).map(|_| rng.normal(0.1) as f32).collect(),
            mean: (0..oc).map(|_| rng.normal(0.1) as f32).collect(),
            var: (0..oc).map(|_| (0.5 + rng.uniform()) as f32).collect(),
            eps: 1e-5,
        });
        map.insert(l.name.to_string(), FloatLayer { weight, bias, bn });
    }
    map
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batch_norm_folds_per_output_channel_in_both_layouts() {
        // 2 in, 2 out, 1 tap. Conv [O][I]: channel 0 = w[0], w[1]; transposed [I][O]: w[0], w[2].
        let layer = FloatLayer {
            weight: vec![1.0, 2.0, 3.0, 4.0],
            bias: vec![0.5, -0.5],
            bn: Some(BatchNorm {
                gamma: vec![2.0, 1.0],
                beta: vec![0.1, 0.2],
                mean: vec![0.5, 1.5],
                var: vec![3.0, 0.0],
                eps: 1.0,
            }),
        };
        let conv = WeightLayout {
            in_channels: 2,
            out_channels: 2,
            kernel_volume: 1,
            transposed: false,
        };
        let (w, b) = fold_batch_norm(&layer, &conv);
        // g = γ/√(σ²+ε) is 1 for both channels here, so only the biases move.
        assert_eq!(w, vec![1.0, 2.0, 3.0, 4.0]);
        assert!((b[0] - 0.1f32 as f64).abs() < 1e-12);
        assert!((b[1] - (-2.0 + 0.2f32 as f64)).abs() < 1e-12);
        let mut l2 = layer.clone();
        l2.bn.as_mut().unwrap().gamma = vec![4.0, 3.0];
        let (w, _) = fold_batch_norm(&l2, &conv);
        assert_eq!(w, vec![2.0, 4.0, 9.0, 12.0]);
        let tr = WeightLayout {
            transposed: true,
            ..conv
        };
        let (w, _) = fold_batch_norm(&l2, &tr);
        assert_eq!(w, vec![2.0, 6.0, 6.0, 12.0]);
    }
}
