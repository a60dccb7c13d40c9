//! The calibration procedure as a pure state machine (sans-IO): fed timestamped samples, button
//! presses and timer ticks, it returns commands (servo, LED, report, store, apply). No I/O, no
//! allocation, bounded work per input. The firmware and the host tests drive the same machine.
//!
//! Phases: wait for rest → gyro bias → accelerometer (hand-held poses, skipped when a valid
//! stored calibration exists; every move between two of them is kept as a rotation constraint,
//! [`crate::rotation`]) → re-clamp and press → static rig poses and the moves between them,
//! there and back → the paper's constant-rate rotation → both one-axis estimators, and with
//! hand-held moves the full 3×3 `K` from the rig's axis and the rotations → validate → store →
//! (verified) report → apply.
//!
//! With a pan/tilt bracket ([`Config::pan_tilt`]): wait for rest → gyro bias → the rig poses,
//! there and back across the pan range at every tilt setting, tilt moves between the settings
//! at pan `pose_first_deg` and back down through them → the accelerometer fitted to those
//! poses → the full 3×3 `K` ([`crate::full`]), the sweep estimator of the most oblique pan axis
//! beside it → validate → store → report → apply. No user action after the press.
//!
//! Contract: after every `handle_*` call, drain [`Procedure::poll`] until it returns `None`
//! (one call queues at most 10 commands; the queue holds 16). A full queue fails the
//! calibration with [`Error::CommandQueueFull`] at the end of the call that overflowed it, after
//! every other state change of that call: the queue is emptied (a pending store with it) and
//! holds only the failure's commands, so no store follows a failure. A [`Command::Store`] is answered with
//! [`Procedure::handle_stored`]; only then are the result reported, applied and shown as done.
//! [`Procedure::drive`] does both for a [`Shell`].

mod command;
mod config;

pub use command::{Command, ErrorClass, Led, Report, Shell};
pub use config::{Config, ServoKind, TILT_SETTINGS};

use crate::accel::{AccelCal, AccelCalibrator, AccelModel};
use crate::axis::Poses;
use crate::bias::{Bias, BiasEstimator};
use crate::full::{Axes, FullAxis, FullCal};
use crate::gyro::{GyroCal, Method};
use crate::pipeline::GravityTurn;
use crate::record::{self, Record, StoreError};
use crate::rest::{RestDetector, RestState, Window};
use crate::rotation::{Rotations, MAX_ROTATION_MOVES};
use crate::stats::Welford3;
use crate::sweep::{Integrator, Moves};
use crate::vec3::{sub, to_f64 as v64};
use crate::{paper, pipeline, sweep, Error, Vec3};
use heapless::Deque;

/// One IMU sample as the shell delivers it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sample {
    /// MCU timestamp (s), from the crystal clock, never from the nominal ODR.
    pub t_s: f64,
    /// Raw accelerometer (g).
    pub accel_g: Vec3,
    /// Raw gyro (°/s).
    pub gyro_dps: Vec3,
    /// Sensor temperature (°C), `None` if it could not be read (a sample needs none).
    pub temp_c: Option<f32>,
}

/// The phase the procedure is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Phase {
    /// Waiting for the button.
    Idle,
    /// Waiting for the rig to be still.
    WaitRest,
    /// Measuring the gyro bias.
    Bias,
    /// Capturing hand-held accelerometer poses.
    HandHeld,
    /// Waiting for the board to be clamped back on the shaft and the button pressed.
    Reattach,
    /// Static rig poses and the moves between them.
    RigPoses,
    /// The paper's constant-rate rotation.
    Rotation,
    /// Waiting for the shell to store the record.
    Store,
    /// Calibration stored and applied.
    Done,
    /// Calibration failed; nothing stored.
    Failed,
}

impl Phase {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Phase::Idle => "idle",
            Phase::WaitRest => "wait-rest",
            Phase::Bias => "bias",
            Phase::HandHeld => "hand-held",
            Phase::Reattach => "reattach",
            Phase::RigPoses => "rig-poses",
            Phase::Rotation => "rotation",
            Phase::Store => "store",
            Phase::Done => "done",
            Phase::Failed => "failed",
        }
    }
}

/// Averages whole still windows into one pose; a disturbed window restarts it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Capture {
    accel: Welford3,
    gyro: Welford3,
    t_first: f64,
    t_last: f64,
    retries: u8,
}

enum CaptureStep {
    Pending,
    Done,
    Disturbed,
}

impl Capture {
    fn feed(&mut self, w: &Window, tainted: bool, need_s: f32) -> CaptureStep {
        if w.still && w.state == RestState::Still && !tainted {
            if self.accel.count() == 0 {
                self.t_first = w.t_start_s;
            }
            self.accel.merge(&w.accel);
            self.gyro.merge(&w.gyro);
            self.t_last = w.t_end_s;
            return if self.t_last - self.t_first >= need_s as f64 { CaptureStep::Done } else { CaptureStep::Pending };
        }
        if self.accel.count() > 0 {
            *self = Capture { retries: self.retries.saturating_add(1), ..Capture::default() };
            return CaptureStep::Disturbed;
        }
        CaptureStep::Pending
    }

