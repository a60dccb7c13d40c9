//! Offline calibration of a recorded log with the same calib-core code as the firmware.
//!
//! The phases are found from the data: still windows (calib-core's rest detector, with
//! thresholds raised to the log's own noise floor) grouped into still segments; a still segment
//! with an empty servo column is a hand-held accelerometer pose, one with a servo value a rig
//! pose; the motion between two consecutive rig poses is a move; a long run of windows with a
//! steady gyro rate is the paper's constant-rate spin.

use crate::csvlog::{Log, Row};
use calib_core::estimators::accel::{AccelCal, AccelCalibrator, AccelModel, AccelSigma};
use calib_core::estimators::axis::{Poses, MAX_POSES};
use calib_core::estimators::bias::{Bias, BiasEstimator, BiasLimits, Drift, RestBias};
use calib_core::estimators::full::FullCal;
use calib_core::estimators::gyro::{GyroCal, GyroQuality, Method};
use calib_core::estimators::rest::{RestConfig, RestDetector, RestState};
use calib_core::estimators::rotation::{PoseRest, PoseTurn, RotationLimits, Rotations};
use calib_core::estimators::sweep::{Integrator, Moves, MAX_MOVES};
use calib_core::estimators::{full, paper, sweep};
use calib_core::formats::record::{self, Record, SensorSetup};
use calib_core::math::stats::Moments3;
use calib_core::math::vec3::{sub, to_real as v64};
use calib_core::procedure::pipeline;
use calib_core::procedure::pipeline::{GravityTurn, SteadyRate};
use calib_core::procedure::Config;
use calib_core::Error;
use calib_core::Vec3;
use nalgebra::Vector3;
use serde::Serialize;

mod advice;
mod checks;
mod driven;
mod mag_axes;
mod magnetometer;
mod output;
mod phases;

use checks::{check_accel_units, gyro_units, implied_scale};
pub use checks::{check_time_base, sample_intervals, TimeBase};
pub use mag_axes::MagAxes;
pub use magnetometer::MagOutcome;
pub use output::{EstimatorOut, Estimators, FullOut, HandMoves, Output, QualityOut, Segments};
pub use phases::{phases, steady_spin, Phases, Segment, SteadySpin};

/// Why a log could not be calibrated.
#[derive(Debug, Clone, PartialEq)]
pub enum OfflineError {
    /// A calib-core step failed.
    Calib {
        /// Which step.
        stage: &'static str,
        /// Its error.
        error: Error,
    },
    /// The log has no still period to measure the gyro bias.
    NoRest,
    /// The paper method was asked for but the log has no constant-rate spin of ≥ 3 s.
    NoSpin,
    /// The time column is not regular sampling at an IMU's rate (or, in a run of the firmware,
    /// not an LSM9DS1 ODR); `hint` names the likely mistake.
    TimeBase {
        /// Median sample rate of the log (Hz).
        rate_hz: f64,
        /// What is probably wrong.
        hint: &'static str,
    },
    /// The accelerometer at rest does not read 1 g; `hint` names the likely mistake.
    AccelUnits {
        /// Mean |a| over the still segments.
        norm: f64,
        /// What is probably wrong.
        hint: &'static str,
    },
    /// The gyro scale comes out near a unit conversion factor: the column is in other units.
    GyroUnits {
        /// The scale factor found (mean of the diagonal).
        k: f64,
        /// What is probably wrong.
        hint: &'static str,
    },
}

impl std::fmt::Display for OfflineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            OfflineError::Calib { stage, error } => write!(f, "{stage}: {error}"),
            OfflineError::NoRest => f.write_str("no still period in the log: cannot measure the gyro bias"),
            OfflineError::NoSpin => f.write_str("no constant-rate spin of at least 3 s in the log: the paper method cannot run"),
            OfflineError::TimeBase { rate_hz, hint } => write!(f, "median sample rate {rate_hz:.4} Hz: {hint}"),
            OfflineError::AccelUnits { norm, hint } => write!(f, "the accelerometer reads {norm:.3} at rest, not 1 g: {hint}"),
            OfflineError::GyroUnits { k, hint } => write!(f, "gyro scale factor {k:.3}: {hint}"),
        }
    }
}

fn stage(stage: &'static str) -> impl Fn(Error) -> OfflineError {
    move |error| OfflineError::Calib { stage, error }
}

