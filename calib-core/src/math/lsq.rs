//! Weighted linear least squares through normal equations, accumulated one row at a time.
//!
//! `NormalEquations<N>` keeps `Σ w x xᵀ`, `Σ w x y`, `Σ w y²` in `f64`: O(N²) state whatever the
//! number of rows. Every linear solve of the crate goes through it (3 unknowns for the gyro,
//! 6 and 9 for the accelerometer).

use crate::math::linalg::{
    cholesky, cholesky_in, cholesky_inverse, cholesky_inverse_in, cholesky_solve, cholesky_solve_in, sym_extremes_in, MAX_N,
};
use crate::Error;

/// Largest accepted condition number of the equilibrated normal matrix (unit diagonal).
pub const MAX_CONDITION: f64 = 1e8;

/// Accumulated normal equations `(Σ w x xᵀ) β = Σ w x y` of an `N`-unknown problem `x·β ≈ y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEquations<const N: usize> {
    /// Lower triangle (`j ≤ i`) of `Σ w x xᵀ`; the upper one stays zero.
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
    /// Parameter covariance `s² (Σ w x xᵀ)⁻¹` with `s² = (rss / dof) ·`
    /// [`few_dof_factor`]`(dof)` (zero when `dof == 0`).
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
        const { assert!(N <= MAX_N, "more unknowns than the linear algebra's MAX_N") };
        Self { xtx: [[0.0; N]; N], xty: [0.0; N], yty: 0.0, rows: 0 }
    }

    /// The prior `β ~ N(0, I/w)`: the `N` unit rows `eᵢ·β ≈ 0` of weight `w` (the same sums as
    /// adding them).
    pub const fn prior(w: f64) -> Self {
        let mut out = Self::new();
        let mut i = 0;
        while i < N {
            out.xtx[i][i] = w;
            i += 1;
        }
        out.rows = N as u32;
        out
    }

    /// Number of rows added.
    pub fn rows(&self) -> u32 {
        self.rows
    }

    /// Adds the row `x·β ≈ y` with weight `w` (inverse variance). Non-finite rows are refused.
    pub fn add_row(&mut self, x: &[f64; N], y: f64, w: f64) -> Result<(), Error> {
        add_row(self.xtx.as_flattened_mut(), &mut self.xty, &mut self.yty, x, y, w)?;
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

    /// `(Σ w x xᵀ)⁻¹` by Cholesky: the parameter covariance before its scaling by the residual.
    pub fn inverse(&self) -> Result<[[f64; N]; N], Error> {
        let l = cholesky(&self.xtx, 1e-13).ok_or(Error::Singular)?;
        Ok(cholesky_inverse(&l))
    }

    /// Condition number of the normal matrix after scaling it to a unit diagonal, so that it
    /// measures geometry, not units. Infinite when a column is all zero.
    pub fn condition(&self) -> f64 {
        condition(self.xtx.as_flattened(), N)
    }

    /// The parameters alone, by Cholesky (no condition number, no covariance): for the
    /// iterates of an iterative solve, whose last step is checked by [`Self::solve`].
    pub fn estimate(&self) -> Result<[f64; N], Error> {
        let (mut l, mut x) = ([0.0; MAX_N * MAX_N], [0.0; N]);
        if !cholesky_in(self.xtx.as_flattened(), &mut l[..N * N], N, 1e-13) {
            return Err(Error::Singular);
        }
        cholesky_solve_in(&l[..N * N], &self.xty, &mut x);
        Ok(x)
    }

    /// Marginalises `M` more unknowns `z` out of equations whose rows were `x·β + c·z ≈ y`, given
    /// `Σ w x cᵀ` (`cross`) and the rows `c·z ≈ y` alone (`nuisance`, positive definite: a prior
    /// added): what is left are the normal equations of `β` alone (the Schur complement), whose
    /// solution and covariance are those of the joint solve.
    pub fn eliminate<const M: usize>(&mut self, cross: &[[f64; M]; N], nuisance: &NormalEquations<M>) -> Result<(), Error> {
        let l = cholesky(&nuisance.xtx, 1e-13).ok_or(Error::Singular)?;
        let dot = |a: &[f64; M], b: &[f64; M]| a.iter().zip(b).map(|(a, b)| a * b).sum::<f64>();
        let cy = &nuisance.xty;
        for i in 0..N {
            let s = cholesky_solve(&l, &cross[i]);
            for j in 0..=i {
                self.xtx[i][j] -= dot(&cross[j], &s);
            }
            self.xty[i] -= dot(&s, cy);
        }
        self.yty -= dot(cy, &cholesky_solve(&l, cy));
        Ok(())
    }

    /// Solves by Cholesky. Errors: fewer rows than unknowns, a singular or ill-conditioned matrix.
    pub fn solve(&self) -> Result<Solution<N>, Error> {
        let (mut x, mut covariance) = ([0.0; N], [[0.0; N]; N]);
        let (rss, dof, condition) =
            solve(self.xtx.as_flattened(), &self.xty, self.yty, self.rows, None, &mut x, covariance.as_flattened_mut())?;
        Ok(Solution { x, rss, dof, covariance, condition })
    }

    /// [`Self::solve`]'s checks alone, its errors or the condition number: for a caller that
    /// needs neither the solution nor its covariance (the last equations of an iteration).
    pub fn check(&self) -> Result<f64, Error> {
        self.solve().map(|s| s.condition)
    }

    /// [`Self::check`] with its condition number already computed ([`Self::condition`], most of
    /// the work): the same result, for a caller that runs the two in calls of their own.
    pub fn check_given(&self, condition: f64) -> Result<f64, Error> {
        let (mut x, mut covariance) = ([0.0; N], [[0.0; N]; N]);
        solve(self.xtx.as_flattened(), &self.xty, self.yty, self.rows, Some(condition), &mut x, covariance.as_flattened_mut())
            .map(|(_, _, c)| c)
    }

    /// The [`Solution`] [`Self::solve`] gave, from its parts but the covariance, which is
    /// computed again, bit for bit the same: for a caller that keeps a solution across calls
    /// without its `N × N` covariance.
    pub fn solution(&self, x: [f64; N], rss: f64, dof: u32, condition: f64) -> Result<Solution<N>, Error> {
        let mut l = [0.0; MAX_N * MAX_N];
        if !cholesky_in(self.xtx.as_flattened(), &mut l[..N * N], N, 1e-13) {
            return Err(Error::Singular);
        }
        let mut covariance = [[0.0; N]; N];
        scaled_inverse(&l[..N * N], N, rss, dof, covariance.as_flattened_mut());
        Ok(Solution { x, rss, dof, covariance, condition })
    }
}

