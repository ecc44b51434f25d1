//! Seeded random numbers: the SplitMix64 generator as a `rand` generator, and a normal
//! sampler over any `rand` generator.
//!
//! The built-in actor and the solve benchmark draw from [`SplitMix64`] by its own
//! [`SplitMix64::next_f64`], which this crate defines: rand's `StdRng` and its conversions
//! are not promised to give the same stream across rand versions, and every checked-in
//! recording and reported figure depends on the built-in actor's stream.

use rand::RngCore;

/// The SplitMix64 generator (Steele, Lea and Flood 2014): tiny, well mixed and
/// deterministic. Implements [`RngCore`], so rand's distributions draw from it too.
#[derive(Debug, Clone)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator started at `seed`.
    pub fn new(seed: u64) -> Self {
        Self { state: seed }
    }

    /// Uniform in [0, 1): the top 53 bits of [`RngCore::next_u64`] over 2⁵³.
    pub fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next_f64()
    }
}

impl RngCore for SplitMix64 {
    fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn fill_bytes(&mut self, dst: &mut [u8]) {
        for chunk in dst.chunks_mut(8) {
            let bytes = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&bytes[..chunk.len()]);
        }
    }
}

/// A standard normal sample (Box–Muller, the cosine branch) from two uniform draws of
/// `rng` in [0, 1) (the first kept above 1e-300 so that its logarithm is finite).
pub fn standard_normal(rng: &mut impl rand::Rng) -> f64 {
    let u1 = rng.random::<f64>().max(1e-300);
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn splitmix64_gives_the_reference_stream() {
        // The first outputs for seed 1234567 of the reference implementation
        // (Vigna, splitmix64.c).
        let mut r = SplitMix64::new(1234567);
        let expected = [
            6457827717110365317u64,
            3203168211198807973,
            9817491932198370423,
            4593380528125082431,
            16408922859458223821,
        ];
        for e in expected {
            assert_eq!(r.next_u64(), e);
        }
    }

    #[test]
    fn rand_draws_the_same_uniforms() {
        let (mut a, mut b) = (SplitMix64::new(9), SplitMix64::new(9));
        for _ in 0..100 {
            assert_eq!(a.next_f64(), b.random::<f64>());
        }
    }

    #[test]
    fn normal_samples_have_unit_variance() {
        let mut r = SplitMix64::new(5);
        let n = 20_000;
        let xs: Vec<f64> = (0..n).map(|_| standard_normal(&mut r)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors: 0.007 for the mean, 0.01 for the variance.
        assert!(mean.abs() < 0.03, "{mean}");
        assert!((var - 1.0).abs() < 0.05, "{var}");
    }
}