    fn accel_mean(&self) -> Vec3 {
        self.accel.mean().map(|v| v as f32)
    }
}

/// A commanded positional ramp (°) in time of servo `channel` (0 rotation, 1 tilt).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ramp {
    channel: u8,
    from_deg: f32,
    to_deg: f32,
    t0: f64,
    duration_s: f64,
}

impl Ramp {
    fn at(&self, t: f64) -> (f32, bool) {
        let x = if self.duration_s > 0.0 { ((t - self.t0) / self.duration_s).clamp(0.0, 1.0) } else { 1.0 };
        (self.from_deg + (self.to_deg - self.from_deg) * x as f32, x >= 1.0)
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Step {
    Idle,
    WaitRest,
    Bias {
        capture: Capture,
    },
    HandHeld {
        capture: Capture,
    },
    Reattach,
    /// Moving to rig step `k` (started at `t0`).
    Move {
        k: u16,
        ramp: Ramp,
    },
    /// Capturing rig step `k`.
    Pose {
        k: u16,
        capture: Capture,
        since: f64,
    },
    /// The paper's constant-rate rotation.
    Rotation {
        rot: Rotation,
    },
    /// `record` was handed to the shell to store; waiting for [`Procedure::handle_stored`].
    Storing {
        record: Record,
    },
    Finished(Phase),
}

/// The paper's rotation: mean bias-free rate over its middle and, for a continuous servo whose
/// speed is unknown, the angle gravity turned about the axis over the same samples.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Rotation {
    ramp: Ramp,
    rate: Welford3,
    gravity: GravityTurn,
}

/// Longest a shell may take to answer a store (s): a page erase and a write take ≈ 0.1 s.
const STORE_TIMEOUT_S: f32 = 5.0;

/// The calibration procedure.
pub struct Procedure {
    cfg: Config,
    stored: Option<Record>,
    step: Step,
    phase_t0: f64,
    last_sample_t: Option<f64>,
    queue: Deque<Command, 16>,
    rest: RestDetector,
    tainted: bool,
    servo_deg: Option<f32>,
    tilt_deg: Option<f32>,
    last_pulse: Option<u16>,
    last_tilt_pulse: Option<u16>,
    bias: Option<Bias>,
    accel_cal: AccelCal,
    accel_poses: AccelCalibrator,
    poses: Poses,
    moves: Moves,
    axes: Axes,
    rotations: Rotations,
    full: Option<FullCal>,
    integ: Integrator,
    gbar: Option<(Vec3, f32)>,
    temp: Welford3,
    /// A command did not fit in the queue during this call ([`Self::settle`]).
    overflow: bool,
}

impl Procedure {
    /// A procedure in `Idle`; `stored` is the valid record found in flash, if any (its
    /// accelerometer calibration is reused and its sequence number continued).
    pub const fn new(cfg: Config, stored: Option<Record>) -> Self {
        Self {
            cfg,
            stored,
            step: Step::Idle,
            phase_t0: 0.0,
            last_sample_t: None,
            queue: Deque::new(),
            rest: RestDetector::new(cfg.rest),
            tainted: false,
            servo_deg: None,
            tilt_deg: None,
            last_pulse: None,
            last_tilt_pulse: None,
            bias: None,
            accel_cal: AccelCal::IDENTITY,
            accel_poses: AccelCalibrator::new(),
            poses: Poses::new(),
            moves: Moves::new(),
            axes: Axes::new(),
            rotations: Rotations::new(),
            full: None,
            integ: Integrator::new(),
            gbar: None,
            temp: Welford3::new(),
            overflow: false,
        }
    }

    /// What a calibration started now asks for: (rig poses, hand-held poses). No hand-held
    /// poses when the stored accelerometer calibration is reused or the pan/tilt plan fits it.
    pub fn plan(&self) -> (u16, u8) {
        let reuse = self.stored.is_some_and(|r| r.accel().model != AccelModel::None);
        let hand = if self.cfg.pan_tilt || reuse { 0 } else { self.cfg.accel_poses.max(6) };
        (self.cfg.plan_steps(), hand)
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        match self.step {
            Step::Idle => Phase::Idle,
            Step::WaitRest => Phase::WaitRest,
            Step::Bias { .. } => Phase::Bias,
            Step::HandHeld { .. } => Phase::HandHeld,
            Step::Reattach => Phase::Reattach,
            Step::Move { .. } | Step::Pose { .. } => Phase::RigPoses,
            Step::Rotation { .. } => Phase::Rotation,
            Step::Storing { .. } => Phase::Store,
            Step::Finished(p) => p,
        }
    }

    /// The commanded rotation-servo angle (°), `None` while no servo is commanded (idle,
    /// hand-held poses): the `servo_deg` column of the raw log. For a continuous servo it is the
    /// nominal angle, commanded speed × time.
    pub fn servo_deg(&self) -> Option<f32> {
        self.servo_deg
    }

    /// The commanded tilt angle (°, 0 = level), `None` without a tilt servo: the optional
    /// `tilt_deg` column of the raw log.
    pub fn tilt_deg(&self) -> Option<f32> {
        self.tilt_deg
    }

