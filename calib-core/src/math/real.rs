//! [`Real`]: the number the fits and solves compute in, and the functions of it they use.
//!
//! `f32` on the Cortex-M4F (feature `single`, every firmware build: its FPU adds and
//! multiplies in one cycle, where `f64` is software), `f64` on the PC (the offline tool, the
//! simulator, the benchmarks). Times are integer µs in both ([`crate::Time`]): a timestamp an
//! hour after boot needs a resolution `f32` does not have; differences of two are `Real`
//! seconds. The firmware's K against the PC's on the firmware's own log is vboard's precision
//! test.

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

use super::wide::Wide;

/// What needs more than `f32` whatever [`Real`] is (the normal equations' sums: their residual is
/// a small difference of large sums): `f64` on the PC, a [`Wide`] double-single on the FPU (no
/// software `f64` on the firmware).
#[cfg(feature = "single")]
pub type Sum = Wide;
/// What needs more than `f32` whatever [`Real`] is (see the `single` build's).
#[cfg(not(feature = "single"))]
pub type Sum = f64;

/// `x` as a [`Sum`] (exactly).
#[inline]
pub const fn widen(x: Real) -> Sum {
    #[cfg(feature = "single")]
    {
        Wide::new(x)
    }
    #[cfg(not(feature = "single"))]
    {
        x
    }
}

/// The [`Real`] nearest `s`.
#[inline]
pub fn narrow(s: Sum) -> Real {
    #[cfg(feature = "single")]
    {
        s.to_f32()
    }
    #[cfg(not(feature = "single"))]
    {
        s
    }
}

/// `x²`.
pub fn sq(x: Real) -> Real {
    x * x
}

/// `√x` (the FPU's `vsqrt.f32` on the firmware).
#[inline]
pub fn sqrt(x: Real) -> Real {
    Scalar::sqrt(x)
}

/// The floating-point types the code is generic over where it runs in both: [`Real`], and
/// [`Sum`] for the normal equations' sums (the Cholesky routines of `linalg`; each instance is
/// linked only where used).
pub(crate) trait Scalar:
    Copy
    + PartialOrd
    + core::ops::Add<Output = Self>
    + core::ops::Sub<Output = Self>
    + core::ops::Mul<Output = Self>
    + core::ops::Div<Output = Self>
    + core::ops::SubAssign
{
    /// 0 and 1.
    const ZERO: Self;
    const ONE: Self;
    /// `√self`.
    fn sqrt(self) -> Self;
    /// `|self|`.
    fn abs(self) -> Self;
    /// The larger of the two (the other for a NaN).
    fn max(self, other: Self) -> Self;
    /// Neither infinite nor NaN.
    fn is_finite(self) -> bool;
}

macro_rules! scalar {
    ($t:ident, $sqrt:path) => {
        impl Scalar for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            fn sqrt(self) -> Self {
                $sqrt(self)
            }
            fn abs(self) -> Self {
                $t::abs(self)
            }
            fn max(self, other: Self) -> Self {
                $t::max(self, other)
            }
            fn is_finite(self) -> bool {
                $t::is_finite(self)
            }
        }
    };
}

scalar!(f32, super::vec3::sqrtf);
scalar!(f64, libm::sqrt);

impl Scalar for Wide {
    const ZERO: Self = Wide::ZERO;
    const ONE: Self = Wide::ONE;
    fn sqrt(self) -> Self {
        Wide::sqrt(self)
    }
    fn abs(self) -> Self {
        Wide::abs(self)
    }
    fn max(self, other: Self) -> Self {
        if other > self || self.to_f32().is_nan() {
            other
        } else {
            self
        }
    }
    fn is_finite(self) -> bool {
        Wide::is_finite(self)
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
