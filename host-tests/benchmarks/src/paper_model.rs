//! The paper's own simulation model (Li et al., "Simulation validation"), used to reproduce its
//! tables: a gyro with scale factors and bias, a rotation at a nominal speed with per-sample
//! speed noise `N(0, (0.05 ω)²)`, static accelerometer poses with `N(0, 0.005²)` noise, a
//! random installation tilt. Protocol choices the paper leaves open are the fields of
//! [`PaperProtocol`] and are printed by `paper-tables`.

use calib_core::estimators::accel::AccelCalibrator;
use calib_core::estimators::axis::{GeometryLimits, Poses};
use calib_core::estimators::bias::{BiasEstimator, BiasLimits};
use calib_core::estimators::paper;
use calib_core::math::stats::Moments3;
use calib_core::Error;
use nalgebra::{Rotation3, Unit, Vector3};
use rand::Rng;
use rand_distr::{Distribution, Normal};

/// Choices the paper leaves open.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperProtocol {
    /// Sample rate of accelerometer and gyro (Hz).
    pub rate_hz: f64,
    /// Static poses at random shaft angles in [0°, 360°).
    pub poses: usize,
    /// Samples averaged per static pose.
    pub pose_samples: usize,
    /// Samples of the constant-rate spin.
    pub rotation_samples: usize,
    /// Samples of the rest period used for the bias.
    pub rest_samples: usize,
    /// Rotation-length multiplier in the noise study (Table III).
    pub noise_study_factor: usize,
    /// Shaft tilt from vertical drawn from U(lo, hi) (°); the mounting is random with every
    /// component of the axis ≥ `min_axis_component`.
    pub tilt_deg: (f64, f64),
    /// Smallest |component| of the axis on a sensor axis.
    pub min_axis_component: f64,
}

impl Default for PaperProtocol {
    fn default() -> Self {
        Self {
            rate_hz: 100.0,
            poses: 12,
            pose_samples: 100,
            rotation_samples: 1000,
            rest_samples: 200,
            noise_study_factor: 10,
            tilt_deg: (20.0, 70.0),
            min_axis_component: 0.2,
        }
    }
}

/// One simulated sensor and test condition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PaperCase {
    /// True gyro scale factors `K` (`ω = K (g − b)`).
    pub k: [f64; 3],
    /// Gyro bias (°/s).
    pub bias_dps: [f64; 3],
    /// Gyro white noise per sample (°/s).
    pub gyro_noise_dps: f64,
    /// Nominal rotation speed (°/s).
    pub omega_dps: f64,
    /// Relative per-sample speed noise (paper: 0.05).
    pub rotation_noise: f64,
    /// Accelerometer noise per sample per axis (g; paper: 0.005).
    pub accel_noise_g: f64,
    /// Accelerometer scale factors (reading = scale ∘ f + offset).
    pub accel_scale: [f64; 3],
    /// Accelerometer offset (g).
    pub accel_offset_g: [f64; 3],
    /// Calibrate the accelerometer first (6 axis poses, 6-parameter fit of Ye et al.).
    pub precalibrate_accel: bool,
    /// Bias known exactly (the paper's noise study) instead of estimated from a rest.
    pub bias_known: bool,
    /// Fixed installation (axis in B, tilt from vertical in °) instead of a random one.
    pub geometry: Option<([f64; 3], f64)>,
}

impl PaperCase {
    /// The paper's first simulation: `K ~ U(0.9, 1.1)`, bias `~ U(−2, 2)` °/s, perfect accelerometer.
    pub fn random(rng: &mut impl Rng) -> Self {
        Self {
            k: std::array::from_fn(|_| rng.random_range(0.9..1.1)),
            bias_dps: std::array::from_fn(|_| rng.random_range(-2.0..2.0)),
            gyro_noise_dps: 0.01,
            omega_dps: 20.0,
            rotation_noise: 0.05,
            accel_noise_g: 0.005,
            accel_scale: [1.0; 3],
            accel_offset_g: [0.0; 3],
            precalibrate_accel: false,
            bias_known: false,
            geometry: None,
        }
    }
}