/// Everything the offline calibration found.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// The chosen diagonal gyro result, validated as the firmware would; or why there is none.
    pub gyro: Result<GyroCal, OfflineError>,
    /// On a pan/tilt log: the full 3×3 `K` (validated), or why it failed; preferred to `gyro`.
    pub full: Option<Result<FullCal, Error>>,
    /// Gyro bias.
    pub bias: Bias,
    /// Accelerometer calibration (identity when the log has fewer than 6 hand-held poses).
    pub accel: AccelCal,
    /// Its 1σ (`None`: no fit, or a replayed run of the firmware, whose procedure does not give
    /// it).
    pub accel_sigma: Option<AccelSigma>,
    /// Sweep estimator outcome.
    pub sweep: Result<GyroCal, Error>,
    /// Paper estimator outcome (`None` without a steady spin).
    pub paper: Option<Result<GyroCal, Error>>,
    /// The speed the paper estimator used (°/s) and where it came from.
    pub spin_rate: Option<(f32, &'static str)>,
    /// The phases.
    pub phases: Phases,
    /// Rig poses and moves used.
    pub rig_poses: usize,
    /// Moves used.
    pub moves: usize,
    /// Hand-held poses used.
    pub handheld_poses: usize,
    /// The log was a run of the firmware's procedure, replayed through it under this
    /// configuration ([`crate::replay`]): the results are the firmware's.
    pub replayed: Option<&'static str>,
    /// The record the firmware's procedure built on the replay (none if it failed or the log
    /// took the data-driven path).
    pub replayed_record: Option<Record>,
    /// The log's sample rate.
    pub time_base: TimeBase,
    /// The sensor setup the log states (the firmware's raw log does), if it states one.
    pub setup: Option<SensorSetup>,
    /// The moves between hand-held poses (the data-driven path).
    pub hand_moves: Option<HandMoves>,
    /// The magnetometer from the hand-held rows (`None`: the log has no magnetometer columns).
    pub mag: Option<MagOutcome>,
    /// The hand-held moves as rotation constraints (the data-driven path): with the full `K`
    /// they refine the magnetometer's alignment.
    pub rotations: Option<Box<HostRotations>>,
    /// The F-test that chose the accelerometer model (`None`: only one model could be fitted, or
    /// a replayed run of the firmware).
    pub accel_test: Option<pipeline::ModelTest>,
    /// What the data-driven path left out, each with its count and why (the PC's stores hold a
    /// whole log; only the one-axis estimators' fixed sizes and the poses' index remain).
    pub left_out: Vec<String>,
    /// The full `K` the moves gave before validation (the data-driven path): what its moves'
    /// misfits are measured at when it is rejected ([`advice`]).
    pub full_tried: Option<calib_core::Mat3>,
    /// The gyro followed the accelerometer with the left-hand rule ([`Error::AxesMirrored`]
    /// with its evidence), as the LSM9DS1's raw axes do: calibrated with its readings negated,
    /// then `K` and the bias put back for the readings as logged (`ω = K (g − b)`, the rates in
    /// the log's own, mirrored, convention). `None`: right-handed.
    pub mirrored: Option<Error>,
}

/// Calibrates a log. `method`: force one estimator; `None` picks the best the log supports.
/// Fails only if nothing at all can be calibrated (no rest, wrong units); a log that supports
/// only part of the calibration gives what it can, with the gyro's error in
/// [`Calibration::gyro`].
pub fn calibrate(rows: &[Row], method: Option<Method>) -> Result<Calibration, OfflineError> {
    calibrate_with(rows, method, true)
}

/// How a log is calibrated (the tool's options).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Options {
    /// Force one estimator; `None` picks the best the log supports.
    pub method: Option<Method>,
    /// Leave out the rotation constraints of the moves between hand-held poses.
    pub no_rotations: bool,
    /// Every turn about the vertical is a whole number of revolutions (`--whole-turns`: the
    /// Ferraris protocol); else such a turn constrains its axis only.
    pub whole_turns: bool,
    /// The gyro's full scale (°/s, `--range`): readings at it are clipped. Without it, the
    /// log's stated setup, else repeated extreme readings ([`full_scale`]).
    pub range_dps: Option<f32>,
}

/// The PC's store of hand-held moves: every move of a log between up to [`MAX_POSES`] poses
/// (the firmware keeps [`calib_core::estimators::rotation::MAX_ROTATION_MOVES`] in 480 chunks;
/// a 180° hand move takes ~35 chunks).
pub type HostRotations = Rotations<MAX_POSES, 8192, MAX_POSES>;
/// The PC's store of accelerometer poses (the firmware keeps
/// [`calib_core::estimators::accel::MAX_ACCEL_POSES`]).
pub const HOST_ACCEL_POSES: usize = 256;

