//! The full 9-parameter gyro K on synthetic pan/tilt data generated here (no simulator): exact
//! recovery, LSM9DS1-like noise, back-and-forth bias cancellation, f32 inputs against an f64
//! reference, and every degenerate rig as a named error.
//!
//! World frame W: z up; at rest the accelerometer measures the specific force `A_W = +z` (1 g).
//! Board attitude `R_WB(ψ, φ) = R_pan(ψ) R_hinge(φ) R_mount`: pan about the (tilted) shaft `p_W`,
//! tilt about the hinge `h` (⟂ `p_W`, given at pan 0), board clamped askew by `R_mount`.

use calib_core::estimators::full::{Axes, FullCal, FullLimits, MAX_AXES};
use calib_core::estimators::sweep::Integrator;
use calib_core::math::vec3;
use calib_core::{Error, Time};
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

type V3 = Vector3<f64>;

/// xorshift64* with Box–Muller: reproducible noise without dependencies.
struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn gauss(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
    fn gauss3(&mut self, s: f64) -> V3 {
        V3::new(self.gauss(), self.gauss(), self.gauss()) * s
    }
}

fn rot(axis: V3, deg: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Unit::new_normalize(axis), deg.to_radians())
}

/// `diag(1.02, 0.97, 1.01)` plus off-diagonals uniform in ±1 %.
fn k_true(rng: &mut Rng) -> Matrix3<f64> {
    let mut k = Matrix3::from_diagonal(&V3::new(1.02, 0.97, 1.01));
    for r in 0..3 {
        for c in (0..3).filter(|&c| c != r) {
            k[(r, c)] = 0.02 * (rng.uniform() - 0.5);
        }
    }
    k
}

/// One synthetic pan/tilt session.
#[derive(Clone)]
struct Scenario {
    /// Pan shaft angle from vertical (°).
    shaft_tilt_deg: f64,
    tilt_settings_deg: Vec<f64>,
    pan_poses_deg: Vec<f64>,
    /// Tilt moves between consecutive settings at pan 0 (and, with `tilt_back`, back to the first).
    tilt_moves: bool,
    tilt_back: bool,
    /// 1σ of a pose mean per component (g) and of a move's gyro integral per component (°).
    accel_sigma_g: f64,
    gamma_sigma_deg: f64,
    /// Residual (uncorrected) gyro bias (°/s, raw axes): adds `b T` to every move, `T = |Δθ| / rate`.
    residual_bias_dps: V3,
    rate_dps: f64,
    /// The board slips on the bracket by this rotation (axis, °) after this pose index.
    slip: Option<(usize, V3, f64)>,
    seed: u64,
}

impl Default for Scenario {
    fn default() -> Self {
        Scenario {
            shaft_tilt_deg: 30.0,
            tilt_settings_deg: vec![0.0, 30.0, 60.0, 90.0],
            pan_poses_deg: vec![0.0, 45.0, 90.0, 135.0, 180.0, 135.0, 90.0, 45.0, 0.0],
            tilt_moves: true,
            tilt_back: true,
            accel_sigma_g: 0.0,
            gamma_sigma_deg: 0.0,
            residual_bias_dps: V3::zeros(),
            rate_dps: 60.0,
            slip: None,
            seed: 1,
        }
    }
}

/// A move as generated: axis id, poses, commanded turn, exact `Γ = K⁻¹ Δθ u` and the noisy one.
struct GenMove {
    axis: u8,
    from: u8,
    to: u8,
    commanded_deg: f64,
    gamma_exact: V3,
    gamma: V3,
}

struct Generated {
    k: Matrix3<f64>,
    poses: Vec<V3>,
    moves: Vec<GenMove>,
    /// True pan axis of each setting and the hinge (B), signed along increasing servo angle.
    axes: Vec<V3>,
}

