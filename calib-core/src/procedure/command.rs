//! What the procedure asks its I/O shell to do, and what it reports.

use super::Phase;
use crate::estimators::accel::AccelCal;
use crate::estimators::bias::{Bias, TempCo};
use crate::estimators::gyro::{GyroCal, Method};
use crate::estimators::rotation::MAX_ROTATION_MOVES;
use crate::formats::record::{Record, StoreError};
use crate::{Error, Mat3, Vec3};

/// LED patterns (the shell maps them to pins and blink timing).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Led {
    /// Waiting for the button.
    Idle,
    /// Working on a phase.
    Busy(Phase),
    /// The user must act in this phase: hold the board still in a new orientation
    /// ([`Phase::HandHeld`]), or re-clamp it and press ([`Phase::Reattach`]).
    WaitUser(Phase),
    /// Calibration stored and applied.
    Done,
    /// Failed; the class tells what to check.
    Error(ErrorClass),
}

/// Error classes shown on the LEDs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorClass {
    /// Sensor stopped, saturated or out of range.
    Sensor,
    /// Motion where the rig must be still.
    Motion,
    /// Servo not turning.
    Servo,
    /// Rig geometry (axis, mounting, span).
    Geometry,
    /// The solution was singular, implausible or rejected.
    Result,
    /// A phase timed out.
    Timeout,
    /// The record could not be stored (the previous one is kept).
    Storage,
}

impl ErrorClass {
    /// The class of an error.
    pub fn of(e: &Error) -> Self {
        match e {
            Error::SensorTimeout { .. }
            | Error::Saturated
            | Error::BiasOutOfRange { .. }
            | Error::BiasDrifting { .. }
            | Error::NonFinite => ErrorClass::Sensor,
            Error::NotStill { .. } | Error::PoseDisturbed { .. } | Error::AxisNotFixed { .. } => ErrorClass::Motion,
            Error::ServoNotTurning { .. } | Error::NoSpin { .. } | Error::NoUsableMove => ErrorClass::Servo,
            Error::AxisNearVertical { .. }
            | Error::AxisNearHorizontal { .. }
            | Error::WeakSensorAxis { .. }
            | Error::AngleSpanTooSmall { .. }
            | Error::TooFewPoses { .. }
            | Error::TooFewAxes { .. }
            | Error::AxesCoplanar { .. }
            | Error::AxisUndetermined { .. }
            | Error::FullKUnobservable { .. }
            | Error::RotationAxesCoplanar { .. } => ErrorClass::Geometry,
            Error::MovesDropped { .. } => ErrorClass::Motion,
            Error::PhaseTimeout { .. } => ErrorClass::Timeout,
            Error::Storage(_) => ErrorClass::Storage,
            Error::SamplesLost { .. } | Error::SensorFault => ErrorClass::Sensor,
            Error::TooFewRows { .. }
            | Error::Singular
            | Error::IllConditioned { .. }
            | Error::CapacityExceeded { .. }
            | Error::ImplausibleScale { .. }
            | Error::TooFewSamples { .. }
            | Error::AccelFitFailed
            | Error::ResultRejected { .. }
            | Error::TooUncertain { .. }
            | Error::MagFitFailed
            | Error::MagTooFew { .. }
            | Error::MagDisturbed { .. }
            | Error::MagFitPoor { .. }
            | Error::MagCoverageThin { .. }
            | Error::CommandQueueFull
            | Error::ResultNotFinite
            | Error::MovesInconsistent { .. }
            | Error::AxesMirrored { .. } => ErrorClass::Result,
        }
    }
}

