//! Streaming statistics: the mean and covariance of 3-vectors from exact integer sums, and the
//! spread of a scalar.

use crate::math::real::{self, Real};
use crate::Vec3;

/// Fraction bits of the fixed point the sums keep: a reading is rounded to 2⁻¹⁸ of its unit
/// (3.8e-6 g, °/s or µT, far below any part's LSB) once, as it enters.
const FRACTION_BITS: i32 = 18;
/// `2^FRACTION_BITS`.
const SCALE: f32 = (1u32 << FRACTION_BITS) as f32;

/// `x` in the sums' fixed point, `round(x · 2¹⁸)`: to nearest, ties to even (an f32 reading lies
/// on a grid finer than the quantum, so ties occur and must not bias the mean), by the FPU's
/// own rounding of `y ± 2²³` (whose unit in the last place is 1) below 2²³; beyond it `y` is
/// already whole. The cast saturates (NaN to 0: [`Moments3`] flags it apart).
fn fixed(x: f32) -> i32 {
    const TWO_23: f32 = 8_388_608.0;
    let y = x * SCALE;
    let r = if (0.0..TWO_23).contains(&y) {
        (y + TWO_23) - TWO_23
    } else if y < 0.0 && y > -TWO_23 {
        (y - TWO_23) + TWO_23
    } else {
        y
    };
    r as i32
}

/// Running mean and covariance of 3-vectors (readings: g, °/s, µT, °C) from exact sums. Each
/// component is rounded once to the fixed point `q = round(x · 2¹⁸)` (an `i32`: |x| up to 8192,
/// beyond any part's full scale; larger values are clamped there), then only integers are
/// added: `Σq` (`i64`), `Σq²` and `Σqᵢqⱼ` (`i128`). Sums of any length and any order are
/// exact, so a merge equals the sequential sum bit for bit, and the per-sample cost is a few
/// integer multiply-accumulates on the MCU (issue 50: no software doubles per sample). The
/// mean and the (co)variances are formed from the exact sums when asked, `n Σq² − (Σq)²` in
/// integers first: no cancellation. A non-finite reading poisons the statistics (NaN).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Moments3 {
    n: u32,
    /// A non-finite component was added.
    poisoned: bool,
    s1: [i64; 3],
    s2: [i128; 3],
    /// `Σ qᵢ qⱼ` of the axis pairs (0, 1), (0, 2), (1, 2) (`sc[i + j − 1]`).
    sc: [i128; 3],
}

impl Moments3 {
    /// Empty.
    pub const fn new() -> Self {
        Self { n: 0, poisoned: false, s1: [0; 3], s2: [0; 3], sc: [0; 3] }
    }

    /// Adds one vector (any unit; the statistics keep it).
    pub fn add(&mut self, v: Vec3) {
        self.n += 1;
        self.poisoned |= !(v[0].is_finite() && v[1].is_finite() && v[2].is_finite());
        let [x, y, z] = v.map(fixed);
        // 32 × 32 → 64-bit products (one SMULL each), summed in 128 bits.
        let p = |a: i32, b: i32| (a as i64 * b as i64) as i128;
        self.s1[0] += x as i64;
        self.s1[1] += y as i64;
        self.s1[2] += z as i64;
        self.s2[0] += p(x, x);
        self.s2[1] += p(y, y);
        self.s2[2] += p(z, z);
        self.sc[0] += p(x, y);
        self.sc[1] += p(x, z);
        self.sc[2] += p(y, z);
    }

    /// Adds all vectors summarised by `other` (exact: the same as adding them one by one).
    pub fn merge(&mut self, other: &Moments3) {
        self.n += other.n;
        self.poisoned |= other.poisoned;
        for k in 0..3 {
            self.s1[k] += other.s1[k];
            self.s2[k] += other.s2[k];
            self.sc[k] += other.sc[k];
        }
    }

    /// Number of vectors added.
    pub fn count(&self) -> u32 {
        self.n
    }

    /// Mean (f64; NaN if a non-finite vector was added, 0 when empty).
    pub fn mean(&self) -> [Real; 3] {
        if self.poisoned {
            return [Real::NAN; 3];
        }
        let n = self.n.max(1) as Real * SCALE as Real;
        self.s1.map(|s| s as Real / n)
    }

