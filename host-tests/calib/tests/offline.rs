//! The offline `calib` tool: logs written from simulated runs, calibrated back; bad logs named.

use calib::csvlog::{self, Row, HEADER};
use calib::offline::{self, OfflineError};
use calib_core::estimators::gyro::Method;
use calib_core::procedure::{Config, Procedure};
use calib_core::Time;
use common::{calib, simulated_log};
use rig_sim::harness::{record_log, Faults};
use rig_sim::sim::{Rig, RigConfig, ServoModel};
use rig_sim::variant::Variant;

use crate::common;

fn errors(k: [[f32; 3]; 3], truth: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|i| k[i][i] as f64 / truth[i] - 1.0)
}

#[test]
fn default_method_is_speed_free_and_accurate_despite_servo_scale_error() {
    for (run_idx, scale) in [(0usize, 0.03), (1, -0.03)] {
        let mut cfg = Variant::Hobby.config(21, run_idx);
        if let ServoModel::Positional(p) = &mut cfg.servo {
            p.scale_error = scale;
        }
        let (log, truth) = simulated_log(cfg);
        let rows = csvlog::parse(&log).unwrap().rows;
        let c = offline::calibrate(&rows, None).unwrap();
        assert_eq!(c.gyro.as_ref().unwrap().method, Method::Sweep);
        let e = errors(c.gyro.as_ref().unwrap().k, truth);
        assert!(e.iter().all(|x| x.abs() < 0.003), "servo scale {scale}: errors {e:?}");
        // The paper estimator, run on the same log at the commanded speed, inherits the servo error.
        let paper = offline::calibrate(&rows, Some(Method::Paper)).unwrap();
        let ep = errors(paper.gyro.as_ref().unwrap().k, truth);
        let mean = ep.iter().sum::<f64>() / 3.0;
        assert!((mean - (1.0 / (1.0 + scale) - 1.0)).abs() < 0.006, "paper errors {ep:?}");
        assert!(c.accel.rms_after_g < c.accel.rms_before_g / 10.0);
    }
}

#[test]
fn logs_without_the_paper_rotation_still_calibrate_and_paper_is_refused() {
    let (log, truth) = simulated_log(Variant::Hobby.config(22, 0));
    // Cut the log before the paper's spin (the last servo ramp): keep up to the last rig pose.
    let rows = csvlog::parse(&log).unwrap().rows;
    let cut = rows.len() - rows.iter().rev().position(|r| r.servo_deg.is_some_and(|s| s > 1.0 && s < 179.0)).unwrap();
    let rows: Vec<Row> = rows[..cut.saturating_sub(1500)].to_vec();
    let c = offline::calibrate(&rows, None).unwrap();
    assert!(errors(c.gyro.as_ref().unwrap().k, truth).iter().all(|x| x.abs() < 0.003));
    assert_eq!(offline::calibrate(&rows, Some(Method::Paper)).unwrap().gyro.unwrap_err(), OfflineError::NoSpin);
}

#[test]
fn degenerate_logs_are_named_errors() {
    // Only a rest: no rig poses.
    let mut text = format!("{HEADER}\n");
    for i in 0..500 {
        let r = Row {
            t: Time::from_s(i as f64 / 119.0).unwrap(),
            accel_g: [0.0, 0.0, 1.0],
            gyro_dps: [0.5, -0.2, 0.1],
            servo_deg: Some(0.0),
            tilt_deg: None,
            mag_ut: None,
            temp_c: None,
        };
        csvlog::format_row(&mut text, &r);
    }
    let rows = csvlog::parse(&text).unwrap().rows;
    let e = offline::calibrate(&rows, None).unwrap().gyro.unwrap_err();
    assert!(matches!(e, OfflineError::Calib { error: calib_core::Error::TooFewPoses { .. }, .. }), "{e}");
    // A vertical shaft: every rig pose sees the same gravity.
    let mut cfg = Variant::Hobby.config(23, 0);
    let axis = cfg.axis_b();
    cfg.shaft_tilt_deg = 2.0;
    let (log, _) = simulated_log(cfg.with_axis(axis, 0.0));
    let e = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap().gyro.unwrap_err();
    assert!(matches!(e, OfflineError::Calib { error: calib_core::Error::AxisNearVertical { .. }, .. }), "{e}");
}

