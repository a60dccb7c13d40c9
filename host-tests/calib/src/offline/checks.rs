//! What a log's numbers say about its units: the time base (regular sampling at an IMU's rate),
//! the accelerometer's (1 g at rest) and the gyro's (a scale near a unit factor).

use super::*;

/// The LSM9DS1's output data rates (Hz): gyro 14.9, 59.5, 119, 238, 476, 952; accelerometer
/// alone also 10 and 50.
const ODRS_HZ: [f64; 8] = [10.0, 14.9, 50.0, 59.5, 119.0, 238.0, 476.0, 952.0];
/// How far a real ODR may be from nominal (the datasheet gives none; boards show several %).
const ODR_TOLERANCE: f64 = 0.1;
/// Sample rates a MEMS IMU logs at (Hz): a time column in ms or µs falls far below.
const IMU_RATE_HZ: (f64, f64) = (5.0, 10_000.0);
/// Share of the sample intervals that must lie within ±50 % of the median (regular sampling;
/// the rest are gaps or jitter).
const REGULAR_SHARE: f64 = 0.9;

/// The LSM9DS1 ODR (nominal, Hz) a measured rate is, if any.
fn odr_of(rate_hz: f64) -> Option<f64> {
    ODRS_HZ.into_iter().find(|o| (rate_hz / o - 1.0).abs() <= ODR_TOLERANCE)
}

fn is_imu_rate(rate_hz: f64) -> bool {
    (IMU_RATE_HZ.0..=IMU_RATE_HZ.1).contains(&rate_hz)
}

/// The log's time base.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TimeBase {
    /// Median sample rate (Hz).
    pub rate_hz: f64,
    /// It is an LSM9DS1 output data rate (within 10 %): false for another sensor's log.
    pub lsm9ds1_odr: bool,
}

impl TimeBase {
    /// The rate a record states: the nominal LSM9DS1 ODR the log was sampled at (its real rate
    /// differs by several %), else the measured rate (Hz).
    pub fn nominal_hz(&self) -> f64 {
        odr_of(self.rate_hz).unwrap_or(self.rate_hz)
    }
}

/// The median sample interval (s) and every interval, sorted; `None` for fewer than 2 rows.
pub fn sample_intervals(rows: &[Row]) -> Option<(f64, Vec<f64>)> {
    let mut dt: Vec<f64> = rows.windows(2).map(|w| w[1].t.s() - w[0].t.s()).collect();
    dt.sort_by(f64::total_cmp);
    Some((*dt.get(dt.len() / 2)?, dt))
}

/// Checks the time column: regular sampling at a rate an IMU logs at (a time column in ms or µs
/// is named). Another sensor's rate is accepted and said in [`TimeBase::lsm9ds1_odr`].
pub fn check_time_base(rows: &[Row]) -> Result<TimeBase, OfflineError> {
    let Some((median, dt)) = sample_intervals(rows) else {
        return Ok(TimeBase { rate_hz: 0.0, lsm9ds1_odr: false });
    };
    let rate_hz = 1.0 / median;
    // Within a quarter of the median: a log with every third row lost (intervals T and 2T, the
    // median either) is irregular whichever the median is (with ±50 %, T counted as regular
    // beside a median of 2T).
    let regular = dt.iter().filter(|d| (*d / median - 1.0).abs() <= 0.25).count() as f64 / dt.len() as f64;
    if is_imu_rate(rate_hz) && regular >= REGULAR_SHARE {
        return Ok(TimeBase { rate_hz, lsm9ds1_odr: odr_of(rate_hz).is_some() });
    }
    let hint = if is_imu_rate(rate_hz * 1e3) {
        "the time column looks like milliseconds: t_s must be in seconds (divide by 1000, or --columns t_s=NAME/1000)"
    } else if is_imu_rate(rate_hz * 1e6) {
        "the time column looks like microseconds: t_s must be in seconds (divide by 1e6, or --columns t_s=NAME/1e6)"
    } else if is_imu_rate(rate_hz) {
        "the sampling is irregular: more than a tenth of the intervals are off the median by over 25 % (samples missing or duplicated)"
    } else {
        "not a rate an IMU logs at: is t_s in seconds?"
    };
    Err(OfflineError::TimeBase { rate_hz, hint })
}

/// Checks the accelerometer's units from the still segments: |a| ≈ 1 g. Their means from the
/// rows in f64: the segments' own sums (`Moments3`, fixed point) hold readings to ±8192, and a
/// log in raw counts goes beyond.
pub(super) fn check_accel_units(rows: &[Row], ph: &Phases) -> Result<(), OfflineError> {
    let means: Vec<Vector3<f64>> = ph
        .segments
        .iter()
        .map(|s| {
            rows[s.first..=s.last].iter().map(|r| Vector3::from(r.accel_g.map(f64::from))).sum::<Vector3<f64>>()
                / (s.last + 1 - s.first) as f64
        })
        .collect();
    let norms: Vec<f64> = means.iter().map(|m| m.norm()).collect();
    let norm = norms.iter().sum::<f64>() / norms.len().max(1) as f64;
    if (0.8..=1.25).contains(&norm) {
        return Ok(());
    }
    let hint = if (8.0..=12.0).contains(&norm) {
        "the accelerometer columns look like m/s²: they must be in g (divide by 9.80665, or --columns ax_g=NAME/9.80665 …)"
    } else if (800.0..=1250.0).contains(&norm) {
        "the accelerometer columns look like mg: divide by 1000"
    } else if means.iter().all(|m| m.iter().all(|v| (16_384.0..=49_152.0).contains(v))) {
        "raw counts of an unsigned 16-bit part (every axis near 32768 at rest): subtract 32768 and apply the sensitivity of the sensor's datasheet; the log holds g and deg/s"
    } else {
        "raw counts? apply the sensitivity (e.g. 0.061 mg/LSB at ±2 g: --columns ax_g=NAME*0.000061 …)"
    };
    Err(OfflineError::AccelUnits { norm, hint })
}

/// Names a gyro unit mistake from the scale factor found (K ≈ 180/π: rad/s; ≈ 1e3: m°/s).
pub(super) fn gyro_units(k: f64) -> Option<OfflineError> {
    let near = |v: f64| (k / v - 1.0).abs() < 0.15;
    let hint = if near(180.0 / std::f64::consts::PI) {
        "K ≈ 180/π: the gyro columns are in rad/s; they must be in °/s (multiply by 57.29578, or --columns gx_dps=NAME*57.29578 …)"
    } else if near(1e-3) {
        "K ≈ 1/1000: the gyro columns look like m°/s; divide by 1000"
    } else if near(1e3) {
        "K ≈ 1000: the gyro columns look like k°/s or wrongly scaled counts"
    } else {
        return None;
    };
    Some(OfflineError::GyroUnits { k, hint })
}

/// The gyro scale a result implies (the mean of its diagonal), or an error implies (an
/// implausible scale, or a move whose gyro turn was that far from the commanded one): a scale
/// near a unit factor names the mistake ([`gyro_units`]).
pub(super) fn implied_scale(r: Result<&GyroCal, &Error>) -> Option<f64> {
    match r {
        Ok(c) => Some((c.k[0][0] + c.k[1][1] + c.k[2][2]) as f64 / 3.0),
        Err(Error::ServoNotTurning { commanded_deg, measured_deg, .. }) if *measured_deg != 0.0 => {
            Some((commanded_deg / measured_deg).abs() as f64)
        }
        Err(Error::ImplausibleScale { value, .. }) => Some(*value as f64),
        Err(_) => None,
    }
}
