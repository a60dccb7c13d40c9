//! A log of the firmware's own calibration run, replayed through the firmware's own
//! `Procedure`: the same samples through the same state machine give the same poses, moves,
//! estimates and acceptance as on the board, to the rounding of the log's numbers.
//!
//! The log carries everything the procedure's decisions depend on: the samples, and in its
//! servo columns the angles the procedure commanded before each sample. The two button presses
//! are where those columns change: idle → commanded (the start), and after the hand-held poses
//! empty → commanded (back on the shaft). The press times only set phase timeouts. While
//! replaying, the procedure's own commanded angles must equal the logged ones at every row;
//! the first mismatch means the log is not a run of this procedure with this configuration
//! (another protocol, a stored accelerometer calibration on the board that the replay was not
//! given, another servo type), and the replay gives up for the data-driven path of
//! [`crate::offline`]. Given the board's stored record, the replay starts from it as the board
//! did (its accelerometer calibration instead of the hand-held poses).

use crate::csvlog::Row;
use calib_core::estimators::accel::AccelCal;
use calib_core::estimators::bias::Bias;
use calib_core::estimators::full::FullCal;
use calib_core::estimators::gyro::{GyroCal, Method};
use calib_core::formats::record::{Record, SensorSetup, StoreError};
use calib_core::procedure::pipeline;
use calib_core::procedure::{Config, Led, Phase, Procedure, Report, Sample, ServoKind, Shell};
use calib_core::{Error, Time};

/// What the procedure concluded on the replayed log.
#[derive(Debug, Clone)]
pub struct Replay {
    /// The configuration that replays the log.
    pub config: &'static str,
    /// The gyro bias at the end of the run (the record's, [`Procedure::bias_at`]).
    pub bias: Bias,
    /// The accelerometer calibration.
    pub accel: AccelCal,
    /// The sweep estimator's outcome, if it ran.
    pub sweep: Option<Result<GyroCal, Error>>,
    /// The paper estimator's outcome, if it ran.
    pub paper: Option<Result<GyroCal, Error>>,
    /// The one-axis result the firmware would store, or why it would not (beside a full `K`: the
    /// sweep estimator of the rig's axis, as reported).
    pub result: Result<GyroCal, Error>,
    /// On a pan/tilt run, or a run with hand-held moves: the full `K` the firmware would store,
    /// or why it would not.
    pub full: Option<Result<FullCal, Error>>,
    /// The record the firmware would store (none if it failed).
    pub record: Option<Record>,
}

/// The procedure's reports, collected; stores always succeed (nothing is written).
#[derive(Default)]
struct Collect {
    bias: Option<Bias>,
    accel: Option<AccelCal>,
    sweep: Option<Result<GyroCal, Error>>,
    paper: Option<Result<GyroCal, Error>>,
    failed: Option<Error>,
    done: Option<Record>,
    /// The procedure went for the full K with rotation constraints.
    rotations: bool,
}

impl Shell for Collect {
    fn servo(&mut self, _: u8, _: u16) {}
    fn servo_off(&mut self, _: u8) {}
    fn led(&mut self, _: Led) {}
    fn report(&mut self, r: &Report) {
        match *r {
            Report::Bias(b) => self.bias = Some(b),
            Report::Accel(a) => self.accel = Some(a),
            Report::Gyro(c) if c.method == Method::Sweep => self.sweep = Some(Ok(c)),
            Report::Gyro(c) => self.paper = Some(Ok(c)),
            Report::EstimatorFailed { method: Method::Sweep, error } => self.sweep = Some(Err(error)),
            Report::EstimatorFailed { error, .. } => self.paper = Some(Err(error)),
            Report::Failed(e) => self.failed = Some(e),
            Report::Done(rec) => self.done = Some(rec),
            Report::Rotations { .. } => self.rotations = true,
            _ => {}
        }
    }
    fn store(&mut self, _: &Record) -> Result<(), StoreError> {
        Ok(())
    }
    fn apply(&mut self, _: &Record) {}
}

/// The configurations tried, in order: the firmware's default build, its `tilt-servo` build (the
/// pan/tilt plan), a continuous-rotation servo, and the default with exactly 12 hand-held poses
/// (firmware before the hand-held step's goal); each at the sensor `setup` the log states.
fn configs(setup: SensorSetup) -> [(&'static str, Config); 4] {
    [
        ("default", Config { setup, ..Config::DEFAULT }),
        ("tilt-servo", Config { setup, ..Config::PAN_TILT }),
        ("continuous servo", Config { servo: ServoKind::CONTINUOUS, setup, ..Config::DEFAULT }),
        ("default, 12 hand-held poses", Config { hand_k_sigma: f32::INFINITY, setup, ..Config::DEFAULT }),
    ]
}

/// Ticks after the re-clamp's press within which the procedure starts the rig: the
/// accelerometer's choice and the magnetometer's parts (its points a batch a tick), with room.
const MAX_FIT_TICKS: usize = 32;

/// The re-clamp's press in a replay of a log, at `t`, the sample before the log's first
/// commanded row after the hand-held step: the press came before it on the board, which made
/// the hand-held step's fits still due a tick each (they need no samples), then started the
/// rig; here they are ticked at `t`.
pub fn press_to_rig(p: &mut Procedure, t: Time, shell: &mut impl Shell) {
    p.handle_button(t);
    p.drive(t, shell);
    for _ in 0..MAX_FIT_TICKS {
        if p.phase() != Phase::Reattach {
            break;
        }
        p.handle_tick(t);
        p.drive(t, shell);
    }
}

/// Logged angles are written with two decimals.
fn same(a: Option<f32>, b: Option<f32>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => (a - b).abs() <= 0.006,
        _ => false,
    }
}