/// [`NormalEquations::add_row`] into the row-major lower triangle `xtx` (`n = x.len()`), `xty`, `yty`.
fn add_row(xtx: &mut [f64], xty: &mut [f64], yty: &mut f64, x: &[f64], y: f64, w: f64) -> Result<(), Error> {
    if !(x.iter().all(|v| v.is_finite()) && y.is_finite() && w.is_finite() && w >= 0.0) {
        return Err(Error::NonFinite);
    }
    let n = x.len();
    for i in 0..n {
        let wxi = w * x[i];
        for j in 0..=i {
            xtx[i * n + j] += wxi * x[j];
        }
        xty[i] += wxi * y;
    }
    *yty += w * y * y;
    Ok(())
}

/// [`NormalEquations::condition`] of the `n × n` row-major lower triangle `xtx`.
fn condition(xtx: &[f64], n: usize) -> f64 {
    let mut s = [0.0; MAX_N];
    for i in 0..n {
        let d = xtx[i * n + i];
        if !(d > 0.0) {
            return f64::INFINITY;
        }
        s[i] = 1.0 / libm::sqrt(d);
    }
    let mut e = [0.0; MAX_N * MAX_N];
    for i in 0..n {
        for j in 0..n {
            e[i * n + j] = xtx[i.max(j) * n + i.min(j)] * (s[i] * s[j]);
        }
    }
    let (smallest, largest) = sym_extremes_in(&e[..n * n], n);
    if smallest > 0.0 {
        largest / smallest
    } else {
        f64::INFINITY
    }
}

/// The variance factor for a residual variance estimated from `dof` degrees of freedom: a
/// parameter's error over its σ is then Student-t with `dof` degrees, not normal (with 3, only
/// 86 % lie within 2σ). The factor is the square root of the t's variance `ν / (ν − 2)` — σ
/// halfway (geometrically) between the estimate and the t's standard deviation — which puts
/// 68–72 % within 1σ and ≥ 92 % within 2σ for every `ν ≥ 3`; 4 for `ν = 2` (82 % / 94 %), 36 for
/// `ν = 1` (90 % / 95 %); → 1 for many rows.
/// A weighted (fractional) `dof` below 3 takes the factor of the whole number below it.
pub fn few_dof_factor(dof: f64) -> f64 {
    if dof >= 3.0 {
        libm::sqrt(dof / (dof - 2.0))
    } else if dof >= 2.0 {
        4.0
    } else {
        36.0
    }
}

/// χ²'s 95 % point for `nu` degrees of freedom (Wilson & Hilferty 1931: `ν (1 − 2/(9ν) +
/// 1.645 √(2/(9ν)))³`, within 1 % for `ν ≥ 2`, 2.4 % low at `ν = 1`; fractional `ν` as is;
/// not for `ν < 1`): a residual sum beyond it says the residuals exceed the noise they were
/// weighted by.
pub fn chi2_95(nu: f64) -> f64 {
    let c = 1.0 - 2.0 / (9.0 * nu) + 1.645 * libm::sqrt(2.0 / (9.0 * nu));
    nu * c * c * c
}

