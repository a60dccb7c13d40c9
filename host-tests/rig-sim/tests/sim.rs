//! Physics checks of the rig simulator (rig_sim::sim).

use nalgebra::{Matrix3, SymmetricEigen, UnitQuaternion, Vector3};
use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rig_sim::sim::{tilted_axis, ContinuousServo, PositionalServo, Reading, Rig, RigConfig, ServoModel, Truth, Vibration, G0};
use rig_sim::sim::{AccelRange, GyroRange, HandLevel};

fn v3(a: [f32; 3]) -> Vector3<f64> {
    Vector3::new(f64::from(a[0]), f64::from(a[1]), f64::from(a[2]))
}

/// Runs for `seconds` of true time and returns the samples.
fn run(rig: &mut Rig, seconds: f64) -> Vec<Reading> {
    let end = rig.time_s() + seconds;
    let mut out = Vec::new();
    while rig.time_s() < end {
        out.push(rig.next_sample());
    }
    out
}

/// Runs for `seconds` of true time and returns each sample with the truth right after it.
fn record(rig: &mut Rig, seconds: f64) -> Vec<(Reading, Truth)> {
    let end = rig.time_s() + seconds;
    let mut out = Vec::new();
    while rig.time_s() < end {
        out.push((rig.next_sample(), rig.truth()));
    }
    out
}

fn mean_accel(samples: &[Reading]) -> Vector3<f64> {
    samples.iter().map(|s| v3(s.accel_g)).sum::<Vector3<f64>>() / samples.len() as f64
}

/// Specific force of a board at rest with attitude `q_wb`, in B: `R_BW ẑ`.
fn gravity_b(q_wb: &UnitQuaternion<f64>) -> Vector3<f64> {
    q_wb.inverse() * Vector3::z()
}

/// Signed angle (rad) from `a` to `b` about unit `u`, both projected on the plane ⟂ `u`.
fn angle_about(a: &Vector3<f64>, b: &Vector3<f64>, u: &Vector3<f64>) -> f64 {
    let (pa, pb) = (a - u * u.dot(a), b - u * u.dot(b));
    u.dot(&pa.cross(&pb)).atan2(pa.dot(&pb))
}

fn with_servo(servo: ServoModel) -> RigConfig {
    RigConfig { servo, ..RigConfig::ideal() }
}

#[test]
fn same_seed_gives_identical_samples() {
    let cfg = RigConfig::realistic(&mut ChaCha8Rng::seed_from_u64(7));
    let script = |seed| {
        let mut rig = Rig::new(cfg, seed);
        rig.set_pulse_us(1200.0);
        let mut s = run(&mut rig, 1.0);
        rig.disturb(0.5, 30.0);
        s.extend(run(&mut rig, 1.0));
        rig.detach_to(UnitQuaternion::from_euler_angles(0.3, -0.2, 1.0), 0.5);
        s.extend(run(&mut rig, 1.0));
        (s, rig.truth())
    };
    let (a, truth_a) = script(11);
    let (b, truth_b) = script(11);
    let (c, _) = script(12);
    assert_eq!(a, b);
    assert_eq!(truth_a, truth_b);
    assert_ne!(a, c, "another seed must give other noise");
}

#[test]
fn ideal_rig_at_rest_measures_gravity() {
    let cfg = RigConfig::ideal();
    let mut rig = Rig::new(cfg, 1);
    let expected = gravity_b(&cfg.mount);
    for s in run(&mut rig, 0.5) {
        let a = v3(s.accel_g);
        assert!((a - expected).norm() < 1e-6, "{a} vs {expected}");
        assert!((a.norm() - 1.0).abs() < 1e-6);
        assert_eq!(s.gyro_dps, [0.0; 3]);
        assert!(!s.accel_saturated && !s.gyro_saturated);
    }
    assert!((rig.truth().specific_force_b_g - expected).norm() < 1e-15);
}

/// Σ ω_k Δt_k over a move equals Δθ · u_B, with vibration, dead band and lever arm on, for a
/// positional move and for two full turns of a continuous servo.
#[test]
fn integrated_ideal_gyro_equals_shaft_turn() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let servos =
        [ServoModel::Positional(PositionalServo::realistic(&mut rng)), ServoModel::Continuous(ContinuousServo::realistic(&mut rng))];
    for servo in servos {
        let cfg = RigConfig { radius_m: 0.02, ..with_servo(servo) };
        let mut rig = Rig::new(cfg, 5);
        rig.set_pulse_us(1100.0);
        run(&mut rig, 1.0);
        let (theta0, axis0) = (rig.truth().shaft_deg, rig.truth().axis_b);
        rig.set_pulse_us(1900.0);
        let (mut exact, mut sampled) = (Vector3::zeros(), Vector3::zeros());
        let mut max_rate = 0.0f64;
        for (s, t) in record(&mut rig, 3.0) {
            exact += t.rate_b_dps * t.dt_s;
            sampled += v3(s.gyro_dps) * t.dt_s;
            max_rate = max_rate.max(t.rate_b_dps.norm());
        }
        let truth = rig.truth();
        let turn = (truth.shaft_deg - theta0) * truth.axis_b;
        assert!(turn.norm() > 90.0 && max_rate > 50.0, "the shaft must have moved: {turn}");
        assert_eq!(axis0, truth.axis_b);
        assert!((exact - turn).norm() < 1e-9 * turn.norm(), "{exact} vs {turn}");
        assert!((sampled - turn).norm() < 1e-6 * turn.norm(), "{sampled} vs {turn}");
    }
}

