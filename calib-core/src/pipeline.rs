//! The calibration's decisions, made once: the firmware's procedure and the offline tool both
//! call these, so that they choose, gate and reject alike.

use crate::accel::{AccelCal, AccelCalibrator};
use crate::full::FullCal;
use crate::gyro::GyroCal;
use crate::Error;

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