impl Scenario {
    fn generate(&self) -> Generated {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ self.seed.wrapping_mul(0x1234_5678_9ABC_DEF1));
        let k = k_true(&mut rng);
        let kinv = k.try_inverse().unwrap();
        let t = self.shaft_tilt_deg.to_radians();
        let p_w = V3::new(t.sin(), 0.0, t.cos());
        let h_w = V3::new(0.0, 1.0, 0.0);
        let mount0 = rot(V3::new(0.3, -0.5, 0.8), 40.0);
        let a_w = V3::new(0.0, 0.0, 1.0);
        let mut poses: Vec<V3> = Vec::new();
        let mut moves = Vec::new();
        let mount_at = |index: usize| match self.slip {
            Some((after, axis, deg)) if index > after => rot(axis, deg) * mount0,
            _ => mount0,
        };
        let pose = |rng: &mut Rng, psi: f64, phi: f64, poses: &mut Vec<V3>| -> u8 {
            let r_wb = rot(p_w, psi) * rot(h_w, phi) * mount_at(poses.len());
            poses.push(r_wb.inverse() * a_w + rng.gauss3(self.accel_sigma_g));
            (poses.len() - 1) as u8
        };
        let gen_move = |rng: &mut Rng, axis: u8, from: u8, to: u8, u_b: V3, dtheta: f64| {
            let exact = kinv * u_b * dtheta;
            let duration = dtheta.abs() / self.rate_dps;
            let gamma = exact + rng.gauss3(self.gamma_sigma_deg) + self.residual_bias_dps * duration;
            GenMove { axis, from, to, commanded_deg: dtheta, gamma_exact: exact, gamma }
        };
        let n_set = self.tilt_settings_deg.len();
        let hinge_id = n_set as u8;
        // (index, tilt, pan) of the last pose: tilt moves start there and keep its pan angle.
        let mut last: Option<(u8, f64, f64)> = None;
        for (s, &phi) in self.tilt_settings_deg.iter().enumerate() {
            let mut prev: Option<(u8, f64)> = None;
            let mut start = 0;
            if let (Some((i0, phi0, psi)), true) = (last, self.tilt_moves) {
                let idx = pose(&mut rng, psi, phi, &mut poses);
                let u_b = mount_at(idx as usize).inverse() * h_w; // the hinge in B, whatever the pan
                moves.push(gen_move(&mut rng, hinge_id, i0, idx, u_b, phi - phi0));
                if psi == self.pan_poses_deg[0] {
                    (prev, start) = (Some((idx, psi)), 1);
                }
            }
            for &psi in &self.pan_poses_deg[start..] {
                let idx = pose(&mut rng, psi, phi, &mut poses);
                if let Some((i0, psi0)) = prev {
                    let u_b = mount_at(idx as usize).inverse() * rot(h_w, phi).inverse() * p_w;
                    moves.push(gen_move(&mut rng, s as u8, i0, idx, u_b, psi - psi0));
                }
                prev = Some((idx, psi));
            }
            last = prev.map(|(i, psi)| (i, phi, psi));
        }
        if self.tilt_moves && self.tilt_back {
            // Back through the settings: every tilt move gets its reverse.
            for &phi in self.tilt_settings_deg.iter().rev().skip(1) {
                let (i0, phi0, psi) = last.unwrap();
                let idx = pose(&mut rng, psi, phi, &mut poses);
                let u_b = mount_at(idx as usize).inverse() * h_w;
                moves.push(gen_move(&mut rng, hinge_id, i0, idx, u_b, phi - phi0));
                last = Some((idx, phi, psi));
            }
        }
        let mut axes: Vec<V3> = self.tilt_settings_deg.iter().map(|&phi| mount0.inverse() * rot(h_w, phi).inverse() * p_w).collect();
        axes.push(mount0.inverse() * h_w);
        Generated { k, poses, moves, axes }
    }
}

impl Generated {
    /// The rig as the caller builds it (f32 poses); `exact` uses the noise-free `Γ`.
    fn rig(&self, exact: bool) -> Axes {
        let mut rig = Axes::new();
        for p in &self.poses {
            rig.push_pose([p[0] as f32, p[1] as f32, p[2] as f32]).unwrap();
        }
        for m in &self.moves {
            let g = if exact { m.gamma_exact } else { m.gamma };
            rig.push_move(m.axis, m.from, m.to, m.commanded_deg as f32, [g[0], g[1], g[2]]).unwrap();
        }
        rig
    }
}

fn k_of(cal: &FullCal) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| cal.k[r][c] as f64)
}

/// (max |K̂ − K|, max |K̂ K⁻¹ − I|, RMS of K̂ K⁻¹ − I) over the 9 elements.
fn errors(cal: &FullCal, k: &Matrix3<f64>) -> (f64, f64, f64) {
    let kh = k_of(cal);
    let e = kh * k.try_inverse().unwrap() - Matrix3::identity();
    let d = kh - k;
    (d.amax(), e.amax(), (e.norm_squared() / 9.0).sqrt())
}

