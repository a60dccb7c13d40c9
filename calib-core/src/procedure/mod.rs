//! The calibration procedure as a pure state machine (sans-IO): fed timestamped samples, button
//! presses and timer ticks, it returns commands (servo, LED, report, store, apply). No I/O, no
//! allocation, bounded work per input. The firmware and the host tests drive the same machine.
//!
//! Phases: wait for rest → gyro bias → accelerometer (hand-held poses, skipped when a valid
//! stored calibration exists; every move between two of them is kept as a rotation constraint,
//! [`crate::estimators::rotation`]) → re-clamp and press → static rig poses and the moves between them,
//! there and back → the paper's constant-rate spin → both one-axis estimators, and with
//! hand-held moves the full 3×3 `K` from the rig's axis and the rotations → validate → store →
//! (verified) report → apply.
//!
//! With a pan/tilt bracket ([`Config::pan_tilt`]): wait for rest → gyro bias → the rig poses,
//! there and back across the pan range at every tilt setting, tilt moves between the settings
//! at pan `pose_first_deg` and back down through them → the accelerometer fitted to those
//! poses → the full 3×3 `K` ([`crate::estimators::full`]), the sweep estimator of the most oblique pan axis
//! beside it → validate → store → report → apply. No user action after the press.
//!
//! Contract: after every `handle_*` call, drain [`Procedure::poll`] until it returns `None`
//! (one call queues at most 10 commands, 9 measured at the pan/tilt plan's end; the queue holds
//! [`QUEUE`]). A full queue fails the
//! calibration with [`Error::CommandQueueFull`] at the end of the call that overflowed it, after
//! every other state change of that call: the queue is emptied (a pending store with it) and
//! holds only the failure's commands, so no store follows a failure (nor does one a failure
//! overtook before the shell polled: the queue holds no record, [`Procedure::poll`] takes it
//! from the store under way). A [`Command::Store`] is answered with
//! [`Procedure::handle_stored`]; only then are the result reported, applied and shown as done.
//! [`Procedure::drive`] does both for a [`Shell`].

use crate::math::real::Real;
mod command;
mod config;
mod handheld;
pub mod pipeline;
mod rig;
mod solve;

pub use command::{Command, ErrorClass, Led, Report, Shell};
pub use config::{Config, ServoKind, TILT_SETTINGS};

use crate::estimators::accel::{AccelCal, AccelCalibrator, AccelModel, Params};
use crate::estimators::axis::Poses;
use crate::estimators::bias::{Bias, BiasEstimator, Drift, RestBias, TempFit};
use crate::estimators::full::{self, Axes, FullAxis, FullCal, RigPart, RotationFit, GAUSS_NEWTON_ITERATIONS};
use crate::estimators::gyro::Method;
use crate::estimators::mag::{ellipsoid_from, Alignment, Ellipsoid, MagCal, MagCalibrator, MagLimits};
use crate::estimators::rest::{RestDetector, RestState, Window};
use crate::estimators::rotation::{self, PoseRest, PoseTurn, Rotations, RowSum, MAX_ROTATION_MOVES};
use crate::estimators::sweep;
use crate::estimators::sweep::{Integrator, Moves};
use crate::formats::record::{self, Record, SensorSetup, StoreError};
use crate::math::lsq::NormalEquations;
use crate::math::stats::{Mean, Moments3};
use crate::math::vec3::{sub, to_real as v64};
use crate::procedure::pipeline::{GravityTurn, OneAxis};
use crate::{Error, Time, Vec3};
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use heapless::Deque;
use nalgebra::{Matrix3, Vector3};

/// One IMU sample as the shell delivers it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sample {
    /// MCU timestamp, from the crystal clock, never from the nominal ODR.
    pub t: Time,
    /// Raw accelerometer (g).
    pub accel_g: Vec3,
    /// Raw gyro (°/s).
    pub gyro_dps: Vec3,
    /// Sensor temperature (°C), `None` if it could not be read (a sample needs none).
    pub temp_c: Option<f32>,
}

/// A change refused because a calibration is running.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Running;

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
    /// The paper's constant-rate spin.
    Spin,
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
            Phase::Spin => "spin",
            Phase::Store => "store",
            Phase::Done => "done",
            Phase::Failed => "failed",
        }
    }
}

/// Averages whole still windows into one pose; a disturbed window restarts it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Capture {
    accel: Moments3,
    gyro: Moments3,
    /// Temperature (°C) of the samples of its windows that had one.
    temp: Mean,
    /// Magnetometer readings (raw, µT) during its windows.
    mag: Moments3,
    /// The bias-free gyro turn over its windows (hand-held poses: the sway inside the pose).
    turn: PoseTurn,
    t_first: Time,
    t_last: Time,
    retries: u8,
}

/// What the shell read beside the IMU's samples since the rest detector's last window closed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct WindowReadings {
    /// Temperatures (°C).
    temp: Mean,
    /// Magnetometer readings (raw, µT).
    mag: Moments3,
}

enum CaptureStep {
    Pending,
    Done,
    Disturbed,
}

