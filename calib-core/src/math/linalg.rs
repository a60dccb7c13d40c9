//! Small dense linear algebra: Cholesky factorisation (in [`Real`] or [`real::Sum`]: [`Scalar`]) and the
//! symmetric Jacobi eigen-decomposition. No allocation, bounded iteration counts. Each routine is
//! one core on a row-major slice (`n × n`, `n ≤ MAX_N`, generic over its scalar alone) behind a
//! thin wrapper generic over the size, so the firmware links one copy a scalar whatever the sizes.

use crate::math::real::{self, Real, Scalar};
use nalgebra::Matrix3;

/// `det(K) K⁻ᵀ`, the cofactor matrix (columns `k₁ × k₂`, `k₂ × k₀`, `k₀ × k₁` of the columns
/// `k_c` of `K`); `None` for a singular `K`.
pub(crate) fn cofactor(k: &Matrix3<Real>) -> Option<Matrix3<Real>> {
    let at = |r: usize, c: usize| k[(r % 3, c % 3)];
    let cof = Matrix3::from_fn(|r, c| at(r + 1, c + 1) * at(r + 2, c + 2) - at(r + 2, c + 1) * at(r + 1, c + 2));
    (k.column(0).dot(&cof.column(0)) != 0.0).then_some(cof)
}

/// `K⁻¹` of a 3 × 3 matrix from its [`cofactor`] matrix (one small routine for every 3 × 3
/// inverse: nalgebra's general one costs the firmware 768 B of flash); `None` when singular.
pub(crate) fn inverse3(k: &Matrix3<Real>) -> Option<Matrix3<Real>> {
    let cof = cofactor(k)?;
    Some(cof.transpose() / k.column(0).dot(&cof.column(0)))
}

/// Largest dimension of the dense routines.
pub(crate) const MAX_N: usize = 9;

/// Lower-triangular Cholesky factor `L` of a symmetric positive-definite `a = L Lᵀ`.
///
/// Returns `None` when a pivot is not positive relative to `rel_tol × max diagonal`
/// (singular or indefinite within the precision of the data).
pub(crate) fn cholesky<T: Scalar, const N: usize>(a: &[[T; N]; N], rel_tol: T) -> Option<[[T; N]; N]> {
    let mut l = [[T::ZERO; N]; N];
    cholesky_in(a.as_flattened(), l.as_flattened_mut(), N, rel_tol).then_some(l)
}

/// [`cholesky`] of the `n × n` row-major `a` (only its lower triangle is read) into `l` (zeroed
/// by the caller); `false` for a non-positive pivot.
pub(crate) fn cholesky_in<T: Scalar>(a: &[T], l: &mut [T], n: usize, rel_tol: T) -> bool {
    let scale = (0..n).fold(T::ZERO, |m, i| m.max(a[i * n + i].abs()));
    if !(scale > T::ZERO && scale.is_finite()) {
        return false;
    }
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= l[j * n + k] * l[j * n + k];
        }
        if !(d > rel_tol * scale) {
            return false;
        }
        let d = d.sqrt();
        l[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= l[i * n + k] * l[j * n + k];
            }
            l[i * n + j] = s / d;
        }
    }
    true
}

/// Solves `L Lᵀ x = b` for a Cholesky factor `L`.
pub(crate) fn cholesky_solve<T: Scalar, const N: usize>(l: &[[T; N]; N], b: &[T; N]) -> [T; N] {
    const { assert!(N <= MAX_N) };
    let mut x = [T::ZERO; N];
    cholesky_solve_in(l.as_flattened(), b, &mut x);
    x
}

/// [`cholesky_solve`] with `n = b.len()` and `L` row-major `n × n`.
pub(crate) fn cholesky_solve_in<T: Scalar>(l: &[T], b: &[T], x: &mut [T]) {
    let n = b.len();
    let mut y = [T::ZERO; MAX_N];
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i * n + k] * y[k];
        }
        y[i] = s / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut s = y[i];
        for k in i + 1..n {
            s -= l[k * n + i] * x[k];
        }
        x[i] = s / l[i * n + i];
    }
}

/// Inverse of `L Lᵀ` from its Cholesky factor.
pub(crate) fn cholesky_inverse<T: Scalar, const N: usize>(l: &[[T; N]; N]) -> [[T; N]; N] {
    const { assert!(N <= MAX_N) };
    let mut inv = [[T::ZERO; N]; N];
    cholesky_inverse_in(l.as_flattened(), inv.as_flattened_mut(), N);
    inv
}

