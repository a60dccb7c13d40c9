//! What a magnetometer calibration buys a user: the tilt-compensated heading error over random
//! attitudes, against the simulator's truth, in the calibrated accelerometer's frame (the frame
//! `K`, `M` and the magnetometer's `A` share: `Q = polar(M̂ C_a)`).

use crate::sim::Rig;
use calib_core::estimators::mag::heading_deg;
use calib_core::math::vec3::{mat_to_real, to_real};
use nalgebra::{Matrix3, Quaternion, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// A calibration as applied: accelerometer `f = M (a − o)` (g) and magnetometer
/// `m = A (m_raw − o_m)` (µT).
#[derive(Clone, Copy, Debug)]
pub struct Applied {
    /// `M`.
    pub accel_m: [[f32; 3]; 3],
    /// `o` (g).
    pub accel_o: [f32; 3],
    /// `A`.
    pub mag_a: [[f32; 3]; 3],
    /// `o_m` (µT).
    pub mag_o: [f32; 3],
}

/// `Q = polar(M̂ C_a)`: the calibrated accelerometer's frame (that of `K`, `M` and `A`) from
/// the body frame B, for a calibrated `M̂` (row-major).
pub fn calibrated_frame(accel_m: [[f32; 3]; 3], rig: &Rig) -> Option<Matrix3<f64>> {
    let svd = (mat_to_real(&accel_m) * rig.truth().accel_c).svd(true, true);
    Some(svd.u? * svd.v_t?)
}

/// Heading (°, clockwise from magnetic north seen from above, −180..180] of the vector `x_w`
/// (in W) under the site's field `field_w`: W's z is up.
pub fn heading_w(x_w: &Vector3<f64>, field_w: &Vector3<f64>) -> Option<f64> {
    let north = Vector3::new(field_w[0], field_w[1], 0.0).try_normalize(1e-9)?;
    let east = north.cross(&Vector3::z());
    Some(x_w.dot(&east).atan2(x_w.dot(&north)).to_degrees())
}

/// (RMS, largest) heading error (°) of `cal` over `n` random attitudes (noise-free readings of
/// the rig's parts); `None` without a magnetometer.
pub fn heading_error(cal: &Applied, rig: &Rig, n: usize, seed: u64) -> Option<(f64, f64)> {
    let truth = rig.truth();
    let mag = truth.mag?;
    let q_frame = calibrated_frame(cal.accel_m, rig)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut ss, mut max) = (0.0, 0.0f64);
    for _ in 0..n {
        let g: [f64; 4] = core::array::from_fn(|_| StandardNormal.sample(&mut rng));
        let q = UnitQuaternion::from_quaternion(Quaternion::new(g[0], g[1], g[2], g[3]));
        let (f_b, b_b) = (q.inverse() * Vector3::z(), q.inverse() * mag.field_w);
        let raw_a = truth.accel_c * f_b + truth.accel_offset_g;
        let raw_m = mag.s * b_b + mag.h;
        let est = heading_deg(
            mat_to_real(&cal.accel_m) * (raw_a - to_real(cal.accel_o)),
            mat_to_real(&cal.mag_a) * (raw_m - to_real(cal.mag_o)),
        )?;
        let want = heading_deg(q_frame * f_b, q_frame * b_b)?;
        let e = (est - want + 540.0) % 360.0 - 180.0;
        ss += e * e;
        max = max.max(e.abs());
    }
    Some(((ss / n as f64).sqrt(), max))
}