fn report(name: &str, cal: &FullCal, k: &Matrix3<f64>) {
    let (dk, emax, erms) = errors(cal, k);
    println!(
        "{name}: max|K̂−K| {dk:.2e}  max|K̂K⁻¹−I| {emax:.2e}  rms {erms:.2e}  max σ_K {:.2e}  cond {:.1}  \
         non-coplanar {:.1}°  min pair {:.1}°  residual {:.2e}°  noise ratio {:.2}  σ_a {:.1e} g  moves {} (+{} skipped)  rows {}  axes {}",
        cal.sigma_k.iter().flatten().fold(0.0f32, |m, &s| m.max(s)),
        cal.condition,
        cal.non_coplanar_deg,
        cal.min_pair_angle_deg,
        cal.residual_rms_deg,
        cal.noise_ratio,
        cal.accel_sigma_g,
        cal.moves,
        cal.moves_skipped,
        cal.rows,
        cal.n_axes,
    );
}

#[test]
fn exact_data_recover_every_element() {
    let g = Scenario::default().generate();
    let cal = g.rig(true).solve(&FullLimits::default()).unwrap();
    report("exact", &cal, &g.k);
    let (dk, _, _) = errors(&cal, &g.k);
    assert!(dk <= 1e-6, "max |K̂ − K| = {dk:.3e}");
    assert_eq!((cal.n_axes, cal.moves, cal.moves_skipped), (5, 38, 0));
    // Axis signs: along increasing commanded servo angle (here the right-hand shaft axes).
    for (a, u) in g.axes.iter().enumerate() {
        let got = V3::new(cal.axes[a].u[0] as f64, cal.axes[a].u[1] as f64, cal.axes[a].u[2] as f64);
        assert!((got - u).norm() < 1e-5, "axis {a}: {got:?} vs {u:?}");
        assert!(!cal.axes[a].direction_only);
    }
    println!("axes: {:?}", &cal.axes[..5]);
    assert!(cal.axes[5..].iter().all(|a| a.moves == 0) && MAX_AXES == 8);
}

/// (max |K̂ − K|, RMS of K̂ − K, max |K̂ − K| / σ) over 20 rigs with this noise.
fn noisy_runs(accel_sigma_g: f64, gamma_sigma_deg: f64, residual_bias_dps: f64, print: bool) -> (f64, f64, f64) {
    let (mut worst, mut sum2, mut worst_ratio) = (0.0f64, 0.0, 0.0f64);
    let runs = 20;
    for seed in 0..runs {
        let mut rng = Rng(seed + 77);
        let sc = Scenario { accel_sigma_g, gamma_sigma_deg, residual_bias_dps: rng.gauss3(residual_bias_dps), seed, ..Scenario::default() };
        let g = sc.generate();
        let cal = g.rig(false).solve(&FullLimits::default()).unwrap();
        if print && seed < 3 {
            report(&format!("noisy seed {seed}"), &cal, &g.k);
        }
        let kh = k_of(&cal);
        for r in 0..3 {
            for c in 0..3 {
                let d = (kh[(r, c)] - g.k[(r, c)]).abs();
                worst = worst.max(d);
                sum2 += d * d;
                worst_ratio = worst_ratio.max(d / cal.sigma_k[r][c] as f64);
            }
        }
    }
    let rms = (sum2 / (9 * runs) as f64).sqrt();
    println!(
        "20 rigs, pose σ {accel_sigma_g:.0e} g, Γ σ {gamma_sigma_deg}°, residual bias σ {residual_bias_dps} °/s: \
         max |K̂−K| {worst:.2e}, rms {rms:.2e}, max |error|/σ {worst_ratio:.2}"
    );
    (worst, rms, worst_ratio)
}

#[test]
fn lsm9ds1_like_noise() {
    // The rig simulator's LSM9DS1: accel 150 µg/√Hz at 119 Hz (1.16 mg per sample), 1 s poses →
    // 1.06e-4 g per pose mean; gyro 0.008 °/s/√Hz over a 1.5 s move → 0.01° per component;
    // plus a residual bias of 0.01 °/s (the bias 1σ of a short rest).
    noisy_runs(1e-4, 0.0, 0.0, false);
    noisy_runs(0.0, 0.01, 0.0, false);
    let (worst, rms, ratio) = noisy_runs(1e-4, 0.01, 0.01, true);
    assert!(rms <= 2e-4 && worst <= 6e-4, "max {worst:.3e}, rms {rms:.3e}");
    // The 1σ are honest: no element beyond 4σ over 180 elements.
    assert!(ratio < 4.0, "{ratio}");
}

