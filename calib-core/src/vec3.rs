//! The two 3-vector helpers every shell needs around the `[f32; 3]` API.

use crate::Vec3;
use nalgebra::Vector3;

/// `a − b`, element-wise (e.g. a raw gyro reading minus the bias, °/s).
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The same vector in `f64` for the math.
pub fn to_f64(a: Vec3) -> Vector3<f64> {
    Vector3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}