    /// `Σ (xᵢ − x̄ᵢ)(xⱼ − x̄ⱼ)` from the exact sums, in the readings' unit².
    fn comoment(&self, i: usize, j: usize) -> Real {
        if self.poisoned {
            return Real::NAN;
        }
        let sij = if i == j { self.s2[i] } else { self.sc[i + j - 1] };
        // n Σqᵢqⱼ − Σqᵢ Σqⱼ: at most 2³² · 2⁹⁴ and 2⁶³ · 2⁶³, within i128; to f64 by halves.
        let num = self.n as i128 * sij - self.s1[i] as i128 * self.s1[j] as i128;
        let num = (num >> 64) as i64 as Real * 18_446_744_073_709_551_616.0 + num as u64 as Real;
        num / (self.n.max(1) as Real * SCALE as Real * SCALE as Real)
    }

    /// Unbiased per-axis variance (0 with fewer than two samples).
    pub fn variance(&self) -> [Real; 3] {
        if self.n < 2 {
            return [0.0; 3];
        }
        let d = (self.n - 1) as Real;
        core::array::from_fn(|k| self.comoment(k, k) / d)
    }

    /// Largest per-axis standard deviation.
    pub fn max_std(&self) -> Real {
        let v = self.variance();
        real::sqrt(v[0].max(v[1]).max(v[2]))
    }

    /// Largest per-axis standard deviation of the mean, `max_std / √n`.
    pub fn max_std_of_mean(&self) -> Real {
        self.max_std() / real::sqrt(self.n.max(1) as Real)
    }

    /// Standard deviation of the mean along the mean's own direction, `√(uᵀ Σ u / n)` with
    /// `u = mean / |mean|`: an accelerometer pose's noise in `|a|`, without the sway that only
    /// turns gravity about. 0 for a zero mean or fewer than two vectors.
    pub fn radial_std_of_mean(&self) -> Real {
        let mean = self.mean();
        let norm = real::sqrt(mean.iter().map(|m| m * m).sum::<Real>());
        if self.n < 2 || !(norm > 0.0) {
            return 0.0;
        }
        let u = mean.map(|m| m / norm);
        let var: Real = (0..9).map(|k| u[k / 3] * u[k % 3] * self.comoment(k / 3, k % 3)).sum();
        real::sqrt((var / (self.n - 1) as Real).max(0.0) / self.n as Real)
    }
}

/// Running mean of a scalar (a temperature, °C) from the exact sum of [`Moments3`]'s fixed point:
/// `Σq` in an `i64`, so that a merge equals the sequential sum bit for bit. A non-finite value
/// poisons the mean (NaN).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Mean {
    n: u32,
    poisoned: bool,
    s1: i64,
}

impl Mean {
    /// Empty.
    pub const fn new() -> Self {
        Self { n: 0, poisoned: false, s1: 0 }
    }

    /// Adds one value.
    pub fn add(&mut self, x: f32) {
        self.n += 1;
        self.poisoned |= !x.is_finite();
        self.s1 += fixed(x) as i64;
    }

    /// Adds all values summarised by `other`.
    pub fn merge(&mut self, other: &Mean) {
        self.n += other.n;
        self.poisoned |= other.poisoned;
        self.s1 += other.s1;
    }

    /// Number of values added.
    pub fn count(&self) -> u32 {
        self.n
    }

