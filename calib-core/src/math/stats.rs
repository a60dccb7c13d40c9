//! Streaming statistics: Welford mean and variance of 3-vectors, in `f64`.

use crate::Vec3;

/// Running mean and covariance of 3-vectors (Welford). O(1) state, numerically stable.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Welford3 {
    n: u32,
    mean: [f64; 3],
    m2: [f64; 3],
    /// Co-moments of the axis pairs `CROSS`.
    m2c: [f64; 3],
}

/// The axis pairs of the co-moments.
const CROSS: [(usize, usize); 3] = [(0, 1), (0, 2), (1, 2)];

impl Welford3 {
    /// Empty.
    pub const fn new() -> Self {
        Self { n: 0, mean: [0.0; 3], m2: [0.0; 3], m2c: [0.0; 3] }
    }

    /// Adds one vector (any unit; the statistics keep it).
    pub fn add(&mut self, v: Vec3) {
        self.n += 1;
        let n = self.n as f64;
        let mut d = [0.0; 3];
        for (((m, m2), &x), d) in self.mean.iter_mut().zip(self.m2.iter_mut()).zip(v.iter()).zip(d.iter_mut()) {
            let x = x as f64;
            *d = x - *m;
            *m += *d / n;
            *m2 += *d * (x - *m);
        }
        for (c, (i, j)) in self.m2c.iter_mut().zip(CROSS) {
            *c += d[i] * (v[j] as f64 - self.mean[j]);
        }
    }

    /// Adds all vectors summarised by `other` (Chan et al. parallel update).
    pub fn merge(&mut self, other: &Welford3) {
        if other.n == 0 {
            return;
        }
        let (na, nb) = (self.n as f64, other.n as f64);
        let n = na + nb;
        let d: [f64; 3] = core::array::from_fn(|k| other.mean[k] - self.mean[k]);
        for k in 0..3 {
            self.mean[k] += d[k] * nb / n;
            self.m2[k] += other.m2[k] + d[k] * d[k] * na * nb / n;
        }
        for ((c, oc), (i, j)) in self.m2c.iter_mut().zip(other.m2c).zip(CROSS) {
            *c += oc + d[i] * d[j] * na * nb / n;
        }
        self.n += other.n;
    }

    /// Number of vectors added.
    pub fn count(&self) -> u32 {
        self.n
    }

    /// Mean (f64).
    pub fn mean(&self) -> [f64; 3] {
        self.mean
    }

    /// Unbiased per-axis variance (0 with fewer than two samples).
    pub fn variance(&self) -> [f64; 3] {
        if self.n < 2 {
            return [0.0; 3];
        }
        let d = (self.n - 1) as f64;
        [self.m2[0] / d, self.m2[1] / d, self.m2[2] / d]
    }

    /// Largest per-axis standard deviation.
    pub fn max_std(&self) -> f64 {
        let v = self.variance();
        libm::sqrt(v[0].max(v[1]).max(v[2]))
    }

    /// Largest per-axis standard deviation of the mean, `max_std / √n`.
    pub fn max_std_of_mean(&self) -> f64 {
        self.max_std() / libm::sqrt(self.n.max(1) as f64)
    }

    /// Standard deviation of the mean along the mean's own direction, `√(uᵀ Σ u / n)` with
    /// `u = mean / |mean|`: an accelerometer pose's noise in `|a|`, without the sway that only
    /// turns gravity about. 0 for a zero mean or fewer than two vectors.
    pub fn radial_std_of_mean(&self) -> f64 {
        let norm = libm::sqrt(self.mean.iter().map(|m| m * m).sum::<f64>());
        if self.n < 2 || !(norm > 0.0) {
            return 0.0;
        }
        let u = self.mean.map(|m| m / norm);
        let diag: f64 = (0..3).map(|k| u[k] * u[k] * self.m2[k]).sum();
        let cross: f64 = self.m2c.iter().zip(CROSS).map(|(c, (i, j))| 2.0 * u[i] * u[j] * c).sum();
        libm::sqrt(((diag + cross) / (self.n - 1) as f64).max(0.0) / self.n as f64)
    }
}

/// Running mean, standard deviation and range of a scalar: the spread of the dot-product
/// invariant in the quality report.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Spread {
    /// Number of values.
    pub n: u32,
    /// Mean.
    pub mean: f32,
    /// Standard deviation (unbiased).
    pub std: f32,
    /// Largest minus smallest value.
    pub range: f32,
}