/// Progress and results, for the log. `R` is the record's place ([`Report::Done`]): the
/// procedure's queue holds `()` there and [`super::Procedure::poll`] puts the record in, so that
/// a queued command takes 128 B rather than 328.
#[allow(missing_docs)] // variant fields are named with their units
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Report<R = Record> {
    /// A phase started.
    Phase(Phase),
    /// Gyro bias measured.
    Bias(Bias),
    /// A hand-held pose was captured (raw mean, g); from [`super::Config::accel_poses`] on it
    /// adds a move only.
    AccelPose { index: u8, accel_g: Vec3 },
    /// The accelerometer calibration.
    Accel(AccelCal),
    /// The magnetometer's calibration from the hand-held step.
    Mag(crate::estimators::mag::MagCal),
    /// A static rig pose was captured (calibrated mean, g; raw with the pan/tilt plan, whose
    /// accelerometer is fitted to these poses at the end).
    RigPose { index: u8, servo_deg: f32, accel_g: Vec3 },
    /// A pose was disturbed and is being retaken.
    Retake { index: u8, retries: u8 },
    /// A move between two poses: its raw gyro turn |Γ| (°).
    Move { from: u8, to: u8, gyro_turn_deg: f32 },
    /// One gyro estimator's result.
    Gyro(GyroCal),
    /// The full 3×3 `K` of the pan/tilt plan (row-major, with the 1σ of every element), the
    /// condition of its normal matrix, its axes' angle from coplanar (°) and its residual (°).
    FullK { k: Mat3, sigma_k: Mat3, condition: f32, non_coplanar_deg: f32, residual_rms_deg: f32, axes: u8, moves: u16 },
    /// A hand-held move was kept for the rotation constraints: its raw turn (°) and the spread
    /// of the kept moves' axes so far (smallest eigenvalue of their mean `n nᵀ`, 1/3 at best;
    /// `need` is the least accepted), or rejected (`rejected` says why; counted). From
    /// [`super::Config::accel_poses`] poses on, `k_sigma` is the 1σ the moves alone give `K`
    /// and `goal` the one that ends the step ([`super::Config::hand_k_sigma`]); NaN before.
    HandMove {
        from: u8,
        to: u8,
        rejected: Option<crate::estimators::rotation::Rejected>,
        turn_deg: f32,
        spread: f32,
        need: f32,
        k_sigma: f32,
        goal: f32,
    },
    /// The rotation constraints used in the full `K`: the misfit (°) of each of the `moves`
    /// kept moves at the solution (0 when none was solved), and the moves rejected by reason
    /// ([`crate::estimators::rotation::Rejected`]).
    Rotations { moves: u8, rejected: [u16; crate::estimators::rotation::REJECTED_REASONS], residual_deg: [f32; MAX_ROTATION_MOVES] },
    /// The gyro bias's temperature coefficient over the rests, or `None` when their
    /// temperatures spanned too little to determine it ([`crate::estimators::bias::MIN_TEMP_SPAN_C`]).
    TempCo(Option<TempCo>),
    /// One gyro estimator failed (the other may still succeed).
    EstimatorFailed { method: Method, error: Error },
    /// The calibration was stored (verified) and is applied from now on.
    Done(R),
    /// The calibration failed; nothing was stored.
    Failed(Error),
}

/// A command to the I/O shell (`R`: the record's place, as in [`Report`]).
#[allow(missing_docs)] // variant fields are named with their units
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Command<R = Record> {
    /// Drive servo `channel` (0 = rotation, 1 = tilt) with a pulse (µs, already clamped).
    Servo { channel: u8, pulse_us: u16 },
    /// Stop driving servo `channel`.
    ServoOff { channel: u8 },
    /// Show an LED pattern.
    Led(Led),
    /// Log a report.
    Report(Report<R>),
    /// Store this record in flash (power-fail safe; keep the previous one until it is written),
    /// then tell the procedure how it went: [`super::Procedure::handle_stored`].
    Store(R),
    /// Apply this calibration to every reading from now on.
    Apply(R),
}

impl Command<()> {
    /// The queued command with its record: `store` for [`Command::Store`] (the one being
    /// stored), `stored` for [`Command::Apply`] and [`Report::Done`] (the one in flash). `None`
    /// when that record is gone (a store the calibration's failure overtook): dropped.
    pub(super) fn with_record(self, store: Option<Record>, stored: Option<Record>) -> Option<Command> {
        Some(match self {
            Command::Servo { channel, pulse_us } => Command::Servo { channel, pulse_us },
            Command::ServoOff { channel } => Command::ServoOff { channel },
            Command::Led(l) => Command::Led(l),
            Command::Store(()) => Command::Store(store?),
            Command::Apply(()) => Command::Apply(stored?),
            Command::Report(Report::Done(())) => Command::Report(Report::Done(stored?)),
            Command::Report(r) => {
                let mut out = core::mem::MaybeUninit::<Report>::uninit();
                // SAFETY: `Report` is `repr(u8)`: each variant is laid out as a `repr(C)` struct
                // of its `u8` tag and its fields (RFC 2195), so every variant but `Done` (the
                // one that holds `R`, not this one) has the same layout whatever `R`; a
                // `Report<()>` is no larger than a `Report`. `r`'s bytes are the same variant's.
                unsafe {
                    core::ptr::copy_nonoverlapping(
                        &r as *const Report<()> as *const u8,
                        out.as_mut_ptr() as *mut u8,
                        size_of::<Report<()>>(),
                    );
                    Command::Report(out.assume_init())
                }
            }
        })
    }
}

/// What a shell does with the procedure's commands: the one dispatch of every shell (the
/// firmware, the simulated rig, the offline tool). [`super::Procedure::drive`] drains the queue
/// into it and feeds the store's result back.
pub trait Shell {
    /// Drives servo `channel` (0 = rotation, 1 = tilt) with a pulse (µs, already clamped).
    fn servo(&mut self, channel: u8, pulse_us: u16);
    /// Stops driving servo `channel`.
    fn servo_off(&mut self, channel: u8);
    /// Shows an LED pattern.
    fn led(&mut self, led: Led);
    /// Logs a report.
    fn report(&mut self, report: &Report);
    /// Stores a record (power-fail safe) and says whether it is now in flash, read back.
    fn store(&mut self, record: &Record) -> Result<(), StoreError>;
    /// Applies a (stored) calibration to every reading from now on.
    fn apply(&mut self, record: &Record);
}
