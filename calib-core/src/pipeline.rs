//! The calibration's decisions, made once: the firmware's procedure and the offline tool both
//! call these, so that they choose, gate and reject alike.

use crate::accel::{AccelCal, AccelCalibrator};
use crate::axis::turn_deg;
use crate::full::FullCal;
use crate::gyro::GyroCal;
use crate::vec3::to_f64 as v64;
use crate::{Error, Vec3};
use nalgebra::Vector3;

/// What a result must meet to be stored or printed.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Acceptance {
    /// Accepted range of each scale factor.
    pub k_min: f32,
    /// See `k_min`.
    pub k_max: f32,
    /// Largest accepted 1σ of a scale factor.
    pub max_sigma_k: f32,
    /// Largest accepted accelerometer residual | |a| − 1 | RMS after calibration (g).
    pub max_accel_rms_g: f32,
}

/// Poses the 6-parameter accelerometer fit needs; from [`NINE_PARAM_POSES`] on, the 9-parameter
/// fit is tried first.
pub const SIX_PARAM_POSES: usize = 6;
/// See [`SIX_PARAM_POSES`].
pub const NINE_PARAM_POSES: usize = 9;

/// The accelerometer fit: 9 parameters when there are enough poses and it succeeds, else 6;
/// rejected if its residual exceeds the acceptance.
pub fn fit_accel(poses: &AccelCalibrator, acc: &Acceptance) -> Result<AccelCal, Error> {
    let fit = if poses.len() >= NINE_PARAM_POSES { poses.solve9().or_else(|_| poses.solve6()) } else { poses.solve6() }?;
    if !(fit.rms_after_g <= acc.max_accel_rms_g) {
        return Err(Error::AccelFitFailed);
    }
    Ok(fit)
}

/// The estimator's result to use: the speed-free sweep estimator, else the paper's.
pub fn choose(sweep: Result<GyroCal, Error>, paper: Option<Result<GyroCal, Error>>) -> Result<GyroCal, Error> {
    match (sweep, paper) {
        (Ok(c), _) | (Err(_), Some(Ok(c))) => Ok(c),
        (Err(e), _) => Err(e),
    }
}

/// Rejects a result whose scale factors are implausible or too uncertain.
pub fn validate(cal: &GyroCal, acc: &Acceptance) -> Result<(), Error> {
    for i in 0..3 {
        let (k, sigma) = (cal.k[i][i], cal.quality.sigma_k[i]);
        if !(k >= acc.k_min && k <= acc.k_max && sigma <= acc.max_sigma_k) {
            return Err(Error::ResultRejected { axis: i as u8, k, sigma });
        }
    }
    Ok(())
}

/// Largest accepted cross-axis term of a full `K` (|K_ij|, i ≠ j): low-cost MEMS couple ≈ 1 %.
pub const MAX_CROSS_AXIS: f32 = 0.1;

/// Rejects a full `K` whose scale factors are implausible or too uncertain, or whose cross-axis
/// terms are implausible.
pub fn validate_full(cal: &FullCal, acc: &Acceptance) -> Result<(), Error> {
    for i in 0..3 {
        let (k, sigma) = (cal.k[i][i], cal.sigma_k[i][i]);
        if !(k >= acc.k_min && k <= acc.k_max && sigma <= acc.max_sigma_k) {
            return Err(Error::ResultRejected { axis: i as u8, k, sigma });
        }
        for j in (0..3).filter(|&j| j != i) {
            if !(cal.k[i][j].abs() <= MAX_CROSS_AXIS) {
                return Err(Error::ResultRejected { axis: i as u8, k: cal.k[i][j], sigma: cal.sigma_k[i][j] });
            }
        }
    }
    Ok(())
}

/// Bias drift (°/s per minute, first rest to last) above which moves that disagree with one `K`
/// are blamed on the gyro warming up ([`Error::BiasDrifting`]) rather than on the rig (a slip).
/// A warm-up of 2–6 °C at 0.03–0.05 °/s/°C with τ of 1–2.5 min drifts 0.05–0.3 °/s/min in its
/// first minutes; a warmed-up part's bias instability stays below 0.005 °/s/min.
pub const MAX_DRIFT_DPS_PER_MIN: f32 = 0.02;

