//! Attitude helpers: shaft geometry, smooth hand-held transitions, wobble disturbances and the
//! specific force of an off-axis sensor.
//!
//! Frames: world W with z up; body B = the board frame (docs/frames.md; each part model reads it in its own axes); `q_wb` rotates body vectors into W.

use nalgebra::{Unit, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{PI, TAU};

/// Standard gravity (m/s²): the unit of the accelerometer.
pub const G0: f64 = 9.80665;

/// Unit vector tilted by `tilt_deg` from world +z, at azimuth `azimuth_deg` (from +x towards +y).
pub fn tilted_axis(tilt_deg: f64, azimuth_deg: f64) -> Unit<Vector3<f64>> {
    let (t, a) = (tilt_deg.to_radians(), azimuth_deg.to_radians());
    Unit::new_normalize(Vector3::new(t.sin() * a.cos(), t.sin() * a.sin(), t.cos()))
}

/// Shortest rotation taking direction `a` onto direction `b` (a half-turn if they are opposite).
pub(crate) fn rotation_between(a: &Vector3<f64>, b: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(a, b).unwrap_or_else(|| {
        let e = if a.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
        UnitQuaternion::from_axis_angle(&Unit::new_normalize(a.cross(&e)), PI)
    })
}

/// A unit vector perpendicular to unit `u`: body x (or y if `u` is close to x) minus its
/// component along `u`.
pub(crate) fn perpendicular(u: &Vector3<f64>) -> Vector3<f64> {
    let e = if u.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    (e - u * u.dot(&e)).normalize()
}

/// Rotation vector (rad, in the frame of `a`) of `a⁻¹ b`, the shortest turn from attitude `a`
/// to attitude `b`; exactly zero when `a == b`.
pub(crate) fn rotation_vector_between(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (a, b) = (a.quaternion(), b.quaternion());
    let w = a.w * b.w + a.imag().dot(&b.imag());
    let v = b.imag() * a.w - a.imag() * b.w - a.imag().cross(&b.imag());
    let (w, v) = if w < 0.0 { (-w, -v) } else { (w, v) };
    let n = v.norm();
    if n == 0.0 {
        Vector3::zeros()
    } else {
        v * (2.0 * n.atan2(w) / n)
    }
}

/// Smooth-step 3x² − 2x³ of x clamped to [0, 1]: zero slope at both ends.
pub(crate) fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (3.0 - 2.0 * x)
}

/// A smooth move of the board from a frozen attitude to a (possibly moving) target attitude.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Transition {
    pub from: UnitQuaternion<f64>,
    pub t0_s: f64,
    pub duration_s: f64,
}

impl Transition {
    /// Slerp (shortest path) from `from` to `target` with smooth-step timing, at true time `t_s`.
    pub fn attitude(&self, t_s: f64, target: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        let s = if self.duration_s > 0.0 { smoothstep((t_s - self.t0_s) / self.duration_s) } else { 1.0 };
        let delta = rotation_vector_between(&self.from, target);
        self.from * UnitQuaternion::from_scaled_axis(delta * s)
    }

    pub fn is_over(&self, t_s: f64) -> bool {
        t_s >= self.t0_s + self.duration_s
    }
}

/// Someone touching the rig: a few sinusoids (1–6 Hz) about one random body axis under a
/// Hann window, so the wobble starts and ends at rest.
#[derive(Clone, Debug)]
pub(crate) struct Wobble {
    axis_b: Vector3<f64>,
    /// (angle amplitude rad, angular frequency rad/s, phase rad) per component.
    parts: [(f64, f64, f64); 3],
    t0_s: f64,
    duration_s: f64,
}

impl Wobble {
    /// Each of the three components has a rate amplitude of `amplitude_dps / 3`.
    pub fn new(rng: &mut impl Rng, t0_s: f64, duration_s: f64, amplitude_dps: f64) -> Self {
        let axis_b = Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)).normalize();
        let parts = [(); 3].map(|()| {
            let w = TAU * rng.random_range(1.0..6.0);
            (amplitude_dps.to_radians() / 3.0 / w, w, rng.random_range(0.0..TAU))
        });
        Self { axis_b, parts, t0_s, duration_s }
    }

    /// Body-frame rotation to apply on top of the board attitude at true time `t_s`.
    pub fn rotation(&self, t_s: f64) -> UnitQuaternion<f64> {
        let tau = t_s - self.t0_s;
        if tau <= 0.0 || tau >= self.duration_s {
            return UnitQuaternion::identity();
        }
        let window = (PI * tau / self.duration_s).sin().powi(2);
        let angle: f64 = self.parts.iter().map(|&(a, w, p)| a * (w * tau + p).sin()).sum();
        UnitQuaternion::from_scaled_axis(self.axis_b * (angle * window))
    }

    pub fn is_over(&self, t_s: f64) -> bool {
        t_s >= self.t0_s + self.duration_s
    }
}

/// Acceleration (g, in B) of a point at lever `r_b` (m) from the fixed shaft axis `u_b`, for a
/// shaft rate `rate` (rad/s) and angular acceleration `accel` (rad/s²): tangential α×r plus
/// centripetal ω×(ω×r) = −ω² r.
pub(crate) fn lever_accel_g(u_b: &Vector3<f64>, r_b: &Vector3<f64>, rate: f64, accel: f64) -> Vector3<f64> {
    let (w, a) = (u_b * rate, u_b * accel);
    (a.cross(r_b) + w.cross(&w.cross(r_b))) / G0
}
