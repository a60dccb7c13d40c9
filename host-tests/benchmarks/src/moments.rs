//! Sample statistics for the benchmark tables: mean, variance, range, skewness, kurtosis, RMS.

/// Summary of a sample of values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moments {
    /// Number of values.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Unbiased variance.
    pub variance: f64,
    /// Largest minus smallest.
    pub range: f64,
    /// Skewness (third standardised moment).
    pub skewness: f64,
    /// Excess kurtosis (fourth standardised moment − 3).
    pub kurtosis: f64,
    /// Root mean square (about zero).
    pub rms: f64,
}

impl Moments {
    /// Moments of `xs` (all zero for an empty slice).
    pub fn of(xs: &[f64]) -> Self {
        let n = xs.len();
        if n == 0 {
            return Self { n, mean: 0.0, variance: 0.0, range: 0.0, skewness: 0.0, kurtosis: 0.0, rms: 0.0 };
        }
        let nf = n as f64;
        let mean = xs.iter().sum::<f64>() / nf;
        let m = |p: i32| xs.iter().map(|x| (x - mean).powi(p)).sum::<f64>() / nf;
        let (m2, m3, m4) = (m(2), m(3), m(4));
        let lo = xs.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = xs.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let sd = m2.sqrt();
        Self {
            n,
            mean,
            variance: if n > 1 { m2 * nf / (nf - 1.0) } else { 0.0 },
            range: hi - lo,
            skewness: if sd > 0.0 { m3 / sd.powi(3) } else { 0.0 },
            kurtosis: if sd > 0.0 { m4 / (m2 * m2) - 3.0 } else { 0.0 },
            rms: (xs.iter().map(|x| x * x).sum::<f64>() / nf).sqrt(),
        }
    }

    /// As JSON.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "n": self.n, "mean": self.mean, "variance": self.variance, "range": self.range,
            "skewness": self.skewness, "kurtosis": self.kurtosis, "rms": self.rms,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moments_of_a_known_sample() {
        let m = Moments::of(&[1.0, 2.0, 3.0, 4.0]);
        assert_eq!((m.mean, m.range), (2.5, 3.0));
        assert!((m.variance - 5.0 / 3.0).abs() < 1e-12 && m.skewness.abs() < 1e-12);
        assert!((m.kurtosis - (-1.36)).abs() < 1e-12);
        assert!((m.rms - 7.5f64.sqrt()).abs() < 1e-12);
    }
}
