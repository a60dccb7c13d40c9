//! Offline calibration of a recorded log with the same calib-core code as the firmware.
//!
//! The phases are found from the data: still windows (calib-core's rest detector, with
//! thresholds raised to the log's own noise floor) grouped into still segments; a still segment
//! with an empty servo column is a hand-held accelerometer pose, one with a servo value a rig
//! pose; the motion between two consecutive rig poses is a move; a long run of windows with a
//! steady gyro rate is the paper's constant-rate rotation.

use crate::csvlog::Row;
use calib_core::accel::{AccelCal, AccelCalibrator, AccelModel};
use calib_core::axis::{Poses, MAX_POSES};
use calib_core::bias::{Bias, BiasEstimator, BiasLimits};
use calib_core::full::FullCal;
use calib_core::gyro::{GyroCal, GyroQuality, Method};
use calib_core::pipeline::{GravityTurn, SteadyRate};
use calib_core::procedure::Config;
use calib_core::record::{self, Record};
use calib_core::rest::{RestConfig, RestDetector, RestState};
use calib_core::rotation::Rotations;
use calib_core::stats::Welford3;
use calib_core::sweep::{Integrator, Moves, MAX_MOVES};
use calib_core::vec3::{sub, to_f64 as v64};
use calib_core::{full, paper, pipeline, sweep, Error};
use calib_core::{Mat3, Vec3};
use nalgebra::Vector3;
use serde::Serialize;

/// A still segment: consecutive still windows.
#[derive(Debug, Clone, Copy)]
pub struct Segment {
    /// First row index.
    pub first: usize,
    /// Last row index (inclusive).
    pub last: usize,
    /// Accelerometer statistics (raw g).
    pub accel: Welford3,
    /// Gyro statistics (raw °/s).
    pub gyro: Welford3,
    /// Commanded servo angle (°), `None` for a hand-held pose.
    pub servo_deg: Option<f32>,
    /// Commanded tilt angle (°), when the log has the column.
    pub tilt_deg: Option<f32>,
}

impl Segment {
    /// A rig pose: the servo commanded (at any tilt). A segment with no servo commanded is a
    /// hand-held accelerometer pose.
    pub fn is_rig_pose(&self) -> bool {
        self.servo_deg.is_some()
    }

    /// The tilt setting of a rig pose (°, 0 without a tilt column), to 0.5°.
    fn tilt_setting(&self) -> i32 {
        (self.tilt_deg.unwrap_or(0.0) * 2.0).round() as i32
    }
}

/// A steady-rate run: the paper's rotation.
#[derive(Debug, Clone, Copy)]
pub struct SteadyRotation {
    /// First and last row index (inclusive) of the averaged part.
    pub rows: (usize, usize),
    /// Mean raw gyro over it (°/s).
    pub gyro: Welford3,
}

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
    /// The paper method was asked for but the log has no constant-rate rotation of ≥ 3 s.
    NoRotation,
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
            OfflineError::NoRotation => f.write_str("no constant-rate rotation of at least 3 s in the log: the paper method cannot run"),
            OfflineError::TimeBase { rate_hz, hint } => write!(f, "median sample rate {rate_hz:.4} Hz: {hint}"),
            OfflineError::AccelUnits { norm, hint } => write!(f, "the accelerometer reads {norm:.3} at rest, not 1 g: {hint}"),
            OfflineError::GyroUnits { k, hint } => write!(f, "gyro scale factor {k:.3}: {hint}"),
        }
    }
}

fn stage(stage: &'static str) -> impl Fn(Error) -> OfflineError {
    move |error| OfflineError::Calib { stage, error }
}

/// The phases found in a log.
#[derive(Debug, Clone)]
pub struct Phases {
    /// Thresholds used (raised to the log's noise floor).
    pub rest: RestConfig,
    /// Still segments in time order.
    pub segments: Vec<Segment>,
}

/// Shortest still segment used as a pose (s).
const MIN_SEGMENT_S: f64 = 0.5;

fn window_len(rows: &[Row], window_s: f64) -> Vec<(usize, usize)> {
    let mut out = vec![];
    let mut start = 0;
    for i in 0..rows.len() {
        if rows[i].t_s - rows[start].t_s >= window_s {
            out.push((start, i));
            start = i + 1;
            if start >= rows.len() {
                break;
            }
        }
    }
    out
}

