//! A scripted pan/tilt calibration protocol, independent of the firmware's procedure (as another
//! tool would record it), logged in the shared format: optional hand-held poses first, then at
//! four tilt settings pan poses 0–180° every 45° and back, with the tilt moves at pan 0 (always
//! reached from 45°: a hobby servo's dead band lands it where it came from).

use crate::harness::operator_attitudes;
use crate::sim::{Reading, Rig, RigConfig, TiltStage};
use crate::variant::Variant;
use calib_core::formats::log;
use nalgebra::{Matrix3, Quaternion, UnitQuaternion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Tilt settings (°, 0 = level).
pub const TILTS_DEG: [f32; 4] = [-60.0, -20.0, 20.0, 60.0];
/// Commanded move rate of both servos (°/s).
const RATE_DPS: f32 = 30.0;
/// Still time at every pose (s).
const HOLD_S: f64 = 1.5;

/// Pulse (µs) for a commanded angle of a 1000–2000 µs ↔ 0–180° servo.
fn pulse(deg: f32) -> f64 {
    1000.0 + deg as f64 / 0.18
}

struct Script<'a> {
    rig: &'a mut Rig,
    text: String,
    pan: f32,
    tilt: f32,
}

impl Script<'_> {
    fn sample(&mut self, servo: Option<f32>, tilt: Option<f32>) -> Reading {
        let s = self.rig.next_sample();
        crate::harness::write_log_row(&mut self.text, &crate::harness::log_row(&s, servo, tilt), self.rig.config().mag.is_some());
        s
    }

    fn hold(&mut self, secs: f64, commanded: bool) {
        let t0 = self.sample(commanded.then_some(self.pan), commanded.then_some(self.tilt)).t_s;
        while self.sample(commanded.then_some(self.pan), commanded.then_some(self.tilt)).t_s - t0 < secs {}
    }

    /// Ramps pan and tilt to the targets at the commanded rate, then holds.
    fn go(&mut self, pan: f32, tilt: f32) {
        let (p0, t0) = (self.pan, self.tilt);
        let dur = ((pan - p0).abs().max((tilt - t0).abs()) / RATE_DPS) as f64;
        let start = self.sample(Some(p0), Some(t0)).t_s;
        loop {
            let x = if dur > 0.0 { (((self.rig.truth().t_s - start) / dur).min(1.0)) as f32 } else { 1.0 };
            (self.pan, self.tilt) = (p0 + (pan - p0) * x, t0 + (tilt - t0) * x);
            self.rig.set_pulse_us(pulse(self.pan));
            self.rig.set_tilt_pulse_us(pulse(90.0 + self.tilt));
            self.sample(Some(self.pan), Some(self.tilt));
            if x >= 1.0 {
                break;
            }
        }
        self.hold(HOLD_S, true);
    }
}

/// Runs the protocol on `rig` (which must have a tilt stage) and returns the log.
pub fn log(rig: &mut Rig, handheld: bool) -> String {
    log_at(rig, handheld, &TILTS_DEG)
}

/// The protocol at these tilt settings (°).
pub fn log_at(rig: &mut Rig, handheld: bool, tilts_deg: &[f32]) -> String {
    let poses = if handheld { operator_attitudes(rig.operator_rng()).into_iter().take(12).collect() } else { vec![] };
    log_posed(rig, &poses, tilts_deg)
}

/// `n` attitudes drawn uniformly over all attitudes from `rng`: a pose set unlike the simulated
/// operator's (near the vertices of an icosahedron), as another person or simulator holds them.
pub fn random_attitudes(rng: &mut impl Rng, n: usize) -> Vec<UnitQuaternion<f64>> {
    use rand_distr::StandardNormal;
    (0..n)
        .map(|_| {
            let g: [f64; 4] = core::array::from_fn(|_| rng.sample(StandardNormal));
            UnitQuaternion::from_quaternion(Quaternion::new(g[0], g[1], g[2], g[3]))
        })
        .collect()
}

/// The protocol at these tilt settings (°), the board held by hand first at these attitudes
/// (none: no hand-held step).
pub fn log_posed(rig: &mut Rig, poses: &[UnitQuaternion<f64>], tilts_deg: &[f32]) -> String {
    let header = crate::harness::log_header(rig.config());
    let mut s = Script { rig, text: format!("# pan/tilt protocol\n{header}\n"), pan: 0.0, tilt: 0.0 };
    s.rig.set_pulse_us(pulse(0.0));
    s.rig.set_tilt_pulse_us(pulse(90.0));
    s.hold(3.0, true);
    if !poses.is_empty() {
        // About 4 s each as the firmware asks: 1 s to turn, 3 s held, of which a hand's pose
        // averages 2 s once it has settled.
        for &q in poses {
            s.rig.detach_to(q, 1.0);
            s.hold(4.0, false);
        }
        s.rig.attach();
        let settle = s.rig.config().attach_transition_s + 1.0;
        s.hold(settle, true);
    }
    // Every pose at pan 0 is reached from 45°, so that the servo's dead band puts all of them,
    // and so the hinge's poses, at the same shaft angle.
    s.go(45.0, 0.0);
    s.go(0.0, 0.0);
    for &tilt in tilts_deg {
        s.go(0.0, tilt);
        for pan in [45.0, 90.0, 135.0, 180.0, 135.0, 90.0, 45.0, 0.0] {
            s.go(pan, tilt);
        }
    }
    s.text
}