#[test]
fn back_and_forth_cancels_residual_bias() {
    let bias = V3::new(0.05, -0.04, 0.03); // °/s, uncorrected
    let both = Scenario { residual_bias_dps: bias, ..Scenario::default() };
    let forward =
        Scenario { pan_poses_deg: vec![0.0, 45.0, 90.0, 135.0, 180.0], tilt_back: false, residual_bias_dps: bias, ..Scenario::default() };
    let mut r = [0.0; 2];
    for (i, sc) in [both, forward].iter().enumerate() {
        let g = sc.generate();
        // Forward only: tilt moves at pan 180, the return to pan 0 is not a move.
        let cal = g.rig(false).solve(&FullLimits::default()).unwrap();
        report(["back-and-forth, bias 0.05 °/s", "forward only, bias 0.05 °/s"][i], &cal, &g.k);
        r[i] = errors(&cal, &g.k).0;
    }
    assert!(r[0] < 1e-5 && r[1] > 20.0 * r[0], "back-and-forth {:.2e}, forward {:.2e}", r[0], r[1]);
}

/// Samples of one move at 119 Hz (MCU timestamps from t0, s) whose f64 trapezoid is exactly `gamma`:
/// a smooth sin² rate profile plus a raw bias, as the sensor would give them.
fn samples(gamma: V3, bias: V3, t0: f64) -> Vec<(f64, V3)> {
    let (dt, n) = (1.0 / 119.0, 150);
    let shape: Vec<f64> = (0..=n).map(|k| (std::f64::consts::PI * k as f64 / n as f64).sin().powi(2)).collect();
    let s: f64 = shape.windows(2).map(|w| 0.5 * (w[0] + w[1]) * dt).sum();
    shape.iter().enumerate().map(|(k, &v)| (t0 + k as f64 * dt, gamma * (v / s) + bias)).collect()
}

#[test]
fn f32_inputs_with_f64_accumulators_match_an_f64_reference() {
    let g = Scenario::default().generate();
    let reference = g.rig(true).solve(&FullLimits::default()).unwrap();
    let bias = V3::new(1.7, -0.9, 2.3); // °/s raw bias, removed in f32 as the firmware does
    let bias32 = [bias[0] as f32, bias[1] as f32, bias[2] as f32];
    let mut rig = Axes::new();
    for p in &g.poses {
        rig.push_pose([p[0] as f32, p[1] as f32, p[2] as f32]).unwrap();
    }
    let (mut worst_gamma, mut worst_naive) = (0.0f64, 0.0f64);
    let mut t0 = 3600.0; // an hour after power-up: large timestamps
    for m in &g.moves {
        let mut integ = Integrator::new();
        let mut naive = [0.0f32; 3];
        let mut last: Option<(f32, [f32; 3])> = None;
        for (t, v) in samples(m.gamma_exact, bias, t0) {
            let raw = [v[0] as f32, v[1] as f32, v[2] as f32];
            let w = vec3::sub(raw, bias32);
            integ.add(Time::from_s(t).unwrap(), w);
            let t32 = t as f32;
            if let Some((tl, wl)) = last {
                for k in 0..3 {
                    naive[k] += 0.5 * (wl[k] + w[k]) * (t32 - tl);
                }
            }
            last = Some((t32, w));
        }
        t0 += 5.0;
        let gm = integ.gamma();
        worst_gamma = worst_gamma.max((V3::from(gm) - m.gamma_exact).amax());
        worst_naive = worst_naive.max((0..3).map(|k| (naive[k] as f64 - m.gamma_exact[k]).abs()).fold(0.0, f64::max));
        rig.push_move(m.axis, m.from, m.to, m.commanded_deg as f32, gm).unwrap();
    }
    let cal = rig.solve(&FullLimits::default()).unwrap();
    let d = (k_of(&cal) - k_of(&reference)).amax();
    println!(
        "f32 samples → f64 Integrator: max |ΔΓ| {worst_gamma:.2e}° (an all-f32 accumulator: {worst_naive:.2e}°), max |K − K_ref| {d:.2e}"
    );
    assert!(d <= 1e-5, "{d:.3e}");
}

