//! Drives the calib-core procedure with the simulated rig and a simulated operator, from button
//! press to stored record: the end-to-end harness of the tests and of `calib --simulate`.
//!
//! The operator presses the button, holds the board near the icosahedron's orientations when
//! asked (as many as the procedure asks for, 12 to 20), each at a heading of its own ([`operator_attitudes`]; moving to the next one after each
//! captured pose), clamps it back on the shaft and presses again. Faults are injected through
//! [`Faults`].

use crate::lsm_model::Lsm9ds1Model;
use crate::sim::{Reading, Rig, RigConfig};
use calib_core::estimators::gyro::GyroCal;
use calib_core::formats::log::{self, Row};
use calib_core::formats::record::{Record, StoreError};
use calib_core::procedure::{Config, Led, Phase, Procedure, Report, Sample, Shell};
use calib_core::{Error, Time};
use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use std::f64::consts::TAU;

/// Faults to inject.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Faults {
    /// The sensor stops delivering samples at this time (s); the timer keeps ticking.
    pub sensor_stops_at_s: Option<f64>,
    /// Someone keeps bumping the rig during the static rig poses.
    pub disturb_rig_poses: bool,
    /// The servo stalls once the first rig pose is captured.
    pub stall_after_first_pose: bool,
    /// The tilt servo is stalled (or unplugged) from the start.
    pub tilt_stalled: bool,
    /// The board slips 3° on its bracket once rig pose `n` is captured.
    pub slip_after_pose: Option<u8>,
    /// Every store fails with this error.
    pub store_fails: Option<StoreError>,
    /// Every n-th sample has no temperature reading (1 = none has one); the others after such
    /// a gap read NaN once (a garbled transfer) before reading right again.
    pub temp_missing_every: Option<usize>,
    /// The shell reports lost samples (a FIFO overrun) once the procedure is in this phase.
    pub samples_lost_in: Option<Phase>,
    /// The shell stops draining the command queue for this many samples once the procedure is
    /// in this phase (it drains again after them).
    pub no_drain_in: Option<(Phase, usize)>,
    /// A magnet (or a laptop) near the board while it is held at hand-held pose `k`: a stray
    /// field (µT, in W) from that pose until the next.
    pub magnet_at_hand_pose: Option<(usize, [f64; 3])>,
    /// The shell reads the LSM9DS1 as the firmware did before the board frame: its raw axes
    /// ([`crate::lsm_model::Lsm9ds1Model::raw_axes`], a left-handed triad) handed on unmapped.
    pub lsm9ds1_unmapped: bool,
    /// Each move starts with a jolt: the accelerometer's z reads its full scale (this, g) for
    /// the move's first sample (a rig move: a hobby servo's kick at the lever arm; a hand-held
    /// one: a brisk start of the hand).
    pub accel_clip_in_moves: Option<f32>,
    /// The user presses the button the moment the re-clamp step begins, before the hand-held
    /// step's fits are due (the procedure then makes them all at the press).
    pub press_on_reattach: bool,
}

/// What a run produced.
#[derive(Debug, Clone, Default)]
pub struct Run {
    /// Every report, in order.
    pub reports: Vec<Report>,
    /// Records stored (the shell's store succeeded).
    pub stored: Vec<Record>,
    /// Records the procedure asked to apply.
    pub applied: Vec<Record>,
    /// The error it ended with, if any.
    pub error: Option<Error>,
    /// Samples delivered.
    pub samples: usize,
    /// The last LED pattern shown.
    pub led: Option<Led>,
    /// MCU time at the end (s).
    pub end_s: f64,
    /// Samples whose accelerometer the harness clipped ([`Faults::accel_clip_in_moves`]).
    pub accel_clips: usize,
}

impl Run {
    /// Gyro results reported by the estimators.
    pub fn gyro_results(&self) -> Vec<GyroCal> {
        self.reports.iter().filter_map(|r| if let Report::Gyro(c) = r { Some(*c) } else { None }).collect()
    }
}