/// The same log with only its hand-held rows (both servo columns empty), comments and header:
/// a log of hand-held poses and no servo, as other tools record.
pub fn handheld_only(log: &str) -> String {
    let servo_empty = |l: &str| l.split(',').skip(7).take(2).all(str::is_empty);
    let keep = |l: &&str| l.starts_with('#') || log::is_header(l) || servo_empty(l);
    log.lines().filter(keep).map(|l| format!("{l}\n")).collect()
}

/// `E = Qᵀ K̂ K⁻¹ − I`: a full `K̂` (row-major) in the frame of the calibrated accelerometer `M̂`,
/// against the simulator's truth, after aligning the two frames (`Q = polar(M̂ C_a)`, `C_a` the
/// simulated accelerometer's matrix). Its diagonal is the scale error, the rest the cross-axis error.
pub fn k_error_matrix(k_hat: [[f32; 3]; 3], m_hat: [[f32; 3]; 3], rig: &Rig) -> Option<Matrix3<f64>> {
    let m = |a: [[f32; 3]; 3]| Matrix3::from_fn(|r, c| a[r][c] as f64);
    let svd = (m(m_hat) * rig.config().accel.matrix()).svd(true, true);
    let q = svd.u? * svd.v_t?;
    Some(q.transpose() * m(k_hat) * rig.truth().gyro_k.try_inverse()? - Matrix3::identity())
}

/// `|E_ij| / σ_ij` (row-major) of an error matrix `e` ([`k_error_matrix`]) against the 1σ `sigma`
/// a result gives each element of `K̂` (`E ≈ K̂ − K` for `K ≈ I`, so `σ(E_ij) ≈ σ(K_ij)`); an
/// element with no 1σ is 0 when exact, else infinite.
pub fn k_error_z(e: &Matrix3<f64>, sigma: [[f32; 3]; 3]) -> [f64; 9] {
    core::array::from_fn(|i| {
        let (e, s) = (e[(i / 3, i % 3)].abs(), sigma[i / 3][i % 3] as f64);
        if s > 0.0 {
            e / s
        } else if e == 0.0 {
            0.0
        } else {
            f64::INFINITY
        }
    })
}

/// How many of a full `K̂`'s 9 elements have their error within 1σ and within 2σ of their
/// reported 1σ ([`k_error_z`]; none without an error matrix).
pub fn k_error_covered(k_hat: [[f32; 3]; 3], sigma: [[f32; 3]; 3], m_hat: [[f32; 3]; 3], rig: &Rig) -> [usize; 2] {
    let Some(e) = k_error_matrix(k_hat, m_hat, rig) else { return [0; 2] };
    let z = k_error_z(&e, sigma);
    [1.0, 2.0].map(|n| z.iter().filter(|z| **z <= n).count())
}

/// (largest |E_ij|, RMS over the 9) of [`k_error_matrix`].
pub fn k_error(k_hat: [[f32; 3]; 3], m_hat: [[f32; 3]; 3], rig: &Rig) -> Option<(f64, f64)> {
    let e = k_error_matrix(k_hat, m_hat, rig)?;
    Some((e.amax(), (e.norm_squared() / 9.0).sqrt()))
}

/// A realistic pan/tilt rig of the benchmarks: the hobby rig of `seed`/`run` with the pan shaft
/// 30–50° from vertical, a tilt stage, gyro cross-axis coupling U(±1 %) and accelerometer
/// misalignment U(±0.3 %).
pub fn rig_config(seed: u64, run: usize) -> RigConfig {
    let mut cfg = Variant::Hobby.config(seed, run);
    let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(7919).wrapping_add(run as u64));
    cfg.shaft_tilt_deg = rng.random_range(30.0..50.0);
    let mut off = |max: f64| Matrix3::from_fn(|r, c| if r == c { 0.0 } else { rng.random_range(-max..max) });
    cfg.gyro.misalignment = off(0.01);
    cfg.accel.misalignment = off(0.003);
    let servo = crate::sim::PositionalServo::realistic(&mut ChaCha8Rng::seed_from_u64(seed + 17 * run as u64 + 1));
    cfg.tilt = Some(TiltStage { servo, hinge_deg: 60.0 });
    cfg
}
