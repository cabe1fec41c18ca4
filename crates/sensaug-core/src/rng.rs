//! Seeded, allocation-free Gaussian noise for motor and sensor noise.
//!
//! xoshiro256++ (from `rand_xoshiro`) seeded through SplitMix64, and the
//! ziggurat standard normal of `rand_distr`: both `no_std`, both well tested
//! upstream, so trials are reproducible from one `u64` seed.

use rand_distr::{Distribution, StandardNormal};
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

/// A reproducible source of standard-normal samples.
#[derive(Clone, Debug)]
pub struct Noise {
    rng: Xoshiro256PlusPlus,
}

impl Noise {
    /// A generator whose whole sequence is fixed by `seed`.
    pub fn new(seed: u64) -> Self {
        Noise {
            rng: Xoshiro256PlusPlus::seed_from_u64(seed),
        }
    }

    /// One draw of `N(0, 1)`.
    pub fn standard(&mut self) -> f64 {
        StandardNormal.sample(&mut self.rng)
    }

    /// One draw of `N(0, std^2)`; exactly 0 when `std == 0`, without consuming
    /// a sample, so a noise-free channel does not shift the others' sequences.
    pub fn normal(&mut self, std: f64) -> f64 {
        if std == 0.0 {
            0.0
        } else {
            std * self.standard()
        }
    }
}