/// Integrating the ideal gyro (q ← q · exp(ω Δt)) reproduces the attitude through shaft moves,
/// a disturbance, a hand-held pose and re-attachment.
#[test]
fn integrated_ideal_gyro_reproduces_attitude() {
    let mut rig = Rig::new(with_servo(ServoModel::Positional(PositionalServo::ideal())), 9);
    let mut q = rig.truth().q_wb;
    let mut step = |rig: &mut Rig, seconds: f64| {
        for (_, t) in record(rig, seconds) {
            q *= UnitQuaternion::from_scaled_axis(t.rate_b_dps.map(f64::to_radians) * t.dt_s);
        }
    };
    rig.set_pulse_us(1800.0);
    step(&mut rig, 1.0);
    rig.disturb(0.8, 40.0);
    step(&mut rig, 1.0);
    rig.detach_to(UnitQuaternion::from_euler_angles(2.0, 0.5, -1.0), 1.0);
    step(&mut rig, 1.5);
    rig.attach();
    step(&mut rig, 1.5);
    assert!(q.angle_to(&rig.truth().q_wb) < 1e-9);
    assert!(rig.truth().attached);
}

/// The accelerometer tips of poses on the shaft lie on a plane with normal u_B, A·u = cos(tilt)
/// in every pose, and the projected gravity turns by −Δθ about u_B.
#[test]
fn poses_on_the_shaft_lie_on_a_cone_about_the_axis() {
    let cfg = RigConfig::ideal();
    let mut rig = Rig::new(cfg, 2);
    let axis_before = rig.truth().axis_b;
    let mut tips = Vec::new();
    let mut angles = Vec::new();
    for us in [1000.0, 1300.0, 1500.0, 1800.0, 2000.0] {
        rig.set_pulse_us(us);
        let s = run(&mut rig, 1.5);
        tips.push(mean_accel(&s[s.len() - 20..]));
        angles.push(rig.truth().shaft_deg);
        assert!((rig.truth().shaft_deg - (us - 1000.0) * 0.18).abs() < 1e-6);
    }
    let u = rig.truth().axis_b;
    assert_eq!(u, axis_before);
    assert!((u - cfg.axis_b()).norm() < 1e-15 && (u.norm() - 1.0).abs() < 1e-15);

    let centre = tips.iter().sum::<Vector3<f64>>() / tips.len() as f64;
    let scatter: Matrix3<f64> = tips.iter().map(|a| (a - centre) * (a - centre).transpose()).sum();
    let eig = SymmetricEigen::new(scatter);
    let normal = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
    assert!(normal.cross(&u).norm() < 1e-5, "plane normal {normal} vs axis {u}");

    let cos_tilt = cfg.shaft_tilt_deg.to_radians().cos();
    for (i, a) in tips.iter().enumerate() {
        assert!((a.dot(&u) - cos_tilt).abs() < 1e-6, "A·u = {} in pose {i}", a.dot(&u));
        let turned = angle_about(&tips[0], a, &u).to_degrees();
        assert!((turned + (angles[i] - angles[0])).abs() < 1e-4, "pose {i}: {turned}");
    }
}

#[test]
fn odr_error_and_crystal_show_in_timestamps() {
    let cfg = RigConfig { odr_error: -0.04, ..RigConfig::ideal() };
    let mut rig = Rig::new(cfg, 1);
    let t = run(&mut rig, 2.0).iter().map(|s| s.t_s).collect::<Vec<_>>();
    for w in t.windows(2) {
        assert!((w[1] - w[0] - 1.0 / (119.0 * 0.96)).abs() < 1e-12);
    }

    let cfg = RigConfig::realistic(&mut ChaCha8Rng::seed_from_u64(4));
    let mut rig = Rig::new(cfg, 1);
    let t = run(&mut rig, 20.0).iter().map(|s| s.t_s).collect::<Vec<_>>();
    assert!(t.windows(2).all(|w| w[1] > w[0]));
    let spacing = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let expected = (1.0 + cfg.mcu_clock_ppm * 1e-6) / cfg.actual_odr_hz();
    assert!((spacing / expected - 1.0).abs() < 2e-6, "{spacing} vs {expected}");
    assert!(spacing * cfg.odr_hz - 1.0 > 0.02 / 1.05, "slow ODR must show: {spacing}");
    assert!((rig.truth().odr_hz - cfg.actual_odr_hz()).abs() < 1e-12);
}

