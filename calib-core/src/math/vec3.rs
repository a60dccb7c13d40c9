//! The 3-vector helpers around the `[f32; 3]` API.

use crate::{Mat3, Vec3};
use nalgebra::{Matrix3, Vector3};

/// `a − b`, element-wise (e.g. a raw gyro reading minus the bias, °/s).
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// An orthonormal basis `(e₁, e₂)` of the plane ⟂ the unit vector `u`.
pub fn tangent_basis(u: &Vector3<f64>) -> [Vector3<f64>; 2] {
    let helper = if u[0].abs() < 0.6 { Vector3::x() } else { Vector3::y() };
    let e1 = u.cross(&helper).normalize();
    [e1, u.cross(&e1)]
}

/// The same vector in `f64` for the math.
pub fn to_f64(a: Vec3) -> Vector3<f64> {
    Vector3::new(a[0] as f64, a[1] as f64, a[2] as f64)
}

/// A row-major `[[f32; 3]; 3]` as an `f64` matrix.
pub fn mat_to_f64(m: &Mat3) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| m[r][c] as f64)
}