/// The 12 icosahedron vertices (unit vectors): Ye et al.'s accelerometer poses.
pub fn icosahedron() -> [Vector3<f64>; 12] {
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    [
        [-1.0, phi, 0.0],
        [1.0, phi, 0.0],
        [-1.0, -phi, 0.0],
        [1.0, -phi, 0.0],
        [0.0, -1.0, phi],
        [0.0, 1.0, phi],
        [0.0, -1.0, -phi],
        [0.0, 1.0, -phi],
        [phi, 0.0, -1.0],
        [phi, 0.0, 1.0],
        [-phi, 0.0, -1.0],
        [-phi, 0.0, 1.0],
    ]
    .map(|v| Vector3::from(v).normalize())
}

/// Board attitudes (body → world) that point each icosahedron vertex up.
pub fn handheld_attitudes() -> Vec<UnitQuaternion<f64>> {
    icosahedron()
        .iter()
        .map(|v| {
            UnitQuaternion::rotation_between(v, &Vector3::z())
                .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI))
        })
        .collect()
}

/// The attitudes (body → world) a person holds the board in when asked for clearly different
/// orientations turned about varied axes, drawn from `rng`: the icosahedron's 12 vertices twice
/// over (24, beyond the procedure's `max_hand_poses`), each pointed up within 10° (a random
/// direction; the vertices stay ≥ 43° apart, beyond the procedure's 30°), at a heading uniform
/// over the turn. A person turns the board about the vertical as readily
/// as they tilt it; [`handheld_attitudes`] (no heading: tilts only) leaves the body axis that is
/// vertical unturned between two poses.
pub fn operator_attitudes(rng: &mut impl Rng) -> Vec<UnitQuaternion<f64>> {
    let round = handheld_attitudes();
    round
        .iter()
        .chain(&round)
        .map(|&q| {
            let aim = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(0.0..TAU));
            let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), rng.random_range(0.0f64..10.0).to_radians());
            let heading = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(0.0..TAU));
            heading * aim * tilt * aim.inverse() * q
        })
        .collect()
}

/// When the simulated operator presses the button (s of rig time): [`Run::end_s`] minus this is
/// the time from the press.
pub const PRESS_AT_S: f64 = 1.0;

/// A simulated MCU time (s) as the procedure's (to the µs, as the board's clock and the log
/// hold it); the simulator's times are finite and small.
pub fn at(t_s: f64) -> Time {
    Time::from_s(t_s).expect("a simulated time within 1e12 s")
}

/// Converts a simulator sample to the procedure's input.
pub fn to_input(s: &Reading) -> Sample {
    Sample { t: at(s.t_s), accel_g: s.accel_g, gyro_dps: s.gyro_dps, temp_c: log::temp_as_logged(Some(s.temp_c)) }
}

/// The simulated board's outputs and its operator: servo commands go to the rig, reports move
/// the operator (typed reports, not log wording), stores go to `out` (or fail as injected).
struct SimBoard<'a> {
    rig: &'a mut Rig,
    out: &'a mut Run,
    faults: Faults,
    attitudes: Vec<UnitQuaternion<f64>>,
    next_pose: usize,
    handheld: bool,
    press_at: Option<f64>,
    t: f64,
}

impl Shell for SimBoard<'_> {
    fn servo(&mut self, channel: u8, pulse_us: u16) {
        match channel {
            0 => self.rig.set_pulse_us(pulse_us as f64),
            _ => self.rig.set_tilt_pulse_us(pulse_us as f64),
        }
    }

    fn servo_off(&mut self, channel: u8) {
        if channel == 0 {
            self.rig.servo_off();
        }
    }

    fn led(&mut self, led: Led) {
        self.out.led = Some(led);
    }

    fn report(&mut self, r: &Report) {
        self.handheld |= *r == Report::Phase(Phase::HandHeld);
        match *r {
            Report::Phase(Phase::HandHeld) | Report::AccelPose { .. } if self.handheld => {
                if let Some(q) = self.attitudes.get(self.next_pose) {
                    self.rig.detach_to(*q, 1.0);
                    let stray = self.faults.magnet_at_hand_pose.filter(|(k, _)| *k == self.next_pose).map_or([0.0; 3], |(_, f)| f);
                    self.rig.set_stray_field_ut(Vector3::from(stray));
                    self.next_pose += 1;
                }
            }
            Report::Phase(Phase::Reattach) => {
                self.handheld = false;
                self.rig.attach();
                let wait = if self.faults.press_on_reattach { 0.0 } else { self.rig.config().attach_transition_s + 1.0 };
                self.press_at = Some(self.t + wait);
            }
            Report::RigPose { index: 0, .. } if self.faults.stall_after_first_pose => self.rig.stall(true),
            Report::RigPose { index, .. } if self.faults.slip_after_pose == Some(index) => {
                self.rig.slip(Vector3::new(1.0, 0.4, 0.2), 3.0, 0.3)
            }
            Report::Failed(e) => self.out.error = Some(e),
            _ => {}
        }
        self.out.reports.push(*r);
    }

    fn store(&mut self, r: &Record) -> Result<(), StoreError> {
        match self.faults.store_fails {
            Some(e) => Err(e),
            None => {
                self.out.stored.push(*r);
                Ok(())
            }
        }
    }

    fn apply(&mut self, r: &Record) {
        self.out.applied.push(*r);
    }
}

