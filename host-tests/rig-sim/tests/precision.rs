//! `f32` inputs, `f64` accumulators: results within 1e-5 relative of an `f64` reference over
//! 100 000 samples (a naive `f32` running mean is not).

use calib_core::estimators::bias::{BiasEstimator, BiasLimits};
use calib_core::estimators::sweep::Integrator;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

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
    let mut ref64 = [0.0f64; 3];
    for _ in 0..N {
        t += 1.0 / 952.0 * (1.0 + rng.random_range(-0.01..0.01));
        let g: [f32; 3] = [21.7 + rng.random_range(-0.5..0.5), -8.9 + rng.random_range(-0.5..0.5), 13.3 + rng.random_range(-0.5..0.5)];
        it.add(t, g);
        if let Some((t0, g0)) = prev {
            for k in 0..3 {
                ref64[k] += 0.5 * (g0[k] as f64 + g[k] as f64) * (t - t0);
            }
        }
        prev = Some((t, g));
    }
    let gamma = it.gamma();
    for k in 0..3 {
        // The result handed to the f32 world, rounded to f32.
        assert!(rel(gamma[k] as f32 as f64, ref64[k]) < 1e-5, "axis {k}");
    }
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
