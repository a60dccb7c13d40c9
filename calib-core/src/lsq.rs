//! Weighted linear least squares through normal equations, accumulated one row at a time.
//!
//! `NormalEquations<N>` keeps `Σ w x xᵀ`, `Σ w x y`, `Σ w y²` in `f64`: O(N²) state whatever the
//! number of rows. Every linear solve of the crate goes through it (3 unknowns for the gyro,
//! 6 and 9 for the accelerometer).

use crate::linalg::{cholesky, cholesky_inverse, cholesky_solve, sym_eigen};
use crate::Error;

/// Largest accepted condition number of the equilibrated normal matrix (unit diagonal).
pub const MAX_CONDITION: f64 = 1e8;

/// Accumulated normal equations `(Σ w x xᵀ) β = Σ w x y` of an `N`-unknown problem `x·β ≈ y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEquations<const N: usize> {
    xtx: [[f64; N]; N],
    xty: [f64; N],
    yty: f64,
    rows: u32,
}

/// A least-squares solution with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solution<const N: usize> {
    /// The parameters `β`.
    pub x: [f64; N],
    /// Weighted residual sum of squares `Σ w (y − x·β)²`.
    pub rss: f64,
    /// Rows minus unknowns.
    pub dof: u32,
    /// Parameter covariance `s² (Σ w x xᵀ)⁻¹` with `s² = rss / dof` (zero when `dof == 0`).
    pub covariance: [[f64; N]; N],
    /// 2-norm condition number of the equilibrated normal matrix.
    pub condition: f64,
}

impl<const N: usize> Solution<N> {
    /// 1σ of parameter `i` (square root of the covariance diagonal).
    pub fn sigma(&self, i: usize) -> f64 {
        libm::sqrt(self.covariance[i][i].max(0.0))
    }
}

impl<const N: usize> Default for NormalEquations<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> NormalEquations<N> {
    /// Empty equations.
    pub const fn new() -> Self {
        Self { xtx: [[0.0; N]; N], xty: [0.0; N], yty: 0.0, rows: 0 }
    }

    /// Number of rows added.
    pub fn rows(&self) -> u32 {
        self.rows
    }

    /// Adds the row `x·β ≈ y` with weight `w` (inverse variance). Non-finite rows are refused.
    pub fn add_row(&mut self, x: &[f64; N], y: f64, w: f64) -> Result<(), Error> {
        if !(x.iter().all(|v| v.is_finite()) && y.is_finite() && w.is_finite() && w >= 0.0) {
            return Err(Error::NonFinite);
        }
        for i in 0..N {
            let wxi = w * x[i];
            for j in 0..=i {
                self.xtx[i][j] += wxi * x[j];
            }
            self.xty[i] += wxi * y;
        }
        self.yty += w * y * y;
        self.rows += 1;
        Ok(())
    }

    /// The same equations for the rows `d ∘ x` (element-wise scaled regressors): lets rows be
    /// accumulated before a per-column factor is known.
    pub fn scaled(&self, d: &[f64; N]) -> Self {
        let mut out = *self;
        for i in 0..N {
            for j in 0..=i {
                out.xtx[i][j] *= d[i] * d[j];
            }
            out.xty[i] *= d[i];
        }
        out
    }

    /// The normal matrix `Σ w x xᵀ` (symmetric, full).
    pub fn matrix(&self) -> [[f64; N]; N] {
        let mut a = self.xtx;
        for i in 0..N {
            for j in i + 1..N {
                a[i][j] = a[j][i];
            }
        }
        a
    }

    /// Condition number of the normal matrix after scaling it to a unit diagonal, so that it
    /// measures geometry, not units. Infinite when a column is all zero.
    pub fn condition(&self) -> f64 {
        let a = self.matrix();
        let mut s = [0.0; N];
        for i in 0..N {
            if !(a[i][i] > 0.0) {
                return f64::INFINITY;
            }
            s[i] = 1.0 / libm::sqrt(a[i][i]);
        }
        let mut e = a;
        for i in 0..N {
            for j in 0..N {
                e[i][j] *= s[i] * s[j];
            }
        }
        let (vals, _) = sym_eigen(&e);
        if vals[0] > 0.0 {
            vals[N - 1] / vals[0]
        } else {
            f64::INFINITY
        }
    }

    /// The parameters alone, by Cholesky (no condition number, no covariance): for the
    /// iterates of an iterative solve, whose last step is checked by [`Self::solve`].
    pub fn estimate(&self) -> Result<[f64; N], Error> {
        let l = cholesky(&self.matrix(), 1e-13).ok_or(Error::Singular)?;
        Ok(cholesky_solve(&l, &self.xty))
    }

