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

/// The log with columns remapped: each `(to, from, negate)` writes column `from` (negated) into
/// column `to`, on every data row (text-exact: a sign added or removed).
fn remap(text: &str, maps: &[(&str, &str, bool)]) -> String {
    let mut lines = text.lines();
    let header = lines.next().unwrap();
    let cols: Vec<&str> = header.split(',').collect();
    let at = |name: &str| cols.iter().position(|c| *c == name).unwrap();
    let mut out = format!("{header}\n");
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        let mut g: Vec<String> = f.iter().map(|s| s.to_string()).collect();
        if f.len() == cols.len() {
            for (to, from, negate) in maps {
                let v = f[at(from)];
                g[at(to)] = match (negate, v.strip_prefix('-')) {
                    (false, _) | (true, _) if v.is_empty() => v.to_string(),
                    (false, _) => v.to_string(),
                    (true, Some(pos)) => pos.to_string(),
                    (true, None) => format!("-{v}"),
                };
            }
        }
        out.push_str(&g.join(","));
        out.push('\n');
    }
    out
}

/// The heading error (° RMS) of a calibration for the readings of `text`, whose magnetometer
/// columns are `p` times the rig's (`m_logged = P m`): its `A P` applies to the rig's readings.
fn heading_rms(c: &offline::Calibration, rig: &Rig, p: [[f32; 3]; 3]) -> f64 {
    let cal = c.mag.as_ref().unwrap().cal.as_ref().unwrap();
    let ap = core::array::from_fn(|i| core::array::from_fn(|j| (0..3).map(|k| cal.a[i][k] * p[k][j]).sum()));
    let o = core::array::from_fn(|i| (0..3).map(|k| p[k][i] * cal.offset_ut[k]).sum());
    let applied = Applied { accel_m: c.accel.m, accel_o: c.accel.offset_g, mag_a: ap, mag_o: o };
    heading_error(&applied, rig, 500, 1).unwrap().0
}

#[test]
fn a_magnetometer_turned_or_mirrored_against_the_accelerometer_is_found_and_named() {
    let (text, rig) = log(None);
    let truth = rig.truth().mag.unwrap();
    let dip = (-truth.field_w[2] / truth.field_w.norm()).asin().to_degrees();
    let calibrate = |text: &str| offline::calibrate(&csvlog::parse(text).unwrap().rows, None).unwrap();
    assert_eq!(calibrate(&text).mag.unwrap().axes, None, "the axes as logged fit");
    // Turned 180° about x: found, calibrated, A for the readings as logged.
    let turned = remap(&text, &[("my_ut", "my_ut", true), ("mz_ut", "mz_ut", true)]);
    let c = calibrate(&turned);
    let axes = c.mag.as_ref().unwrap().axes.expect("the turn found");
    println!("MEASURED turned: {}", axes.describe());
    assert_eq!(axes.r, [[1, 0, 0], [0, -1, 0], [0, 0, -1]]);
    assert!(axes.dip_scatter_logged_deg > 10.0 && axes.dip_scatter_turned_deg < 0.5, "{axes:?}");
    assert!((axes.dip_deg as f64 - dip).abs() < 0.5 && (c.mag.as_ref().unwrap().cal.as_ref().unwrap().dip_deg as f64 - dip).abs() < 0.5);
    let rms = heading_rms(&c, &rig, [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]);
    assert!(rms < 0.3, "heading error {rms} deg RMS");
    // Mirrored (x negated) under a right-handed gyro: the data fit the turn of the field's
    // negative as well; the turn is taken, the dip comes out negative and the mirror is named.
    let mirrored = remap(&text, &[("mx_ut", "mx_ut", true)]);
    let c = calibrate(&mirrored);
    let axes = c.mag.as_ref().unwrap().axes.expect("the mirror's class found");
    let said = axes.describe();
    println!("MEASURED mirrored: {said}");
    assert_eq!(axes.r, [[1, 0, 0], [0, -1, 0], [0, 0, -1]]);
    assert!((axes.dip_deg as f64 + dip).abs() < 0.5, "{axes:?}");
    assert!(said.contains("up: the southern hemisphere") && said.contains("mirrored instead, (-x, y, z)"), "{said}");
    // The LSM9DS1's raw axes: accelerometer and gyro mirrored (x negated), the magnetometer
    // not: the gyro's handedness picks the mirror, and the heading comes out right.
    let lsm = remap(&text, &[("ax_g", "ax_g", true), ("gx_dps", "gx_dps", true)]);
    let c = calibrate(&lsm);
    assert!(c.mirrored.is_some(), "the gyro's axes found mirrored");
    let axes = c.mag.as_ref().unwrap().axes.expect("the magnetometer found mirrored against the accelerometer");
    println!("MEASURED LSM9DS1 raw axes: {}", axes.describe());
    assert_eq!(axes.r, [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]);
    assert!((axes.dip_deg as f64 - dip).abs() < 0.5, "{axes:?}");
    let out = serde_json::to_value(c.output(0)).unwrap();
    assert_eq!(out["quality"]["mag"]["axes"]["r"][0][0], -1, "{}", out["quality"]["mag"]);
}
