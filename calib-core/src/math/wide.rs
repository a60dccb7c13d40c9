//! [`Wide`]: a double-single number, the unevaluated sum of two `f32`s (a 48-bit significand,
//! `f32`'s exponent range), for the few sums and solves that need more than `f32` (the normal
//! equations' sums, the FIFO timestamps' line), computed on the Cortex-M4F's single-precision FPU
//! instead of software `f64`. Error-free transformations: Knuth's two-sum and Dekker's product
//! (Dekker 1971; Hida, Li and Bailey's double-double, in half the width). They rely on every
//! `f32` operation being rounded on its own, which Rust guarantees (no contraction into fused
//! multiply-adds, no reassociation).

use core::cmp::Ordering;
use core::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// `hi + lo` with `|lo| ≤ ulp(hi) / 2`: about 14 significant digits.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Wide {
    hi: f32,
    lo: f32,
}

/// `a + b` as `s + e` exactly (`s` the rounded sum).
#[inline]
fn two_sum(a: f32, b: f32) -> (f32, f32) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// [`two_sum`] for `|a| ≥ |b|`.
#[inline]
fn fast_two_sum(a: f32, b: f32) -> Wide {
    let s = a + b;
    Wide { hi: s, lo: b - (s - a) }
}

/// `a` as two halves of 12 bits each (Veltkamp's split, `2¹² + 1`).
#[inline]
fn split(a: f32) -> (f32, f32) {
    let c = 4097.0 * a;
    let hi = c - (c - a);
    (hi, a - hi)
}

/// `a · b` as `p + e` exactly (`p` the rounded product; `|a|, |b|` below 8e34).
#[inline]
fn two_prod(a: f32, b: f32) -> (f32, f32) {
    let p = a * b;
    let ((ah, al), (bh, bl)) = (split(a), split(b));
    (p, ((ah * bh - p) + ah * bl + al * bh) + al * bl)
}

impl Wide {
    /// 0.
    pub const ZERO: Wide = Wide { hi: 0.0, lo: 0.0 };
    /// 1.
    pub const ONE: Wide = Wide { hi: 1.0, lo: 0.0 };

    /// `x` exactly.
    pub const fn new(x: f32) -> Wide {
        Wide { hi: x, lo: 0.0 }
    }

    /// `n` exactly below 2⁴⁸ in magnitude (to 48 bits beyond).
    pub fn from_i64(n: i64) -> Wide {
        let hi = n as f32;
        // `n − hi` is below 2⁴⁰ for |n| < 2⁶³: exact in i64, to 24 bits in f32.
        fast_two_sum(hi, n.saturating_sub(hi as i64) as f32)
    }

    /// The nearest `f32`.
    pub fn to_f32(self) -> f32 {
        self.hi + self.lo
    }

    /// Rounded to the nearest integer (halves away from zero), saturating at `i64`'s range.
    pub fn round_i64(self) -> i64 {
        let a = libm::roundf(self.hi);
        let r = libm::roundf((self.hi - a) + self.lo);
        (a as i64).saturating_add(r as i64)
    }

    /// `√self` (NaN below 0).
    pub fn sqrt(self) -> Wide {
        if !(self.hi > 0.0) {
            return Wide::new(if self.hi == 0.0 { 0.0 } else { f32::NAN });
        }
        // One Newton step from the f32 root: x + (a − x²) / 2x.
        let x = super::vec3::sqrtf(self.hi);
        let (p, e) = two_prod(x, x);
        fast_two_sum(x, (((self.hi - p) - e) + self.lo) / (2.0 * x))
    }

    /// `|self|`.
    pub fn abs(self) -> Wide {
        if self.hi < 0.0 {
            -self
        } else {
            self
        }
    }

    /// Neither infinite nor NaN.
    pub fn is_finite(self) -> bool {
        self.hi.is_finite() && self.lo.is_finite()
    }
}

impl Neg for Wide {
    type Output = Wide;
    fn neg(self) -> Wide {
        Wide { hi: -self.hi, lo: -self.lo }
    }
}

impl Add for Wide {
    type Output = Wide;
    /// The accurate sum (two two-sums: the low parts' own rounding carried).
    #[inline(never)] // one copy: 30 instructions
    fn add(self, b: Wide) -> Wide {
        let (s, e) = two_sum(self.hi, b.hi);
        let (t, f) = two_sum(self.lo, b.lo);
        let Wide { hi, lo } = fast_two_sum(s, e + t);
        fast_two_sum(hi, lo + f)
    }
}

impl Sub for Wide {
    type Output = Wide;
    fn sub(self, b: Wide) -> Wide {
        self + -b
    }
}

