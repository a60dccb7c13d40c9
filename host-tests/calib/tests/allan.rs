//! `calib allan`: the noise figures of a static log recover the simulator's noise (white density,
//! random walk) within their uncertainty; a moving or short log is a named error; the JSON and
//! Kalibr's YAML are written.

use calib::allan::{analyse, AllanError};
use calib::csvlog::{self, Row};
use common::calib;
use rig_sim::sim::{Rig, RigConfig};
use rig_sim::variant::Variant;

use crate::common;

/// The simulator's gyro random walk here (°/s/√s).
const GYRO_RW: f64 = 5e-4;

/// A rig whose board lies still on the idle shaft: the realistic sensor noise, a bias random walk,
/// nothing else that moves the bias.
fn still(seed: u64) -> RigConfig {
    let mut cfg = Variant::Hobby.config(seed, 0).constant_bias();
    cfg.bias_rw_dps_rtsec = GYRO_RW;
    cfg
}

fn rows(cfg: RigConfig, seed: u64, seconds: f64) -> Vec<Row> {
    let mut rig = Rig::new(cfg, seed);
    let mut out = vec![];
    loop {
        let r = rig.next_sample();
        if r.t_s > seconds {
            return out;
        }
        out.push(rig_sim::harness::bare_row(&r));
    }
}

#[test]
fn an_hour_still_recovers_the_simulated_noise_within_its_uncertainty() {
    let cfg = still(41);
    let a = analyse(&rows(cfg, 41, 3600.0)).unwrap();
    assert!((a.sample_rate_hz / cfg.actual_odr_hz() - 1.0).abs() < 1e-3 && a.duration_s > 3500.0);
    // The simulator's densities are one-sided (RMS per sample = density · √(ODR/2)): N = density/√2,
    // with the output's rounding to counts (LSB²/12 per sample) on top.
    let two_sided = |density: f64, lsb: f64| (density * density / 2.0 + lsb * lsb / (12.0 * a.sample_rate_hz)).sqrt();
    let gyro_n = two_sided(cfg.gyro.noise_dps_rthz, cfg.gyro.range.lsb_dps());
    let accel_n = two_sided(cfg.accel.noise_ug_rthz * 1e-6, cfg.accel.range.lsb_g());
    for k in 0..3 {
        let (n, rw, an, arw) = (a.gyro.noise_density[k], a.gyro.random_walk[k], a.accel.noise_density[k], a.accel.random_walk[k]);
        println!(
            "axis {k}: gyro N {:.6} ± {:.6} (true {gyro_n:.6}), K {:.2e} ± {:.1e} (true {GYRO_RW:.1e}); accel N {:.4e} ± {:.1e} (true {accel_n:.4e}), K {:.1e} ± {:.1e} (none)",
            n.value, n.sigma, rw.value, rw.sigma, an.value, an.sigma, arw.value, arw.sigma
        );
        assert!((n.value - gyro_n).abs() <= 3.0 * n.sigma && n.sigma < 0.01 * gyro_n, "gyro N axis {k}");
        assert!((rw.value - GYRO_RW).abs() <= 3.0 * rw.sigma && rw.sigma < 0.3 * GYRO_RW, "gyro K axis {k}");
        assert!((an.value - accel_n).abs() <= 3.0 * an.sigma && an.sigma < 0.01 * accel_n, "accel N axis {k}");
        // No accelerometer random walk in the simulator: none found, or one within its 1σ of 0.
        assert!(arw.value <= 3.0 * arw.sigma && arw.sigma < 1e-5, "accel K axis {k}");
        assert!((a.gyro.datasheet_density[k] / n.value - 2f64.sqrt()).abs() < 1e-12);
    }
    // The curve falls as 1/√τ, then rises as the walk takes over (its floor between).
    let (floor, at) = a.gyro.adev_floor[0];
    assert!(at > 5.0 && at < 200.0 && floor > 0.0, "floor {floor} at {at} s");
    // Its plot, rendered: a marker per point and axis, falling then rising on the page.
    let plot = calib::report::adev_plot("gyro", "°/s", &a.gyro).unwrap();
    let tree = resvg::usvg::Tree::from_str(&plot.svg, &resvg::usvg::Options::default()).unwrap();
    let size = tree.size().to_int_size();
    let mut pixmap = resvg::tiny_skia::Pixmap::new(size.width(), size.height()).unwrap();
    resvg::render(&tree, resvg::tiny_skia::Transform::default(), &mut pixmap.as_mut());
    for (axis, m) in plot.markers.iter().enumerate() {
        assert_eq!(m.len(), a.gyro.tau_s.len());
        let c = calib::report::AXES[axis];
        // Each axis' last point is drawn in its colour (later axes may cover earlier ones elsewhere).
        let (x, y) = m[m.len() - 1];
        let p = pixmap.pixel(x as u32, y as u32).unwrap();
        assert!(axis < 2 || (p.red(), p.green(), p.blue()) == (c.0, c.1, c.2), "axis {axis} at ({x}, {y})");
        let lowest = m.iter().enumerate().max_by_key(|(_, p)| p.1).map(|(i, _)| i).unwrap();
        assert!(lowest > 0 && lowest < m.len() - 1, "the curve's floor is inside the plot (screen y grows down)");
    }
}

