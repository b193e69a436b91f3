//! # eikon-rng
//!
//! SplitMix64 (Steele, Lea and Flood 2014, "Fast splittable pseudorandom
//! number generators", OOPSLA, doi:10.1145/2714064.2660195): the one
//! generator of eikon and its output function, [`mix`]. It draws the
//! bumpy sphere's bumps, the camera's pixel jitter (through [`mix`] as a
//! counter hash), the photons' paths and run ids, and the tests'
//! reproducible cases. No dependencies and no state beyond one `u64`: a
//! seed gives the same bits on every platform and in every build.

/// The stream's increment, `2^64 / phi` rounded to odd (the golden ratio).
pub const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// The SplitMix64 output function: a bijective 64-bit mixer with full
/// avalanche (every input bit flips each output bit with probability
/// about one half), also usable alone as a hash of a counter.
#[inline]
pub fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The top 53 bits of `bits` as a double, uniform in `[0, 1)`.
#[inline]
pub fn unit_f64(bits: u64) -> f64 {
    (bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A SplitMix64 stream: the state advances by [`GOLDEN`], and each output
/// is the state through [`mix`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// The stream that starts at state `seed` (its first output is
    /// `mix(seed + GOLDEN)`).
    pub const fn new(seed: u64) -> Self {
        SplitMix64(seed)
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(GOLDEN);
        mix(self.0)
    }

    /// Uniform in `[0, 1)`, 53 random bits.
    #[inline]
    pub fn unit(&mut self) -> f64 {
        unit_f64(self.next_u64())
    }

    /// Uniform in `[lo, hi)`.
    #[inline]
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// In `0..n` by the remainder (biased by under `n / 2^64`); 0, without
    /// drawing, when `n` is 0.
    #[inline]
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }

    /// True with probability `p`.
    #[inline]
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// A uniform random unit vector `[x, y, z]`: `z` uniform in `[-1, 1)`
    /// (Archimedes), then the azimuth uniform.
    pub fn direction(&mut self) -> [f64; 3] {
        let z = 2.0 * self.unit() - 1.0;
        let phi = std::f64::consts::TAU * self.unit();
        let s = (1.0 - z * z).sqrt();
        [s * phi.cos(), s * phi.sin(), z]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first outputs from seed 1234567, as Vigna's reference
    /// splitmix64.c gives them (checked with an independent Python
    /// transcription of it).
    #[test]
    fn matches_the_reference_stream() {
        let mut r = SplitMix64::new(1_234_567);
        let want = [
            6_457_827_717_110_365_317,
            3_203_168_211_198_807_973,
            9_817_491_932_198_370_423,
            4_593_380_528_125_082_431,
            16_408_922_859_458_223_821,
        ];
        for w in want {
            assert_eq!(r.next_u64(), w);
        }
    }

    #[test]
    fn mix_is_the_stream_s_output_and_a_bijection_on_samples() {
        let mut r = SplitMix64::new(42);
        assert_eq!(r.next_u64(), mix(42u64.wrapping_add(GOLDEN)));
        assert_eq!(mix(0), 0);
        let outs: std::collections::HashSet<u64> = (0..10_000u64).map(mix).collect();
        assert_eq!(outs.len(), 10_000);
    }

    #[test]
    fn draws_lie_in_their_ranges_and_spread() {
        let mut r = SplitMix64::new(7);
        let (mut sum, n) = (0.0, 100_000);
        for _ in 0..n {
            let u = r.unit();
            assert!((0.0..1.0).contains(&u));
            sum += u;
            let x = r.uniform(-2.0, 3.0);
            assert!((-2.0..3.0).contains(&x));
            assert!(r.below(7) < 7);
            let d = r.direction();
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-12);
        }
        // The mean of n uniforms: 0.5 within 5 standard errors.
        let se = (1.0 / 12.0 / n as f64).sqrt();
        assert!((sum / n as f64 - 0.5).abs() < 5.0 * se);
        // `below(0)` draws nothing.
        let mut a = SplitMix64::new(3);
        let b = a.clone();
        assert_eq!(a.below(0), 0);
        assert_eq!(a, b);
        assert_eq!(unit_f64(u64::MAX), 1.0 - 2f64.powi(-53));
    }
}