/// A solve's error as the user must read it: [`Error::MovesInconsistent`] becomes
/// [`Error::BiasDrifting`] when the bias moved faster than [`MAX_DRIFT_DPS_PER_MIN`].
pub fn blame(e: Error, drift_dps_per_min: f32) -> Error {
    match e {
        Error::MovesInconsistent { .. } if drift_dps_per_min > MAX_DRIFT_DPS_PER_MIN => {
            Error::BiasDrifting { dps_per_min: drift_dps_per_min, limit_dps_per_min: MAX_DRIFT_DPS_PER_MIN }
        }
        e => e,
    }
}

/// The paper's constant-rate spin: which part of it is averaged (the servo speeds up after
/// the start and slows before the end), how long that part must be, and the least rate.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SteadyRate {
    /// Skipped after the spin starts (s).
    pub skip_start_s: f32,
    /// Skipped before it ends (s).
    pub skip_end_s: f32,
    /// Shortest averaged part a log's steady run needs (s).
    pub min_s: f32,
    /// Smallest shaft rate that counts as a spin (°/s).
    pub min_dps: f32,
}

impl SteadyRate {
    /// One second skipped at the start, half a second at the end; ≥ 3 s at ≥ 2 °/s.
    pub const DEFAULT: SteadyRate = SteadyRate { skip_start_s: 1.0, skip_end_s: 0.5, min_s: 3.0, min_dps: 2.0 };

    /// A sample `elapsed_s` after the start of a spin that lasts `duration_s` is averaged.
    pub fn averaged(&self, elapsed_s: f64, duration_s: f64) -> bool {
        elapsed_s > self.skip_start_s as f64 && elapsed_s < duration_s - self.skip_end_s as f64
    }
}

/// Where the paper's estimator takes the shaft rate `ω_n` from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RateSource {
    /// The rate the servo was commanded at (a positional servo; a log's servo column).
    Commanded,
    /// The rate gravity turned about the axis, seen by the calibrated accelerometer (a
    /// continuous servo's speed is unknown).
    Gravity,
}

impl RateSource {
    /// Its name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            RateSource::Commanded => "servo column",
            RateSource::Gravity => "accelerometer",
        }
    }
}

/// The angle gravity turns about a fixed axis over a spin, summed sample to sample, and the
/// time it took: the shaft's rate without knowing the servo's speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GravityTurn {
    axis: Option<Vector3<f64>>,
    prev: Option<Vec3>,
    turn_deg: f64,
    t_first: Option<f64>,
    t_last: f64,
}

impl GravityTurn {
    /// About `axis` (unit, calibrated accelerometer frame); `None`: no axis, no rate.
    pub fn new(axis: Option<Vector3<f64>>) -> Self {
        Self { axis, prev: None, turn_deg: 0.0, t_first: None, t_last: 0.0 }
    }

    /// A calibrated accelerometer sample (g) at `t_s`.
    pub fn add(&mut self, t_s: f64, accel_g: Vec3) {
        if let (Some(u), Some(p)) = (self.axis, self.prev) {
            self.turn_deg += turn_deg(&u, &v64(p), &v64(accel_g));
        }
        self.prev = Some(accel_g);
        self.t_first.get_or_insert(t_s);
        self.t_last = t_s;
    }

    /// Mean rate of the turn (°/s, ≥ 0; 0 before two samples).
    pub fn rate_dps(&self) -> f32 {
        match self.t_first {
            Some(t0) if self.t_last > t0 => (self.turn_deg.abs() / (self.t_last - t0)) as f32,
            _ => 0.0,
        }
    }
}

/// The shaft rate for the paper's estimator (°/s) and its source: the commanded rate when the
/// servo turned at a known one, else the rate gravity turned.
pub fn spin_rate(commanded_dps: Option<f32>, gravity: &GravityTurn) -> (f32, RateSource) {
    match commanded_dps {
        Some(w) => (w, RateSource::Commanded),
        None => (gravity.rate_dps(), RateSource::Gravity),
    }
}
