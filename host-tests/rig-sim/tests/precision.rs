//! The per-sample paths against `f64` references at their worst case (the 952 Hz ODR, the
//! longest runs, the largest turns): `f32` inputs into exact integer moments, `f32` chunks of a
//! move, `f32` pose turns; results within bounds far below what the calibration resolves (a
//! naive `f32` running mean is not).

use calib_core::estimators::bias::{BiasEstimator, BiasLimits, RestBias};
use calib_core::estimators::rotation::{PoseTurn, RotationLimits, Rotations};
use calib_core::estimators::sweep::Integrator;
use calib_core::math::stats::Moments3;
use nalgebra::{Matrix3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rig_sim::harness::at;

const N: usize = 100_000;

fn rel(a: f64, b: f64) -> f64 {
    ((a - b) / b).abs()
}

#[test]
fn bias_mean_over_100k_samples_matches_f64() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut est = BiasEstimator::new();
    let (mut sum64, mut sum32) = ([0.0f64; 3], [0.0f32; 3]);
    for _ in 0..N {
        let g: [f32; 3] = [27.3 + rng.random_range(-0.3..0.3), -11.1 + rng.random_range(-0.3..0.3), 0.7 + rng.random_range(-0.3..0.3)];
        est.add(g, [0.0, 0.0, 1.0]);
        for k in 0..3 {
            sum64[k] += g[k] as f64;
            sum32[k] += g[k];
        }
    }
    let b = est.finish(&BiasLimits::default()).unwrap();
    let worst_naive = (0..3).map(|k| rel((sum32[k] / N as f32) as f64, sum64[k] / N as f64)).fold(0.0, f64::max);
    for (k, (&bias, &sum)) in b.bias_dps.iter().zip(sum64.iter()).enumerate() {
        assert!(rel(bias as f64, sum / N as f64) < 1e-5, "axis {k}");
    }
    assert!(worst_naive > 1e-5, "naive f32 mean error {worst_naive:e}: the test would not discriminate");
}

#[test]
fn gyro_integral_over_100k_samples_matches_f64() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let mut it = Integrator::new();
    let (mut t, mut prev) = (1000.0f64, None::<(f64, [f32; 3])>);
    let (mut ref64, mut naive) = ([0.0f64; 3], [0.0f32; 3]);
    for _ in 0..N {
        t += 1.0 / 952.0 * (1.0 + rng.random_range(-0.01..0.01));
        let g: [f32; 3] = [21.7 + rng.random_range(-0.5..0.5), -8.9 + rng.random_range(-0.5..0.5), 13.3 + rng.random_range(-0.5..0.5)];
        it.add(at(t), g);
        // The reference at the times the integrator is given (the board's µs).
        let t = at(t).s();
        if let Some((t0, g0)) = prev {
            for k in 0..3 {
                ref64[k] += 0.5 * (g0[k] as f64 + g[k] as f64) * (t - t0);
                naive[k] += 0.5 * (g0[k] + g[k]) * (t - t0) as f32;
            }
        }
        prev = Some((t, g));
    }
    let gamma = it.gamma();
    let worst_naive = (0..3).map(|k| rel(naive[k] as f64, ref64[k])).fold(0.0, f64::max);
    for k in 0..3 {
        // 105 s at 952 Hz, 2300 deg on x: within 1e-8 of the f64 sum (measured 4e-10; a plain
        // f32 sum: 6e-6).
        assert!(rel(gamma[k], ref64[k]) < 1e-8, "axis {k}: {:e}", rel(gamma[k], ref64[k]));
    }
    assert!(worst_naive > 2e-6, "plain f32 sum error {worst_naive:e}: the test would not discriminate");
}