#[test]
fn outputs_are_whole_lsbs_when_quantised() {
    let counts_off = |v: f32, lsb: f64| {
        let c = f64::from(v) / lsb;
        (c - c.round()).abs()
    };
    let realistic = RigConfig::realistic(&mut ChaCha8Rng::seed_from_u64(5));
    let mut off_grid = 0;
    for (cfg, quantised) in [(realistic, true), (RigConfig::ideal(), false)] {
        let mut rig = Rig::new(cfg, 3);
        rig.set_pulse_us(1900.0);
        let (g_lsb, a_lsb) = (cfg.gyro.range.lsb_dps(), cfg.accel.range.lsb_g());
        for s in run(&mut rig, 2.0) {
            for i in 0..3 {
                let (g, a) = (counts_off(s.gyro_dps[i], g_lsb), counts_off(s.accel_g[i], a_lsb));
                if quantised {
                    assert!(g < 1e-2 && a < 1e-2, "{s:?}");
                } else if g > 0.05 || a > 0.05 {
                    off_grid += 1;
                }
            }
            assert!((s.temp_c * 16.0 - (s.temp_c * 16.0).round()).abs() < 1e-3);
        }
    }
    assert!(off_grid > 100, "unquantised outputs must fall between LSBs");
}

#[test]
fn saturation_is_flagged_beyond_full_scale() {
    // The int16 range at 8.75 mdps/LSB spans ±286.7 °/s ("245 dps" full scale).
    let servo = ContinuousServo { max_rate_dps: 400.0, ..ContinuousServo::ideal() };
    let mut cfg = with_servo(ServoModel::Continuous(servo));
    cfg.gyro.range = GyroRange::Dps245;
    let mut rig = Rig::new(cfg, 1);
    rig.set_pulse_us(1800.0); // 240 °/s, u_z = 6/7: 206 °/s on z
    assert!(run(&mut rig, 1.0).iter().all(|s| !s.gyro_saturated && !s.accel_saturated));
    rig.set_pulse_us(2000.0); // 400 °/s: 343 °/s on z
    let s = *run(&mut rig, 1.0).last().unwrap();
    assert!(s.gyro_saturated && !s.accel_saturated);
    assert_eq!(s.gyro_dps[2], (32767.0 * 8.75e-3) as f32);
    assert!(f64::from(s.gyro_dps[0]).abs() < 286.0);

    let mut cfg = RigConfig::ideal();
    cfg.accel.offset_g = Vector3::repeat(3.0);
    cfg.accel.range = AccelRange::G2;
    let s = Rig::new(cfg, 1).next_sample();
    assert!(s.accel_saturated && !s.gyro_saturated);
    assert_eq!(s.accel_g, [(32767.0 * 0.061e-3) as f32; 3]);
    cfg.accel.range = AccelRange::G4;
    assert!(!Rig::new(cfg, 1).next_sample().accel_saturated);
}

#[test]
fn positional_servo_settles_at_offset_plus_scaled_command() {
    let servo = PositionalServo { offset_deg: 3.0, scale_error: 0.025, ..PositionalServo::ideal() };
    let mut rig = Rig::new(with_servo(ServoModel::Positional(servo)), 1);
    rig.set_pulse_us(1000.0);
    let start = mean_accel(&run(&mut rig, 2.0)[200..]);
    assert!((rig.truth().shaft_deg - 3.0).abs() < 1e-9);
    rig.set_pulse_us(1700.0);
    let end = mean_accel(&run(&mut rig, 3.0)[300..]);
    let expected = 3.0 + 1.025 * 126.0;
    assert!((rig.truth().shaft_deg - expected).abs() < 1e-9, "{}", rig.truth().shaft_deg);
    assert!((servo.target_deg(1700.0) - expected).abs() < 1e-12);
    // Gravity seen in B turned by −(1.025 · 126°) about u_B.
    let turned = angle_about(&start, &end, &rig.truth().axis_b).to_degrees();
    assert!((turned + 1.025 * 126.0).abs() < 1e-4, "{turned}");

    // With a dead band the shaft stops inside it, short of the target.
    let servo = PositionalServo { deadband_us: 4.0, ..servo };
    let mut rig = Rig::new(with_servo(ServoModel::Positional(servo)), 1);
    rig.set_pulse_us(1700.0);
    run(&mut rig, 3.0);
    let miss = expected - rig.truth().shaft_deg;
    let band = 4.0 * 0.18 * 1.025;
    assert!(miss > 0.5 * band && miss <= band, "{miss}");
}