    /// The full `K` of the last pan/tilt run with its whole quality report (its axes), once
    /// solved (also when validation then rejected it); [`Report::FullK`] logs its summary.
    pub fn full(&self) -> Option<&FullCal> {
        self.full.as_ref()
    }

    /// Next command for the shell.
    pub fn poll(&mut self) -> Option<Command> {
        self.queue.pop_front()
    }

    /// The button was pressed: starts a calibration (from idle, done or failed) or confirms
    /// that the board is back on the shaft.
    pub fn handle_button(&mut self, t_s: f64) {
        match self.step {
            Step::Idle | Step::Finished(_) => self.start(t_s),
            Step::Reattach => {
                self.begin_rig(t_s);
            }
            _ => {}
        }
        self.settle();
    }

    /// Samples were lost (`count`, at least 1: a FIFO overrun, or a read that failed): every
    /// gyro integral of a running calibration now has a gap, so it fails with
    /// [`Error::SamplesLost`] (nothing is stored).
    pub fn handle_samples_lost(&mut self, count: u16) {
        if self.running() && !matches!(self.step, Step::Storing { .. }) {
            self.fail(Error::SamplesLost { count });
        }
        self.settle();
    }

    /// The sensor stopped answering (an I2C error): a running calibration fails with
    /// [`Error::SensorFault`].
    pub fn handle_sensor_fault(&mut self) {
        if self.running() && !matches!(self.step, Step::Storing { .. }) {
            self.fail(Error::SensorFault);
        }
        self.settle();
    }

    /// Ends every `handle_*` call: a queue that overflowed during it is emptied and the
    /// calibration failed, as the call's last state change.
    fn settle(&mut self) {
        if core::mem::take(&mut self.overflow) {
            self.queue.clear();
            self.fail(Error::CommandQueueFull);
        }
    }

    /// Timer tick without a sample: detects a sensor that stopped and phase timeouts.
    pub fn handle_tick(&mut self, t_s: f64) {
        self.tick(t_s);
        self.settle();
    }

    fn tick(&mut self, t_s: f64) {
        if !self.running() {
            return;
        }
        // Storing needs no samples (and follows the solve, the longest call).
        if let (Some(last), false) = (self.last_sample_t, matches!(self.step, Step::Storing { .. })) {
            let gap = t_s - last;
            if gap > self.cfg.sample_timeout_s as f64 {
                return self.fail(Error::SensorTimeout { gap_s: gap as f32 });
            }
        }
        self.check_timeout(t_s);
    }

    /// A sensor sample. (Never inlined, so that its cost per sample can be measured on the
    /// emulated MCU.)
    #[inline(never)]
    pub fn handle_sample(&mut self, s: &Sample) {
        self.sample(s);
        self.settle();
    }

    fn sample(&mut self, s: &Sample) {
        if !self.running() {
            return;
        }
        let finite = s.accel_g.iter().chain(s.gyro_dps.iter()).all(|v| v.is_finite()) && s.t_s.is_finite();
        if !finite {
            return self.fail(Error::NonFinite);
        }
        if let Some(last) = self.last_sample_t {
            if !(s.t_s > last) {
                return; // duplicate or out-of-order timestamp: dropped
            }
        }
        self.last_sample_t = Some(s.t_s);
        let saturated = s.accel_g.iter().any(|v| v.abs() >= 0.98 * self.cfg.accel_range_g)
            || s.gyro_dps.iter().any(|v| v.abs() >= 0.98 * self.cfg.gyro_range_dps);
        self.tainted |= saturated;
        let window = self.rest.update(s.t_s, s.accel_g, s.gyro_dps);
        let tainted = self.tainted;
        if window.is_some() {
            self.tainted = false;
        }
        let g = self.bias.map_or(s.gyro_dps, |b| sub(s.gyro_dps, b.bias_dps));
        if let Some(t) = s.temp_c.filter(|t| t.is_finite()) {
            self.temp.add([t, 0.0, 0.0]);
        }
        match self.step {
            Step::Idle | Step::Finished(_) | Step::Reattach | Step::Storing { .. } => {}
            Step::WaitRest => {
                if self.rest.state() == RestState::Still {
                    if self.bias.is_none() {
                        self.enter(Step::Bias { capture: Capture::default() }, s.t_s);
                    } else {
                        self.enter(Step::Pose { k: 0, capture: Capture::default(), since: s.t_s }, s.t_s);
                    }
                }
            }
            Step::Bias { mut capture } => {
                if let Some(w) = window {
                    match capture.feed(&w, tainted, self.cfg.bias_s) {
                        CaptureStep::Pending => self.step = Step::Bias { capture },
                        CaptureStep::Disturbed => self.retake(0, capture, |c| Step::Bias { capture: c }),
                        CaptureStep::Done => self.finish_bias(&capture, s.t_s),
                    }
                }
            }
            Step::HandHeld { mut capture } => {
                self.rotations.add(s.t_s, g, saturated);
                if let Some(w) = window {
                    match capture.feed(&w, tainted, self.cfg.pose_average_s) {
                        CaptureStep::Done => self.finish_accel_pose(&capture, s.t_s),
                        // A disturbed hand-held pose is simply taken again: the user is moving it.
                        CaptureStep::Pending | CaptureStep::Disturbed => self.step = Step::HandHeld { capture },
                    }
                }
            }
            Step::Move { k, ramp } => {
                if saturated {
                    return self.fail(Error::Saturated);
                }
                self.integ.add(s.t_s, g);
                let (deg, done) = ramp.at(s.t_s);
                if ramp.channel == 1 {
                    self.set_tilt(deg);
                } else {
                    self.set_angle(deg);
                }
                if done {
                    if let (ServoKind::Continuous { .. }, 0) = (self.cfg.servo, ramp.channel) {
                        self.push(Command::ServoOff { channel: 0 });
                    }
                    self.step = Step::Pose { k, capture: Capture::default(), since: s.t_s };
                }
            }
            Step::Pose { k, mut capture, since } => {
                if saturated {
                    // The shaft may still be settling: a clipped sample corrupts the move's integral.
                    return self.fail(Error::Saturated);
                }
                self.integ.add(s.t_s, g);
                if let Some(w) = window {
                    match capture.feed(&w, tainted, self.cfg.pose_average_s) {
                        CaptureStep::Pending => self.step = Step::Pose { k, capture, since },
                        CaptureStep::Disturbed => self.retake(k.min(255) as u8, capture, |c| Step::Pose { k, capture: c, since }),
                        CaptureStep::Done => self.finish_pose(k, &capture, s),
                    }
                }
            }
            Step::Rotation { mut rot } => {
                if saturated {
                    return self.fail(Error::Saturated);
                }
                let elapsed = s.t_s - rot.ramp.t0;
                let duration = rot.ramp.duration_s;
                self.set_angle(rot.ramp.at(s.t_s).0);
                if self.cfg.steady.averaged(elapsed, duration) {
                    rot.rate.add(g);
                    rot.gravity.add(s.t_s, self.accel_cal.apply(s.accel_g));
                }
                if elapsed >= duration {
                    self.finish_rotation(&rot, s.t_s);
                } else {
                    self.step = Step::Rotation { rot };
                }
            }
        }
        self.check_timeout(s.t_s);
    }

