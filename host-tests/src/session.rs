//! Drives the calib-core procedure with the simulated rig and a simulated operator, from button
//! press to stored record: the end-to-end harness of the tests and of `calib --simulate`.
//!
//! The operator presses the button, holds the board in the 12 icosahedron orientations when
//! asked (moving to the next one after each captured pose), clamps it back on the shaft and
//! presses again. Faults are injected through [`Faults`].

use crate::csvlog::{self, Row};
use crate::sim::{Rig, Sample as SimSample};
use calib_core::gyro::GyroCal;
use calib_core::procedure::{Command, Phase, Procedure, Report, Sample};
use calib_core::record::Record;
use calib_core::Error;
use nalgebra::{UnitQuaternion, Vector3};

/// Faults to inject.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Faults {
    /// The sensor stops delivering samples at this time (s); the timer keeps ticking.
    pub sensor_stops_at_s: Option<f64>,
    /// Someone keeps bumping the rig during the static rig poses.
    pub disturb_rig_poses: bool,
    /// The servo stalls once the first rig pose is captured.
    pub stall_after_first_pose: bool,
}

/// What a run produced.
#[derive(Debug, Clone, Default)]
pub struct Outcome {
    /// Every report, in order.
    pub reports: Vec<Report>,
    /// Records the procedure asked to store.
    pub stored: Vec<Record>,
    /// Records the procedure asked to apply.
    pub applied: Vec<Record>,
    /// The error it ended with, if any.
    pub error: Option<Error>,
    /// Samples delivered.
    pub samples: usize,
    /// MCU time at the end (s).
    pub end_s: f64,
}

impl Outcome {
    /// Gyro results reported by the estimators.
    pub fn gyro_results(&self) -> Vec<GyroCal> {
        self.reports.iter().filter_map(|r| if let Report::Gyro(c) = r { Some(*c) } else { None }).collect()
    }
}

/// The 12 icosahedron vertices (unit vectors): Ye et al.'s accelerometer poses.
pub fn icosahedron() -> [Vector3<f64>; 12] {
    let phi = (1.0 + 5f64.sqrt()) / 2.0;
    [
        [-1.0, phi, 0.0], [1.0, phi, 0.0], [-1.0, -phi, 0.0], [1.0, -phi, 0.0],
        [0.0, -1.0, phi], [0.0, 1.0, phi], [0.0, -1.0, -phi], [0.0, 1.0, -phi],
        [phi, 0.0, -1.0], [phi, 0.0, 1.0], [-phi, 0.0, -1.0], [-phi, 0.0, 1.0],
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

/// Converts a simulator sample to the procedure's input.
pub fn to_input(s: &SimSample) -> Sample {
    Sample { t_s: s.t_s, accel_g: s.accel_g, gyro_dps: s.gyro_dps, temp_c: s.temp_c }
}

/// Runs `proc` on `rig` until it is done or failed (or `max_s` of MCU time passed).
/// `log` sees every delivered sample with the commanded rotation and tilt angles.
pub fn run(
    rig: &mut Rig,
    proc: &mut Procedure,
    faults: Faults,
    max_s: f64,
    mut log: impl FnMut(&SimSample, Option<f32>, Option<f32>),
) -> Outcome {
    let mut out = Outcome::default();
    let attitudes = handheld_attitudes();
    let mut next_pose = 0usize;
    let mut handheld = false;
    let mut press_at = Some(1.0);
    let mut last_bump = f64::NEG_INFINITY;
    let mut t = 0.0;
    let mut started = false;
    while t < max_s {
        let stopped = faults.sensor_stops_at_s.is_some_and(|ts| t >= ts);
        if stopped {
            t += 0.01;
            proc.handle_tick(t);
        } else {
            let s = rig.next_sample();
            t = s.t_s;
            log(&s, proc.servo_deg(), proc.tilt_deg());
            proc.handle_sample(&to_input(&s));
            out.samples += 1;
        }
        if press_at.is_some_and(|tp| t >= tp) {
            press_at = None;
            started = true;
            proc.handle_button(t);
        }
        if faults.disturb_rig_poses && proc.phase() == Phase::RigPoses && t - last_bump > 1.6 {
            rig.disturb(0.3, 20.0);
            last_bump = t;
        }
        while let Some(c) = proc.poll() {
            match c {
                Command::Servo { channel: 0, pulse_us } => rig.set_pulse_us(pulse_us as f64),
                Command::Servo { pulse_us, .. } => rig.set_tilt_pulse_us(pulse_us as f64),
                Command::ServoOff { channel: 0 } => rig.servo_off(),
                Command::ServoOff { .. } | Command::Led(_) => {}
                Command::Store(r) => out.stored.push(r),
                Command::Apply(r) => out.applied.push(r),
                Command::Report(r) => {
                    handheld |= r == Report::Phase(Phase::HandHeld);
                    match r {
                        Report::Phase(Phase::HandHeld) | Report::AccelPose { .. } if handheld => {
                            if let Some(q) = attitudes.get(next_pose) {
                                rig.detach_to(*q, 1.0);
                                next_pose += 1;
                            }
                        }
                        Report::Phase(Phase::Reattach) => {
                            handheld = false;
                            rig.attach();
                            press_at = Some(t + rig.config().attach_transition_s + 1.0);
                        }
                        Report::RigPose { index: 0, .. } if faults.stall_after_first_pose => rig.stall(true),
                        Report::Failed(e) => out.error = Some(e),
                        _ => {}
                    }
                    out.reports.push(r);
                }
            }
        }
        if started && matches!(proc.phase(), Phase::Done | Phase::Failed) {
            break;
        }
    }
    out.end_s = t;
    out
}

/// Runs like [`run`] and records the log (DESIGN §5 CSV, `comments` first; a `tilt_deg` column
/// when the rig has a tilt stage).
pub fn record_log(rig: &mut Rig, proc: &mut Procedure, faults: Faults, comments: &str) -> (String, Outcome) {
    let tilt = rig.config().tilt.is_some();
    let mut text = format!("{comments}{}", csvlog::header(tilt));
    let out = run(rig, proc, faults, 900.0, |s, servo_deg, tilt_deg| {
        let row = Row { t_s: s.t_s, accel_g: s.accel_g, gyro_dps: s.gyro_dps, servo_deg, tilt_deg };
        csvlog::format_row(&mut text, &row, tilt);
    });
    (text, out)
}