#[test]
fn slew_rate_is_limited() {
    let servo = PositionalServo { max_rate_dps: 250.0, ..PositionalServo::ideal() };
    let mut rig = Rig::new(with_servo(ServoModel::Positional(servo)), 1);
    rig.set_pulse_us(1000.0);
    run(&mut rig, 1.0);
    rig.set_pulse_us(2000.0);
    let (mut prev, mut peak, mut t_10, mut t_170) = (rig.truth().shaft_deg, 0.0f64, None, None);
    for (_, t) in record(&mut rig, 2.0) {
        peak = peak.max((t.shaft_deg - prev) / t.dt_s).max(t.shaft_rate_dps);
        prev = t.shaft_deg;
        if t.shaft_deg > 10.0 && t_10.is_none() {
            t_10 = Some(t.t_s);
        }
        if t.shaft_deg > 170.0 && t_170.is_none() {
            t_170 = Some(t.t_s);
        }
    }
    assert!(peak <= 250.0 * (1.0 + 1e-12) && peak > 0.98 * 250.0, "peak rate {peak}");
    let crossing = t_170.unwrap() - t_10.unwrap();
    assert!(crossing >= 160.0 / 250.0 - 1.0 / 119.0, "{crossing} s");
    assert!((rig.truth().shaft_deg - 180.0).abs() < 1e-9);
}

#[test]
fn stalled_servo_does_not_move() {
    let mut rig = Rig::new(RigConfig::ideal(), 1);
    rig.set_pulse_us(1000.0);
    let before = *run(&mut rig, 0.5).last().unwrap();
    rig.stall(true);
    rig.set_pulse_us(2000.0);
    for s in run(&mut rig, 2.0) {
        assert_eq!(s.gyro_dps, [0.0; 3]);
        assert_eq!(s.accel_g, before.accel_g);
    }
    assert_eq!(rig.truth().shaft_deg, 0.0);
    rig.stall(false);
    run(&mut rig, 2.0);
    assert!((rig.truth().shaft_deg - 180.0).abs() < 1e-9);
}

/// A sensor 5 cm off the axis at a steady 180 °/s feels ω² r towards the axis, ⟂ u_B.
#[test]
fn off_axis_radius_adds_centripetal_acceleration() {
    let cfg = RigConfig { radius_m: 0.05, ..with_servo(ServoModel::Continuous(ContinuousServo::ideal())) };
    let mut rig = Rig::new(cfg, 1);
    rig.set_pulse_us(1800.0);
    let samples = run(&mut rig, 2.0);
    let truth = rig.truth();
    let omega = 180f64.to_radians();
    let expected = omega * omega * 0.05 / G0;
    let extra = truth.specific_force_b_g - gravity_b(&truth.q_wb);
    assert!((truth.shaft_rate_dps - 180.0).abs() < 1e-6);
    assert!((extra.norm() / expected - 1.0).abs() < 1e-6, "{} vs {expected}", extra.norm());
    assert!((truth.lever_b_m.norm() - 0.05).abs() < 1e-15 && truth.lever_b_m.dot(&truth.axis_b).abs() < 1e-15);
    assert!((extra + truth.lever_b_m * omega * omega / G0).norm() < 1e-6 * expected, "not towards the axis");
    let measured = v3(samples.last().unwrap().accel_g) - gravity_b(&truth.q_wb);
    assert!((measured - extra).norm() < 1e-6);
    assert!((v3(samples.last().unwrap().gyro_dps) - 180.0 * truth.axis_b).norm() < 1e-4);
}

#[test]
fn continuous_servo_rate_follows_its_model() {
    let servo = ContinuousServo { neutral_offset_us: 12.0, deadband_us: 8.0, ..ContinuousServo::ideal() };
    let mut rig = Rig::new(with_servo(ServoModel::Continuous(servo)), 1);
    let u = rig.truth().axis_b;
    for (us, rate) in [(1515.0, 0.0), (1800.0, 300.0 * 288.0 / 500.0), (1200.0, -300.0 * 312.0 / 500.0), (2600.0, 300.0)] {
        rig.set_pulse_us(us);
        let s = run(&mut rig, 1.5);
        assert!((servo.rate_dps(us) - rate).abs() < 1e-12);
        assert!((rig.truth().shaft_rate_dps - rate).abs() < 1e-6, "{us} µs");
        let mean = s[s.len() - 50..].iter().map(|s| v3(s.gyro_dps).dot(&u)).sum::<f64>() / 50.0;
        assert!((mean - rate).abs() < 1e-4, "{us} µs: gyro {mean} vs {rate}");
    }
}