/// The one configuration of the data-driven path: the firmware's defaults (acceptance, limits,
/// the paper's spin window).
const CONFIG: Config = Config::DEFAULT;

/// [`calibrate`], with the rotation constraints of the moves between hand-held poses on or off
/// (`calib --no-rotations`: to see what they add).
pub fn calibrate_with(rows: &[Row], method: Option<Method>, rotations_on: bool) -> Result<Calibration, OfflineError> {
    calibrate_from(rows, &Options { method, no_rotations: !rotations_on, ..Options::default() }, None, None)
}

/// [`calibrate_with`] of a whole log, at the sensor setup it states (else the firmware's
/// default full scales); a run of the firmware that started with `stored` in its flash (the
/// board's `s` answer) is replayed from it, as the board did.
pub fn calibrate_log(log: &Log, options: &Options, stored: Option<&Record>) -> Result<Calibration, OfflineError> {
    calibrate_from(&log.rows, options, stored, log.setup)
}

/// [`calibrate_axes`]; when its moves show the gyro mirrored relative to the accelerometer, the
/// log again with the gyro negated, its bias (and tempco) negated back: `−g = K'(…)` is
/// `ω_logged = K (g − b)` with `K = K'`, `b = −b'`.
fn calibrate_from(
    rows: &[Row],
    options: &Options,
    stored: Option<&Record>,
    setup: Option<SensorSetup>,
) -> Result<Calibration, OfflineError> {
    let c = calibrate_axes(rows, options, stored, setup)?;
    let mirrored = match (&c.full, &c.gyro) {
        (Some(Err(e @ Error::AxesMirrored { .. })), _) | (_, Err(OfflineError::Calib { error: e @ Error::AxesMirrored { .. }, .. })) => *e,
        _ => return Ok(c),
    };
    let negated: Vec<Row> = rows.iter().map(|r| Row { gyro_dps: r.gyro_dps.map(|v| -v), ..*r }).collect();
    let mut m = calibrate_axes(&negated, options, stored, setup)?;
    let neg = |v: [f32; 3]| v.map(|x| -x);
    m.bias.bias_dps = neg(m.bias.bias_dps);
    if let Some(r) = m.replayed_record.as_mut() {
        r.gyro_bias_dps = neg(r.gyro_bias_dps);
        if let Some(t) = r.tempco.as_mut() {
            t.dps_per_c = neg(t.dps_per_c);
        }
    }
    // Axes left-handed by the gyro's moves: a turned magnetometer is mirrored in them.
    if let Some(mag) = m.mag.as_mut() {
        mag.mirror_axes();
    }
    m.mirrored = Some(mirrored);
    Ok(m)
}

fn calibrate_axes(
    rows: &[Row],
    options: &Options,
    stored: Option<&Record>,
    setup: Option<SensorSetup>,
) -> Result<Calibration, OfflineError> {
    let (method, rotations_on) = (options.method, !options.no_rotations);
    let time_base = check_time_base(rows)?;
    let ph = phases(rows);
    if ph.segments.is_empty() {
        return Err(OfflineError::NoRest);
    }
    check_accel_units(rows, &ph)?;
    // A run of the firmware's own procedure: replayed through it, the firmware's results (which
    // use the rotation constraints: `--no-rotations` takes the data-driven path).
    if method.is_none() && rotations_on {
        if let Some(r) = crate::replay::replay(rows, stored, setup.unwrap_or(SensorSetup::DEFAULT)) {
            let c = replayed(r, time_base, setup, ph)?;
            // The procedure's own magnetometer (refined by the moves, as the board stores it)
            // when it made one: the JSON and the exported record then agree.
            let mut mag = magnetometer::calibrate(rows, &c.phases, &c.accel, None);
            if let (Some(m), Some(own)) = (mag.as_mut(), c.replayed_record.and_then(|r| r.mag)) {
                m.cal = Ok(own);
            }
            return Ok(Calibration { setup, mag, ..c });
        }
    }
    let range = options.range_dps.or(setup.map(|s| s.gyro_range_dps)).or_else(|| full_scale(rows));
    let c = driven::calibrate(rows, options, range, time_base, ph)?;
    // The full K turns the hand-held moves into rotations the field must follow.
    let turns = c.rotations.as_deref().zip(c.full.as_ref().and_then(|f| f.as_ref().ok()).map(|f| f.k));
    let mag = magnetometer::calibrate(rows, &c.phases, &c.accel, turns);
    Ok(Calibration { setup, mag, ..c })
}