impl Capture {
    /// A closed window, the temperatures and magnetometer readings taken during it and the
    /// gyro's turn over it.
    fn feed(&mut self, w: &Window, read: &WindowReadings, turn: &PoseTurn, tainted: bool, need_s: f32) -> CaptureStep {
        if w.still && w.state == RestState::Still && !tainted {
            if self.accel.count() == 0 {
                self.t_first = w.t_start;
            }
            self.accel.merge(&w.accel);
            self.gyro.merge(&w.gyro);
            self.temp.merge(&read.temp);
            self.mag.merge(&read.mag);
            self.turn.merge(turn);
            self.t_last = w.t_end;
            return if self.t_last.since(self.t_first) >= need_s as Real { CaptureStep::Done } else { CaptureStep::Pending };
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

    /// Its rest's gyro mean relative to the measured bias.
    fn rest(&self, bias: Option<Bias>) -> RestBias {
        RestBias::new(self.t_first, self.t_last, self.gyro.mean().map(|v| v as f32), bias.map_or([0.0; 3], |b| b.bias_dps))
    }

    /// Its mean temperature (°C; NaN when none was read).
    fn temp_c(&self) -> f32 {
        if self.temp.count() > 0 {
            self.temp.mean()
        } else {
            f32::NAN
        }
    }
}

/// A commanded positional ramp (°) in time of servo `channel` (0 rotation, 1 tilt).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Ramp {
    channel: u8,
    from_deg: f32,
    to_deg: f32,
    t0: Time,
    duration_s: f32,
}

impl Ramp {
    fn at(&self, t: Time) -> (f32, bool) {
        let x = if self.duration_s > 0.0 { (t.since(self.t0) as f32 / self.duration_s).clamp(0.0, 1.0) } else { 1.0 };
        (self.from_deg + (self.to_deg - self.from_deg) * x, x >= 1.0)
    }
}

/// A hand-held pose's end after its sample, one part a tick ([`Procedure::fit_due`]): the move
/// into pose `to` (`rejected`: why it was not kept) joins the rows, then `K`'s 1σ by the moves
/// so far, the report and whether the step goes on. (At 952 Hz the FIFO holds 34 ms: a pose's
/// end in one call outlasted it.)
#[derive(Debug, Clone, Copy, PartialEq)]
enum HandDue {
    None,
    Rows { to: u8, rejected: Option<rotation::Rejected> },
    Report { to: u8, rejected: Option<rotation::Rejected> },
}

/// The accelerometer's fits after the hand-held step, one part a tick ([`Procedure::fit_due`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum AccelFit {
    /// The 9-parameter fit's start (at the first tick; [`AccelCalibrator::start9`]).
    Nine,
    /// Its Gauss–Newton at `p`, one iterate a tick, `left` at most ([`pipeline::nine_params`]
    /// in parts; the procedure's `rows` keep the last iterate's equations).
    NineIter { p: Params, left: u8 },
    /// Its equations' condition number ([`NormalEquations::condition`]: the most of the check).
    NineEnd(Params),
    /// Its calibration from them with it ([`AccelCalibrator::calibration9_given`]).
    NineCal(Params, Real),
    /// The 6-parameter fit and the choice between the two, with the 9-parameter fit if there
    /// is one.
    Choice(Option<AccelCal>),
    /// None due.
    Done,
}

/// The magnetometer's fit after the hand-held step, in parts, one a tick
/// ([`Procedure::fit_due`]): the ellipsoid's rows a batch a call ([`MAG_ROWS_PER_CALL`]
/// points), its alignment, the calibration and its checks.
#[allow(clippy::large_enum_variant)] // inside `Step::Reattach`, smaller than `Step::Solving`: no RAM lost
#[derive(Debug, Clone, Copy, PartialEq)]
enum MagFit {
    /// `stage` next (consulted once the accelerometer's fit is done).
    Due(MagStage),
    /// Made (or nothing to fit).
    Done,
}

#[allow(clippy::large_enum_variant)] // as `MagFit`
#[derive(Debug, Clone, Copy, PartialEq)]
enum MagStage {
    /// The poses into the calibrated accelerometer's frame, the points' centre.
    Start,
    /// The ellipsoid's rows from point `next` on (the procedure's `rows` hold them).
    Rows {
        centre: Vector3<Real>,
        next: u16,
    },
    Align(Ellipsoid),
    Finish(Ellipsoid, Alignment),
}

/// Points of the magnetometer's ellipsoid a call adds to its rows (~0.8 M instructions).
const MAG_ROWS_PER_CALL: usize = 64;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Step {
    Idle,
    WaitRest,
    Bias {
        capture: Capture,
    },
    HandHeld {
        capture: Capture,
        due: HandDue,
    },
    /// Waiting for the board back on the shaft and the button (`pressed`) while the hand-held
    /// step's fits are made ([`Procedure::fit_due`]).
    Reattach {
        accel: AccelFit,
        mag: MagFit,
        pressed: bool,
    },
    /// Moving to rig step `k` (started at `t0`).
    Move {
        k: u16,
        ramp: Ramp,
    },
    /// Capturing rig step `k`.
    Pose {
        k: u16,
        capture: Capture,
        since: Time,
    },
    /// The paper's constant-rate spin.
    Spin {
        spin: Spin,
    },
    /// The full `K` in calls of bounded length ([`Procedure::solve_step`]): at `stage`, its
    /// Gauss–Newton at `k` after `iterations`; the next due at `next` (s) or later.
    Solving {
        stage: SolveStage,
        k: Option<[Real; 9]>,
        iterations: u8,
        next: Time,
    },
    /// `record` was handed to the shell to store; waiting for [`Procedure::handle_stored`].
    Storing {
        record: Record,
    },
    Finished(Phase),
}