#[test]
fn vibration_only_while_moving() {
    let vibration = Vibration { rms_deg: 0.05, freq_hz: 40.0, damping: 0.2 };
    let servo = ContinuousServo { vibration, ..ContinuousServo::ideal() };
    let mut rig = Rig::new(with_servo(ServoModel::Continuous(servo)), 8);
    rig.set_pulse_us(2000.0);
    run(&mut rig, 1.0);
    let (t0, a0) = (rig.truth().t_s, rig.truth().shaft_deg);
    let mut jitter = Vec::new();
    for (_, t) in record(&mut rig, 20.0) {
        jitter.push(t.shaft_deg - a0 - 300.0 * (t.t_s - t0));
    }
    let mean = jitter.iter().sum::<f64>() / jitter.len() as f64;
    let rms = (jitter.iter().map(|j| (j - mean).powi(2)).sum::<f64>() / jitter.len() as f64).sqrt();
    assert!((rms / 0.05 - 1.0).abs() < 0.3, "vibration RMS {rms}°");
    rig.set_pulse_us(1500.0);
    run(&mut rig, 1.0);
    assert!(rig.truth().shaft_rate_dps.abs() < 1e-3, "{}", rig.truth().shaft_rate_dps);
}

#[test]
fn hand_held_pose_and_reattachment() {
    let cfg = RigConfig::ideal();
    let mut rig = Rig::new(cfg, 1);
    let target = UnitQuaternion::from_euler_angles(0.4, 2.5, -0.7);
    rig.detach_to(target, 1.0);
    let moving = run(&mut rig, 1.0);
    assert!(moving.iter().any(|s| v3(s.gyro_dps).norm() > 10.0));
    assert!(!rig.truth().attached);
    rig.set_pulse_us(1500.0); // the shaft keeps turning while the board is off it
    let held = run(&mut rig, 1.5);
    for s in &held[5..] {
        assert!((v3(s.accel_g) - gravity_b(&target)).norm() < 1e-6);
        assert!(v3(s.gyro_dps).norm() < 1e-9);
    }
    let theta = rig.truth().shaft_deg;
    assert!((theta - 90.0).abs() < 1e-6);
    rig.attach();
    run(&mut rig, 1.5);
    let truth = rig.truth();
    assert!(truth.attached);
    let on_shaft = UnitQuaternion::from_axis_angle(&cfg.shaft_axis_w(), theta.to_radians()) * cfg.mount;
    assert!(truth.q_wb.angle_to(&on_shaft) < 1e-12);
    assert_eq!(truth.axis_b, cfg.axis_b());
}

#[test]
fn disturbance_wobbles_then_settles() {
    let mut rig = Rig::new(RigConfig::ideal(), 1);
    let rest = rig.next_sample();
    rig.disturb(1.0, 30.0);
    let peak = run(&mut rig, 1.2).iter().map(|s| v3(s.gyro_dps).norm()).fold(0.0, f64::max);
    assert!(peak > 3.0 && peak < 60.0, "peak {peak} °/s");
    let after = rig.next_sample();
    assert!(v3(after.gyro_dps).norm() < 1e-9);
    assert!((v3(after.accel_g) - v3(rest.accel_g)).norm() < 1e-6);
}

/// Raw outputs follow g = C_g ω + b and a = C_a f + o with the truth's K = C_g⁻¹ and C_a.
#[test]
fn truth_describes_the_sensor_models() {
    // The linear drift alone (no warm-up, walk or Earth rate: `rate_b_dps` is the rig's).
    let mut cfg = RigConfig::realistic(&mut ChaCha8Rng::seed_from_u64(6)).constant_bias();
    (cfg.gyro.noise_dps_rthz, cfg.gyro.quantize) = (0.0, false);
    (cfg.accel.noise_ug_rthz, cfg.accel.quantize) = (0.0, false);
    cfg.temp_drift_c_per_s = 0.01;
    cfg.gyro.bias_tempco_dps_per_c = Vector3::new(0.01, -0.02, 0.005);
    cfg.gyro.scale_tempco_per_c = Vector3::zeros();
    let mut rig = Rig::new(cfg, 1);
    rig.set_pulse_us(1900.0);
    for (s, t) in record(&mut rig, 3.0) {
        let omega = t.gyro_k * (v3(s.gyro_dps) - t.gyro_bias_dps);
        assert!((omega - t.rate_b_dps).norm() < 1e-4, "{omega} vs {}", t.rate_b_dps);
        let a = t.accel_c * t.specific_force_b_g + t.accel_offset_g;
        assert!((v3(s.accel_g) - a).norm() < 1e-6);
        assert!((f64::from(s.temp_c) - t.temp_c).abs() <= 1.0 / 32.0 + 1e-6);
    }
    let t = rig.truth();
    let drift = cfg.gyro.bias_tempco_dps_per_c * 0.01 * t.t_s;
    assert!((t.gyro_bias_dps - cfg.gyro.bias_dps - drift).norm() < 1e-12);
    // C = (I + misalignment) · diag(scale), with a misalignment that is really there.
    let c_g = (Matrix3::identity() + cfg.gyro.misalignment) * Matrix3::from_diagonal(&cfg.gyro.scale);
    let c_a = (Matrix3::identity() + cfg.accel.misalignment) * Matrix3::from_diagonal(&cfg.accel.scale);
    assert!(cfg.gyro.misalignment.norm() > 1e-4 && cfg.accel.misalignment.norm() > 1e-4);
    assert!((t.gyro_k * c_g - Matrix3::identity()).norm() < 1e-12);
    assert!((t.accel_c - c_a).norm() < 1e-15);
}