    fn running(&self) -> bool {
        !matches!(self.step, Step::Idle | Step::Finished(_))
    }

    fn push(&mut self, c: Command) {
        // Bounded by the contract (≤ 10 per call, drained after each). A shell that breaks it
        // fails the calibration when the call ends ([`Self::settle`]).
        if self.queue.push_back(c).is_err() {
            self.overflow = true;
        }
    }

    fn start(&mut self, t_s: f64) {
        // Cleared in place: no second copy of the (large) state on the stack.
        self.last_sample_t = None;
        self.rest.reset();
        self.tainted = false;
        self.servo_deg = None;
        self.tilt_deg = None;
        self.last_pulse = None;
        self.last_tilt_pulse = None;
        self.bias = None;
        self.accel_cal = AccelCal::IDENTITY;
        self.accel_poses.clear();
        self.poses.clear();
        self.moves.clear();
        self.axes.clear();
        self.rotations.clear();
        self.full = None;
        self.integ = Integrator::new();
        self.gbar = None;
        self.temp = Welford3::new();
        if let Some(acc) = self.stored.map(|r| r.accel()).filter(|a| a.model != AccelModel::None) {
            self.accel_cal = acc;
        }
        self.park_servo();
        self.enter(Step::WaitRest, t_s);
    }

    fn park_servo(&mut self) {
        if let ServoKind::Continuous { .. } = self.cfg.servo {
            self.push(Command::ServoOff { channel: 0 });
        }
        self.set_angle(self.cfg.pose_first_deg);
        if self.cfg.pan_tilt {
            self.set_tilt(self.cfg.tilt_settings_deg[0]);
        }
    }

    /// Sets the commanded angle (°): drives a positional servo; for a continuous servo it is
    /// only the nominal angle (commanded speed × time) logged in the `servo_deg` column.
    fn set_angle(&mut self, deg: f32) {
        self.servo_deg = Some(deg);
        if let ServoKind::Positional = self.cfg.servo {
            let pulse = self.cfg.pulse_for_deg(deg);
            if self.last_pulse != Some(pulse) {
                self.last_pulse = Some(pulse);
                self.push(Command::Servo { channel: 0, pulse_us: pulse });
            }
        }
    }

    /// Starts a commanded turn from the current angle: a positional ramp to `to_deg` at
    /// `rate_dps`, or a continuous servo at speed `dir` (±1) for `secs`.
    fn start_ramp(&mut self, t_s: f64, to_deg: f32, rate_dps: f32, dir: f32, secs: f32) -> Ramp {
        let from_deg = self.servo_deg.unwrap_or(self.cfg.pose_first_deg);
        match self.cfg.servo {
            ServoKind::Positional => {
                Ramp { channel: 0, from_deg, to_deg, t0: t_s, duration_s: ((to_deg - from_deg).abs() / rate_dps.max(1.0)) as f64 }
            }
            ServoKind::Continuous { neutral_us, span_us, speed, nominal_rate_dps, .. } => {
                let pulse = self.cfg.clamp_pulse(neutral_us as f32 + dir * speed * span_us as f32);
                self.push(Command::Servo { channel: 0, pulse_us: pulse });
                Ramp { channel: 0, from_deg, to_deg: from_deg + dir * nominal_rate_dps * secs, t0: t_s, duration_s: secs as f64 }
            }
        }
    }