impl Spread {
    /// Spread of `values` (computed in f64).
    pub fn of(values: impl Iterator<Item = f64>) -> Self {
        let (mut n, mut mean, mut m2) = (0u32, 0.0f64, 0.0f64);
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for x in values {
            n += 1;
            let d = x - mean;
            mean += d / n as f64;
            m2 += d * (x - mean);
            lo = lo.min(x);
            hi = hi.max(x);
        }
        if n == 0 {
            return Self::default();
        }
        let std = if n > 1 { libm::sqrt(m2 / (n - 1) as f64) } else { 0.0 };
        Self { n, mean: mean as f32, std: std as f32, range: (hi - lo) as f32 }
    }

    /// Standard deviation relative to the mean's magnitude (0 when the mean is 0).
    pub fn relative_std(&self) -> f32 {
        if self.mean == 0.0 {
            0.0
        } else {
            self.std / libm::fabsf(self.mean)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn welford_matches_two_pass() {
        let xs: [[f32; 3]; 5] = [[1.0, 2.0, 3.0], [2.0, 2.5, -1.0], [0.5, 2.0, 0.0], [3.0, 1.0, 2.0], [1.5, 2.0, 1.0]];
        let mut w = Welford3::new();
        xs.iter().for_each(|&x| w.add(x));
        for k in 0..3 {
            let m: f64 = xs.iter().map(|x| x[k] as f64).sum::<f64>() / 5.0;
            let v: f64 = xs.iter().map(|x| (x[k] as f64 - m).powi(2)).sum::<f64>() / 4.0;
            assert!((w.mean()[k] - m).abs() < 1e-12 && (w.variance()[k] - v).abs() < 1e-12);
        }
    }

    #[test]
    fn merge_equals_sequential() {
        let xs: [[f32; 3]; 6] = [[1.0, 2.0, 3.0], [2.0, 2.5, -1.0], [0.5, 2.0, 0.0], [3.0, 1.0, 2.0], [1.5, 2.0, 1.0], [0.0; 3]];
        let (mut all, mut a, mut b) = (Welford3::new(), Welford3::new(), Welford3::new());
        xs.iter().for_each(|&x| all.add(x));
        xs[..2].iter().for_each(|&x| a.add(x));
        xs[2..].iter().for_each(|&x| b.add(x));
        a.merge(&b);
        a.merge(&Welford3::new());
        for k in 0..3 {
            assert!((a.mean()[k] - all.mean()[k]).abs() < 1e-12 && (a.variance()[k] - all.variance()[k]).abs() < 1e-12);
        }
        assert_eq!(a.count(), 6);
        assert!((a.radial_std_of_mean() - all.radial_std_of_mean()).abs() < 1e-12);
    }

    #[test]
    fn radial_std_is_the_spread_along_the_mean() {
        // Unit vectors swayed by ±3° about a diagonal, with a little noise in length: the
        // per-axis spread sees the sway, the radial one only the length.
        let (mut w, mut v) = (Welford3::new(), [0.0f64; 40]);
        let c = 1.0 / libm::sqrt(3.0);
        let mut xs = [[0.0f32; 3]; 40];
        for (k, x) in xs.iter_mut().enumerate() {
            let (a, len) = (0.05 * libm::sin(k as f64 * 0.9), 1.0 + 1e-3 * libm::cos(k as f64 * 2.3));
            let dir = [c * libm::cos(a) + c * libm::sin(a), c * libm::cos(a) - c * libm::sin(a), c];
            let n = libm::sqrt(dir.iter().map(|d| d * d).sum::<f64>());
            *x = dir.map(|d| (d / n * len) as f32);
            w.add(*x);
        }
        let m = w.mean();
        let mn = libm::sqrt(m.iter().map(|x| x * x).sum::<f64>());
        for (vi, x) in v.iter_mut().zip(xs.iter()) {
            *vi = (0..3).map(|k| x[k] as f64 * m[k] / mn).sum();
        }
        let s = Spread::of(v.iter().copied());
        let expect = s.std as f64 / libm::sqrt(40.0);
        assert!((w.radial_std_of_mean() - expect).abs() < 1e-3 * expect, "{} vs {expect}", w.radial_std_of_mean());
        assert!(w.max_std_of_mean() > 10.0 * w.radial_std_of_mean());
    }

    #[test]
    fn spread_of_values() {
        let s = Spread::of([1.0, 3.0, 2.0].into_iter());
        assert_eq!((s.n, s.mean, s.std, s.range), (3, 2.0, 1.0, 2.0));
        assert_eq!(Spread::of(core::iter::empty()), Spread::default());
    }
}