/// Replays `rows` under `cfg`; `None` at the first row whose logged angles differ from the
/// procedure's, or if the run never ends. With the full `K`, if one was solved, and the bias
/// at the end ([`Procedure::bias_at`]: the record's).
fn run(rows: &[Row], cfg: Config, stored: Option<&Record>) -> Option<(Collect, Option<FullCal>, Option<Bias>)> {
    let mut p = Procedure::new(cfg, stored.copied());
    let mut out = Collect::default();
    let mut prev_t = rows.first()?.t;
    let mut started = false;
    for r in rows {
        let commanded = r.servo_deg.is_some() || r.tilt_deg.is_some();
        if !started {
            if !commanded {
                prev_t = r.t;
                continue;
            }
            p.handle_button(prev_t);
            p.drive(prev_t, &mut out);
            started = true;
        } else if p.phase() == Phase::Reattach && commanded {
            press_to_rig(&mut p, prev_t, &mut out);
        }
        if !same(p.servo_deg(), r.servo_deg) || !same(p.tilt_deg(), r.tilt_deg) {
            return None;
        }
        // A field reading enters before its row's sample, as the firmware feeds them.
        if let Some(m) = r.mag_ut {
            p.handle_mag(m);
            p.drive(r.t, &mut out);
        }
        // The temperature the firmware saw, if the log has it (the hand-held poses' bias follows
        // the warm-up with it; a log without it replays with the bias on lines in time).
        p.handle_sample(&Sample { t: r.t, accel_g: r.accel_g, gyro_dps: r.gyro_dps, temp_c: r.temp_c });
        // The firmware ticks after each FIFO read: the solve's steps advance on the ticks.
        p.handle_tick(r.t);
        p.drive(r.t, &mut out);
        if matches!(p.phase(), Phase::Done | Phase::Failed) {
            return Some((out, p.full().copied(), p.bias_at(r.t)));
        }
        prev_t = r.t;
    }
    // A log that ends while the board solves: its steps need no samples (one a tick once the
    // procedure's spacing has passed), and their count is bounded.
    for i in 1..=calib_core::procedure::MAX_SOLVE_STEPS {
        if p.phase() != Phase::Store {
            break;
        }
        let t = prev_t.plus_s(calib_core::procedure::SOLVE_STEP_S * i as f64);
        p.handle_tick(t);
        p.drive(t, &mut out);
        if matches!(p.phase(), Phase::Done | Phase::Failed) {
            return Some((out, p.full().copied(), p.bias_at(t)));
        }
    }
    None
}

/// Replays a log of the firmware's procedure; `None` if it is not one (see the module).
/// `stored`: the record the board had in flash when the run started, if any; `setup`: the sensor
/// setup the run was made at.
pub fn replay(rows: &[Row], stored: Option<&Record>, setup: SensorSetup) -> Option<Replay> {
    configs(setup).into_iter().find_map(|(name, cfg)| {
        let (c, full, bias) = run(rows, cfg, stored)?;
        let attempted = cfg.pan_tilt || c.rotations;
        let full = attempted.then_some(match (c.done, c.failed, full) {
            (Some(_), _, Some(f)) => Ok(f),
            (_, Some(e), _) => Err(e),
            _ => Err(Error::NoUsableMove),
        });
        let result = match (c.done, c.failed) {
            // Beside the full K: the sweep estimator of one setting, as reported, under the
            // firmware's acceptance (the firmware would not store it, but it is a valid one-axis K).
            _ if attempted => c.sweep.unwrap_or(Err(Error::NoUsableMove)).and_then(|g| pipeline::validate(&g, &cfg.acceptance).map(|_| g)),
            (Some(rec), _) => {
                let chosen = [&c.sweep, &c.paper].into_iter().flatten().flatten().find(|g| g.method == rec.method && g.k == rec.gyro_k);
                Ok(*chosen?)
            }
            (None, Some(e)) => Err(e),
            (None, None) => return None,
        };
        let accel = c.accel.unwrap_or(AccelCal::IDENTITY);
        Some(Replay { config: name, bias: bias.or(c.bias)?, accel, sweep: c.sweep, paper: c.paper, result, full, record: c.done })
    })
}