#[test]
fn cli_calibrates_a_log_into_one_json_object_and_names_bad_input() {
    let dir = std::env::temp_dir().join(format!("calib-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("sim.csv");
    let log = log.to_str().unwrap();
    std::fs::write(log, simulated_log(Variant::Hobby.config(5, 0)).0).unwrap();
    let (code, out, err) = calib(&[log]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(out.trim().lines().count(), 1);
    // A log of the procedure with hand-held moves: the full K; the one-axis estimators beside it.
    assert_eq!(v["gyro"]["method"], "full");
    assert!(v["quality"]["full"]["rotation_moves"].as_u64().unwrap() >= 9, "{v}");
    assert_eq!(v["quality"]["estimators"]["sweep"]["method"], "sweep");
    assert_eq!(v["gyro"]["K"].as_array().unwrap().len(), 3);
    assert_eq!(v["gyro"]["bias_dps"].as_array().unwrap().len(), 3);
    assert_eq!(v["accel"]["M"][2].as_array().unwrap().len(), 3);
    // The 1σ in quality.gyro is the reported K's (the full one's diagonal).
    for i in 0..3 {
        assert_eq!(v["quality"]["gyro"]["sigma_k"][i], v["quality"]["full"]["sigma_k"][i][i], "{v}");
    }
    let (code, out, _) = calib(&[log, "--method", "paper"]);
    assert_eq!(code, 0);
    assert!(out.contains("\"method\":\"paper\""));

    // Bad input: each with a clear message and its exit code, never a panic.
    let bad = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        calib(&[p.to_str().unwrap()])
    };
    let (code, _, err) = bad("missing.csv", "t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps\n0,0,0,1,0,0,0\n");
    assert_eq!(code, 3);
    assert!(err.contains("missing column \"servo_deg\""), "{err}");
    let (code, _, err) = bad("time.csv", &format!("{HEADER}\n1,0,0,1,0,0,0,,\n0.5,0,0,1,0,0,0,,\n"));
    assert_eq!(code, 3);
    assert!(err.contains("line 3") && err.contains("does not increase"), "{err}");
    let (code, _, err) = bad("nan.csv", &format!("{HEADER}\n0,0,nan,1,0,0,0,,\n"));
    assert_eq!(code, 3);
    assert!(err.contains("ay_g is not a finite number"), "{err}");
    let (code, _, err) = bad("short.csv", &format!("{HEADER}\n0,0,0,1,0,0,0,0,\n0.0084,0,0,1,0,0,0,0,\n"));
    assert_eq!(code, 1);
    assert!(err.contains("no still period") || err.contains("too few"), "{err}");
    let (code, _, _) = calib(&[dir.join("nope.csv").to_str().unwrap()]);
    assert_eq!(code, 2);
    let (code, _, _) = calib(&[log, "--method", "magic"]);
    assert_eq!(code, 2);
    let (code, _, err) = calib(&[log, "--columns"]);
    assert_eq!(code, 2, "a missing value is a usage error: {err}");
    let (code, out, _) = calib(&["--help"]);
    assert_eq!(code, 0);
    assert!(out.contains("--columns") && out.contains("Exit codes"));
    assert!(!err.contains("panicked"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_pan_tilt_firmware_log_is_replayed_to_the_firmware_s_full_k() {
    let mut rig = Rig::new(rig_sim::pan_tilt::rig_config(25, 0), 3);
    let mut p = Procedure::new(Config::PAN_TILT, None);
    let (log, out) = record_log(&mut rig, &mut p, Faults::default(), "");
    assert_eq!(out.error, None);
    assert_eq!(log.lines().next().unwrap(), format!("{HEADER},mx_ut,my_ut,mz_ut,temp_c"));
    assert!(log.lines().skip(1).any(|l| !l.split(',').nth(8).unwrap_or("").is_empty()), "the tilt column is filled");
    let rec = out.stored[0];
    let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
    assert_eq!(c.replayed, Some("tilt-servo"));
    assert_eq!(c.accel.model, calib_core::estimators::accel::AccelModel::NineParam);
    let full = c.full.expect("a full K").expect("solved");
    // The firmware's K, to the rounding of the log's numbers.
    let d = (0..9).map(|i| (full.k[i / 3][i % 3] - rec.gyro_k[i / 3][i % 3]).abs()).fold(0.0, f32::max);
    assert!(d < 2e-5, "calib vs firmware: {d:.2e}");
    let (largest, _) = rig_sim::pan_tilt::k_error(full.k, c.accel.m, &rig).unwrap();
    assert!(largest < 1.5e-3, "{largest:.2e}");
}

#[test]
fn one_servo_logs_of_another_protocol_give_the_full_k_from_the_hand_held_moves() {
    use rig_sim::pan_tilt;
    let mut rig = Rig::new(pan_tilt::rig_config(41, 0), 41);
    let log = pan_tilt::log_at(&mut rig, true, &[0.0]);
    let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
    assert_eq!(c.replayed, None);
    let full = c.full.expect("a full K").expect("solved");
    assert_eq!(full.n_axes, 1);
    let (largest, rms) = pan_tilt::k_error(full.k, c.accel.m, &rig).unwrap();
    assert!(largest < 1e-3 && rms < 3e-4, "largest {largest:.2e}, rms {rms:.2e}");
}

/// A board warming fast through its hand-held step (6 °C along τ = 60 s from 5 s after power-on,
/// 0.05 °/s/°C on every axis: 0.3 °/s of bias, no walk, no Earth's rate): a line in time between
/// the rests around the step misses the curve by up to 0.02 °/s, 0.1° over a move. With the
/// log's temperatures the poses' bias follows it, as the firmware's does: the moves fit as well
/// as on the same rig with a constant bias. The same log without them keeps the line.
#[test]
fn hand_held_moves_follow_a_warm_up_by_the_log_s_temperatures() {
    use rig_sim::pan_tilt;
    use rig_sim::sim::Warmup;
    // Per rig: (largest |E|, the moves' RMS misfit in °) with temperatures, without, and on the
    // rig with a constant bias.
    let mut runs = vec![];
    for run in 0..4 {
        let fit = |rig: &mut Rig, strip: bool| {
            let log = pan_tilt::log_at(rig, true, &[0.0]);
            let log = if strip { rewrite(&log, |_| true) } else { log };
            let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
            let full = c.full.expect("a full K").expect("solved");
            (pan_tilt::k_error(full.k, c.accel.m, rig).unwrap().0, full.rotation_residual_rms_deg as f64)
        };
        let mut cfg = pan_tilt::rig_config(43, run).constant_bias();
        let still = fit(&mut Rig::new(cfg, 43 + run as u64), false);
        cfg.warmup = Some(Warmup { rise_c: 6.0, tau_s: 60.0, since_power_on_s: 5.0 });
        cfg.gyro.bias_tempco_dps_per_c = nalgebra::Vector3::new(0.05, -0.05, 0.05);
        let rig = || Rig::new(cfg, 43 + run as u64);
        runs.push([fit(&mut rig(), false), fit(&mut rig(), true), still]);
    }
    let text: Vec<String> = runs.iter().map(|r| r.map(|(e, m)| format!("{e:.2e} {m:.4}°")).join(" / ")).collect();
    eprintln!("largest |E| and misfit, with / without temperatures / constant bias: {text:?}");
    let mean = |i: usize, f: fn((f64, f64)) -> f64| runs.iter().map(|r| f(r[i])).sum::<f64>() / runs.len() as f64;
    // Measured: with 1.03–1.14× the constant bias' misfit, without 1.26–3.0×.
    assert!(runs.iter().all(|r| r[0].1 < 1.2 * r[2].1), "{text:?}");
    assert!(mean(1, |r| r.1) > 1.5 * mean(2, |r| r.1), "{text:?}");
    assert!(mean(0, |r| r.0) < 0.6 * mean(1, |r| r.0), "{text:?}");
}

#[test]
fn hand_held_poses_alone_give_the_full_k_and_the_accelerometer() {
    use rig_sim::pan_tilt;
    let mut rig = Rig::new(pan_tilt::rig_config(40, 0), 40);
    let log = pan_tilt::handheld_only(&pan_tilt::log_at(&mut rig, true, &[]));
    let rows = csvlog::parse(&log).unwrap().rows;
    assert!(rows.iter().all(|r| r.servo_deg.is_none() && r.tilt_deg.is_none()), "no servo at all");
    let c = offline::calibrate(&rows, None).unwrap();
    assert!(c.missing().is_empty(), "{:?}", c.missing());
    assert_eq!(c.accel.model, calib_core::estimators::accel::AccelModel::NineParam);
    let full = c.full.expect("a full K").expect("solved");
    assert!(full.rotation_moves >= 10, "{} moves", full.rotation_moves);
    let (largest, rms) = pan_tilt::k_error(full.k, c.accel.m, &rig).unwrap();
    assert!(largest < 3e-3 && rms < 1e-3, "largest {largest:.2e}, rms {rms:.2e}");
    // Without the rotation constraints there is no gyro calibration at all.
    let off = offline::calibrate_with(&rows, None, false).unwrap();
    assert!(off.full.is_none() && off.gyro.is_err());
}

/// A simulated log rewritten row by row.
fn rewrite(log: &str, f: impl Fn(&mut Row) -> bool) -> String {
    let mut text = csvlog::header();
    for mut r in csvlog::parse(log).unwrap().rows {
        if f(&mut r) {
            csvlog::format_row(&mut text, &r);
        }
    }
    text
}

#[test]
fn common_mistakes_are_named_and_partial_logs_give_what_they_can() {
    let dir = std::env::temp_dir().join(format!("calib-mistakes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (log, truth) = simulated_log(Variant::Hobby.config(26, 0));
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p.to_str().unwrap().to_string()
    };
    // The recording stopped while writing its last row: read up to it, with a warning.
    let cut = write("cut.csv", &log[..log.trim_end().rfind('\n').unwrap() + 15]);
    let (code, _, err) = calib(&[&cut]);
    let last = log.trim_end().lines().count();
    assert_eq!(code, 0, "{err}");
    assert!(err.contains(&format!("line {last} was cut mid-row")) && err.contains(&format!("read up to line {}", last - 1)), "{err}");
    // Time in milliseconds: named, never a wrong K.
    let ms = write(
        "ms.csv",
        &rewrite(&log, |r| {
            r.t = Time::from_us(r.t.us() * 1000);
            true
        }),
    );
    let (code, out, err) = calib(&[&ms]);
    assert_eq!((code, out.as_str()), (1, ""), "{err}");
    assert!(err.contains("milliseconds"), "{err}");
    // Gyro in rad/s: named.
    let rad = write(
        "rad.csv",
        &rewrite(&log, |r| {
            r.gyro_dps = r.gyro_dps.map(|g| g.to_radians());
            true
        }),
    );
    let (code, _, err) = calib(&[&rad]);
    assert_eq!(code, 1, "{err}");
    assert!(err.contains("rad/s") && err.contains("57.29578"), "{err}");
    // Accelerometer in m/s²: named.
    let ms2 = write(
        "ms2.csv",
        &rewrite(&log, |r| {
            r.accel_g = r.accel_g.map(|a| a * 9.80665);
            true
        }),
    );
    let (code, _, err) = calib(&[&ms2]);
    assert_eq!(code, 1);
    assert!(err.contains("m/s²"), "{err}");
    // The same two mistakes converted with --columns: the same K as the log in our units.
    let (code, good, _) = calib(&[write("good.csv", &log).as_str()]);
    assert_eq!(code, 0);
    let both = write(
        "both.csv",
        &rewrite(&log, |r| {
            r.accel_g = r.accel_g.map(|a| a * 9.80665);
            r.gyro_dps = r.gyro_dps.map(|g| g.to_radians());
            true
        })
        .replacen("ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps", "ax,ay,az,wx,wy,wz", 1),
    );
    let map = "ax_g=ax/9.80665,ay_g=ay/9.80665,az_g=az/9.80665,gx_dps=wx*57.29577951308232,gy_dps=wy*57.29577951308232,gz_dps=wz*57.29577951308232";
    let (code, conv, err) = calib(&[&both, "--columns", map]);
    assert_eq!(code, 0, "{err}");
    let k = |text: &str| -> Vec<f64> {
        let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
        (0..3).map(|i| v["gyro"]["K"][i][i].as_f64().unwrap()).collect()
    };
    for (a, b) in k(&good).iter().zip(k(&conv)) {
        assert!((a - b).abs() < 2e-4, "{a} vs {b}");
    }
    for (a, t) in k(&good).iter().zip(truth) {
        assert!((a / t - 1.0).abs() < 0.003);
    }
    // Hand-held poses only (no servo at all): the full K from their moves and the
    // accelerometer, exit 0; without the rotation constraints the gyro is named as missing, exit 4.
    // (The rows after the rig's last pose, the board solving on the shaft, are not hand-held.)
    let last_rig_s = csvlog::parse(&log).unwrap().rows.iter().rev().find(|r| r.servo_deg.is_some()).unwrap().t.s();
    let hand = write("hand.csv", &rewrite(&log, |r| r.servo_deg.is_none() && r.t.s() < last_rig_s));
    let (code, out, err) = calib(&[&hand]);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(v["gyro"]["method"], "full", "{v}");
    // The accelerometer model is the F-test's choice (20 poses: 11 degrees of freedom for the
    // 9-parameter fit), said in the JSON; rig-sim's part has ±0.1° misalignment, which a norm
    // fit barely sees.
    let test = &v["quality"]["accel_model_test"];
    let nine = test["f"].as_f64().unwrap() > test["critical"].as_f64().unwrap();
    assert_eq!(v["quality"]["accel"]["model"], if nine { "nine_param" } else { "six_param" }, "{v}");
    assert!((test["critical"].as_f64().unwrap() - 3.5874).abs() < 1e-3, "{test}");
    // The rig's rows are cut out: the move across the hole (the shaft turned unseen) is dropped.
    assert_eq!(v["quality"]["hand_moves"]["dropped"]["gap"], 1, "{v}");
    // A gyro whose full scale the user states (`--range`, any sensor): the moves that reach it
    // are dropped, counted and named; a reading beyond what a part of that range outputs is a
    // bad number (or not this log's range), named with its line.
    let clipped_at_60 = write(
        "clipped60.csv",
        &rewrite(&log, |r| {
            r.gyro_dps = r.gyro_dps.map(|g| g.clamp(-60.0, 60.0));
            r.servo_deg.is_none()
        }),
    );
    let (code, _, err) = calib(&[&clipped_at_60, "--range", "60"]);
    assert_eq!(code, 4, "{err}");
    assert!(err.contains("moves between poses were dropped: they reached the gyro's full scale"), "{err}");
    let (code, _, err) = calib(&[&hand, "--range", "60"]);
    assert_eq!(code, 3, "{err}");
    assert!(err.contains("is beyond the full scale --range states (readings reach at most 72 °/s)"), "{err}");
    // A clipped gyro whose full scale nobody states (issue 31's MPU-6050 session at ±250 °/s):
    // found from its repeated extreme values, the moves that reach it dropped and counted, the
    // rest calibrate; no stated scale and no clipping: nothing dropped as saturated.
    for (clip, dropped) in [(200.0f32, 6), (250.0, 2), (1e4, 0)] {
        let clipped = write(
            "clipped.csv",
            &rewrite(&log, |r| {
                r.gyro_dps = r.gyro_dps.map(|g| g.clamp(-clip, clip));
                r.servo_deg.is_none()
            }),
        );
        let (code, out, err) = calib(&[&clipped]);
        assert_eq!(code, 0, "clip {clip}: {err}");
        let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
        assert_eq!(v["quality"]["hand_moves"]["dropped"]["saturated"], dropped, "clip {clip}: {v}");
        for (a, t) in k(&out).iter().zip(truth) {
            assert!((a / t - 1.0).abs() < 0.003, "clip {clip}: {a} vs {t}");
        }
    }
    let (code, out, err) = calib(&[&hand, "--no-rotations"]);
    assert_eq!(code, 4, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert!(v["gyro"].is_null());
    assert!(v["quality"]["missing"][0].as_str().unwrap().starts_with("gyro:"), "{v}");
    assert!(err.contains("partial calibration"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_log_of_the_procedure_gives_the_procedures_k_and_verdict() {
    // Accepted: the K the procedure stored, from the log alone, to 1e-6.
    let mut rig = Rig::new(Variant::Hobby.config(27, 0), 3);
    let mut p = Procedure::new(Config::default(), None);
    let (log, run) = record_log(&mut rig, &mut p, Faults::default(), "");
    let stored = run.stored[0];
    let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
    assert_eq!(c.replayed, Some("default"));
    // Without the rotation constraints: not the firmware's run any more, no full K.
    let off = offline::calibrate_with(&csvlog::parse(&log).unwrap().rows, None, false).unwrap();
    assert!(off.replayed.is_none() && off.full.is_none() && off.gyro.is_ok());
    // The full K (the rig's axis and the hand-held moves), as stored.
    assert_eq!(stored.method, calib_core::estimators::gyro::Method::Full);
    let k = c.full.as_ref().unwrap().as_ref().unwrap().k;
    let diff = (0..9).map(|i| (k[i / 3][i % 3] - stored.gyro_k[i / 3][i % 3]).abs()).fold(0.0f32, f32::max);
    println!("MEASURED calib_vs_procedure_max_abs_k_diff={diff:e}");
    assert!(diff <= 1e-6, "{diff}");
    // The bias, the temperature and the tempco: the record's (the log's temperature column gives
    // the replay what the procedure saw).
    let off = (0..3).map(|k| (c.bias.bias_dps[k] - stored.gyro_bias_dps[k]).abs()).fold(0.0f32, f32::max);
    println!("MEASURED replayed_bias_vs_record={off:e} tempco={:?}", stored.tempco);
    assert!(off <= 1e-5, "{off}");
    let (rec, close) = (c.record().unwrap(), |a: f32, b: f32| (a - b).abs() <= 1e-6 * b.abs().max(1.0));
    let (t, st) = (rec.tempco.unwrap(), stored.tempco.unwrap());
    assert!((0..3).all(|k| close(t.dps_per_c[k], st.dps_per_c[k]) && close(t.sigma_dps_per_c[k], st.sigma_dps_per_c[k])), "{t:?}");
    assert!(close(rec.temp_c.unwrap(), stored.temp_c.unwrap()), "{rec:?}");
    // A log that ends at the rig's last pose, before the board's solve (its steps need no
    // samples): replayed to the same K.
    let rows = csvlog::parse(&log).unwrap().rows;
    let cut = rows.iter().rposition(|r| r.servo_deg.is_some()).unwrap() + 1;
    let short = offline::calibrate(&rows[..cut], None).unwrap();
    assert_eq!(short.replayed, Some("default"));
    assert_eq!(short.full.as_ref().unwrap().as_ref().unwrap().k, k);
    // Rejected (a gyro scale the acceptance refuses): the same verdict, the same error.
    let mut cfg = Variant::Hobby.config(28, 0);
    cfg.gyro.scale.x = 1.3;
    let mut rig = Rig::new(cfg, 3);
    let mut p = Procedure::new(Config::default(), None);
    let (log, run) = record_log(&mut rig, &mut p, Faults::default(), "");
    assert!(matches!(run.error, Some(calib_core::Error::ResultRejected { axis: 0, .. })), "{:?}", run.error);
    let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
    assert!(matches!(c.gyro, Err(OfflineError::Calib { error: calib_core::Error::ResultRejected { axis: 0, .. }, .. })), "{:?}", c.gyro);
    // Another protocol (the rows reordered into a different timeline) is not replayed.
    let rows = csvlog::parse(&log).unwrap().rows;
    let hand: Vec<Row> = rows.iter().filter(|r| r.servo_deg.is_none()).copied().collect();
    assert_eq!(offline::calibrate(&hand, None).unwrap().replayed, None);
}

#[test]
fn pan_tilt_logs_of_another_protocol_give_the_full_k() {
    use rig_sim::pan_tilt;
    let mut rig = Rig::new(pan_tilt::rig_config(31, 0), 31);
    let log = pan_tilt::log(&mut rig, true);
    let c = offline::calibrate(&csvlog::parse(&log).unwrap().rows, None).unwrap();
    assert_eq!(c.replayed, None);
    let f = c.full.as_ref().unwrap().as_ref().unwrap();
    let (max, rms) = pan_tilt::k_error(f.k, c.accel.m, &rig).unwrap();
    println!("MEASURED pan_tilt_full_k max={max:.2e} rms={rms:.2e} axes={} moves={}", f.n_axes, f.moves);
    assert!(rms <= 5e-4 && max <= 1.5e-3, "rms {rms:e} max {max:e}");
    let v: serde_json::Value = serde_json::from_str(&c.json(0)).unwrap();
    assert_eq!(v["gyro"]["method"], "full");
}

#[test]
fn pan_tilt_rigs_that_cannot_give_the_full_k_are_named() {
    use rig_sim::pan_tilt;
    let full_error = |cfg: RigConfig, tilts: &[f32]| {
        let mut rig = Rig::new(cfg, 32);
        let log = pan_tilt::log_at(&mut rig, true, tilts);
        // The rig alone (the hand-held moves would give the full K anyway).
        let c = offline::calibrate_with(&csvlog::parse(&log).unwrap().rows, None, false).unwrap();
        let e = c.full.expect("a pan/tilt log").expect_err("no full K");
        (e, c.missing().join("; "))
    };
    // Too few tilt settings: one pan axis, and the hinge seen at two orientations only.
    let (e, missing) = full_error(pan_tilt::rig_config(33, 0), &[40.0]);
    assert!(matches!(e, calib_core::Error::AxisUndetermined { .. } | calib_core::Error::TooFewAxes { .. }), "{e:?}");
    assert!(missing.contains("full K: axis") && missing.contains("at least 3 poses"), "{missing}");
}

#[test]
fn another_sensor_s_rate_is_accepted_and_said_but_a_firmware_run_must_be_at_an_odr() {
    use rig_sim::pan_tilt;
    // A hand-held log of "another IMU" at 100 Hz: time stretched by 119/100 and the gyro
    // scaled by 100/119, so that every turn stays what it was.
    let mut rig = Rig::new(pan_tilt::rig_config(41, 0), 41);
    let log = pan_tilt::handheld_only(&pan_tilt::log_at(&mut rig, true, &[]));
    let s = 119.0 / 100.0;
    let other = rewrite(&log, |r| {
        r.t = Time::from_s(r.t.s() * s).unwrap();
        r.gyro_dps = r.gyro_dps.map(|g| (g as f64 / s) as f32);
        true
    });
    let rows = csvlog::parse(&other).unwrap().rows;
    let c = offline::calibrate(&rows, None).unwrap();
    // (the simulated ODR is off nominal by a few %, as on real boards)
    assert!(!c.time_base.lsm9ds1_odr && (85.0..115.0).contains(&c.time_base.rate_hz), "{:?}", c.time_base);
    assert!(c.full.as_ref().is_some_and(|f| f.is_ok()), "calibrated: {:?}", c.missing());
    let json: serde_json::Value = serde_json::from_str(&c.json(0)).unwrap();
    assert_eq!(json["quality"]["sample_rate"]["lsm9ds1_odr"], serde_json::Value::Bool(false));
    // The same in ms is named.
    let ms = rewrite(&other, |r| {
        r.t = Time::from_us(r.t.us() * 1000);
        true
    });
    let err = offline::calibrate(&csvlog::parse(&ms).unwrap().rows, None).unwrap_err().to_string();
    assert!(err.contains("milliseconds"), "{err}");
    // A run of the firmware's own procedure with every third row lost: named, not calibrated.
    let (fw, _) = simulated_log(Variant::Hobby.config(42, 0));
    let n = std::cell::Cell::new(0);
    let lossy = rewrite(&fw, |_| {
        n.set(n.get() + 1);
        n.get() % 3 != 0
    });
    let err = offline::calibrate(&csvlog::parse(&lossy).unwrap().rows, None).unwrap_err();
    assert!(matches!(err, OfflineError::TimeBase { .. }), "{err}");
}