fn stats(rows: &[Row]) -> (Welford3, Welford3) {
    let (mut a, mut g) = (Welford3::new(), Welford3::new());
    for r in rows {
        a.add(r.accel_g);
        g.add(r.gyro_dps);
    }
    (a, g)
}

fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p) as usize]
}

/// Finds still segments and the steady-rate rotation.
pub fn phases(rows: &[Row]) -> Phases {
    let defaults = CONFIG.rest;
    // Noise floor: the 10th percentile of the per-window standard deviations.
    let windows = window_len(rows, defaults.window_s as f64);
    let (mut sa, mut sg) = (vec![], vec![]);
    for &(a, b) in &windows {
        let (wa, wg) = stats(&rows[a..=b]);
        sa.push(wa.max_std());
        sg.push(wg.max_std());
    }
    let (fa, fg) = (percentile(sa, 0.1), percentile(sg, 0.1));
    let accel_std_max_g = defaults.accel_std_max_g.max((3.0 * fa) as f32);
    let rest = RestConfig {
        accel_std_max_g,
        gyro_std_max_dps: defaults.gyro_std_max_dps.max((3.0 * fg) as f32),
        accel_drift_max_g: defaults.accel_drift_max_g.max(0.7 * accel_std_max_g),
        ..defaults
    };

    let mut det = RestDetector::new(rest);
    let mut segments: Vec<Segment> = vec![];
    let mut open: Option<Segment> = None;
    let mut start = 0;
    for (i, r) in rows.iter().enumerate() {
        let Some(w) = det.update(r.t_s, r.accel_g, r.gyro_dps) else { continue };
        let span = &rows[start..=i];
        start = i + 1;
        let (servo, tilt) = (column_of(span, |r| r.servo_deg), column_of(span, |r| r.tilt_deg));
        let still = w.still && w.state == RestState::Still && servo.is_some() && tilt.is_some();
        let (servo, tilt) = (servo.flatten(), tilt.flatten());
        let same = |a: Option<f32>, b: Option<f32>| match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => (a - b).abs() < 0.5,
            _ => false,
        };
        match (&mut open, still) {
            (Some(seg), true) if same(seg.servo_deg, servo) && same(seg.tilt_deg, tilt) => {
                seg.accel.merge(&w.accel);
                seg.gyro.merge(&w.gyro);
                seg.last = i;
            }
            (_, true) => {
                close(&mut open, &mut segments, rows);
                let first = i + 1 - span.len();
                open = Some(Segment { first, last: i, accel: w.accel, gyro: w.gyro, servo_deg: servo, tilt_deg: tilt });
            }
            (_, false) => close(&mut open, &mut segments, rows),
        }
    }
    close(&mut open, &mut segments, rows);
    Phases { rest, segments }
}

/// A command column over a window: `Some(None)` all empty, `Some(Some(mean))` all set and
/// within 0.5°, `None` mixed or moving.
fn column_of(rows: &[Row], col: impl Fn(&Row) -> Option<f32>) -> Option<Option<f32>> {
    let set: Vec<f32> = rows.iter().filter_map(col).collect();
    if set.is_empty() {
        return Some(None);
    }
    if set.len() != rows.len() {
        return None;
    }
    let (lo, hi) = set.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
    (hi - lo < 0.5).then(|| Some(set.iter().sum::<f32>() / set.len() as f32))
}

fn close(open: &mut Option<Segment>, segments: &mut Vec<Segment>, rows: &[Row]) {
    if let Some(seg) = open.take() {
        if rows[seg.last].t_s - rows[seg.first].t_s >= MIN_SEGMENT_S {
            segments.push(seg);
        }
    }
}

