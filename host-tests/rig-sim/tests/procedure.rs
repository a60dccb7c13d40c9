//! The calibration procedure end to end on the simulated rig: button press to stored record,
//! and every failure ending in its own error with nothing stored.

use calib_core::procedure::{Config, ErrorClass, Led, Phase, Procedure, Report, ServoKind};
use calib_core::record::{Record, StoreError};
use calib_core::Error;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::{run, Faults, Run};
use rig_sim::sim::{ContinuousServo, GyroRange, PositionalServo, Rig, RigConfig, ServoModel, TiltStage};
use rig_sim::variant::Variant;

fn calibrate(cfg: RigConfig, pcfg: Config, stored: Option<Record>, faults: Faults) -> (Run, Rig) {
    let mut rig = Rig::new(cfg, 5);
    let mut p = Procedure::new(pcfg, stored);
    let out = run(&mut rig, &mut p, faults, 900.0, |_, _, _| {});
    (out, rig)
}

fn max_rel_error(rec: &Record, rig: &Rig) -> f64 {
    let k = rig.truth().gyro_k;
    (0..3).map(|i| (rec.gyro_k[i][i] as f64 / k[(i, i)] - 1.0).abs()).fold(0.0, f64::max)
}

#[test]
fn positional_servo_at_every_odr_and_several_mounts() {
    for (run_idx, odr) in [119.0, 238.0, 476.0, 952.0].into_iter().enumerate() {
        let mut cfg = Variant::Hobby.config(11, run_idx);
        cfg.odr_hz = odr;
        let (out, rig) = calibrate(cfg, Config::default(), None, Faults::default());
        assert_eq!(out.error, None, "ODR {odr}: {:?}", out.reports.last());
        assert_eq!(out.stored.len(), 1, "ODR {odr}");
        let rec = out.stored[0];
        assert_eq!((rec.seq, out.applied.len()), (1, 1));
        let err = max_rel_error(&rec, &rig);
        assert!(err < 0.003, "ODR {odr}: max scale error {:.4} %", err * 100.0);
        // Both estimators ran and reported their quality; the sweep one was chosen.
        assert_eq!(out.gyro_results().len(), 2);
        assert_eq!(rec.method, calib_core::gyro::Method::Sweep);
        assert!(rec.invariant_after_rel < rec.invariant_before_rel);
        assert_eq!(Record::decode(&rec.encode()), Ok(rec));
    }
}

#[test]
fn second_run_reuses_the_stored_accelerometer_calibration() {
    let cfg = Variant::Hobby.config(12, 0);
    let (first, _) = calibrate(cfg, Config::default(), None, Faults::default());
    let stored = first.stored[0];
    let (second, rig) = calibrate(cfg, Config::default(), Some(stored), Faults::default());
    assert!(!second.reports.contains(&Report::Phase(Phase::HandHeld)));
    assert!(first.reports.contains(&Report::Phase(Phase::HandHeld)));
    assert_eq!(second.stored.len(), 1);
    assert_eq!(second.stored[0].seq, 2);
    assert!(max_rel_error(&second.stored[0], &rig) < 0.003);
}

#[test]
fn continuous_rotation_servo() {
    for seed in [1u64, 2] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut cfg = Variant::Hobby.config(13, seed as usize);
        cfg.servo = ServoModel::Continuous(ContinuousServo::realistic(&mut rng));
        let pcfg = Config { servo: ServoKind::CONTINUOUS, ..Config::default() };
        let (out, rig) = calibrate(cfg, pcfg, None, Faults::default());
        assert_eq!(out.error, None, "{:?}", out.reports.iter().rev().take(3).collect::<Vec<_>>());
        let err = max_rel_error(&out.stored[0], &rig);
        assert!(err < 0.003, "seed {seed}: max scale error {:.4} %", err * 100.0);
        // The paper estimator, fed the rate measured from the accelerometer, also works here.
        let paper = out.gyro_results().into_iter().find(|c| c.method == calib_core::gyro::Method::Paper).unwrap();
        let k = rig.truth().gyro_k;
        for i in 0..3 {
            assert!((paper.k[i][i] as f64 / k[(i, i)] - 1.0).abs() < 0.01);
        }
    }
}

fn expect_failure(cfg: RigConfig, pcfg: Config, faults: Faults, check: impl Fn(&Error) -> bool) {
    let (out, _) = calibrate(cfg, pcfg, None, faults);
    let e = out.error.unwrap_or_else(|| panic!("no error; last reports {:?}", out.reports.iter().rev().take(3).collect::<Vec<_>>()));
    assert!(check(&e), "unexpected error {e:?} ({e})");
    assert!(out.stored.is_empty() && out.applied.is_empty(), "a failed run stored a record");
}

#[test]
fn disturbed_poses_end_in_pose_disturbed() {
    let faults = Faults { disturb_rig_poses: true, ..Faults::default() };
    expect_failure(Variant::Hobby.config(14, 0), Config::default(), faults, |e| matches!(e, Error::PoseDisturbed { .. }));
}

#[test]
fn stalled_servo_ends_in_servo_not_turning() {
    let faults = Faults { stall_after_first_pose: true, ..Faults::default() };
    expect_failure(Variant::Hobby.config(15, 0), Config::default(), faults, |e| matches!(e, Error::ServoNotTurning { .. }));
}

#[test]
fn nearly_vertical_axis_is_rejected() {
    let mut cfg = Variant::Hobby.config(16, 0);
    let axis = cfg.axis_b();
    cfg.shaft_tilt_deg = 3.0;
    let cfg = cfg.with_axis(axis, 10.0);
    expect_failure(cfg, Config::default(), Faults::default(), |e| matches!(e, Error::AxisNearVertical { .. }));
}