/// The sweep estimator end to end on noisy f32 data vs the same formulas in f64 with nalgebra.
#[test]
fn sweep_result_matches_an_f64_reference() {
    use calib_core::estimators::axis::{GeometryLimits, Poses};
    use calib_core::estimators::sweep::{self, Moves};
    use nalgebra::{Matrix3, Rotation3, Unit, Vector3};
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let u = Vector3::new(0.5, -0.45, 0.74).normalize();
    let k = Vector3::new(1.03, 0.97, 1.01);
    let e1 = u.cross(&Vector3::z()).normalize();
    let up = Rotation3::from_axis_angle(&Unit::new_normalize(e1), -0.8) * u;
    let mut noisy = |v: Vector3<f64>, s: f64| v.map(|c| (c + rng.random_range(-s..s)) as f32);
    let angles = [0.0f64, 30.0, 60.0, 90.0, 120.0, 150.0];
    let pose: Vec<[f32; 3]> =
        angles.iter().map(|a| noisy(Rotation3::from_axis_angle(&Unit::new_normalize(u), -a.to_radians()) * up, 1e-3).into()).collect();
    let mut poses = Poses::new();
    for p in &pose {
        poses.push(*p).unwrap();
    }
    let mut moves = Moves::new();
    let mut gam = Vec::new();
    for i in 0..5 {
        for (from, to, s) in [(i, i + 1, 1.0), (i + 1, i, -1.0)] {
            let g: [f32; 3] = noisy(u.component_div(&k) * (30.0 * s), 0.05).into();
            let g64 = [g[0] as f64, g[1] as f64, g[2] as f64];
            moves.push(from as u8, to as u8, g64).unwrap();
            gam.push((from, to, Vector3::from(g64)));
        }
    }
    let cal = sweep::solve(&poses, &moves, &GeometryLimits::default()).unwrap();
    // f64 reference: plane normal by nalgebra's symmetric eigen-decomposition, then per-axis LSQ.
    let a: Vec<Vector3<f64>> = pose.iter().map(|p| Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)).collect();
    let mean = a.iter().sum::<Vector3<f64>>() / a.len() as f64;
    let scatter: Matrix3<f64> = a.iter().map(|p| (p - mean) * (p - mean).transpose()).sum();
    let eig = scatter.symmetric_eigen();
    let imin = eig.eigenvalues.imin();
    let mut n = eig.eigenvectors.column(imin).into_owned();
    if n.dot(&mean) < 0.0 {
        n = -n;
    }
    let (mut num, mut den) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
    for (from, to, g) in &gam {
        let p = a[*from] - n * a[*from].dot(&n);
        let q = a[*to] - n * a[*to].dot(&n);
        let dth = -n.dot(&p.cross(&q)).atan2(p.dot(&q)).to_degrees();
        for c in 0..3 {
            num[c] += g[c] * dth * n[c];
            den[c] += g[c] * g[c];
        }
    }
    for c in 0..3 {
        let reference = num[c] / den[c];
        assert!(rel(cal.k[c][c] as f64, reference) < 1e-5, "axis {c}: {} vs {reference}", cal.k[c][c]);
    }
}

#[test]
fn moments_are_exact_sums_over_an_hour_at_952_hz() {
    // 3.4 million gyro readings near full scale (the largest sums): the mean and the variance
    // against f64 two-pass references, and two halves merged equal to the whole, bit for bit.
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let n = 3_427_200usize;
    let xs: Vec<[f32; 3]> = (0..n)
        .map(|_| [1990.0 + rng.random_range(-9.0..9.0), -0.37 + rng.random_range(-0.05..0.05), 25.0 + rng.random_range(-1e-3..1e-3)])
        .collect();
    let (mut all, mut a, mut b) = (Moments3::new(), Moments3::new(), Moments3::new());
    for (i, x) in xs.iter().enumerate() {
        all.add(*x);
        if i < n / 3 {
            a.add(*x)
        } else {
            b.add(*x)
        }
    }
    a.merge(&b);
    assert_eq!(a, all);
    let mean: [f64; 3] = core::array::from_fn(|k| xs.iter().map(|x| x[k] as f64).sum::<f64>() / n as f64);
    let var: [f64; 3] = core::array::from_fn(|k| xs.iter().map(|x| (x[k] as f64 - mean[k]).powi(2)).sum::<f64>() / (n - 1) as f64);
    for k in 0..3 {
        // The fixed point's quantum (2^-18) enters once per reading, unbiased: ~1e-9 of the mean.
        assert!((all.mean()[k] - mean[k]).abs() < 1e-8 * mean[k].abs().max(1.0), "axis {k}: {} vs {}", all.mean()[k], mean[k]);
        assert!(rel(all.variance()[k], var[k]) < 1e-3, "axis {k}: {} vs {}", all.variance()[k], var[k]);
    }
    // A scatter a million times below the mean (25 degC within 1 mdegC) is still resolved.
    assert!(rel(all.variance()[2], var[2]) < 1e-3);
}

/// `Exp(φ)` of a rotation vector (rad), in f64.
fn exp64(phi: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(*phi).into_inner()
}

/// The angle (rad) between two rotations.
fn angle(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    let d = a.transpose() * b;
    let skew = Vector3::new(d[(2, 1)] - d[(1, 2)], d[(0, 2)] - d[(2, 0)], d[(1, 0)] - d[(0, 1)]) * 0.5;
    skew.norm().atan2((d.trace() - 1.0) / 2.0)
}