fn random_axis(rng: &mut impl Rng, min_component: f64) -> Vector3<f64> {
    loop {
        let v = Vector3::<f64>::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let n = v.norm();
        if n > 0.1 && n <= 1.0 && v.iter().all(|c| (c / n).abs() >= min_component) {
            return v / n;
        }
    }
}

/// Runs one calibration of `case` under `proto`; returns the estimated diagonal of `K`.
pub fn run(case: &PaperCase, proto: &PaperProtocol, rng: &mut impl Rng) -> Result<[f64; 3], Error> {
    let (u, tilt) = match case.geometry {
        Some((axis, tilt_deg)) => (Vector3::from(axis).normalize(), tilt_deg.to_radians()),
        None => (random_axis(rng, proto.min_axis_component), rng.random_range(proto.tilt_deg.0..proto.tilt_deg.1).to_radians()),
    };
    let side = u.cross(&random_axis(rng, 0.0)).normalize();
    let up0 = Rotation3::from_axis_angle(&Unit::new_normalize(side), tilt) * u;
    let an = Normal::new(0.0, case.accel_noise_g).map_err(|_| Error::NonFinite)?;
    let gn = Normal::new(0.0, case.gyro_noise_dps).map_err(|_| Error::NonFinite)?;
    let rn = Normal::new(0.0, case.rotation_noise).map_err(|_| Error::NonFinite)?;
    let accel = |f: Vector3<f64>, rng: &mut dyn rand::RngCore| -> [f32; 3] {
        std::array::from_fn(|i| (case.accel_scale[i] * f[i] + case.accel_offset_g[i] + an.sample(rng)) as f32)
    };
    let mean_pose = |f: Vector3<f64>, rng: &mut dyn rand::RngCore| {
        let mut w = Moments3::new();
        for _ in 0..proto.pose_samples {
            w.add(accel(f, rng));
        }
        w.mean().map(|v| v as f32)
    };
    // Accelerometer pre-calibration on the six axis poses.
    let accel_cal = if case.precalibrate_accel {
        let mut c = <AccelCalibrator>::new();
        for f in [Vector3::x(), -Vector3::x(), Vector3::y(), -Vector3::y(), Vector3::z(), -Vector3::z()] {
            c.add_pose(mean_pose(f, rng))?;
        }
        Some(c.solve6()?)
    } else {
        None
    };
    // Gyro reading of a true body rate.
    let gyro = |w: Vector3<f64>, rng: &mut dyn rand::RngCore| -> [f32; 3] {
        std::array::from_fn(|i| (w[i] / case.k[i] + case.bias_dps[i] + gn.sample(rng)) as f32)
    };
    let bias = if case.bias_known {
        case.bias_dps.map(|b| b as f32)
    } else {
        let mut b = BiasEstimator::new();
        for _ in 0..proto.rest_samples {
            b.add(gyro(Vector3::zeros(), rng), accel(up0, rng));
        }
        b.finish(&BiasLimits { min_samples: 10, max_std_dps: 100.0, max_accel_std_g: 1.0, ..BiasLimits::default() })?.bias_dps
    };
    let mut poses = Poses::new();
    for _ in 0..proto.poses {
        let th = rng.random_range(0.0..std::f64::consts::TAU);
        let f = Rotation3::from_axis_angle(&Unit::new_normalize(u), -th) * up0;
        let a = mean_pose(f, rng);
        poses.push(accel_cal.map_or(a, |c| c.apply(a)))?;
    }
    let mut rot = Moments3::new();
    for _ in 0..proto.rotation_samples * if case.bias_known { proto.noise_study_factor } else { 1 } {
        let g = gyro(u * case.omega_dps * (1.0 + rn.sample(rng)), rng);
        rot.add([g[0] - bias[0], g[1] - bias[1], g[2] - bias[2]]);
    }
    let limits = GeometryLimits { min_span_deg: 45.0, ..GeometryLimits::default() };
    let gbar = rot.mean().map(|v| v as f32);
    let cal = paper::solve(&poses, gbar, case.omega_dps as f32, &limits)?;
    Ok(std::array::from_fn(|i| cal.k[i][i] as f64))
}