    fn enter(&mut self, step: Step, t_s: f64) {
        self.step = step;
        self.phase_t0 = t_s;
        let phase = self.phase();
        self.push(Command::Report(Report::Phase(phase)));
        let led = match phase {
            Phase::HandHeld | Phase::Reattach => Led::WaitUser,
            p => Led::Busy(p),
        };
        self.push(Command::Led(led));
    }

    fn fail(&mut self, e: Error) {
        self.step = Step::Finished(Phase::Failed);
        self.last_pulse = None;
        self.push(Command::ServoOff { channel: 0 });
        if self.cfg.pan_tilt {
            self.last_tilt_pulse = None;
            self.push(Command::ServoOff { channel: 1 });
        }
        self.servo_deg = None;
        self.push(Command::Report(Report::Failed(e)));
        self.push(Command::Led(Led::Error(ErrorClass::of(&e))));
    }

    fn retake(&mut self, index: u8, capture: Capture, back: impl Fn(Capture) -> Step) {
        if capture.retries > self.cfg.pose_retries {
            return self.fail(Error::PoseDisturbed { index, retries: capture.retries });
        }
        self.push(Command::Report(Report::Retake { index, retries: capture.retries }));
        self.step = back(capture);
    }

    fn check_timeout(&mut self, t_s: f64) {
        let c = &self.cfg;
        let (since, limit) = match self.step {
            Step::WaitRest | Step::Bias { .. } => (self.phase_t0, c.rest_timeout_s + c.bias_s),
            Step::HandHeld { .. } => (self.phase_t0, c.handheld_timeout_s),
            Step::Reattach => (self.phase_t0, c.reattach_timeout_s),
            Step::Move { ramp, .. } => (ramp.t0, ramp.duration_s as f32 + c.rest_timeout_s),
            Step::Pose { since, .. } => (since, c.rest_timeout_s + c.pose_average_s),
            Step::Rotation { rot } => (rot.ramp.t0, rot.ramp.duration_s as f32 + c.rest_timeout_s),
            Step::Storing { .. } => (self.phase_t0, STORE_TIMEOUT_S),
            Step::Idle | Step::Finished(_) => return,
        };
        if t_s - since > limit as f64 {
            let phase = self.phase();
            self.fail(Error::PhaseTimeout { phase, limit_s: limit });
        }
    }

    fn finish_bias(&mut self, capture: &Capture, t_s: f64) {
        let mut est = BiasEstimator::new();
        est.add_window(&capture.gyro, &capture.accel);
        match est.finish(&self.cfg.bias) {
            Ok(b) => {
                self.bias = Some(b);
                self.push(Command::Report(Report::Bias(b)));
                // The pan/tilt plan fits the accelerometer to its own rig poses.
                if self.cfg.pan_tilt {
                    self.begin_rig(t_s);
                } else if self.accel_cal.model == AccelModel::None {
                    self.servo_deg = None;
                    self.last_pulse = None;
                    self.push(Command::ServoOff { channel: 0 });
                    self.enter(Step::HandHeld { capture: Capture::default() }, t_s);
                } else {
                    self.begin_rig(t_s);
                }
            }
            Err(e) => self.fail(e),
        }
    }

    fn finish_accel_pose(&mut self, capture: &Capture, t_s: f64) {
        let a = capture.accel_mean();
        let min_sep = self.cfg.accel_min_separation_deg as f64;
        let new = v64(a);
        let distinct = (0..self.accel_poses.len()).all(|i| {
            let old = self.accel_poses.pose(i);
            libm::atan2(old.cross(&new).norm(), old.dot(&new)).to_degrees() >= min_sep
        });
        self.step = Step::HandHeld { capture: Capture::default() };
        if !distinct {
            return;
        }
        if let Err(e) = self.accel_poses.add_pose(a) {
            return self.fail(e);
        }
        let index = (self.accel_poses.len() - 1) as u8;
        self.push(Command::Report(Report::AccelPose { index, accel_g: a }));
        // The move from the previous pose to this one: a rotation constraint on the full K.
        let sigma = capture.accel.max_std_of_mean() as f32;
        let gyro = capture.gyro.mean().map(|v| v as f32);
        let gyro = self.bias.map_or(gyro, |b| sub(gyro, b.bias_dps));
        match self.rotations.push_pose(a, sigma, gyro) {
            Ok(to) if to > 0 => {
                let kept = self.rotations.end(to, &self.cfg.rotation).is_ok();
                let turn_deg = self.rotations.moves().last().filter(|_| kept).map_or(0.0, |m| m.turn_deg);
                let (spread, need) = (self.rotations.axis_spread(), self.cfg.rotation.min_axis_spread);
                self.push(Command::Report(Report::HandMove { from: to - 1, to, kept, turn_deg, spread, need }));
                self.rotations.begin(to);
            }
            Ok(to) => self.rotations.begin(to),
            Err(e) => return self.fail(e),
        }
        if self.accel_poses.len() < self.cfg.accel_poses.max(6) as usize {
            return;
        }
        // The hand-held moves must turn about three dimensions to give the full K.
        let spread = self.rotations.axis_spread();
        if self.rotations.moves().len() >= 3 && !(spread >= self.cfg.rotation.min_axis_spread) {
            return self.fail(Error::RotationAxesCoplanar { spread, limit: self.cfg.rotation.min_axis_spread });
        }
        match self.fit_accel() {
            Ok(()) => {
                self.rotations.calibrate_poses(&self.accel_cal);
                self.enter(Step::Reattach, t_s)
            }
            Err(e) => self.fail(e),
        }
    }