/// Runs `proc` on `rig` until it is done or failed (or `max_s` of MCU time passed).
/// `log` sees every delivered sample with the commanded rotation and tilt angles.
pub fn run(rig: &mut Rig, proc: &mut Procedure, faults: Faults, max_s: f64, log: impl FnMut(&Reading, Option<f32>, Option<f32>)) -> Run {
    let attitudes = operator_attitudes(rig.operator_rng());
    run_posed(rig, proc, faults, max_s, attitudes, log)
}

/// A fresh rig (seed 5) and procedure, with the operator holding the board at `attitude(i)`
/// (body → world) for hand-held pose `i` instead of the icosahedron's.
pub fn run_with_attitudes(cfg: RigConfig, pcfg: Config, attitude: impl Fn(usize) -> UnitQuaternion<f64>) -> Run {
    let mut rig = Rig::new(cfg, 5);
    let mut p = Procedure::new(pcfg, None);
    run_posed(&mut rig, &mut p, Faults::default(), 900.0, (0..40).map(attitude).collect(), |_, _, _| {})
}

fn run_posed(
    rig: &mut Rig,
    proc: &mut Procedure,
    faults: Faults,
    max_s: f64,
    attitudes: Vec<UnitQuaternion<f64>>,
    mut log: impl FnMut(&Reading, Option<f32>, Option<f32>),
) -> Run {
    let mut out = Run::default();
    let mut last_bump = f64::NEG_INFINITY;
    let mut started = false;
    let mut samples = 0;
    let (mut lost_reported, mut undrained) = (false, 0usize);
    let (mut last_servo_deg, mut was_moving, mut out_clips) = (None, false, 0usize);
    let mut b = SimBoard { rig, out: &mut out, faults, attitudes, next_pose: 0, handheld: false, press_at: Some(PRESS_AT_S), t: 0.0 };
    b.rig.stall_tilt(faults.tilt_stalled);
    while b.t < max_s {
        let stopped = faults.sensor_stops_at_s.is_some_and(|ts| b.t >= ts);
        if stopped {
            b.t += 0.01;
            proc.handle_tick(at(b.t));
        } else {
            let s = b.rig.next_sample();
            b.t = s.t_s;
            log(&s, proc.servo_deg(), proc.tilt_deg());
            let mut input = to_input(&s);
            if faults.lsm9ds1_unmapped {
                (input.accel_g, input.gyro_dps) = (Lsm9ds1Model::raw_axes(input.accel_g), Lsm9ds1Model::raw_axes(input.gyro_dps));
            }
            if let Some(clip_g) = faults.accel_clip_in_moves {
                // A rig move: the servo's angle changing; a hand's: the gyro above 20 °/s.
                let servo_deg = proc.servo_deg();
                let moving = match proc.phase() {
                    Phase::RigPoses => last_servo_deg.is_some() && servo_deg != last_servo_deg,
                    Phase::HandHeld => input.gyro_dps.iter().any(|v| v.abs() > 20.0),
                    _ => false,
                };
                if moving && !was_moving {
                    input.accel_g[2] = clip_g;
                    out_clips += 1;
                }
                (last_servo_deg, was_moving) = (servo_deg, moving);
            }
            if let Some(n) = faults.temp_missing_every {
                input.temp_c = match samples % n.max(1) {
                    0 => None,
                    1 => Some(f32::NAN),
                    _ => input.temp_c,
                };
            }
            // A field reading enters before its sample, as the firmware feeds them (as logged);
            // its commands (a failure's, at most 4) are drained with the sample's below.
            if let Some(m) = s.mag_ut {
                proc.handle_mag(calib_core::formats::log::mag_as_logged(m));
            }
            proc.handle_sample(&input);
            proc.handle_tick(at(s.t_s));
            samples += 1;
        }
        if !lost_reported && faults.samples_lost_in == Some(proc.phase()) {
            lost_reported = true;
            proc.handle_samples_lost(1);
        }
        if let Some((phase, n)) = faults.no_drain_in {
            if undrained < n && (undrained > 0 || proc.phase() == phase) {
                undrained += 1;
                continue;
            }
        }
        proc.drive(at(b.t), &mut b);
        if b.press_at.is_some_and(|tp| b.t >= tp) {
            b.press_at = None;
            started = true;
            proc.handle_button(at(b.t));
            proc.drive(at(b.t), &mut b);
        }
        if faults.disturb_rig_poses && proc.phase() == Phase::RigPoses && b.t - last_bump > 1.6 {
            b.rig.disturb(0.3, 20.0);
            last_bump = b.t;
        }
        if started && matches!(proc.phase(), Phase::Done | Phase::Failed) {
            break;
        }
    }
    let t = b.t;
    out.samples = samples;
    out.end_s = t;
    out.accel_clips = out_clips;
    out
}