/// [`NormalEquations::solve`] with `n = xty.len()` unknowns (`xtx` its row-major lower triangle):
/// writes `x` and the covariance, returns `(rss, dof, condition)` (`known`: the condition number,
/// computed before).
fn solve(
    xtx: &[f64],
    xty: &[f64],
    yty: f64,
    rows: u32,
    known: Option<f64>,
    x: &mut [f64],
    covariance: &mut [f64],
) -> Result<(f64, u32, f64), Error> {
    let n = xty.len();
    if (rows as usize) < n {
        return Err(Error::TooFewRows { have: rows, need: n as u32 });
    }
    let mut l = [0.0; MAX_N * MAX_N];
    let l = &mut l[..n * n];
    if !cholesky_in(xtx, l, n, 1e-13) {
        return Err(Error::Singular);
    }
    let condition = known.unwrap_or_else(|| condition(xtx, n));
    if !(condition <= MAX_CONDITION) {
        return Err(Error::IllConditioned { condition: condition as f32, limit: MAX_CONDITION as f32 });
    }
    cholesky_solve_in(l, xty, x);
    let fit: f64 = (0..n).map(|i| x[i] * xty[i]).sum();
    let rss = (yty - fit).max(0.0);
    let dof = rows - n as u32;
    scaled_inverse(l, n, rss, dof, covariance);
    Ok((rss, dof, condition))
}

/// The covariance from the Cholesky factor `l` (`n × n`) of the normal matrix: its inverse scaled by the
/// residual variance `rss / dof` (and the few-dof factor).
fn scaled_inverse(l: &[f64], n: usize, rss: f64, dof: u32, covariance: &mut [f64]) {
    let s2 = if dof > 0 { rss / dof as f64 * few_dof_factor(dof as f64) } else { 0.0 };
    cholesky_inverse_in(l, covariance, n);
    for c in covariance.iter_mut() {
        *c *= s2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// χ²'s 95 % points from the tables (ν = 1, 2, 3, 5, 10, 30) within what the doc says.
    #[test]
    fn chi2_95_is_the_table_s() {
        for (nu, table, tol) in
            [(1.0, 3.841, 0.025), (2.0, 5.991, 0.01), (3.0, 7.815, 0.01), (5.0, 11.070, 0.01), (10.0, 18.307, 0.01), (30.0, 43.773, 0.01)]
        {
            let v = chi2_95(nu);
            assert!((v / table - 1.0).abs() <= tol, "nu {nu}: {v} against {table}");
        }
    }

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
        // σ_b² = s² / Σ(t−t̄)², s² = rss / (n − 2) times the few-dof factor √(18/16).
        let sxx: f64 = (0..n).map(|k| (k as f64 - 9.5).powi(2)).sum();
        let expect = libm::sqrt(s.rss / (n as f64 - 2.0) * (18.0f64 / 16.0).sqrt() / sxx);
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
    fn inverse_is_the_unscaled_covariance() {
        let mut ne = NormalEquations::<2>::new();
        for k in 0..5 {
            ne.add_row(&[1.0, k as f64], (k * k) as f64, 1.0).unwrap();
        }
        let (s, inv) = (ne.solve().unwrap(), ne.inverse().unwrap());
        let s2 = s.rss / s.dof as f64 * few_dof_factor(s.dof as f64);
        for i in 0..2 {
            for j in 0..2 {
                assert_eq!(s.covariance[i][j], inv[i][j] * s2);
            }
        }
    }

    /// A line fitted to 5 points with unit-variance noise (3 degrees of freedom), 4000 times:
    /// the slope's error lies within its 1σ and 2σ as often as [`few_dof_factor`] promises (the
    /// plain `rss / dof` gives about 61 % and 86 %).
    #[test]
    fn sigma_covers_the_error_with_few_degrees_of_freedom() {
        let mut noise = crate::math::test_noise::Gaussian::new(0x2545_f491_4f6c_dd1d);
        let (mut within, runs) = ([0u32; 2], 4000);
        for _ in 0..runs {
            let mut ne = NormalEquations::<2>::new();
            for k in 0..5 {
                ne.add_row(&[1.0, k as f64], 2.0 + 0.5 * k as f64 + noise.next(), 1.0).unwrap();
            }
            let s = ne.solve().unwrap();
            let (e, sigma) = ((s.x[1] - 0.5).abs(), s.sigma(1));
            within[0] += (e <= sigma) as u32;
            within[1] += (e <= 2.0 * sigma) as u32;
        }
        let [one, two] = within.map(|n| n as f64 / runs as f64);
        assert!((0.65..=0.76).contains(&one) && two >= 0.92, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
    }

    #[test]
    fn non_finite_rows_are_refused() {
        let mut ne = NormalEquations::<2>::new();
        assert_eq!(ne.add_row(&[f64::NAN, 1.0], 1.0, 1.0), Err(Error::NonFinite));
        assert_eq!(ne.rows(), 0);
    }
}