/// Where the stepped solve of the full `K` is ([`Step::Solving`]).
#[allow(clippy::large_enum_variant)] // inside `Step`, whose pose captures are larger still: no RAM lost
#[derive(Debug, Clone, Copy, PartialEq)]
enum SolveStage {
    /// The pan/tilt plan's accelerometer, fitted to its rig poses, which it then calibrates,
    /// in parts ([`AccelFit`]'s): the 9-parameter fit's parameters, its calibration, the
    /// choice.
    PanTilt,
    PanTiltNine(Params),
    PanTiltAccel(Option<AccelCal>),
    /// The temperature fit over the rests, and the hand-held moves' chunks made to follow its
    /// warm-up ([`Rotations::follow_warmup`]).
    Warmup,
    /// The diagonal (one-axis) estimators, and the start of the full `K`.
    Diagonal,
    /// A Gauss–Newton iteration: the rig's rows (into [`Procedure::rows`]) and where it
    /// linearises (the step's `k` from then on).
    Iterate,
    /// Its rotation rows, [`ROW_CHUNKS`] chunks of moves a call (`sum` carries their sums on),
    /// and at the last batch the next iterate.
    IterateRows {
        sum: RowSum,
    },
    /// The solve at the last iterate `k` (converged, or the iterations ran out): the rig's rows
    /// (into [`Procedure::rows`]) and the axes' checks; when an iteration `failed`, its error
    /// once the checks (which name a bad geometry better) pass.
    Solve {
        failed: Option<Error>,
    },
    /// The rotation rows at `k`, [`ROW_CHUNKS`] chunks a call.
    SolveRows {
        part: RigPart,
        sum: RowSum,
    },
    /// The solution of the rows and its condition ([`full::solve_k`]); `rotation` what the
    /// rotations gave (none with the pan/tilt plan).
    SolveK {
        part: RigPart,
        rotation: Option<RotationFit>,
    },
    /// The result: the rig's residual and the 1σ of `K` ([`Axes::solve_end`]), from the
    /// solution's parts but its covariance, which is computed again.
    SolveEnd {
        part: RigPart,
        rotation: Option<RotationFit>,
        x: [Real; 9],
        rss: Real,
        dof: u32,
        condition: Real,
    },
    /// Solved (in `full`): the magnetometer's alignment refined with it, its first steps; with
    /// the pan/tilt plan the sweep estimator beside it and the store.
    Store,
    /// The refinement's next step (one a call, `left` of them) from the die's rotation `rot`
    /// the steps before reached.
    RefineMag {
        rot: Matrix3<Real>,
        left: u8,
    },
    /// Each move's misfit reported, the record stored.
    StoreEnd,
}

/// The paper's spin: mean bias-free rate over its middle and, for a continuous servo whose
/// speed is unknown, the angle gravity turned about the axis over the same samples.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Spin {
    ramp: Ramp,
    rate: Moments3,
    gravity: GravityTurn,
}

/// Least time between two steps of the solve (s): the shell reads the sensor's FIFO between
/// them and drains what a step held back (≈ 0.14 s of samples' log rows; a USB port that is
/// polled only between steps drops lines); ≈ 2 s for the whole solve.
pub const SOLVE_STEP_S: Real = 0.25;

/// Longest a shell may take to answer a store (s): a page erase and a write take ≈ 0.1 s.
const STORE_TIMEOUT_S: f32 = 5.0;
/// Chunks of hand-held moves whose rotation rows one call of the solve adds
/// ([`SolveStage::IterateRows`]): ≈ 7 k instructions a chunk on the MCU, with a move's own rows.
const ROW_CHUNKS: usize = 120;
/// Most calls of the one-servo solve ([`SolveStage`]): the warm-up, the diagonal estimators,
/// every Gauss–Newton iteration's rig rows and row batches, the solve's four parts with its
/// batches, the magnetometer's refinement and the store. A batch ends past [`ROW_CHUNKS`]: one
/// more than the chunks fill.
pub const MAX_SOLVE_STEPS: usize = {
    let batches = rotation::MAX_CHUNKS.div_ceil(ROW_CHUNKS) + 1;
    2 + GAUSS_NEWTON_ITERATIONS as usize * (1 + batches) + 3 + batches + 2
};
/// Commands the queue holds (132 B each): one call's at most 10 (module doc) and one spare.
const QUEUE: usize = 11;

