//! A counter-based random stream: every beam draws from its own stream keyed by
//! `(seed, beam index)`, so the noise of a beam does not depend on which thread cast it,
//! on the thread count, or on how many other beams were cast.

/// SplitMix64's output function (Steele, Lea & Flood 2014): a bijective 64-bit mixer.
#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

const GOLDEN: u64 = 0x9e37_79b9_7f4a_7c15;

/// The random stream of one beam.
pub struct BeamRng {
    state: u64,
}

impl BeamRng {
    pub fn new(seed: u64, beam: u64) -> Self {
        BeamRng {
            state: mix(seed ^ mix(beam.wrapping_add(GOLDEN))),
        }
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN);
        mix(self.state)
    }

    /// Uniform in the open interval `(0, 1)` (53 random bits, never 0 or 1).
    #[inline]
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal by Box–Muller (one of the pair is discarded: simpler, still cheap).
    #[inline]
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_has_unit_moments_and_streams_differ() {
        let n = 200_000;
        let mut sum = 0.0;
        let mut sum2 = 0.0;
        for i in 0..n {
            let x = BeamRng::new(42, i).normal();
            sum += x;
            sum2 += x * x;
        }
        let mean = sum / n as f64;
        let var = sum2 / n as f64 - mean * mean;
        // Standard errors: 1/sqrt(n) = 0.0022 for the mean, sqrt(2/n) = 0.0032 for the variance.
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.015, "variance {var}");
        assert_ne!(BeamRng::new(1, 0).next_u64(), BeamRng::new(2, 0).next_u64());
        assert_ne!(BeamRng::new(1, 0).next_u64(), BeamRng::new(1, 1).next_u64());
    }

    #[test]
    fn uniform_is_open_interval() {
        for i in 0..10_000 {
            let u = BeamRng::new(7, i).uniform();
            assert!(u > 0.0 && u < 1.0);
        }
    }
}
