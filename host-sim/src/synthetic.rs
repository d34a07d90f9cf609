//! Deterministic synthetic data: random float weights for an untrained model and sonar-like
//! polar images, for tests, calibration of untrained weights and benchmarks.

use std::collections::BTreeMap;

use crate::quantise::{BatchNorm, FloatLayer, FloatWeights};
use epssn::config::{LayerKind, LAYERS};

/// A small deterministic generator (SplitMix64) for test data.
pub struct Rng(pub u64);

impl Rng {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        // SplitMix64: the output is the finaliser of the advanced state.
        let z = crate::scene::mix64(self.0);
        self.0 = self.0.wrapping_add(crate::scene::SPLITMIX_GAMMA);
        z
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Approximately normal (sum of uniforms), mean 0, standard deviation `sd`.
    pub fn normal(&mut self, sd: f64) -> f64 {
        ((0..4).map(|_| self.uniform()).sum::<f64>() - 2.0) * sd * 3f64.sqrt()
    }
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

/// A synthetic sonar-like polar image: a bright arc at a range depending on the column, plus
/// speckle.
pub fn synthetic_image(rng: &mut Rng, shift: f64) -> Vec<u8> {
    let (r, b) = (
        epssn::config::INPUT_RANGE_BINS,
        epssn::config::INPUT_COLUMNS,
    );
    let mut img = vec![0u8; r * b];
    for k in 0..b {
        let centre = r as f64 * (0.3 + 0.3 * ((k as f64 / b as f64) * 3.0 + shift).sin().abs());
        for i in 0..r {
            let d = (i as f64 - centre) / 6.0;
            let v = 200.0 * (-d * d).exp() + 25.0 * rng.uniform();
            img[i * b + k] = v.clamp(0.0, 255.0) as u8;
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::Rng;

    #[test]
    fn rng_is_splitmix64() {
        // The published SplitMix64 outputs for seed 0.
        let mut r = Rng(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
        let mut m = crate::model::SplitMix64::new(0);
        assert_eq!(m.next_u64(), 0xE220_A839_7B1D_CDAF);
    }
}
