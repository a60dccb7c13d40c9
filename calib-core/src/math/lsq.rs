//! Weighted linear least squares through normal equations, accumulated one row at a time.
//!
//! `NormalEquations<N>` keeps `Σ w x xᵀ`, `Σ w x y`, `Σ w y²` in [`Sum`] whatever [`Real`] is
//! (`f64` on the PC, a double-single [`crate::math::wide::Wide`] on the FPU):
//! O(N²) state whatever the number of rows. It solves in [`Real`], but takes the residual sum
//! from those sums at the solution, `Σ w y² − 2 βᵀ Σ w x y + βᵀ (Σ w x xᵀ) β`: a small
//! difference of large sums, which sums in `f32` lose (the firmware's 1σ of K came out 0.6 times
//! the PC's on a 952 Hz log), and which the solve's rounding of `β` changes
//! only to second order. Every linear solve of the crate goes through it (3 unknowns for the
//! gyro, 6 and 9 for the accelerometer).

use crate::math::linalg::{
    cholesky, cholesky_in, cholesky_inverse, cholesky_inverse_in, cholesky_solve, cholesky_solve_in, sym_extremes_in, MAX_N,
};
use crate::math::real::{self, narrow, widen, Real, Scalar, Sum};
use crate::Error;

/// Largest accepted condition number of the equilibrated normal matrix (unit diagonal): 1e8 in
/// `f64`; 1e6 in `f32` (the firmware), whose solves and condition estimates (its smallest
/// eigenvalue to ± the rounding of the largest, 1e-7 of it) resolve no more.
pub const MAX_CONDITION: Real = if cfg!(feature = "single") { 1e6 } else { 1e8 };

/// Accumulated normal equations `(Σ w x xᵀ) β = Σ w x y` of an `N`-unknown problem `x·β ≈ y`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEquations<const N: usize> {
    /// Lower triangle (`j ≤ i`) of `Σ w x xᵀ`; the upper one stays zero.
    xtx: [[Sum; N]; N],
    xty: [Sum; N],
    yty: Sum,
    rows: u32,
}

/// A least-squares solution with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Solution<const N: usize> {
    /// The parameters `β`.
    pub x: [Real; N],
    /// Weighted residual sum of squares `Σ w (y − x·β)²`.
    pub rss: Real,
    /// Rows minus unknowns.
    pub dof: u32,
    /// Parameter covariance `s² (Σ w x xᵀ)⁻¹` with `s² = (rss / dof) ·`
    /// [`few_dof_factor`]`(dof)` (zero when `dof == 0`).
    pub covariance: [[Real; N]; N],
    /// 2-norm condition number of the equilibrated normal matrix.
    pub condition: Real,
}

impl<const N: usize> Solution<N> {
    /// 1σ of parameter `i` (square root of the covariance diagonal).
    pub fn sigma(&self, i: usize) -> Real {
        real::sqrt(self.covariance[i][i].max(0.0))
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
        Self { xtx: [[<Sum as Scalar>::ZERO; N]; N], xty: [<Sum as Scalar>::ZERO; N], yty: <Sum as Scalar>::ZERO, rows: 0 }
    }