#[test]
fn a_move_chunked_in_f32_composes_as_in_f64_at_952_hz() {
    // The largest turn (540 deg) at 952 Hz with a wobble about a second axis (coning): the
    // rotation the f32 chunks compose at K = I against the same chunked integration (trapezoid
    // increments, coning integral β, a chunk per CHUNK_DEG, Exp(Γ + β) each) in f64 (rounding
    // only), and against the rotation integrated finely from the rate itself (16 steps a sample:
    // what the chunking's approximation leaves).
    let mut r: Rotations<4, 512> = Rotations::new();
    r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias::default()).unwrap();
    r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias::default()).unwrap();
    r.begin(0);
    let (dt, secs) = (1.0 / 952.0, 3.0);
    let rate = |t: f64| {
        let spin = 360.0 * (std::f64::consts::PI * t / secs).sin().powi(2);
        let wob = 40.0 * (7.0 * t).sin();
        [spin * 0.6 + wob * 0.3, -spin * 0.48 + wob * 0.9, spin * 0.64 - wob * 0.3]
    };
    let (mut reference, mut exact) = (Matrix3::<f64>::identity(), Matrix3::<f64>::identity());
    let (mut gamma, mut coning) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
    let mut close = |gamma: &mut Vector3<f64>, coning: &mut Vector3<f64>| {
        reference *= exp64(&(gamma.map(f64::to_radians) + coning.map(|v| v.to_radians().to_radians())));
        (*gamma, *coning) = (Vector3::zeros(), Vector3::zeros());
    };
    let mut prev: Option<[f32; 3]> = None;
    let t0 = 3600.0;
    for i in 0..=(secs / dt) as usize {
        let t = i as f64 * dt;
        let w = rate(t).map(|v| v as f32);
        r.add(at(t0 + t), w, false);
        if let Some(p) = prev {
            let d = Vector3::from_fn(|k, _| 0.5 * (p[k] as f64 + w[k] as f64) * dt);
            // β (deg²): ½ Σ Γ × d.
            coning += gamma.cross(&d) * 0.5;
            gamma += d;
            for j in 0..16 {
                let tj = t - dt + (j as f64 + 0.5) * dt / 16.0;
                exact *= exp64(&(Vector3::from(rate(tj)).map(f64::to_radians) * (dt / 16.0)));
            }
            if gamma.norm() >= calib_core::estimators::rotation::CHUNK_DEG {
                close(&mut gamma, &mut coning);
            }
        }
        prev = Some(w);
    }
    close(&mut gamma, &mut coning);
    r.end(1, &RotationLimits::default()).unwrap();
    let m = r.moves()[0];
    let got = r.rotation(&m, &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).unwrap();
    let (rounding, chunking) = (angle(&reference, &got), angle(&exact, &got));
    println!("MEASURED {:.1} deg: {rounding:.2e} rad from the f64 integration, {chunking:.2e} rad from the fine one", m.turn_deg);
    // 1e-5 rad over a 540 deg move: 1e-6 of the turn, 100x below the 1e-4 a K resolves.
    assert!(rounding < 1e-5, "{rounding:e} rad");
    // The chunks' second-order (Bortz) vector: 1.6e-5 rad measured; with its coning term at
    // half strength 1.2e-3 rad, the turn a K error of 1.3e-4 makes.
    assert!(chunking < 5e-5, "{chunking:e} rad");
}

#[test]
fn a_pose_turn_in_f32_rises_as_in_f64_an_hour_in() {
    // A 10 s pose at 952 Hz an hour after power-on (times near 3600 s): the turn from its mean
    // instant to its end against the same sums in f64.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let (mut turn, mut a, mut c) = (PoseTurn::new(), [0.0f64; 3], [0.0f64; 3]);
    let (t_first, dt) = (3600.123, 1.0 / 952.0);
    let mut half = PoseTurn::new();
    let n = 9520;
    for i in 1..=n {
        let t = t_first + i as f64 * dt;
        let w: [f32; 3] = core::array::from_fn(|k| (0.8 * (2.0 * t + k as f64).sin()) as f32 + rng.random_range(-0.1..0.1));
        if i <= n / 2 {
            turn.add(at(t), dt, w)
        } else {
            half.add(at(t), dt, w)
        }
        for k in 0..3 {
            a[k] += w[k] as f64 * dt;
            c[k] += t * w[k] as f64 * dt;
        }
    }
    turn.merge(&half);
    let t_last = t_first + n as f64 * dt;
    let got = turn.rise_deg(at(t_first), at(t_last));
    for k in 0..3 {
        let want = (c[k] - t_first * a[k]) / (t_last - t_first);
        assert!((got[k] as f64 - want).abs() < 1e-6, "axis {k}: {} vs {want}", got[k]);
    }
}