#[test]
fn a_log_that_moves_or_is_short_is_named_and_the_cli_writes_json_and_kalibr_yaml() {
    let cfg = still(42);
    let short = rows(cfg, 42, 60.0);
    assert!(matches!(analyse(&short), Err(AllanError::TooShort { duration_s }) if duration_s < 61.0));
    // Turned by hand for a moment in the middle (a tenth of the log): not a static log.
    let mut moved = rows(cfg, 42, 300.0);
    let n = moved.len();
    for r in &mut moved[n / 2..n / 2 + n / 10] {
        r.gyro_dps[2] += 40.0;
        r.accel_g[0] += 0.3;
    }
    assert!(matches!(analyse(&moved), Err(AllanError::NotStatic { .. })), "{:?}", analyse(&moved).map(|a| a.duration_s));
    // Rows lost (a host that paused reading USB): named, not analysed.
    let mut lossy = rows(cfg, 42, 300.0);
    lossy.drain(1000..1100);
    assert_eq!(analyse(&lossy), Err(AllanError::Gaps { missing: 100 }));
    // An axis that never changes (a stuck output) gives figures of 0, not NaN.
    let mut stuck = rows(cfg, 42, 300.0);
    stuck.iter_mut().for_each(|r| r.gyro_dps[1] = 0.5);
    let a = analyse(&stuck).unwrap();
    // 0 up to rounding (the jittered time stamps leave ~1e-16), finite.
    assert!(a.gyro.noise_density[1].value.abs() < 1e-12 && a.gyro.noise_density[0].value > 0.0, "{:?}", a.gyro.noise_density);
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("allan");
    std::fs::create_dir_all(&dir).unwrap();
    let (log, yaml) = (dir.join("still.csv"), dir.join("imu.yaml"));
    let mut text = csvlog::header();
    for r in rows(cfg, 42, 300.0) {
        csvlog::format_row(&mut text, &r);
    }
    std::fs::write(&log, text).unwrap();
    let page = dir.join("allan.html");
    let (code, out, err) = calib(&["allan", log.to_str().unwrap(), "--yaml", yaml.to_str().unwrap(), "--report", page.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let html = std::fs::read_to_string(&page).unwrap();
    assert_eq!(html.matches("<svg").count(), 2, "gyro and accelerometer plots");
    assert!(html.contains("N (°/s/√Hz)") && html.contains("± "));
    let j: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    let n = j["allan"]["gyro"]["noise_density"][0]["value"].as_f64().unwrap();
    assert!((n / (cfg.gyro.noise_dps_rthz / 2f64.sqrt()) - 1.0).abs() < 0.05, "{n}");
    assert_eq!(j["allan"]["gyro"]["tau_s"].as_array().unwrap().len(), j["allan"]["gyro"]["adev"].as_array().unwrap().len());
    let y = std::fs::read_to_string(&yaml).unwrap();
    let value = |key: &str| -> f64 {
        let line = y.lines().find(|l| l.starts_with(&format!("{key}:"))).unwrap_or_else(|| panic!("{key} in {y}"));
        line.split_whitespace().nth(1).unwrap().parse().unwrap()
    };
    // SI units: rad/s/√Hz for the gyro, m/s²/√Hz for the accelerometer; every figure > 0.
    assert!((value("gyroscope_noise_density") / (n * std::f64::consts::PI / 180.0) - 1.0).abs() < 0.05);
    for key in ["accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_random_walk", "update_rate"] {
        assert!(value(key) > 0.0, "{key}");
    }
    assert!(y.contains("rostopic: /imu0"));
    let (code, _, err) = calib(&["allan", dir.join("missing.csv").to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
}
