//! The magnetometer from a log's hand-held step, end to end: simulated logs with the board's
//! magnetometer, read and calibrated by `gyrocal-calib`'s code.

use calib::{csvlog, offline};
use calib_core::Error;
use nalgebra::Vector3;
use rig_sim::harness::{handheld_attitudes, log_header, write_log_row};
use rig_sim::heading::{heading_error, Applied};
use rig_sim::pan_tilt;
use rig_sim::sim::Rig;

/// A one-servo rig's log (rig poses, then 12 hand-held poses), a magnet brought near the
/// board for hand-held pose `magnet_at` (if any).
fn log(magnet_at: Option<usize>) -> (String, Rig) {
    let mut rig = Rig::new(pan_tilt::rig_config(41, 0), 41);
    let mut text = format!("{}\n", log_header(rig.config()));
    let mag = rig.config().mag.is_some();
    let hold = |rig: &mut Rig, text: &mut String, secs: f64, servo: Option<f32>| {
        let t0 = rig.truth().t_s;
        while rig.truth().t_s - t0 < secs {
            let s = rig.next_sample();
            let row = rig_sim::harness::log_row(&s, servo, None);
            write_log_row(text, &row, mag);
        }
    };
    rig.set_pulse_us(1000.0);
    hold(&mut rig, &mut text, 3.0, Some(0.0));
    for (i, q) in handheld_attitudes().into_iter().enumerate() {
        rig.detach_to(q, 1.0);
        let stray = if magnet_at == Some(i) { Vector3::new(0.0, 25.0, 10.0) } else { Vector3::zeros() };
        hold(&mut rig, &mut text, 1.0, None);
        rig.set_stray_field_ut(stray);
        hold(&mut rig, &mut text, 3.0, None);
        rig.set_stray_field_ut(Vector3::zeros());
    }
    rig.attach();
    hold(&mut rig, &mut text, 3.0, Some(0.0));
    (text, rig)
}

#[test]
fn the_hand_held_step_calibrates_the_magnetometer_and_leaves_the_rig_out() {
    let (text, rig) = log(None);
    let c = offline::calibrate(&csvlog::parse(&text).unwrap().rows, None).unwrap();
    let m = c.mag.as_ref().expect("the log has magnetometer columns");
    let cal = m.cal.as_ref().unwrap();
    // The rig's rows (servo commanded, motor magnet near) are counted and left out.
    assert!(m.left_out > 200 && m.used > 1000, "used {} left out {}", m.used, m.left_out);
    assert_eq!(cal.poses, 12);
    let truth = rig.truth().mag.unwrap();
    assert!((cal.field_ut as f64 - truth.field_w.norm()).abs() < 0.05 * truth.field_w.norm(), "{cal:?}");
    let dip = (-truth.field_w[2] / truth.field_w.norm()).asin().to_degrees();
    assert!((cal.dip_deg as f64 - dip).abs() < 0.5, "dip {} vs {dip}", cal.dip_deg);
    let applied = Applied { accel_m: c.accel.m, accel_o: c.accel.offset_g, mag_a: cal.a, mag_o: cal.offset_ut };
    let (rms, max) = heading_error(&applied, &rig, 500, 1).unwrap();
    let (ea, eo) = m.ellipsoid.unwrap();
    let (rms_e, _) = heading_error(&Applied { mag_a: ea, mag_o: eo, ..applied }, &rig, 500, 1).unwrap();
    println!("MEASURED heading error {rms:.3} deg RMS, {max:.3} max; ellipsoid alone {rms_e:.3} RMS (die {:.2} deg)", truth.die_deg);
    assert!(rms < 0.3 && max < 1.0, "{rms} {max}");
    // The JSON carries A and the offset, and the readings left out.
    let out = serde_json::to_value(c.output(0)).unwrap();
    assert_eq!(out["mag"]["offset_ut"][0].as_f64().map(|v| v as f32), Some(cal.offset_ut[0]));
    assert_eq!(out["quality"]["mag"]["rig_readings_left_out"].as_u64(), Some(m.left_out as u64));
}

#[test]
fn a_magnet_near_the_board_is_named_and_no_calibration_given() {
    let (text, _) = log(Some(6));
    let c = offline::calibrate(&csvlog::parse(&text).unwrap().rows, None).unwrap();
    let e = c.mag.as_ref().unwrap().cal.as_ref().unwrap_err();
    println!("MEASURED {e}");
    assert!(matches!(e, Error::MagDisturbed { pose: 6, .. }), "{e:?}");
    let out = serde_json::to_value(c.output(0)).unwrap();
    assert!(out["mag"].is_null());
    let missing = c.missing().join("; ");
    assert!(missing.contains("magnetometer: the field at pose 6") && missing.contains("a magnet, a laptop"), "{missing}");
}

#[test]
fn a_log_without_magnetometer_columns_calibrates_as_before() {
    let (text, _) = log(None);
    let stripped: String = text.lines().map(|l| l.split(',').take(9).collect::<Vec<_>>().join(",") + "\n").collect();
    let c = offline::calibrate(&csvlog::parse(&stripped).unwrap().rows, None).unwrap();
    assert!(c.mag.is_none());
    assert!(serde_json::to_value(c.output(0)).unwrap()["quality"]["mag"].is_null());
}