    /// The prior `β ~ N(0, I/w)`: the `N` unit rows `eᵢ·β ≈ 0` of weight `w` (the same sums as
    /// adding them).
    pub const fn prior(w: Real) -> Self {
        let mut out = Self::new();
        let mut i = 0;
        while i < N {
            out.xtx[i][i] = widen(w);
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
    pub fn add_row(&mut self, x: &[Real; N], y: Real, w: Real) -> Result<(), Error> {
        add_row(self.xtx.as_flattened_mut(), &mut self.xty, &mut self.yty, x, y, w)?;
        self.rows += 1;
        Ok(())
    }

    /// The same equations for the rows `d ∘ x` (element-wise scaled regressors): lets rows be
    /// accumulated before a per-column factor is known.
    pub fn scaled(&self, d: &[Real; N]) -> Self {
        let mut out = *self;
        for i in 0..N {
            for j in 0..=i {
                out.xtx[i][j] *= widen(d[i]) * widen(d[j]);
            }
            out.xty[i] *= widen(d[i]);
        }
        out
    }

    /// `(Σ w x xᵀ)⁻¹` by Cholesky: the parameter covariance before its scaling by the residual.
    pub fn inverse(&self) -> Result<[[Real; N]; N], Error> {
        let l = cholesky(&self.xtx.map(|r| r.map(narrow)), 1e-13).ok_or(Error::Singular)?;
        Ok(cholesky_inverse(&l))
    }

    /// Condition number of the normal matrix after scaling it to a unit diagonal, so that it
    /// measures geometry, not units. Infinite when a column is all zero.
    pub fn condition(&self) -> Real {
        condition(&self.real()[..N * N], N)
    }

    /// The parameters alone, by Cholesky (no condition number, no covariance): for the
    /// iterates of an iterative solve, whose last step is checked by [`Self::solve`].
    pub fn estimate(&self) -> Result<[Real; N], Error> {
        let (mut l, mut x) = ([0.0; MAX_N * MAX_N], [0.0; N]);
        if !cholesky_in(&self.real()[..N * N], &mut l[..N * N], N, 1e-13) {
            return Err(Error::Singular);
        }
        cholesky_solve_in(&l[..N * N], &self.xty.map(narrow), &mut x);
        Ok(x)
    }

    /// `Σ w x xᵀ` in [`Real`], row-major `N × N` (its lower triangle), for the solves.
    fn real(&self) -> [Real; MAX_N * MAX_N] {
        let mut a = [0.0; MAX_N * MAX_N];
        for (a, v) in a.iter_mut().zip(self.xtx.as_flattened()) {
            *a = narrow(*v);
        }
        a
    }

    /// Marginalises `M` more unknowns `z` out of equations whose rows were `x·β + c·z ≈ y`, given
    /// `Σ w x cᵀ` (`cross`) and the rows `c·z ≈ y` alone (`nuisance`, positive definite: a prior
    /// added): what is left are the normal equations of `β` alone (the Schur complement), whose
    /// solution and covariance are those of the joint solve. In [`Sum`], as the sums are.
    pub fn eliminate<const M: usize>(&mut self, cross: &[[Sum; M]; N], nuisance: &NormalEquations<M>) -> Result<(), Error> {
        let l = cholesky(&nuisance.xtx, widen(1e-13)).ok_or(Error::Singular)?;
        let dot = |a: &[Sum; M], b: &[Sum; M]| a.iter().zip(b).fold(<Sum as Scalar>::ZERO, |s, (a, b)| s + *a * *b);
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
        let (rss, dof, condition) = self.solve_into(None, &mut x, covariance.as_flattened_mut())?;
        Ok(Solution { x, rss, dof, covariance, condition })
    }

    /// [`Self::solve`]'s checks alone, its errors or the condition number: for a caller that
    /// needs neither the solution nor its covariance (the last equations of an iteration).
    pub fn check(&self) -> Result<Real, Error> {
        self.solve().map(|s| s.condition)
    }

    /// [`Self::check`] with its condition number already computed ([`Self::condition`], most of
    /// the work): the same result, for a caller that runs the two in calls of their own.
    pub fn check_given(&self, condition: Real) -> Result<Real, Error> {
        let (mut x, mut covariance) = ([0.0; N], [[0.0; N]; N]);
        self.solve_into(Some(condition), &mut x, covariance.as_flattened_mut()).map(|(_, _, c)| c)
    }

    /// The [`Solution`] [`Self::solve`] gave, from its parts but the covariance, which is
    /// computed again, bit for bit the same: for a caller that keeps a solution across calls
    /// without its `N × N` covariance.
    pub fn solution(&self, x: [Real; N], rss: Real, dof: u32, condition: Real) -> Result<Solution<N>, Error> {
        let mut l = [0.0; MAX_N * MAX_N];
        if !cholesky_in(&self.real()[..N * N], &mut l[..N * N], N, 1e-13) {
            return Err(Error::Singular);
        }
        let mut covariance = [[0.0; N]; N];
        scaled_inverse(&l[..N * N], N, rss, dof, covariance.as_flattened_mut());
        Ok(Solution { x, rss, dof, covariance, condition })
    }

    /// [`Self::solve`] into `x` and the covariance: `(rss, dof, condition)` (`known`: the
    /// condition number, computed before).
    fn solve_into(&self, known: Option<Real>, x: &mut [Real; N], covariance: &mut [Real]) -> Result<(Real, u32, Real), Error> {
        if (self.rows as usize) < N {
            return Err(Error::TooFewRows { have: self.rows, need: N as u32 });
        }
        let a = self.real();
        let mut l = [0.0; MAX_N * MAX_N];
        let l = &mut l[..N * N];
        if !cholesky_in(&a[..N * N], l, N, 1e-13) {
            return Err(Error::Singular);
        }
        let condition = known.unwrap_or_else(|| condition(&a[..N * N], N));
        if !(condition <= MAX_CONDITION) {
            return Err(Error::IllConditioned { condition: condition as f32, limit: MAX_CONDITION as f32 });
        }
        cholesky_solve_in(l, &self.xty.map(narrow), x);
        let rss = narrow(self.rss_at(x)).max(0.0);
        let dof = self.rows - N as u32;
        scaled_inverse(l, N, rss, dof, covariance);
        Ok((rss, dof, condition))
    }

    /// `Σ w (y − x·β)²` at `β`, from the [`Sum`]s.
    fn rss_at(&self, beta: &[Real; N]) -> Sum {
        let mut q = self.yty;
        for i in 0..N {
            let bi = widen(beta[i]);
            q += bi * (bi * self.xtx[i][i] - (self.xty[i] + self.xty[i]));
            for j in 0..i {
                let p = bi * widen(beta[j]) * self.xtx[i][j];
                q += p + p;
            }
        }
        q
    }
}

/// [`NormalEquations::add_row`] into the row-major lower triangle `xtx` (`n = x.len()`), `xty`, `yty`.
fn add_row(xtx: &mut [Sum], xty: &mut [Sum], yty: &mut Sum, x: &[Real], y: Real, w: Real) -> Result<(), Error> {
    if !(x.iter().all(|v| v.is_finite()) && y.is_finite() && w.is_finite() && w >= 0.0) {
        return Err(Error::NonFinite);
    }
    let (n, y, w) = (x.len(), widen(y), widen(w));
    let mut xd = [<Sum as Scalar>::ZERO; MAX_N];
    for (d, v) in xd.iter_mut().zip(x) {
        *d = widen(*v);
    }
    for i in 0..n {
        let wxi = w * xd[i];
        for j in 0..=i {
            xtx[i * n + j] += wxi * xd[j];
        }
        xty[i] += wxi * y;
    }
    *yty += w * y * y;
    Ok(())
}

/// [`NormalEquations::condition`] of the `n × n` row-major lower triangle `xtx`.
fn condition(xtx: &[Real], n: usize) -> Real {
    let mut s = [0.0; MAX_N];
    for i in 0..n {
        let d = xtx[i * n + i];
        if !(d > 0.0) {
            return Real::INFINITY;
        }
        s[i] = 1.0 / real::sqrt(d);
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
        Real::INFINITY
    }
}

/// The variance factor for a residual variance estimated from `dof` degrees of freedom: a
/// parameter's error over its σ is then Student-t with `dof` degrees, not normal (with 3, only
/// 86 % lie within 2σ). The factor is the square root of the t's variance `ν / (ν − 2)` — σ
/// halfway (geometrically) between the estimate and the t's standard deviation — which puts
/// 68–72 % within 1σ and ≥ 92 % within 2σ for every `ν ≥ 3`; 4 for `ν = 2` (82 % / 94 %), 36 for
/// `ν = 1` (90 % / 95 %); → 1 for many rows.
/// A weighted (fractional) `dof` below 3 takes the factor of the whole number below it.
pub fn few_dof_factor(dof: Real) -> Real {
    if dof >= 3.0 {
        real::sqrt(dof / (dof - 2.0))
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
pub fn chi2_95(nu: Real) -> Real {
    let c = 1.0 - 2.0 / (9.0 * nu) + 1.645 * real::sqrt(2.0 / (9.0 * nu));
    nu * c * c * c
}

/// The covariance from the Cholesky factor `l` (`n × n`) of the normal matrix: its inverse scaled by the
/// residual variance `rss / dof` (and the few-dof factor).
fn scaled_inverse(l: &[Real], n: usize, rss: Real, dof: u32, covariance: &mut [Real]) {
    let s2 = if dof > 0 { rss / dof as Real * few_dof_factor(dof as Real) } else { 0.0 };
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
        let (mut ne, mut yty) = (NormalEquations::<3>::new(), 0.0);
        for k in 0..10 {
            let x = [1.0 + k as Real, (k * k) as Real * 0.1, libm::sin(k as Real)];
            let y: Real = (0..3).map(|i| x[i] * beta[i]).sum();
            ne.add_row(&x, y, 1.0).unwrap();
            yty += y * y;
        }
        let s = ne.solve().unwrap();
        for i in 0..3 {
            assert!((s.x[i] - beta[i]).abs() < 1e-10, "{:?}", s.x);
        }
        // Zero within the rounding of the sums it is the difference of (`Σ y²` and the
        // fit's quadratic form, each ≈ `yty`).
        assert!(s.rss < 1e-14 * yty && s.dof == 7, "rss {:e} of {yty:e}", s.rss);
    }

    #[test]
    fn residual_and_sigma_match_known_line_fit() {
        // y = a + b t with residuals ±1 alternating: rss = n, s² = n/(n−2).
        let mut ne = NormalEquations::<2>::new();
        let n = 20;
        for k in 0..n {
            let t = k as Real;
            let e = if k % 2 == 0 { 1.0 } else { -1.0 };
            ne.add_row(&[1.0, t], 3.0 + 0.5 * t + e, 1.0).unwrap();
        }
        let s = ne.solve().unwrap();
        assert!((s.rss - n as Real).abs() < 1e-6 * n as Real + 0.2, "rss {}", s.rss);
        // σ_b² = s² / Σ(t−t̄)², s² = rss / (n − 2) times the few-dof factor √(18/16).
        let sxx: Real = (0..n).map(|k| (k as Real - 9.5).powi(2)).sum();
        let expect = libm::sqrt(s.rss / (n as Real - 2.0) * ((18.0 as Real) / 16.0).sqrt() / sxx);
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
            let x = [1.0, k as Real, (k as Real).powi(2) - 3.0];
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
            ne.add_row(&[1.0, k as Real], (k * k) as Real, 1.0).unwrap();
        }
        let (s, inv) = (ne.solve().unwrap(), ne.inverse().unwrap());
        let s2 = s.rss / s.dof as Real * few_dof_factor(s.dof as Real);
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
                ne.add_row(&[1.0, k as Real], 2.0 + 0.5 * k as Real + noise.next(), 1.0).unwrap();
            }
            let s = ne.solve().unwrap();
            let (e, sigma) = ((s.x[1] - 0.5).abs(), s.sigma(1));
            within[0] += (e <= sigma) as u32;
            within[1] += (e <= 2.0 * sigma) as u32;
        }
        let [one, two] = within.map(|n| n as Real / runs as Real);
        assert!((0.65..=0.76).contains(&one) && two >= 0.92, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
    }

    #[test]
    fn non_finite_rows_are_refused() {
        let mut ne = NormalEquations::<2>::new();
        assert_eq!(ne.add_row(&[Real::NAN, 1.0], 1.0, 1.0), Err(Error::NonFinite));
        assert_eq!(ne.rows(), 0);
    }
}
