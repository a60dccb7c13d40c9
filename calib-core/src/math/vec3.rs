//! The 3-vector helpers around the `[f32; 3]` API.

use crate::math::real::Real;
use crate::{Mat3, Vec3};
use nalgebra::{Matrix3, Vector3};

/// `√x` on the FPU (`vsqrt.f32`, 14 cycles on a Cortex-M4F; libm's is software there), libm's
/// elsewhere.
#[inline]
pub fn sqrtf(x: f32) -> f32 {
    #[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
    {
        vsqrt(x)
    }
    #[cfg(not(all(target_arch = "arm", target_abi = "eabihf")))]
    {
        libm::sqrtf(x)
    }
}

/// `vsqrt.f32` alone, called (AAPCS-VFP: `x` and the result in `s0`): one `bl` at each use
/// instead of an inlined sequence (the FPU's register class needs a target feature that stable
/// Rust does not name, so `asm!` would move `x` through core registers and a saved `s15`).
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
#[unsafe(naked)]
extern "C" fn vsqrt(x: f32) -> f32 {
    core::arch::naked_asm!(".fpu fpv4-sp-d16", "vsqrt.f32 s0, s0", "bx lr")
}

/// `a − b`, element-wise (e.g. a raw gyro reading minus the bias, °/s).
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// A [`Real`] 3-vector's length and direction through [`crate::math::real::sqrt`] (the FPU's on
/// the firmware; nalgebra's `norm` would link libm's software `sqrtf`).
pub trait Length {
    /// `|v|`, in the vector's units.
    fn length(&self) -> Real;
    /// `v / |v|` (NaN for the zero vector, as nalgebra's `normalize`).
    fn unit(&self) -> Self;
    /// `v / |v|`, or `None` if `|v| <= min`.
    fn try_unit(&self, min: Real) -> Option<Self>
    where
        Self: Sized;
}

impl Length for Vector3<Real> {
    fn length(&self) -> Real {
        crate::math::real::sqrt(self.norm_squared())
    }
    fn unit(&self) -> Self {
        self / self.length()
    }
    fn try_unit(&self, min: Real) -> Option<Self> {
        let n = self.length();
        (n > min).then(|| self / n)
    }
}

/// An orthonormal basis `(e₁, e₂)` of the plane ⟂ the unit vector `u`.
pub fn tangent_basis(u: &Vector3<Real>) -> [Vector3<Real>; 2] {
    let helper = if u[0].abs() < 0.6 { Vector3::x() } else { Vector3::y() };
    let e1 = u.cross(&helper).unit();
    [e1, u.cross(&e1)]
}

/// The same vector in [`Real`] for the math.
pub fn to_real(a: Vec3) -> Vector3<Real> {
    Vector3::new(a[0] as Real, a[1] as Real, a[2] as Real)
}

/// A row-major `[[f32; 3]; 3]` as a [`Real`] matrix.
pub fn mat_to_real(m: &Mat3) -> Matrix3<Real> {
    Matrix3::from_fn(|r, c| m[r][c] as Real)
}
