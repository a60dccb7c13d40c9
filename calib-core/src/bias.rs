//! Gyro bias from a rest period.

use crate::stats::Welford3;
use crate::{Error, Vec3};

/// Limits applied to a bias estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BiasLimits {
    /// Fewest samples of rest.
    pub min_samples: u32,
    /// Largest |bias| per axis (°/s). LSM9DS1 zero-rate level: ±30 °/s typical at 2000 °/s FS.
    pub max_bias_dps: f32,
    /// Largest per-axis gyro standard deviation during the rest (°/s).
    pub max_std_dps: f32,
    /// Largest per-axis accelerometer standard deviation during the rest (g).
    pub max_accel_std_g: f32,
}

impl BiasLimits {
    /// The defaults (also as `Default`).
    pub const DEFAULT: BiasLimits = BiasLimits { min_samples: 100, max_bias_dps: 30.0, max_std_dps: 0.8, max_accel_std_g: 0.006 };
}

impl Default for BiasLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A gyro bias estimate (raw units: °/s in the sensor frame).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Bias {
    /// Mean gyro reading at rest (°/s).
    pub bias_dps: Vec3,
    /// 1σ of the mean (°/s).
    pub sigma_dps: Vec3,
    /// Per-axis noise standard deviation (°/s).
    pub noise_dps: Vec3,
    /// Samples averaged.
    pub samples: u32,
}

/// Accumulates a rest period, then checks it and returns the bias.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BiasEstimator {
    gyro: Welford3,
    accel: Welford3,
}

impl BiasEstimator {
    /// Empty.
    pub const fn new() -> Self {
        Self { gyro: Welford3::new(), accel: Welford3::new() }
    }

    /// Adds one rest sample: raw gyro (°/s), raw accel (g).
    pub fn add(&mut self, gyro_dps: Vec3, accel_g: Vec3) {
        self.gyro.add(gyro_dps);
        self.accel.add(accel_g);
    }

    /// Adds a whole window of rest samples (gyro °/s, accel g), summarised.
    pub fn add_window(&mut self, gyro: &Welford3, accel: &Welford3) {
        self.gyro.merge(gyro);
        self.accel.merge(accel);
    }

    /// Mean accelerometer reading over the rest (g): a free static pose.
    pub fn accel_mean(&self) -> Vec3 {
        let m = self.accel.mean();
        [m[0] as f32, m[1] as f32, m[2] as f32]
    }

    /// The bias, or why the rest period does not give one.
    pub fn finish(&self, limits: &BiasLimits) -> Result<Bias, Error> {
        let n = self.gyro.count();
        if n < limits.min_samples.max(2) {
            return Err(Error::TooFewSamples { have: n, need: limits.min_samples.max(2) });
        }
        let (g_std, a_std) = (self.gyro.max_std(), self.accel.max_std());
        if !(g_std <= limits.max_std_dps as f64 && a_std <= limits.max_accel_std_g as f64) {
            return Err(Error::NotStill { gyro_std_dps: g_std as f32, accel_std_g: a_std as f32 });
        }
        let (m, v) = (self.gyro.mean(), self.gyro.variance());
        let mut out = Bias { bias_dps: [0.0; 3], sigma_dps: [0.0; 3], noise_dps: [0.0; 3], samples: n };
        for k in 0..3 {
            if !m[k].is_finite() {
                return Err(Error::NonFinite);
            }
            if m[k].abs() > limits.max_bias_dps as f64 {
                return Err(Error::BiasOutOfRange { axis: k as u8, bias_dps: m[k] as f32, limit_dps: limits.max_bias_dps });
            }
            out.bias_dps[k] = m[k] as f32;
            out.noise_dps[k] = libm::sqrt(v[k]) as f32;
            out.sigma_dps[k] = libm::sqrt(v[k] / n as f64) as f32;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bias_is_the_rest_mean_and_checks_apply() {
        let mut b = BiasEstimator::new();
        for k in 0..200 {
            let e = if k % 2 == 0 { 0.1 } else { -0.1 };
            b.add([1.0 + e, -2.0, 0.5 - e], [0.0, 0.0, 1.0]);
        }
        let r = b.finish(&BiasLimits::default()).unwrap();
        assert!((r.bias_dps[0] - 1.0).abs() < 1e-6 && (r.bias_dps[1] + 2.0).abs() < 1e-6);
        assert!((r.noise_dps[0] - 0.1).abs() < 1e-3 && r.sigma_dps[0] < 0.01);
        let tight = BiasLimits { max_bias_dps: 1.5, ..BiasLimits::default() };
        assert!(matches!(b.finish(&tight), Err(Error::BiasOutOfRange { axis: 1, .. })));
        let few = BiasLimits { min_samples: 500, ..BiasLimits::default() };
        assert_eq!(b.finish(&few), Err(Error::TooFewSamples { have: 200, need: 500 }));
    }

    #[test]
    fn motion_is_not_a_rest() {
        let mut b = BiasEstimator::new();
        for k in 0..200 {
            b.add([if k % 2 == 0 { 5.0 } else { -5.0 }, 0.0, 0.0], [0.0, 0.0, 1.0]);
        }
        assert!(matches!(b.finish(&BiasLimits::default()), Err(Error::NotStill { .. })));
    }
}