/// [`cholesky_inverse`] of the `n × n` row-major `l` into `inv`.
pub(crate) fn cholesky_inverse_in<T: Scalar>(l: &[T], inv: &mut [T], n: usize) {
    for j in 0..n {
        let mut e = [T::ZERO; MAX_N];
        e[j] = T::ONE;
        let mut col = [T::ZERO; MAX_N];
        cholesky_solve_in(l, &e[..n], &mut col[..n]);
        for i in 0..n {
            inv[i * n + j] = col[i];
        }
    }
}

/// Eigenvalues (ascending) and unit eigenvectors (columns, same order) of a symmetric matrix,
/// by cyclic Jacobi rotations (at most 50 sweeps; converges quadratically).
pub(crate) fn sym_eigen<const N: usize>(a: &[[Real; N]; N]) -> ([Real; N], [[Real; N]; N]) {
    let mut m = *a;
    let (mut vals, mut v) = ([0.0; N], [[0.0; N]; N]);
    sym_eigen_in(m.as_flattened_mut(), &mut vals, v.as_flattened_mut());
    (vals, v)
}

/// [`sym_eigen`] with `n = vals.len()`: diagonalises the row-major `m` in place, `v` zeroed by
/// the caller.
pub(crate) fn sym_eigen_in(m: &mut [Real], vals: &mut [Real], v: &mut [Real]) {
    let n = vals.len();
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..50 {
        let mut off = 0.0;
        let mut diag = 0.0;
        for i in 0..n {
            diag += m[i * n + i] * m[i * n + i];
            for j in i + 1..n {
                off += m[i * n + j] * m[i * n + j];
            }
        }
        if off <= 1e-30 * diag || off == 0.0 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let mpq = m[p * n + q];
                if mpq == 0.0 {
                    continue;
                }
                let theta = (m[q * n + q] - m[p * n + p]) / (2.0 * mpq);
                let t = theta.signum() / (theta.abs() + real::sqrt(theta * theta + 1.0));
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / real::sqrt(t * t + 1.0);
                let s = t * c;
                // Columns p, q of m, then its rows p, q, then the columns of v.
                for pass in 0..3 {
                    let (mat, stride, step) = match pass {
                        0 => (&mut *m, 1, n),
                        1 => (&mut *m, n, 1),
                        _ => (&mut *v, 1, n),
                    };
                    for k in 0..n {
                        let (ip, iq) = (k * step + p * stride, k * step + q * stride);
                        let (xp, xq) = (mat[ip], mat[iq]);
                        mat[ip] = c * xp - s * xq;
                        mat[iq] = s * xp + c * xq;
                    }
                }
            }
        }
    }
    // Sort ascending (selection sort: n ≤ 9).
    for (i, val) in vals.iter_mut().enumerate() {
        *val = m[i * n + i];
    }
    for i in 0..n {
        let mut best = i;
        for j in i + 1..n {
            if vals[j] < vals[best] {
                best = j;
            }
        }
        if best != i {
            vals.swap(i, best);
            for k in 0..n {
                v.swap(k * n + i, k * n + best);
            }
        }
    }
}