    /// Fits the accelerometer to the poses (9 parameters from 9 poses on), checks and reports it.
    fn fit_accel(&mut self) -> Result<(), Error> {
        let fit = pipeline::fit_accel(&self.accel_poses, &self.cfg.acceptance)?;
        self.accel_cal = fit;
        self.push(Command::Report(Report::Accel(fit)));
        Ok(())
    }

    /// Sets the commanded tilt (°, 0 = level) and drives the tilt servo (channel 1) there.
    fn set_tilt(&mut self, deg: f32) {
        self.tilt_deg = Some(deg);
        let pulse = self.cfg.pulse_for_deg(deg + 90.0);
        if self.last_tilt_pulse != Some(pulse) {
            self.last_tilt_pulse = Some(pulse);
            self.push(Command::Servo { channel: 1, pulse_us: pulse });
        }
    }

    fn begin_rig(&mut self, t_s: f64) {
        self.rest.reset();
        self.park_servo();
        self.poses.clear();
        self.moves.clear();
        self.axes.clear();
        self.integ = Integrator::new();
        self.enter(Step::WaitRest, t_s);
    }

    fn finish_pose(&mut self, k: u16, capture: &Capture, s: &Sample) {
        let (pan_tilt, (setting, j)) = (self.cfg.pan_tilt, self.cfg.plan_at(k));
        // The pan/tilt plan keeps the raw means: its accelerometer is fitted to them at the end,
        // from the first visit of every pan angle at every setting.
        let a = if pan_tilt { capture.accel_mean() } else { self.accel_cal.apply(capture.accel_mean()) };
        let idx = match if pan_tilt { self.axes.push_pose(a) } else { self.poses.push(a) } {
            Ok(i) => i,
            Err(e) => return self.fail(e),
        };
        let forward_pass = k < self.cfg.rig_steps() * TILT_SETTINGS as u16;
        if pan_tilt && forward_pass && j < self.cfg.pose_count as u16 {
            if let Err(e) = self.accel_poses.add_pose(a) {
                return self.fail(e);
            }
        }
        let servo_deg = self.servo_deg.unwrap_or(f32::NAN);
        self.push(Command::Report(Report::RigPose { index: idx, servo_deg, accel_g: a }));
        if k > 0 {
            let gamma = self.integ.gamma();
            let turned = libm::sqrt(gamma.iter().map(|v| v * v).sum::<f64>()) as f32;
            // Step 0 of a later tilt setting (and every return step) is reached by a tilt move
            // (about the hinge, axis id `TILT_SETTINGS`); every other step by a pan move about
            // the setting's own axis.
            let tilt_move = pan_tilt && j == 0;
            let (channel, commanded) = match self.cfg.servo {
                _ if tilt_move => (1, self.cfg.tilt_settings_deg[setting] - self.cfg.tilt_settings_deg[self.cfg.plan_at(k - 1).0]),
                ServoKind::Positional => (0, self.cfg.step_deg(j) - self.cfg.step_deg(j - 1)),
                ServoKind::Continuous { nominal_rate_dps, move_s, .. } => (0, nominal_rate_dps * move_s),
            };
            if turned < self.cfg.min_turn_fraction * commanded.abs() {
                return self.fail(Error::ServoNotTurning { channel, commanded_deg: commanded.abs(), measured_deg: turned });
            }
            let axis = if tilt_move { TILT_SETTINGS } else { setting } as u8;
            let pushed =
                if pan_tilt { self.axes.push_move(axis, idx - 1, idx, commanded, gamma) } else { self.moves.push(idx - 1, idx, gamma) };
            if let Err(e) = pushed {
                return self.fail(e);
            }
            self.push(Command::Report(Report::Move { from: idx - 1, to: idx, gyro_turn_deg: turned }));
        }
        self.integ = Integrator::new();
        self.integ.add(s.t_s, self.bias.map_or(s.gyro_dps, |b| sub(s.gyro_dps, b.bias_dps)));
        let next = k + 1;
        if next < self.cfg.plan_steps() {
            let (next_setting, nj) = self.cfg.plan_at(next);
            let ramp = if pan_tilt && nj == 0 {
                let (from_deg, to_deg) = (self.cfg.tilt_settings_deg[setting], self.cfg.tilt_settings_deg[next_setting]);
                let duration_s = ((to_deg - from_deg).abs() / self.cfg.move_rate_dps.max(1.0)) as f64;
                Ramp { channel: 1, from_deg, to_deg, t0: s.t_s, duration_s }
            } else {
                // Forward over the first half of each round trip, back over the second.
                let forward = self.cfg.pose_slot(nj) > self.cfg.pose_slot(j);
                let move_s = if let ServoKind::Continuous { move_s, .. } = self.cfg.servo { move_s } else { 0.0 };
                let dir = if forward { 1.0 } else { -1.0 };
                self.start_ramp(s.t_s, self.cfg.step_deg(nj), self.cfg.move_rate_dps, dir, move_s)
            };
            self.step = Step::Move { k: next, ramp };
        } else if pan_tilt {
            self.solve_full(s.t_s);
        } else if self.cfg.rotation_rate_dps > 0.0 {
            let ramp = self.start_ramp(s.t_s, self.cfg.pose_last_deg, self.cfg.rotation_rate_dps, 1.0, self.cfg.rotation_s);
            let axis = self.poses.geometry(&self.cfg.geometry, false).ok().map(|g| g.u);
            let rot = Rotation { ramp, rate: Welford3::new(), gravity: GravityTurn::new(axis) };
            self.enter(Step::Rotation { rot }, s.t_s);
        } else {
            self.solve(s.t_s);
        }
    }