impl Mul for Wide {
    type Output = Wide;
    #[inline(never)] // one copy: 25 instructions
    fn mul(self, b: Wide) -> Wide {
        let (p, e) = two_prod(self.hi, b.hi);
        fast_two_sum(p, e + (self.hi * b.lo + self.lo * b.hi))
    }
}

impl Div for Wide {
    type Output = Wide;
    /// Long division: the f32 quotient and one correction.
    #[inline(never)]
    fn div(self, b: Wide) -> Wide {
        let q = self.hi / b.hi;
        let r = self - b * Wide::new(q);
        fast_two_sum(q, r.hi / b.hi)
    }
}

impl AddAssign for Wide {
    fn add_assign(&mut self, b: Wide) {
        *self = *self + b;
    }
}

impl SubAssign for Wide {
    fn sub_assign(&mut self, b: Wide) {
        *self = *self - b;
    }
}

impl MulAssign for Wide {
    fn mul_assign(&mut self, b: Wide) {
        *self = *self * b;
    }
}

impl PartialOrd for Wide {
    fn partial_cmp(&self, b: &Wide) -> Option<Ordering> {
        match self.hi.partial_cmp(&b.hi)? {
            Ordering::Equal => self.lo.partial_cmp(&b.lo),
            o => Some(o),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;

    fn f64_of(w: Wide) -> f64 {
        w.hi as f64 + w.lo as f64
    }

    /// `f32`s of every sign and magnitude from 1e-6 to 1e9 (xorshift, fixed seed).
    fn values(n: usize) -> impl Iterator<Item = f64> {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        (0..n).map(move |_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let m = (x >> 11) as f64 / (1u64 << 53) as f64;
            let e = ((x & 0xFF) as i32 % 16) - 6;
            let v = (0.5 + m) * libm::pow(10.0, e as f64);
            if x >> 63 == 1 {
                -v
            } else {
                v
            }
        })
    }

    /// A value as a `Wide` (its 48 leading bits).
    fn wide(v: f64) -> Wide {
        let hi = v as f32;
        Wide { hi, lo: (v - hi as f64) as f32 }
    }

    /// Each operation within a few units of 2⁻⁴⁶ of the `f64` result.
    #[test]
    fn operations_keep_46_bits() {
        let vs: std::vec::Vec<f64> = values(400).collect();
        for w in vs.windows(2) {
            let (a, b) = (w[0], w[1]);
            let (wa, wb) = (wide(a), wide(b));
            let (a, b) = (f64_of(wa), f64_of(wb));
            let close = |got: Wide, want: f64, scale: f64, what: &str| {
                assert!(
                    (f64_of(got) - want).abs() <= 4.0 * libm::ldexp(scale, -47),
                    "{what} of {a:e}, {b:e}: {:e} vs {want:e}",
                    f64_of(got)
                );
            };
            close(wa + wb, a + b, a.abs().max(b.abs()), "sum");
            close(wa - wb, a - b, a.abs().max(b.abs()), "difference");
            close(wa * wb, a * b, (a * b).abs(), "product");
            close(wa / wb, a / b, (a / b).abs(), "quotient");
            close(wa.abs().sqrt(), a.abs().sqrt(), a.abs().sqrt(), "root");
            assert_eq!(wa < wb, a < b);
        }
        assert!(Wide::new(-4.0).sqrt().to_f32().is_nan());
        assert_eq!(Wide::ZERO.sqrt(), Wide::ZERO);
    }

    /// What `f32` cannot: a small difference of large sums (the normal equations' residual).
    #[test]
    fn a_sum_of_a_million_terms_cancels_as_in_f64() {
        let (mut w, mut d, mut f) = (Wide::ZERO, 0.0f64, 0.0f32);
        for (k, v) in values(1_000_000).enumerate() {
            let v = v as f32;
            let t = if k % 2 == 0 { v } else { -v * 0.999_9 };
            w += Wide::new(t) * Wide::new(t);
            d += t as f64 * t as f64;
            f += t * t;
        }
        assert!((f64_of(w) - d).abs() < 1e-11 * d, "{:e} vs {d:e}", f64_of(w));
        assert!((f as f64 - d).abs() > 1e-5 * d, "the test would not discriminate: f32 {f:e} vs {d:e}");
    }

    #[test]
    fn integers_and_rounding() {
        for n in [0i64, 1, -1, 16_777_217, -123_456_789_012, (1 << 47) + 12_345] {
            assert_eq!(Wide::from_i64(n).round_i64(), n);
        }
        assert_eq!((wide(2.5e9 + 0.5)).round_i64(), 2_500_000_001);
        assert_eq!((wide(-7.4)).round_i64(), -7);
    }
}