/// The gyro's scale moves with temperature: each reading follows `C_g` at its own temperature,
/// and the truth's K is the one at the samples' mean temperature (what a calibration over them
/// measures).
#[test]
fn the_gyro_scale_follows_the_temperature() {
    let mut cfg = RigConfig::realistic(&mut ChaCha8Rng::seed_from_u64(6)).constant_bias();
    (cfg.gyro.noise_dps_rthz, cfg.gyro.quantize) = (0.0, false);
    cfg.temp_drift_c_per_s = 0.5;
    cfg.gyro.scale_tempco_per_c = Vector3::new(2e-4, -1e-4, 1.5e-4);
    let mut rig = Rig::new(cfg, 1);
    rig.set_pulse_us(1900.0);
    let samples = record(&mut rig, 4.0);
    for (s, t) in &samples {
        let c = cfg.gyro.matrix_at(cfg.delta_temp_c(t.t_s));
        assert!((v3(s.gyro_dps) - t.gyro_bias_dps - c * t.rate_b_dps).norm() < 1e-4);
    }
    let moving = samples.iter().filter(|(_, t)| t.rate_b_dps.norm() > 10.0).count();
    assert!(moving > 40, "the servo must turn for the readings to show the scale: {moving}");
    let mean = samples.iter().map(|(_, t)| cfg.delta_temp_c(t.t_s)).sum::<f64>() / samples.len() as f64;
    assert!(mean > 0.5, "{mean}");
    let k = rig.truth().gyro_k;
    assert!((k * cfg.gyro.matrix_at(mean) - Matrix3::identity()).norm() < 1e-9);
    assert!((k * cfg.gyro.matrix() - Matrix3::identity()).norm() > 1e-4, "the scale did not move");
}

#[test]
fn realistic_configs_respect_their_ranges() {
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    for _ in 0..50 {
        let cfg = RigConfig::realistic(&mut rng);
        assert!(cfg.axis_b().iter().all(|c| c.abs() >= 0.2 - 1e-12), "{}", cfg.axis_b());
        assert!((20.0..70.0).contains(&cfg.shaft_tilt_deg));
        assert!((-0.05..-0.02).contains(&cfg.odr_error));
        let s_w = tilted_axis(cfg.shaft_tilt_deg, cfg.shaft_azimuth_deg);
        assert!((cfg.mount * cfg.axis_b() - s_w.into_inner()).norm() < 1e-12);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(12))]

    /// Σ ω Δt = Δθ u_B for any tilt, axis and sequence of positional commands.
    #[test]
    fn gyro_integral_matches_any_move(
        tilt in 5.0..85.0f64,
        azimuth in 0.0..360.0f64,
        axis in prop::array::uniform3(-1.0..1.0f64),
        twist in 0.0..360.0f64,
        pulses in prop::collection::vec(1000.0..2000.0f64, 1..4),
    ) {
        let axis = Vector3::from(axis);
        prop_assume!(axis.norm() > 0.1);
        let cfg = RigConfig { shaft_tilt_deg: tilt, shaft_azimuth_deg: azimuth, ..RigConfig::ideal() }
            .with_axis(axis, twist);
        let mut rig = Rig::new(cfg, 1);
        let mut sum = Vector3::zeros();
        for us in pulses {
            rig.set_pulse_us(us);
            for (_, t) in record(&mut rig, 1.0) {
                sum += t.rate_b_dps * t.dt_s;
            }
        }
        let truth = rig.truth();
        prop_assert!((truth.axis_b - axis.normalize()).norm() < 1e-12);
        let turn = truth.shaft_deg * truth.axis_b;
        prop_assert!((sum - turn).norm() < 1e-9 * turn.norm().max(1.0));
    }
}