#[test]
fn upright_bracket_is_unobservable_not_wrong() {
    let g = Scenario { shaft_tilt_deg: 0.0, ..Scenario::default() }.generate();
    let r = g.rig(true).solve(&FullLimits::default());
    println!("upright, exact: {r:?}");
    assert!(matches!(r, Err(Error::FullKUnobservable { .. })), "{r:?}");
    let msg = format!("{}", r.unwrap_err());
    assert!(msg.contains("tilt the pan servo's shaft >= 20 deg from vertical"), "{msg}");
    // With noise too, and with the shaft a little off vertical (a bracket set up by eye): below
    // `min_tilt_deg` (10°) the pan axes give direction-only rows and the null direction stays.
    for tilt in [0.0, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0] {
        let sc = Scenario { shaft_tilt_deg: tilt, accel_sigma_g: 1e-4, gamma_sigma_deg: 0.01, ..Scenario::default() };
        let r = sc.generate().rig(false).solve(&FullLimits::default());
        match &r {
            Ok(c) => {
                let (dk, _, _) = errors(c, &sc.generate().k);
                println!("shaft {tilt}° from vertical, noisy: Ok, cond {:.1}, max |K̂−K| {dk:.2e}", c.condition);
                assert!(tilt >= 10.0 && dk < 1e-3, "{tilt}°: {dk:.2e}");
            }
            Err(e) => {
                println!("shaft {tilt}° from vertical, noisy: {e:?}");
                assert!(tilt < 10.0 && matches!(e, Error::FullKUnobservable { .. }), "{tilt}°: {e:?}");
            }
        }
    }
}

#[test]
fn coplanar_or_too_few_axes_are_named() {
    let lim = FullLimits::default();
    // One tilt setting: one pan axis.
    let one = Scenario { tilt_settings_deg: vec![30.0], ..Scenario::default() }.generate();
    let r = one.rig(true).solve(&lim);
    println!("one tilt setting: {r:?}");
    assert_eq!(r.unwrap_err(), Error::TooFewAxes { have: 1, need: 3 });
    // Four settings, no tilt moves: the pan axes all lie in the plane ⟂ hinge.
    let no_hinge = Scenario { tilt_moves: false, ..Scenario::default() }.generate();
    let r = no_hinge.rig(true).solve(&lim);
    println!("no tilt moves: {r:?}");
    assert!(matches!(r, Err(Error::AxesCoplanar { angle_deg, .. }) if angle_deg < 1e-3), "{r:?}");
    // Two settings: the hinge sees only two orientations and cannot be fitted.
    let two = Scenario { tilt_settings_deg: vec![0.0, 45.0], ..Scenario::default() }.generate();
    let r = two.rig(true).solve(&lim);
    println!("two tilt settings: {r:?}");
    assert!(matches!(r, Err(Error::AxisUndetermined { axis: 2, .. })), "{r:?}");
    // Three settings suffice (3 pan axes + hinge).
    let three = Scenario { tilt_settings_deg: vec![0.0, 40.0, 80.0], ..Scenario::default() }.generate();
    let cal = three.rig(true).solve(&lim).unwrap();
    report("three tilt settings, exact", &cal, &three.k);
    assert!(errors(&cal, &three.k).0 < 1e-6);
}