#[test]
fn saturation_during_a_move_is_an_error() {
    let mut cfg = Variant::Hobby.config(17, 0);
    cfg.gyro.range = GyroRange::Dps245;
    // A fast digital servo: 30° steps peak well above 245 °/s.
    if let ServoModel::Positional(p) = &mut cfg.servo {
        p.max_rate_dps = 1000.0;
        p.tau_s = 0.03;
    }
    let pcfg = Config { move_rate_dps: 2000.0, gyro_range_dps: 245.0, ..Config::default() };
    expect_failure(cfg, pcfg, Faults::default(), |e| *e == Error::Saturated);
}

#[test]
fn bias_out_of_range_is_an_error() {
    let mut cfg = Variant::Hobby.config(18, 0);
    cfg.gyro.bias_dps[1] = 45.0;
    expect_failure(cfg, Config::default(), Faults::default(), |e| matches!(e, Error::BiasOutOfRange { axis: 1, .. }));
}

#[test]
fn sensor_data_stopping_is_an_error() {
    for at in [5.0, 60.0] {
        let faults = Faults { sensor_stops_at_s: Some(at), ..Faults::default() };
        expect_failure(Variant::Hobby.config(19, 0), Config::default(), faults, |e| matches!(e, Error::SensorTimeout { .. }));
    }
}

#[test]
fn tilt_servo_takes_the_accelerometer_poses() {
    let mut rng = ChaCha8Rng::seed_from_u64(24);
    let mut cfg = Variant::Hobby.config(24, 0);
    cfg.tilt = Some(TiltStage { servo: PositionalServo::realistic(&mut rng), hinge_deg: 30.0 });
    let pcfg = Config { tilt_accel: true, ..Config::default() };
    let (out, rig) = calibrate(cfg, pcfg, None, Faults::default());
    assert_eq!(out.error, None, "{:?}", out.reports.iter().rev().take(3).collect::<Vec<_>>());
    assert!(out.reports.contains(&Report::Phase(Phase::TiltPoses)));
    assert!(!out.reports.contains(&Report::Phase(Phase::HandHeld)));
    let rec = out.stored[0];
    assert_eq!(rec.accel_model, calib_core::accel::AccelModel::NineParam);
    assert!(rec.accel_rms_g < 0.002, "accel residual {}", rec.accel_rms_g);
    let err = max_rel_error(&rec, &rig);
    assert!(err < 0.003, "max scale error {:.4} %", err * 100.0);
}

#[test]
fn a_failed_store_is_a_failure_nothing_applied_and_the_sequence_unchanged() {
    let cfg = Variant::Hobby.config(12, 0);
    let (first, _) = calibrate(cfg, Config::default(), None, Faults::default());
    let previous = first.stored[0];
    let mut rig = Rig::new(cfg, 6);
    let mut p = Procedure::new(Config::default(), Some(previous));
    let faults = Faults { store_fails: Some(StoreError::Verify), ..Faults::default() };
    let out = run(&mut rig, &mut p, faults, 900.0, |_, _, _| {});
    assert_eq!(out.error, Some(Error::Storage(StoreError::Verify)));
    assert_eq!(ErrorClass::of(&Error::Storage(StoreError::Verify)), ErrorClass::Storage);
    assert_eq!(out.led, Some(Led::Error(ErrorClass::Storage)), "the LEDs show the storage error, not done");
    assert!(out.applied.is_empty() && out.stored.is_empty());
    assert!(!out.reports.iter().any(|r| matches!(r, Report::Done(_))), "no Done before a verified store");
    assert_eq!(p.phase(), Phase::Failed);
    // The same procedure again, with a working store: the sequence continues from the record
    // that is really in flash.
    let out = run(&mut rig, &mut p, Faults::default(), 900.0, |_, _, _| {});
    assert_eq!(out.error, None);
    assert_eq!(out.stored.len(), 1);
    assert_eq!(out.stored[0].seq, previous.seq + 1);
    assert_eq!(out.led, Some(Led::Done));
    assert_eq!(out.applied, out.stored);
}

#[test]
fn temperature_reads_that_fail_never_reach_the_record() {
    let cfg = Variant::Hobby.config(16, 0);
    let faults = Faults { temp_missing_every: Some(7), ..Faults::default() };
    let (out, rig) = calibrate(cfg, Config::default(), None, faults);
    assert_eq!(out.error, None);
    let rec = out.stored[0];
    assert!(rec.temp_c.is_finite() && (rec.temp_c as f64 - rig.config().temp_c).abs() < 2.0, "temp {}", rec.temp_c);
    assert_eq!(Record::decode(&rec.encode()), Ok(rec));
    // Not a single reading: a named error, nothing stored.
    let faults = Faults { temp_missing_every: Some(1), ..Faults::default() };
    expect_failure(cfg, Config::default(), faults, |e| *e == Error::NoTemperature);
}

#[test]
fn a_shell_that_never_drains_the_queue_gets_a_failure_not_lost_commands() {
    let mut rig = Rig::new(Variant::Hobby.config(17, 0), 7);
    let mut p = Procedure::new(Config::default(), None);
    // Start, lose the sensor (a timeout failure), start again, ... and never poll.
    let mut t = 0.0;
    for _ in 0..10 {
        p.handle_button(t);
        let s = rig.next_sample();
        p.handle_sample(&rig_sim::harness::to_input(&s));
        t = s.t_s + 10.0;
        p.handle_tick(t);
    }
    let cmds: Vec<_> = std::iter::from_fn(|| p.poll()).collect();
    assert!(cmds.len() <= 16);
    assert!(cmds.contains(&calib_core::procedure::Command::Report(Report::Failed(Error::CommandQueueFull))), "{cmds:?}");
}
