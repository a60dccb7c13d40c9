//! Rest (stillness) detection on consecutive windows, with thresholds in physical units.
//!
//! Each completed window is returned with its statistics so that callers build pose and bias
//! means from whole still windows only: a window with motion never leaks into a mean.

use crate::math::real::Real;
use crate::math::stats::Moments3;
use crate::{Time, Vec3};

/// Thresholds of the rest detector.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct RestConfig {
    /// Length of one analysis window (s).
    pub window_s: f32,
    /// Continuous still time before the state is `Still` (s).
    pub hold_s: f32,
    /// Largest per-axis accelerometer standard deviation in a still window (g).
    pub accel_std_max_g: f32,
    /// Largest per-axis gyro standard deviation in a still window (°/s).
    pub gyro_std_max_dps: f32,
    /// Largest change of the accelerometer mean between consecutive windows (g):
    /// catches slow turns whose per-window variance is small.
    pub accel_drift_max_g: f32,
}

impl RestConfig {
    /// For the LSM9DS1 at 119–952 Hz: noise ≈ 1–3 mg and 0.1–0.3 °/s rms.
    /// The defaults (also as `Default`).
    pub const DEFAULT: RestConfig =
        RestConfig { window_s: 0.25, hold_s: 0.5, accel_std_max_g: 0.006, gyro_std_max_dps: 0.8, accel_drift_max_g: 0.004 };

    /// A person's hand (DESIGN §4.7): quasi-static, not still. Held in the air a board sways
    /// 0.1–0.3° at 0.3–1.5 Hz under 8–12 Hz tremor: gyro rate RMS up to ≈ 2 °/s, linear
    /// accelerations up to ≈ 0.01 g, the mean tilting by up to ≈ 0.005 g per window. A move (tens
    /// of °/s and more) or a slow turn (10 °/s tilts gravity 0.04 g per window) stays out.
    pub const HAND: RestConfig =
        RestConfig { window_s: 0.25, hold_s: 0.5, accel_std_max_g: 0.015, gyro_std_max_dps: 3.0, accel_drift_max_g: 0.01 };
}

impl Default for RestConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Output of the detector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RestState {
    /// The last completed window showed motion.
    Moving,
    /// Still windows so far, but not yet for `hold_s`.
    Settling,
    /// Still for at least `hold_s`.
    Still,
}

/// One completed analysis window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    /// Time of its first sample.
    pub t_start: Time,
    /// Time of its last sample.
    pub t_end: Time,
    /// Accelerometer statistics (g).
    pub accel: Moments3,
    /// Gyro statistics (°/s).
    pub gyro: Moments3,
    /// Whether the window itself met the thresholds.
    pub still: bool,
    /// Detector state after this window.
    pub state: RestState,
}

/// Block-window rest detector: O(1) state, one decision per completed window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestDetector {
    cfg: RestConfig,
    window_start: Option<Time>,
    accel: Moments3,
    gyro: Moments3,
    prev_accel_mean: Option<[Real; 3]>,
    still_since: Option<Time>,
    state: RestState,
}

impl RestDetector {
    /// A detector that starts in `Moving`.
    pub const fn new(cfg: RestConfig) -> Self {
        Self {
            cfg,
            window_start: None,
            accel: Moments3::new(),
            gyro: Moments3::new(),
            prev_accel_mean: None,
            still_since: None,
            state: RestState::Moving,
        }
    }

    /// Its thresholds.
    pub fn config(&self) -> &RestConfig {
        &self.cfg
    }

    /// Forgets all history (state `Moving`).
    pub fn reset(&mut self) {
        *self = Self::new(self.cfg);
    }

    /// Current state.
    pub fn state(&self) -> RestState {
        self.state
    }

    /// Feeds one sample: time (MCU clock), raw accel (g), raw gyro (°/s). Returns the window it
    /// completed, if any.
    pub fn update(&mut self, t: Time, accel_g: Vec3, gyro_dps: Vec3) -> Option<Window> {
        let start = *self.window_start.get_or_insert(t);
        self.accel.add(accel_g);
        self.gyro.add(gyro_dps);
        if t.since(start) < self.cfg.window_s as Real {
            return None;
        }
        let mean = self.accel.mean();
        let drift = self.prev_accel_mean.map_or(0.0, |p| (0..3).fold(0.0 as Real, |m, k| m.max((mean[k] - p[k]).abs())));
        let still = self.accel.count() >= 2
            && self.accel.max_std() <= self.cfg.accel_std_max_g as Real
            && self.gyro.max_std() <= self.cfg.gyro_std_max_dps as Real
            && drift <= self.cfg.accel_drift_max_g as Real;
        if still {
            let since = *self.still_since.get_or_insert(start);
            self.state = if t.since(since) >= self.cfg.hold_s as Real { RestState::Still } else { RestState::Settling };
        } else {
            self.still_since = None;
            self.state = RestState::Moving;
        }
        self.prev_accel_mean = Some(mean);
        let window = Window { t_start: start, t_end: t, accel: self.accel, gyro: self.gyro, still, state: self.state };
        self.window_start = None;
        self.accel = Moments3::new();
        self.gyro = Moments3::new();
        Some(window)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::secs;

    fn feed(d: &mut RestDetector, t0: f64, span_s: Real, f: impl Fn(Real) -> (Vec3, Vec3)) -> (RestState, Real) {
        let mut t = t0;
        while t < t0 + span_s {
            let (a, g) = f(t);
            d.update(secs(t), a, g);
            t += 0.01;
        }
        (d.state(), t)
    }

    #[test]
    fn still_after_hold_and_moving_on_rotation() {
        let mut d = RestDetector::new(RestConfig::default());
        let tiny = |t: f64| libm::sin(t * 377.0) as f32 * 1e-3;
        let (s, t) = feed(&mut d, 0.0, 0.3, |t| ([0.0, 0.0, 1.0 + tiny(t)], [tiny(t); 3]));
        assert_eq!(s, RestState::Settling);
        let (s, t) = feed(&mut d, t, 0.6, |t| ([0.0, 0.0, 1.0 + tiny(t)], [tiny(t); 3]));
        assert_eq!(s, RestState::Still);
        // A slow turn at 2 °/s: gyro variance is small, accel drifts.
        let (s, _) = feed(&mut d, t, 1.0, |t| {
            let th = (t * 2.0 as Real).to_radians();
            ([libm::sin(th) as f32, 0.0, libm::cos(th) as f32], [0.0, 2.0, 0.0])
        });
        assert_eq!(s, RestState::Moving);
    }

    #[test]
    fn vibration_is_motion_and_windows_partition_the_samples() {
        let mut d = RestDetector::new(RestConfig::default());
        let mut n = 0;
        let mut t = 0.0;
        for _ in 0..200 {
            if let Some(w) = d.update(secs(t), [0.0, 0.0, 1.0], [5.0 * libm::sin(t * 60.0) as f32, 0.0, 0.0]) {
                assert!(!w.still && w.state == RestState::Moving);
                assert!(w.t_end.since(w.t_start) >= 0.25 - 1e-6);
                n += w.gyro.count();
            }
            t += 0.01;
        }
        assert!(n > 180 && n <= 200);
    }
}
