//! The result shared by the gyro estimators: `ω = K (g − b)` with its quality report.

use crate::math::real::Real;
use crate::math::stats::Spread;
use crate::{Mat3, Vec3};

/// Which gyro estimator produced a result.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "lowercase"))]
pub enum Method {
    /// The paper's estimator: constant-rate spin at a known servo speed (DESIGN §4.1).
    Paper,
    /// Speed-free sweeps: turn angles from the accelerometer (DESIGN §4.2).
    Sweep,
    /// The full 3×3 `K` from moves about several axes ([`crate::estimators::full`]).
    Full,
}

impl Method {
    /// Lower-case name, as in logs and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Method::Paper => "paper",
            Method::Sweep => "sweep",
            Method::Full => "full",
        }
    }
}

/// Everything known about how good a gyro calibration is.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct GyroQuality {
    /// Spread over poses of the invariant `A·ḡ` (°/s·g) with the raw gyro (`K = I`).
    pub invariant_before: Spread,
    /// The same with the calibrated gyro `A·(K ḡ)`: ideally constant.
    pub invariant_after: Spread,
    /// 1σ of the diagonal of `K`.
    pub sigma_k: Vec3,
    /// Condition number of the equilibrated normal matrix.
    pub condition: f32,
    /// RMS residual of the least-squares rows (dimensionless for the paper rows, ° for sweeps).
    pub residual_rms: f32,
    /// Unit rotation axis in the sensor frame.
    pub axis: Vec3,
    /// Axis angle from vertical (°).
    pub tilt_deg: f32,
    /// Shaft-angle span of the poses (°).
    pub span_deg: f32,
    /// Smallest |component| of the axis on a sensor axis.
    pub min_axis_component: f32,
    /// RMS distance of the pose tips from their plane (g).
    pub plane_rms_g: f32,
    /// Static poses used.
    pub poses: u8,
    /// Least-squares rows used (poses for the paper, moves for the sweeps).
    pub rows: u16,
}

/// A gyro scale calibration: `ω = K (g − b)`, `K` in the 6-parameter (diagonal) model.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct GyroCal {
    /// Scale matrix `K` (row-major, dimensionless).
    pub k: Mat3,
    /// The estimator used.
    pub method: Method,
    /// Its quality report.
    pub quality: GyroQuality,
}

/// Plausible range of a gyro scale factor (a raw scale error of ±50 % is a broken setup).
pub(crate) const SCALE_RANGE: (Real, Real) = (0.5, 1.5);
