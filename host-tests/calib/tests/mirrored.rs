//! A log whose gyro follows its accelerometer with the left-hand rule (the LSM9DS1's raw axes,
//! as Arduino_LSM9DS1 returns them): `gyrocal-calib` names the mirror and calibrates in the log's
//! own axes, to the accuracy of the same log in the board frame.

use calib::{csvlog, offline};
use calib_core::formats::log::Row;
use calib_core::Error;
use rig_sim::harness::{handheld_attitudes, log_header, log_row, write_log_row};
use rig_sim::lsm_model::Lsm9ds1Model;
use rig_sim::pan_tilt;
use rig_sim::sim::Rig;

/// A one-servo rig's log (rig poses, 12 hand-held poses, rig poses), each row through `axes`.
fn log(axes: impl Fn(Row) -> Row) -> String {
    let mut rig = Rig::new(pan_tilt::rig_config(43, 0), 43);
    let mut text = format!("{}\n", log_header(rig.config()));
    let mag = rig.config().mag.is_some();
    let mut hold = |rig: &mut Rig, secs: f64, servo: Option<f32>| {
        let t0 = rig.truth().t_s;
        while rig.truth().t_s - t0 < secs {
            write_log_row(&mut text, &axes(log_row(&rig.next_sample(), servo, None)), mag);
        }
    };
    rig.set_pulse_us(1000.0);
    hold(&mut rig, 3.0, Some(0.0));
    for q in handheld_attitudes() {
        rig.detach_to(q, 1.0);
        hold(&mut rig, 4.0, None);
    }
    rig.attach();
    hold(&mut rig, 3.0, Some(0.0));
    text
}

#[test]
fn a_mirrored_gyro_is_named_and_calibrated_in_the_logs_own_axes() {
    let board = offline::calibrate(&csvlog::parse(&log(|r| r)).unwrap().rows, None).unwrap();
    assert!(board.mirrored.is_none());
    // The LSM9DS1's raw axes: accelerometer, gyro and (its accelerometer's axes, as the firmware
    // before the board frame logged it) magnetometer with x negated.
    let raw = |r: Row| Row {
        accel_g: Lsm9ds1Model::raw_axes(r.accel_g),
        gyro_dps: Lsm9ds1Model::raw_axes(r.gyro_dps),
        mag_ut: r.mag_ut.map(Lsm9ds1Model::raw_axes),
        ..r
    };
    let mirrored = offline::calibrate(&csvlog::parse(&log(raw)).unwrap().rows, None).unwrap();
    let Some(Error::AxesMirrored { right_hand, left_hand }) = mirrored.mirrored else { panic!("not named: {:?}", mirrored.mirrored) };
    println!("MEASURED mirrored log: {left_hand} moves left-handed, {right_hand} right-handed");
    assert!(left_hand >= 6 && right_hand == 0);
    let (kb, km) = (board.record().unwrap(), mirrored.record().unwrap());
    // The same K conjugated by the reflection P = diag(−1, 1, 1) (`P K P`), the bias P b: the
    // same calibration, to the same accuracy, for the readings as logged.
    let p = [-1.0f32, 1.0, 1.0];
    for i in 0..3 {
        for j in 0..3 {
            assert!((km.gyro_k[i][j] - p[i] * p[j] * kb.gyro_k[i][j]).abs() < 1e-5, "K[{i}][{j}]: {km:?} {kb:?}");
        }
        assert!((km.gyro_bias_dps[i] - p[i] * kb.gyro_bias_dps[i]).abs() < 1e-4);
    }
    let out = serde_json::to_value(mirrored.output(0)).unwrap();
    assert_eq!(out["quality"]["gyro_axes"], "mirrored");
    assert_eq!(out["quality"]["gyro_axes_evidence"]["left_hand_moves"].as_u64(), Some(left_hand as u64));
    assert_eq!(serde_json::to_value(board.output(0)).unwrap()["quality"]["gyro_axes"], "right-handed");
}