#[test]
fn slipped_board_is_named() {
    let lim = FullLimits::default();
    // A 3° slip in the middle of the second tilt setting: its poses leave their plane.
    let mid = Scenario { slip: Some((12, V3::new(1.0, 0.2, -0.4), 3.0)), ..Scenario::default() }.generate();
    let r = mid.rig(false).solve(&lim);
    println!("slip mid-setting: {r:?}");
    assert!(matches!(r, Err(Error::AxisNotFixed { .. })), "{r:?}");
    // A 3° slip between two settings: every plane is fine, the hinge plane is not.
    let between = Scenario { slip: Some((17, V3::new(0.2, 1.0, 0.5), 3.0)), ..Scenario::default() }.generate();
    let r = between.rig(false).solve(&lim);
    println!("slip between settings: {r:?}");
    assert!(matches!(r, Err(Error::AxisNotFixed { .. } | Error::MovesInconsistent { .. })), "{r:?}");
    // Smaller slips between settings, with noise: a named error, or a K still within 1e-3.
    for deg in [0.25, 0.5, 1.0, 1.5, 2.0] {
        for (i, axis) in [V3::new(0.2, 1.0, 0.5), V3::new(1.0, -0.3, 0.2), V3::new(0.0, 0.3, 1.0)].into_iter().enumerate() {
            let sc = Scenario { slip: Some((17, axis, deg)), accel_sigma_g: 1e-4, gamma_sigma_deg: 0.01, ..Scenario::default() };
            let g = sc.generate();
            match g.rig(false).solve(&lim) {
                Ok(cal) => {
                    let (dk, _, _) = errors(&cal, &g.k);
                    println!(
                        "slip {deg}° about #{i}: Ok, max |K̂−K| {dk:.2e}, residual {:.3}°, ratio {:.2}, planes {:?}",
                        cal.residual_rms_deg,
                        cal.noise_ratio,
                        cal.axes[..5].iter().map(|a| a.plane_rms_g).collect::<Vec<_>>()
                    );
                    assert!(dk < 1e-3, "slip {deg}° #{i}: undetected, K off by {dk:.2e}");
                }
                Err(e) => {
                    println!("slip {deg}° about #{i}: {e}");
                    assert!(matches!(e, Error::AxisNotFixed { .. } | Error::MovesInconsistent { .. }), "{e:?}");
                    // The message's numbers are the ones compared: the value beyond its limit.
                    if let Error::AxisNotFixed { plane_rms_g, limit_g } = e {
                        assert!(plane_rms_g > limit_g, "{e}");
                    }
                }
            }
        }
    }
}

#[test]
fn bad_input_never_panics() {
    let mut rig = Axes::new();
    assert_eq!(rig.push_pose([f32::NAN, 0.0, 1.0]), Err(Error::NonFinite));
    for _ in 0..3 {
        rig.push_pose([0.0, 0.0, 1.0]).unwrap();
    }
    assert_eq!(rig.push_move(0, 0, 1, 45.0, [f64::NAN, 0.0, 0.0]), Err(Error::NonFinite));
    assert_eq!(rig.push_move(0, 0, 1, f32::INFINITY, [1.0, 0.0, 0.0]), Err(Error::NonFinite));
    assert!(matches!(rig.push_move(0, 0, 7, 45.0, [1.0, 0.0, 0.0]), Err(Error::TooFewPoses { .. })));
    assert!(matches!(rig.push_move(MAX_AXES as u8, 0, 1, 45.0, [1.0, 0.0, 0.0]), Err(Error::CapacityExceeded { .. })));
    assert!(rig.solve(&FullLimits::default()).is_err()); // no move at all
                                                         // Degenerate numbers: zero and huge poses, huge integrals.
    let mut rig = Axes::new();
    for p in [[0.0f32; 3], [1e30, -1e30, 1e30], [0.0, 0.0, 1.0], [1e-30, 0.0, 0.0]] {
        rig.push_pose(p).unwrap();
    }
    for a in 0..4u8 {
        rig.push_move(a, a, (a + 1) % 4, 45.0, [1e300, -1e300, 0.0]).unwrap();
        rig.push_move(a, (a + 2) % 4, a, -45.0, [0.0, 45.0, 0.0]).unwrap();
    }
    let r = rig.solve(&FullLimits::default());
    println!("degenerate numbers: {r:?}");
    assert!(r.is_err());
}

mod prop {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]
        /// Random poses and moves: `solve` returns, never panics, and a success has finite results.
        #[test]
        fn random_rigs_never_panic(
            poses in proptest::collection::vec(proptest::array::uniform3(-2.0f32..2.0), 0..20),
            moves in proptest::collection::vec((0u8..6, 0u8..20, 0u8..20, -90.0f32..90.0, proptest::array::uniform3(-200.0f64..200.0)), 0..40),
        ) {
            let mut rig = Axes::new();
            for p in &poses {
                rig.push_pose(*p).unwrap();
            }
            for (a, f, t, c, g) in moves {
                let _ = rig.push_move(a, f, t, c, g);
            }
            if let Ok(cal) = rig.solve(&FullLimits::default()) {
                prop_assert!(cal.k.iter().flatten().chain(cal.sigma_k.iter().flatten()).all(|v| v.is_finite()));
            }
        }
    }
}
