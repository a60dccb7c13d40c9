//! A scripted hobby-servo session on the simulated rig, solved by both gyro estimators: the
//! realistic benchmark of `paper-tables` (servo angle-scale error up to ±3 %, ODR −4 %,
//! accelerometer calibrated by our own 9-parameter fit on 12 hand-held poses).
//!
//! Script (MCU time): rest 2 s (bias) → 12 hand-held icosahedron poses → back on the shaft →
//! 7 static poses 0°…180° every 30° and back (settle 0.7 s, average 1 s), each move commanded
//! at 30 °/s → the paper's rotation: 0° → 180° commanded at 20 °/s, `ḡ` averaged over its
//! constant-rate middle. The sweep estimator uses the moves, the paper's the rotation.

use crate::moments::Moments;
use crate::session::handheld_attitudes;
use crate::sim::{Rig, RigConfig, Sample, ServoModel};
use calib_core::accel::AccelCalibrator;
use calib_core::axis::{GeometryLimits, Poses};
use calib_core::bias::{BiasEstimator, BiasLimits};
use calib_core::gyro::GyroCal;
use calib_core::stats::Welford3;
use calib_core::sweep::{Integrator, Moves};
use calib_core::vec3::sub;
use calib_core::{paper, sweep, Error};
use nalgebra::Matrix3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};

/// Pulse (µs) for a nominal servo angle (°): 1000–2000 µs ↔ 0–180°.
pub fn pulse_for_deg(deg: f64) -> f64 {
    1000.0 + deg / 0.18
}

/// Both estimators' results and the truth of one session.
#[derive(Debug, Clone, Copy)]
pub struct Session {
    /// Sweep estimator.
    pub sweep: Result<GyroCal, Error>,
    /// Paper estimator with the nominal (commanded) speed.
    pub paper: Result<GyroCal, Error>,
    /// True diagonal of `K`.
    pub k_true: [f64; 3],
}

impl Session {
    /// Relative scale errors `K̂_ii / K_ii − 1` of a result.
    pub fn rel_errors(&self, cal: &Result<GyroCal, Error>) -> Option<[f64; 3]> {
        cal.as_ref().ok().map(|c| std::array::from_fn(|i| c.k[i][i] as f64 / self.k_true[i] - 1.0))
    }
}

/// Feeds samples to `f` for `secs` seconds of MCU time.
fn run_for(rig: &mut Rig, secs: f64, mut f: impl FnMut(&Sample)) {
    let t0 = rig.next_sample().t_s;
    loop {
        let s = rig.next_sample();
        if s.t_s - t0 >= secs {
            break;
        }
        f(&s);
    }
}

/// Ramps the pulse from `from_deg` to `to_deg` at `rate_dps` (nominal), feeding every sample.
fn ramp(rig: &mut Rig, from_deg: f64, to_deg: f64, rate_dps: f64, mut f: impl FnMut(&Sample)) {
    let dur = (to_deg - from_deg).abs() / rate_dps;
    let t0 = rig.next_sample().t_s;
    loop {
        let s = rig.next_sample();
        let x = ((s.t_s - t0) / dur).min(1.0);
        rig.set_pulse_us(pulse_for_deg(from_deg + (to_deg - from_deg) * x));
        f(&s);
        if x >= 1.0 {
            break;
        }
    }
}


/// Runs the scripted session on a rig.
pub fn session(cfg: RigConfig, seed: u64) -> Result<Session, Error> {
    let mut rig = Rig::new(cfg, seed);
    let k_true = std::array::from_fn(|i| rig.truth().gyro_k[(i, i)]);
    rig.set_pulse_us(pulse_for_deg(0.0));
    run_for(&mut rig, 1.5, |_| {});
    let mut b = BiasEstimator::new();
    run_for(&mut rig, 2.0, |s| b.add(s.gyro_dps, s.accel_g));
    let bias = b.finish(&BiasLimits::default())?.bias_dps;

    // Hand-held accelerometer poses: the 12 icosahedron vertices pointing up in turn.
    let mut acc = AccelCalibrator::new();
    for q in handheld_attitudes() {
        rig.detach_to(q, 1.0);
        run_for(&mut rig, 1.5, |_| {});
        let mut w = Welford3::new();
        run_for(&mut rig, 1.0, |s| w.add(s.accel_g));
        acc.add_pose(w.mean().map(|x| x as f32))?;
    }
    let accel = acc.solve9()?;
    rig.attach();
    run_for(&mut rig, 2.5, |_| {});

    // Static poses and the moves between them.
    let angles: Vec<f64> = (0..=6).map(|i| 30.0 * i as f64).chain((0..6).rev().map(|i| 30.0 * i as f64)).collect();
    let (mut poses, mut moves) = (Poses::new(), Moves::new());
    let mut integ = Integrator::new();
    let mut prev: Option<(u8, f64)> = None;
    for &deg in &angles {
        if let Some((_, from)) = prev {
            ramp(&mut rig, from, deg, 30.0, |s| integ.add(s.t_s, sub(s.gyro_dps, bias)));
        }
        run_for(&mut rig, 0.7, |s| integ.add(s.t_s, sub(s.gyro_dps, bias)));
        let mut w = Welford3::new();
        let mut last = None;
        run_for(&mut rig, 1.0, |s| {
            w.add(s.accel_g);
            last = Some(*s);
        });
        let idx = poses.push(accel.apply(w.mean().map(|x| x as f32)))?;
        if let Some((from, _)) = prev {
            moves.push(from, idx, integ.gamma())?;
        }
        // The next move starts where this pose's averaging window ends.
        integ = Integrator::new();
        if let Some(s) = last {
            integ.add(s.t_s, sub(s.gyro_dps, bias));
        }
        prev = Some((idx, deg));
    }

    // The paper's constant-rate rotation, 0° → 180° at a commanded 20 °/s.
    let omega_n = 20.0;
    rig.set_pulse_us(pulse_for_deg(0.0));
    run_for(&mut rig, 1.5, |_| {});
    let (mut rot, mut t_start) = (Welford3::new(), None::<f64>);
    ramp(&mut rig, 0.0, 180.0, omega_n, |s| {
        let t0 = *t_start.get_or_insert(s.t_s);
        if s.t_s - t0 > 1.5 && s.t_s - t0 < 180.0 / omega_n - 0.5 {
            rot.add(sub(s.gyro_dps, bias));
        }
    });
    let limits = GeometryLimits::default();
    let gbar = rot.mean().map(|x| x as f32);
    Ok(Session {
        sweep: sweep::solve(&poses, &moves, &limits),
        paper: paper::solve(&poses, gbar, omega_n as f32, &limits),
        k_true,
    })
}