/// The smallest and largest eigenvalue of the symmetric positive-definite row-major `n × n`
/// matrix `m` (its lower triangle; the smallest is 0 when `m` is not positive definite, or
/// its eigenvalues are 1e16 apart), each to a relative [`EXTREMES_REL`] (an interval's
/// conservative end: the smallest from below, the largest from above). By bisection on
/// Sylvester's law of inertia: `m − x I` is positive definite, its Cholesky factorisation
/// succeeds, exactly when `x` is below every eigenvalue (`x I − m`: above). ≈ 28 factorisations:
/// 1/6 of the work of [`sym_eigen_in`] at `n = 9`, and no code beyond [`cholesky_in`]'s.
pub(crate) fn sym_extremes_in(m: &[Real], n: usize) -> (Real, Real) {
    let (mut a, mut l) = ([0.0; MAX_N * MAX_N], [0.0; MAX_N * MAX_N]);
    // Whether `sign (m − x I)` is positive definite.
    let mut definite = |x: Real, sign: Real| {
        for i in 0..n {
            for j in 0..=i {
                a[i * n + j] = sign * (m[i * n + j] - if i == j { x } else { 0.0 });
            }
        }
        cholesky_in(&a[..n * n], &mut l[..n * n], n, 0.0)
    };
    // The largest lies between the largest diagonal element and the trace (the eigenvalues'
    // sum, all of them positive).
    let diag = (0..n).fold(0.0 as Real, |d, i| d.max(m[i * n + i]));
    let trace = (0..n).map(|i| m[i * n + i]).sum::<Real>();
    let (mut lo, mut hi) = (diag, trace);
    let floor = 1e-16 * hi;
    if !(diag > 0.0 && hi.is_finite() && definite(floor, 1.0)) {
        return (0.0, hi);
    }
    while hi - lo > EXTREMES_REL * hi {
        let mid = 0.5 * (lo + hi);
        *(if definite(mid, -1.0) { &mut hi } else { &mut lo }) = mid;
    }
    let largest = hi;
    // The smallest lies in [floor, trace / n], bisected geometrically.
    let (mut lo, mut hi) = (floor, trace / n as Real);
    while hi > lo * (1.0 + EXTREMES_REL) {
        let mid = real::sqrt(lo * hi);
        *(if definite(mid, 1.0) { &mut lo } else { &mut hi }) = mid;
    }
    (lo, largest)
}

/// The relative precision of [`sym_extremes_in`]: a condition number is compared with a limit
/// and reported to 3 digits (each 1e-5 cost 14 more factorisations, ≈ 1/3 of a fit's time).
const EXTREMES_REL: Real = 1e-3;