/// The log's header for a rig: with the magnetometer's columns when it has one, then the
/// temperature's.
pub fn log_header(cfg: &RigConfig) -> String {
    match cfg.mag {
        Some(_) => log::HEADER_RAW.to_string(),
        None => format!("{},{}", log::HEADER, log::TEMP_COLUMN),
    }
}

/// Appends a row (its magnetometer fields when the log has them, its temperature) and its
/// newline.
pub fn write_log_row(text: &mut String, row: &Row, mag: bool) {
    let _ = log::write_row(text, row);
    if mag {
        let _ = log::write_mag(text, row.mag_ut);
    }
    let _ = log::write_temp(text, row.temp_c);
    text.push('\n');
}

/// A reading as a log's row holds it, with the commanded servo angles.
pub fn log_row(s: &Reading, servo_deg: Option<f32>, tilt_deg: Option<f32>) -> Row {
    Row { servo_deg, tilt_deg, mag_ut: s.mag_ut, temp_c: to_input(s).temp_c, ..bare_row(s) }
}

/// A reading's time, accelerometer and gyro as a row, nothing else (no servo, field or
/// temperature).
pub fn bare_row(s: &Reading) -> Row {
    Row { t: at(s.t_s), accel_g: s.accel_g, gyro_dps: s.gyro_dps, servo_deg: None, tilt_deg: None, mag_ut: None, temp_c: None }
}

/// Runs like [`run`] and records the log ([`calib_core::formats::log`], `comments` first).
pub fn record_log(rig: &mut Rig, proc: &mut Procedure, faults: Faults, comments: &str) -> (String, Run) {
    let mag = rig.config().mag.is_some();
    let mut text = format!("{comments}{}\n", log_header(rig.config()));
    let out = run(rig, proc, faults, 900.0, |s, servo_deg, tilt_deg| {
        write_log_row(&mut text, &log_row(s, servo_deg, tilt_deg), mag);
    });
    (text, out)
}

/// A plausible record (a sweep `K` near 1, an identity accelerometer) with sequence number
/// `seq`, for the storage and boot tests.
pub fn record(seq: u32) -> Record {
    Record {
        seq,
        temp_c: Some(24.0),
        gyro_k: [[1.0 + (seq % 100) as f32 * 1e-3, 0.0, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.01]],
        gyro_bias_dps: [0.1, -0.2, 0.3],
        method: calib_core::estimators::gyro::Method::Sweep,
        accel_m: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        accel_offset_g: [0.0; 3],
        accel_model: calib_core::estimators::accel::AccelModel::NineParam,
        poses: 13,
        rows: 12,
        sigma_k: [[1e-4, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 0.0, 1e-4]],
        invariant_before_rel: 0.01,
        invariant_after_rel: 0.001,
        condition: 2.0,
        tilt_deg: 40.0,
        span_deg: 180.0,
        accel_rms_g: 1e-4,
        residual_rms: 0.01,
        non_coplanar_deg: 0.0,
        setup: calib_core::formats::record::SensorSetup::DEFAULT,
        tempco: None,
        mag: None,
    }
}