/// The calibration procedure.
pub struct Procedure {
    cfg: Config,
    stored: Option<Record>,
    step: Step,
    phase_t0: Time,
    last_sample_t: Option<Time>,
    /// The commands for the shell, their records left out ([`Command::with_record`]).
    queue: Deque<Command<()>, QUEUE>,
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
    /// The normal equations under way: in the hand-held step the kept moves' rows at `K = I`
    /// ([`Rotations::add_last_at_identity`]); then the magnetometer's ellipsoid's
    /// ([`MagStage::Rows`]); in the solve those of its Gauss–Newton iteration,
    /// the rig's and then the rotations' a batch a call ([`SolveStage::IterateRows`]).
    rows: NormalEquations<9>,
    full: Option<FullCal>,
    integ: Integrator,
    /// The rests so far (bias, poses): the bias tracked between them.
    drift: Drift,
    /// The rests' biases against their temperatures.
    temp_fit: TempFit,
    /// The latest rest's mean temperature (°C; NaN unknown).
    rest_temp_c: f32,
    /// Temperatures and magnetometer readings since the rest detector's last window closed.
    window_read: WindowReadings,
    /// The hand-held step's magnetometer readings and still poses.
    mag: MagCalibrator,
    /// The magnetometer's calibration of this run (or the stored one, reused with its
    /// accelerometer's).
    mag_cal: Option<MagCal>,
    /// The hand-held pose number of the magnetometer's first pose.
    mag_first_pose: u8,
    /// The bias-free gyro turn since then (hand-held phase only).
    window_turn: PoseTurn,
    /// The board's attitude from the bias rest to the first rig rest after the hand-held step
    /// (rotation from the body frame to the bias rest's, gyro at `K = I`): the Earth's rate in
    /// the hand-held poses ([`Rotations::push_attitude`]); `None` outside it, or once a gyro
    /// sample saturated or turned more than 0.25 rad from the last (a gap).
    attitude: Option<Matrix3<f32>>,
    gbar: Option<(Vec3, f32)>,
    temp: Mean,
    /// A command did not fit in the queue during this call ([`Self::settle`]).
    overflow: bool,
}

impl Procedure {
    /// A procedure in `Idle`; `stored` is the valid record found in flash, if any (its
    /// accelerometer calibration is reused and its sequence number continued).
    pub const fn new(cfg: Config, stored: Option<Record>) -> Self {
        let mut out = MaybeUninit::uninit();
        Self::init(&mut out, cfg, stored);
        // SAFETY: `init` wrote every field.
        unsafe { out.assume_init() }
    }

    /// [`Self::new`] built in place in `out` (e.g. a static's storage), field by field: the
    /// procedure is ~48 KiB, which a value built first and moved after would take on the stack.
    #[inline(never)]
    pub const fn init(out: &mut MaybeUninit<Self>, cfg: Config, stored: Option<Record>) -> &mut Self {
        let p = out.as_mut_ptr();
        // SAFETY: `p` is valid for writes; every field is written once, so the value is whole.
        unsafe {
            addr_of_mut!((*p).cfg).write(cfg);
            addr_of_mut!((*p).stored).write(stored);
            addr_of_mut!((*p).step).write(Step::Idle);
            addr_of_mut!((*p).phase_t0).write(Time::ZERO);
            addr_of_mut!((*p).last_sample_t).write(None);
            addr_of_mut!((*p).queue).write(Deque::new());
            addr_of_mut!((*p).rest).write(RestDetector::new(cfg.rest));
            addr_of_mut!((*p).tainted).write(false);
            addr_of_mut!((*p).servo_deg).write(None);
            addr_of_mut!((*p).tilt_deg).write(None);
            addr_of_mut!((*p).last_pulse).write(None);
            addr_of_mut!((*p).last_tilt_pulse).write(None);
            addr_of_mut!((*p).bias).write(None);
            addr_of_mut!((*p).accel_cal).write(AccelCal::IDENTITY);
            addr_of_mut!((*p).accel_poses).write(AccelCalibrator::new());
            addr_of_mut!((*p).poses).write(Poses::new());
            addr_of_mut!((*p).moves).write(Moves::new());
            addr_of_mut!((*p).axes).write(Axes::new());
            Rotations::init_in(addr_of_mut!((*p).rotations));
            addr_of_mut!((*p).rows).write(NormalEquations::new());
            addr_of_mut!((*p).full).write(None);
            addr_of_mut!((*p).integ).write(Integrator::new());
            addr_of_mut!((*p).drift).write(Drift::new());
            addr_of_mut!((*p).temp_fit).write(TempFit::new());
            addr_of_mut!((*p).rest_temp_c).write(f32::NAN);
            addr_of_mut!((*p).window_read).write(WindowReadings { temp: Mean::new(), mag: Moments3::new() });
            addr_of_mut!((*p).mag).write(MagCalibrator::new());
            addr_of_mut!((*p).mag_cal).write(None);
            addr_of_mut!((*p).mag_first_pose).write(0);
            addr_of_mut!((*p).window_turn).write(PoseTurn::new());
            addr_of_mut!((*p).attitude).write(None);
            addr_of_mut!((*p).gbar).write(None);
            addr_of_mut!((*p).temp).write(Mean::new());
            addr_of_mut!((*p).overflow).write(false);
            out.assume_init_mut()
        }
    }