    /// Solves by Cholesky. Errors: fewer rows than unknowns, a singular or ill-conditioned matrix.
    pub fn solve(&self) -> Result<Solution<N>, Error> {
        if (self.rows as usize) < N {
            return Err(Error::TooFewRows { have: self.rows, need: N as u32 });
        }
        let a = self.matrix();
        let l = cholesky(&a, 1e-13).ok_or(Error::Singular)?;
        let condition = self.condition();
        if !(condition <= MAX_CONDITION) {
            return Err(Error::IllConditioned { condition: condition as f32, limit: MAX_CONDITION as f32 });
        }
        let x = cholesky_solve(&l, &self.xty);
        let fit: f64 = (0..N).map(|i| x[i] * self.xty[i]).sum();
        let rss = (self.yty - fit).max(0.0);
        let dof = self.rows - N as u32;
        let s2 = if dof > 0 { rss / dof as f64 } else { 0.0 };
        let mut covariance = cholesky_inverse(&l);
        for row in covariance.iter_mut() {
            for c in row.iter_mut() {
                *c *= s2;
            }
        }
        Ok(Solution { x, rss, dof, covariance, condition })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exact_recovery_and_zero_residual() {
        let beta = [1.5, -2.0, 0.25];
        let mut ne = NormalEquations::<3>::new();
        for k in 0..10 {
            let x = [1.0 + k as f64, (k * k) as f64 * 0.1, libm::sin(k as f64)];
            let y: f64 = (0..3).map(|i| x[i] * beta[i]).sum();
            ne.add_row(&x, y, 1.0).unwrap();
        }
        let s = ne.solve().unwrap();
        for i in 0..3 {
            assert!((s.x[i] - beta[i]).abs() < 1e-10, "{:?}", s.x);
        }
        assert!(s.rss < 1e-16 * 10.0 && s.dof == 7);
    }

    #[test]
    fn residual_and_sigma_match_known_line_fit() {
        // y = a + b t with residuals ±1 alternating: rss = n, s² = n/(n−2).
        let mut ne = NormalEquations::<2>::new();
        let n = 20;
        for k in 0..n {
            let t = k as f64;
            let e = if k % 2 == 0 { 1.0 } else { -1.0 };
            ne.add_row(&[1.0, t], 3.0 + 0.5 * t + e, 1.0).unwrap();
        }
        let s = ne.solve().unwrap();
        assert!((s.rss - n as f64).abs() < 1e-6 * n as f64 + 0.2, "rss {}", s.rss);
        // σ_b² = s² / Σ(t−t̄)²
        let sxx: f64 = (0..n).map(|k| (k as f64 - 9.5).powi(2)).sum();
        let expect = libm::sqrt(s.rss / (n as f64 - 2.0) / sxx);
        assert!((s.sigma(1) - expect).abs() < 1e-9);
    }

    #[test]
    fn too_few_rows_singular_and_ill_conditioned_are_distinct() {
        let mut ne = NormalEquations::<3>::new();
        ne.add_row(&[1.0, 0.0, 0.0], 1.0, 1.0).unwrap();
        assert_eq!(ne.solve(), Err(Error::TooFewRows { have: 1, need: 3 }));
        ne.add_row(&[2.0, 0.0, 0.0], 2.0, 1.0).unwrap();
        ne.add_row(&[0.0, 1.0, 0.0], 2.0, 1.0).unwrap();
        assert_eq!(ne.solve(), Err(Error::Singular));
        let mut ne = NormalEquations::<2>::new();
        ne.add_row(&[1.0, 1.0], 1.0, 1.0).unwrap();
        ne.add_row(&[1.0, 1.0 + 1e-6], 1.0, 1.0).unwrap();
        assert!(matches!(ne.solve(), Err(Error::IllConditioned { .. })));
    }

    #[test]
    fn scaled_equals_rows_scaled_up_front() {
        let d = [2.0, -3.0, 0.5];
        let mut a = NormalEquations::<3>::new();
        let mut b = NormalEquations::<3>::new();
        for k in 0..6 {
            let x = [1.0, k as f64, (k as f64).powi(2) - 3.0];
            a.add_row(&x, 1.0, 1.0).unwrap();
            b.add_row(&[x[0] * d[0], x[1] * d[1], x[2] * d[2]], 1.0, 1.0).unwrap();
        }
        let (sa, sb) = (a.scaled(&d).solve().unwrap(), b.solve().unwrap());
        for i in 0..3 {
            assert!((sa.x[i] - sb.x[i]).abs() < 1e-12);
        }
    }

    #[test]
    fn non_finite_rows_are_refused() {
        let mut ne = NormalEquations::<2>::new();
        assert_eq!(ne.add_row(&[f64::NAN, 1.0], 1.0, 1.0), Err(Error::NonFinite));
        assert_eq!(ne.rows(), 0);
    }
}
