//! Deterministic synthetic data: the one random generator of tests and bring-up data
//! (SplitMix64) and sonar-like polar images, for tests, calibration of untrained weights and
//! benchmarks.

/// The small deterministic generator (SplitMix64) of the host's test data, bring-up weights,
/// training initialisation and shuffling.
#[derive(Clone, Debug)]
pub struct Rng(pub u64);

impl Rng {
    /// Seeds the generator.
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

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

    /// Uniform in [0, 1) as f32 (24 bits).
    pub fn unit(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `0..n` (`n` > 0; modulo bias is irrelevant for test data).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }

    /// Uniform in `lo..=hi`.
    pub fn range(&mut self, lo: i64, hi: i64) -> i64 {
        lo + (self.next_u64() % (hi - lo + 1) as u64) as i64
    }

    /// Fisher–Yates shuffle.
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = (self.next_u64() % (i as u64 + 1)) as usize;
            v.swap(i, j);
        }
    }

    /// Approximately normal (sum of uniforms), mean 0, standard deviation `sd`.
    pub fn normal(&mut self, sd: f64) -> f64 {
        ((0..4).map(|_| self.uniform()).sum::<f64>() - 2.0) * sd * 3f64.sqrt()
    }
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
    }
}