/// The rig variants of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// Hobby servo as drawn (angle-scale error U(−3, 3) %, offset), sensors without cross-axis
    /// misalignment: the 6-parameter world of the paper.
    Hobby,
    /// The same rigs with an exact servo (no scale error, no offset).
    ExactServo,
    /// Hobby servo and cross-axis misalignment (gyro ±0.2°, accel ±0.1°), which a diagonal `K`
    /// from one rotation axis cannot separate from scale.
    HobbyMisaligned,
}

impl Variant {
    fn name(self) -> &'static str {
        match self {
            Variant::Hobby => "hobby_servo",
            Variant::ExactServo => "exact_servo",
            Variant::HobbyMisaligned => "hobby_servo_misaligned",
        }
    }

    /// The rig of run `run` under this variant (same draw for every variant).
    pub fn config(self, seed: u64, run: usize) -> RigConfig {
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1000).wrapping_add(run as u64));
        let mut cfg = RigConfig::realistic(&mut rng);
        cfg.odr_error = -0.04;
        if self != Variant::HobbyMisaligned {
            cfg.gyro.misalignment = Matrix3::zeros();
            cfg.accel.misalignment = Matrix3::zeros();
        }
        if let (Variant::ExactServo, ServoModel::Positional(p)) = (self, &mut cfg.servo) {
            p.scale_error = 0.0;
            p.offset_deg = 0.0;
        }
        cfg
    }
}

/// Runs `runs` random realistic rigs under each [`Variant`] and prints both estimators side by
/// side (scale-factor error in %). Returns the JSON summary.
pub fn compare(runs: usize, seed: u64) -> Value {
    println!("\nHobby-servo rig ({runs} random rigs per variant; simulated LSM9DS1 at 119 Hz with ODR -4 %, scale,");
    println!("bias, noise, quantisation; servo lag, slew, dead band, vibration; MCU timestamps; accelerometer by our");
    println!("9-parameter fit on 12 hand-held poses). Script: rest 2 s (bias); 12 hand-held poses; on the shaft,");
    println!("13 static poses 0..180..0 deg every 30 deg (settle 0.7 s, average 1 s), moves commanded at 30 deg/s (sweep);");
    println!("rotation 0 -> 180 deg commanded at 20 deg/s (paper, w_n = 20 deg/s). Error of diag(K) against truth, in %:");
    println!("{:<24}{:<8}{:>10}{:>10}{:>10}{:>8}", "variant", "method", "RMS", "max|e|", "mean", "failed");
    let mut out = serde_json::Map::new();
    for variant in [Variant::Hobby, Variant::ExactServo, Variant::HobbyMisaligned] {
        let (mut e_sweep, mut e_paper) = (vec![], vec![]);
        let (mut f_sweep, mut f_paper) = (vec![], vec![]);
        for r in 0..runs {
            match session(variant.config(seed, r), r as u64 + 1) {
                Ok(s) => {
                    for (errs, cal, f) in [(&mut e_sweep, &s.sweep, &mut f_sweep), (&mut e_paper, &s.paper, &mut f_paper)] {
                        match s.rel_errors(cal) {
                            Some(e) => errs.extend(e.iter().map(|x| x * 100.0)),
                            None => f.push(cal.err().map(|e| e.to_string()).unwrap_or_default()),
                        }
                    }
                }
                Err(e) => {
                    f_sweep.push(e.to_string());
                    f_paper.push(e.to_string());
                }
            }
        }
        let (ms, mp) = (Moments::of(&e_sweep), Moments::of(&e_paper));
        let max = |e: &[f64]| e.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for (method, m, e, f) in [("sweep", &ms, &e_sweep, &f_sweep), ("paper", &mp, &e_paper, &f_paper)] {
            println!("{:<24}{:<8}{:>10.4}{:>10.4}{:>10.4}{:>8}", variant.name(), method, m.rms, max(e), m.mean, f.len());
        }
        let ratio = if ms.rms > 0.0 { mp.rms / ms.rms } else { f64::INFINITY };
        println!("{:<24}paper RMS / sweep RMS = {:.2}", "", ratio);
        out.insert(
            variant.name().into(),
            json!({"sweep_rms_pct": ms.rms, "paper_rms_pct": mp.rms, "paper_over_sweep": ratio,
                   "sweep_max_pct": max(&e_sweep), "paper_max_pct": max(&e_paper),
                   "sweep": ms.json(), "paper": mp.json(), "sweep_failed": f_sweep, "paper_failed": f_paper}),
        );
    }
    Value::Object(out)
}