/// The cube root of `x > 0` (`x` itself for 0, ∞ or NaN; NaN below 0): Newton's iteration from
/// a third of the exponent. `libm::cbrt` would link a 1 KiB soft `f64` `fma` into the firmware.
pub(crate) fn cbrt(x: Real) -> Real {
    if !(x > 0.0 && x.is_finite()) {
        return if x < 0.0 { Real::NAN } else { x };
    }
    // Within ≈ 10 % of the root (the exponent's bits divided by 3, in 32 bits: no 64-bit
    // division linked; fdlibm's offsets); each step squares the error.
    #[cfg(feature = "single")]
    let mut y = Real::from_bits(x.to_bits() / 3 + 0x2A51_19F2);
    #[cfg(not(feature = "single"))]
    let mut y = Real::from_bits((((x.to_bits() >> 32) as u32 / 3 + 0x2A9F_7893) as u64) << 32);
    for _ in 0..6 {
        y -= (y - x / (y * y)) / 3.0;
    }
    y
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cofactor_is_det_times_inverse_transpose_and_gives_the_inverse() {
        let k = Matrix3::new(1.02, -0.01, 0.03, 0.02, 0.97, -0.04, -0.05, 0.01, 1.01);
        let expect = k.try_inverse().unwrap().transpose() * k.determinant();
        assert!((cofactor(&k).unwrap() - expect).amax() < 1e-15);
        assert!((inverse3(&k).unwrap() * k - Matrix3::identity()).amax() < 1e-15);
        let singular = Matrix3::new(1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.0, 1.0, 1.0);
        assert_eq!((cofactor(&singular), inverse3(&singular)), (None, None));
    }

    #[test]
    fn cbrt_matches_libm_over_the_range_of_f64() {
        for e in -300..300 {
            for m in [1.0, 1.7, 2.9, 5.3, 7.9] {
                let x = m * (10 as Real).powi(e);
                let (ours, libm) = (cbrt(x), libm::cbrt(x));
                assert!((ours - libm).abs() <= 4.0 * Real::EPSILON * libm, "{x:e}: {ours:e} vs {libm:e}");
            }
        }
        assert_eq!(cbrt(0.0), 0.0);
        assert!(cbrt(-1.0).is_nan() && cbrt(Real::NAN).is_nan() && cbrt(Real::INFINITY) == Real::INFINITY);
    }

    #[test]
    fn cholesky_solves_spd_system() {
        let a = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let l = cholesky(&a, 1e-12).unwrap();
        let x = cholesky_solve(&l, &[1.0, 2.0, 3.0]);
        for i in 0..3 {
            let r: Real = (0..3).map(|j| a[i][j] * x[j]).sum();
            assert!((r - [1.0, 2.0, 3.0][i]).abs() < 1e-12);
        }
        let inv = cholesky_inverse(&l);
        for i in 0..3 {
            for j in 0..3 {
                let p: Real = (0..3).map(|k| a[i][k] * inv[k][j]).sum();
                assert!((p - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn cholesky_rejects_singular_and_indefinite() {
        assert!(cholesky(&[[1.0, 1.0], [1.0, 1.0]], 1e-12).is_none());
        assert!(cholesky(&[[1.0, 2.0], [2.0, 1.0]], 1e-12).is_none());
        assert!(cholesky(&[[0.0, 0.0], [0.0, 0.0]], 1e-12).is_none());
    }

    #[test]
    fn extremes_match_jacobi_to_the_condition_limit() {
        // Random symmetric positive-definite matrices Q diag(λ) Qᵀ, scaled to unit diagonal as
        // `lsq`'s condition number does, with condition numbers from 1 to 1e10.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as Real / (1u64 << 53) as Real - 0.5
        };
        for case in 0..60 {
            let n = 2 + case % 8;
            let cond = libm::pow(10.0, (case % 11) as Real);
            let mut a = [0.0; MAX_N * MAX_N];
            for i in 0..n {
                for j in 0..n {
                    a[i * n + j] = if i == j { 1.0 } else { 0.0 };
                }
            }
            // Product of random reflections: an orthogonal Q; A = Q Λ Qᵀ.
            for _ in 0..n {
                let v: [Real; MAX_N] = core::array::from_fn(|_| rnd());
                let vv: Real = v[..n].iter().map(|x| x * x).sum();
                let mut q = [0.0; MAX_N * MAX_N];
                for i in 0..n {
                    for j in 0..n {
                        let h: Real = (0..n).map(|k| (if i == k { 1.0 } else { 0.0 } - 2.0 * v[i] * v[k] / vv) * a[k * n + j]).sum();
                        q[i * n + j] = h;
                    }
                }
                a = q;
            }
            let lam: [Real; MAX_N] = core::array::from_fn(|i| if i < n { libm::pow(cond, -(i as Real) / (n - 1) as Real) } else { 0.0 });
            let mut m = [0.0; MAX_N * MAX_N];
            for i in 0..n {
                for j in 0..n {
                    m[i * n + j] = (0..n).map(|k| a[i * n + k] * lam[k] * a[j * n + k]).sum();
                }
            }
            let mut m1 = m;
            let (mut vals, mut v) = ([0.0; MAX_N], [0.0; MAX_N * MAX_N]);
            sym_eigen_in(&mut m1[..n * n], &mut vals[..n], &mut v[..n * n]);
            let (lo, hi) = sym_extremes_in(&m[..n * n], n);
            // Each within EXTREMES_REL on its conservative side (the condition number from
            // above); the smallest also so up to a condition of 1e12, 1 % beyond.
            let big = vals[n - 1];
            let rel = 1.1 * EXTREMES_REL;
            assert!(hi >= big * (1.0 - 1e-12) && hi <= big * (1.0 + rel), "case {case}: largest {hi} vs {big}");
            let tol = if cond <= 1e12 { rel } else { 1e-2 };
            let small = vals[0];
            assert!(
                lo <= small * (1.0 + 1e-9) && lo >= small * (1.0 - tol),
                "case {case} (n {n}, cond {cond:e}): smallest {lo:e} vs Jacobi's {small:e}"
            );
        }
        // Singular or indefinite: the smallest is 0, the condition number beyond any limit.
        assert_eq!(sym_extremes_in(&[1.0, 1.0, 1.0, 1.0], 2).0, 0.0);
        assert_eq!(sym_extremes_in(&[1.0, 2.0, 2.0, 1.0], 2).0, 0.0);
    }

    #[test]
    fn jacobi_finds_eigenpairs() {
        let a = [[2.0, 1.0, 0.0], [1.0, 2.0, 0.0], [0.0, 0.0, 5.0]];
        let (vals, vecs) = sym_eigen(&a);
        assert!((vals[0] - 1.0).abs() < 1e-12 && (vals[1] - 3.0).abs() < 1e-12);
        assert!((vals[2] - 5.0).abs() < 1e-12);
        for k in 0..3 {
            for i in 0..3 {
                let av: Real = (0..3).map(|j| a[i][j] * vecs[j][k]).sum();
                assert!((av - vals[k] * vecs[i][k]).abs() < 1e-12);
            }
        }
    }
}