/// The longest run of windows whose mean bias-free gyro vector stays within 3 % of the run's
/// first, above `steady.min_dps`, averaged over `steady.min_s` at least once `steady`'s start and
/// end are skipped, as the firmware averages its rotation.
pub fn steady_rotation(rows: &[Row], bias_dps: [f32; 3], window_s: f32, steady: &SteadyRate) -> Option<SteadyRotation> {
    let windows = window_len(rows, window_s as f64);
    let b = v64(bias_dps);
    let means: Vec<Vector3<f64>> = windows.iter().map(|&(a, c)| Vector3::from(stats(&rows[a..=c]).1.mean()) - b).collect();
    // The averaged rows of windows i..=j.
    let averaged = |i: usize, j: usize| {
        let (t0, t1) = (rows[windows[i].0].t_s, rows[windows[j].1].t_s);
        let first = (windows[i].0..=windows[j].1).find(|&r| steady.averaged(rows[r].t_s - t0, t1 - t0))?;
        let last = (windows[i].0..=windows[j].1).rev().find(|&r| steady.averaged(rows[r].t_s - t0, t1 - t0))?;
        (rows[last].t_s - rows[first].t_s >= steady.min_s as f64).then_some((first, last))
    };
    let mut best: Option<(usize, usize)> = None;
    let mut i = 0;
    while i < means.len() {
        let m0 = means[i];
        let mut j = i;
        if m0.norm() > steady.min_dps as f64 {
            while j + 1 < means.len() && (means[j + 1] - m0).norm() <= 0.03 * m0.norm() {
                j += 1;
            }
        }
        if let Some(r) = averaged(i, j).filter(|_| j > i) {
            if best.is_none_or(|(a, b)| r.1 - r.0 > b - a) {
                best = Some(r);
            }
        }
        i = j + 1;
    }
    best.map(|rows_range| SteadyRotation { rows: rows_range, gyro: stats(&rows[rows_range.0..=rows_range.1]).1 })
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
    /// Sweep estimator outcome.
    pub sweep: Result<GyroCal, Error>,
    /// Paper estimator outcome (`None` without a steady rotation).
    pub paper: Option<Result<GyroCal, Error>>,
    /// The speed the paper estimator used (°/s) and where it came from.
    pub rotation_rate: Option<(f32, &'static str)>,
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
}

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

fn is_odr(rate_hz: f64) -> bool {
    ODRS_HZ.iter().any(|o| (rate_hz / o - 1.0).abs() <= ODR_TOLERANCE)
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

/// Checks the time column: regular sampling at a rate an IMU logs at (a time column in ms or µs
/// is named). Another sensor's rate is accepted and said in [`TimeBase::lsm9ds1_odr`].
pub fn check_time_base(rows: &[Row]) -> Result<TimeBase, OfflineError> {
    let mut dt: Vec<f64> = rows.windows(2).map(|w| w[1].t_s - w[0].t_s).collect();
    if dt.is_empty() {
        return Ok(TimeBase { rate_hz: 0.0, lsm9ds1_odr: false });
    }
    dt.sort_by(f64::total_cmp);
    let median = dt[dt.len() / 2];
    let rate_hz = 1.0 / median;
    let regular = dt.iter().filter(|d| (*d / median - 1.0).abs() <= 0.5).count() as f64 / dt.len() as f64;
    if is_imu_rate(rate_hz) && regular >= REGULAR_SHARE {
        return Ok(TimeBase { rate_hz, lsm9ds1_odr: is_odr(rate_hz) });
    }
    let hint = if is_imu_rate(rate_hz * 1e3) {
        "the time column looks like milliseconds: t_s must be in seconds (divide by 1000, or --columns t_s=NAME/1000)"
    } else if is_imu_rate(rate_hz * 1e6) {
        "the time column looks like microseconds: t_s must be in seconds (divide by 1e6, or --columns t_s=NAME/1e6)"
    } else if is_imu_rate(rate_hz) {
        "the sampling is irregular: more than a tenth of the intervals are off the median by over 50 % (samples missing or duplicated)"
    } else {
        "not a rate an IMU logs at: is t_s in seconds?"
    };
    Err(OfflineError::TimeBase { rate_hz, hint })
}

/// Checks the accelerometer's units from the still segments: |a| ≈ 1 g.
fn check_accel_units(ph: &Phases) -> Result<(), OfflineError> {
    let norms: Vec<f64> = ph.segments.iter().map(|s| Vector3::from(s.accel.mean()).norm()).collect();
    let norm = norms.iter().sum::<f64>() / norms.len().max(1) as f64;
    if (0.8..=1.25).contains(&norm) {
        return Ok(());
    }
    let hint = if (8.0..=12.0).contains(&norm) {
        "the accelerometer columns look like m/s²: they must be in g (divide by 9.80665, or --columns ax_g=NAME/9.80665 …)"
    } else if (800.0..=1250.0).contains(&norm) {
        "the accelerometer columns look like mg: divide by 1000"
    } else {
        "raw counts? apply the sensitivity (e.g. 0.061 mg/LSB at ±2 g: --columns ax_g=NAME*0.000061 …)"
    };
    Err(OfflineError::AccelUnits { norm, hint })
}

/// Names a gyro unit mistake from the scale factor found (K ≈ 180/π: rad/s; ≈ 1e3: m°/s).
fn gyro_units(k: f64) -> Option<OfflineError> {
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
fn implied_scale(r: Result<&GyroCal, &Error>) -> Option<f64> {
    match r {
        Ok(c) => Some((c.k[0][0] + c.k[1][1] + c.k[2][2]) as f64 / 3.0),
        Err(Error::ServoNotTurning { commanded_deg, measured_deg, .. }) if *measured_deg != 0.0 => {
            Some((commanded_deg / measured_deg).abs() as f64)
        }
        Err(Error::ImplausibleScale { value, .. }) => Some(*value as f64),
        Err(_) => None,
    }
}

/// Calibrates a log. `method`: force one estimator; `None` picks the best the log supports.
/// Fails only if nothing at all can be calibrated (no rest, wrong units); a log that supports
/// only part of the calibration gives what it can, with the gyro's error in
/// [`Calibration::gyro`].
pub fn calibrate(rows: &[Row], method: Option<Method>) -> Result<Calibration, OfflineError> {
    calibrate_with(rows, method, true)
}

/// The one configuration of the data-driven path: the firmware's defaults (acceptance, limits,
/// the paper's rotation window).
const CONFIG: Config = Config::DEFAULT;

/// [`calibrate`], with the rotation constraints of the moves between hand-held poses on or off
/// (`calib --no-rotations`: to see what they add).
pub fn calibrate_with(rows: &[Row], method: Option<Method>, rotations_on: bool) -> Result<Calibration, OfflineError> {
    calibrate_from(rows, method, rotations_on, None)
}

/// [`calibrate`] of a log of the firmware's run that started with `stored` in its flash (the
/// board's `s` answer): the replay starts from it, as the board did.
pub fn calibrate_stored(rows: &[Row], stored: Option<&Record>) -> Result<Calibration, OfflineError> {
    calibrate_from(rows, None, true, stored)
}

fn calibrate_from(rows: &[Row], method: Option<Method>, rotations_on: bool, stored: Option<&Record>) -> Result<Calibration, OfflineError> {
    let time_base = check_time_base(rows)?;
    let ph = phases(rows);
    if ph.segments.is_empty() {
        return Err(OfflineError::NoRest);
    }
    check_accel_units(&ph)?;
    // A run of the firmware's own procedure: replayed through it, the firmware's results (which
    // use the rotation constraints: `--no-rotations` takes the data-driven path).
    if method.is_none() && rotations_on {
        if let Some(r) = crate::replay::replay(rows, stored) {
            if !time_base.lsm9ds1_odr {
                let hint = "a run of the firmware samples at an LSM9DS1 output data rate: samples missing or duplicated";
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
            return Ok(Calibration {
                gyro,
                full: r.full,
                bias: r.bias,
                accel: r.accel,
                sweep: r.sweep.unwrap_or(Err(Error::NoUsableMove)),
                paper: r.paper,
                rotation_rate: None,
                rig_poses: q.map_or(0, |q| q.poses as usize),
                moves: q.map_or(0, |q| q.rows as usize),
                handheld_poses: r.accel.poses as usize,
                replayed: Some(r.config),
                replayed_record: r.record,
                time_base,
                phases: ph,
            });
        }
    }
    // Bias: every still segment pooled.
    let mut b = BiasEstimator::new();
    for s in &ph.segments {
        b.add_window(&s.gyro, &s.accel);
    }
    let cfg = &CONFIG;
    let limits = BiasLimits { min_samples: 20, max_std_dps: ph.rest.gyro_std_max_dps, max_accel_std_g: f32::INFINITY, ..cfg.bias };
    let bias = b.finish(&limits).map_err(stage("gyro bias"))?;

    // Rig poses by tilt setting: each setting turns about its own pan axis.
    let rig: Vec<&Segment> = ph.segments.iter().filter(|s| s.is_rig_pose()).collect();
    let mut settings: Vec<(i32, usize)> = vec![];
    for s in &rig {
        match settings.iter_mut().find(|(t, _)| *t == s.tilt_setting()) {
            Some((_, n)) => *n += 1,
            None => settings.push((s.tilt_setting(), 1)),
        }
    }
    let pan_tilt = settings.len() >= 2;

    // Accelerometer from the hand-held poses, and on a pan/tilt rig from every rig pose too
    // (spread over pan × tilt, they are no cone).
    let mut acc = AccelCalibrator::new();
    for s in ph.segments.iter().filter(|s| !s.is_rig_pose() || pan_tilt) {
        if acc.add_pose(s.accel.mean().map(|v| v as f32)).is_err() {
            break;
        }
    }
    let acceptance = cfg.acceptance;
    let accel = match acc.len() {
        n if n >= pipeline::SIX_PARAM_POSES => pipeline::fit_accel(&acc, &acceptance).map_err(stage("accelerometer"))?,
        _ => AccelCal::IDENTITY,
    };
    let gamma = |from_end: usize, to: &Segment| {
        let mut it = Integrator::new();
        for r in &rows[from_end..=to.last] {
            it.add(r.t_s, sub(r.gyro_dps, bias.bias_dps));
        }
        it.gamma()
    };

    // One axis (the most populated tilt setting): rig poses and the moves between consecutive
    // ones, for the diagonal estimators.
    let main_setting = settings.iter().max_by_key(|(_, n)| *n).map(|(t, _)| *t);
    let mut poses = Poses::new();
    let mut moves = Moves::new();
    let mut prev: Option<(u8, usize)> = None;
    for s in &ph.segments {
        if !s.is_rig_pose() || Some(s.tilt_setting()) != main_setting {
            prev = None;
            continue;
        }
        if poses.len() == MAX_POSES {
            break;
        }
        let idx = poses.push(accel.apply(s.accel.mean().map(|v| v as f32))).map_err(stage("rig poses"))?;
        if let Some((from, end)) = prev {
            if moves.len() < MAX_MOVES {
                moves.push(from, idx, gamma(end, s)).map_err(stage("moves"))?;
            }
        }
        prev = Some((idx, s.last));
    }

    // Rotation constraints: every move between two consecutive hand-held poses (calibrated
    // gravity directions at both ends, the gyro integrated between them in chunks).
    let rot_limits = cfg.rotation;
    let mut rotations = Rotations::new();
    let mut prev: Option<(u8, usize)> = None;
    for s in &ph.segments {
        if s.is_rig_pose() {
            prev = None;
            continue;
        }
        let sigma = s.accel.max_std_of_mean();
        let gyro = sub(s.gyro.mean().map(|v| v as f32), bias.bias_dps);
        let Ok(idx) = rotations.push_pose(s.accel.mean().map(|v| v as f32), sigma as f32, gyro) else { break };
        if let Some((from, end)) = prev {
            rotations.begin(from);
            for r in &rows[end..=s.last] {
                rotations.add(r.t_s, sub(r.gyro_dps, bias.bias_dps), r.gyro_dps.iter().any(|v| clipped(*v)));
            }
            let _ = rotations.end(idx, &rot_limits); // a rejected move is counted, not an error
        }
        prev = Some((idx, s.last));
    }
    rotations.calibrate_poses(&accel);
    let with_rotations = (rotations_on && !rotations.moves().is_empty()).then_some((&rotations, &rot_limits));

    // Pan/tilt: the full K from the pan moves of every setting and the tilt moves between them.
    // A pan axis needs poses at ≥ 3 shaft angles (the plane through their tips). One servo: its
    // axis and the rotation constraints. No servo: the rotation constraints alone.
    let pan_angles = |setting: i32| {
        let mut a: Vec<i32> =
            rig.iter().filter(|s| s.tilt_setting() == setting).filter_map(|s| s.servo_deg).map(|d| d.round() as i32).collect();
        a.sort_unstable();
        a.dedup();
        a.len()
    };
    // `--method paper|sweep` asks for that one-axis estimator alone.
    let one_axis_only = matches!(method, Some(Method::Paper | Method::Sweep));
    let full = (!one_axis_only && (pan_tilt || with_rotations.is_some())).then(|| {
        let hinge = settings.len().min(full::MAX_AXES - 1) as u8;
        let mut axes = full::Axes::new();
        let mut prev: Option<(&Segment, u8)> = None;
        for s in &ph.segments {
            if !s.is_rig_pose() {
                prev = None;
                continue;
            }
            let idx = axes.push_pose(accel.apply(s.accel.mean().map(|v| v as f32)))?;
            if let Some((p, from)) = prev {
                let (d_pan, d_tilt) =
                    (s.servo_deg.unwrap_or(0.0) - p.servo_deg.unwrap_or(0.0), (s.tilt_setting() - p.tilt_setting()) as f32 / 2.0);
                let axis = settings.iter().position(|(t, _)| *t == s.tilt_setting()).unwrap_or(0).min(full::MAX_AXES - 2) as u8;
                if d_tilt == 0.0 && d_pan.abs() >= 1.0 && (pan_angles(s.tilt_setting()) >= 3 || !pan_tilt) {
                    axes.push_move(axis, from, idx, d_pan, gamma(p.last, s))?;
                } else if d_pan.abs() < 0.5 && d_tilt.abs() >= 1.0 {
                    axes.push_move(hinge, from, idx, d_tilt, gamma(p.last, s))?;
                }
            }
            prev = Some((s, idx));
        }
        axes.solve_with(&cfg.full, with_rotations).and_then(|f| pipeline::validate_full(&f, &acceptance).map(|_| f))
    });
    let lim = cfg.geometry;
    let sweep = sweep::solve(&poses, &moves, &lim);

    // The paper's estimator on the steady rotation, at the commanded rate when the servo column
    // ramps linearly, else at the rate gravity turns about the axis.
    let (mut paper, mut rotation_rate) = (None, None);
    if let Some(rot) = steady_rotation(rows, bias.bias_dps, cfg.rest.window_s, &cfg.steady) {
        let span = &rows[rot.rows.0..=rot.rows.1];
        let mut gravity = GravityTurn::new(poses.geometry(&lim, false).ok().map(|g| g.u));
        for r in span {
            gravity.add(r.t_s, accel.apply(r.accel_g));
        }
        let (w, source) = pipeline::rotation_rate(servo_rate(span, cfg.steady.min_dps), &gravity);
        if w > 0.0 {
            let gbar = sub(rot.gyro.mean().map(|v| v as f32), bias.bias_dps);
            paper = Some(paper::solve(&poses, gbar, w, &lim));
            rotation_rate = Some((w, source.name()));
        }
    }
    let chosen = match method {
        Some(Method::Sweep | Method::Full) => sweep.map_err(stage("sweep estimator")),
        Some(Method::Paper) => paper.ok_or(OfflineError::NoRotation).and_then(|p| p.map_err(stage("paper estimator"))),
        None => pipeline::choose(sweep, paper).map_err(stage("sweep estimator")),
    };
    // The firmware's acceptance: a result it would not store is not given either; a scale near
    // a unit factor names the mistake.
    let scale = implied_scale(chosen.as_ref().map_err(|e| match e {
        OfflineError::Calib { error, .. } => error,
        _ => &Error::NoUsableMove,
    }));
    let gyro = match scale.and_then(gyro_units) {
        Some(e) => Err(e),
        None => chosen.and_then(|c| pipeline::validate(&c, &acceptance).map(|_| c).map_err(stage("validation"))),
    };
    if let Err(e @ OfflineError::GyroUnits { .. }) = gyro {
        return Err(e);
    }
    Ok(Calibration {
        gyro,
        full,
        bias,
        accel,
        sweep,
        paper,
        rotation_rate,
        rig_poses: poses.len(),
        moves: moves.len(),
        handheld_poses: acc.len(),
        replayed: None,
        replayed_record: None,
        time_base,
        phases: ph,
    })
}

/// A gyro reading at an LSM9DS1 full scale (±245, ±500 or ±2000 °/s: 32 767 counts of 8.75,
/// 17.5 or 70 m°/s): the sample is clipped.
fn clipped(v: f32) -> bool {
    [8.75e-3f32, 17.5e-3, 70e-3].iter().any(|s| (v.abs() / (32767.0 * s) - 1.0).abs() < 1e-3)
}

/// |slope| (°/s) of the servo column when it ramps linearly over `rows` (residual < 0.5° RMS)
/// faster than `min_dps`.
fn servo_rate(rows: &[Row], min_dps: f32) -> Option<f32> {
    let pts: Vec<(f64, f64)> = rows.iter().map(|r| r.servo_deg.map(|s| (r.t_s, s as f64))).collect::<Option<_>>()?;
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

/// The tool's JSON output: the calibration to apply, then everything about its quality.
#[derive(Debug, Clone, Serialize)]
pub struct Output<'a> {
    /// `ω = K (g − b)`; `null` when the log does not support it (see `quality.missing`).
    pub gyro: Option<GyroOut>,
    /// `f = M (a − o)`.
    pub accel: AccelOut,
    /// Quality of every part.
    pub quality: QualityOut<'a>,
}

/// The gyro calibration.
#[derive(Debug, Clone, Serialize)]
pub struct GyroOut {
    /// Scale matrix (row-major).
    #[serde(rename = "K")]
    pub k: Mat3,
    /// Bias (raw °/s).
    pub bias_dps: Vec3,
    /// The estimator used.
    pub method: Method,
}

/// The accelerometer calibration.
#[derive(Debug, Clone, Serialize)]
pub struct AccelOut {
    /// Gain matrix (row-major).
    #[serde(rename = "M")]
    pub m: Mat3,
    /// Offset (raw g).
    pub offset_g: Vec3,
}

/// One estimator's outcome: its result, or why it failed.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum EstimatorOut<'a> {
    /// The result.
    Ok(&'a GyroCal),
    /// The failure.
    Failed {
        /// What went wrong.
        error: String,
    },
}

impl<'a> EstimatorOut<'a> {
    fn of(r: &'a Result<GyroCal, Error>) -> Self {
        match r {
            Ok(c) => EstimatorOut::Ok(c),
            Err(e) => EstimatorOut::Failed { error: e.to_string() },
        }
    }
}

/// The full `K`'s outcome.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub enum FullOut<'a> {
    /// The result.
    Ok(&'a FullCal),
    /// The failure.
    Failed {
        /// What went wrong.
        error: String,
    },
}

/// Both estimators.
#[derive(Debug, Clone, Serialize)]
pub struct Estimators<'a> {
    /// The speed-free sweep estimator.
    pub sweep: EstimatorOut<'a>,
    /// The paper's estimator.
    pub paper: EstimatorOut<'a>,
}

/// What the phase detection found.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Segments {
    /// Still segments.
    pub still: usize,
    /// Accelerometer poses (hand-held or tilt servo).
    pub handheld_poses: usize,
    /// Rig poses.
    pub rig_poses: usize,
    /// Moves between rig poses.
    pub moves: usize,
}

/// Quality of every part of the calibration.
#[derive(Debug, Clone, Serialize)]
pub struct QualityOut<'a> {
    /// The parts of the calibration the log did not support, each with the reason.
    pub missing: Vec<String>,
    /// The chosen gyro result's quality report.
    pub gyro: Option<&'a GyroQuality>,
    /// The bias.
    pub bias: &'a Bias,
    /// The accelerometer fit.
    pub accel: &'a AccelCal,
    /// Both estimators' outcomes.
    pub estimators: Estimators<'a>,
    /// On a pan/tilt log, the full `K`'s quality (or its error).
    pub full: Option<FullOut<'a>>,
    /// The rotation rate the paper estimator used (°/s).
    pub rotation_rate_dps: Option<f32>,
    /// Where it came from (`servo column` or `accelerometer`).
    pub rotation_rate_source: Option<&'static str>,
    /// The log's sample rate, and whether it is an LSM9DS1 ODR (false: another sensor's log).
    pub sample_rate: TimeBase,
    /// Phases found.
    pub segments: Segments,
    /// The rest thresholds used (raised to the log's noise floor).
    pub rest_thresholds: &'a RestConfig,
    /// Log messages between the rows that were skipped.
    pub log_messages: usize,
    /// The log was a run of the firmware's procedure, replayed through it under this
    /// configuration (`null`: phases found from the data).
    pub replayed: Option<&'static str>,
}

const NO_ROTATION: Result<GyroCal, Error> = Err(Error::NoRotation { rate_dps: 0.0, min_dps: CONFIG.steady.min_dps });

impl Calibration {
    /// The parts the log did not support, each with the reason (empty: a full calibration).
    pub fn missing(&self) -> Vec<String> {
        let mut m = vec![];
        match (&self.gyro, &self.full) {
            (_, Some(Ok(_))) => {}
            (Err(e), Some(Err(f))) => m.push(format!("gyro: full K: {f}; one axis: {e}")),
            (Err(e), None) => m.push(format!("gyro: {e}")),
            (Ok(_), Some(Err(f))) => m.push(format!("full K (the diagonal K of one axis is given): {f}")),
            (Ok(_), None) => {}
        }

        if self.accel.model == AccelModel::None {
            m.push(format!(
                "accelerometer: {} accelerometer poses, need {} (hand-held or tilt-servo poses; the identity is used)",
                self.handheld_poses,
                pipeline::SIX_PARAM_POSES
            ));
        }
        m
    }

    /// The tool's output; `log_messages` lines of the log were skipped as messages.
    pub fn output(&self, log_messages: usize) -> Output<'_> {
        let gyro = self.gyro.as_ref().ok();
        let full = self.full.as_ref().and_then(|f| f.as_ref().ok());
        let chosen = match (full, gyro) {
            (Some(f), _) => Some(GyroOut { k: f.k, bias_dps: self.bias.bias_dps, method: Method::Full }),
            (None, g) => g.map(|g| GyroOut { k: g.k, bias_dps: self.bias.bias_dps, method: g.method }),
        };
        Output {
            gyro: chosen,
            accel: AccelOut { m: self.accel.m, offset_g: self.accel.offset_g },
            quality: QualityOut {
                missing: self.missing(),
                gyro: gyro.map(|g| &g.quality),
                bias: &self.bias,
                accel: &self.accel,
                estimators: Estimators {
                    sweep: EstimatorOut::of(&self.sweep),
                    paper: EstimatorOut::of(self.paper.as_ref().unwrap_or(&NO_ROTATION)),
                },
                rotation_rate_dps: self.rotation_rate.map(|r| r.0),
                rotation_rate_source: self.rotation_rate.map(|r| r.1),
                sample_rate: self.time_base,
                segments: Segments {
                    still: self.phases.segments.len(),
                    handheld_poses: self.handheld_poses,
                    rig_poses: self.rig_poses,
                    moves: self.moves,
                },
                full: self.full.as_ref().map(|f| match f {
                    Ok(f) => FullOut::Ok(f),
                    Err(e) => FullOut::Failed { error: e.to_string() },
                }),
                rest_thresholds: &self.phases.rest,
                log_messages,
                replayed: self.replayed,
            },
        }
    }

    /// The result as a flash record, for `calib_core::export`: the gyro `K` of
    /// [`Self::output`] (the full `K` if there is one) with its quality, the bias and the
    /// accelerometer; `seq` 0 (never stored: the export names the source `calib`), temperature
    /// NaN (a log has none). `None` without a gyro result.
    pub fn record(&self) -> Option<Record> {
        if let Some(r) = self.replayed_record {
            return Some(Record { seq: 0, temp_c: f32::NAN, ..r });
        }
        let ctx = record::Context { seq: 0, temp_c: f32::NAN, gyro_bias_dps: self.bias.bias_dps, accel: self.accel };
        // The full K's poses: every rig pose (each one went into its axes).
        let rig_poses = self.phases.segments.iter().filter(|s| s.is_rig_pose()).count().min(u8::MAX as usize) as u8;
        match (&self.full, &self.gyro) {
            (Some(Ok(f)), _) => Some(ctx.full(f, rig_poses)),
            (_, Ok(g)) => Some(ctx.one_axis(g)),
            _ => None,
        }
    }

    /// The output as one line of JSON.
    pub fn json(&self, log_messages: usize) -> String {
        serde_json::to_string(&self.output(log_messages)).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"))
    }
}
