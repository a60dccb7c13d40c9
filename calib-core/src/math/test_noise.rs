//! Seeded Gaussian noise for the unit tests' Monte-Carlo checks (xorshift64, Box–Muller): no
//! dependency, the same draws on every machine.

/// A stream of standard normal draws from a seed.
pub(crate) struct Gaussian(u64);

impl Gaussian {
    /// The stream of `seed` (non-zero).
    pub(crate) fn new(seed: u64) -> Self {
        Self(seed)
    }

    /// Uniform on [0, 1).
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The next draw (mean 0, variance 1).
    pub(crate) fn next(&mut self) -> f64 {
        let r = libm::sqrt(-2.0 * libm::log(1.0 - self.uniform()));
        r * libm::cos(core::f64::consts::TAU * self.uniform())
    }
}