/// White noise RMS per sample is density · √(ODR/2) at the actual ODR.
#[test]
fn noise_rms_matches_density() {
    let cfg = RigConfig::realistic(&mut ChaCha8Rng::seed_from_u64(12));
    let samples = run(&mut Rig::new(cfg, 4), 30.0);
    let half_odr = (cfg.actual_odr_hz() / 2.0).sqrt();
    let std = |f: &dyn Fn(&Reading) -> f64| {
        let n = samples.len() as f64;
        let mean = samples.iter().map(f).sum::<f64>() / n;
        (samples.iter().map(|s| (f(s) - mean).powi(2)).sum::<f64>() / n).sqrt()
    };
    for i in 0..3 {
        let g = std(&|s: &Reading| f64::from(s.gyro_dps[i])) / (cfg.gyro.noise_dps_rthz * half_odr);
        let a = std(&|s: &Reading| f64::from(s.accel_g[i])) / (cfg.accel.noise_ug_rthz * 1e-6 * half_odr);
        assert!((g - 1.0).abs() < 0.06 && (a - 1.0).abs() < 0.06, "axis {i}: {g} {a}");
    }
}

/// While a continuous servo spins up, the lever arm also feels the tangential α × r.
#[test]
fn off_axis_radius_adds_tangential_acceleration() {
    let cfg = RigConfig { radius_m: 0.05, ..with_servo(ServoModel::Continuous(ContinuousServo::ideal())) };
    let mut rig = Rig::new(cfg, 1);
    run(&mut rig, 0.1);
    rig.set_pulse_us(2000.0);
    let rec = record(&mut rig, 0.2);
    let mut checked = 0;
    for w in rec.windows(3) {
        let (before, now, after) = (&w[0].1, &w[1].1, &w[2].1);
        let alpha = (after.shaft_rate_dps - before.shaft_rate_dps).to_radians() / (after.t_s - before.t_s);
        if before.shaft_rate_dps <= 0.0 || alpha < 20.0 {
            continue; // not spinning up smoothly across the window
        }
        let (u, r, omega) = (now.axis_b, now.lever_b_m, now.shaft_rate_dps.to_radians());
        let expected = ((u * alpha).cross(&r) - r * omega * omega) / G0;
        let extra = now.specific_force_b_g - gravity_b(&now.q_wb);
        assert!((extra - expected).norm() < 0.02 * expected.norm(), "{extra} vs {expected}");
        checked += 1;
    }
    assert!(checked > 5, "the spin-up must be sampled");
}

/// The warm-up (1 − e^(−t/τ) from power-on), the bias random walk and the Earth's rotation,
/// each off by default: a board at rest measures bias(T(t)) + walk + the Earth rate in its
/// frame, and the truth's bias follows the temperature and the walk.
#[test]
fn warm_up_bias_walk_and_earth_rate() {
    use rig_sim::sim::{Warmup, EARTH_RATE_RAD_S};
    let mut cfg = RigConfig::ideal();
    cfg.warmup = Some(Warmup { rise_c: 4.0, tau_s: 100.0, since_power_on_s: 10.0 });
    assert_eq!(cfg.delta_temp_c(0.0), 0.0);
    let left = 4.0 * (-0.1f64).exp();
    assert!((cfg.delta_temp_c(1e4) - left).abs() < 1e-9, "the rest of the rise after 10 s");
    assert!(cfg.delta_temp_c(10.0) > cfg.delta_temp_c(100.0) - cfg.delta_temp_c(90.0), "steepest first");
    // Earth rate at the pole: the ideal gyro at rest reads ω_e along W's z in the body frame.
    cfg.latitude_deg = Some(90.0);
    cfg.gyro.bias_tempco_dps_per_c = Vector3::new(0.03, -0.05, 0.04);
    let mut rig = Rig::new(cfg, 3);
    let samples = record(&mut rig, 2.0);
    let (s, t) = samples.last().unwrap();
    let earth_b = (t.q_wb.inverse() * Vector3::z()) * EARTH_RATE_RAD_S.to_degrees();
    assert!((v3(s.gyro_dps) - t.gyro_bias_dps - earth_b).norm() < 1e-6, "{:?}", s.gyro_dps);
    assert!((earth_b.norm() - 0.004178).abs() < 1e-5);
    let expected_bias = cfg.gyro.bias_tempco_dps_per_c * cfg.delta_temp_c(t.t_s);
    assert!((t.gyro_bias_dps - expected_bias).norm() < 1e-12);
    // The walk: 5e-4 °/s/√s over 400 s spreads the bias by ~0.01 °/s per axis.
    let mut cfg = RigConfig::ideal();
    cfg.bias_rw_dps_rtsec = 5e-4;
    let mut rig = Rig::new(cfg, 4);
    let samples = record(&mut rig, 400.0);
    let (s, t) = samples.last().unwrap();
    assert!((v3(s.gyro_dps) - t.gyro_bias_dps).norm() < 1e-6, "the reading follows the truth's bias");
    let spread = t.gyro_bias_dps.norm() / 3f64.sqrt();
    assert!((0.002..0.04).contains(&spread), "walk {spread:.4} °/s after 400 s (expected ~0.01)");
}

