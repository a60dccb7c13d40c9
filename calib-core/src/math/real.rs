//! [`Real`]: the number the fits and solves compute in, and the functions of it they use.
//!
//! `f32` on the Cortex-M4F (feature `single`, every firmware build: its FPU adds and
//! multiplies in one cycle, where `f64` is software), `f64` on the PC (the offline tool, the
//! simulator, the benchmarks). Times stay `f64` seconds in both: a timestamp an hour after boot
//! needs a resolution `f32` does not have. The firmware's K against the PC's on the firmware's
//! own log is vboard's precision test.

/// The fits' and solves' real number (see the module).
#[cfg(feature = "single")]
pub type Real = f32;
/// The fits' and solves' real number (see the module).
#[cfg(not(feature = "single"))]
pub type Real = f64;

#[cfg(feature = "single")]
pub use core::f32::consts;
#[cfg(not(feature = "single"))]
pub use core::f64::consts;

/// `√x` (the FPU's `vsqrt.f32` on the firmware).
#[inline]
pub fn sqrt(x: Real) -> Real {
    #[cfg(feature = "single")]
    {
        super::vec3::sqrtf(x)
    }
    #[cfg(not(feature = "single"))]
    {
        libm::sqrt(x)
    }
}

/// `eˣ`.
#[inline]
pub fn exp(x: Real) -> Real {
    #[cfg(feature = "single")]
    {
        libm::expf(x)
    }
    #[cfg(not(feature = "single"))]
    {
        libm::exp(x)
    }
}

/// `x` rounded to the nearest integer, halves away from zero.
#[inline]
pub fn round(x: Real) -> Real {
    #[cfg(feature = "single")]
    {
        libm::roundf(x)
    }
    #[cfg(not(feature = "single"))]
    {
        libm::round(x)
    }
}