    /// The end of the pan/tilt plan: the accelerometer from the rig poses, the poses calibrated
    /// with it, the full `K`, and beside it the one-axis sweep estimator of the tilt setting whose
    /// pan axis is the most oblique to the sensor axes.
    fn solve_full(&mut self, t_s: f64) {
        if let Err(e) = self.fit_accel() {
            // Poses too little spread for the accelerometer: the rig's geometry, seen on the raw
            // poses, says what to change (an upright bracket's pan axis is vertical; coplanar
            // axes); else the fit's own error.
            let vertical = |g| match g {
                Err(e @ Error::AxisNearVertical { .. }) => Err(e),
                _ => Ok(()),
            };
            let geometry = self
                .load_setting(0)
                .and_then(|_| vertical(self.poses.geometry(&self.cfg.geometry, false)))
                .and_then(|_| self.axes.solve(&self.cfg.full).map(|_| ()));
            return self.fail(geometry.err().unwrap_or(e));
        }
        self.axes.calibrate_poses(&self.accel_cal);
        let full = self.axes.solve(&self.cfg.full);
        let oblique = |a: &FullAxis| a.u.iter().fold(f32::INFINITY, |m, c| m.min(c.abs()));
        let setting = match &full {
            Ok(f) => (0..TILT_SETTINGS).max_by(|&a, &b| oblique(&f.axes[a]).total_cmp(&oblique(&f.axes[b]))).unwrap_or(0),
            Err(_) => 0,
        };
        if let Err(e) = self.one_axis_beside(setting) {
            return self.fail(e);
        }
        self.store_full(full, t_s);
    }

    /// Reports a full `K` (or fails with why there is none), validates it and hands its record
    /// to the shell.
    fn store_full(&mut self, full: Result<FullCal, Error>, t_s: f64) {
        let full = match full {
            Ok(f) => f,
            Err(e) => return self.fail(e),
        };
        self.full = Some(full);
        self.push(Command::Report(Report::FullK {
            k: full.k,
            sigma_k: full.sigma_k,
            condition: full.condition,
            non_coplanar_deg: full.non_coplanar_deg,
            residual_rms_deg: full.residual_rms_deg,
            axes: full.n_axes,
            moves: full.moves,
        }));
        if let Err(e) = pipeline::validate_full(&full, &self.cfg.acceptance) {
            return self.fail(e);
        }
        let poses = self.axes.poses().len() as u8;
        let record = self.context().map(|c| c.full(&full, poses));
        self.store(record, t_s);
    }

    /// The poses and pan moves of one tilt setting as a one-axis rig (`poses`, `moves`).
    fn load_setting(&mut self, setting: usize) -> Result<(), Error> {
        self.poses.clear();
        self.moves.clear();
        let per = self.cfg.rig_steps() as usize;
        for p in setting * per..((setting + 1) * per).min(self.axes.poses().len()) {
            let v = self.axes.poses().get(p);
            self.poses.push([v[0] as f32, v[1] as f32, v[2] as f32])?;
        }
        let first = (setting * per) as u8;
        for m in self.axes.moves().iter().filter(|m| m.axis as usize == setting) {
            self.moves.push(m.from - first, m.to - first, m.gamma_deg)?;
        }
        Ok(())
    }

    /// The sweep estimator on the (calibrated) poses and pan moves of one tilt setting, reported
    /// for comparison with the full `K`.
    fn one_axis_beside(&mut self, setting: usize) -> Result<(), Error> {
        self.load_setting(setting)?;
        match sweep::solve(&self.poses, &self.moves, &self.cfg.geometry) {
            Ok(cal) => self.push(Command::Report(Report::Gyro(cal))),
            Err(error) => self.push(Command::Report(Report::EstimatorFailed { method: Method::Sweep, error })),
        }
        Ok(())
    }

    fn finish_rotation(&mut self, rot: &Rotation, t_s: f64) {
        self.push(Command::ServoOff { channel: 0 });
        self.servo_deg = None;
        self.last_pulse = None;
        // A continuous servo's speed is unknown: the rate at which gravity turns about the axis.
        let commanded = matches!(self.cfg.servo, ServoKind::Positional).then_some(self.cfg.rotation_rate_dps);
        let (omega, _) = pipeline::rotation_rate(commanded, &rot.gravity);
        if rot.rate.count() > 0 {
            self.gbar = Some((rot.rate.mean().map(|v| v as f32), omega));
        }
        self.solve(t_s);
    }