/// The calibration of a replayed run of the firmware: its procedure's results. Its rate must
/// be the ODR the log states (a BMI270's on a Rev2 board), else an LSM9DS1 ODR.
fn replayed(r: crate::replay::Replay, time_base: TimeBase, setup: Option<SensorSetup>, ph: Phases) -> Result<Calibration, OfflineError> {
    let at_odr = match setup {
        Some(s) => (time_base.rate_hz / s.odr_hz as f64 - 1.0).abs() <= 0.1,
        None => time_base.lsm9ds1_odr,
    };
    if !at_odr {
        let hint = "a run of the firmware samples at its sensor's output data rate: samples missing or duplicated";
        return Err(OfflineError::TimeBase { rate_hz: time_base.rate_hz, hint });
    }
    let gyro = match (implied_scale(r.result.as_ref()).and_then(gyro_units), r.result) {
        (Some(e), _) => Err(e),
        (None, Ok(c)) => Ok(c),
        (None, Err(error)) => Err(OfflineError::Calib { stage: "the firmware's procedure", error }),
    };
    if let Err(e @ OfflineError::GyroUnits { .. }) = gyro {
        return Err(e);
    }
    let q = r.sweep.as_ref().and_then(|s| s.as_ref().ok()).map(|c| c.quality);
    Ok(Calibration {
        gyro,
        full: r.full,
        bias: r.bias,
        accel: r.accel,
        accel_sigma: None,
        sweep: r.sweep.unwrap_or(Err(Error::NoUsableMove)),
        paper: r.paper,
        spin_rate: None,
        rig_poses: q.map_or(0, |q| q.poses as usize),
        moves: q.map_or(0, |q| q.rows as usize),
        handheld_poses: r.accel.poses as usize,
        replayed: Some(r.config),
        replayed_record: r.record,
        hand_moves: None,
        time_base,
        phases: ph,
        setup: None,
        mag: None,
        rotations: None,
        accel_test: None,
        left_out: vec![],
        full_tried: None,
        mirrored: None,
    })
}

/// A gyro reading is clipped: at (or beyond, within 0.1 %) the full scale `range_dps`, known
/// from `--range`, the log's setup line or its runs of equal extremes ([`full_scale`]); never
/// from a full scale of a part the log does not claim to be.
fn clipped(v: f32, range_dps: Option<f32>) -> bool {
    range_dps.is_some_and(|r| v.abs() >= 0.999 * r)
}

/// The gyro's full scale (°/s) read off a log that does not state it: the largest |reading| of
/// an axis, when at least [`CLIP_COUNT`] samples hold exactly that value, of either sign (a
/// clipped sensor repeats its limit, a hand's brief turn for one or two samples at a time; a
/// turning one reaches its largest rate once) and it is above 100 °/s.
pub fn full_scale(rows: &[Row]) -> Option<f32> {
    let mut found: Option<f32> = None;
    for axis in 0..3 {
        let peak = rows.iter().map(|r| r.gyro_dps[axis].abs()).fold(0.0f32, f32::max);
        if peak >= 100.0 && rows.iter().filter(|r| r.gyro_dps[axis].abs() == peak).count() >= CLIP_COUNT {
            found = Some(found.map_or(peak, |f| f.min(peak)));
        }
    }
    found
}

/// Samples at one extreme |value| that mark a clipped gyro axis.
const CLIP_COUNT: usize = 3;

/// |slope| (°/s) of the servo column when it ramps linearly over `rows` (residual < 0.5° RMS)
/// faster than `min_dps`.
fn servo_rate(rows: &[Row], min_dps: f32) -> Option<f32> {
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| r.servo_deg.map(|s| (r.t.s(), s as f64))).collect::<Option<_>>()?;
    let n = pts.len() as f64;
    if n < 3.0 {
        return None;
    }
    let (mt, ms) = (pts.iter().map(|p| p.0).sum::<f64>() / n, pts.iter().map(|p| p.1).sum::<f64>() / n);
    let stt: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
    let slope = pts.iter().map(|p| (p.0 - mt) * (p.1 - ms)).sum::<f64>() / stt;
    let rms = (pts.iter().map(|p| (p.1 - ms - slope * (p.0 - mt)).powi(2)).sum::<f64>() / n).sqrt();
    (rms < 0.5 && slope.abs() > min_dps as f64).then_some(slope.abs() as f32)
}