    /// The stored record's accelerometer calibration, if it has one made at this setup (one from
    /// another full scale is never reused).
    fn stored_accel(&self) -> Option<AccelCal> {
        self.stored.filter(|r| r.setup == self.cfg.setup).map(|r| r.accel()).filter(|a| a.model != AccelModel::None)
    }

    /// What a calibration started now asks for: (rig poses, hand-held poses). No hand-held
    /// poses when the stored accelerometer calibration is reused or the pan/tilt plan fits it.
    pub fn plan(&self) -> (u16, u8) {
        let reuse = self.stored_accel().is_some();
        let hand = if self.cfg.is_pan_tilt() || reuse { 0 } else { self.cfg.accel_poses.max(6) };
        (self.cfg.plan_steps(), hand)
    }

    /// A record was handed to the shell to store ([`Command::Store`] queued or under way): the
    /// samples are not wanted until it is answered.
    pub fn storing(&self) -> bool {
        matches!(self.step, Step::Storing { .. })
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        match self.step {
            Step::Idle => Phase::Idle,
            Step::WaitRest => Phase::WaitRest,
            Step::Bias { .. } => Phase::Bias,
            Step::HandHeld { .. } => Phase::HandHeld,
            Step::Reattach { .. } => Phase::Reattach,
            Step::Move { .. } | Step::Pose { .. } => Phase::RigPoses,
            Step::Spin { .. } => Phase::Spin,
            Step::Solving { .. } | Step::Storing { .. } => Phase::Store,
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
        let store = match self.step {
            Step::Storing { record } => Some(record),
            _ => None,
        };
        while let Some(c) = self.queue.pop_front() {
            if let Some(c) = c.with_record(store, self.stored) {
                return Some(c);
            }
        }
        None
    }

    /// The button was pressed: starts a calibration (from idle, done or failed) or confirms
    /// that the board is back on the shaft. False: a press that does nothing in this phase (a
    /// calibration is running and not waiting for the re-clamp), for the shell to report.
    pub fn handle_button(&mut self, t: Time) -> bool {
        let acted = match self.step {
            Step::Idle | Step::Finished(_) => {
                self.start(t);
                true
            }
            Step::Reattach { ref mut pressed, .. } => {
                // The rig starts once the hand-held step's fits are made (`fit_due`).
                *pressed = true;
                self.fit_due(t);
                true
            }
            _ => false,
        };
        self.settle();
        acted
    }

    /// The sensor now runs at `setup` (a console command reconfigured it): the calibrations from
    /// now on are made at it and their records say so. Refused while one runs (its samples are at
    /// the setup it started with).
    pub fn handle_setup(&mut self, setup: SensorSetup) -> Result<(), Running> {
        match self.step {
            Step::Idle | Step::Finished(_) => {
                self.cfg.setup = setup;
                Ok(())
            }
            _ => Err(Running),
        }
    }

    /// The sensor setup calibrations are made at.
    pub fn setup(&self) -> SensorSetup {
        self.cfg.setup
    }

    /// Samples were lost (`count`, at least 1: a FIFO overrun, or a read that failed): every
    /// gyro integral of a running calibration now has a gap, so it fails with
    /// [`Error::SamplesLost`] (nothing is stored). Not once every sample is in: solving and
    /// storing use none.
    pub fn handle_samples_lost(&mut self, count: u16) {
        if self.running() && !matches!(self.step, Step::Solving { .. } | Step::Storing { .. }) {
            self.fail(Error::SamplesLost { count });
        }
        self.settle();
    }

    /// The sensor stopped answering (an I2C error): a running calibration fails with
    /// [`Error::SensorFault`] (not while it solves or stores: they need no samples).
    pub fn handle_sensor_fault(&mut self) {
        if self.running() && !matches!(self.step, Step::Solving { .. } | Step::Storing { .. }) {
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

    /// A magnetometer reading (raw, µT, in the accelerometer's axes: the part's axis mapping
    /// applied), read since the last sample. Only the hand-held step uses them, from its first pose on: on
    /// the rig a servo's motor magnet moves with the shaft, and the step's first pose is
    /// usually taken before the board is lifted off it. A non-finite reading fails the
    /// calibration there.
    pub fn handle_mag(&mut self, m_ut: Vec3) {
        if matches!(self.step, Step::HandHeld { .. }) && self.one_servo() && !self.accel_poses.is_empty() {
            match self.mag.add_sample(m_ut) {
                Ok(()) => self.window_read.mag.add(m_ut),
                Err(e) => self.fail(e),
            }
        }
        self.settle();
    }

    /// Timer tick without a sample: detects a sensor that stopped and phase timeouts, and takes
    /// the solve's next step. (Never inlined, so that its longest call can be measured on the
    /// emulated MCU.)
    #[inline(never)]
    pub fn handle_tick(&mut self, t: Time) {
        self.tick(t);
        self.settle();
    }

    fn tick(&mut self, t: Time) {
        if !self.running() {
            return;
        }
        // The solve's steps and the store need no samples: the solve advances on the ticks
        // alone, one step a tick (the shell ticks after each FIFO read).
        if let Step::Solving { next, .. } = self.step {
            if t >= next {
                self.solve_step(t);
            }
        } else if let (Some(last), false) = (self.last_sample_t, matches!(self.step, Step::Storing { .. })) {
            let gap = t.since(last);
            if gap > self.cfg.sample_timeout_s as Real {
                return self.fail(Error::SensorTimeout { gap_s: gap as f32 });
            }
            self.fit_due(t);
        }
        self.check_timeout(t);
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
        let finite = s.accel_g.iter().chain(s.gyro_dps.iter()).all(|v| v.is_finite());
        if !finite {
            return self.fail(Error::NonFinite);
        }
        let last = self.last_sample_t;
        if last.is_some_and(|last| s.t <= last) {
            return; // duplicate or out-of-order timestamp: dropped
        }
        self.last_sample_t = Some(s.t);
        let gyro_saturated = s.gyro_dps.iter().any(|v| v.abs() >= 0.98 * self.cfg.setup.gyro_range_dps);
        let saturated = gyro_saturated || s.accel_g.iter().any(|v| v.abs() >= 0.98 * self.cfg.setup.accel_range_g);
        self.tainted |= saturated;
        // The window's temperatures join the calibration's as the window closes.
        if let Some(t) = s.temp_c.filter(|t| t.is_finite()) {
            self.window_read.temp.add(t);
        }
        let window = self.rest.update(s.t, s.accel_g, s.gyro_dps);
        let tainted = self.tainted;
        let g = self.bias.map_or(s.gyro_dps, |b| sub(s.gyro_dps, b.bias_dps));
        let hand = matches!(self.step, Step::HandHeld { .. }) && self.one_servo();
        if hand || self.attitude.is_some() {
            let dt = last.map_or(0.0, |last| s.t.since(last));
            if hand {
                self.window_turn.add(s.t, dt as Real, g);
            }
            if let Some(a) = self.attitude.filter(|_| self.one_servo()) {
                // A clipped gyro sample, or a step beyond `exp_jr`'s series (a gap in the
                // samples): lost. (A knock that clips only the accelerometer turns nothing unseen.)
                let phi = Vector3::from(g).map(|v| v.to_radians() * dt as f32);
                self.attitude = (!gyro_saturated && phi.norm_squared() <= 0.0625).then(|| a * rotation::exp(&phi));
            }
        }
        // A closed window with what was read during it (taken only then: the captures and the
        // readings are hundreds of bytes, not copied a sample).
        let closed = window.map(|w| {
            self.tainted = false;
            let wt = core::mem::take(&mut self.window_read);
            self.temp.merge(&wt.temp);
            (w, wt, core::mem::take(&mut self.window_turn))
        });
        match self.step {
            Step::Idle | Step::Finished(_) | Step::Reattach { .. } | Step::Solving { .. } | Step::Storing { .. } => {}
            Step::WaitRest => {
                if self.rest.state() == RestState::Still {
                    if self.bias.is_none() {
                        self.enter(Step::Bias { capture: Capture::default() }, s.t);
                    } else {
                        self.enter(Step::Pose { k: 0, capture: Capture::default(), since: s.t }, s.t);
                    }
                }
            }
            Step::Bias { ref mut capture } => {
                if let Some((w, wt, turn)) = &closed {
                    match capture.feed(w, wt, turn, tainted, self.cfg.bias_s) {
                        CaptureStep::Pending => {}
                        CaptureStep::Disturbed => {
                            let c = *capture;
                            self.retake(0, c, |c| Step::Bias { capture: c })
                        }
                        CaptureStep::Done => {
                            let c = *capture;
                            self.finish_bias(&c, s.t)
                        }
                    }
                }
            }
            Step::HandHeld { .. } if !hand => {}
            Step::HandHeld { ref mut capture, .. } => {
                // A move's turn is the gyro's: only its clipping spoils it.
                self.rotations.add(s.t, g, gyro_saturated);
                if let Some((w, wt, turn)) = &closed {
                    // A disturbed hand-held pose is simply taken again: the user is moving it.
                    if let CaptureStep::Done = capture.feed(w, wt, turn, tainted, self.cfg.hand_pose_s) {
                        let c = *capture;
                        self.finish_accel_pose(&c, s.t);
                        // The next move starts at this sample (its first interval is the next).
                        self.rotations.add(s.t, g, gyro_saturated);
                    }
                }
            }
            Step::Move { k, ramp } => {
                // The move's integral is the gyro's: a clipped gyro sample corrupts it, a clipped
                // accelerometer one (a hobby servo's jerk at the lever arm) does not.
                if gyro_saturated {
                    return self.fail(Error::Saturated);
                }
                self.integ.add(s.t, g);
                let (deg, done) = ramp.at(s.t);
                if ramp.channel == 1 {
                    self.set_tilt(deg);
                } else {
                    self.set_angle(deg);
                }
                if done {
                    if let (ServoKind::Continuous { .. }, 0) = (self.cfg.servo(), ramp.channel) {
                        self.push(Command::ServoOff { channel: 0 });
                    }
                    self.step = Step::Pose { k, capture: Capture::default(), since: s.t };
                }
            }
            Step::Pose { k, ref mut capture, since } => {
                if gyro_saturated {
                    // The shaft may still be settling: a clipped gyro sample corrupts the move's
                    // integral (a clipped accelerometer one taints the pose's window: retaken).
                    return self.fail(Error::Saturated);
                }
                self.integ.add(s.t, g);
                if let Some((w, wt, turn)) = &closed {
                    match capture.feed(w, wt, turn, tainted, self.cfg.pose_average_s) {
                        CaptureStep::Pending => {}
                        CaptureStep::Disturbed => {
                            let c = *capture;
                            self.retake(k.min(255) as u8, c, |c| Step::Pose { k, capture: c, since })
                        }
                        CaptureStep::Done => {
                            let c = *capture;
                            self.finish_pose(k, &c, s)
                        }
                    }
                }
            }
            Step::Spin { ref mut spin } => {
                if saturated {
                    return self.fail(Error::Saturated);
                }
                let elapsed = s.t.since(spin.ramp.t0);
                let duration = spin.ramp.duration_s as Real;
                let deg = spin.ramp.at(s.t).0;
                if self.cfg.steady.averaged(elapsed, duration) {
                    spin.rate.add(g);
                    // The rate gravity turns at is a continuous servo's (a positional one's is
                    // commanded).
                    if let ServoKind::Continuous { .. } = self.cfg.servo() {
                        spin.gravity.add(s.t, self.accel_cal.apply(s.accel_g));
                    }
                }
                let done = (elapsed >= duration).then_some(*spin);
                self.set_angle(deg);
                if let Some(spin) = done {
                    self.finish_spin(&spin, s.t);
                }
            }
        }
    }

    /// The one-servo plan (hand-held step, the stepped solve): the pan/tilt plan has neither,
    /// and a firmware built for it links neither ([`Config::is_pan_tilt`]).
    fn one_servo(&self) -> bool {
        !self.cfg.is_pan_tilt()
    }

    fn running(&self) -> bool {
        !matches!(self.step, Step::Idle | Step::Finished(_))
    }

    fn push(&mut self, c: Command<()>) {
        // Bounded by the contract (≤ 10 per call, drained after each). A shell that breaks it
        // fails the calibration when the call ends ([`Self::settle`]).
        if self.queue.push_back(c).is_err() {
            self.overflow = true;
        }
    }

    fn start(&mut self, t: Time) {
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
        self.rows = NormalEquations::new();
        self.full = None;
        self.integ = Integrator::new();
        self.drift = Drift::new();
        self.temp_fit = TempFit::new();
        self.rest_temp_c = f32::NAN;
        self.window_read = WindowReadings::default();
        self.mag = MagCalibrator::new();
        self.mag_cal = self.stored.filter(|_| !self.cfg.is_pan_tilt() && self.stored_accel().is_some()).and_then(|r| r.mag);
        self.window_turn = PoseTurn::new();
        self.attitude = None;
        self.gbar = None;
        self.temp = Mean::new();
        if let Some(acc) = self.stored_accel() {
            self.accel_cal = acc;
        }
        self.park_servo();
        self.enter(Step::WaitRest, t);
    }

    fn enter(&mut self, step: Step, t: Time) {
        let rest = if matches!(step, Step::HandHeld { .. }) { self.cfg.hand_rest } else { self.cfg.rest };
        if *self.rest.config() != rest {
            self.rest = RestDetector::new(rest);
        }
        self.step = step;
        self.phase_t0 = t;
        let phase = self.phase();
        self.push(Command::Report(Report::Phase(phase)));
        let led = match phase {
            p @ (Phase::HandHeld | Phase::Reattach) => Led::WaitUser(p),
            p => Led::Busy(p),
        };
        self.push(Command::Led(led));
    }

    fn fail(&mut self, e: Error) {
        let e = pipeline::blame(e, &self.drift, Some((&self.rotations, &self.cfg.rotation)));
        self.step = Step::Finished(Phase::Failed);
        self.last_pulse = None;
        self.push(Command::ServoOff { channel: 0 });
        if self.cfg.is_pan_tilt() {
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

    fn check_timeout(&mut self, t: Time) {
        let c = &self.cfg;
        let (since, limit) = match self.step {
            Step::WaitRest | Step::Bias { .. } => (self.phase_t0, c.rest_timeout_s + c.bias_s),
            Step::HandHeld { .. } => (self.phase_t0, c.handheld_timeout_s),
            Step::Reattach { .. } => (self.phase_t0, c.reattach_timeout_s),
            Step::Move { ramp, .. } => (ramp.t0, ramp.duration_s + c.rest_timeout_s),
            Step::Pose { since, .. } => (since, c.rest_timeout_s + c.pose_average_s),
            Step::Spin { spin } => (spin.ramp.t0, spin.ramp.duration_s + c.rest_timeout_s),
            // Steps every call: nothing to wait for.
            Step::Solving { .. } => return,
            Step::Storing { .. } => (self.phase_t0, STORE_TIMEOUT_S),
            Step::Idle | Step::Finished(_) => return,
        };
        if t.since(since) > limit as Real {
            let phase = self.phase();
            self.fail(Error::PhaseTimeout { phase, limit_s: limit });
        }
    }

    /// Drains the commands into `shell`, answering each store with [`Self::handle_stored`]
    /// (the one dispatch loop of every shell). Call after every `handle_*`.
    pub fn drive(&mut self, t: Time, shell: &mut impl Shell) {
        while let Some(c) = self.poll() {
            match c {
                Command::Servo { channel, pulse_us } => shell.servo(channel, pulse_us),
                Command::ServoOff { channel } => shell.servo_off(channel),
                Command::Led(l) => shell.led(l),
                Command::Report(r) => shell.report(&r),
                Command::Store(rec) => {
                    let result = shell.store(&rec);
                    self.handle_stored(t, result);
                }
                Command::Apply(rec) => shell.apply(&rec),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::record::tests::sample;
    use crate::time::secs;

    fn drain(p: &mut Procedure) -> heapless::Vec<Command, QUEUE> {
        core::iter::from_fn(|| p.poll()).collect()
    }

    #[test]
    fn the_queue_hands_out_each_record_it_was_given() {
        let mut p = Procedure::new(Config::default(), None);
        p.handle_button(secs(0.0));
        drain(&mut p);
        p.store(sample(), secs(1.0));
        p.settle();
        let cmds = drain(&mut p);
        assert_eq!(cmds.last(), Some(&Command::Store(sample())), "{cmds:?}");
        p.handle_stored(secs(1.5), Ok(()));
        let cmds = drain(&mut p);
        assert_eq!(cmds[..2], [Command::Report(Report::Done(sample())), Command::Apply(sample())], "{cmds:?}");
        assert_eq!(p.stored, Some(sample()));
    }

    /// One report of every kind of payload, its fields all different, `Done` holding `r`.
    fn every_report<R>(r: R) -> [Report<R>; 11] {
        use crate::estimators::rotation::Rejected;
        [
            Report::Phase(Phase::HandHeld),
            Report::AccelPose { index: 3, accel_g: [0.1, -0.2, 0.97] },
            Report::RigPose { index: 9, servo_deg: 42.5, accel_g: [-0.3, 0.4, 0.86] },
            Report::Retake { index: 4, retries: 2 },
            Report::Move { from: 1, to: 2, gyro_turn_deg: 91.25 },
            Report::HandMove {
                from: 5,
                to: 6,
                rejected: Some(Rejected::Saturated),
                turn_deg: 80.5,
                spread: 0.2,
                need: 0.05,
                k_sigma: 3e-4,
                goal: 2e-4,
            },
            Report::Rotations { moves: 7, rejected: [1, 2, 3, 4, 5, 6, 7], residual_deg: core::array::from_fn(|i| i as f32 * 0.01) },
            Report::FullK {
                k: [[1.01, 2e-3, 3e-3], [4e-3, 0.99, 5e-3], [6e-3, 7e-3, 1.02]],
                sigma_k: [[1e-4; 3]; 3],
                condition: 12.5,
                non_coplanar_deg: 61.0,
                residual_rms_deg: 0.02,
                axes: 3,
                moves: 17,
            },
            Report::EstimatorFailed { method: Method::Paper, error: Error::NoSpin { rate_dps: 1.5, min_dps: 5.0 } },
            Report::Failed(Error::PoseDisturbed { index: 2, retries: 3 }),
            Report::Done(r),
        ]
    }

    #[test]
    fn a_queued_report_comes_out_as_it_went_in() {
        // `with_record` copies every report but `Done` byte for byte (`Report` is `repr(u8)`).
        let rec = sample();
        for (queued, want) in every_report(()).into_iter().zip(every_report(rec)) {
            assert_eq!(Command::Report(queued).with_record(None, Some(rec)), Some(Command::Report(want)));
        }
    }

    #[test]
    fn a_store_a_failure_overtook_is_never_handed_to_the_shell() {
        // A shell that does not drain after the call that asks for the store: the store times
        // out and the calibration fails before the shell polls. The failure is handed out; the
        // record of the failed calibration is not, neither to store nor to apply.
        let mut p = Procedure::new(Config::default(), None);
        p.handle_button(secs(0.0));
        drain(&mut p);
        p.store(sample(), secs(1.0));
        p.settle();
        p.handle_tick(secs(1.0 + STORE_TIMEOUT_S as Real + 0.1));
        let cmds = drain(&mut p);
        assert!(!cmds.iter().any(|c| matches!(c, Command::Store(_) | Command::Apply(_))), "{cmds:?}");
        let timeout = Error::PhaseTimeout { phase: Phase::Store, limit_s: STORE_TIMEOUT_S };
        assert!(cmds.contains(&Command::Report(Report::Failed(timeout))), "{cmds:?}");
        assert_eq!(p.stored, None);
    }
}