/// Error-free sensors, the board held still in the air by `level` (10 s after 2 s to settle):
/// the gyro's RMS (°/s), its largest turn from the held attitude (°), the linear acceleration of
/// every sample (g, the reading less gravity) and the ODR (Hz).
fn held_still(level: HandLevel, seed: u64) -> (f64, f64, Vec<Vector3<f64>>, f64) {
    let cfg = RigConfig { hand: Some(level), ..RigConfig::ideal() };
    let mut rig = Rig::new(cfg, seed);
    let q = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.7);
    rig.detach_to(q, 0.5);
    run(&mut rig, 2.0);
    let s = record(&mut rig, 10.0);
    let rms = (s.iter().map(|(r, _)| v3(r.gyro_dps).norm_squared()).sum::<f64>() / s.len() as f64).sqrt();
    let tilt = s.iter().map(|(_, t)| t.q_wb.angle_to(&q).to_degrees()).fold(0.0, f64::max);
    let lin = s.iter().map(|(r, t)| v3(r.accel_g) - gravity_b(&t.q_wb)).collect();
    (rms, tilt, lin, rig.config().odr_hz)
}

#[test]
fn a_hand_sways_and_trembles_as_the_literature_says_and_braced_a_quarter_of_it() {
    // Error-free sensors, the board held still in the air: what the gyro and the accelerometer
    // see is the hand. Issue 31's figures: gyro RMS up to ~2 deg/s, linear accelerations up to
    // ~0.01 g, sway 0.1-0.3 deg; braced about a quarter.
    let measure = |level: HandLevel, seed: u64| {
        let (rms, tilt, lin, _) = held_still(level, seed);
        (rms, tilt, lin.iter().map(|v| v.norm()).fold(0.0, f64::max))
    };
    for seed in 1..4 {
        let (rms, tilt, lin) = measure(HandLevel::Free, seed);
        println!("MEASURED free hand seed {seed}: gyro RMS {rms:.2} deg/s, largest turn {tilt:.3} deg, largest linear accel {lin:.4} g");
        assert!((0.5..=2.5).contains(&rms) && (0.1..=0.6).contains(&tilt) && (0.003..=0.015).contains(&lin));
        let (b_rms, b_tilt, b_lin) = measure(HandLevel::Braced, seed);
        assert!((b_rms / rms - 0.25).abs() < 0.01 && (b_tilt / tilt - 0.25).abs() < 0.02 && (b_lin / lin - 0.25).abs() < 0.02);
    }
}

#[test]
fn every_hand_of_the_family_stays_within_what_hands_do() {
    // Error-free sensors, the board held still: gyro RMS, largest turn, largest linear
    // acceleration (for the hands turning about a pivot away from the sensor, the turn's own)
    // and the linear acceleration averaged over 2 s (what a pose's mean keeps).
    for level in rig_sim::sim::HANDS {
        for seed in 1..6 {
            let (rms, tilt, lin, odr_hz) = held_still(level, seed);
            let peak = lin.iter().map(|v| v.norm()).fold(0.0, f64::max);
            let w = (2.0 * odr_hz) as usize;
            let mean2 = lin.chunks_exact(w).map(|c| (c.iter().sum::<Vector3<f64>>() / c.len() as f64).norm()).fold(0.0, f64::max);
            println!(
                "MEASURED {} seed {seed}: gyro RMS {rms:.2} deg/s, turn {tilt:.3} deg, linear accel {peak:.4} g, over 2 s {mean2:.5} g",
                level.name()
            );
            // Issue 31's figures for a hand: gyro RMS up to ~2 deg/s, sway 0.1-0.3 deg in the
            // air (a quarter braced), linear accelerations up to ~0.01 g; a pose's mean keeps
            // a fraction of them.
            assert!((0.1..=2.5).contains(&rms) && (0.03..=0.35).contains(&tilt), "{} seed {seed}", level.name());
            assert!(peak <= 0.015 && mean2 <= 0.3 * peak.max(1e-3), "{} seed {seed}", level.name());
        }
    }
}

/// The models' raw axes (what the parts report, from their sources) and calib-core's maps into
/// the board frame (what the drivers and the record conversions apply) undo each other.
#[test]
fn the_part_models_raw_axes_are_the_board_maps_inverses() {
    use calib_core::board::{BMI270, BMM150, LSM9DS1_AG, LSM9DS1_MAG};
    let v = [0.25f32, -0.5, 2.0];
    let lsm = rig_sim::lsm_model::Lsm9ds1Model::raw_axes(v);
    assert_eq!(LSM9DS1_AG.apply(lsm), v);
    // The LSM9DS1's magnetometer: x is its accelerometer's −x (DS Figure 1).
    assert_eq!(LSM9DS1_MAG.apply([-lsm[0], lsm[1], lsm[2]]), v);
    assert_eq!(BMI270.apply(rig_sim::bmi_model::Bmi270Model::raw_axes(v)), v);
    assert_eq!(BMM150.apply(rig_sim::bmm_model::raw_axes(v)), v);
}