    /// The mean (NaN if a non-finite value was added, 0 when empty), rounded once to f32.
    pub fn mean(&self) -> f32 {
        if self.poisoned {
            return f32::NAN;
        }
        (self.s1 as Real / (self.n.max(1) as Real * SCALE as Real)) as f32
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
    /// Spread of `values`, in [`Real`] (a `dyn` iterator: one copy of the code for every caller).
    pub fn of(values: &mut dyn Iterator<Item = Real>) -> Self {
        let (mut n, mut mean, mut m2) = (0u32, 0.0 as Real, 0.0 as Real);
        let (mut lo, mut hi) = (Real::INFINITY, Real::NEG_INFINITY);
        for x in values {
            n += 1;
            let d = x - mean;
            mean += d / n as Real;
            m2 += d * (x - mean);
            lo = lo.min(x);
            hi = hi.max(x);
        }
        if n == 0 {
            return Self::default();
        }
        let std = if n > 1 { real::sqrt(m2 / (n - 1) as Real) } else { 0.0 };
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
    fn mean_is_moments3_first_mean() {
        let xs = [21.5f32, 21.75, 22.0625, -3.0, 1e-3];
        let (mut m, mut v) = (Mean::new(), Moments3::new());
        xs.iter().for_each(|&x| {
            m.add(x);
            v.add([x, 0.0, 0.0]);
        });
        assert_eq!(m.count(), 5);
        assert_eq!(m.mean(), v.mean()[0] as f32);
        let (mut a, mut b) = (Mean::new(), Mean::new());
        xs[..2].iter().for_each(|&x| a.add(x));
        xs[2..].iter().for_each(|&x| b.add(x));
        a.merge(&b);
        assert_eq!(a, m);
        m.add(f32::NAN);
        assert!(m.mean().is_nan());
        assert_eq!(Mean::new().mean(), 0.0);
    }

    #[test]
    fn moments_match_two_pass() {
        let xs: [[f32; 3]; 5] = [[1.0, 2.0, 3.0], [2.0, 2.5, -1.0], [0.5, 2.0, 0.0], [3.0, 1.0, 2.0], [1.5, 2.0, 1.0]];
        let mut w = Moments3::new();
        xs.iter().for_each(|&x| w.add(x));
        for k in 0..3 {
            let m: Real = xs.iter().map(|x| x[k] as Real).sum::<Real>() / 5.0;
            let v: Real = xs.iter().map(|x| (x[k] as Real - m).powi(2)).sum::<Real>() / 4.0;
            assert!((w.mean()[k] - m).abs() < 1e-12 && (w.variance()[k] - v).abs() < 1e-12);
        }
    }

    #[test]
    fn readings_round_to_the_nearest_quantum_ties_to_even() {
        let q = 1.0 / SCALE;
        assert_eq!([fixed(1.5 * q), fixed(2.5 * q), fixed(-2.5 * q), fixed(2.4 * q), fixed(-2.6 * q)], [2, 2, -2, 2, -3]);
        // Between 2^22 and 2^23 quanta a float still has halves: 25 + 2^-19 is 25·2^18 + 0.5.
        assert_eq!(fixed(25.0 + q / 2.0), 25 * (1 << 18));
        assert_eq!(fixed(25.0 + 1.5 * q), 25 * (1 << 18) + 2);
        assert_eq!((fixed(1e10), fixed(-1e10), fixed(f32::NAN)), (i32::MAX, i32::MIN, 0));
        let mut m = Moments3::new();
        m.add([1.0, f32::NAN, 0.0]);
        assert!(m.mean()[0].is_nan() && m.variance().iter().all(|v| *v == 0.0));
        m.add([1.0, 0.0, 0.0]);
        assert!(m.variance()[0].is_nan());
    }

    #[test]
    fn merge_equals_sequential() {
        let xs: [[f32; 3]; 6] = [[1.0, 2.0, 3.0], [2.0, 2.5, -1.0], [0.5, 2.0, 0.0], [3.0, 1.0, 2.0], [1.5, 2.0, 1.0], [0.0; 3]];
        let (mut all, mut a, mut b) = (Moments3::new(), Moments3::new(), Moments3::new());
        xs.iter().for_each(|&x| all.add(x));
        xs[..2].iter().for_each(|&x| a.add(x));
        xs[2..].iter().for_each(|&x| b.add(x));
        a.merge(&b);
        a.merge(&Moments3::new());
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
        let (mut w, mut v) = (Moments3::new(), [0.0 as Real; 40]);
        let c = 1.0 / libm::sqrt(3.0);
        let mut xs = [[0.0f32; 3]; 40];
        for (k, x) in xs.iter_mut().enumerate() {
            let (a, len) = (0.05 * libm::sin(k as Real * 0.9), 1.0 + 1e-3 * libm::cos(k as Real * 2.3));
            let dir = [c * libm::cos(a) + c * libm::sin(a), c * libm::cos(a) - c * libm::sin(a), c];
            let n = libm::sqrt(dir.iter().map(|d| d * d).sum::<Real>());
            *x = dir.map(|d| (d / n * len) as f32);
            w.add(*x);
        }
        let m = w.mean();
        let mn = libm::sqrt(m.iter().map(|x| x * x).sum::<Real>());
        for (vi, x) in v.iter_mut().zip(xs.iter()) {
            *vi = (0..3).map(|k| x[k] as Real * m[k] / mn).sum();
        }
        let s = Spread::of(&mut v.iter().copied());
        let expect = s.std as Real / libm::sqrt(40.0);
        assert!((w.radial_std_of_mean() - expect).abs() < 1e-3 * expect, "{} vs {expect}", w.radial_std_of_mean());
        assert!(w.max_std_of_mean() > 10.0 * w.radial_std_of_mean());
    }

    #[test]
    fn spread_of_values() {
        let s = Spread::of(&mut [1.0, 3.0, 2.0].into_iter());
        assert_eq!((s.n, s.mean, s.std, s.range), (3, 2.0, 1.0, 2.0));
        assert_eq!(Spread::of(&mut core::iter::empty()), Spread::default());
    }
}
