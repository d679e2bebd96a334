//! A small seeded pseudo-random generator for simulation and noise: `SplitMix64` for uniform bits, Box–Muller
//! for normal deviates. The same seed always gives the same sequence, on every platform.

/// A deterministic pseudo-random generator (`SplitMix64`) with a Gaussian sampler.
///
/// Not for cryptography: it only has to be fast, well spread and repeatable.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseRng {
    state: u64,
    spare: Option<f64>,
}

impl NoiseRng {
    /// A generator for `seed`. `salt` separates the streams of different sensors sharing one seed.
    pub fn new(seed: i64, salt: u64) -> Self {
        // Reinterpreting the seed's bits is the intent: every i64 is a distinct seed.
        let mut rng = NoiseRng {
            state: (seed as u64) ^ salt.rotate_left(17),
            spare: None,
        };
        // Stir once so that nearby seeds do not start on nearby states.
        let _ = rng.next_u64();
        rng
    }

    /// The next 64 uniformly distributed bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A uniform deviate in the half-open interval (0, 1]: never zero, so its logarithm is finite.
    pub fn uniform(&mut self) -> f64 {
        // 53 random bits, shifted by one so that zero cannot come out.
        ((self.next_u64() >> 11) + 1) as f64 * (1.0 / (1_u64 << 53) as f64)
    }

    /// A standard normal deviate (mean 0, standard deviation 1), by the Box–Muller transform.
    pub fn gaussian(&mut self) -> f64 {
        if let Some(spare) = self.spare.take() {
            return spare;
        }
        let radius = (-2.0 * self.uniform().ln()).sqrt();
        let angle = std::f64::consts::TAU * self.uniform();
        self.spare = Some(radius * angle.sin());
        radius * angle.cos()
    }

    /// A normal deviate with standard deviation `sigma` (zero when `sigma` is not positive).
    pub fn normal(&mut self, sigma: f64) -> f64 {
        if sigma > 0.0 { sigma * self.gaussian() } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::NoiseRng;

    #[test]
    fn same_seed_same_sequence_and_seeds_differ() {
        let mut a = NoiseRng::new(7, 1);
        let mut b = NoiseRng::new(7, 1);
        let mut c = NoiseRng::new(8, 1);
        let mut d = NoiseRng::new(7, 2);
        let first: Vec<u64> = (0..16).map(|_| a.next_u64()).collect();
        let second: Vec<u64> = (0..16).map(|_| b.next_u64()).collect();
        let other_seed: Vec<u64> = (0..16).map(|_| c.next_u64()).collect();
        let other_salt: Vec<u64> = (0..16).map(|_| d.next_u64()).collect();
        assert_eq!(first, second);
        assert_ne!(first, other_seed);
        assert_ne!(first, other_salt);
    }

    #[test]
    fn gaussian_has_unit_variance() {
        let mut rng = NoiseRng::new(42, 0);
        let n = 200_000;
        let values: Vec<f64> = (0..n).map(|_| rng.gaussian()).collect();
        let mean = values.iter().sum::<f64>() / f64::from(n);
        let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / f64::from(n);
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((variance - 1.0).abs() < 0.02, "variance {variance}");
        let uniform: Vec<f64> = (0..1000).map(|_| rng.uniform()).collect();
        assert!(uniform.iter().all(|u| *u > 0.0 && *u <= 1.0));
        assert!(rng.normal(0.0).abs() < f64::MIN_POSITIVE);
    }
}