    fn solve(&mut self, t_s: f64) {
        let lim = self.cfg.geometry;
        let sweep = sweep::solve(&self.poses, &self.moves, &lim);
        let paper = self.gbar.map(|(g, w)| paper::solve(&self.poses, g, w, &lim));
        for (method, r) in [(Method::Sweep, Some(sweep)), (Method::Paper, paper)] {
            match r {
                Some(Ok(cal)) => self.push(Command::Report(Report::Gyro(cal))),
                Some(Err(error)) => self.push(Command::Report(Report::EstimatorFailed { method, error })),
                None => {}
            }
        }
        // With hand-held moves: the rig's axis and their rotation constraints give the full K.
        if !self.rotations.moves().is_empty() {
            let start = sweep.as_ref().ok().or(paper.as_ref().and_then(|p| p.as_ref().ok()));
            let full = self.full_from_rotations(start);
            // Each move's misfit at the solution (none without one).
            let residual_deg = full.as_ref().map_or([0.0; MAX_ROTATION_MOVES], |f| self.rotations.residuals_deg(&f.k));
            let (moves, rejected) = (self.rotations.moves().len() as u8, self.rotations.rejected());
            self.push(Command::Report(Report::Rotations { moves, rejected, residual_deg }));
            return self.store_full(full, t_s);
        }
        let chosen = match pipeline::choose(sweep, paper).and_then(|c| pipeline::validate(&c, &self.cfg.acceptance).map(|_| c)) {
            Ok(c) => c,
            Err(e) => return self.fail(e),
        };
        let record = self.context().map(|c| c.one_axis(&chosen));
        self.store(record, t_s);
    }

    /// The full `K` from the rig's poses and moves (one axis) and the hand-held rotations,
    /// Gauss–Newton started at the diagonal `K` of the one-axis estimator when there is one.
    fn full_from_rotations(&mut self, start: Option<&GyroCal>) -> Result<FullCal, Error> {
        self.axes.clear();
        for p in self.poses.iter() {
            self.axes.push_pose([p[0] as f32, p[1] as f32, p[2] as f32])?;
        }
        for m in self.moves.as_slice() {
            self.axes.push_move(0, m.from, m.to, 0.0, m.gamma_deg)?;
        }
        let start = start.map(|c| core::array::from_fn(|i| c.k[i % 3][i / 3] as f64));
        self.axes.solve_from(&self.cfg.full, Some((&self.rotations, &self.cfg.rotation)), start)
    }

    /// Hands a built record to the shell to store (or fails with why it could not be built).
    fn store(&mut self, record: Result<Record, Error>, t_s: f64) {
        match record {
            Ok(record) => {
                self.enter(Step::Storing { record }, t_s);
                self.push(Command::Store(record));
            }
            Err(e) => self.fail(e),
        }
    }

    /// The shell's answer to [`Command::Store`]: only a verified store reports the result,
    /// applies it, shows it as done and moves the sequence number on; a failed one fails the
    /// calibration with [`Error::Storage`] (the previous record stays in use).
    pub fn handle_stored(&mut self, t_s: f64, result: Result<(), StoreError>) {
        self.stored_answer(t_s, result);
        self.settle();
    }

    fn stored_answer(&mut self, t_s: f64, result: Result<(), StoreError>) {
        let Step::Storing { record } = self.step else { return };
        match result {
            Ok(()) => {
                self.stored = Some(record);
                self.phase_t0 = t_s;
                self.step = Step::Finished(Phase::Done);
                self.push(Command::Report(Report::Done(record)));
                self.push(Command::Apply(record));
                self.push(Command::Led(Led::Done));
            }
            Err(e) => self.fail(Error::Storage(e)),
        }
    }

    /// Drains the commands into `shell`, answering each store with [`Self::handle_stored`]
    /// (the one dispatch loop of every shell). Call after every `handle_*`.
    pub fn drive(&mut self, t_s: f64, shell: &mut impl Shell) {
        while let Some(c) = self.poll() {
            match c {
                Command::Servo { channel, pulse_us } => shell.servo(channel, pulse_us),
                Command::ServoOff { channel } => shell.servo_off(channel),
                Command::Led(l) => shell.led(l),
                Command::Report(r) => shell.report(&r),
                Command::Store(rec) => {
                    let result = shell.store(&rec);
                    self.handle_stored(t_s, result);
                }
                Command::Apply(rec) => shell.apply(&rec),
            }
        }
    }

    /// The record's calibration-independent part (sequence, temperature, bias, accelerometer).
    fn context(&self) -> Result<record::Context, Error> {
        if self.temp.count() == 0 {
            return Err(Error::NoTemperature);
        }
        Ok(record::Context {
            seq: self.stored.map_or(1, |r| r.seq.wrapping_add(1)),
            temp_c: self.temp.mean()[0] as f32,
            gyro_bias_dps: self.bias.map_or([0.0; 3], |b| b.bias_dps),
            accel: self.accel_cal,
        })
    }
}
