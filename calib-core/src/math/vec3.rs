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

/// `vsqrt.f32` through core registers (the FPU's register class needs a target feature that
/// stable Rust does not name), its scratch `s15` saved and restored on the stack.
#[cfg(all(target_arch = "arm", target_abi = "eabihf"))]
fn vsqrt(x: f32) -> f32 {
    let r: u32;
    // SAFETY: FPU instructions the hard-float target has; `s15` is restored, the stack balanced.
    unsafe {
        core::arch::asm!(
            "vpush {{s15}}",
            "vmov s15, {x}",
            "vsqrt.f32 s15, s15",
            "vmov {r}, s15",
            "vpop {{s15}}",
            x = in(reg) x.to_bits(),
            r = lateout(reg) r,
            options(pure, readonly, preserves_flags),
        )
    };
    f32::from_bits(r)
}

/// `a − b`, element-wise (e.g. a raw gyro reading minus the bias, °/s).
pub fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// An orthonormal basis `(e₁, e₂)` of the plane ⟂ the unit vector `u`.
pub fn tangent_basis(u: &Vector3<Real>) -> [Vector3<Real>; 2] {
    let helper = if u[0].abs() < 0.6 { Vector3::x() } else { Vector3::y() };
    let e1 = u.cross(&helper).normalize();
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
